//! `kausal equations`: print the acausal equations, unknowns, states and
//! incidence matrix of a netlist.

use std::path::PathBuf;
use std::process::ExitCode;

use kausal::io::FsLoader;
use kausal::ir::print;
use kausal::pipeline;

use crate::args::{BuildArgs, Format};
use crate::error::Error;
use crate::output::{emit, json, print_diags};

#[derive(clap::Args)]
pub struct Args {
    /// The netlist file.
    netlist: PathBuf,
    #[command(flatten)]
    build: BuildArgs,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Text)]
    format: Format,
    /// Write to this file instead of standard output.
    #[arg(long, short)]
    out: Option<PathBuf>,
}

/// The text listing omits the incidence matrix above this many unknowns.
const MAX_INCIDENCE: usize = 60;

pub fn run(args: Args) -> Result<ExitCode, Error> {
    let (el, built) = pipeline::equations(&args.netlist, &FsLoader, args.build.options())
        .map_err(Error::netlist)?;
    print_diags(&el.sources, &el.warnings);
    let text = match args.format {
        Format::Text => print::system(&built.system, MAX_INCIDENCE),
        Format::Json => json(&print::system_json(&built.system))?,
    };
    emit(args.out.as_ref(), &text)?;
    Ok(ExitCode::SUCCESS)
}
