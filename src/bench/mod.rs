//! Speed against error (`kausal bench`): work-precision of kausal's solvers
//! and of ngspice's integrators on a set of circuits, measured in one run,
//! and scaling of both with circuit size.
//!
//! The reference of a circuit is kausal at a very tight tolerance
//! ([`Options::ref_rtol`]), cross-checked against ngspice at a tight reltol;
//! their disagreement is reported next to every table, so a reader can see
//! how far the errors below it can be trusted.

mod plot;

pub use plot::work_precision_svg;

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::io::FsLoader;
use crate::pipeline::{self, SortOptions, Sorted};
use crate::sim::{self, Method, Waveforms};
use crate::validate::{self, RawData, ValidateError, interp};

/// Options of [`bench`].
#[derive(Clone, Debug)]
pub struct Options {
    /// Relative tolerances (kausal's rtol, ngspice's reltol).
    pub tolerances: Vec<f64>,
    /// kausal's solvers.
    pub methods: Vec<Method>,
    /// Runs per measurement; the median time is reported.
    pub repeats: usize,
    /// Run ngspice too (else kausal only).
    pub ngspice: bool,
    /// kausal's rtol for the reference solution.
    pub ref_rtol: f64,
    /// ngspice's reltol for the cross-check of the reference.
    pub ngspice_ref_reltol: f64,
    /// The `kausal` executable: its whole-job time is that of a `kausal sim`
    /// process, as ngspice's is that of an `ngspice -b` process. Without it
    /// (a library caller), parse + sort + solve in process.
    pub exe: Option<std::path::PathBuf>,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            tolerances: vec![1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7],
            methods: vec![
                Method::Bdf,
                Method::TrBdf2,
                Method::Esdirk34,
                Method::Circuit,
            ],
            repeats: 3,
            ngspice: true,
            ref_rtol: 1e-11,
            ngspice_ref_reltol: 1e-8,
            exe: None,
        }
    }
}

/// One measurement: a solver at a tolerance.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Point {
    /// `kausal bdf`, `ngspice gear`, `ngspice default`.
    pub solver: String,
    /// The relative tolerance; `None` for ngspice's defaults.
    pub tol: Option<f64>,
    /// Median solve time (kausal: `simulate`, in process; ngspice: its
    /// "Transient analysis time").
    pub solve_seconds: f64,
    /// Median whole-job wall time: a `kausal sim -o FILE.raw` process
    /// (start-up, parse, sort, solve, binary raw file written) against an
    /// `ngspice -b -r FILE.raw` process.
    pub total_seconds: f64,
    /// Largest absolute error over the compared signals (their units).
    pub error: f64,
    pub worst_signal: String,
    /// Accepted steps.
    pub steps: usize,
    /// Largest relative change of the circuit's stored energy
    /// (`* kausal-bench: energy=...`), when the netlist gives one.
    pub energy_drift: Option<f64>,
    /// Why the run failed, if it did.
    pub failed: Option<String>,
    /// Peak resident memory of the whole-job process, in bytes.
    pub peak_bytes: Option<u64>,
}

/// Where kausal beats ngspice's default run.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Verdict {
    pub ngspice_default_error: f64,
    /// The fastest kausal point with an error at most ngspice's default one.
    pub kausal: Option<Point>,
    /// ngspice default solve time / kausal solve time.
    pub solve_speedup: Option<f64>,
    /// ngspice default process time / kausal whole job.
    pub total_speedup: Option<f64>,
}

/// The benchmark of one circuit.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CircuitBench {
    pub netlist: String,
    pub states: usize,
    pub equations: usize,
    /// Parse, elaborate and build the equations.
    pub front_seconds: f64,
    /// Index reduction, causalization, tearing and scheduling.
    pub sort_seconds: f64,
    pub reference: String,
    /// Largest difference between the reference and ngspice's tight run.
    pub reference_check: Option<f64>,
    /// With an exact reference: largest difference between it and kausal's
    /// tight run (a wrong formula shows here).
    pub exact_check: Option<f64>,
    /// The step cap both simulators ran with (see [`StepCap`]).
    pub cap: StepCap,
    pub points: Vec<Point>,
    pub verdict: Option<Verdict>,
    /// Solvers whose error did not decrease as the tolerance tightened
    /// (beyond a factor 3 of noise, above the reference's own accuracy).
    pub non_monotone: Vec<String>,
}

/// The longest step of a benchmark's runs, the same on both sides: a
/// comparison where only ngspice's step is capped measures the cap.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub enum StepCap {
    /// The netlist's TMAX, which both honour.
    Tmax(f64),
    /// TSTEP below span/50, where ngspice caps its step at TSTEP (its
    /// default TMAX is min(TSTEP, span/50)): kausal is given TMAX = TSTEP.
    Tstep(f64),
    /// TSTEP at least span/50: ngspice at its defaults (its own cap,
    /// span/50, allows 50 steps), kausal without a cap.
    Free,
}

impl StepCap {
    pub fn of(tran: &crate::elab::Tran) -> StepCap {
        match tran.tmax {
            Some(m) => StepCap::Tmax(m),
            // TSTEP = span/50 (to rounding) caps both ways alike.
            None if tran.tstep < (tran.tstop - tran.tstart) / 50.0 * (1.0 - 1e-9) => {
                StepCap::Tstep(tran.tstep)
            }
            None => StepCap::Free,
        }
    }

    /// The TMAX kausal runs with.
    pub fn tmax(self) -> Option<f64> {
        match self {
            StepCap::Tmax(m) | StepCap::Tstep(m) => Some(m),
            StepCap::Free => None,
        }
    }

