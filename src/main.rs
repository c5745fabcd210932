//! The `kausal` command line: arguments, file IO, rendering, exit codes.
//! All the work is done by the library's stages.

use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand, ValueEnum};
use kausal::back::listing;
use kausal::build::{self, Kvl};
use kausal::diag::{self, Diagnostic, RenderOptions, SourceMap, ToDiagnostic};
use kausal::io::FsLoader;
use kausal::pipeline::{self, Failed};
use kausal::sim::{self, Method};
use kausal::validate;

/// mimalloc: building the IR of a big circuit is allocation-bound, and it
/// halves that time against the system allocator.
#[global_allocator]
static ALLOC: mimalloc::MiMalloc = mimalloc::MiMalloc;

#[derive(Parser)]
#[command(
    name = "kausal",
    version,
    about = "SPICE netlists to causal equations: sorted, simulated, checked against ngspice"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Clone, Copy, Debug, ValueEnum, PartialEq, Eq)]
enum Format {
    Text,
    Json,
}

#[derive(Clone, Copy, Debug, ValueEnum, PartialEq, Eq)]
enum SortFormat {
    Text,
    Json,
    /// Graphviz: the coloured bipartite graph.
    Dot,
}

#[derive(clap::Args)]
struct BuildArgs {
    /// How Kirchhoff's voltage law is written.
    #[arg(long, value_enum, default_value_t = Kvl::Nodes)]
    kvl: Kvl,
    /// Eliminate alias equations (`x = y`, `x = -y`, `x = known`).
    #[arg(long)]
    alias: bool,
}

impl BuildArgs {
    fn options(&self) -> build::Options {
        build::Options {
            kvl: self.kvl,
            alias: self.alias,
        }
    }
}

#[derive(Subcommand)]
enum Command {
    /// Parse and check a netlist, through the structural analysis (loops of
    /// sources, singular circuits); print problems only.
    Check {
        /// The netlist file.
        netlist: PathBuf,
    },
    /// Print the acausal equations, unknowns, states and incidence matrix.
    Equations {
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
    },
    /// Simulate with kausal and with ngspice, compare signal by signal.
    Validate {
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
    },
    /// Speed against error: kausal's solvers and ngspice's integrators at a
    /// range of tolerances, errors against a tight reference, in one run.
    Bench(BenchArgs),
    /// Generate standalone source of f(t, y) (and J·w) from the sorted equations.
    Codegen {
        /// The netlist file.
        netlist: PathBuf,
        /// Target language.
        #[arg(long, value_enum, default_value_t = kausal::back::codegen::Lang::Rust)]
        lang: kausal::back::codegen::Lang,
        /// Write to this file instead of standard output.
        #[arg(long, short)]
        out: Option<PathBuf>,
    },
    /// Sort the equations into causal assignments (colour-edge algorithm),
    /// tear algebraic loops, and print the sorted listing.
    Sort {
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
    },
    /// Simulate the netlist's `.tran` and write the waveforms (CSV).
    Sim {
        /// The netlist file.
        netlist: PathBuf,
        #[command(flatten)]
        build: BuildArgs,
        /// Write the CSV here instead of standard output.
        #[arg(long, short)]
        out: Option<PathBuf>,
        /// Also write an ngspice ASCII raw file.
        #[arg(long)]
        raw: Option<PathBuf>,
        /// An output vector, e.g. `v(out)`, `v(a,b)`, `i(v1)` (repeatable).
        #[arg(long = "probe", value_name = "VECTOR")]
        probes: Vec<String>,
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
        /// Keep this capacitor's or inductor's state under index reduction.
        #[arg(long, value_name = "ELEMENT")]
        prefer_state: Vec<String>,
    },
}

fn main() -> ExitCode {
    kausal::io::no_huge_pages();
    kausal::io::remove_pending_on_interrupt();
    let cli = Cli::parse();
    match run(cli) {
        Ok(code) => code,
        Err(msg) => {
            eprintln!("error: {msg}");
            ExitCode::FAILURE
        }
    }
}

static PROGRESS: std::sync::OnceLock<indicatif::ProgressBar> = std::sync::OnceLock::new();

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

fn render_opts() -> RenderOptions {
    RenderOptions {
        color: std::io::stderr().is_terminal(),
    }
}

/// Diagnostics of one code shown in full before the rest are counted (a
/// chain of 3000 inductors in a cutset gave 3000 K0310 warnings).
const SAME_CODE_SHOWN: usize = 10;

