//! Simulation: the sorted system compiled to a tape and integrated by
//! diffsol (BDF by default), from a consistent DC start or `uic` initial
//! conditions, hitting source breakpoints exactly, with output on the
//! `.tran` grid.
//!
//! It knows the circuit (for names, initial conditions and outputs), the
//! schedule and diffsol; it does no IO.

use crate::diag::codes;
mod budget;
mod circuit;
mod dc;
mod driver;
mod events;
mod fixed;
mod grid;
mod ic;
mod modes;
pub mod ode;
pub mod output;
mod probe;
mod record;

use std::collections::HashMap;
use std::rc::Rc;
use std::time::{Duration, Instant};

use diffsol::{
    FaerSparseMat, LinearSolver, Matrix, NalgebraLU, NalgebraMat, OdeBuilder, OdeSolverMethod,
    OdeSolverProblem, OdeSolverState, OdeSolverStopReason,
};

use crate::build::Built;
use crate::elab::{Circuit, ElementKind, GROUND, Output};
use crate::ir::{EquationSystem, NameTable, VarId};
use crate::numeric::dense::{lu_factor, lu_solve};
use crate::numeric::newton::{self, Damping};
use crate::numeric::sparse_lu::CircuitLu;
use crate::numeric::{DenseLu, Factored, TripletLu, UnionFind};
use crate::pipeline::Sorted;
use crate::tape::{self, EvalError, Mode, OutputRef, Tape};
use ode::{CircuitOde, EvalCounts, HostVec, Regs};

pub use dc::DcStage;
use dc::*;
use driver::*;
pub use events::StateEvent;
use grid::*;
use modes::*;
use record::*;

pub use budget::DEFAULT_MAX_STEPS;
pub use driver::{atol_pair, run_rtol};
pub use grid::RowSink;
use probe::output_ref;
pub use probe::{output_list, outputs};

/// The integration method.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// Variable-order BDF (stiff; the default). Its orders above 2 are not
    /// A-stable: on an undamped oscillator (an LC tank) at a loose --rtol
    /// (1e-2) the amplitude can grow; tr-bdf2 cannot.
    Bdf,
    /// TR-BDF2, an L-stable SDIRK (stiff).
    TrBdf2,
    /// ESDIRK34 (stiff, 4th order).
    Esdirk34,
    /// Tsitouras 5(4), explicit (non-stiff circuits only).
    Tsit5,
    /// TR-BDF2 for circuits (kausal's own, small circuits): every output
    /// point is a step, and each state's error is measured against its
    /// largest magnitude so far, as circuit simulators measure it; fastest
    /// on switching circuits (rectifiers).
    Circuit,
    /// `circuit` with one BDF2 stage per step after the first (ngspice's
    /// gear of order 2) where TR-BDF2 has two: half the work of a step
    /// bound by TMAX or the output spacing; about as much as `circuit`
    /// where the error test sets the steps (its error constant is 5.5
    /// times TR-BDF2's).
    Gear2,
    /// Forward Euler at a fixed `--step` (seed 004; no error control).
    Euler,
    /// Runge–Kutta 2, the midpoint rule, at a fixed `--step` (seed 004).
    Rk2,
    /// Runge–Kutta 4 at a fixed `--step` (seed 004).
    Rk4,
}

impl Method {
    /// The name the command line gives it.
    pub fn name(self) -> &'static str {
        match self {
            Method::Bdf => "bdf",
            Method::TrBdf2 => "tr-bdf2",
            Method::Esdirk34 => "esdirk34",
            Method::Tsit5 => "tsit5",
            Method::Circuit => "circuit",
            Method::Gear2 => "gear2",
            Method::Euler => "euler",
            Method::Rk2 => "rk2",
            Method::Rk4 => "rk4",
        }
    }

    /// Seed 004's fixed-step methods, which take `--step` and have no error
    /// control.
    pub fn is_fixed_step(self) -> bool {
        matches!(self, Method::Euler | Method::Rk2 | Method::Rk4)
    }
}

pub use fixed::stability_bound;

/// Default relative tolerance: accurate by default (see README).
pub const DEFAULT_RTOL: f64 = 1e-7;
/// Up to this many states the integrator's matrices are dense (nalgebra);
/// above, sparse (faer) with a coloured Jacobian.
pub const DENSE_STATES: usize = 64;
/// Default absolute tolerance on voltage-like states (V).
pub const DEFAULT_ATOL_V: f64 = 1e-9;
/// Default absolute tolerance on current-like states (A).
pub const DEFAULT_ATOL_I: f64 = 1e-12;

