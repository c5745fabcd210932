//! `kausal validate`: simulate with kausal and with ngspice and compare the
//! waveforms signal by signal; a table or JSON, and optionally a plot per
//! signal.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use kausal::io::FsLoader;
use kausal::pipeline;
use kausal::validate::{self, Report};

use crate::args::{Format, Method, positive, relative_tolerance};
use crate::error::Error;
use crate::output::{emit, json, print_diags};

#[derive(clap::Args)]
pub struct Args {
    /// The netlist file.
    netlist: PathBuf,
    /// Largest normalized error (over the reference's range) that passes.
    #[arg(long, default_value_t = 1e-3, value_parser = positive)]
    tol: f64,
    /// ngspice's reltol for the reference run (a netlist may ask for a
    /// tighter one: `* kausal-validate: ref-tol=3e-9`).
    #[arg(long, default_value_t = 1e-8, value_parser = relative_tolerance)]
    ref_tol: f64,
    /// Write an SVG per signal (both waveforms and the error) here.
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Text)]
    format: Format,
    /// Compare only these vectors (default: as `kausal sim`).
    #[arg(long = "probe", value_name = "VECTOR")]
    probes: Vec<String>,
    /// kausal's integration method.
    #[arg(long, visible_alias = "solver", value_enum)]
    method: Option<Method>,
    /// kausal's relative tolerance.
    #[arg(long, value_parser = relative_tolerance)]
    rtol: Option<f64>,
}

/// Exit code 1 when a signal's error is above `--tol`.
pub fn run(args: Args) -> Result<ExitCode, Error> {
    let sorted = pipeline::sort(&args.netlist, &FsLoader, &pipeline::SortOptions::default())
        .map_err(Error::netlist)?;
    print_diags(&sorted.elaborated.sources, &sorted.elaborated.warnings);
    let opts = validate::Options {
        tol: args.tol,
        ref_reltol: args.ref_tol,
        sim: kausal::sim::Options {
            method: args.method.map(Into::into),
            rtol: args.rtol,
            probes: args.probes,
            ..Default::default()
        },
        ngspice_default: true,
    };
    let report = match validate::validate(&args.netlist, &sorted, &opts) {
        Ok(r) => r,
        Err(e) => return Err(Error::stage(sorted.elaborated.sources, e)),
    };
    if let Some(dir) = &args.plot {
        plot(dir, &args.netlist, &report)?;
    }
    let text = match args.format {
        Format::Text => validate::table(&report),
        Format::Json => json(&report)?,
    };
    emit(None, &text)?;
    Ok(if report.pass {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}

/// An SVG per compared signal in `dir`: both waveforms and the error.
fn plot(dir: &Path, netlist: &Path, report: &Report) -> Result<(), Error> {
    std::fs::create_dir_all(dir).map_err(Error::create_dir(dir))?;
    for (k, s) in report.signals.iter().enumerate() {
        let col = report
            .reference
            .names
            .iter()
            .position(|n| *n == s.name)
            .unwrap_or(0);
        let svg = validate::plot::svg(
            &s.name,
            &report.reference.time,
            &report.reference.data[col],
            &report.kausal.data[k],
        )
        .map_err(Error::Plot)?;
        let path = validate::plot_path(dir, netlist, &s.name);
        kausal::io::write_atomic(&path, svg.as_bytes()).map_err(Error::write(&path))?;
    }
    Ok(())
}
