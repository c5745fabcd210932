//! `kausal sim`: simulate a netlist's `.tran` and write the waveforms as CSV
//! or ngspice's binary raw file (streamed while they are computed), and
//! optionally as an ngspice ASCII raw file;
//! the solver's statistics on standard error.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::OnceLock;

use kausal::io::{AtomicFile, FsLoader};
use kausal::pipeline::{self, Sorted};
use kausal::sim::{self, Waveforms};

use crate::args::{BuildArgs, Method, positive, relative_tolerance};
use crate::error::Error;
use crate::output::{WaveFormat, emit, print_diags, stream_waves};

#[derive(clap::Args)]
pub struct Args {
    /// The netlist file.
    netlist: PathBuf,
    #[command(flatten)]
    build: BuildArgs,
    /// Write the waveforms here instead of standard output: CSV, or
    /// ngspice's binary raw file if the name ends in `.raw`.
    #[arg(long, short)]
    out: Option<PathBuf>,
    /// Also write an ngspice ASCII raw file.
    #[arg(long)]
    raw: Option<PathBuf>,
    /// An output vector, e.g. `v(out)`, `v(a,b)`, `i(v1)` (repeatable);
    /// `all` is every node voltage and voltage source current. Without
    /// it, the netlist's `.save` vectors, else all of those and the
    /// `.print` vectors (as ngspice stores them).
    #[arg(long = "probe", value_name = "VECTOR")]
    probes: Vec<String>,
    /// `--save all`: store every node voltage and voltage source current,
    /// whatever the netlist's `.save` says (as well as any `--probe`).
    #[arg(long, value_enum, value_name = "all")]
    save: Option<Save>,
    /// Integration method (default: bdf).
    #[arg(long, visible_alias = "solver", value_enum)]
    method: Option<Method>,
    /// Relative tolerance (default 1e-7: within 1e-3 of a tight
    /// reference on every circuit of the benchmark set). At 1e-2 the
    /// local error allowed is 1 % a step: expect visible error.
    #[arg(long, value_parser = relative_tolerance)]
    rtol: Option<f64>,
    /// Absolute tolerance for voltages (currents: 1e-3 of it).
    #[arg(long, value_parser = positive)]
    atol: Option<f64>,
    /// Also output every accepted step.
    #[arg(long)]
    all_steps: bool,
    /// List the state events (time, switch or B source, control, new state)
    /// on standard error.
    #[arg(long)]
    events: bool,
    /// The most steps the run may take; a run whose pace would need more
    /// stops early with a diagnostic (default 5e7).
    #[arg(long, value_name = "N")]
    max_steps: Option<usize>,
    /// The longest step, in seconds (in place of `.tran`'s fourth argument,
    /// TMAX, which ngspice reads the same way).
    #[arg(long, value_parser = positive, value_name = "SECONDS")]
    tmax: Option<f64>,
    /// The step of `--method euler`, `rk2` or `rk4`, in seconds (they have
    /// no error control: before the run, kausal states the longest step
    /// that keeps them stable on the circuit).
    #[arg(long, value_parser = positive, value_name = "SECONDS")]
    step: Option<f64>,
    /// Keep this capacitor's or inductor's state under index reduction.
    #[arg(long, value_name = "ELEMENT")]
    prefer_state: Vec<String>,
}

/// What `--save` stores.
#[derive(Clone, Copy, clap::ValueEnum)]
enum Save {
    All,
}

/// Where the waveforms went.
enum WaveFile {
    /// Streamed into a temporary file, renamed over `-o` by committing it.
    File(AtomicFile),
    /// Streamed to standard output.
    Stdout,
    /// Kept in memory (with `--raw`), written at the end.
    Kept,
}

pub fn run(mut args: Args) -> Result<ExitCode, Error> {
    crate::purge_freed_memory_at_once();
    if let Some(Save::All) = args.save {
        args.probes.push("all".into());
    }
    let opts = pipeline::SortOptions {
        build: args.build.options(),
        prefer_state: std::mem::take(&mut args.prefer_state),
        ..Default::default()
    };
    let mut sorted = pipeline::sort(&args.netlist, &FsLoader, &opts).map_err(Error::netlist)?;
    print_diags(&sorted.elaborated.sources, &sorted.elaborated.warnings);
    let sim_opts = sim::Options {
        method: args.method.map(Into::into),
        rtol: args.rtol,
        atol: args.atol,
        all_steps: args.all_steps,
        probes: std::mem::take(&mut args.probes),
        progress: std::io::stderr()
            .is_terminal()
            .then_some(progress as fn(f64)),
        times: None,
        max_steps: args.max_steps,
        tmax: args.tmax,
        step: args.step,
        dc_work: None,
        dc_deadline: None,
    };
    // The tape compiler reads the schedule, not the causalization: drop it
    // first (the schedule goes once the tape exists).
    sorted.causal = Default::default();
    let prepared = match sim::prepare(&sorted, &sim_opts) {
        Ok(p) => p,
        Err(e) => return Err(Error::stage(sorted.elaborated.sources, e)),
    };
    // The integrator's memory takes the place of the schedule's.
    sorted.schedule = Default::default();
    let (waves, file) = match simulate(&mut sorted, prepared, &sim_opts, &args) {
        Ok(x) => x,
        Err(e) => return Err(Error::stage(sorted.elaborated.sources, e)),
    };
    // The files first: a closed stderr cannot lose them.
    write_files(&sorted, &waves, file, &args)?;
    print_diags(&sorted.elaborated.sources, &waves.warnings);
    print_stats(&waves.stats);
    print_events(&waves.events, args.events);
    Ok(ExitCode::SUCCESS)
}