/// Options of [`simulate`].
#[derive(Clone, Debug, Default)]
pub struct Options {
    pub method: Option<Method>,
    pub rtol: Option<f64>,
    pub atol: Option<f64>,
    /// Output every accepted step too, not only the `.tran` grid.
    pub all_steps: bool,
    /// Output vectors (`v(out)`, `i(v1)`); empty: `.print`/`.save`, else all.
    pub probes: Vec<String>,
    /// Called with the fraction done, now and then.
    pub progress: Option<fn(f64)>,
    /// Output at these times instead of the `.tran` grid.
    pub times: Option<Vec<f64>>,
    /// The most steps a run may take (default [`DEFAULT_MAX_STEPS`]).
    pub max_steps: Option<usize>,
    /// The longest step (in place of `.tran`'s TMAX).
    pub tmax: Option<f64>,
    /// The step of the fixed-step methods (euler, rk2, rk4).
    pub step: Option<f64>,
    /// The operating point's work limit in tape instructions (default
    /// 1.2·10^10, about a minute and a half).
    pub dc_work: Option<u64>,
    /// The time the operating point must end by (default 90 s from its
    /// start).
    pub dc_deadline: Option<std::time::Instant>,
}

/// Solver statistics of a run.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Stats {
    pub method: Option<Method>,
    pub states: usize,
    pub steps: usize,
    pub rejected: usize,
    /// Steps whose corrector (the integrator's Newton) failed to converge.
    pub newton_fails: usize,
    pub rhs_evals: usize,
    pub jac_mul_evals: usize,
    pub jacobians: usize,
    pub lu_factorizations: usize,
    pub restarts: usize,
    /// Restarts after repeated error-test failures (a kink in the history).
    pub rescues: usize,
    /// Where a stalled BDF run went on with ESDIRK34.
    pub switched_at: Option<f64>,
    /// The longest stable step of a fixed-step method on the circuit, where
    /// it was estimated (see [`stability_bound`]).
    pub stable_step: Option<f64>,
    pub wall: Duration,
    /// The operating point's stages in the order tried (empty: `uic` or
    /// held `.ic` nodes), and the one whose point the run started from.
    pub dc_stages: Vec<DcStage>,
    pub dc_found: Option<DcStage>,
    /// Assignments computed in `f` / at output points only / never.
    pub in_f: usize,
    pub at_outputs: usize,
    pub unused: usize,
}

/// The result: signals on a common time axis.
#[derive(Clone, Debug, Default)]
pub struct Waveforms {
    /// ngspice vector names (`v(out)`, `i(v1)`).
    pub names: Vec<String>,
    pub time: Vec<f64>,
    /// One column per name.
    pub data: Vec<Vec<f64>>,
    pub stats: Stats,
    /// What the run could not do as asked (an `.ic` it could not hold).
    pub warnings: Vec<crate::diag::Diagnostic>,
    /// The switches' changes of state, in time order.
    pub events: Vec<StateEvent>,
}

