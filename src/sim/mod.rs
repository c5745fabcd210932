//! Simulation: the sorted system compiled to a tape and integrated by
//! diffsol (BDF by default), from a consistent DC start or `uic` initial
//! conditions, hitting source breakpoints exactly, with output on the
//! `.tran` grid.
//!
//! It knows the circuit (for names, initial conditions and outputs), the
//! schedule and diffsol; it does no IO.

mod ic;
pub mod ode;
pub mod output;
mod trbdf2;

use std::collections::HashMap;
use std::rc::Rc;
use std::time::{Duration, Instant};

use diffsol::{
    FaerSparseMat, LinearSolver, Matrix, NalgebraLU, NalgebraMat, OdeBuilder, OdeSolverMethod,
    OdeSolverProblem, OdeSolverState, OdeSolverStopReason,
};

use crate::build::Built;
use crate::elab::{Circuit, ElementKind, GROUND, Output};
use crate::ir::{EquationSystem, VarId};
use crate::numeric::dense::{lu_factor, lu_solve};
use crate::numeric::newton::{self, Damping};
use crate::numeric::sparse_lu::CircuitLu;
use crate::numeric::{DenseLu, Factored, TripletLu, UnionFind};
use crate::pipeline::Sorted;
use crate::tape::{self, EvalError, OutputRef, Tape};
use ode::{CircuitOde, EvalCounts, HostVec, Regs};

/// The integration method.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
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
}

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
}

/// Solver statistics of a run.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Stats {
    pub method: Option<Method>,
    pub states: usize,
    pub steps: usize,
    pub rejected: usize,
    pub rhs_evals: usize,
    pub jac_mul_evals: usize,
    pub jacobians: usize,
    pub lu_factorizations: usize,
    pub restarts: usize,
    /// Restarts after repeated error-test failures (a kink in the history).
    pub rescues: usize,
    pub wall: Duration,
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
}

#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SimError {
    #[error("the netlist has no `.tran` line")]
    NoTran,
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
    #[error("the solver failed at t = {t:e}: {message}")]
    Solver { t: f64, message: String },
    #[error("no DC operating point: {message}")]
    DcFailed { message: String },
    #[error(
        "no DC operating point: the DC Jacobian is singular: a node or loop has no DC path (a capacitor-only node, an inductor loop); use `.tran ... uic`"
    )]
    DcSingular,
    #[error("cannot write the waveforms: {message}")]
    Write { message: String },
    #[error("{what} is {value}; it must be {range}")]
    BadTolerance {
        what: &'static str,
        value: f64,
        range: &'static str,
    },
}

impl crate::diag::ToDiagnostic for SimError {
    fn to_diagnostic(&self) -> crate::diag::Diagnostic {
        let (code, help) = match self {
            SimError::NoTran => ("K0400", "add `.tran TSTEP TSTOP`"),
            SimError::UnknownProbe(_) => (
                "K0401",
                "see `kausal equations` for the circuit's nodes and elements",
            ),
            SimError::Eval { .. } => (
                "K0402",
                "check the elements of the loop for values that allow no solution",
            ),
            SimError::NonFinite { .. } => (
                "K0403",
                "an expression left its domain (division by zero, log of a negative number)",
            ),
            SimError::StepUnderflow { .. } => (
                "K0404",
                "the circuit may be ill-posed there, or change faster than steps of TSTOP·1e-16 can follow (shorten TSTOP); try another --method or a looser --rtol",
            ),
            SimError::Solver { .. } => ("K0405", "try another --method"),
            SimError::DcFailed { .. } | SimError::DcSingular => {
                ("K0406", "give initial conditions and use `.tran ... uic`")
            }
            SimError::Write { .. } => ("K0407", "check the output path and free space"),
            SimError::BadTolerance { .. } => ("K0411", "e.g. rtol 1e-6, atol 1e-9"),
        };
        crate::diag::Diagnostic::error(code, self.to_string()).with_help(help)
    }
}

/// The output a probe names.
fn resolve_probe(c: &Circuit, probe: &str) -> Result<Output, SimError> {
    let p = probe.trim().to_ascii_lowercase();
    let bad = || SimError::UnknownProbe(probe.to_string());
    let inner = |prefix: &str| -> Option<&str> { p.strip_prefix(prefix)?.strip_suffix(')') };
    if let Some(args) = inner("v(") {
        let nodes: Vec<&str> = args.split(',').map(str::trim).collect();
        let ids: Vec<_> = nodes
            .iter()
            .map(|n| c.find_node(n))
            .collect::<Option<_>>()
            .ok_or_else(bad)?;
        return match ids.as_slice() {
            [a] => Ok(Output::Voltage {
                pos: *a,
                neg: GROUND,
            }),
            [a, b] => Ok(Output::Voltage { pos: *a, neg: *b }),
            _ => Err(bad()),
        };
    }
    if let Some(name) = inner("i(") {
        let e = c.find_element(name.trim()).ok_or_else(bad)?;
        if matches!(c.elements[e].kind, ElementKind::Coupling { .. }) {
            return Err(bad());
        }
        return Ok(Output::Current { elem: e });
    }
    Err(bad())
}

/// What computes an output in the equations `b`.
fn output_ref(b: &Built, out: &Output) -> OutputRef {
    match *out {
        Output::Voltage { pos, neg } if neg == GROUND => {
            OutputRef::Expr(b.node_pot[pos.0 as usize])
        }
        Output::Voltage { pos, neg } => {
            OutputRef::Diff(b.node_pot[pos.0 as usize], b.node_pot[neg.0 as usize])
        }
        Output::Current { elem } => OutputRef::Var(
            b.elem_vars[elem.0 as usize]
                .expect("two-terminal element")
                .i,
        ),
    }
}

/// The outputs of a run: `--probe`s, else `.print`/`.save`, else every node
/// voltage and every voltage source's current (ngspice's default vectors).
pub fn output_list(c: &Circuit, probes: &[String]) -> Result<Vec<Output>, SimError> {
    if !probes.is_empty() {
        return probes.iter().map(|p| resolve_probe(c, p)).collect();
    }
    if !c.outputs.is_empty() {
        return Ok(c.outputs.clone());
    }
    let mut v: Vec<Output> = c
        .nodes
        .ids()
        .filter(|&n| n != GROUND)
        .map(|n| Output::Voltage {
            pos: n,
            neg: GROUND,
        })
        .collect();
    v.extend(
        c.elements
            .iter()
            .filter(|(_, e)| matches!(e.kind, ElementKind::VSource { .. }))
            .map(|(id, _)| Output::Current { elem: id }),
    );
    Ok(v)
}

/// [`output_list`] with each output's name and what computes it.
pub fn outputs(sorted: &Sorted, probes: &[String]) -> Result<Vec<(String, OutputRef)>, SimError> {
    let c = &sorted.elaborated.circuit;
    Ok(output_list(c, probes)?
        .iter()
        .map(|o| (c.output_name(o), output_ref(&sorted.built, o)))
        .collect())
}

/// The absolute tolerances of voltages and currents.
fn atol_pair(opts: &Options, c: &Circuit) -> (f64, f64) {
    match opts.atol {
        Some(a) => (a, a * 1e-3),
        None => (
            c.options
                .vntol
                .map_or(DEFAULT_ATOL_V, |v| v.min(DEFAULT_ATOL_V * 1e3)),
            c.options
                .abstol
                .map_or(DEFAULT_ATOL_I, |v| v.min(DEFAULT_ATOL_I * 1e3)),
        ),
    }
}

/// Per-state absolute tolerances: voltages and currents differ by orders of
/// magnitude, so each state gets the tolerance of its kind.
fn atols(sys: &EquationSystem, states: &[VarId], opts: &Options, c: &Circuit) -> Vec<f64> {
    let (atol_v, atol_i) = atol_pair(opts, c);
    states
        .iter()
        .map(|&s| match sys.vars[s].kind {
            crate::ir::VarKind::BranchCurrent => atol_i,
            // A junction's charge error δq moves its voltage by δq/C, and the
            // current through its series resistance by δq/(C·RS): charges get
            // the voltage tolerance times 1 pF (a small junction). At 1e-17 C
            // (1e-5 V on 1 pF) a 1 Ω diode's reverse current carried 1e-5 A
            // of noise, 0.2 % of a rectifier's range, at any rtol.
            crate::ir::VarKind::Charge => atol_v * 1e-12,
            _ => atol_v,
        })
        .collect()
}

