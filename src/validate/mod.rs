//! Cross-validation against real ngspice: run `ngspice -b` on the same
//! netlist in a temporary directory (a tight-tolerance reference and its
//! default run), read the raw file, and compare signal by signal.
//!
//! kausal is evaluated at ngspice's own time points (with its solver's
//! interpolant), so no linear interpolation error enters the comparison.
//! This module, `bench/`, `io.rs` and the CLI are the only ones that touch
//! the file system and run programs.

use crate::diag::codes;
pub mod plot;
pub mod raw;

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::diag::{Diagnostic, ToDiagnostic};
use crate::pipeline::Sorted;
use crate::sim::{self, SimError, Waveforms};
pub use raw::RawData;

#[derive(Clone, Debug, thiserror::Error)]
pub enum ValidateError {
    #[error(
        "ngspice was not found (looked for `{program}`): install it with `apt-get install ngspice`"
    )]
    Missing { program: String },
    #[error("ngspice failed ({status}):\n{output}")]
    Failed { status: String, output: String },
    #[error("ngspice wrote no data: {reason}\n{output}")]
    NoData { reason: String, output: String },
    #[error("ngspice's raw file is malformed: {0}")]
    Malformed(String),
    #[error("cannot prepare the ngspice run: {0}")]
    Io(String),
    #[error("kausal's simulation failed: {0}")]
    Sim(#[from] SimError),
    #[error("ngspice has no vector `{0}`")]
    NoVector(String),
    #[error("ngspice did not finish within {seconds} s ({reltol})")]
    TimedOut { seconds: u64, reltol: String },
}

/// How long one ngspice run, or the reference's runs at every tolerance
/// tried, may take: `$KAUSAL_NGSPICE_TIMEOUT` seconds, else
/// 300 (ngspice needs 156 s for a 100×100 resistor mesh; at a tight reltol it
/// can also shrink its step without end).
pub fn ngspice_time_limit() -> std::time::Duration {
    let secs = std::env::var("KAUSAL_NGSPICE_TIMEOUT")
        .ok()
        .and_then(|v| v.parse::<u64>().ok())
        .filter(|&s| s > 0)
        .unwrap_or(300);
    std::time::Duration::from_secs(secs)
}

impl ToDiagnostic for ValidateError {
    fn to_diagnostic(&self) -> Diagnostic {
        let help = match self {
            ValidateError::Missing { .. } => {
                "Debian/Ubuntu: apt-get update && apt-get install -y ngspice; or set KAUSAL_NGSPICE to its path"
            }
            ValidateError::Failed { .. } => "ngspice's own message is shown above",
            ValidateError::NoData { .. } | ValidateError::Malformed(_) => {
                "check that the netlist has a .tran line ngspice accepts"
            }
            ValidateError::Io(_) => "check the temporary directory",
            ValidateError::Sim(_) => "see `kausal sim` for the same run",
            ValidateError::NoVector(_) => {
                "probe a vector both simulators know: v(node) or i(vsource)"
            }
            ValidateError::TimedOut { .. } => {
                "it was stopped (the reference runs at every tolerance tried share this limit); set KAUSAL_NGSPICE_TIMEOUT (seconds) to wait longer"
            }
        };
        Diagnostic::error(codes::VALIDATE_FAILED, self.to_string()).with_help(help)
    }
}

/// The ngspice program: `$KAUSAL_NGSPICE`, else `ngspice` on the PATH.
pub fn ngspice_program() -> String {
    std::env::var("KAUSAL_NGSPICE").unwrap_or_else(|_| "ngspice".into())
}

/// Tolerances of an ngspice run: `None` for ngspice's defaults.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RefTol {
    pub reltol: f64,
    /// Gear's method instead of ngspice's default trapezoidal rule.
    pub gear: bool,
    /// The absolute tolerances (see [`AbsTol`]).
    pub abs: AbsTol,
}

/// The absolute tolerances of a reference run, tightest first: each is
/// tried where ngspice's steps collapse ("timestep too small") at the one
/// before it.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct AbsTol {
    /// ABSTOL (A).
    pub abstol: f64,
    /// VNTOL (V).
    pub vntol: f64,
    /// CHGTOL (C).
    pub chgtol: f64,
}

impl AbsTol {
    /// Femtoampere, picovolt and attocoulomb floors.
    pub const TIGHT: AbsTol = AbsTol {
        abstol: 1e-15,
        vntol: 1e-12,
        chgtol: 1e-18,
    };
    /// ngspice's default ABSTOL (MOS circuits' femtoampere currents collapse
    /// its steps at 1e-15).
    pub const PICOAMPERE: AbsTol = AbsTol {
        abstol: 1e-12,
        ..AbsTol::TIGHT
    };
    /// ngspice's defaults: the picovolt and attocoulomb floors also collapse
    /// its steps on digital MOS and bipolar decks (`mux8`, `cram`), where its
    /// defaults with a tight reltol get through. A microvolt floor is still
    /// a thousandth of the 1e-3 test on a signal of a volt.
    pub const NGSPICE: AbsTol = AbsTol {
        abstol: 1e-12,
        vntol: 1e-6,
        chgtol: 1e-14,
    };
    const LADDER: [AbsTol; 3] = [AbsTol::TIGHT, AbsTol::PICOAMPERE, AbsTol::NGSPICE];
}