    fn describe(self) -> String {
        match self {
            StepCap::Tmax(m) => format!("TMAX {} from the netlist, on both sides", sci(m)),
            StepCap::Tstep(m) => format!(
                "TSTEP {} caps ngspice's step (below span/50): kausal runs with the same TMAX",
                sci(m)
            ),
            StepCap::Free => "free steps (TSTEP ≥ span/50: ngspice at its defaults)".into(),
        }
    }
}

/// Errors of a benchmark run.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error("{0}")]
    Pipeline(String),
    #[error(transparent)]
    Sim(#[from] sim::SimError),
    #[error(transparent)]
    Ngspice(#[from] ValidateError),
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    if v.is_empty() { 0.0 } else { v[v.len() / 2] }
}

/// A pipeline failure as one line: the file and the errors' messages.
fn pipeline_error(path: &Path, f: &pipeline::Failed) -> BenchError {
    let msgs: Vec<String> = f.errors().map(|d| d.message.clone()).collect();
    BenchError::Pipeline(format!("{}: {}", path.display(), msgs.join("; ")))
}

/// Parse, build and sort `path`; the front-end and sort times.
fn sorted_from(path: &Path) -> Result<(Sorted, f64, f64), BenchError> {
    let t0 = Instant::now();
    let (el, built) = pipeline::equations(path, &FsLoader, SortOptions::default().build)
        .map_err(|f| pipeline_error(path, &f))?;
    let front = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let sorted = pipeline::sort_built(el, built, &SortOptions::default())
        .map_err(|f| pipeline_error(path, &f))?;
    Ok((sorted, front, t1.elapsed().as_secs_f64()))
}

/// The value of `key=` in a netlist's `* kausal-bench: key=value ...` comment.
fn bench_hint(text: &str, key: &str) -> Option<String> {
    text.lines().find_map(|l| {
        l.trim_start()
            .strip_prefix('*')?
            .trim_start()
            .strip_prefix("kausal-bench:")?
            .split_whitespace()
            .find_map(|kv| kv.strip_prefix(key)?.strip_prefix('='))
            .map(str::to_string)
    })
}

/// An analytic solution stated by the netlist, one `* kausal-exact: NAME =
/// EXPR` line per definition, in order. `EXPR` is a parameter expression in
/// `t` and the names defined above it; `NAME` is an output vector (`v(out)`,
/// `i(v1)`: compared) or a helper.
#[derive(Clone, Debug)]
pub struct Exact {
    defs: Vec<(String, crate::front::expr::PExpr)>,
}

impl Exact {
    /// The netlist's exact solution, if it states one; a malformed line is
    /// an error naming its line and column.
    pub fn from_netlist(text: &str) -> Result<Option<Exact>, String> {
        let mut defs = Vec::new();
        for (k, line) in text.lines().enumerate() {
            let Some(rest) = line
                .trim_start()
                .strip_prefix('*')
                .map(str::trim_start)
                .and_then(|l| l.strip_prefix("kausal-exact:"))
            else {
                continue;
            };
            let at = |col: usize, why: &str| format!("line {}, column {}: {why}", k + 1, col + 1);
            let start = line.len() - rest.len();
            let Some((name, expr)) = rest.split_once('=') else {
                return Err(at(start, "expected `NAME = EXPR`"));
            };
            let name = name.trim().to_ascii_lowercase();
            if name.is_empty() {
                return Err(at(start, "missing name before `=`"));
            }
            let expr_start = start + name.len() + 1;
            let parsed = crate::front::expr::parse_expr(expr.trim()).map_err(|off| {
                let lead = expr.len() - expr.trim_start().len();
                at(expr_start + lead + off, "cannot parse this expression")
            })?;
            defs.push((name, parsed));
        }
        if defs.is_empty() {
            return Ok(None);
        }
        let exact = Exact { defs };
        if exact.signals().is_empty() {
            return Err("kausal-exact lines define no output vector (`v(..)` or `i(..)`)".into());
        }
        Ok(Some(exact))
    }

    fn is_signal(name: &str) -> bool {
        (name.starts_with("v(") || name.starts_with("i(")) && name.ends_with(')')
    }

    /// The output vectors it defines.
    pub fn signals(&self) -> Vec<String> {
        self.defs
            .iter()
            .filter(|(n, _)| Self::is_signal(n))
            .map(|(n, _)| n.clone())
            .collect()
    }

    /// The signals at `times`.
    pub fn at(&self, times: &[f64]) -> Result<Waveforms, String> {
        let names = self.signals();
        let mut data = vec![Vec::with_capacity(times.len()); names.len()];
        let mut env: Vec<(&str, f64)> = Vec::with_capacity(self.defs.len() + 1);
        for &t in times {
            env.clear();
            env.push(("t", t));
            let mut col = 0;
            for (name, e) in &self.defs {
                let v = e
                    .eval(&|n| env.iter().rev().find(|(m, _)| *m == n).map(|p| p.1))
                    .map_err(|err| format!("exact {name} at t = {t:e}: {err:?}"))?;
                env.push((name, v));
                if Self::is_signal(name) {
                    data[col].push(v);
                    col += 1;
                }
            }
        }
        Ok(Waveforms {
            names,
            time: times.to_vec(),
            data,
            ..Default::default()
        })
    }
}

/// Solvers a netlist asks to be benchmarked with besides the chosen ones:
/// `* kausal-bench: solvers=tsit5` on a circuit known not to be stiff (an
/// explicit method would crawl through a stiff one, so it is never a default).
pub fn extra_solvers(text: &str) -> Vec<Method> {
    bench_hint(text, "solvers")
        .map(|list| {
            list.split(',')
                .filter_map(|name| {
                    [
                        Method::Bdf,
                        Method::TrBdf2,
                        Method::Esdirk34,
                        Method::Tsit5,
                        Method::Circuit,
                        Method::Gear2,
                    ]
                    .into_iter()
                    .find(|&m| method_name(m).eq_ignore_ascii_case(name))
                })
                .collect()
        })
        .unwrap_or_default()
}

/// The chosen solvers, then those the netlist asks for besides; `circuit`
/// and `gear2` only where they run (at most [`sim::DENSE_STATES`] states).
fn methods_for(opts: &Options, text: &str, states: usize) -> Vec<Method> {
    let mut methods = opts.methods.clone();
    if states > sim::DENSE_STATES {
        methods.retain(|&m| !matches!(m, Method::Circuit | Method::Gear2));
    }
    for m in extra_solvers(text) {
        if !methods.contains(&m) {
            methods.push(m);
        }
    }
    methods
}

/// The stored-energy expression of a netlist: `* kausal-bench:
/// energy=0.5e-6*v(tank)^2+0.5e-3*i(vs)^2` (a sum of `coef*signal^2`).
pub fn energy_terms(text: &str) -> Option<Vec<(f64, String)>> {
    let spec = bench_hint(text, "energy")?;
    spec.split('+')
        .map(|term| {
            let (coef, sig) = term.split_once('*')?;
            let sig = sig.strip_suffix("^2")?;
            Some((
                crate::front::expr::parse_number(coef)?,
                sig.to_ascii_lowercase(),
            ))
        })
        .collect()
}

/// Largest `|E(t) - E(0)| / E(0)` over the samples.
pub fn energy_drift(terms: &[(f64, String)], names: &[String], data: &[Vec<f64>]) -> Option<f64> {
    let cols: Vec<(f64, &Vec<f64>)> = terms
        .iter()
        .map(|(c, s)| {
            let k = names.iter().position(|n| n.eq_ignore_ascii_case(s))?;
            Some((*c, &data[k]))
        })
        .collect::<Option<_>>()?;
    let len = cols.first()?.1.len();
    let energy = |i: usize| cols.iter().map(|(c, v)| c * v[i] * v[i]).sum::<f64>();
    let e0 = energy(0);
    if e0 <= 0.0 {
        return None;
    }
    Some(
        (0..len)
            .map(|i| (energy(i) - e0).abs() / e0)
            .fold(0.0, f64::max),
    )
}

/// Largest absolute error of `test` (on `test_time`, same names) against
/// `reference` at the reference's points where both have the signal.
fn max_error(
    ref_names: &[String],
    ref_time: &[f64],
    ref_data: &[Vec<f64>],
    names: &[String],
    time: &[f64],
    data: &[Vec<f64>],
) -> (f64, String) {
    let mut worst = (0.0f64, String::new());
    for (k, name) in ref_names.iter().enumerate() {
        let Some(j) = names.iter().position(|n| n.eq_ignore_ascii_case(name)) else {
            continue;
        };
        for (i, &t) in ref_time.iter().enumerate() {
            let v = if time.len() == ref_time.len() && time[i] == t {
                Some(data[j][i])
            } else {
                interp(time, &data[j], t)
            };
            if let Some(v) = v {
                let e = (v - ref_data[k][i]).abs();
                let e = if e.is_nan() { f64::INFINITY } else { e };
                if e > worst.0 {
                    worst = (e, name.clone());
                }
            }
        }
    }
    worst
}

fn method_name(m: Method) -> &'static str {
    m.name()
}