/// The breakpoints: where a source's value or slope jumps, inside (t0, t1).
/// The integrator stops and restarts at each. There is no step cap (TMAX):
/// error control keeps the accuracy, and diffsol's stop handling can leave
/// a sub-ulp step after a stop.
fn breakpoints(sys: &EquationSystem, t0: f64, t1: f64) -> Vec<f64> {
    let mut hard: Vec<f64> = sys
        .sources
        .values()
        .flat_map(|s| s.wave.breakpoints(t1))
        .filter(|&t| t > t0 && t < t1)
        .collect();
    hard.sort_by(f64::total_cmp);
    hard.dedup_by(|a, b| (*a - *b).abs() <= 1e-12 * t1.abs().max(1e-30));
    hard
}

/// The start of a run.
struct Start {
    y: Vec<f64>,
    warnings: Vec<crate::diag::Diagnostic>,
    /// The outputs at t = 0 when they are not those of `y`: the operating
    /// point with the `.ic` nodes held, before they are released.
    row: Option<Vec<f64>>,
}

/// The element that owns each branch variable.
fn element_of_vars(sorted: &Sorted) -> HashMap<VarId, crate::elab::ElemId> {
    let mut owner = HashMap::new();
    for (e, ev) in sorted.built.elem_vars.iter().enumerate() {
        if let Some(ev) = ev {
            let id = crate::elab::ElemId(e as u32);
            owner.insert(ev.u, id);
            owner.insert(ev.i, id);
        }
    }
    owner
}

/// The initial states: `uic` (element `ic=` and `.ic` values), the DC
/// operating point with the `.ic` nodes held (see [`ic`]), or the DC
/// operating point (capacitors open, inductors shorted: `f(0, y) = 0`).
fn initial_state<M: Matrix<T = f64>>(
    sorted: &Sorted,
    ode: &CircuitOde<M>,
    t0: f64,
    atol: &[f64],
    outputs: &[Output],
    opts: &Options,
) -> Result<Start, SimError>
where
    M::V: HostVec,
{
    let c = &sorted.elaborated.circuit;
    let tape = &ode.tape;
    let n = tape.states.len();
    let uic = c.tran.as_ref().is_some_and(|t| t.uic);
    let mut warnings = Vec::new();
    if !uic && !c.ics.is_empty() {
        match ic::held_operating_point(sorted, &tape.states, outputs, opts, &c.ics, ".ic") {
            Ok(held) => {
                return Ok(Start {
                    y: held.y,
                    warnings: held.warnings,
                    row: Some(held.row),
                });
            }
            Err(ic::Unheld::Sim(e)) => return Err(name_dc_failure(c, e)),
            Err(ic::Unheld::Structure(why)) => warnings.push(ic::unheld_warning(c, &why)),
        }
    }
    let mut y = vec![0.0; n];
    if uic {
        // Element initial conditions, and `.ic` node voltages across
        // capacitors with a terminal on the `.ic` line; as in ngspice, a node
        // not on it starts at 0 V (a capacitor from a named node to an
        // unnamed one started at 0 V instead of the named node's value).
        let ic_node = |node: crate::elab::NodeId| -> f64 {
            c.ics
                .iter()
                .find(|i| i.node == node && node != GROUND)
                .map_or(0.0, |i| i.value)
        };
        let owner = element_of_vars(sorted);
        for (k, &s) in tape.states.iter().enumerate() {
            let Some(&e) = owner.get(&s) else {
                continue;
            };
            let el = &c.elements[e];
            match el.kind {
                ElementKind::Capacitor { ic: Some(v), .. }
                | ElementKind::Inductor { ic: Some(v), .. } => y[k] = v,
                ElementKind::Capacitor { ic: None, .. } => {
                    let named = |node| node != GROUND && c.ics.iter().any(|i| i.node == node);
                    if named(el.nodes[0]) || named(el.nodes[1]) {
                        y[k] = ic_node(el.nodes[0]) - ic_node(el.nodes[1]);
                    }
                }
                _ => {}
            }
        }
        return Ok(Start {
            y,
            warnings,
            row: None,
        });
    }
    // `.nodeset`: the operating point with those nodes held is the first
    // guess of the free one (ngspice holds them for its first iterations);
    // where it cannot be had, the guess is zero as without.
    if !c.nodesets.is_empty()
        && let Ok(held) =
            ic::held_operating_point(sorted, &tape.states, outputs, opts, &c.nodesets, ".nodeset")
    {
        y = held.y;
        warnings.extend(held.warnings);
    }
    tape.dc.set(true);
    let r = dc_point::<M>(ode, t0, y, atol);
    tape.dc.set(false);
    Ok(Start {
        y: r.map_err(|e| name_dc_failure(c, e))?,
        warnings,
        row: None,
    })
}

/// For each node, a representative of the nodes that the elements `joins`
/// selects connect it to (union-find with path halving).
fn node_components(c: &Circuit, joins: impl Fn(&ElementKind) -> bool) -> Vec<usize> {
    let mut sets = UnionFind::new(c.nodes.len());
    for e in c.elements.values() {
        if e.nodes.len() >= 2 && joins(&e.kind) {
            sets.union(e.nodes[0].0 as usize, e.nodes[1].0 as usize);
        }
    }
    sets.representatives()
}

/// The nodes with no DC path to ground (joined to the rest only through
/// capacitors and current sources), in islands, each with the elements that
/// touch it.
fn floating_islands(c: &Circuit) -> Vec<(Vec<crate::elab::NodeId>, Vec<String>)> {
    let root = node_components(c, |k| {
        matches!(
            k,
            ElementKind::Resistor { .. }
                | ElementKind::Inductor { .. }
                | ElementKind::VSource { .. }
                | ElementKind::Diode { .. }
                | ElementKind::Vcvs { .. }
                | ElementKind::Ccvs { .. }
        )
    });
    let ground = root[GROUND.0 as usize];
    // Islands in order of their first node; each node's island by its root.
    let mut index: HashMap<usize, usize> = HashMap::new();
    let mut islands: Vec<(Vec<crate::elab::NodeId>, Vec<String>)> = Vec::new();
    for id in c.nodes.ids() {
        let r = root[id.0 as usize];
        if r == ground {
            continue;
        }
        let k = *index.entry(r).or_insert_with(|| {
            islands.push((Vec::new(), Vec::new()));
            islands.len() - 1
        });
        islands[k].0.push(id);
    }
    for e in c.elements.values() {
        let n = e.nodes.len().min(2);
        let mut of: Vec<usize> = e.nodes[..n]
            .iter()
            .filter_map(|x| index.get(&root[x.0 as usize]).copied())
            .collect();
        of.dedup();
        for k in of {
            islands[k].1.push(e.name.clone());
        }
    }
    islands
}