/// The netlist text for ngspice: `.include` and `.lib` paths made absolute
/// (it runs in a temporary directory), tolerances appended for a reference
/// run. A `.tran` line in `extra` replaces the netlist's own. A `quit` or
/// `exit` in a `.control` block is left out: ngspice would stop there,
/// before it writes the raw file the comparison reads.
fn prepare_netlist(path: &Path, text: &str, extra: Option<&str>) -> String {
    let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let mut out = String::with_capacity(text.len() + 200);
    let mut end_seen = false;
    let is_tran = |l: &str| {
        l.trim_start()
            .get(..5)
            .is_some_and(|h| h.eq_ignore_ascii_case(".tran"))
    };
    let replace_tran = extra.is_some_and(|x| x.lines().any(is_tran));
    let mut in_control = false;
    for (k, line) in text.lines().enumerate() {
        let trimmed = line.trim_start();
        let lower = trimmed.to_ascii_lowercase();
        let word = lower.split_whitespace().next();
        match word {
            Some(".control") => in_control = true,
            Some(".endc") => in_control = false,
            Some("quit" | "exit") if in_control => continue,
            _ => {}
        }
        if k > 0 && replace_tran && is_tran(line) {
            continue;
        }
        if k > 0 && (lower.starts_with(".include") || lower.starts_with(".inc ")) {
            let mut parts = trimmed.splitn(2, char::is_whitespace);
            let _ = parts.next();
            let p = parts.next().unwrap_or("").trim().trim_matches('"');
            let abs = crate::front::resolve_include(&dir.join("x"), p);
            let abs = std::fs::canonicalize(&abs).unwrap_or(abs);
            out.push_str(&format!(".include \"{}\"\n", abs.display()));
            continue;
        }
        if k > 0 && lower.starts_with(".lib") {
            let parts: Vec<&str> = trimmed.split_whitespace().collect();
            if let [_, p, section, ..] = parts[..] {
                let abs = crate::front::resolve_include(&dir.join("x"), p.trim_matches('"'));
                let abs = std::fs::canonicalize(&abs).unwrap_or(abs);
                out.push_str(&format!(".lib \"{}\" {section}\n", abs.display()));
                continue;
            }
        }
        if k > 0 && lower.split_whitespace().next() == Some(".end") {
            end_seen = true;
            if let Some(x) = extra {
                out.push_str(x);
            }
        }
        out.push_str(line);
        out.push('\n');
    }
    if !end_seen {
        if let Some(x) = extra {
            out.push_str(x);
        }
        out.push_str(".end\n");
    }
    out
}

fn tight_options(t: RefTol) -> String {
    // A reference run: tight local error, tight absolute tolerances, and the
    // truncation-error tolerance at 1 (ngspice's default of 7 is loose).
    format!(
        ".options reltol={:e} abstol={:e} vntol={:e} chgtol={:e} trtol=1{}\n",
        t.reltol,
        t.abs.abstol,
        t.abs.vntol,
        t.abs.chgtol,
        if t.gear { " method=gear" } else { "" }
    )
}

/// Run ngspice on `path` and read its raw file.
pub fn run_ngspice(path: &Path, tol: Option<RefTol>) -> Result<RawData, ValidateError> {
    run_program(&ngspice_program(), path, tol)
}

/// [`run_ngspice`], with `saves` (a `.save` line, or empty) before `.end`.
fn run_ngspice_saving(
    path: &Path,
    tol: Option<RefTol>,
    saves: &str,
) -> Result<RawData, ValidateError> {
    run_ngspice_within(path, tol, saves, ngspice_time_limit())
}

/// [`run_ngspice_saving`], stopped after `limit`.
fn run_ngspice_within(
    path: &Path,
    tol: Option<RefTol>,
    saves: &str,
    limit: std::time::Duration,
) -> Result<RawData, ValidateError> {
    let extra = format!("{}{saves}", tol.map(tight_options).unwrap_or_default());
    let extra = (!extra.is_empty()).then_some(extra);
    exec_within(&ngspice_program(), path, extra.as_deref(), limit).map(|r| r.raw)
}

/// The `.save` line that makes ngspice store the device currents among
/// `names` that are not in its default vectors (`i(r1)` is `@r1[i]`): with
/// `all`, so that nothing else is lost. Empty when there are none.
fn device_saves(names: &[String]) -> String {
    let extra: Vec<String> = names.iter().filter_map(|n| device_vector(n)).collect();
    if extra.is_empty() {
        String::new()
    } else {
        format!(".save all {}\n", extra.join(" "))
    }
}

/// ngspice's device-parameter vector for the current `i(x)` of an element
/// that has no branch of its own (R, C, D, I, G, F); `None` for the others.
fn device_vector(name: &str) -> Option<String> {
    let x = name.strip_prefix("i(")?.strip_suffix(')')?;
    // A flattened subcircuit element (`r.x1.r1`) starts with its letter too.
    let param = match x.chars().next()? {
        'r' | 'c' | 'g' | 'f' => "i",
        'd' => "id",
        'i' => "current",
        _ => return None,
    };
    Some(format!("@{x}[{param}]"))
}