/// kausal on `sorted`, `repeats` times; the waveforms of the last run and
/// the median solve time.
fn run_kausal(
    sorted: &Sorted,
    opts: &sim::Options,
    repeats: usize,
) -> Result<(Waveforms, f64), sim::SimError> {
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..repeats.max(1) {
        let w = sim::simulate(sorted, opts)?;
        times.push(w.stats.wall.as_secs_f64());
        last = Some(w);
    }
    Ok((last.expect("one run"), median(times)))
}

/// The median wall time of `repeats` `kausal sim` processes on `path`
/// writing a binary raw file to a scratch directory, as a user runs it and
/// as the ngspice process writes its own (the same format, the same
/// vectors).
fn kausal_process(
    exe: &Path,
    path: &Path,
    (m, tol): (Method, f64),
    probes: &[String],
    tmax: Option<f64>,
    repeats: usize,
) -> Result<(f64, Option<u64>), String> {
    let dir = crate::io::ScratchDir::new().map_err(|e| format!("no scratch directory: {e}"))?;
    let out = dir.path().join("out.raw");
    let mut times = Vec::new();
    let mut peaks = Vec::new();
    for _ in 0..repeats.max(1) {
        let mut cmd = std::process::Command::new(exe);
        cmd.arg("sim")
            .arg(path)
            .args(["--method", method_name(m), "--rtol", &format!("{tol:e}")]);
        // The vectors ngspice saves, no more.
        for p in probes {
            cmd.args(["--probe", p]);
        }
        if let Some(t) = tmax {
            cmd.args(["--tmax", &format!("{t:e}")]);
        }
        cmd.arg("-o").arg(&out);
        let started = std::time::Instant::now();
        let (run, peak) =
            crate::io::run_child_measured(&mut cmd, std::time::Duration::from_secs(3600))
                .map_err(|e| format!("cannot run `{}`: {e}", exe.display()))?;
        times.push(started.elapsed().as_secs_f64());
        peaks.extend(peak);
        if !run.status.success() {
            return Err(format!(
                "`kausal sim` failed: {}",
                String::from_utf8_lossy(&run.stderr).trim()
            ));
        }
    }
    Ok((median(times), peaks.into_iter().max()))
}

