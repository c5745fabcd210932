//! `kausal bondgraph`: the circuit as a bond graph (seed 003's procedure and
//! simplification rules), its causal strokes by SCAP, the equations read off
//! it; with `--check`, cross-checked against the colouring and index
//! reduction. Text, JSON or DOT; `--svg` runs Graphviz's `dot`.

use std::io::Write;
use std::path::PathBuf;
use std::process::{Command, ExitCode, Stdio};

use clap::ValueEnum;
use kausal::bondgraph::{self, BondGraphError, Check};
use kausal::diag::{Diagnostic, ToDiagnostic};
use kausal::io::FsLoader;
use kausal::pipeline;

use crate::error::Error;
use crate::output::{emit, json, print_diags};

#[derive(Clone, Copy, Debug, ValueEnum, PartialEq, Eq)]
enum BondFormat {
    /// The listing: vertices, bonds, rules applied, SCAP, sorted equations.
    Text,
    Json,
    /// Graphviz: the causal bond graph.
    Dot,
}

#[derive(clap::Args)]
pub struct Args {
    /// The netlist file.
    netlist: PathBuf,
    /// Output format.
    #[arg(long, value_enum, default_value_t = BondFormat::Text)]
    format: BondFormat,
    /// Cross-check against the colouring and index reduction of the same
    /// circuit; exit 1 (K0601) where they disagree.
    #[arg(long)]
    check: bool,
    /// Also draw the graph as SVG into this file (runs Graphviz's `dot`).
    #[arg(long, value_name = "FILE")]
    svg: Option<PathBuf>,
    /// Write to this file instead of standard output.
    #[arg(long, short)]
    out: Option<PathBuf>,
}

pub fn run(args: Args) -> Result<ExitCode, Error> {
    let el = pipeline::elaborate_file(&args.netlist, &FsLoader).map_err(Error::netlist)?;
    print_diags(&el.sources, &el.warnings);
    let analysis = bondgraph::analyse(&el.circuit);
    let conflicts: Vec<Diagnostic> =
        BondGraphError::conflicts(&analysis.graph, &analysis.causality)
            .iter()
            .map(|e| e.to_diagnostic())
            .collect();
    print_diags(&el.sources, &conflicts);
    let check: Option<Check> = args.check.then(|| {
        match pipeline::sort(&args.netlist, &FsLoader, &pipeline::SortOptions::default()) {
            Ok(sorted) => bondgraph::check(&sorted, &analysis),
            Err(failed) => {
                let why: Vec<String> = failed
                    .errors()
                    .map(|d| format!("{}: {}", d.code, d.message))
                    .collect();
                bondgraph::check::check_unsorted(&analysis, &why.join("; "))
            }
        }
    });
    let text = match args.format {
        BondFormat::Text => bondgraph::text(&analysis, check.as_ref()),
        BondFormat::Json => json(&bondgraph::json(&analysis, check.as_ref()))?,
        BondFormat::Dot => bondgraph::dot(&analysis),
    };
    if let Some(path) = &args.svg {
        let svg = render_svg(&bondgraph::dot(&analysis))?;
        kausal::io::write_atomic(path, &svg).map_err(Error::write(path))?;
    }
    emit(args.out.as_ref(), &text)?;
    if let Some(e) = check.as_ref().and_then(BondGraphError::disagreement) {
        print_diags(&el.sources, &[e.to_diagnostic()]);
        return Ok(ExitCode::FAILURE);
    }
    Ok(ExitCode::SUCCESS)
}

/// `dot -Tsvg` on `text`.
fn render_svg(text: &str) -> Result<Vec<u8>, Error> {
    let missing = |e: std::io::Error| {
        Error::Dot(format!(
            "cannot run Graphviz's `dot` ({e}): install it (apt-get install graphviz) or write --format dot and render it elsewhere"
        ))
    };
    let mut child = Command::new("dot")
        .arg("-Tsvg")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(missing)?;
    if let Some(mut stdin) = child.stdin.take() {
        stdin.write_all(text.as_bytes()).map_err(missing)?;
    }
    let out = child.wait_with_output().map_err(missing)?;
    if !out.status.success() {
        return Err(Error::Dot(format!(
            "`dot -Tsvg` failed ({}): {}",
            out.status,
            String::from_utf8_lossy(&out.stderr).trim()
        )));
    }
    Ok(out.stdout)
}