/// ngspice's name for the current of an element two or more subcircuits
/// deep: it repeats the element's letter at every level
/// (`i(v.x1.v.x4.v1)`), where kausal writes the path once
/// (`i(v.x1.x4.v1)`, ngspice's own form one level deep).
fn nested_current(name: &str) -> Option<String> {
    let x = name.strip_prefix("i(")?.strip_suffix(')')?;
    let (letter, path) = x.split_once('.')?;
    let mut parts: Vec<&str> = path.split('.').collect();
    let element = parts.pop()?;
    if parts.len() < 2 {
        return None;
    }
    let mut out = String::from("i(");
    for instance in parts {
        out.push_str(&format!("{letter}.{instance}."));
    }
    out.push_str(element);
    out.push(')');
    Some(out)
}

/// The reference's values of the vector kausal calls `name`: its own
/// column, ngspice's device vector for a branchless element's current, or
/// the difference of two node voltages for `v(a,b)`.
fn reference_column(raw: &RawData, name: &str) -> Option<Vec<f64>> {
    let col = |n: &str| {
        raw.names
            .iter()
            .position(|m| m == n)
            .map(|k| raw.data[k].clone())
    };
    if let Some(c) = col(name) {
        return Some(c);
    }
    if let Some(c) = nested_current(name).and_then(|n| col(&n)) {
        return Some(c);
    }
    if let Some(d) = device_vector(name) {
        // ngspice writes it as `i(@r1[i])` (older versions: `@r1[i]`).
        return col(&format!("i({d})")).or_else(|| col(&d));
    }
    let (a, b) = name
        .strip_prefix("v(")?
        .strip_suffix(')')?
        .split_once(',')?;
    let node = |n: &str| {
        let n = n.trim();
        if n == "0" || n.eq_ignore_ascii_case("gnd") {
            Some(vec![0.0; raw.time.len()])
        } else {
            col(&format!("v({n})"))
        }
    };
    let (va, vb) = (node(a)?, node(b)?);
    Some(va.iter().zip(&vb).map(|(x, y)| x - y).collect())
}

/// [`run_ngspice`] with a given program (tests use stand-ins).
pub fn run_program(
    program: &str,
    path: &Path,
    tol: Option<RefTol>,
) -> Result<RawData, ValidateError> {
    let extra = tol.map(tight_options);
    exec(program, path, extra.as_deref()).map(|r| r.raw)
}

/// One ngspice process: its data, its whole output and its wall time.
pub struct Execution {
    pub raw: RawData,
    pub output: String,
    pub wall: std::time::Duration,
    /// Peak resident memory of the ngspice process, in bytes.
    pub peak: Option<u64>,
}

/// Run `program -b` on `path` with `extra` (an `.options` line) before `.end`.
pub fn exec(program: &str, path: &Path, extra: Option<&str>) -> Result<Execution, ValidateError> {
    exec_within(program, path, extra, ngspice_time_limit())
}

/// [`exec`], stopping the run after `limit`.
pub fn exec_within(
    program: &str,
    path: &Path,
    extra: Option<&str>,
    limit: std::time::Duration,
) -> Result<Execution, ValidateError> {
    // Bytes that are not UTF-8 can only be in comments of a netlist that
    // kausal read; ngspice gets them as U+FFFD.
    let text = crate::io::read_netlist(path)
        .map(|b| String::from_utf8_lossy(&b).into_owned())
        .map_err(|e| ValidateError::Io(format!("{}: {e}", path.display())))?;
    let dir = crate::io::ScratchDir::new().map_err(|e| ValidateError::Io(e.to_string()))?;
    let net = dir.path().join("netlist.cir");
    let rawp = dir.path().join("out.raw");
    std::fs::write(&net, prepare_netlist(path, &text, extra))
        .map_err(|e| ValidateError::Io(e.to_string()))?;
    // ngspice reads `.spiceinit` from its working directory: the netlist's
    // own (`set ngbehavior=ps`, PSpice's syntax) goes with it.
    let init = path.parent().map(|d| d.join(".spiceinit"));
    if let Some(init) = init.filter(|p| p.is_file()) {
        std::fs::copy(&init, dir.path().join(".spiceinit"))
            .map_err(|e| ValidateError::Io(format!("{}: {e}", init.display())))?;
    }
    let program = program.to_string();
    let started = std::time::Instant::now();
    let (output, peak) = crate::io::run_child_measured(
        Command::new(&program)
            .arg("-b")
            .arg("-r")
            .arg(&rawp)
            .arg(&net)
            .current_dir(dir.path())
            .env("SPICE_ASCIIRAWFILE", "0"),
        limit,
    )
    .map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => ValidateError::Missing {
            program: program.clone(),
        },
        std::io::ErrorKind::TimedOut => ValidateError::TimedOut {
            seconds: limit.as_secs(),
            reltol: extra
                .and_then(|x| x.split_whitespace().find(|w| w.starts_with("reltol=")))
                .unwrap_or("its defaults")
                .to_string(),
        },
        _ => ValidateError::Io(format!("{program}: {e}")),
    })?;
    let wall = started.elapsed();
    let mut full = String::from_utf8_lossy(&output.stdout).into_owned();
    full.push_str(&String::from_utf8_lossy(&output.stderr));
    let log = {
        let s = &full;
        let lines: Vec<&str> = s.lines().filter(|l| !l.trim().is_empty()).collect();
        let start = lines.len().saturating_sub(20);
        lines[start..].join("\n")
    };
    if !output.status.success() {
        return Err(ValidateError::Failed {
            status: output.status.to_string(),
            output: log,
        });
    }
    let bytes = std::fs::read(&rawp).map_err(|_| ValidateError::NoData {
        reason: "no raw file".into(),
        output: log.clone(),
    })?;
    if bytes.is_empty() {
        return Err(ValidateError::NoData {
            reason: "the raw file is empty".into(),
            output: log,
        });
    }
    let raw = raw::parse(&bytes).map_err(ValidateError::Malformed)?;
    if raw.time.is_empty() {
        return Err(ValidateError::NoData {
            reason: "no time points".into(),
            output: log,
        });
    }
    Ok(Execution {
        raw,
        output: full,
        wall,
        peak,
    })
}