/// A singular DC Jacobian explained by the nodes that have no DC path.
fn name_dc_failure(c: &Circuit, e: SimError) -> SimError {
    match &e {
        SimError::DcSingular => {
            let islands = floating_islands(c);
            if islands.is_empty() {
                return e;
            }
            let text: Vec<String> = islands
                .iter()
                .take(3)
                .map(|(nodes, elems)| {
                    let names: Vec<String> = nodes
                        .iter()
                        .map(|&n| format!("`{}`", c.nodes[n].name))
                        .collect();
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
            SimError::DcFailed {
                message: format!(
                    "the DC Jacobian is singular: {}; use `.tran ... uic`, or give the node a DC path (a large resistor to ground)",
                    text.join("; ")
                ),
            }
        }
        _ => e,
    }
}

/// DC operating point by damped Newton on f(t0, y) = 0 in DC mode, with the
/// states that `.ic` fixes held: the sparse LU of the coloured Jacobian above
/// `DENSE_STATES` states, else a dense solve. Junction charges take limited
/// steps (as ngspice limits junction voltages); when Newton still fails,
/// the sources are ramped up from zero (source stepping).
fn dc_point<M: Matrix<T = f64>>(
    ode: &CircuitOde<M>,
    t0: f64,
    y: Vec<f64>,
    atol: &[f64],
) -> Result<Vec<f64>, SimError>
where
    M::V: HostVec,
{
    use diffsol::{OdeEquations, Op, Vector};
    let n = y.len();
    let tape = &ode.tape;
    let resid = |y: &[f64], f: &mut Vec<f64>| -> Result<f64, SimError> {
        ode.eval(t0, y, f)
            .map_err(|error| SimError::Eval { error })?;
        Ok(f.iter().map(|x| x.abs()).fold(0.0, f64::max))
    };
    // The junction of each charge state (one pass over the tape: a search
    // per state was quadratic), and its voltage at the last iterate.
    let junction: Vec<Option<&crate::ir::DiodeParams>> = tape
        .charge_states()
        .into_iter()
        .map(|ci| ci.map(|ci| &tape.diodes[ci.diode as usize]))
        .collect();
    let mut volts: Vec<f64> = vec![0.0; n];
    let mut limit = |y: &[f64], step: &mut [f64]| -> bool {
        let mut limited = false;
        for k in 0..n {
            let Some(p) = junction[k] else { continue };
            let Some(old) = p.voltage_at_charge(y[k], volts[k]) else {
                continue;
            };
            volts[k] = old;
            let Some(new) = p.voltage_at_charge(y[k] - step[k], old) else {
                continue;
            };
            let v = p.limit(new, old);
            if v != new {
                step[k] = y[k] - p.charge(v)[0];
                limited = true;
            }
        }
        limited
    };
    let singular = || SimError::DcSingular;
    let mut jacobian: Box<JacobianAt<'_>> = if n > DENSE_STATES {
        // The coloured sparse Jacobian.
        use diffsol::NonLinearOpJacobian;
        let op = ode.rhs();
        let ctx = ode.context().clone();
        let mut jm = M::new_from_sparsity(n, n, op.jacobian_sparsity(), ctx.clone());
        Box::new(move |y: &[f64]| {
            let yv = M::V::from_vec(y.to_vec(), ctx.clone());
            op.jacobian_inplace(&yv, t0, &mut jm);
            if let Some(error) = ode.error.borrow_mut().take() {
                return Err(SimError::Eval { error });
            }
            let (at, vals) = jm.triplet_iter();
            let entries: Vec<(usize, usize, f64)> =
                at.zip(vals).map(|((i, j), v)| (i, j, v)).collect();
            TripletLu::new(n, entries)
                .map(Factored::Sparse)
                .ok_or_else(singular)
        })
    } else {
        let (mut cols, mut fy) = (vec![0.0; n * n], vec![0.0; n]);
        let all: Vec<usize> = (0..n).collect();
        Box::new(move |y: &[f64]| {
            ode.jacobian_columns(Regs::Solver, t0, y, &all, &mut cols, &mut fy)
                .map_err(|error| SimError::Eval { error })?;
            match cols.iter().all(|v| v.is_finite()) {
                true => DenseLu::new(n, cols.clone())
                    .map(Factored::Dense)
                    .ok_or_else(singular),
                false => Err(singular()),
            }
        })
    };
    let solve = &mut *jacobian;
    let first = if direct_dc() {
        dc_newton(y.clone(), &resid, solve, &mut limit, atol)
    } else {
        Err(SimError::DcFailed {
            message: "not tried (test)".into(),
        })
    };
    let Err(error) = first else {
        return first;
    };
    // Source stepping: from all sources off (where y = 0 solves a circuit
    // without sources) up to their full values, each solution the start of
    // the next; a failed stage is retried with a quarter of the increment.
    let mut at = 0.0f64;
    let mut y = y;
    let mut inc = 0.1f64;
    ode.scale_sources(0.0);
    let result = (|| {
        y = dc_newton(y.clone(), &resid, solve, &mut limit, atol)?;
        while at < 1.0 {
            let next = (at + inc).min(1.0);
            ode.scale_sources(next);
            match dc_newton(y.clone(), &resid, solve, &mut limit, atol) {
                Ok(found) => {
                    y = found;
                    at = next;
                    inc = (inc * 2.0).min(0.25);
                }
                Err(_) if inc > 1e-4 => inc *= 0.25,
                Err(e) => return Err(e),
            }
        }
        Ok(y.clone())
    })();
    ode.scale_sources(1.0);
    // Report the direct attempt's failure, which names what went wrong at
    // the full sources.
    result.map_err(|_| error)
}

/// `f` into its argument, returning its max-norm.
type Residual<'a> = dyn Fn(&[f64], &mut Vec<f64>) -> Result<f64, SimError> + 'a;

/// Whether the DC solve tries Newton at the full sources first (tests can
/// send it straight to source stepping).
#[cfg(not(test))]
fn direct_dc() -> bool {
    true
}

#[cfg(test)]
fn direct_dc() -> bool {
    !tests::SOURCES_ONLY.with(|c| c.get())
}

/// The factored DC Jacobian at a point.
/// Rows of held states are identity rows.
type JacobianAt<'a> = dyn FnMut(&[f64]) -> Result<Factored, SimError> + 'a;

/// Damped Newton from `y` (Deuflhard's natural monotonicity test, which
/// compares corrections in the states' own units rather than residuals of
/// mixed units): `jacobian(y)` is factored once per iteration, `limit`
/// shortens junction steps (a limited step is taken whole, as SPICE takes
/// it). Converged when a correction is below 1e-10 relative and 1e-3 of
/// the integration's absolute tolerances, or `f` vanishes; or when no damped
/// step improves a correction already below 1e-7 of that scale with `f`
/// below 1e-12 (rounding).
fn dc_newton(
    mut y: Vec<f64>,
    resid: &Residual<'_>,
    jacobian: &mut JacobianAt<'_>,
    limit: &mut dyn FnMut(&[f64], &mut [f64]) -> bool,
    atol: &[f64],
) -> Result<Vec<f64>, SimError> {
    let n = y.len();
    let mut f = vec![0.0; n];
    let mut norm = resid(&y, &mut f)?;
    if norm == 0.0 {
        return Ok(y);
    }
    let singular = || SimError::DcSingular;
    // Corrections measured against |y| + 1e7 atol: 1e-10 of it converges.
    let scaled = |d: &[f64], y: &[f64]| newton::scaled_norm(d, |k| y[k].abs() + 1e7 * atol[k]);
    let mut trial = vec![0.0; n];
    let mut ft = vec![0.0; n];
    for _ in 0..200 {
        let jac = jacobian(&y)?;
        let mut step = jac.solve(&f).ok_or_else(singular)?;
        let full = scaled(&step, &y);
        if full <= 1e-10 || norm <= 1e-15 {
            for k in 0..n {
                y[k] -= step[k];
            }
            return Ok(y);
        }
        if limit(&y, &mut step) {
            for k in 0..n {
                y[k] -= step[k];
            }
            norm = resid(&y, &mut f)?;
            continue;
        }
        let damping = newton::damp(full, |lambda| {
            for k in 0..n {
                trial[k] = y[k] - lambda * step[k];
            }
            // A trial point where the circuit cannot be evaluated (a loop
            // without solution that far out) is too far: halve the step.
            Ok::<_, SimError>(match resid(&trial, &mut ft) {
                Ok(nn) if nn.is_finite() => {
                    jac.solve(&ft).map_or(f64::INFINITY, |b| scaled(&b, &y))
                }
                _ => f64::INFINITY,
            })
        })?;
        if damping == Damping::Stalled {
            // No step along the correction is better: rounding, not the
            // circuit, sets the corrections now. When they are already within
            // 1e-7 of the integration's scale and f is at the level of
            // ngspice's ABSTOL (1 pA), this is the operating point; with a
            // larger f it is not, as a charge's correction reaches its
            // current amplified by 1/(C·RS) (source stepping goes on).
            if full <= 1e-7 && norm <= 1e-12 {
                return Ok(y);
            }
            return Err(SimError::DcFailed {
                message: format!("Newton stalled (residual {norm:.3e})"),
            });
        }
        std::mem::swap(&mut y, &mut trial);
        std::mem::swap(&mut f, &mut ft);
        norm = f.iter().map(|x| x.abs()).fold(0.0, f64::max);
    }
    Err(SimError::DcFailed {
        message: format!("Newton did not converge (residual {norm:.3e})"),
    })
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
    let start = Instant::now();
    let c = &sorted.elaborated.circuit;
    let tran = c.tran.clone().ok_or(SimError::NoTran)?;
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
    let sys = sorted.system();
    let list = output_list(c, &opts.probes)?;
    let refs: Vec<OutputRef> = list.iter().map(|o| output_ref(&sorted.built, o)).collect();
    let tape = Rc::new(tape::compile(
        sys,
        &sorted.causal.graph,
        &sorted.schedule,
        &refs,
    ));
    let n = tape.states.len();
    let method = opts.method.unwrap_or(Method::Bdf);
    let mut w = if n == 0 {
        algebraic(sorted, tape.clone(), &tran, &list, opts, sink)?
    } else if method == Method::Circuit && n > DENSE_STATES {
        return Err(SimError::Solver {
            t: 0.0,
            message: format!(
                "--method circuit integrates circuits of at most {DENSE_STATES} states (this one has {n}): use --method bdf"
            ),
        });
    } else if n <= DENSE_STATES {
        run::<NalgebraMat<f64>, NalgebraLU<f64>>(
            sorted,
            sys,
            tape.clone(),
            &tran,
            &list,
            opts,
            method,
            false,
            sink,
        )?
    } else {
        run::<FaerSparseMat<f64>, CircuitLu>(
            sorted,
            sys,
            tape.clone(),
            &tran,
            &list,
            opts,
            method,
            true,
            sink,
        )?
    };
    w.names = list.iter().map(|o| c.output_name(o)).collect();
    w.stats.method = Some(method);
    w.stats.states = n;
    w.stats.in_f = tape.n_in_f;
    w.stats.at_outputs = tape.n_at_outputs;
    w.stats.unused = tape.n_unused;
    w.stats.wall = start.elapsed();
    Ok(w)
}

/// A circuit without states: every output is a function of time alone, so
/// it is evaluated on the grid (and at the source corners with `--all-steps`).
fn algebraic(
    sorted: &Sorted,
    tape: Rc<Tape>,
    tran: &crate::elab::Tran,
    outputs: &[Output],
    opts: &Options,
    sink: Option<RowSink<'_>>,
) -> Result<Waveforms, SimError> {
    let sys = sorted.system();
    let c = &sorted.elaborated.circuit;
    // The operating point with the `.ic` nodes held, output at t = 0.
    let mut warnings = Vec::new();
    let mut held = None;
    if !tran.uic && !c.ics.is_empty() {
        match ic::held_operating_point(sorted, &[], outputs, opts, &c.ics, ".ic") {
            Ok(h) => {
                held = Some(h.row);
                warnings = h.warnings;
            }
            Err(ic::Unheld::Sim(e)) => return Err(e),
            Err(ic::Unheld::Structure(why)) => warnings.push(ic::unheld_warning(c, &why)),
        }
    }
    let mut times = opts
        .times
        .clone()
        .map_or_else(|| Grid::of(tran), Grid::Times);
    if opts.all_steps {
        let hard = breakpoints(sys, 0.0, tran.tstop);
        let mut all: Vec<f64> = (0..times.len()).map(|k| times.at(k)).collect();
        all.extend(hard.into_iter().filter(|&t| t >= tran.tstart));
        all.sort_by(f64::total_cmp);
        all.dedup();
        times = Grid::Times(all);
    }
    let mut regs = tape.registers();
    let mut out = vec![0.0; tape.out_regs.len()];
    let mut rows = Rows::new(out.len(), sink);
    let mut stats = Stats::default();
    for k in 0..times.len() {
        let t = times.at(k);
        let first = k == 0 && t == 0.0;
        if first && let Some(row) = held.take() {
            rows.push(t, &row)?;
            continue;
        }
        // The first point is the DC operating point unless `uic`.
        tape.dc.set(first && !tran.uic);
        let r = tape.outputs(&mut regs, t, &[], &mut out);
        tape.dc.set(false);
        r.map_err(|error| SimError::Eval { error })?;
        stats.rhs_evals += 1;
        rows.push(t, &out)?;
    }
    let mut w = rows.into_waveforms(stats);
    w.warnings = warnings;
    Ok(w)
}

/// Output times: `.tran`'s uniform grid, computed point by point (a long
/// run at a fine TSTEP must not hold its grid in memory: memory stays
/// bounded by the circuit), or times given.
#[derive(Clone, Debug)]
enum Grid {
    /// `start + k·step` for `k < n`, then `stop` when it is not on the grid.
    Uniform {
        start: f64,
        step: f64,
        n: usize,
        stop: Option<f64>,
    },
    Times(Vec<f64>),
}

impl Grid {
    /// The output times of `.tran tstep tstop tstart`.
    fn of(tran: &crate::elab::Tran) -> Grid {
        let k = ((tran.tstop - tran.tstart) / tran.tstep + 1e-9).floor() as usize;
        let last = tran.tstart + k as f64 * tran.tstep;
        Grid::Uniform {
            start: tran.tstart,
            step: tran.tstep,
            n: k + 1,
            stop: (tran.tstop - last > 1e-9 * tran.tstep).then_some(tran.tstop),
        }
    }

    fn len(&self) -> usize {
        match self {
            Grid::Uniform { n, stop, .. } => n + usize::from(stop.is_some()),
            Grid::Times(t) => t.len(),
        }
    }

    /// The `k`-th time (`k < len()`).
    fn at(&self, k: usize) -> f64 {
        match *self {
            Grid::Uniform {
                start,
                step,
                n,
                stop,
            } => {
                if k < n {
                    start + k as f64 * step
                } else {
                    stop.unwrap_or(f64::NAN)
                }
            }
            Grid::Times(ref t) => t[k],
        }
    }

    fn first(&self) -> Option<f64> {
        (self.len() > 0).then(|| self.at(0))
    }

    fn last(&self) -> Option<f64> {
        self.len().checked_sub(1).map(|k| self.at(k))
    }
}

/// Where output rows go as they are computed (time, one value per output).
pub type RowSink<'s> = &'s mut dyn FnMut(f64, &[f64]) -> std::io::Result<()>;

/// The output rows of a run: kept (columns) or handed to a sink.
struct Rows<'s> {
    time: Vec<f64>,
    data: Vec<Vec<f64>>,
    sink: Option<RowSink<'s>>,
    last: Option<f64>,
}