/// Why a simulation stopped. Errors of diffsol and of writing are kept as
/// they came (shared, so that the error stays `Clone`).
#[derive(Clone, Debug, thiserror::Error)]
pub enum SimError {
    #[error("the netlist has no `.tran` line")]
    NoTran { title: crate::diag::Span },
    #[error("unknown output vector `{0}`: write v(node), v(node1,node2) or i(element)")]
    UnknownProbe(String),
    #[error("{error}")]
    Eval { error: EvalError },
    #[error("`{name}` became {value} at t = {t:e} (computed by: {what})")]
    NonFinite {
        name: String,
        value: f64,
        t: f64,
        what: String,
    },
    #[error(
        "step size underflow at t = {t:e}; the fastest-changing state is `{state}` (= {value:e})"
    )]
    StepUnderflow { t: f64, state: String, value: f64 },
    #[error("the solver failed at t = {t:e}: {source}")]
    Solver {
        t: f64,
        source: std::rc::Rc<diffsol::DiffsolError>,
    },
    #[error(
        "--method circuit integrates circuits of at most {max} states (this one has {n}): use --method bdf"
    )]
    TooManyStates { n: usize, max: usize },
    #[error(
        "the run stopped making progress: {steps} steps reached t = {t:.4e} s of {tstop:.4e} s, with steps of {h:.2e} s{}{}",
        too_many_text(*max, *projected),
        held_text(*newton)
    )]
    TooManySteps {
        steps: usize,
        max: usize,
        t: f64,
        h: f64,
        tstop: f64,
        /// The steps the whole run would take at its recent pace, when
        /// that is what stopped it.
        projected: Option<f64>,
        /// The integrator's Newton failures and error-test failures since
        /// its last restart (diffsol's methods).
        newton: Option<(usize, usize)>,
    },
    #[error("no DC operating point: {reason}")]
    DcFailed { reason: DcFailure },
    /// The operating point with `.ic` nodes held failed: the diagnostic
    /// points at the held nodes' lines, beside whatever `cause` names.
    #[error("{cause}, with `{directive}` holding {}", held.iter().map(|h| h.1.as_str()).collect::<Vec<_>>().join(", "))]
    HeldDcFailed {
        directive: String,
        /// Each held node's line and `v(node) = value`.
        held: Vec<(crate::diag::Span, String)>,
        cause: Box<SimError>,
    },
    #[error(
        "no DC operating point: the DC Jacobian is singular where Newton stopped{}, though every node has a DC path to ground: a conductance vanishes there (junctions or transistors cut off, a switch open) or controlled sources cancel each other",
        weakest_text(at)
    )]
    /// Only where no node lacks a DC path: those are named by
    /// [`DcFailure::NoDcPath`] instead. `point`: the states where Newton
    /// stopped; `at`: the element whose state the Jacobian depends least on
    /// there, named once the operating point has failed for good.
    DcSingular {
        point: Option<std::rc::Rc<Vec<f64>>>,
        at: Option<String>,
    },
    #[error("cannot write the waveforms: {}{source}", path_prefix(path.as_deref()))]
    Write {
        /// The file, when the error is the writer's own (not the sink's).
        path: Option<std::path::PathBuf>,
        source: std::rc::Rc<std::io::Error>,
    },
    #[error(
        "{method} blew up at t = {t:.4e} s: `{state}` reached {value:.3e} with steps of {h:.4e} s{}",
        match bound {
            Some(b) => format!(", {:.2}× its stability bound {b:.4e} s on this circuit", h / b),
            None => String::new(),
        }
    )]
    BlewUp {
        method: &'static str,
        t: f64,
        state: String,
        value: f64,
        h: f64,
        bound: Option<f64>,
    },
    #[error("{0}")]
    FixedStep(String),
    #[error("{0}")]
    SwitchMethod(String),
    #[error(
        "`{condition}` in {element} flipped {flips} times in a row, each within {steps} steps of the last, up to t = {t:e}: its output drives its own input back across the threshold (a sliding mode), which no step can follow"
    )]
    Chatter {
        element: String,
        condition: String,
        flips: u32,
        steps: u64,
        t: f64,
    },
    #[error(
        "the Jacobian of the {} states is too dense to integrate: it has more than {:.1e} nonzero entries (kausal's limit){}",
        dense.states,
        dense.limit as f64,
        match &dense.block {
            Some((k, elements, n)) => format!("; algebraic loop {k} couples {n} of them, through {}", crate::back::listing::shortened(elements, crate::back::listing::ELEMENTS_SHOWN)),
            None => String::new(),
        }
    )]
    DenseJacobian { dense: tape::DensePattern },
    #[error("{what} is {value}; it must be {range}")]
    BadTolerance {
        what: &'static str,
        value: f64,
        range: &'static str,
    },
}

fn too_many_text(max: usize, projected: Option<f64>) -> String {
    match projected {
        Some(p) => format!(
            "; at that pace the run would take {p:.1e} steps, more than its budget of {max}"
        ),
        None => format!(", the whole of its budget of {max} steps"),
    }
}

/// Where the corrector's failures outnumber the error test's, it is the
/// integrator's Newton that holds the steps short, not the error control.
fn held_text(newton: Option<(usize, usize)>) -> String {
    match newton {
        Some((fails, rejected)) if fails > rejected && fails >= 10 => format!(
            "; the integrator's Newton failed {fails} times at longer steps (its error test {rejected} times): the steps are held short by a nonlinearity the corrector cannot follow, not by the error control"
        ),
        _ => String::new(),
    }
}

