//! `kausal bench`: speed against error of kausal's solvers and ngspice's
//! integrators over a range of tolerances, as a markdown report, and
//! optionally `bench.json` and a work-precision SVG per circuit.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use indicatif::{ProgressBar, ProgressStyle};
use kausal::bench::{self, BenchError, CircuitBench, Scaling};
use kausal::validate::ValidateError;

use crate::args::{Method, relative_tolerance};
use crate::error::Error;
use crate::output::emit;

#[derive(clap::Args)]
pub struct Args {
    /// The netlist files.
    netlists: Vec<PathBuf>,
    /// Relative tolerances (kausal's rtol and ngspice's reltol). The loosest, 1e-2,
    /// reaches the error of ngspice's defaults where that error is large.
    #[arg(long, value_delimiter = ',', value_parser = relative_tolerance, default_values_t = [1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7])]
    tolerances: Vec<f64>,
    /// kausal's solvers.
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = [Method::Bdf, Method::TrBdf2, Method::Esdirk34, Method::Circuit])]
    solvers: Vec<Method>,
    /// Runs per measurement (the median is reported).
    #[arg(long, default_value_t = 3)]
    repeats: usize,
    /// kausal only, no ngspice runs.
    #[arg(long)]
    no_ngspice: bool,
    /// Also run generated RC ladders of 10^2 sections up to --max-sections.
    #[arg(long)]
    scaling: bool,
    /// The largest ladder of --scaling.
    #[arg(long, default_value_t = 100_000)]
    max_sections: usize,
    /// Also bench generated RC ladders of these many sections at free steps
    /// (1 kΩ, 1 nF, `.tran 20u 1m`, `.save v(n1) v(n10)`), as circuits.
    #[arg(long, value_delimiter = ',', value_name = "SECTIONS")]
    ladders: Vec<usize>,
    /// Write bench.json and a work-precision SVG per circuit here.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Write the markdown report to this file (else standard output).
    #[arg(long)]
    report: Option<PathBuf>,
}

/// What the circuits gave: their measurements, and a line per circuit that
/// failed.
struct Results {
    benches: Vec<CircuitBench>,
    failures: Vec<String>,
}