/// How one signal compares.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct SignalReport {
    pub name: String,
    pub max_abs: f64,
    /// Max error over the reference's peak-to-peak range.
    pub max_norm: f64,
    pub rms: f64,
    pub worst_time: f64,
    /// The normalization used (range, or a floor for constant signals).
    pub scale: f64,
    /// The same for ngspice's default run against the reference.
    pub ngspice_default_norm: Option<f64>,
    pub pass: bool,
    /// For a failing signal: how much later (negative: earlier) kausal's
    /// waveform takes the reference's value at the worst point, when it
    /// does within [`EDGE_POINTS`] points of it (an edge whose timing differs).
    pub shift: Option<f64>,
}

/// Compare `test` with `reference` at the reference's points (both on the
/// same time axis).
pub fn compare(
    name: &str,
    reference: &[f64],
    test: &[f64],
    time: &[f64],
    tol: f64,
) -> SignalReport {
    let (lo, hi) = reference
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    let peak = reference.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let range = hi - lo;
    // A constant signal is compared relative to its level, and no scale is
    // below an absolute floor (1 nV / 1 nA): a signal that is zero but for
    // rounding (a range of 2e-16) would otherwise be its own scale, and
    // kausal's rounding would fail it at a normalized error of 1.
    let scale = if range > 1e-9 * peak && range > 0.0 {
        range
    } else {
        peak
    }
    .max(1e-9);
    let mut max_abs = 0.0f64;
    let mut worst = 0;
    let mut sq = 0.0;
    for (k, (r, t)) in reference.iter().zip(test).enumerate() {
        let e = (r - t).abs();
        let e = if e.is_nan() { f64::INFINITY } else { e };
        if e > max_abs {
            max_abs = e;
            worst = k;
        }
        sq += e * e;
    }
    let n = reference.len().max(1) as f64;
    let max_norm = max_abs / scale;
    SignalReport {
        name: name.to_string(),
        max_abs,
        max_norm,
        rms: (sq / n).sqrt(),
        worst_time: time.get(worst).copied().unwrap_or(0.0),
        scale,
        ngspice_default_norm: None,
        pass: max_norm <= tol,
        shift: None,
    }
}

/// Linear interpolation of `(t, y)` at `x` inside the range (no extrapolation).
pub fn interp(t: &[f64], y: &[f64], x: f64) -> Option<f64> {
    if t.is_empty() || x < t[0] || x > t[t.len() - 1] {
        return None;
    }
    let k = t.partition_point(|&v| v < x);
    if k < t.len() && t[k] == x {
        return Some(y[k]);
    }
    let (t0, t1, y0, y1) = (t[k - 1], t[k], y[k - 1], y[k]);
    Some(y0 + (y1 - y0) * (x - t0) / (t1 - t0))
}

/// A full validation of one netlist.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Report {
    pub netlist: String,
    pub tol: f64,
    pub ref_reltol: f64,
    /// The reference used Gear's method (the trapezoidal rule failed).
    pub ref_gear: bool,
    /// The reference's absolute tolerances (see [`AbsTol`]).
    pub ref_abstol: f64,
    pub ref_vntol: f64,
    pub ref_chgtol: f64,
    pub signals: Vec<SignalReport>,
    /// Set where every tight ngspice run failed and the reference is
    /// kausal's own tight run, cross-checked by ngspice's default run.
    pub fallback: Option<Fallback>,
    /// Hard breakpoints the reference did not step on.
    pub missed_breakpoints: Vec<f64>,
    pub pass: bool,
    #[serde(skip)]
    pub reference: RawData,
    #[serde(skip)]
    pub kausal: Waveforms,
}

/// Options of [`validate`].
#[derive(Clone, Debug)]
pub struct Options {
    pub tol: f64,
    pub ref_reltol: f64,
    pub sim: sim::Options,
    /// Also run ngspice at its defaults and report its error.
    pub ngspice_default: bool,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            tol: 1e-3,
            ref_reltol: 1e-8,
            sim: sim::Options::default(),
            ngspice_default: true,
        }
    }
}

/// The reference tolerance a netlist asks for in a comment
/// (`* kausal-validate: ref-tol=3e-9`), for circuits whose trapezoidal
/// reference drifts (long oscillations).
pub fn netlist_ref_tol(text: &str) -> Option<f64> {
    netlist_validate_setting(text, "ref-tol=")
}

/// The longest step a netlist asks the reference run to take, in a comment
/// (`* kausal-validate: ref-tmax=2n`): for circuits whose edges ngspice
/// places late at any tolerance it can reach (its step control lets the
/// trapezoidal rule's error through on regenerative switching), and where a
/// capped step converges.
pub fn netlist_ref_tmax(text: &str) -> Option<f64> {
    netlist_validate_setting(text, "ref-tmax=")
}