/// Why no DC operating point was found.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum DcFailure {
    /// No damped Newton step improves the point. `state`: the index of the
    /// state whose residual is largest there; `at`: what owns it, named
    /// once known.
    #[error("Newton stalled (residual {residual:.3e}{})", at_text(at))]
    Stalled {
        residual: f64,
        state: Option<usize>,
        at: Option<String>,
    },
    #[error("Newton did not converge (residual {residual:.3e}{})", at_text(at))]
    NoConvergence {
        residual: f64,
        state: Option<usize>,
        at: Option<String>,
    },
    /// The DC Jacobian is singular where these islands of nodes (named,
    /// with the elements that touch them) have no DC path to ground.
    #[error(
        "the DC Jacobian is singular: {}; use `.tran ... uic`, or give the node a DC path (a large resistor to ground)",
        islands_text(islands)
    )]
    NoDcPath {
        islands: Vec<(Vec<String>, Vec<String>)>,
    },
    /// Newton, continuation, GMIN and source stepping ran out of the
    /// operating point's work limit. `state`: where the first attempt's
    /// residual was largest, `at`: what owns it, named once known.
    #[error(
        "Newton, continuation, GMIN and source stepping found none within the operating point's work limit ({:.1e} tape instructions or {} s, whichever came first){}",
        *work as f64,
        dc::DC_MAX_TIME.as_secs(),
        at.as_ref().map_or_else(String::new, |e| format!("; Newton's first attempt left its largest residual at {e}"))
    )]
    WorkLimit {
        work: u64,
        state: Option<usize>,
        at: Option<String>,
    },
    /// Newton at the full sources was skipped (a test's switch).
    #[error("not tried (test)")]
    NotTried,
}

/// "`path`: " before a write error that names its file.
fn path_prefix(path: Option<&std::path::Path>) -> String {
    path.map_or_else(String::new, |p| format!("`{}`: ", p.display()))
}

/// The element a singular DC Jacobian depends least on, as words after it.
fn weakest_text(at: &Option<String>) -> String {
    at.as_ref()
        .map_or_else(String::new, |e| format!(" (it depends least on {e})"))
}

/// Where a failed Newton's residual is largest, as words after it.
fn at_text(at: &Option<String>) -> String {
    at.as_ref()
        .map_or_else(String::new, |e| format!(", largest at {e}"))
}

/// The first three islands of [`DcFailure::NoDcPath`] as a sentence.
fn islands_text(islands: &[(Vec<String>, Vec<String>)]) -> String {
    let text: Vec<String> = islands
        .iter()
        .take(3)
        .map(|(nodes, elems)| {
            let names: Vec<String> = nodes.iter().map(|n| format!("`{n}`")).collect();
            format!(
                "{} {} no DC path to ground (only {} {} {})",
                crate::back::listing::shortened(&names, 8),
                if nodes.len() == 1 { "has" } else { "have" },
                crate::back::listing::shortened(elems, 8),
                if elems.len() == 1 {
                    "connects"
                } else {
                    "connect"
                },
                if nodes.len() == 1 { "it" } else { "them" }
            )
        })
        .collect();
    text.join("; ")
}

impl crate::diag::ToDiagnostic for SimError {
    fn to_diagnostic(&self) -> crate::diag::Diagnostic {
        let (code, help) = match self {
            SimError::NoTran { .. } => (codes::NO_TRAN, "add `.tran TSTEP TSTOP`"),
            SimError::UnknownProbe(_) => (
                codes::UNKNOWN_PROBE,
                "see `kausal equations` for the circuit's nodes and elements",
            ),
            SimError::Eval { .. } => (
                codes::EVAL_FAILED,
                "check the elements of the loop for values that allow no solution",
            ),
            SimError::NonFinite { .. } => (
                codes::NON_FINITE,
                "an expression left its domain (division by zero, log of a negative number)",
            ),
            SimError::StepUnderflow { .. } => (
                codes::STEP_UNDERFLOW,
                "the circuit may be ill-posed there, or change faster than steps of TSTOP·1e-16 can follow (shorten TSTOP); try another --method or a looser --rtol",
            ),
            SimError::TooManySteps { .. } => (
                codes::NO_PROGRESS,
                "the circuit changes faster than the run can follow (a fast oscillation over a long TSTOP, or a lightly damped mode the steps must resolve: a shorter run names it in a K0409 warning); try --method esdirk34 or tr-bdf2, a looser --rtol, a shorter TSTOP, or raise --max-steps",
            ),
            SimError::Solver { .. } | SimError::TooManyStates { .. } => {
                (codes::SOLVER_FAILED, "try another --method")
            }
            SimError::DcFailed { .. } => (
                codes::DC_FAILED,
                "give initial conditions and use `.tran ... uic`",
            ),
            SimError::HeldDcFailed { .. } => (
                codes::DC_FAILED,
                "the operating point is solved with these nodes held at their values: check them, or use `.tran ... uic` to start from them instead",
            ),
            SimError::DcSingular { .. } => (
                codes::DC_FAILED,
                "give a `.nodeset` near the operating point, or initial conditions with `.tran ... uic`",
            ),
            SimError::Write { .. } => (codes::WRITE_FAILED, "check the output path and free space"),
            SimError::BadTolerance { .. } => (codes::BAD_TOLERANCE, "e.g. rtol 1e-6, atol 1e-9"),
            SimError::DenseJacobian { .. } => (
                codes::DENSE_JACOBIAN,
                "tearing this loop makes every state it reads depend on every other (`kausal sort` lists it); kausal does not yet integrate with node voltages as unknowns, whose Jacobian stays sparse",
            ),
            SimError::BlewUp { .. } => (
                codes::BLEW_UP,
                "shorten --step below the bound, or use an implicit method (bdf, tr-bdf2), whose steps are not bound by the fastest mode",
            ),
            SimError::FixedStep(_) => (
                codes::FIXED_STEP,
                "--step goes with --method euler, rk2 or rk4, which need it",
            ),
            SimError::SwitchMethod(_) => (
                codes::SWITCH_METHOD,
                "use --method bdf (the default), tr-bdf2, esdirk34 or tsit5",
            ),
            SimError::Chatter { .. } => (
                codes::CHATTER,
                "give the comparison hysteresis (an S switch with VH, or a threshold that moves with the output), or a continuous law (tanh) in place of the jump",
            ),
        };
        let d = crate::diag::Diagnostic::error(code, self.to_string()).with_help(help);
        match self {
            SimError::NoTran { title } => d.with_label(*title, "this netlist"),
            SimError::HeldDcFailed { held, .. } => held.iter().fold(d, |d, (span, what)| {
                d.with_label(*span, format!("held at {what}"))
            }),
            _ => d,
        }
    }
}