/// The reference (kausal at `ref_rtol`) at given times.
fn reference_at(
    sorted: &Sorted,
    probes: &[String],
    ref_rtol: f64,
    times: Option<Vec<f64>>,
) -> Result<Waveforms, sim::SimError> {
    let opts = sim::Options {
        method: Some(Method::Bdf),
        rtol: Some(ref_rtol),
        probes: probes.to_vec(),
        times,
        ..Default::default()
    };
    sim::simulate(sorted, &opts)
}

/// ngspice's time points inside `[0, tstop]`, strictly increasing.
fn clean_times(t: &[f64], tstop: f64) -> Vec<f64> {
    let mut v: Vec<f64> = t
        .iter()
        .copied()
        .filter(|&x| (0.0..=tstop).contains(&x))
        .collect();
    v.dedup();
    v
}

/// The seconds of an ngspice `acct` line such as `Transient analysis time = 0.25`.
fn acct_seconds(output: &str, key: &str) -> Option<f64> {
    output.lines().find_map(|l| {
        let rest = l.trim().strip_prefix(key)?;
        rest.trim().strip_prefix('=')?.trim().parse().ok()
    })
}

fn acct_usize(output: &str, key: &str) -> Option<usize> {
    acct_seconds(output, key).map(|x| x as usize)
}

/// Run ngspice `repeats` times with an options line; the last run's data
/// and the median solve and process times.
fn run_ngspice(
    path: &Path,
    options: &str,
    probes: &[String],
    repeats: usize,
) -> Result<NgspiceRun, ValidateError> {
    let program = validate::ngspice_program();
    let mut line = format!(".options {options} acct\n");
    // The vectors kausal writes, no more (without `.save` ngspice stores
    // every node and branch).
    if !probes.is_empty() {
        line.push_str(&format!(".save {}\n", probes.join(" ")));
    }
    let mut solve = Vec::new();
    let mut total = Vec::new();
    let mut last = None;
    let mut peaks = Vec::new();
    for _ in 0..repeats.max(1) {
        let e = validate::exec(&program, path, Some(&line))?;
        total.push(e.wall.as_secs_f64());
        peaks.extend(e.peak);
        solve.push(
            acct_seconds(&e.output, "Transient analysis time").unwrap_or(e.wall.as_secs_f64()),
        );
        let steps = acct_usize(&e.output, "Accepted timepoints").unwrap_or(e.raw.time.len());
        last = Some((e.raw, steps));
    }
    let (raw, steps) = last.expect("one run");
    Ok(NgspiceRun {
        raw,
        solve: median(solve),
        total: median(total),
        steps,
        peak: peaks.into_iter().max(),
    })
}

/// What [`run_ngspice`] measured: the last run's data, median solve and
/// process times, accepted steps and the largest peak memory.
struct NgspiceRun {
    raw: RawData,
    solve: f64,
    total: f64,
    steps: usize,
    peak: Option<u64>,
}

/// What every run of one netlist is measured against.
struct Baseline<'b> {
    sorted: &'b Sorted,
    probes: &'b [String],
    exact: Option<&'b Exact>,
    ref_rtol: f64,
    /// The reference at the time points of kausal's tight run.
    reference: Waveforms,
    /// The netlist's energy terms, when it states them.
    energy: Option<Vec<(f64, String)>>,
    /// The step cap of every run.
    cap: StepCap,
}

impl Baseline<'_> {
    /// The reference at `times`: the exact solution, else a tight kausal run.
    fn on(&self, times: Vec<f64>) -> Result<Waveforms, String> {
        match self.exact {
            Some(x) => x.at(&times),
            None => reference_at(self.sorted, self.probes, self.ref_rtol, Some(times))
                .map_err(|e| e.to_string()),
        }
    }

    fn drift(&self, names: &[String], data: &[Vec<f64>]) -> Option<f64> {
        self.energy
            .as_ref()
            .and_then(|e| energy_drift(e, names, data))
    }
}