/// The absolute current tolerance a netlist asks the reference run to use
/// instead of 1e-15, in a comment (`* kausal-validate: ref-abstol=1e-12`):
/// for circuits where ngspice cannot take a step at 1e-15 ("timestep too
/// small" from the first steps, at every reltol).
pub fn netlist_ref_abstol(text: &str) -> Option<f64> {
    netlist_validate_setting(text, "ref-abstol=")
}

fn netlist_validate_setting(text: &str, key: &str) -> Option<f64> {
    text.lines().find_map(|l| {
        let rest = l
            .trim_start()
            .strip_prefix('*')?
            .trim_start()
            .strip_prefix("kausal-validate:")?;
        rest.split_whitespace()
            .find_map(|kv| kv.strip_prefix(key))
            .and_then(crate::front::expr::parse_number)
    })
}

/// The reference run: at the requested tolerance, or (when ngspice gives up,
/// "timestep too small") at ten and a hundred times looser; then the same
/// with Gear's method, whose damping gets through where the trapezoidal
/// rule's ringing keeps cutting the step; all of that at each rung of
/// [`AbsTol::LADDER`] in turn.
/// `tran` is a `.tran` line replacing the netlist's and `.options` lines
/// overriding the tight ones, or empty.
fn reference_run_with(
    path: &Path,
    reltol: f64,
    saves: &str,
    tran: &str,
) -> Result<(RawData, RefTol), ValidateError> {
    // The rungs share one time limit: past it, the fallback reference.
    let deadline = std::time::Instant::now() + ngspice_time_limit();
    let mut last = None;
    for (abs, gear, k) in AbsTol::LADDER.into_iter().flat_map(|a| {
        [false, true]
            .into_iter()
            .flat_map(move |g| (0..3).map(move |k| (a, g, k)))
    }) {
        let tol = RefTol {
            reltol: reltol * 10f64.powi(k),
            gear,
            abs,
        };
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        if left.is_zero() {
            break;
        }
        match run_ngspice_within(path, Some(tol), &format!("{saves}{tran}"), left) {
            Ok(r) => return Ok((r, tol)),
            Err(
                e @ (ValidateError::Failed { .. }
                | ValidateError::NoData { .. }
                | ValidateError::TimedOut { .. }),
            ) => last = Some(e),
            Err(e) => return Err(e),
        }
    }
    Err(last.unwrap_or(ValidateError::TimedOut {
        seconds: ngspice_time_limit().as_secs(),
        reltol: format!("reltol={reltol:e} and looser"),
    }))
}

/// The reference used where no tight ngspice run finishes.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Fallback {
    /// Why ngspice's tight runs gave none (the last one's error).
    pub why: String,
    /// kausal's relative and absolute (voltage) tolerances in the reference run.
    pub rtol: f64,
    pub atol: f64,
    /// How close ngspice's default run must come to the reference, on every
    /// signal, for it to count: ten times the test's tolerance, as ngspice's
    /// default run is itself within about 1e-2 of a tight reference on most
    /// of the corpus (VALIDATION.md), not within 1e-3.
    pub cross_tol: f64,
}

/// One line of why ngspice gave no data: its "timestep too small" line, or
/// the last line it wrote.
fn short_reason(e: &ValidateError) -> String {
    match e {
        ValidateError::Failed { status, output }
        | ValidateError::NoData {
            reason: status,
            output,
        } => {
            let line = output
                .lines()
                .find(|l| l.contains("too small"))
                .or_else(|| output.lines().rev().find(|l| !l.trim().is_empty()))
                .unwrap_or("");
            format!("{status}: {}", line.trim())
        }
        e => e.to_string(),
    }
}

/// How much tighter than the run under test kausal's reference run is.
const FALLBACK_TIGHTER: f64 = 1e-2;

/// kausal at a hundredth of the tested tolerances, at the points of
/// ngspice's default run `d` (within TSTOP): the reference where ngspice's
/// tight runs all fail (`why`).
fn kausal_reference(
    sorted: &Sorted,
    opts: &Options,
    names: &[String],
    d: &RawData,
    why: &ValidateError,
) -> Result<(RawData, Fallback), ValidateError> {
    let tstop = sim::tran_of(&sorted.elaborated.circuit)?.tstop;
    let (atol_v, _) = sim::atol_pair(&opts.sim, &sorted.elaborated.circuit);
    let rtol = sim::run_rtol(&opts.sim, &sorted.elaborated.circuit) * FALLBACK_TIGHTER;
    let atol = atol_v * FALLBACK_TIGHTER;
    let time: Vec<f64> = d.time.iter().map(|&t| t.min(tstop)).collect();
    let so = sim::Options {
        rtol: Some(rtol),
        atol: Some(atol),
        probes: names.to_vec(),
        times: Some(time.clone()),
        // A fixed step has no tolerance to tighten.
        method: opts.sim.method.filter(|m| !m.is_fixed_step()),
        ..opts.sim.clone()
    };
    let w = sim::simulate(sorted, &so)?;
    let data = (0..names.len())
        .map(|k| {
            time.iter()
                .map(|&t| interp(&w.time, &w.data[k], t).unwrap_or(f64::NAN))
                .collect()
        })
        .collect();
    let fallback = Fallback {
        why: short_reason(why),
        rtol,
        atol,
        cross_tol: 10.0 * opts.tol,
    };
    Ok((
        RawData {
            title: d.title.clone(),
            names: names.to_vec(),
            time,
            data,
        },
        fallback,
    ))
}