fn print_diags(sources: &SourceMap, diags: &[Diagnostic]) {
    let opts = render_opts();
    let mut err = std::io::stderr().lock();
    let mut seen: std::collections::HashMap<&str, usize> = std::collections::HashMap::new();
    for d in diags {
        let n = seen.entry(d.code).or_default();
        *n += 1;
        if *n <= SAME_CODE_SHOWN {
            let _ = writeln!(err, "{}", diag::render(sources, d, opts));
        }
    }
    let mut more: Vec<(&str, usize)> = seen
        .into_iter()
        .filter(|&(_, n)| n > SAME_CODE_SHOWN)
        .map(|(code, n)| (code, n - SAME_CODE_SHOWN))
        .collect();
    more.sort();
    for (code, n) in more {
        let _ = writeln!(
            err,
            "{code}: {n} more like the {SAME_CODE_SHOWN} above, not shown\n"
        );
    }
}

fn report_failure(f: &Failed) -> ExitCode {
    print_diags(&f.sources, &f.diagnostics);
    let n = f.errors().count();
    eprintln!("error: {n} error{} found", if n == 1 { "" } else { "s" });
    ExitCode::FAILURE
}

/// Where `kausal sim` put its CSV.
enum Csv {
    /// Streamed into a temporary file, renamed over `-o` by committing it.
    File(kausal::io::AtomicFile),
    /// Streamed to standard output.
    Stdout,
    /// Kept in memory (with `--raw`), written at the end.
    Kept,
}

/// Simulate, writing CSV rows as they come: into a file committed by the
/// caller (renamed over `out` only once the run succeeded) or to standard
/// output (a closed pipe, `| head`, ends the writing, not the run).
fn stream_csv(
    sorted: &kausal::pipeline::Sorted,
    opts: &sim::Options,
    out: Option<&PathBuf>,
) -> Result<(sim::Waveforms, Option<kausal::io::AtomicFile>), sim::SimError> {
    let names: Vec<String> = sim::outputs(sorted, &opts.probes)?
        .into_iter()
        .map(|o| o.0)
        .collect();
    let shown = out.map_or(std::path::Path::new("-"), |p| p.as_path());
    let write_err = |e: std::io::Error| sim::SimError::Write {
        message: format!("`{}`: {e}", shown.display()),
    };
    // One row writer for both destinations.
    let run = |w: &mut dyn Write| -> Result<sim::Waveforms, sim::SimError> {
        let mut line = String::new();
        sim::output::csv_header(&mut line, &names);
        w.write_all(line.as_bytes()).map_err(write_err)?;
        let mut sink = |t: f64, v: &[f64]| {
            line.clear();
            sim::output::csv_row(&mut line, t, v);
            w.write_all(line.as_bytes())
        };
        let mut wf = sim::simulate_to(sorted, opts, &mut sink)?;
        w.flush().map_err(write_err)?;
        wf.names = names.clone();
        Ok(wf)
    };
    match out {
        Some(path) => {
            let mut file = kausal::io::AtomicFile::create(path).map_err(write_err)?;
            let w = run(&mut file)?;
            Ok((w, Some(file)))
        }
        None => {
            let stdout = std::io::BufWriter::with_capacity(1 << 16, std::io::stdout().lock());
            Ok((
                run(&mut PipeOk {
                    inner: stdout,
                    open: true,
                })?,
                None,
            ))
        }
    }
}

/// Standard output for streamed rows: once the reader has gone (`| head`),
/// further writes are dropped, not errors; the run finishes.
struct PipeOk<W: Write> {
    inner: W,
    open: bool,
}

impl<W: Write> PipeOk<W> {
    fn guard(&mut self, r: std::io::Result<()>) -> std::io::Result<()> {
        match r {
            Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => {
                self.open = false;
                Ok(())
            }
            r => r,
        }
    }
}

impl<W: Write> Write for PipeOk<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.write_all(buf).map(|_| buf.len())
    }
    fn write_all(&mut self, buf: &[u8]) -> std::io::Result<()> {
        if !self.open {
            return Ok(());
        }
        let r = self.inner.write_all(buf);
        self.guard(r)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        if !self.open {
            return Ok(());
        }
        let r = self.inner.flush();
        self.guard(r)
    }
}