/// Benchmark one netlist. `tick` is called after every measurement.
pub fn bench_circuit(
    path: &Path,
    opts: &Options,
    tick: &dyn Fn(&str),
) -> Result<CircuitBench, BenchError> {
    let (sorted, front, sort) = sorted_from(path)?;
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let energy = energy_terms(&text);
    let tran = sim::tran_of(&sorted.elaborated.circuit)?;
    let (tstop, cap) = (tran.tstop, StepCap::of(tran));
    let probes: Vec<String> = sim::outputs(&sorted, &[])?
        .into_iter()
        .map(|o| o.0)
        .collect();
    let exact = Exact::from_netlist(&text)
        .map_err(|e| BenchError::Pipeline(format!("{}: {e}", path.display())))?;
    // A netlist may ask for a looser reference (`* kausal-bench:
    // ref_rtol=1e-9`) where rtol 1e-11 would take beyond the step budget
    // (a diode bridge at 1 µs TMAX over a second).
    let ref_rtol = bench_hint(&text, "ref_rtol")
        .and_then(|v| v.parse::<f64>().ok())
        .filter(|&r| r > 0.0 && r < 1.0)
        .unwrap_or(opts.ref_rtol);
    let tight = reference_at(&sorted, &probes, ref_rtol, None)?;
    // The reference: the exact solution where the netlist states one (then
    // kausal's tight run is checked against it), else kausal's tight run.
    let (reference, exact_check) = match &exact {
        Some(x) => {
            let r = x.at(&tight.time).map_err(BenchError::Pipeline)?;
            let check = max_error(
                &r.names,
                &r.time,
                &r.data,
                &tight.names,
                &tight.time,
                &tight.data,
            );
            (r, Some(check.0))
        }
        None => (tight, None),
    };
    let base = Baseline {
        sorted: &sorted,
        probes: &probes,
        exact: exact.as_ref(),
        ref_rtol,
        reference,
        energy,
        cap,
    };
    tick("reference");
    let mut points = Vec::new();
    let methods = methods_for(opts, &text, sorted.system().states().count());
    // The measurements a large circuit skips still count for the progress
    // bar ([`measurements`] cannot know the size).
    for _ in 0..(methods_for(opts, &text, 0).len() - methods.len()) * opts.tolerances.len() {
        tick("kausal circuit: too many states");
    }
    for m in methods {
        for &tol in &opts.tolerances {
            points.push(kausal_point(path, opts, &base, m, tol, (front, sort)));
            tick(&format!("kausal {} {tol:e}", method_name(m)));
        }
    }
    let mut reference_check = None;
    let mut verdict = None;
    if opts.ngspice {
        reference_check = ngspice_reference_check(path, opts, &base, tstop);
        tick("ngspice reference");
        let mut runs: Vec<(String, Option<f64>, String)> =
            vec![("ngspice default".into(), None, String::new())];
        for method in ["trap", "gear"] {
            for &tol in &opts.tolerances {
                runs.push((
                    format!("ngspice {method}"),
                    Some(tol),
                    format!("reltol={tol:e} method={method}"),
                ));
            }
        }
        for (solver, tol, line) in runs {
            points.push(ngspice_point(path, opts, &base, tstop, solver, tol, &line)?);
            tick(&line);
        }
        verdict = verdict_of(&points);
    }
    let floor = reference_check.unwrap_or(0.0).max(1e-12);
    let non_monotone = non_monotone(&points, floor);
    Ok(CircuitBench {
        netlist: path.display().to_string(),
        states: sorted.system().states().count(),
        equations: sorted.system().eqs.len(),
        front_seconds: front,
        sort_seconds: sort,
        cap,
        reference: match (&exact, exact_check) {
            (Some(x), Some(c)) => format!(
                "exact ({}), kausal bdf rtol {:e} within {} of it",
                x.signals().join(", "),
                ref_rtol,
                sci(c)
            ),
            _ => format!("kausal bdf, rtol {ref_rtol:e}"),
        },
        reference_check,
        exact_check,
        points,
        verdict,
        non_monotone,
    })
}

/// One kausal run with method `m` at tolerance `tol`, against the
/// reference. `front_sort` are the seconds parsing and sorting took, counted
/// in the total when kausal is not timed as a process.
fn kausal_point(
    path: &Path,
    opts: &Options,
    base: &Baseline<'_>,
    m: Method,
    tol: f64,
    (front, sort): (f64, f64),
) -> Point {
    let so = sim::Options {
        method: Some(m),
        rtol: Some(tol),
        probes: base.probes.to_vec(),
        tmax: base.cap.tmax(),
        ..Default::default()
    };
    let solver = format!("kausal {}", method_name(m));
    let run = run_kausal(base.sorted, &so, opts.repeats).map_err(|e| e.to_string());
    let run = run.and_then(|(w, secs)| {
        let (total, peak) = match &opts.exe {
            Some(exe) => kausal_process(
                exe,
                path,
                (m, tol),
                base.probes,
                base.cap.tmax(),
                opts.repeats,
            )?,
            None => (front + sort + secs, None),
        };
        Ok((w, secs, total, peak))
    });
    match run {
        Ok((w, secs, total, peak)) => {
            let r = &base.reference;
            let (error, worst) = max_error(&r.names, &r.time, &r.data, &w.names, &w.time, &w.data);
            Point {
                solver,
                tol: Some(tol),
                solve_seconds: secs,
                total_seconds: total,
                error,
                worst_signal: worst,
                steps: w.stats.steps,
                energy_drift: base.drift(&w.names, &w.data),
                failed: None,
                peak_bytes: peak,
            }
        }
        Err(e) => failed_point(solver, Some(tol), e),
    }
}

/// The cross-check of the reference: its largest error against a tight
/// ngspice run (`None` when either cannot be had).
fn ngspice_reference_check(
    path: &Path,
    opts: &Options,
    base: &Baseline<'_>,
    tstop: f64,
) -> Option<f64> {
    let tight = format!(
        "reltol={:e} abstol=1e-15 vntol=1e-12 chgtol=1e-18 trtol=1",
        opts.ngspice_ref_reltol
    );
    let raw = run_ngspice(path, &tight, base.probes, 1).ok()?.raw;
    let times = clean_times(&raw.time, tstop);
    let r = base.on(times).ok()?;
    Some(max_error(&r.names, &r.time, &r.data, &raw.names, &raw.time, &raw.data).0)
}

/// One ngspice run with the options `line`, against the reference at
/// ngspice's own time points. A missing ngspice is an error; any other
/// failure is a failed point.
fn ngspice_point(
    path: &Path,
    opts: &Options,
    base: &Baseline<'_>,
    tstop: f64,
    solver: String,
    tol: Option<f64>,
    line: &str,
) -> Result<Point, BenchError> {
    let NgspiceRun {
        raw,
        solve,
        total,
        steps,
        peak,
    } = match run_ngspice(path, line, base.probes, opts.repeats) {
        Ok(run) => run,
        Err(e @ ValidateError::Missing { .. }) => return Err(e.into()),
        Err(e) => return Ok(failed_point(solver, tol, e.to_string())),
    };
    let times = clean_times(&raw.time, tstop);
    let r = match base.on(times) {
        Ok(r) => r,
        Err(e) => {
            let why = format!("reference at ngspice's points: {e}");
            return Ok(failed_point(solver, tol, why));
        }
    };
    let (error, worst) = max_error(&r.names, &r.time, &r.data, &raw.names, &raw.time, &raw.data);
    Ok(Point {
        solver,
        tol,
        solve_seconds: solve,
        total_seconds: total,
        error,
        worst_signal: worst,
        steps,
        energy_drift: base.drift(&raw.names, &raw.data),
        failed: None,
        peak_bytes: peak,
    })
}