/// Prepare and run a simulation of a sorted circuit.
pub fn simulate(sorted: &Sorted, opts: &Options) -> Result<Waveforms, SimError> {
    simulate_rows(sorted, opts, None)
}

/// [`simulate`], handing each output row to `sink` as it is computed instead
/// of keeping it: memory stays bounded by the circuit, not the run. The
/// returned waveforms then hold the names and statistics only.
pub fn simulate_to(
    sorted: &Sorted,
    opts: &Options,
    sink: RowSink<'_>,
) -> Result<Waveforms, SimError> {
    simulate_rows(sorted, opts, Some(sink))
}

fn simulate_rows(
    sorted: &Sorted,
    opts: &Options,
    sink: Option<RowSink<'_>>,
) -> Result<Waveforms, SimError> {
    let prepared = prepare(sorted, opts)?;
    run_prepared(sorted, prepared, opts, sink)
}

/// A simulation ready to run: its options checked, its outputs resolved and
/// its tape compiled. Once it exists the simulation no longer reads the
/// schedule or the causalization, so a caller that owns the [`Sorted`] can
/// drop them (the bulk of a big circuit's memory after the system) before
/// the integrator allocates its own.
pub struct Prepared {
    start: Instant,
    tran: crate::elab::Tran,
    method: Method,
    list: Vec<Output>,
    switches: events::Switches,
    tape: Rc<Tape>,
}

/// The circuit's `.tran` card; K0400, pointing at the title line, without.
pub fn tran_of(c: &crate::elab::Circuit) -> Result<&crate::elab::Tran, SimError> {
    c.tran.as_ref().ok_or(SimError::NoTran {
        title: c.title_span,
    })
}

/// Check `opts` against the circuit and compile its tape.
pub fn prepare(sorted: &Sorted, opts: &Options) -> Result<Prepared, SimError> {
    let start = Instant::now();
    let c = &sorted.elaborated.circuit;
    let tran = tran_of(c)?.clone();
    // A tolerance out of range stalls the error control or voids it.
    if let Some(r) = opts.rtol
        && !(r > 0.0 && r < 1.0)
    {
        return Err(SimError::BadTolerance {
            what: "rtol",
            value: r,
            range: "in (0, 1)",
        });
    }
    if let Some(a) = opts.atol
        && !(a > 0.0 && a.is_finite())
    {
        return Err(SimError::BadTolerance {
            what: "atol",
            value: a,
            range: "finite and above 0",
        });
    }
    let method = opts.method.unwrap_or(Method::Bdf);
    match (method.is_fixed_step(), opts.step) {
        (true, None) => {
            return Err(SimError::FixedStep(format!(
                "--method {} has no error control: it needs --step (the step length, in seconds)",
                method.name()
            )));
        }
        (true, Some(h)) if !(h > 0.0 && h.is_finite()) => {
            return Err(SimError::FixedStep(format!(
                "--step {h} is not a step length above 0"
            )));
        }
        (false, Some(_)) => {
            return Err(SimError::FixedStep(format!(
                "--method {} chooses its own steps; --step is for euler, rk2 and rk4 (--tmax caps an adaptive method's steps)",
                method.name()
            )));
        }
        _ => {}
    }
    let sys = sorted.system();
    let list = output_list(c, &opts.probes)?;
    // The switches' controls are outputs too, after the user's.
    let (switch_list, controls) = events::Switches::of(c);
    let refs: Vec<OutputRef> = list
        .iter()
        .chain(&controls)
        .map(|o| output_ref(&sorted.built, o))
        .collect();
    // The B sources' comparisons are held and located as events where the
    // method locates events.
    let locates = !matches!(
        method,
        Method::Circuit | Method::Gear2 | Method::Euler | Method::Rk2 | Method::Rk4
    );
    let switches = events::Switches::new(switch_list, (list.len(), refs.len()), locates);
    if !switches.is_empty() {
        let why = if matches!(
            method,
            Method::Circuit | Method::Gear2 | Method::Euler | Method::Rk2 | Method::Rk4
        ) {
            Some(format!(
                "--method {} does not locate switch events",
                method.name()
            ))
        } else {
            None
        };
        if let Some(why) = why {
            return Err(SimError::SwitchMethod(why));
        }
    }
    let tape = Rc::new(tape::compile(sys, &sorted.schedule, &refs));
    Ok(Prepared {
        start,
        tran,
        method,
        list,
        switches,
        tape,
    })
}

