//! `kausal sort`: the equations sorted into causal assignments, algebraic
//! loops torn, printed as a listing, JSON or a Graphviz graph.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::ValueEnum;
use kausal::back::listing;
use kausal::diag::{Diagnostic, ToDiagnostic};
use kausal::io::FsLoader;
use kausal::pipeline::{self, Sorted};

use crate::args::BuildArgs;
use crate::error::Error;
use crate::output::{emit, emit_with, json, print_diags};

#[derive(Clone, Copy, Debug, ValueEnum, PartialEq, Eq)]
enum SortFormat {
    Text,
    Json,
    /// Graphviz: the coloured bipartite graph.
    Dot,
}

#[derive(clap::Args)]
pub struct Args {
    /// The netlist file.
    netlist: PathBuf,
    #[command(flatten)]
    build: BuildArgs,
    /// Output format.
    #[arg(long, value_enum, default_value_t = SortFormat::Text)]
    format: SortFormat,
    /// Also print the colouring trace (which rule fired, in which pass).
    #[arg(long)]
    trace: bool,
    /// Also print the sorted incidence matrix.
    #[arg(long)]
    incidence: bool,
    /// Report algebraic loops as errors instead of tearing them.
    #[arg(long)]
    no_tearing: bool,
    /// Keep this capacitor's or inductor's state when index reduction must
    /// remove one (repeatable).
    #[arg(long, value_name = "ELEMENT")]
    prefer_state: Vec<String>,
    /// Write to this file instead of standard output.
    #[arg(long, short)]
    out: Option<PathBuf>,
}

pub fn run(mut args: Args) -> Result<ExitCode, Error> {
    let opts = pipeline::SortOptions {
        build: args.build.options(),
        analysis: kausal::analysis::Options {
            tearing: !args.no_tearing,
        },
        prefer_state: std::mem::take(&mut args.prefer_state),
    };
    let sorted = pipeline::sort(&args.netlist, &FsLoader, &opts).map_err(Error::netlist)?;
    let el = &sorted.elaborated;
    print_diags(&el.sources, &el.warnings);
    let faults: Vec<Diagnostic> = sorted.faults.iter().map(|f| f.to_diagnostic()).collect();
    print_diags(&el.sources, &faults);
    match args.format {
        SortFormat::Text => emit_with(args.out.as_ref(), |w| text(&sorted, &args, w))?,
        SortFormat::Json => emit(args.out.as_ref(), &sorted_json(&sorted)?)?,
        SortFormat::Dot => emit(
            args.out.as_ref(),
            &listing::dot(sorted.system(), &sorted.causal),
        )?,
    }
    // The process ends here: freeing a 10^6-equation IR piece by piece
    // would cost a tenth of the run.
    std::mem::forget(sorted);
    Ok(ExitCode::SUCCESS)
}

/// The text listing: the index reduction (if any), the colouring trace and
/// the incidence matrix when asked, around the sorted assignments.
fn text(sorted: &Sorted, args: &Args, w: &mut dyn Write) -> std::io::Result<()> {
    let sys = sorted.system();
    if let Some(red) = &sorted.reduction {
        w.write_all(listing::index_reduction(&sorted.built.system, red).as_bytes())?;
    }
    if args.trace {
        w.write_all(listing::trace(sys, &sorted.causal).as_bytes())?;
    }
    listing::write_text(sys, &sorted.schedule, w)?;
    if args.incidence {
        w.write_all(listing::incidence(sys, &sorted.causal, &sorted.schedule).as_bytes())?;
    }
    Ok(())
}

/// The sorted listing as JSON, with the index reduction (if any).
fn sorted_json(sorted: &Sorted) -> Result<String, Error> {
    let mut v = listing::json(sorted.system(), &sorted.causal, &sorted.schedule);
    if let Some(red) = &sorted.reduction {
        v["index_reduction"] = listing::index_reduction_json(&sorted.built.system, red);
    }
    json(&v)
}