/// ngspice's default run against the fastest kausal run at least as
/// accurate (`None` when the default run failed).
fn verdict_of(points: &[Point]) -> Option<Verdict> {
    let d = points
        .iter()
        .find(|p| p.solver == "ngspice default" && p.failed.is_none())?;
    let best = points
        .iter()
        .filter(|p| p.solver.starts_with("kausal") && p.failed.is_none() && p.error <= d.error)
        .min_by(|a, b| a.solve_seconds.total_cmp(&b.solve_seconds))
        .cloned();
    Some(Verdict {
        ngspice_default_error: d.error,
        solve_speedup: best
            .as_ref()
            .map(|b| d.solve_seconds / b.solve_seconds.max(1e-9)),
        total_speedup: best
            .as_ref()
            .map(|b| d.total_seconds / b.total_seconds.max(1e-9)),
        kausal: best,
    })
}

/// The solvers whose error grows markedly as their tolerance tightens
/// (errors below ten times `floor`, the reference's own error, are noise).
fn non_monotone(points: &[Point], floor: f64) -> Vec<String> {
    let mut out = Vec::new();
    let mut solvers: Vec<&str> = points.iter().map(|p| p.solver.as_str()).collect();
    solvers.dedup();
    for s in solvers {
        let mut errs: Vec<(f64, f64)> = points
            .iter()
            .filter(|p| p.solver == s && p.failed.is_none())
            .filter_map(|p| Some((p.tol?, p.error)))
            .collect();
        errs.sort_by(|a, b| b.0.total_cmp(&a.0));
        if errs
            .windows(2)
            .any(|w| w[1].1 > 3.0 * w[0].1.max(floor) && w[1].1 > 10.0 * floor)
        {
            out.push(s.to_string());
        }
    }
    out
}

fn failed_point(solver: String, tol: Option<f64>, why: String) -> Point {
    Point {
        solver,
        tol,
        solve_seconds: f64::NAN,
        total_seconds: f64::NAN,
        error: f64::NAN,
        worst_signal: String::new(),
        steps: 0,
        energy_drift: None,
        failed: Some(why),
        peak_bytes: None,
    }
}

/// How many measurements [`bench_circuit`] makes on `netlist` (for a
/// progress bar).
pub fn measurements(opts: &Options, netlist: &Path) -> usize {
    let text = std::fs::read_to_string(netlist).unwrap_or_default();
    let k = methods_for(opts, &text, 0).len() * opts.tolerances.len() + 1;
    if opts.ngspice {
        k + 2 + 2 * opts.tolerances.len()
    } else {
        k
    }
}

fn sci(x: f64) -> String {
    if x.is_nan() {
        "—".into()
    } else if x == 0.0 {
        "0".into()
    } else {
        format!("{x:.1e}")
    }
}

fn ms(x: f64) -> String {
    if x.is_nan() {
        "—".into()
    } else if x < 0.01 {
        format!("{:.3}", x * 1e3)
    } else {
        format!("{:.1}", x * 1e3)
    }
}

fn mb(bytes: Option<u64>) -> String {
    bytes.map_or_else(|| "—".into(), |b| format!("{:.0}", b as f64 / 1e6))
}

fn cap_short(cap: StepCap) -> String {
    match cap {
        StepCap::Tmax(m) => format!("TMAX {}", sci(m)),
        StepCap::Tstep(m) => format!("TMAX = TSTEP {}", sci(m)),
        StepCap::Free => "free".into(),
    }
}

/// How every comparison of the report was made (its first section).
pub const PROTOCOL: &str = "## Protocol\n\n\
- **Same outputs.** Every kausal and ngspice run of a circuit stores the same vectors: \
  ngspice gets a `.save` of what kausal writes (the netlist's `.save`, else its defaults), \
  kausal gets them as `--probe`.\n\
- **Same step cap.** ngspice caps its step at min(TSTEP, span/50) unless the netlist gives \
  TMAX. On a netlist with TSTEP below span/50 that cap, not accuracy, sets ngspice's step \
  count, so kausal is given the same TMAX (`--tmax TSTEP`). A netlist's own TMAX binds both. \
  Otherwise (TSTEP ≥ span/50) ngspice runs at its defaults and kausal's steps are free.\n\
- **Equal accuracy.** Errors are measured against one reference per circuit (a tight kausal \
  run, cross-checked against ngspice at reltol 1e-8); a speed-up compares ngspice at its \
  defaults with the fastest kausal run whose error is no larger.\n\
- **Same run, medians, ratios.** Both sides are measured in one run, each figure the median \
  of its repeats; whole processes against whole processes (wall time, peak resident memory \
  sampled from `/proc` every 2 ms), solve against solve (kausal's integration against ngspice's \
  \"Transient analysis time\"). Absolute times on a shared 2-core machine are noisy; \
  the ratios are the result.\n\n";