/// Exit code 1 when a circuit failed (the others are still measured and
/// reported); ngspice missing stops the run.
pub fn run(mut args: Args) -> Result<ExitCode, Error> {
    // The ladders are written where the report's files go (else a scratch
    // directory that lives as long as the run).
    let scratch = kausal::io::ScratchDir::new().map_err(Error::Scratch)?;
    let ladder_dir = args
        .out
        .clone()
        .unwrap_or_else(|| scratch.path().to_path_buf());
    for &n in &args.ladders {
        std::fs::create_dir_all(&ladder_dir).map_err(Error::Scratch)?;
        let path = ladder_dir.join(format!("rc_ladder_free_{n}.cir"));
        std::fs::write(&path, kausal::generate::rc_ladder_free(n)).map_err(Error::Scratch)?;
        args.netlists.push(path);
    }
    let opts = bench::Options {
        tolerances: args.tolerances.clone(),
        methods: args.solvers.iter().map(|&m| m.into()).collect(),
        repeats: args.repeats,
        ngspice: !args.no_ngspice,
        exe: std::env::current_exe().ok(),
        ..Default::default()
    };
    let sizes = ladder_sizes(&args);
    let total = args
        .netlists
        .iter()
        .map(|n| bench::measurements(&opts, n))
        .sum::<usize>()
        + sizes.len();
    let bar = progress_bar(total);
    let tick = |msg: &str| {
        bar.set_message(msg.to_string());
        bar.inc(1);
    };
    let results = bench_circuits(&args.netlists, &opts, &bar, &tick)?;
    let scaled = if sizes.is_empty() {
        None
    } else {
        let dir = kausal::io::ScratchDir::new().map_err(Error::Scratch)?;
        Some(bench::scaling(&sizes, dir.path(), !args.no_ngspice, &tick).map_err(Error::Scaling)?)
    };
    bar.finish_and_clear();
    let md = markdown(&args, &opts, &results, scaled.as_ref());
    if let Some(dir) = &args.out {
        write_out(dir, &results.benches, scaled.as_ref())?;
    }
    emit(args.report.as_ref(), &md)?;
    Ok(if results.failures.is_empty() {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}

/// The RC ladders of `--scaling`: 10^2, 10^3, ... sections up to
/// `--max-sections` (at least 10^2); none without `--scaling`.
fn ladder_sizes(args: &Args) -> Vec<usize> {
    if !args.scaling {
        return Vec::new();
    }
    (2..=9)
        .map(|k| 10usize.pow(k))
        .take_while(|&n| n <= args.max_sections.max(100))
        .collect()
}

/// A bar of `total` measurements on standard error (terminals only).
fn progress_bar(total: usize) -> ProgressBar {
    let bar = if std::io::stderr().is_terminal() {
        ProgressBar::new(total as u64)
    } else {
        ProgressBar::hidden()
    };
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} {elapsed} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar
}

/// Measure each netlist. ngspice missing fails the run; a circuit that fails
/// is reported and the others go on.
fn bench_circuits(
    netlists: &[PathBuf],
    opts: &bench::Options,
    bar: &ProgressBar,
    tick: &dyn Fn(&str),
) -> Result<Results, Error> {
    let mut results = Results {
        benches: Vec::new(),
        failures: Vec::new(),
    };
    for path in netlists {
        bar.set_message(path.display().to_string());
        match bench::bench_circuit(path, opts, tick) {
            Ok(b) => results.benches.push(b),
            Err(e @ BenchError::Ngspice(ValidateError::Missing { .. })) => {
                bar.finish_and_clear();
                return Err(Error::Bench(e));
            }
            Err(e) => {
                bar.suspend(|| eprintln!("{}: {e}", path.display()));
                results.failures.push(format!("{}: {e}", path.display()));
            }
        }
    }
    Ok(results)
}

/// The markdown report: the machine and the command that regenerates it,
/// the tables, and the circuits that failed.
fn markdown(
    args: &Args,
    opts: &bench::Options,
    results: &Results,
    scaled: Option<&Scaling>,
) -> String {
    let plots = match &args.out {
        Some(d) => format!("{}/", d.display()),
        None => String::new(),
    };
    let mut md = String::from("# kausal benchmarks\n\n");
    md.push_str(&format!(
        "Measured on {} (one run of `kausal bench`; times are medians of {} repeats, wall clock). Regenerate with:\n\n```\n{}\n```\n\n",
        bench::machine(),
        opts.repeats,
        std::env::args()
            .enumerate()
            .map(|(k, a)| if k == 0 { "kausal".to_string() } else { a })
            .collect::<Vec<_>>()
            .join(" ")
    ));
    md.push_str(bench::PROTOCOL);
    md.push_str(&bench::markdown(&results.benches, scaled, &plots));
    if !results.failures.is_empty() {
        md.push_str("## Circuits that failed\n\n");
        for f in &results.failures {
            md.push_str(&format!("- {f}\n"));
        }
    }
    md
}

/// A work-precision SVG per circuit and `bench.json` in `dir`.
fn write_out(dir: &Path, benches: &[CircuitBench], scaled: Option<&Scaling>) -> Result<(), Error> {
    std::fs::create_dir_all(dir).map_err(Error::create_dir(dir))?;
    for b in benches {
        let svg = bench::work_precision_svg(b).map_err(Error::Plot)?;
        let p = dir.join(format!("{}.svg", bench::stem(&b.netlist)));
        kausal::io::write_atomic(&p, svg.as_bytes()).map_err(Error::write(&p))?;
    }
    let json = serde_json::to_string_pretty(&serde_json::json!({
        "circuits": benches,
        "scaling": scaled,
    }))?;
    let p = dir.join("bench.json");
    kausal::io::write_atomic(&p, json.as_bytes()).map_err(Error::write(&p))
}