/// Run a [`Prepared`] simulation of `sorted`, handing rows to `sink` when
/// there is one (as [`simulate_to`]).
pub fn run_prepared(
    sorted: &Sorted,
    p: Prepared,
    opts: &Options,
    sink: Option<RowSink<'_>>,
) -> Result<Waveforms, SimError> {
    run_ir(driver::Ir::Kept(sorted), p, opts, sink)
}

/// [`run_prepared`] for a caller that owns `sorted` and needs only its
/// sources and title afterwards: the equation system and the circuit are
/// released once the operating point is found ([`Sorted::release_ir`]),
/// before the integrator allocates, and `released` is called then (the
/// binary has its allocator return the freed memory to the system there). A
/// circuit with no states keeps them.
pub fn run_prepared_releasing(
    sorted: &mut Sorted,
    p: Prepared,
    opts: &Options,
    sink: Option<RowSink<'_>>,
    released: fn(),
) -> Result<Waveforms, SimError> {
    run_ir(driver::Ir::Released(sorted, released), p, opts, sink)
}

fn run_ir(
    ir: driver::Ir<'_>,
    p: Prepared,
    opts: &Options,
    sink: Option<RowSink<'_>>,
) -> Result<Waveforms, SimError> {
    // Values below f64's normal range are far below every tolerance, and
    // on Intel cores each operation on one costs a microcode assist.
    let _flush = crate::numeric::subnormal::flush_subnormals();
    let sorted = ir.sorted();
    let names = output_names(sorted, &p);
    let n = p.tape.states.len();
    let w = if n == 0 {
        algebraic(
            sorted,
            p.tape.clone(),
            &p.tran,
            &p.list,
            opts,
            &p.switches,
            sink,
        )?
    } else {
        check_method(p.method, n)?;
        let parts = driver::Parts {
            tape: p.tape.clone(),
            tran: &p.tran,
            outputs: &p.list,
            opts,
            method: p.method,
            switches: &p.switches,
        };
        if n <= DENSE_STATES {
            run::<NalgebraMat<f64>, NalgebraLU<f64>>(ir, &parts, sink)?
        } else {
            run::<FaerSparseMat<f64>, CircuitLu>(ir, &parts, sink)?
        }
    };
    Ok(finish(w, names, &p))
}

/// The ngspice names of `p`'s outputs.
fn output_names(sorted: &Sorted, p: &Prepared) -> Vec<String> {
    let c = &sorted.elaborated.circuit;
    p.list.iter().map(|o| c.output_name(o)).collect()
}

/// K0405 where the method cannot integrate `n` states.
fn check_method(method: Method, n: usize) -> Result<(), SimError> {
    if matches!(method, Method::Circuit | Method::Gear2) && n > DENSE_STATES {
        return Err(SimError::TooManyStates {
            n,
            max: DENSE_STATES,
        });
    }
    Ok(())
}

/// The run's waveforms with their names and the tape's statistics.
fn finish(mut w: Waveforms, names: Vec<String>, p: &Prepared) -> Waveforms {
    let tape = &p.tape;
    w.names = names;
    w.stats.method = Some(p.method);
    w.stats.states = tape.states.len();
    w.stats.in_f = tape.coverage.in_f;
    w.stats.at_outputs = tape.coverage.at_outputs;
    w.stats.unused = tape.coverage.unused;
    w.stats.wall = p.start.elapsed();
    w
}

#[cfg(test)]
mod tests {
    use super::*;

    thread_local! {
        pub(super) static SOURCES_ONLY: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
        pub(super) static IMAGE_ONLY: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
        pub(super) static CHARGED_IMAGE: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
    }