/// Validate a sorted netlist read from `path` against ngspice.
pub fn validate(path: &Path, sorted: &Sorted, opts: &Options) -> Result<Report, ValidateError> {
    let text = crate::io::read_netlist(path)
        .ok()
        .map(|b| String::from_utf8_lossy(&b).into_owned())
        .unwrap_or_default();
    let asked = netlist_ref_tol(&text).unwrap_or(opts.ref_reltol);
    let names: Vec<String> = sim::outputs(sorted, &opts.sim.probes)?
        .into_iter()
        .map(|o| o.0)
        .collect();
    let saves = device_saves(&names);
    let tran_line = match (netlist_ref_tmax(&text), &sorted.elaborated.circuit.tran) {
        (Some(tmax), Some(t)) => format!(
            ".tran {:e} {:e} {:e} {:e}{}\n",
            t.tstep,
            t.tstop,
            t.tstart,
            tmax,
            if t.uic { " uic" } else { "" }
        ),
        _ => String::new(),
    };
    // A later `.options` line overrides the tight options' ABSTOL.
    let abstol_line = netlist_ref_abstol(&text)
        .map(|a| format!(".options abstol={a:e}\n"))
        .unwrap_or_default();
    let tried = reference_run_with(path, asked, &saves, &format!("{tran_line}{abstol_line}"));
    let mut default_run = None;
    let (reference, ref_tol, fallback) = match tried {
        Ok((raw, tol)) => (raw, tol, None),
        Err(
            e @ (ValidateError::Failed { .. }
            | ValidateError::NoData { .. }
            | ValidateError::TimedOut { .. }),
        ) => {
            // ngspice's defaults run where its tight runs do not: kausal's
            // own tight run is the reference, on the default run's points,
            // and the default run is its cross-check.
            let Ok(d) = run_ngspice_saving(path, None, &saves) else {
                return Err(e);
            };
            let (raw, fb) = kausal_reference(sorted, opts, &names, &d, &e)?;
            default_run = Some(d);
            (raw, RefTol::default(), Some(fb))
        }
        Err(e) => return Err(e),
    };
    let ref_reltol = ref_tol.reltol;
    // kausal at ngspice's own time points, and just before each source
    // corner the reference steps on: a signal that jumps there (an inductor
    // voltage under a current ramp) is compared with either one-sided value.
    let sys = sorted.system();
    let tran = sim::tran_of(&sorted.elaborated.circuit)?.clone();
    let delta = 1e-9 * tran.tstop;
    // The reference's point at each corner it stepped on (to within delta:
    // ngspice's time can be the corner plus an ulp, 1.3800000000000001e-7
    // for a PWL corner at 1.38e-7, and a capacitor across the source then
    // failed i(V1) by its whole jump).
    // A corner it did not step on is reported (`missed`).
    let mut corners = Vec::new();
    let mut missed = Vec::new();
    for b in sys
        .sources
        .values()
        .flat_map(|s| s.wave.breakpoints(tran.tstop))
    {
        let k = reference.time.partition_point(|&t| t < b - delta);
        match reference.time.get(k).filter(|&&t| (t - b).abs() <= delta) {
            Some(&t) => corners.push(t),
            None => missed.push(b),
        }
    }
    corners.sort_by(f64::total_cmp);
    corners.dedup();
    // ngspice's last point can be TSTOP plus an ulp: kausal's value there is
    // the one at TSTOP (kausal stops at TSTOP and does not extrapolate).
    let within = |t: f64| {
        if t > tran.tstop && t - tran.tstop <= delta {
            tran.tstop
        } else {
            t
        }
    };
    let mut times: Vec<f64> = reference.time.iter().map(|&t| within(t)).collect();
    times.extend(corners.iter().map(|&b| b - delta).filter(|&t| t > 0.0));
    times.sort_by(f64::total_cmp);
    times.dedup();
    let mut so = opts.sim.clone();
    so.probes = names.clone();
    so.times = Some(times.clone());
    let mut w = sim::simulate(sorted, &so)?;
    // Switch events: kausal locates each crossing; ngspice changes a
    // switch's state at one of its own time points (early, after a rejected
    // step, or late), so at the reference's points next to an event either
    // of kausal's one-sided values is taken, as at a source corner. The run
    // is repeated with those values on its grid.
    let events: Vec<f64> = w.events.iter().map(|e| e.t).collect();
    if !events.is_empty() {
        times.extend(events.iter().flat_map(|&t| [t - delta, t + delta]));
        times.retain(|&t| t >= 0.0 && t <= tran.tstop);
        times.sort_by(f64::total_cmp);
        times.dedup();
        so.times = Some(times);
        w = sim::simulate(sorted, &so)?;
    }
    // The event next to each reference point: within twice the longest of
    // the reference's steps around it (ngspice's steps shrink after the
    // step its switch changed in, and may be rejected across it).
    let rt = &reference.time;
    let window = |e: f64| {
        let at = rt.partition_point(|&x| x < e);
        (at.saturating_sub(5)..(at + 5).min(rt.len().saturating_sub(1)))
            .map(|j| rt[j + 1] - rt[j])
            .fold(0.0f64, f64::max)
            * 2.0
    };
    let event_near = |i: usize| -> Option<f64> {
        let t = rt[i];
        let k = events.partition_point(|&e| e < t);
        [k.checked_sub(1), Some(k)]
            .into_iter()
            .flatten()
            .filter_map(|j| events.get(j).copied())
            .find(|&e| (t - e).abs() <= window(e))
    };
    if default_run.is_none() && opts.ngspice_default {
        default_run = run_ngspice_saving(path, None, &saves).ok();
    }
    let mut signals = Vec::new();
    for (k, name) in names.iter().enumerate() {
        let r = &reference_column(&reference, name)
            .ok_or_else(|| ValidateError::NoVector(name.clone()))?;
        // Both on the reference's points (kausal evaluated there); at a
        // corner, the closer of kausal's two one-sided values.
        let test: Vec<f64> = reference
            .time
            .iter()
            .zip(r)
            .enumerate()
            .map(|(i, (&t, &rv))| {
                let at = interp(&w.time, &w.data[k], within(t)).unwrap_or(f64::NAN);
                if let Some(e) = event_near(i) {
                    let closest = [e - delta, e + delta]
                        .into_iter()
                        .filter_map(|x| interp(&w.time, &w.data[k], x))
                        .chain([at])
                        .min_by(|a, b| (a - rv).abs().total_cmp(&(b - rv).abs()));
                    return closest.unwrap_or(at);
                }
                if corners.binary_search_by(|b| b.total_cmp(&t)).is_ok()
                    && let Some(before) = interp(&w.time, &w.data[k], t - delta)
                    && (before - rv).abs() < (at - rv).abs()
                {
                    return before;
                }
                at
            })
            .collect();
        let mut rep = compare(name, r, &test, &reference.time, opts.tol);
        if !rep.pass
            && let Some(i) = reference.time.iter().position(|&t| t == rep.worst_time)
        {
            rep.shift = edge_shift(&w.time, &w.data[k], rep.worst_time, r[i]);
        }
        if let Some(d) = &default_run
            && let Some(dcol) = reference_column(d, name)
        {
            // ngspice's default run, linearly interpolated onto the reference.
            let vals: Vec<(f64, f64)> = reference
                .time
                .iter()
                .zip(r)
                .filter_map(|(&t, &rv)| interp(&d.time, &dcol, t).map(|v| (rv, v)))
                .collect();
            let (rr, dd): (Vec<f64>, Vec<f64>) = vals.into_iter().unzip();
            let c = compare(name, &rr, &dd, &reference.time, opts.tol);
            rep.ngspice_default_norm = Some(c.max_abs / rep.scale);
        }
        signals.push(rep);
    }
    // Against the fallback, kausal's agreement with itself says nothing of
    // the model: ngspice's default run must confirm the reference too.
    if let Some(f) = &fallback {
        for s in &mut signals {
            s.pass &= s.ngspice_default_norm.is_some_and(|d| d <= f.cross_tol);
        }
    }
    let pass = signals.iter().all(|s| s.pass);
    Ok(Report {
        netlist: path.display().to_string(),
        tol: opts.tol,
        ref_reltol,
        ref_gear: ref_tol.gear,
        ref_abstol: ref_tol.abs.abstol,
        ref_vntol: ref_tol.abs.vntol,
        ref_chgtol: ref_tol.abs.chgtol,
        fallback,
        signals,
        missed_breakpoints: missed,
        pass,
        reference,
        kausal: w,
    })
}