impl<'s> Rows<'s> {
    fn new(n_out: usize, sink: Option<RowSink<'s>>) -> Rows<'s> {
        Rows {
            time: Vec::new(),
            data: vec![Vec::new(); n_out],
            sink,
            last: None,
        }
    }

    fn push(&mut self, t: f64, out: &[f64]) -> Result<(), SimError> {
        self.last = Some(t);
        match &mut self.sink {
            Some(sink) => sink(t, out).map_err(|e| SimError::Write {
                message: e.to_string(),
            }),
            None => {
                self.time.push(t);
                for (col, &v) in self.data.iter_mut().zip(out) {
                    col.push(v);
                }
                Ok(())
            }
        }
    }

    fn into_waveforms(self, stats: Stats) -> Waveforms {
        Waveforms {
            names: Vec::new(),
            time: self.time,
            data: self.data,
            stats,
            warnings: Vec::new(),
        }
    }
}

struct Recorder<'a, 's, M: Matrix<T = f64>>
where
    M::V: HostVec,
{
    ode: &'a CircuitOde<M>,
    grid: Grid,
    next: usize,
    rows: Rows<'s>,
    out: Vec<f64>,
    /// The first point is the DC operating point (no `uic`): it is output in
    /// DC mode, as ngspice reports its operating point at t = 0.
    dc_start: bool,
    /// The first point's outputs when they are not the initial state's (the
    /// `.ic` nodes held; see [`Start::row`]).
    first: Option<Vec<f64>>,
    /// The junction-charge states (indices in `y`).
    charges: Vec<usize>,
    /// The factored shifted Jacobian of the charges in the current step.
    settle: Option<Settle>,
    /// The state at the end of the run.
    last: Vec<f64>,
}

/// What [`Recorder::settle_charges`] keeps for the output points of a step.
struct Settle {
    /// The step: the solver's (time, step size).
    step: (f64, f64),
    /// `J_qq - σ I` factored (LU, row order); `None` when singular.
    lu: Option<(Vec<f64>, Vec<usize>)>,
}

/// Newton steps of [`Recorder::settle_charges`]. One left a clamp's reverse
/// leakage (range 1e-9 A) off ngspice by 3.5e-11 A; three, 3.6e-13 A (each
/// further step moves a slow direction by at most h/100 of its residual). It
/// costs the bridge rectifiers 7–15 % of their solve at rtol 1e-3..1e-4.
const SETTLE_STEPS: usize = 3;

impl<M: Matrix<T = f64>> Recorder<'_, '_, M>
where
    M::V: HostVec,
{
    /// Put the junction charges of an interpolated state `y` on their slow
    /// manifold: [`SETTLE_STEPS`] Newton steps (one factored matrix) towards
    /// `f_q(t, y) = dq/dt` of the interpolant, shifted by `σ = 100/h` so
    /// that they act only along directions whose relaxation time is far
    /// below the step `h`
    /// (`(J_qq - σ I) Δ = f_q - q̇`: a stiff direction, |λ| ≫ σ, moves by its
    /// full correction; a slow one by at most `h/100` times its residual).
    ///
    /// A junction's charge sets the current through its series resistance
    /// RS amplified by 1/(C·RS): the interpolant's own error in `q` (within
    /// tolerance, ~rtol·|q|) became a current error of rtol·|v|/RS, 3e-5 A
    /// on a reverse-biased 1N4001 at rtol 1e-7 where the true current is
    /// 1e-8 A. The interpolant's derivative carries no such amplification.
    fn settle_charges(&mut self, t: f64, y: &mut [f64], dy: &[f64], step: (f64, f64)) {
        let m = self.charges.len();
        let h = step.1;
        if m == 0 || h.is_nan() || h <= 0.0 {
            return;
        }
        let n = y.len();
        let mut f = vec![0.0; n];
        // The shifted Jacobian is factored at the first output point of a
        // step and kept for the step's other points (the correction is
        // small: a nearby Jacobian takes nearly all of it). Where a side
        // evaluation fails the point is output unsettled (its own
        // evaluation then reports what failed).
        if self.settle.as_ref().is_none_or(|s| s.step != step) {
            let mut jac = vec![0.0; n * m];
            if self
                .ode
                .jacobian_columns(Regs::Side, t, y, &self.charges, &mut jac, &mut f)
                .is_err()
            {
                self.settle = None;
                return;
            }
            let sigma = 100.0 / h;
            let mut a = vec![0.0; m * m];
            for (r, &i) in self.charges.iter().enumerate() {
                for c in 0..m {
                    a[r * m + c] = jac[i * m + c] - if r == c { sigma } else { 0.0 };
                }
            }
            let mut perm = vec![0; m];
            let regular = a.iter().all(|v| v.is_finite()) && lu_factor(m, &mut a, &mut perm);
            self.settle = Some(Settle {
                step,
                lu: regular.then_some((a, perm)),
            });
        } else if self.ode.side_eval(t, y, &mut f).is_err() {
            return;
        }
        let Some((lu, perm)) = self.settle.as_ref().and_then(|s| s.lu.as_ref()) else {
            return;
        };
        let (mut d, mut tmp) = (vec![0.0; m], vec![0.0; m]);
        for pass in 0..SETTLE_STEPS {
            if pass > 0 && self.ode.side_eval(t, y, &mut f).is_err() {
                return;
            }
            for (dk, &k) in d.iter_mut().zip(&self.charges) {
                *dk = f[k] - dy[k];
            }
            lu_solve(m, lu, perm, &mut d, &mut tmp);
            if !d.iter().all(|d| d.is_finite()) {
                return;
            }
            for (&k, dk) in self.charges.iter().zip(&d) {
                y[k] -= dk;
            }
        }
    }

    fn record(&mut self, t: f64, y: &[f64]) -> Result<(), SimError> {
        self.ode
            .outputs(t, y, &mut self.out)
            .map_err(|error| SimError::Eval { error })?;
        self.rows.push(t, &self.out)
    }
}

#[allow(clippy::too_many_arguments)]
fn run<M, LS>(
    sorted: &Sorted,
    sys: &EquationSystem,
    tape: Rc<Tape>,
    tran: &crate::elab::Tran,
    outputs: &[Output],
    opts: &Options,
    method: Method,
    sparse: bool,
    sink: Option<RowSink<'_>>,
) -> Result<Waveforms, SimError>
where
    M: Matrix<T = f64> + diffsol::DefaultSolver,
    M::V: HostVec + diffsol::DefaultDenseMatrix<T = f64, C = M::C>,
    LS: LinearSolver<M>,
    for<'b> &'b M::V: diffsol::VectorRef<M::V>,
    for<'b> &'b M: diffsol::matrix::MatrixRef<M>,
{
    let t0 = 0.0;
    let ode = CircuitOde::<M>::new(tape.clone(), vec![0.0; tape.states.len()], sparse);
    let c = &sorted.elaborated.circuit;
    let atol = atols(sys, &tape.states, opts, c);
    let start = initial_state::<M>(sorted, &ode, t0, &atol, outputs, opts)?;
    // f must be defined where the run starts: diffsol sizes its first step
    // from f(t0, y0), and a NaN there (a loop that is singular at t0 while
    // the `.ic` operating point was not) made every step size NaN, which no
    // step-size test rejects: the run never ended.
    let mut dy0 = vec![0.0; start.y.len()];
    ode.eval(t0, &start.y, &mut dy0)
        .map_err(|error| SimError::Eval { error })?;
    *ode.y0.borrow_mut() = start.y;
    let rtol = opts.rtol.unwrap_or_else(|| {
        c.options
            .reltol
            .map_or(DEFAULT_RTOL, |r| r.min(DEFAULT_RTOL * 1e3))
    });
    let mut warnings = start.warnings;
    if method == Method::Bdf
        && let Some(d) = oscillation_at_loose_rtol(sys, &ode, tran, rtol, t0, &ode.y0.borrow())
    {
        warnings.push(d);
    }
    let atol_own = atol.clone();
    let problem = OdeBuilder::<M>::new()
        .rtol(rtol)
        .atol(atol)
        .t0(t0)
        .h0((tran.tstep / 100.0).min(tran.tstop * 1e-6).max(1e-15))
        .build_from_eqn(ode)
        .map_err(|e| SimError::Solver {
            t: t0,
            message: e.to_string(),
        })?;
    // diffsol's default minimum step (1e-13 s) is longer than a nanosecond
    // circuit's steps: scale it to the run.
    let mut problem = problem;
    problem.ode_options.min_timestep = tran.tstop * 1e-16;
    // diffsol counts Newton failures over the whole run, not per step: a
    // long run of a switching circuit would hit any fixed limit. A step that
    // cannot converge ends in step-size underflow instead.
    problem.ode_options.max_nonlinear_solver_failures = usize::MAX / 2;
    // Newton stops when its estimated remaining error is 0.1 of the error
    // test's tolerance (CVODE's coefficient), not diffsol's 0.2: at rtol 1e-2
    // a corrector iterate that stopped early across a diode's turn-on (a
    // Jacobian from before it conducted) let the bridge rectifier's junction
    // charges ring and charged its capacitor to 43 V from a 10 V source.
    problem.ode_options.nonlinear_solver_tolerance = 0.1;
    let times = match &opts.times {
        Some(t) => Grid::Times(
            t.iter()
                .copied()
                .filter(|&x| x >= 0.0 && x <= tran.tstop)
                .collect(),
        ),
        None => Grid::of(tran),
    };
    // Junction charges, the states that interpolation must not leave off
    // their slow manifold (see `Recorder::settle_charges`); small circuits only.
    let charges: Vec<usize> = if sparse {
        Vec::new()
    } else {
        tape.states
            .iter()
            .enumerate()
            .filter(|(_, s)| sys.vars[**s].kind == crate::ir::VarKind::Charge)
            .map(|(k, _)| k)
            .collect()
    };
    let rec = Recorder {
        ode: &problem.eqn,
        grid: times,
        next: 0,
        rows: Rows::new(tape.out_regs.len(), sink),
        out: vec![0.0; tape.out_regs.len()],
        dc_start: !tran.uic,
        first: start.row,
        charges,
        settle: None,
        last: Vec::new(),
    };
    let hard = breakpoints(sys, t0, tran.tstop);
    let mut stats = Stats::default();
    let rec = match method {
        Method::Circuit => {
            let y0 = problem.eqn.y0.borrow().clone();
            trbdf2::drive(
                sys,
                &problem.eqn,
                rtol,
                atol_own,
                atol_pair(opts, c).1,
                y0,
                problem.h0,
                rec,
                &hard,
                opts.all_steps,
                opts.progress,
                &mut stats,
            )?
        }
        Method::Bdf => {
            let s = problem.bdf::<LS>().map_err(|e| solver_err(t0, e))?;
            drive(
                sys,
                &problem,
                s,
                |p, st| p.bdf_solver::<LS>(st),
                rec,
                &hard,
                opts,
                &mut stats,
                1,
            )?
        }
        Method::TrBdf2 => {
            let s = problem.tr_bdf2::<LS>().map_err(|e| solver_err(t0, e))?;
            drive(
                sys,
                &problem,
                s,
                |p, st| p.tr_bdf2_solver::<LS>(st),
                rec,
                &hard,
                opts,
                &mut stats,
                2,
            )?
        }
        Method::Esdirk34 => {
            let s = problem.esdirk34::<LS>().map_err(|e| solver_err(t0, e))?;
            drive(
                sys,
                &problem,
                s,
                |p, st| p.esdirk34_solver::<LS>(st),
                rec,
                &hard,
                opts,
                &mut stats,
                3,
            )?
        }
        Method::Tsit5 => {
            let s = problem.tsit45().map_err(|e| solver_err(t0, e))?;
            drive(
                sys,
                &problem,
                s,
                |p, st| p.tsit45_solver(st),
                rec,
                &hard,
                opts,
                &mut stats,
                4,
            )?
        }
    };
    if method != Method::Circuit {
        let counts: EvalCounts = problem.eqn.counts();
        stats.rhs_evals = counts.rhs;
        stats.jac_mul_evals = counts.jac_mul;
        stats.jacobians = counts.jacobians;
    }
    let points = rec.grid.len();
    if let Some(d) = ringing(sys, &problem.eqn, tran, stats.steps, points, &rec.last) {
        warnings.push(d);
    }
    let mut w = rec.rows.into_waveforms(stats);
    w.warnings = warnings;
    Ok(w)
}

/// Steps this many times more numerous than the output points, in a run of at
/// least [`RINGING_MIN_STEPS`], make kausal look for the mode that kept them
/// short.
const RINGING_STEPS_PER_POINT: usize = 20;
const RINGING_MIN_STEPS: usize = 20_000;

/// When the steps were far shorter than the output interval and the circuit
/// is small (dense): the least damped oscillatory mode of the Jacobian at the
/// end of the run that is fast against TSTEP, named by the states that take
/// part in it. A high-Q LC loop (a transformer's leakage inductance with a
/// diode's junction capacitance) rings at MHz through a run of seconds: the
/// error test makes the solver follow every cycle.
fn ringing<M>(
    sys: &EquationSystem,
    ode: &CircuitOde<M>,
    tran: &crate::elab::Tran,
    steps: usize,
    points: usize,
    y: &[f64],
) -> Option<crate::diag::Diagnostic>
where
    M: Matrix<T = f64>,
    M::V: HostVec,
{
    if steps < RINGING_MIN_STEPS || steps < RINGING_STEPS_PER_POINT * points.max(1) {
        return None;
    }
    // Faster than a tenth of the output interval, Q > 5.
    let fast = 20.0 * std::f64::consts::PI / tran.tstep;
    let m = least_damped_mode(sys, ode, tran.tstop, y, fast, 5.0)?;
    Some(
        crate::diag::Diagnostic::warning(
            "K0409",
            format!(
                "{steps} steps for {points} output points: a lightly damped mode rings at {:.3e} Hz (Q ≈ {}), and the solver follows each cycle; it lives in {}",
                m.freq, m.quality(), m.states
            ),
        )
        .with_help(
            "it is the circuit's own ringing (nothing resistive damps it): a series R–C snubber across those elements damps it; a looser --rtol lets BDF damp it numerically instead",
        ),
    )
}

/// Before a BDF run at a loose rtol (above 1e-3): a mode with Q > 20 that
/// goes through 10 or more cycles in the run. BDF's orders 3 to 5 are not
/// A-stable near the imaginary axis, and its error test is relative to the
/// amplitude it computes: at rtol 1e-2 a lossless LC tank grows 170-fold over
/// 1000 periods.
fn oscillation_at_loose_rtol<M>(
    sys: &EquationSystem,
    ode: &CircuitOde<M>,
    tran: &crate::elab::Tran,
    rtol: f64,
    t0: f64,
    y0: &[f64],
) -> Option<crate::diag::Diagnostic>
where
    M: Matrix<T = f64>,
    M::V: HostVec,
{
    if rtol <= 1e-3 {
        return None;
    }
    let ten_cycles =
        20.0 * std::f64::consts::PI / (tran.tstop - tran.tstart).max(f64::MIN_POSITIVE);
    let m = least_damped_mode(sys, ode, t0, y0, ten_cycles, 20.0)?;
    Some(
        crate::diag::Diagnostic::warning(
            "K0410",
            format!(
                "BDF at rtol {rtol:e} on a lightly damped mode at {:.3e} Hz (Q ≈ {}) in {}: BDF's orders above 2 are not A-stable, and over many cycles the amplitude can grow",
                m.freq, m.quality(), m.states
            ),
        )
        .with_help("use --method tr-bdf2 (A-stable), or an rtol of 1e-3 or tighter"),
    )
}

/// An oscillatory mode of the circuit's Jacobian.
struct Mode {
    freq: f64,
    q: f64,
    /// The states that take part, with their share, most first.
    states: String,
}

impl Mode {
    fn quality(&self) -> String {
        if self.q < 1e6 {
            format!("{:.0}", self.q)
        } else {
            "10^6 or more".into()
        }
    }
}

/// The least damped oscillatory mode of `J(t, y)` with angular frequency
/// above `min_omega` and quality factor above `min_q`, for a small (dense)
/// circuit; the states in it by modal participation factors `|w_k v_k|`
/// (right and left eigenvectors by inverse iteration: dimensionless whatever
/// the states' units).
fn least_damped_mode<M>(
    sys: &EquationSystem,
    ode: &CircuitOde<M>,
    t: f64,
    y: &[f64],
    min_omega: f64,
    min_q: f64,
) -> Option<Mode>
where
    M: Matrix<T = f64>,
    M::V: HostVec,
{
    use nalgebra::{Complex, DMatrix, DVector};
    let n = y.len();
    if n == 0 || n > DENSE_STATES {
        return None;
    }
    let cols: Vec<usize> = (0..n).collect();
    let mut jac = vec![0.0; n * n];
    let mut f = vec![0.0; n];
    ode.jacobian_columns(Regs::Side, t, y, &cols, &mut jac, &mut f)
        .ok()?;
    if jac.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let j = DMatrix::from_row_slice(n, n, &jac);
    // Q = |λ| / (2 |Re λ|) > min_q, i.e. -Re λ < |λ| / (2 min_q).
    let lambda = j
        .complex_eigenvalues()
        .iter()
        .copied()
        .filter(|l| l.im > min_omega.max(0.0) && -l.re < l.norm() / (2.0 * min_q))
        .min_by(|a, b| (-a.re / a.im).total_cmp(&(-b.re / b.im)))?;
    let cj = j.map(|v| Complex::new(v, 0.0));
    let shift = lambda * Complex::new(1.0 + 1e-9, 0.0);
    let eye = DMatrix::<Complex<f64>>::identity(n, n) * shift;
    let iterate = |a: DMatrix<Complex<f64>>| -> Option<DVector<Complex<f64>>> {
        let lu = a.lu();
        let mut x = DVector::from_element(n, Complex::new(1.0, 0.0));
        for _ in 0..3 {
            x = lu.solve(&x)?;
            let norm = x.norm();
            if !(norm.is_finite() && norm > 0.0) {
                return None;
            }
            x /= Complex::new(norm, 0.0);
        }
        Some(x)
    };
    let right = iterate(&cj - &eye)?;
    let left = iterate(cj.transpose() - &eye)?;
    let part: Vec<f64> = (0..n).map(|k| (left[k] * right[k]).norm()).collect();
    let total: f64 = part.iter().sum();
    if total.is_nan() || total <= 0.0 {
        return None;
    }
    let mut order: Vec<usize> = (0..n).filter(|&k| part[k] / total >= 0.05).collect();
    order.sort_by(|&a, &b| part[b].total_cmp(&part[a]));
    let states: Vec<String> = order
        .iter()
        .take(6)
        .map(|&k| {
            format!(
                "{} ({:.0} %)",
                sys.vars[ode.tape.states[k]].name,
                100.0 * part[k] / total
            )
        })
        .collect();
    Some(Mode {
        freq: lambda.im / (2.0 * std::f64::consts::PI),
        q: lambda.norm() / (2.0 * (-lambda.re).max(f64::MIN_POSITIVE)),
        states: states.join(", "),
    })
}

fn solver_err(t: f64, e: diffsol::DiffsolError) -> SimError {
    SimError::Solver {
        t,
        message: e.to_string(),
    }
}

/// Step `solver` to the end, stopping on every breakpoint (restarting after
/// the hard ones) and recording the grid points (and every step with
/// `--all-steps`).
#[allow(clippy::too_many_arguments)]
fn drive<'p, 's, M, S>(
    sys: &EquationSystem,
    problem: &'p OdeSolverProblem<CircuitOde<M>>,
    mut solver: S,
    make: impl Fn(&'p OdeSolverProblem<CircuitOde<M>>, S::State) -> Result<S, diffsol::DiffsolError>,
    mut rec: Recorder<'p, 's, M>,
    hard: &[f64],
    opts: &Options,
    stats: &mut Stats,
    order: usize,
) -> Result<Recorder<'p, 's, M>, SimError>
where
    M: Matrix<T = f64>,
    M::V: HostVec,
    S: OdeSolverMethod<'p, CircuitOde<M>>,
{
    let t_end = rec.grid.last().unwrap_or(0.0);
    let tstart = rec.grid.first().unwrap_or(0.0);
    // Stop points in order: the breakpoints, then the end.
    let mut stops: Vec<f64> = hard.to_vec();
    stops.push(t_end);
    let mut k = 0;
    // The initial point.
    {
        let st = solver.state();
        let (t, y) = (st.t, st.y.slice().to_vec());
        if rec.grid.first() == Some(t) {
            if let Some(row) = rec.first.take() {
                rec.rows.push(t, &row)?;
            } else {
                let tape = &problem.eqn.tape;
                tape.dc.set(rec.dc_start);
                let r = rec.record(t, &y);
                tape.dc.set(false);
                r?;
            }
            rec.next = 1;
        }
    }
    let mut last_report = Instant::now();
    // Restarts after too many error-test failures: (time, how many there).
    let mut rescues: Option<(f64, usize)> = None;
    loop {
        let stop = stops[k];
        solver
            .set_stop_time(stop)
            .map_err(|e| solver_err(stop, e))?;
        let reason = loop {
            let r = solver.step();
            // An evaluation that failed inside a step made diffsol retry
            // with a smaller step; it is reported only if the solver gives up.
            if r.is_ok() {
                problem.eqn.error.borrow_mut().take();
            }
            match r {
                Ok(OdeSolverStopReason::InternalTimestep) => {
                    let t = solver.state().t;
                    // A remainder far below the step would be a sub-ulp
                    // step: take the stop as reached (restarted from here).
                    let h = solver.state().h.abs();
                    if stop - t <= 1e-6 * h && stop > t {
                        emit_grid(&solver, &mut rec, t, false)?;
                        break stop;
                    }
                    emit_grid(&solver, &mut rec, t, false)?;
                    if opts.all_steps && t >= tstart {
                        let y = solver.state().y.slice().to_vec();
                        insert_step(&mut rec, t, &y)?;
                    }
                    if let Some(p) = opts.progress
                        && last_report.elapsed() > Duration::from_millis(100)
                    {
                        p(t / t_end.max(1e-300));
                        last_report = Instant::now();
                    }
                }
                Ok(OdeSolverStopReason::TstopReached) => break stop,
                Ok(OdeSolverStopReason::RootFound(t, _)) => break t,
                Err(e) => {
                    if let Some(error) = problem.eqn.error.borrow_mut().take() {
                        return Err(SimError::Eval { error });
                    }
                    // diffsol's BDF keeps its order through repeated error-test
                    // failures; when the history holds a kink (a diode that just
                    // switched), the estimate then stops shrinking with the step.
                    // Restart from the last accepted point at order 1, as CVODE
                    // does after repeated failures, a few times at most.
                    let t = solver.state().t;
                    let too_many = matches!(
                        e,
                        diffsol::DiffsolError::OdeSolverError(
                            diffsol::error::OdeSolverError::TooManyErrorTestFailures { .. }
                        )
                    );
                    let here = match rescues {
                        Some((at, n)) if at == t => n,
                        _ => 0,
                    };
                    if !too_many || here >= 3 {
                        return Err(diagnose(sys, problem, &solver, e));
                    }
                    rescues = Some((t, here + 1));
                    stats.rescues += 1;
                    solver = restart(problem, solver, &make, t, stats, order)?;
                    solver
                        .set_stop_time(stop)
                        .map_err(|e| solver_err(stop, e))?;
                }
            }
        };
        // BDF stops within a few ulps of the stop time: the grid point there
        // takes the state (interpolation would be asked to extrapolate).
        emit_grid(&solver, &mut rec, reason, true)?;
        if opts.all_steps && reason >= tstart && rec.rows.last != Some(reason) {
            let y = solver.state().y.slice().to_vec();
            insert_step(&mut rec, reason, &y)?;
        }
        if reason >= t_end || k + 1 >= stops.len() {
            rec.last = solver.state().y.slice().to_vec();
            add_solver_stats(stats, &solver);
            break;
        }
        // Restart after a corner: fresh history, recomputed slope and step.
        stats.restarts += 1;
        solver = restart(problem, solver, &make, reason, stats, order)?;
        k += 1;
    }
    Ok(rec)
}

/// Add the counters of one solver's life (up to a restart or the end).
fn add_solver_stats<'p, M, S>(stats: &mut Stats, solver: &S)
where
    M: Matrix<T = f64>,
    M::V: HostVec,
    S: OdeSolverMethod<'p, CircuitOde<M>>,
{
    let s = solver.get_statistics();
    stats.steps += s.number_of_steps;
    stats.rejected += s.number_of_error_test_failures;
    stats.lu_factorizations += s.number_of_linear_solver_setups;
}

/// A new solver from `solver`'s state at `t`: fresh history (order 1),
/// recomputed slope and initial step. Its statistics go into `stats`.
fn restart<'p, M, S>(
    problem: &'p OdeSolverProblem<CircuitOde<M>>,
    solver: S,
    make: &impl Fn(&'p OdeSolverProblem<CircuitOde<M>>, S::State) -> Result<S, diffsol::DiffsolError>,
    t: f64,
    stats: &mut Stats,
    order: usize,
) -> Result<S, SimError>
where
    M: Matrix<T = f64>,
    M::V: HostVec,
    S: OdeSolverMethod<'p, CircuitOde<M>>,
{
    add_solver_stats(stats, &solver);
    let mut common = solver.into_state().into_common();
    common.t = t;
    let y = common.y.slice().to_vec();
    let mut dy = vec![0.0; y.len()];
    problem
        .eqn
        .eval(t, &y, &mut dy)
        .map_err(|error| SimError::Eval { error })?;
    common.dy.slice_mut().copy_from_slice(&dy);
    let mut state = S::State::new_from_common(common);
    state
        .as_mut()
        .set_step_size(problem.h0, &problem.atol, problem.rtol, &problem.eqn, order);
    make(problem, state).map_err(|e| solver_err(t, e))
}

/// Record the grid points up to `t` (inclusive when `at_stop`).
fn emit_grid<'p, M, S>(
    solver: &S,
    rec: &mut Recorder<'p, '_, M>,
    t: f64,
    at_stop: bool,
) -> Result<(), SimError>
where
    M: Matrix<T = f64>,
    M::V: HostVec,
    S: OdeSolverMethod<'p, CircuitOde<M>>,
{
    let scale = 1e-9
        * if rec.grid.len() > 1 {
            (rec.grid.at(1) - rec.grid.at(0)).abs()
        } else {
            1.0
        };
    let inside = |tg: f64| if at_stop { tg <= t + scale } else { tg < t };
    // At or past the solver's time (a stop reached to within a sub-ulp
    // remainder): the state itself, never an extrapolation.
    let at_state = |tg: f64| (tg - t).abs() <= scale || tg >= solver.state().t;
    // Many points inside one step with outputs that read few states: the
    // interpolant there is one polynomial, so a few full interpolations at
    // nodes give the read states everywhere in the step.
    let n = solver.state().y.slice().len();
    let few_read = rec.charges.is_empty() && rec.ode.tape.out_inputs.len() * 4 < n;
    let batch = if few_read {
        (rec.next..rec.grid.len())
            .map(|k| rec.grid.at(k))
            .take_while(|&tg| inside(tg) && !at_state(tg))
            .count()
    } else {
        0
    };
    if batch > 2 * NODES {
        let (a, b) = (rec.grid.at(rec.next), rec.grid.at(rec.next + batch - 1));
        let nodes = StepPolynomial::nodes(a, b);
        let read: Vec<usize> = rec.ode.tape.out_inputs.iter().map(|&(k, _)| k).collect();
        let mut values = Vec::with_capacity(NODES * read.len());
        for &tn in &nodes {
            let y = solver.interpolate(tn).map_err(|e| solver_err(tn, e))?;
            values.extend(read.iter().map(|&k| y.slice()[k]));
        }
        let poly = StepPolynomial::new(nodes, values);
        let mut y = vec![0.0; n];
        let mut sub = vec![0.0; read.len()];
        for _ in 0..batch {
            let tg = rec.grid.at(rec.next);
            poly.eval(tg, &mut sub);
            for (&k, &v) in read.iter().zip(&sub) {
                y[k] = v;
            }
            rec.record(tg, &y)?;
            rec.next += 1;
        }
    }
    while rec.next < rec.grid.len() {
        let tg = rec.grid.at(rec.next);
        if !inside(tg) {
            break;
        }
        let (mut y, ty) = if at_state(tg) {
            (solver.state().y.slice().to_vec(), solver.state().t)
        } else {
            let y = solver.interpolate(tg).map_err(|e| solver_err(tg, e))?;
            (y.slice().to_vec(), tg)
        };
        // The derivative of the solver's polynomial there (at a state just
        // after a restart there may be none: the state is then used as is).
        if !rec.charges.is_empty()
            && let Ok(dy) = solver.interpolate_dy(ty)
        {
            let st = solver.state();
            rec.settle_charges(tg, &mut y, dy.slice(), (st.t, st.h.abs()));
        }
        rec.record(tg, &y)?;
        rec.next += 1;
    }
    Ok(())
}

/// Interpolation nodes per step: every solver's interpolant within one step
/// is a polynomial in t of degree at most 5 (BDF: its order ≤ 5; the
/// Runge–Kutta dense outputs: ≤ 4; Hermite: 3), which six nodes determine.
const NODES: usize = 6;

/// The solver's interpolant within one step, for a few components, as its
/// values at Chebyshev nodes (barycentric Lagrange form: stable, exact for
/// the polynomial up to rounding).
struct StepPolynomial {
    nodes: [f64; NODES],
    /// Barycentric weights of first-kind Chebyshev points,
    /// `(-1)^j sin((2j+1)π/2N)` (common factors cancel).
    weights: [f64; NODES],
    /// Row-major: the components at node 0, then at node 1, …
    values: Vec<f64>,
}

impl StepPolynomial {
    /// The angles of the Chebyshev points of the first kind.
    fn angle(j: usize) -> f64 {
        (2 * j + 1) as f64 * std::f64::consts::PI / (2 * NODES) as f64
    }