/// The markdown report of a set of circuits.
/// Plots are linked as `{plots}{stem}.svg`.
pub fn markdown(benches: &[CircuitBench], scaling: Option<&Scaling>, plots: &str) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    if !benches.is_empty() {
        s.push_str("## At ngspice's default error\n\n");
        s.push_str(
            "The fastest kausal run whose error is at most that of ngspice at its defaults \
             (trapezoidal, reltol 1e-3), against that ngspice run. Solve: kausal's \
             integration in process against ngspice's \"Transient analysis time\" (CPU, \
             reported in whole milliseconds). Whole job: wall time of a `kausal sim -o FILE.raw` \
             process against an `ngspice -b -r FILE.raw` process (start-up, parse, solve, \
             the same vectors written as binary raw files), with \
             each process's peak resident memory. Per step: solve time over accepted steps. \
             Cap: the step cap both sides ran with.\n\n",
        );
        s.push_str("| circuit | cap | ngspice default error | kausal run | kausal error | solve speed-up | whole-job speed-up | steps kausal / ngspice | per step kausal / ngspice (µs) | peak MB kausal / ngspice |\n");
        s.push_str("|---|---|---|---|---|---|---|---|---|---|\n");
        for b in benches {
            let name = stem(&b.netlist);
            match &b.verdict {
                Some(v) => match &v.kausal {
                    Some(k) => {
                        let d = b.points.iter().find(|p| p.solver == "ngspice default");
                        let per_step = |p: &Point| p.solve_seconds * 1e6 / p.steps.max(1) as f64;
                        let _ = writeln!(
                            s,
                            "| {name} | {} | {} | {} rtol {} | {} | {:.1}× | {:.1}× | {} / {} | {:.2} / {:.2} | {} / {} |",
                            cap_short(b.cap),
                            sci(v.ngspice_default_error),
                            k.solver,
                            sci(k.tol.unwrap_or(f64::NAN)),
                            sci(k.error),
                            v.solve_speedup.unwrap_or(f64::NAN),
                            v.total_speedup.unwrap_or(f64::NAN),
                            k.steps,
                            d.map_or(0, |d| d.steps),
                            per_step(k),
                            d.map_or(f64::NAN, per_step),
                            mb(k.peak_bytes),
                            mb(d.and_then(|d| d.peak_bytes)),
                        );
                    }
                    None => {
                        let _ = writeln!(
                            s,
                            "| {name} | {} | {} | none as accurate | — | — | — | | | |",
                            cap_short(b.cap),
                            sci(v.ngspice_default_error)
                        );
                    }
                },
                None => {
                    let _ = writeln!(
                        s,
                        "| {name} | {} | (ngspice not run) | | | | | | | |",
                        cap_short(b.cap)
                    );
                }
            }
        }
        s.push('\n');
    }
    for b in benches {
        let name = stem(&b.netlist);
        let _ = writeln!(s, "## {name}\n");
        let _ = writeln!(
            s,
            "`{}`: {} equations, {} states; parse+build {} ms, sort {} ms; {}. Reference: {}{}.\n",
            b.netlist,
            b.equations,
            b.states,
            ms(b.front_seconds),
            ms(b.sort_seconds),
            b.cap.describe(),
            b.reference,
            match b.reference_check {
                Some(c) => format!(", within {} of ngspice at a tight reltol", sci(c)),
                None => String::new(),
            }
        );
        let energy = b.points.iter().any(|p| p.energy_drift.is_some());
        s.push_str(
            "| solver | tol | solve (ms) | whole job (ms) | peak MB | steps | max error | worst signal |",
        );
        if energy {
            s.push_str(" energy drift |");
        }
        s.push_str("\n|---|---|---|---|---|---|---|---|");
        if energy {
            s.push_str("---|");
        }
        s.push('\n');
        for p in &b.points {
            let _ = write!(
                s,
                "| {} | {} | {} | {} | {} | {} | {} | {} |",
                p.solver,
                p.tol.map(sci).unwrap_or_else(|| "default".into()),
                ms(p.solve_seconds),
                ms(p.total_seconds),
                mb(p.peak_bytes),
                p.steps,
                match &p.failed {
                    Some(why) => format!("failed: {}", why.lines().next().unwrap_or("")),
                    None => sci(p.error),
                },
                p.worst_signal,
            );
            if energy {
                let _ = write!(s, " {} |", p.energy_drift.map(sci).unwrap_or_default());
            }
            s.push('\n');
        }
        if !b.non_monotone.is_empty() {
            let _ = writeln!(
                s,
                "\nError not decreasing with tolerance: {}.",
                b.non_monotone.join(", ")
            );
        }
        let _ = writeln!(s, "\n![work-precision of {name}]({plots}{name}.svg)\n");
    }
    if let Some(sc) = scaling {
        s.push_str(&scaling_markdown(sc));
    }
    s
}

/// The file stem of a netlist path.
pub fn stem(netlist: &str) -> String {
    Path::new(netlist)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| netlist.to_string())
}

/// One size of the scaling run.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ScalePoint {
    pub sections: usize,
    pub states: usize,
    pub front_seconds: f64,
    pub sort_seconds: f64,
    pub solve_seconds: f64,
    pub ngspice_solve_seconds: Option<f64>,
    pub ngspice_total_seconds: Option<f64>,
    /// Largest difference of the first and last nodes' voltages, kausal
    /// against ngspice.
    pub difference: Option<f64>,
    /// Why ngspice has no figures here (it did not finish in time).
    pub ngspice_failed: Option<String>,
}

/// The scaling run: RC ladders of growing size at default tolerances.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Scaling {
    pub points: Vec<ScalePoint>,
    /// Log-log slopes between the first and the last size.
    pub slope_front_sort: f64,
    pub slope_solve: f64,
    pub slope_ngspice: Option<f64>,
}