/// Points either side of the worst one searched for an edge's shift.
const EDGE_POINTS: usize = 500;

/// The time nearest `at` (within [`EDGE_POINTS`] points of it) where `(time, y)`
/// crosses `value`, less `at`.
fn edge_shift(time: &[f64], y: &[f64], at: f64, value: f64) -> Option<f64> {
    let i = time.partition_point(|&t| t < at);
    let lo = i.saturating_sub(EDGE_POINTS);
    let hi = (i + EDGE_POINTS).min(time.len().saturating_sub(1));
    (lo..hi)
        .filter_map(|j| {
            let (a, b) = (y[j] - value, y[j + 1] - value);
            (a * b <= 0.0 && a != b).then(|| time[j] + (time[j + 1] - time[j]) * a / (a - b) - at)
        })
        .min_by(|a, b| a.abs().total_cmp(&b.abs()))
}

fn sci(x: f64) -> String {
    if x == 0.0 {
        "0".into()
    } else {
        format!("{x:.2e}")
    }
}

/// The table's first line: what kausal was compared with.
fn reference_line(r: &Report) -> String {
    if let Some(f) = &r.fallback {
        return format!(
            "{}: kausal (default settings) against kausal at rtol={} atol={} V, \
             cross-checked by ngspice's default run (each signal within {}): \
             no tight ngspice run finished ({})\n",
            r.netlist,
            sci(f.rtol),
            sci(f.atol),
            sci(f.cross_tol),
            f.why
        );
    }
    let abs = if r.ref_vntol > AbsTol::TIGHT.vntol {
        format!(
            " and ngspice's default abstol={:e} vntol={:e} chgtol={:e} (at tighter ones its steps collapsed)",
            r.ref_abstol, r.ref_vntol, r.ref_chgtol
        )
    } else if r.ref_abstol > AbsTol::TIGHT.abstol {
        format!(
            " and abstol={:e} (at 1e-15 its steps collapsed)",
            r.ref_abstol
        )
    } else {
        String::new()
    };
    let gear = if r.ref_gear {
        " with method=gear (the trapezoidal rule gave up)"
    } else {
        ""
    };
    format!(
        "{}: kausal (default settings) against ngspice at reltol={:e}{abs}{gear}\n",
        r.netlist, r.ref_reltol
    )
}