    /// Chebyshev points of the first kind on `[a, b]`.
    fn nodes(a: f64, b: f64) -> [f64; NODES] {
        std::array::from_fn(|j| 0.5 * (a + b) + 0.5 * (b - a) * Self::angle(j).cos())
    }

    fn new(nodes: [f64; NODES], values: Vec<f64>) -> StepPolynomial {
        let weights = std::array::from_fn(|j| {
            let w = Self::angle(j).sin();
            if j % 2 == 0 { w } else { -w }
        });
        StepPolynomial {
            nodes,
            weights,
            values,
        }
    }

    /// The components at `t` into `out`.
    fn eval(&self, t: f64, out: &mut [f64]) {
        let m = out.len();
        if let Some(j) = self.nodes.iter().position(|&x| x == t) {
            out.copy_from_slice(&self.values[j * m..(j + 1) * m]);
            return;
        }
        let mut den = 0.0;
        out.fill(0.0);
        for j in 0..NODES {
            let w = self.weights[j] / (t - self.nodes[j]);
            den += w;
            for (o, v) in out.iter_mut().zip(&self.values[j * m..(j + 1) * m]) {
                *o += w * v;
            }
        }
        for o in out.iter_mut() {
            *o /= den;
        }
    }
}

/// Insert an accepted step into the recorded (sorted) series.
fn insert_step<M>(rec: &mut Recorder<'_, '_, M>, t: f64, y: &[f64]) -> Result<(), SimError>
where
    M: Matrix<T = f64>,
    M::V: HostVec,
{
    if rec.rows.last.is_some_and(|l| l >= t) {
        return Ok(());
    }
    rec.record(t, y)
}

/// Turn a solver failure into a message that names what went wrong.
fn diagnose<'p, M, S>(
    sys: &EquationSystem,
    problem: &'p OdeSolverProblem<CircuitOde<M>>,
    solver: &S,
    e: diffsol::DiffsolError,
) -> SimError
where
    M: Matrix<T = f64>,
    M::V: HostVec,
    S: OdeSolverMethod<'p, CircuitOde<M>>,
{
    let st = solver.state();
    let t = st.t;
    let y = st.y.slice().to_vec();
    let eqn = &problem.eqn;
    let tape = &eqn.tape;
    let mut dy = vec![0.0; y.len()];
    let _ = eqn.eval(t, &y, &mut dy);
    if dy.iter().any(|v| !v.is_finite()) {
        let regs = eqn.registers();
        if let Some((reg, var)) = tape.first_non_finite(&regs) {
            let sys_name =
                var.map_or_else(|| format!("register {reg}"), |v| sys.vars[v].name.clone());
            return SimError::NonFinite {
                name: sys_name.clone(),
                value: regs[reg],
                t,
                what: sys_name,
            };
        }
    }
    let msg = e.to_string();
    if msg.to_ascii_lowercase().contains("step size") || msg.contains("StepSizeTooSmall") {
        let atol = problem.atol.slice();
        let k = (0..y.len())
            .max_by(|&a, &b| {
                let sa = dy[a].abs() / (atol[a] + problem.rtol * y[a].abs());
                let sb = dy[b].abs() / (atol[b] + problem.rtol * y[b].abs());
                sa.total_cmp(&sb)
            })
            .unwrap_or(0);
        return SimError::StepUnderflow {
            t,
            state: tape
                .states
                .get(k)
                .map_or_else(String::new, |&v| sys.vars[v].name.clone()),
            value: y.get(k).copied().unwrap_or(f64::NAN),
        };
    }
    SimError::Solver { t, message: msg }
}

#[cfg(test)]
mod tests {
    use super::*;

    thread_local! {
        pub(super) static SOURCES_ONLY: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
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