/// Run the simulation. Without `--raw` (an ASCII raw file's header counts
/// the points) the waveforms are streamed as they are computed: memory stays bounded by the
/// circuit, however long the run or many the saved vectors.
fn simulate(
    sorted: &mut Sorted,
    prepared: sim::Prepared,
    opts: &sim::Options,
    args: &Args,
) -> Result<(Waveforms, WaveFile), sim::SimError> {
    let result = match &args.raw {
        Some(_) => {
            sim::run_prepared_releasing(sorted, prepared, opts, None, crate::return_freed_memory)
                .map(|w| (w, WaveFile::Kept))
        }
        None => stream_waves(
            sorted,
            prepared,
            opts,
            args.out.as_ref(),
            WaveFormat::of(args.out.as_ref()),
        )
        .map(|(w, f)| (w, f.map_or(WaveFile::Stdout, WaveFile::File))),
    };
    if let Some(bar) = PROGRESS.get() {
        bar.finish_and_clear();
    }
    result
}

/// Commit the streamed file, or write the kept waveforms (CSV or binary
/// raw, and the ASCII raw file).
fn write_files(
    sorted: &Sorted,
    waves: &Waveforms,
    file: WaveFile,
    args: &Args,
) -> Result<(), Error> {
    match file {
        WaveFile::File(file) => {
            let path = file.path().to_path_buf();
            file.commit().map_err(Error::write(path))
        }
        WaveFile::Stdout => Ok(()),
        WaveFile::Kept => {
            if let Some(path) = &args.raw {
                let text = sim::output::raw_ascii(waves, &sorted.elaborated.circuit.title);
                kausal::io::write_atomic(path, text.as_bytes()).map_err(Error::write(path))?;
            }
            match WaveFormat::of(args.out.as_ref()) {
                WaveFormat::Csv => emit(args.out.as_ref(), &sim::output::csv(waves)),
                WaveFormat::RawBinary => {
                    let path = args.out.as_ref().expect("a raw format has a path");
                    let bytes = sim::output::raw_binary(waves, &sorted.elaborated.circuit.title);
                    kausal::io::write_atomic(path, &bytes).map_err(Error::write(path))
                }
            }
        }
    }
}

/// The solver's work and the assignments' placement, on standard error.
fn print_stats(s: &sim::Stats) {
    if s.states == 0 {
        // Nothing integrated: the outputs are functions of time (and of
        // the switches' states), evaluated at each output point.
        eprintln!(
            "0 states: no integration, {} output points evaluated; {:.3} s",
            s.rhs_evals,
            s.wall.as_secs_f64()
        );
    } else {
        print_solver(s);
    }
    if let Some(found) = s.dc_found {
        match s.dc_stages.len() {
            0 | 1 => eprintln!("operating point: {}", found.describe()),
            _ => {
                let tried: Vec<&str> = s.dc_stages.iter().map(|d| d.describe()).collect();
                eprintln!(
                    "operating point: {} (tried: {})",
                    found.describe(),
                    tried.join(", ")
                );
            }
        }
    }
    eprintln!(
        "assignments: {} in f, {} at output points only, {} pruned",
        s.in_f, s.at_outputs, s.unused
    );
}

/// The integrator's work.
fn print_solver(s: &sim::Stats) {
    eprintln!(
        "{} states, {:?}{}: {} steps ({} rejected, {} Newton failures), {} f-evaluations, {} J·v, {} Jacobians, {} LU factorizations, {} restarts{}; {:.3} s",
        s.states,
        s.method.unwrap_or(sim::Method::Bdf),
        s.switched_at
            .map_or_else(String::new, |t| format!(" then Esdirk34 from t = {t:.4e}")),
        s.steps,
        s.rejected,
        s.newton_fails,
        s.rhs_evals,
        s.jac_mul_evals,
        s.jacobians,
        s.lu_factorizations,
        s.restarts,
        if s.rescues > 0 {
            format!(" (+{} after repeated error-test failures)", s.rescues)
        } else {
            String::new()
        },
        s.wall.as_secs_f64()
    );
}

/// The state events (switches, B sources' comparisons): a count, and with
/// `--events` each of them.
fn print_events(events: &[sim::StateEvent], list: bool) {
    if events.is_empty() {
        return;
    }
    eprintln!(
        "state events: {}{}",
        events.len(),
        if list { "" } else { " (--events lists them)" }
    );
    if list {
        for e in events {
            let now = match (&e.condition, e.on) {
                (None, true) => "on".to_string(),
                (None, false) => "off".to_string(),
                (Some(c), holds) => format!("`{c}` {holds}"),
            };
            eprintln!(
                "  t = {:.9e}  {}  {now}  (control {:.6e})",
                e.t, e.element, e.control
            );
        }
    }
}

/// The progress bar of a long simulation, created on its first report.
static PROGRESS: OnceLock<indicatif::ProgressBar> = OnceLock::new();

/// Progress of a long simulation, on standard error (terminals only).
fn progress(fraction: f64) {
    let bar = PROGRESS.get_or_init(|| {
        let b = indicatif::ProgressBar::new(1000);
        b.set_style(
            indicatif::ProgressStyle::with_template("{bar:40} {percent}% {elapsed} (eta {eta})")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        b
    });
    bar.set_position((fraction.clamp(0.0, 1.0) * 1000.0) as u64);
}