    /// The DC image (capacitors open, inductors shorted, its node voltages
    /// the unknowns of its loops) finds the operating point that Newton on
    /// the states finds, on a bipolar differential pair with junction
    /// charges and a CMOS stage whose gate capacitances and junctions form a
    /// loop, with its charges algebraic and with them its states; and the
    /// transient runs from it as from the states' point (fails when the
    /// image is not tried).
    #[test]
    fn the_dc_image_finds_the_states_operating_point() {
        let circuits = [
            "pair\nVCC vcc 0 12\nVEE vee 0 -12\nVIN in 0 SIN(0 10m 1k)\nRB1 in b1 1k\n\
             RB2 0 b2 1k\nQ1 c1 b1 e QN\nQ2 c2 b2 e QN\nRE e vee 11k\nRC1 vcc c1 10k\n\
             RC2 vcc c2 10k\nL1 c2 o 1m\nCL o 0 10n\nRL o 0 100k\n\
             .model QN NPN(IS=1e-15 BF=120 VAF=80 RB=100 RE=1 RC=10 CJE=1p CJC=0.5p TF=0.3n)\n\
             .tran 10u 2m\n.end\n",
            "cmos\nVDD vdd 0 5\nVIN in 0 PULSE(0 5 10n 1n 1n 20n 50n)\n\
             MP1 a in vdd vdd PM W=20u L=2u AD=100p AS=100p\nMN1 a in 0 0 NM W=8u L=2u AD=50p AS=50p\n\
             MP2 out a vdd vdd PM W=20u L=2u AD=100p AS=100p\nMN2 out a 0 0 NM W=8u L=2u AD=50p AS=50p\n\
             RF out a 100k\nCL out 0 50f\n\
             .model NM NMOS(LEVEL=3 VTO=0.8 KP=60u GAMMA=0.5 PHI=0.7 CJ=3e-4 CGSO=2e-10 CGDO=2e-10 TOX=30n)\n\
             .model PM PMOS(LEVEL=3 VTO=-0.9 KP=25u GAMMA=0.5 PHI=0.7 CJ=3e-4 CGSO=2e-10 CGDO=2e-10 TOX=30n)\n\
             .tran 1n 100n\n.end\n",
        ];
        for text in circuits {
            let sorted =
                crate::pipeline::sort_text("dc.cir", text.to_string(), &Default::default())
                    .ok()
                    .expect("sorts");
            let states = simulate(&sorted, &Options::default()).expect("from the states' point");
            for charged in [false, true] {
                IMAGE_ONLY.with(|c| c.set(true));
                CHARGED_IMAGE.with(|c| c.set(charged));
                let image = simulate(&sorted, &Options::default());
                IMAGE_ONLY.with(|c| c.set(false));
                CHARGED_IMAGE.with(|c| c.set(false));
                let image = image.expect("from the image's point");
                same_start(&states, &image, 1e-7);
            }
        }
    }

    /// A bipolar op-amp (a textbook µA741 as a follower) whose states'
    /// Newton, continuation, GMIN and source stepping find no operating
    /// point: the image with algebraic charges finds ngspice's (its `.op`)
    /// within a work limit of 10^7 instructions, where the image with
    /// charge states needs more.
    #[test]
    fn an_op_amp_finds_its_operating_point_with_algebraic_charges() {
        let text = std::fs::read_to_string(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("netlists/ua741_follower.cir"),
        )
        .unwrap();
        let sorted = crate::pipeline::sort_text("ua741.cir", text, &Default::default())
            .ok()
            .expect("sorts");
        let at = |w: &Waveforms, name: &str| {
            w.data[w.names.iter().position(|n| n == name).expect(name)][0]
        };
        // ngspice-39's `.op` of the same netlist.
        let ngspice = [
            ("v(out)", 3.272006e-4),
            ("v(n5)", -13.9319),
            ("v(n15)", -1.22422),
        ];
        for charged in [false, true] {
            CHARGED_IMAGE.with(|c| c.set(charged));
            let opts = Options {
                dc_work: Some(30_000_000),
                ..Default::default()
            };
            let run = simulate(&sorted, &opts);
            CHARGED_IMAGE.with(|c| c.set(false));
            match (charged, run) {
                (false, Ok(w)) => {
                    for (name, v) in ngspice {
                        assert!(
                            (at(&w, name) - v).abs() <= 1e-5 * v.abs().max(1e-3),
                            "{name}: {} against ngspice's {v}",
                            at(&w, name)
                        );
                    }
                }
                (false, Err(e)) => panic!("no operating point with algebraic charges: {e}"),
                (true, run) => assert!(
                    matches!(
                        run,
                        Err(SimError::DcFailed {
                            reason: DcFailure::WorkLimit { .. }
                        })
                    ),
                    "the charge states' image within the limit"
                ),
            }
        }
    }

