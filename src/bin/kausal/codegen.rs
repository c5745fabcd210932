//! `kausal codegen`: standalone Rust or C source of f(t, y) and J·w from a
//! netlist's sorted equations.

use std::path::PathBuf;
use std::process::ExitCode;

use kausal::back::codegen;
use kausal::io::FsLoader;
use kausal::pipeline;

use crate::args::Lang;
use crate::error::Error;
use crate::output::{emit, print_diags};

#[derive(clap::Args)]
pub struct Args {
    /// The netlist file.
    netlist: PathBuf,
    /// Target language.
    #[arg(long, value_enum, default_value_t = Lang::Rust)]
    lang: Lang,
    /// Write to this file instead of standard output.
    #[arg(long, short)]
    out: Option<PathBuf>,
}

pub fn run(args: Args) -> Result<ExitCode, Error> {
    let sorted = pipeline::sort(&args.netlist, &FsLoader, &pipeline::SortOptions::default())
        .map_err(Error::netlist)?;
    print_diags(&sorted.elaborated.sources, &sorted.elaborated.warnings);
    let text = codegen::emit(sorted.system(), &sorted.schedule, args.lang.into());
    emit(args.out.as_ref(), &text)?;
    Ok(ExitCode::SUCCESS)
}
