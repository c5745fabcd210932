//! `kausal check`: parse a netlist and run it through the structural
//! analysis, printing problems only.

use std::path::PathBuf;
use std::process::ExitCode;

use kausal::diag::{Diagnostic, ToDiagnostic};
use kausal::io::FsLoader;
use kausal::pipeline;

use crate::error::Error;
use crate::output::print_diags;

#[derive(clap::Args)]
pub struct Args {
    /// The netlist file.
    netlist: PathBuf,
}

/// Through the structural analysis too: a loop of voltage sources or a
/// singular circuit is a problem `sim` would stop on.
pub fn run(args: Args) -> Result<ExitCode, Error> {
    let netlist = args.netlist;
    let sorted = pipeline::sort(&netlist, &FsLoader, &pipeline::SortOptions::default())
        .map_err(Error::netlist)?;
    let el = &sorted.elaborated;
    print_diags(&el.sources, &el.warnings);
    let faults: Vec<Diagnostic> = sorted.faults.iter().map(|f| f.to_diagnostic()).collect();
    print_diags(&el.sources, &faults);
    eprintln!(
        "{}: ok ({} elements, {} nodes, {} equations, {} states)",
        netlist.display(),
        el.circuit.elements.len(),
        el.circuit.nodes.len() - 1,
        sorted.system().eqs.len(),
        sorted.system().states().count()
    );
    Ok(ExitCode::SUCCESS)
}