    /// `a` and `b` start within `rel` of each signal's scale and end within
    /// 1e-3 of it.
    fn same_start(a: &Waveforms, b: &Waveforms, rel: f64) {
        {
            let (states, image) = (a, b);
            for (name, (a, b)) in states.names.iter().zip(states.data.iter().zip(&image.data)) {
                let scale = a.iter().fold(1e-3f64, |m, x| m.max(x.abs()));
                assert!(
                    (a[0] - b[0]).abs() <= rel * scale,
                    "{name} at t = 0: {} from the states, {} from the image",
                    a[0],
                    b[0]
                );
                let last = a.len().min(b.len()) - 1;
                assert!(
                    (a[last] - b[last]).abs() <= 1e-3 * scale,
                    "{name} at the end: {} from the states, {} from the image",
                    a[last],
                    b[last]
                );
            }
        }
    }

    /// Outputs that read few states come from the interpolant's values at a
    /// few nodes per step ([`StepPolynomial`]): the same numbers, to
    /// rounding, as interpolating the whole state at every point, for every
    /// solver (fails if an interpolant had a degree above five).
    #[test]
    fn few_read_states_interpolate_as_the_whole_state() {
        let mut text = String::from("ladder\nV1 n0 0 SIN(0 1 300)\n");
        for k in 1..=40 {
            text += &format!("R{k} n{} n{k} 1k\nC{k} n{k} 0 1u\n", k - 1);
        }
        text += ".tran 1u 10m\n.end\n";
        let sorted = crate::pipeline::sort_text("ladder.cir", text, &Default::default())
            .ok()
            .expect("sorts");
        for method in [Method::Bdf, Method::TrBdf2, Method::Esdirk34, Method::Tsit5] {
            let opts = |probes: Vec<String>| Options {
                method: Some(method),
                rtol: Some(1e-4),
                probes,
                ..Default::default()
            };
            let few =
                simulate(&sorted, &opts(vec!["v(n1)".into(), "v(n40)".into()])).expect("runs");
            let all = simulate(&sorted, &opts(Vec::new())).expect("runs");
            assert!(
                few.stats.steps * 20 < few.time.len(),
                "{method:?}: few points per step"
            );
            assert_eq!(few.time, all.time);
            for (name, col) in few.names.iter().zip(&few.data) {
                let k = all.names.iter().position(|n| n == name).expect("in all");
                for (i, (a, b)) in col.iter().zip(&all.data[k]).enumerate() {
                    assert!(
                        (a - b).abs() <= 1e-13,
                        "{method:?} {name} at {}: {a} from nodes, {b} interpolated",
                        few.time[i]
                    );
                }
            }
        }
    }

    /// Source stepping reaches the operating point that Newton at the full
    /// sources finds, on a zener in breakdown and a clamped inverting stage.
    #[test]
    fn source_stepping_reaches_the_operating_point() {
        let circuits = [
            "zener\nV1 in 0 DC 24\nR1 in out 100\nD1 0 out DZ\nC1 out 0 10u\nRL out 0 1k\n\
             .model DZ D(IS=1e-14 N=1 RS=1 CJO=10p BV=5.1 IBV=5m)\n.tran 10u 20u\n.end\n",
            "clamp\nV1 in 0 DC 2\nR1 in n 1k\nE1 out 0 0 n 1e5\nR2 n out 10k\nD1 n out DX\n\
             D2 out n DX\nC1 out 0 1n\n.model DX D(IS=1e-14 N=1 RS=1 CJO=1p)\n.tran 1u 2u\n.end\n",
        ];
        for text in circuits {
            let sorted =
                crate::pipeline::sort_text("dc.cir", text.to_string(), &Default::default())
                    .ok()
                    .expect("sorts");
            let direct = simulate(&sorted, &Options::default()).expect("direct");
            SOURCES_ONLY.with(|c| c.set(true));
            let stepped = simulate(&sorted, &Options::default());
            SOURCES_ONLY.with(|c| c.set(false));
            let stepped = stepped.expect("stepped");
            for (name, (a, b)) in direct
                .names
                .iter()
                .zip(direct.data.iter().zip(&stepped.data))
            {
                assert!(
                    (a[0] - b[0]).abs() <= 1e-9 * a[0].abs().max(1e-3),
                    "{name}: {} directly, {} by source stepping",
                    a[0],
                    b[0]
                );
            }
        }
    }
}