/// Generated RC ladders of `sizes` sections (written to `dir`), simulated at
/// default tolerances by kausal and ngspice.
pub fn scaling(
    sizes: &[usize],
    dir: &Path,
    ngspice: bool,
    tick: &dyn Fn(&str),
) -> Result<Scaling, BenchError> {
    let mut points = Vec::new();
    for &n in sizes {
        let mut text = crate::generate::rc_ladder(n);
        let end = text.rfind(".end").unwrap_or(text.len());
        text.insert_str(end, &format!(".save v(n1) v(n{n})\n"));
        let path: PathBuf = dir.join(format!("rc_ladder_{n}.cir"));
        std::fs::write(&path, &text).map_err(|e| BenchError::Pipeline(e.to_string()))?;
        let (sorted, front, sort) = sorted_from(&path)?;
        // The first node carries the step; the last barely moves.
        let probe = vec!["v(n1)".to_string(), format!("v(n{n})")];
        // TSTEP 1u caps ngspice's step (below span/50): kausal's too.
        let cap = sorted.elaborated.circuit.tran.as_ref().map(StepCap::of);
        let so = sim::Options {
            probes: probe.clone(),
            tmax: cap.and_then(StepCap::tmax),
            ..Default::default()
        };
        let w = sim::simulate(&sorted, &so)?;
        let solve = w.stats.wall.as_secs_f64();
        let (mut ns, mut nt, mut diff, mut failed) = (None, None, None, None);
        if ngspice {
            // A missing ngspice ends the run; one that failed or did not
            // finish on a large ladder is that point's note (the rest of
            // the report, an hour's measurements, must not be lost to it).
            match run_ngspice(&path, "", &probe, 1) {
                Ok(NgspiceRun {
                    raw,
                    solve: s,
                    total: t,
                    ..
                }) => {
                    ns = Some(s);
                    nt = Some(t);
                    diff = Some(
                        max_error(&w.names, &w.time, &w.data, &raw.names, &raw.time, &raw.data).0,
                    );
                }
                Err(e @ ValidateError::Missing { .. }) => return Err(e.into()),
                Err(e) => failed = Some(e.to_string()),
            }
        }
        points.push(ScalePoint {
            sections: n,
            states: w.stats.states,
            front_seconds: front,
            sort_seconds: sort,
            solve_seconds: solve,
            ngspice_solve_seconds: ns,
            ngspice_total_seconds: nt,
            difference: diff,
            ngspice_failed: failed,
        });
        tick(&format!("ladder {n}"));
    }
    // From the smallest to the largest ladder that has the figure.
    let slope = |f: &dyn Fn(&ScalePoint) -> Option<f64>| -> Option<f64> {
        let a = points.iter().find(|p| f(p).is_some())?;
        let b = points.iter().rev().find(|p| f(p).is_some())?;
        let (ya, yb) = (f(a)?, f(b)?);
        if a.sections == b.sections || ya <= 0.0 || yb <= 0.0 {
            return None;
        }
        Some((yb / ya).ln() / (b.sections as f64 / a.sections as f64).ln())
    };
    Ok(Scaling {
        slope_front_sort: slope(&|p| Some(p.front_seconds + p.sort_seconds)).unwrap_or(f64::NAN),
        slope_solve: slope(&|p| Some(p.solve_seconds)).unwrap_or(f64::NAN),
        slope_ngspice: slope(&|p| p.ngspice_solve_seconds),
        points,
    })
}

fn scaling_markdown(sc: &Scaling) -> String {
    use std::fmt::Write;
    let mut s = String::from("## Scaling: RC ladders at default tolerances\n\n");
    s.push_str("Generated ladders (`kausal::generate::rc_ladder`, 10 ms, 10 001 output points), the first and the last node saved. kausal: its defaults; ngspice: its defaults. TSTEP (1 µs) caps ngspice's step, so kausal runs with the same TMAX: this table measures per-step cost and scaling, not step selection (the ladders of the tables above do that).\n\n");
    s.push_str("| sections | states | parse+build (ms) | sort (ms) | kausal solve (ms) | ngspice solve (ms) | ngspice process (ms) | solve speed-up | max |Δv| vs ngspice |\n|---|---|---|---|---|---|---|---|---|\n");
    for p in &sc.points {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            p.sections,
            p.states,
            ms(p.front_seconds),
            ms(p.sort_seconds),
            ms(p.solve_seconds),
            p.ngspice_solve_seconds
                .map(ms)
                .unwrap_or_else(|| p.ngspice_failed.clone().unwrap_or_default()),
            p.ngspice_total_seconds.map(ms).unwrap_or_default(),
            p.ngspice_solve_seconds
                .map(|n| format!("{:.1}×", n / p.solve_seconds))
                .unwrap_or_default(),
            p.difference.map(sci).unwrap_or_default(),
        );
    }
    let _ = writeln!(
        s,
        "\nLog-log slopes from the smallest to the largest ladder (for ngspice, the largest it finished): parse+build+sort {:.2}, kausal solve {:.2}{}.\n",
        sc.slope_front_sort,
        sc.slope_solve,
        sc.slope_ngspice
            .map(|x| format!(", ngspice solve {x:.2}"))
            .unwrap_or_default()
    );
    s
}

/// Where the numbers come from: the machine, ngspice's version, the date.
pub fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|c| {
            c.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|s| s.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let cores = std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1);
    let ngspice = std::process::Command::new(validate::ngspice_program())
        .arg("-v")
        .output()
        .ok()
        .and_then(|o| {
            String::from_utf8_lossy(&o.stdout)
                .lines()
                .find(|l| l.contains("ngspice-"))
                .map(|l| l.trim().trim_start_matches('*').trim().to_string())
        })
        .unwrap_or_else(|| "ngspice (version unknown)".into());
    format!("{cpu}, {cores} cores; {ngspice}")
}