/// The report as a table, with a verdict.
pub fn table(r: &Report) -> String {
    let mut out = reference_line(r);
    let w = r
        .signals
        .iter()
        .map(|s| s.name.len())
        .max()
        .unwrap_or(6)
        .max(6);
    out.push_str(&format!(
        "  {:<w$}  {:>10}  {:>10}  {:>10}  {:>12}  {:>14}  {}\n",
        "signal", "max |err|", "max norm", "rms", "worst at (s)", "ngspice dflt", "verdict"
    ));
    for s in &r.signals {
        let dflt = match s.ngspice_default_norm {
            Some(d) if d > s.max_norm && r.fallback.is_none() => {
                format!("{} (kausal better)", sci(d))
            }
            Some(d) => sci(d),
            None => "-".into(),
        };
        out.push_str(&format!(
            "  {:<w$}  {:>10}  {:>10}  {:>10}  {:>12}  {:>14}  {}\n",
            s.name,
            sci(s.max_abs),
            sci(s.max_norm),
            sci(s.rms),
            sci(s.worst_time),
            dflt,
            if s.pass { "ok" } else { "FAIL" }
        ));
    }
    let span = r.reference.time.last().copied().unwrap_or(0.0);
    for s in r.signals.iter().filter(|s| !s.pass) {
        if let Some(d) = s.shift {
            out.push_str(&format!(
                "  note: kausal's {} takes the reference's worst-point value {} s {} ({} of the run): where that is an edge, its timing is all that differs\n",
                s.name,
                sci(d.abs()),
                if d > 0.0 { "later" } else { "earlier" },
                sci(d.abs() / span.max(f64::MIN_POSITIVE)),
            ));
        }
    }
    if !r.missed_breakpoints.is_empty() {
        let list: Vec<String> = r.missed_breakpoints.iter().map(|t| sci(*t)).collect();
        out.push_str(&format!(
            "  note: ngspice did not step on the source corners at {}\n",
            list.join(", ")
        ));
    }
    if let Some(f) = &r.fallback {
        let off = r
            .signals
            .iter()
            .map(|s| s.ngspice_default_norm.unwrap_or(f64::INFINITY))
            .fold(0.0, f64::max);
        out.push_str(&format!(
            "  note: ngspice's default run is at most {} off the reference: {}\n",
            sci(off),
            if off <= f.cross_tol {
                "confirmed"
            } else {
                "NOT confirmed, so a signal it is further off fails"
            }
        ));
    }
    let worst = r.signals.iter().map(|s| s.max_norm).fold(0.0, f64::max);
    out.push_str(&format!(
        "verdict: {} (worst normalized error {} against tolerance {})\n",
        if r.pass { "pass" } else { "FAIL" },
        sci(worst),
        sci(r.tol)
    ));
    out
}

/// Where the SVG plot of one signal goes.
pub fn plot_path(dir: &Path, netlist: &Path, signal: &str) -> PathBuf {
    let stem = netlist
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let clean: String = signal
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '.' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    dir.join(format!("{stem}_{clean}.svg"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A step that kausal takes 2e-3 s before the reference: the worst
    /// point's value is kausal's 2e-3 s earlier; a level offset without a
    /// crossing nearby has none.
    #[test]
    fn an_edge_shift_is_measured() {
        let time: Vec<f64> = (0..=1000).map(|k| k as f64 * 1e-3).collect();
        let step = |t: f64, at: f64| ((t - at) / 1e-3).clamp(0.0, 1.0);
        let kausal: Vec<f64> = time.iter().map(|&t| step(t, 0.498)).collect();
        let shift = edge_shift(&time, &kausal, 0.5005, step(0.5005, 0.5)).expect("crosses");
        assert!((shift + 2e-3).abs() < 1e-9, "{shift}");
        let flat = vec![1.0; time.len()];
        assert_eq!(edge_shift(&time, &flat, 0.5, 0.5), None);
    }

    /// A control script's `quit` would end ngspice before it writes the raw
    /// file: it is left out, and the rest of the script kept.
    #[test]
    fn a_control_blocks_quit_is_left_out() {
        let text = "t\nV1 a 0 1\n.control\nrun\n  QUIT\n.endc\n.end\n";
        let out = prepare_netlist(Path::new("t.cir"), text, None);
        assert_eq!(out, "t\nV1 a 0 1\n.control\nrun\n.endc\n.end\n");
        // Outside a control block the word is a node or an element's name.
        let text = "t\nquit a 0 1\n.end\n";
        assert!(prepare_netlist(Path::new("t.cir"), text, None).contains("quit a 0 1"));
    }

    /// A source two subcircuits deep has ngspice's letter at every level;
    /// at the top level and one level deep the names are the same.
    #[test]
    fn nested_source_currents_are_named_as_ngspice_names_them() {
        assert_eq!(
            nested_current("i(v.x1.x4.v1)").as_deref(),
            Some("i(v.x1.v.x4.v1)")
        );
        assert_eq!(
            nested_current("i(e.xa.xb.xc.e2)").as_deref(),
            Some("i(e.xa.e.xb.e.xc.e2)")
        );
        assert_eq!(nested_current("i(v.x1.v1)"), None);
        assert_eq!(nested_current("i(v1)"), None);
        assert_eq!(nested_current("v(x1.x4.n)"), None);
    }
}