/// Write command output to a file (atomically) or standard output.
fn emit(out: Option<&PathBuf>, text: &str) -> Result<(), String> {
    match out {
        Some(path) => kausal::io::write_atomic(path, text.as_bytes())
            .map_err(|e| format!("cannot write `{}`: {e}", path.display())),
        None => {
            let mut stdout = std::io::stdout().lock();
            stdout
                .write_all(text.as_bytes())
                .and_then(|_| stdout.flush())
                .or_else(|e| {
                    // A closed pipe (`| head`) is not an error.
                    if e.kind() == std::io::ErrorKind::BrokenPipe {
                        Ok(())
                    } else {
                        Err(e.to_string())
                    }
                })
        }
    }
}

fn run(cli: Cli) -> Result<ExitCode, String> {
    match cli.command {
        // Through the structural analysis too: a loop of voltage sources or
        // a singular circuit is a problem `sim` would stop on.
        Command::Check { netlist } => {
            match pipeline::sort(&netlist, &FsLoader, &pipeline::SortOptions::default()) {
                Ok(sorted) => {
                    let el = &sorted.elaborated;
                    print_diags(&el.sources, &el.warnings);
                    let faults: Vec<Diagnostic> =
                        sorted.faults.iter().map(|f| f.to_diagnostic()).collect();
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
                Err(f) => Ok(report_failure(&f)),
            }
        }
        Command::Equations {
            netlist,
            build,
            format,
            out,
        } => {
            let (el, built) = match pipeline::equations(&netlist, &FsLoader, build.options()) {
                Ok(x) => x,
                Err(f) => return Ok(report_failure(&f)),
            };
            print_diags(&el.sources, &el.warnings);
            let text = match format {
                Format::Text => kausal::ir::print::system(&built.system, 60),
                Format::Json => {
                    let mut s = serde_json::to_string_pretty(&kausal::ir::print::system_json(
                        &built.system,
                    ))
                    .map_err(|e| e.to_string())?;
                    s.push('\n');
                    s
                }
            };
            emit(out.as_ref(), &text)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Codegen { netlist, lang, out } => {
            let sorted =
                match pipeline::sort(&netlist, &FsLoader, &pipeline::SortOptions::default()) {
                    Ok(x) => x,
                    Err(f) => return Ok(report_failure(&f)),
                };
            print_diags(&sorted.elaborated.sources, &sorted.elaborated.warnings);
            let text = kausal::back::codegen::emit(sorted.system(), &sorted.schedule, lang);
            emit(out.as_ref(), &text)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Bench(args) => cmd_bench(args),
        Command::Validate {
            netlist,
            tol,
            ref_tol,
            plot,
            format,
            probes,
            method,
            rtol,
        } => {
            let sorted =
                match pipeline::sort(&netlist, &FsLoader, &pipeline::SortOptions::default()) {
                    Ok(x) => x,
                    Err(f) => return Ok(report_failure(&f)),
                };
            print_diags(&sorted.elaborated.sources, &sorted.elaborated.warnings);
            let opts = validate::Options {
                tol,
                ref_reltol: ref_tol,
                sim: sim::Options {
                    method,
                    rtol,
                    probes,
                    ..Default::default()
                },
                ngspice_default: true,
            };
            let report = match validate::validate(&netlist, &sorted, &opts) {
                Ok(r) => r,
                Err(e) => {
                    print_diags(&sorted.elaborated.sources, &[e.to_diagnostic()]);
                    return Ok(ExitCode::FAILURE);
                }
            };
            if let Some(dir) = &plot {
                std::fs::create_dir_all(dir)
                    .map_err(|e| format!("cannot create `{}`: {e}", dir.display()))?;
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
                    )?;
                    let path = validate::plot_path(dir, &netlist, &s.name);
                    kausal::io::write_atomic(&path, svg.as_bytes())
                        .map_err(|e| format!("cannot write `{}`: {e}", path.display()))?;
                }
            }
            let text = match format {
                Format::Text => validate::table(&report),
                Format::Json => {
                    let mut s = serde_json::to_string_pretty(&report).map_err(|e| e.to_string())?;
                    s.push('\n');
                    s
                }
            };
            emit(None, &text)?;
            Ok(if report.pass {
                ExitCode::SUCCESS
            } else {
                ExitCode::FAILURE
            })
        }
        Command::Sim {
            netlist,
            build,
            out,
            raw,
            probes,
            method,
            rtol,
            atol,
            all_steps,
            prefer_state,
        } => {
            let opts = pipeline::SortOptions {
                build: build.options(),
                prefer_state,
                ..Default::default()
            };
            let sorted = match pipeline::sort(&netlist, &FsLoader, &opts) {
                Ok(x) => x,
                Err(f) => return Ok(report_failure(&f)),
            };
            print_diags(&sorted.elaborated.sources, &sorted.elaborated.warnings);
            let sim_opts = sim::Options {
                method,
                rtol,
                atol,
                all_steps,
                probes,
                progress: std::io::stderr()
                    .is_terminal()
                    .then_some(progress as fn(f64)),
                times: None,
            };
            // Without a raw file (whose header counts the points), the CSV
            // is streamed as it is computed: memory stays bounded by the
            // circuit, however long the run or many the saved vectors.
            let result = match &raw {
                Some(_) => sim::simulate(&sorted, &sim_opts).map(|w| (w, Csv::Kept)),
                None => stream_csv(&sorted, &sim_opts, out.as_ref())
                    .map(|(w, f)| (w, f.map_or(Csv::Stdout, Csv::File))),
            };
            if let Some(bar) = PROGRESS.get() {
                bar.finish_and_clear();
            }
            let (w, csv) = match result {
                Ok(w) => w,
                Err(e) => {
                    print_diags(&sorted.elaborated.sources, &[e.to_diagnostic()]);
                    return Ok(ExitCode::FAILURE);
                }
            };
            // The files first: a closed stderr cannot lose them.
            match csv {
                Csv::File(file) => {
                    let path = file.path().to_path_buf();
                    file.commit()
                        .map_err(|e| format!("cannot write `{}`: {e}", path.display()))?;
                }
                Csv::Stdout => {}
                Csv::Kept => {
                    if let Some(path) = &raw {
                        let text = sim::output::raw_ascii(&w, &sorted.elaborated.circuit.title);
                        kausal::io::write_atomic(path, text.as_bytes())
                            .map_err(|e| format!("cannot write `{}`: {e}", path.display()))?;
                    }
                    emit(out.as_ref(), &sim::output::csv(&w))?;
                }
            }
            print_diags(&sorted.elaborated.sources, &w.warnings);
            let s = &w.stats;
            eprintln!(
                "{} states, {:?}: {} steps ({} rejected), {} f-evaluations, {} J·v, {} Jacobians, {} LU factorizations, {} restarts{}; {:.3} s",
                s.states,
                s.method.unwrap_or(Method::Bdf),
                s.steps,
                s.rejected,
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
            eprintln!(
                "assignments: {} in f, {} at output points only, {} pruned",
                s.in_f, s.at_outputs, s.unused
            );
            Ok(ExitCode::SUCCESS)
        }
        Command::Sort {
            netlist,
            build,
            format,
            trace,
            incidence,
            no_tearing,
            prefer_state,
            out,
        } => {
            let opts = pipeline::SortOptions {
                build: build.options(),
                analysis: kausal::analysis::Options {
                    tearing: !no_tearing,
                },
                prefer_state,
            };
            let sorted = match pipeline::sort(&netlist, &FsLoader, &opts) {
                Ok(x) => x,
                Err(f) => return Ok(report_failure(&f)),
            };
            print_diags(&sorted.elaborated.sources, &sorted.elaborated.warnings);
            let faults: Vec<Diagnostic> = sorted.faults.iter().map(|f| f.to_diagnostic()).collect();
            print_diags(&sorted.elaborated.sources, &faults);
            let sys = sorted.system();
            let text = match format {
                SortFormat::Text => {
                    let mut t = String::new();
                    if let Some(red) = &sorted.reduction {
                        t.push_str(&listing::index_reduction(&sorted.built.system, red));
                    }
                    if trace {
                        t.push_str(&listing::trace(sys, &sorted.causal));
                    }
                    t.push_str(&listing::text(sys, &sorted.schedule));
                    if incidence {
                        t.push_str(&listing::incidence(sys, &sorted.causal, &sorted.schedule));
                    }
                    t
                }
                SortFormat::Json => {
                    let mut v = listing::json(sys, &sorted.causal, &sorted.schedule);
                    if let Some(red) = &sorted.reduction {
                        v["index_reduction"] =
                            listing::index_reduction_json(&sorted.built.system, red);
                    }
                    let mut s = serde_json::to_string_pretty(&v).map_err(|e| e.to_string())?;
                    s.push('\n');
                    s
                }
                SortFormat::Dot => listing::dot(sys, &sorted.causal),
            };
            emit(out.as_ref(), &text)?;
            Ok(ExitCode::SUCCESS)
        }
    }
}

#[derive(clap::Args)]
struct BenchArgs {
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
    /// Write bench.json and a work-precision SVG per circuit here.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Write the markdown report to this file (else standard output).
    #[arg(long)]
    report: Option<PathBuf>,
}

fn cmd_bench(a: BenchArgs) -> Result<ExitCode, String> {
    use kausal::bench;
    let opts = bench::Options {
        tolerances: a.tolerances,
        methods: a.solvers,
        repeats: a.repeats,
        ngspice: !a.no_ngspice,
        exe: std::env::current_exe().ok(),
        ..Default::default()
    };
    let sizes: Vec<usize> = if a.scaling {
        (2..=9)
            .map(|k| 10usize.pow(k))
            .take_while(|&n| n <= a.max_sections.max(100))
            .collect()
    } else {
        Vec::new()
    };
    let total = a
        .netlists
        .iter()
        .map(|n| bench::measurements(&opts, n))
        .sum::<usize>()
        + sizes.len();
    let bar = if std::io::stderr().is_terminal() {
        indicatif::ProgressBar::new(total as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} {elapsed} {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let tick = |msg: &str| {
        bar.set_message(msg.to_string());
        bar.inc(1);
    };
    let mut benches = Vec::new();
    let mut failures = Vec::new();
    for path in &a.netlists {
        bar.set_message(path.display().to_string());
        match bench::bench_circuit(path, &opts, &tick) {
            Ok(b) => benches.push(b),
            // ngspice missing fails the run; a circuit that fails is reported
            // and the others go on.
            Err(e @ bench::BenchError::Ngspice(validate::ValidateError::Missing { .. })) => {
                bar.finish_and_clear();
                return Err(e.to_string());
            }
            Err(e) => {
                bar.suspend(|| eprintln!("{}: {e}", path.display()));
                failures.push(format!("{}: {e}", path.display()));
            }
        }
    }
    let scaled = if sizes.is_empty() {
        None
    } else {
        let dir = kausal::io::ScratchDir::new().map_err(|e| e.to_string())?;
        Some(
            bench::scaling(&sizes, dir.path(), !a.no_ngspice, &tick)
                .map_err(|e| format!("scaling: {e}"))?,
        )
    };
    bar.finish_and_clear();
    let plots = match &a.out {
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
    md.push_str(&bench::markdown(&benches, scaled.as_ref(), &plots));
    if !failures.is_empty() {
        md.push_str("## Circuits that failed\n\n");
        for f in &failures {
            md.push_str(&format!("- {f}\n"));
        }
    }
    if let Some(dir) = &a.out {
        std::fs::create_dir_all(dir)
            .map_err(|e| format!("cannot create `{}`: {e}", dir.display()))?;
        for b in &benches {
            let svg = bench::work_precision_svg(b)?;
            let p = dir.join(format!("{}.svg", bench::stem(&b.netlist)));
            kausal::io::write_atomic(&p, svg.as_bytes())
                .map_err(|e| format!("cannot write `{}`: {e}", p.display()))?;
        }
        let json = serde_json::to_string_pretty(&serde_json::json!({
            "circuits": benches,
            "scaling": scaled,
        }))
        .map_err(|e| e.to_string())?;
        let p = dir.join("bench.json");
        kausal::io::write_atomic(&p, json.as_bytes())
            .map_err(|e| format!("cannot write `{}`: {e}", p.display()))?;
    }
    emit(a.report.as_ref(), &md)?;
    Ok(if failures.is_empty() {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}

/// A relative tolerance: a number in (0, 1).
fn relative_tolerance(s: &str) -> Result<f64, String> {
    let x: f64 = s.trim().parse().map_err(|e| format!("`{s}`: {e}"))?;
    if x > 0.0 && x < 1.0 {
        Ok(x)
    } else {
        Err(format!("{s} is not in (0, 1): e.g. 1e-6"))
    }
}

/// An absolute tolerance or bound: a finite number above 0.
fn positive(s: &str) -> Result<f64, String> {
    let x: f64 = s.trim().parse().map_err(|e| format!("`{s}`: {e}"))?;
    if x > 0.0 && x.is_finite() {
        Ok(x)
    } else {
        Err(format!("{s} is not a finite number above 0"))
    }
}
