//! The diffsol driver: tolerances, the problem, the solver of each method
//! stepped from breakpoint to breakpoint with restarts, and circuits without
//! states.
//!
//! A simulation restarts its integrator (fresh history, order 1) at every
//! hard breakpoint and after repeated error-test failures, never elsewhere.
//! Before it starts and at every restart, f is evaluated once where it
//! starts: an evaluation error there is the run's error (diffsol would size a
//! NaN first step from it, and a NaN step never fails a step-size test).
//! Within a run, source slopes at its end are the ones before it: the step
//! that lands on a corner integrates the segment it comes from.

use super::*;

/// The absolute tolerances of voltages and currents.
pub fn atol_pair(opts: &Options, c: &Circuit) -> (f64, f64) {
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
pub(super) fn atols(
    sys: &EquationSystem,
    states: &[VarId],
    opts: &Options,
    c: &Circuit,
) -> Vec<f64> {
    let (atol_v, atol_i) = atol_pair(opts, c);
    states
        .iter()
        .map(|&s| match sys.vars[s].kind {
            crate::ir::VarKind::BranchCurrent => atol_i,
            // A junction's charge error δq moves its voltage by δq/C, and the
            // current through its series resistance by δq/(C·RS): charges get
            // the voltage tolerance times 1 pF (a small junction). At 1e-17 C
            // (1e-5 V on 1 pF) a 1 Ω diode's reverse current carried 1e-5 A
            // of noise, 0.2 % of a rectifier's range, at any rtol. A junction
            // of known capacitance gets its own (see `junction_charge_atols`).
            crate::ir::VarKind::Charge => atol_v * 1e-12,
            _ => atol_v,
        })
        .collect()
}

/// A junction charge's absolute tolerance from its own capacitance: the
/// voltage tolerance on the junction, `atol_v · CJO` (at least the 1 pF of
/// [`atols`]). It binds only near zero bias, where `rtol·|q|` vanishes and
/// the junction's capacitance is about CJO. Against 1 pF alone the
/// tolerance was below what rounding leaves in a charge: `f` carries
/// ulps of the node voltages over the series resistance (8.5e-14 A from
/// 20 V over 42 mΩ), which a slow direction turns into charge corrections
/// of about `h·8.5e-14` C, so the integrator's Newton corrected noise,
/// saw no convergence and cut the step. Xyce's `sixNode_in` (BJT NAND
/// gates at a constant bias, CJE 25.6 pF, CJC 14 pF) took 77,980 steps
/// of about a nanosecond over 10 µs, 43,244 of them Newton failures.
fn junction_charge_atols(atol: &mut [f64], sys: &EquationSystem, tape: &Tape, atol_v: f64) {
    for ((a, &s), cap) in atol
        .iter_mut()
        .zip(&tape.states)
        .zip(tape.charge_capacitances())
    {
        if let Some(cap) = cap
            && sys.vars[s].kind == crate::ir::VarKind::Charge
        {
            *a = a.max(atol_v * cap);
        }
    }
}

/// What one run integrates: the circuit, its compiled tape, the `.tran`
/// card, the outputs, the options and the method chosen for it.
pub(super) struct Job<'a> {
    pub(super) sorted: &'a Sorted,
    pub(super) tape: Rc<Tape>,
    pub(super) tran: &'a crate::elab::Tran,
    pub(super) outputs: &'a [Output],
    pub(super) opts: &'a Options,
    pub(super) method: Method,
    pub(super) switches: &'a super::events::Switches,
}

impl Method {
    /// The order diffsol assumes when it sizes a first step after a
    /// restart: the order each method starts at.
    fn start_order(self) -> usize {
        match self {
            Method::Bdf | Method::Circuit | Method::Gear2 | Method::Euler => 1,
            Method::TrBdf2 | Method::Rk2 => 2,
            Method::Esdirk34 => 3,
            Method::Tsit5 | Method::Rk4 => 4,
        }
    }
}

/// How a run holds its sorted circuit: kept for the caller, or released
/// once the operating point is found ([`Sorted::release_ir`]) with the
/// function to call then (the binary returns the freed memory to the
/// system; on a 10^5-section ladder the system and circuit were about half
/// the run's memory).
pub(super) enum Ir<'a> {
    Kept(&'a Sorted),
    Released(&'a mut Sorted, fn()),
}

impl Ir<'_> {
    pub(super) fn sorted(&self) -> &Sorted {
        match self {
            Ir::Kept(sorted) => sorted,
            Ir::Released(sorted, _) => sorted,
        }
    }
}

/// Run `parts` on `ir` with matrices `M` and linear solver `LS`: dense
/// (nalgebra) up to [`DENSE_STATES`] states, sparse (faer and the circuit
/// LU) above.
pub(super) fn run<M, LS>(
    ir: Ir<'_>,
    parts: &Parts<'_>,
    sink: Option<RowSink<'_>>,
) -> Result<Waveforms, SimError>
where
    M: Matrix<T = f64> + diffsol::DefaultSolver,
    M::V: HostVec + diffsol::DefaultDenseMatrix<T = f64, C = M::C>,
    LS: LinearSolver<M>,
    for<'b> &'b M::V: diffsol::VectorRef<M::V>,
    for<'b> &'b M: diffsol::matrix::MatrixRef<M>,
{
    let mut ready = setup::<M>(&parts.with(ir.sorted()))?;
    ready.names = match ir {
        Ir::Kept(sorted) => sorted.system().names.clone(),
        Ir::Released(sorted, released) => {
            let names = sorted.release_ir();
            released();
            names
        }
    };
    integrate::<M, LS>(ready, parts, sink)
}

/// A [`Job`] without its circuit: what the integration reads.
pub(super) struct Parts<'a> {
    pub(super) tape: Rc<Tape>,
    pub(super) tran: &'a crate::elab::Tran,
    pub(super) outputs: &'a [Output],
    pub(super) opts: &'a Options,
    pub(super) method: Method,
    pub(super) switches: &'a super::events::Switches,
}

impl<'a> Parts<'a> {
    fn with<'s>(&self, sorted: &'s Sorted) -> Job<'s>
    where
        'a: 's,
    {
        Job {
            sorted,
            tape: self.tape.clone(),
            tran: self.tran,
            outputs: self.outputs,
            opts: self.opts,
            method: self.method,
            switches: self.switches,
        }
    }
}

/// A run whose operating point is found: its problem, tolerances,
/// breakpoints and first row, and the names its diagnostics need. Nothing in
/// it refers to the equation system or the circuit.
pub(super) struct Ready<M: Matrix<T = f64>>
where
    M::V: HostVec,
{
    problem: OdeSolverProblem<CircuitOde<M>>,
    /// The variables' names: left empty by [`setup`] for its caller to
    /// move (or copy) from the system.
    names: NameTable<VarId>,
    atol_own: Vec<f64>,
    atol_current: f64,
    rtol: f64,
    first: Option<Vec<f64>>,
    charges: Vec<usize>,
    inversions: Option<Vec<crate::tape::ChargeInverse>>,
    hard: Vec<f64>,
    tmax: Option<f64>,
    stats: Stats,
    warnings: Vec<crate::diag::Diagnostic>,
}

/// The operating point and everything [`integrate`] needs from the circuit.
fn setup<M>(job: &Job<'_>) -> Result<Ready<M>, SimError>
where
    M: Matrix<T = f64> + diffsol::DefaultSolver,
    M::V: HostVec,
{
    let Job {
        sorted,
        ref tape,
        tran,
        outputs,
        opts,
        method,
        switches,
    } = *job;
    let sys = sorted.system();
    let sparse = tape.states.len() > DENSE_STATES;
    let t0 = 0.0;
    let ode = CircuitOde::<M>::new(tape.clone(), vec![0.0; tape.states.len()], sparse)?;
    let c = &sorted.elaborated.circuit;
    let mut atol = atols(sys, &tape.states, opts, c);
    junction_charge_atols(&mut atol, sys, tape, atol_pair(opts, c).0);
    switches.apply(&ode);
    let mut start = initial_state::<M>(sorted, &ode, t0, &atol, outputs, opts)?;
    // The switches' states at the operating point: each from its control
    // there (as ngspice iterates them), solved again until none changes.
    if !switches.is_empty() && !tran.uic {
        for _ in 0..20 {
            if !switches.settle(&ode, t0, &start.y)? {
                break;
            }
            start = initial_state::<M>(sorted, &ode, t0, &atol, outputs, opts)?;
        }
    }
    switches.hold(&ode, t0, &start.y)?;
    // f must be defined where the run starts: diffsol sizes its first step
    // from f(t0, y0), and a NaN there (a loop that is singular at t0 while
    // the `.ic` operating point is not) would make every step size NaN,
    // which no step-size test rejects: the run would never end.
    let mut dy0 = vec![0.0; start.y.len()];
    ode.eval(t0, &start.y, &mut dy0)
        .map_err(|error| SimError::Eval { error })?;
    *ode.y0.borrow_mut() = start.y;
    let rtol = run_rtol(opts, c);
    let mut warnings = start.warnings;
    let (dc_stages, dc_found) = (start.stages, start.found);
    if method == Method::Bdf
        && let Some(d) =
            oscillation_at_loose_rtol(&sys.names, &ode, tran, rtol, t0, &ode.y0.borrow())
    {
        warnings.push(d);
    }
    let nl_tol = if sparse {
        NEWTON_TOL
    } else {
        // Junction charges are left out: their gain into a diode's current
        // (1/(C·RS)) is the junction's own, which the charge settling at
        // output points handles (see `Recorder::settle_charges`).
        let charge: Vec<bool> = tape
            .states
            .iter()
            .map(|&s| sys.vars[s].kind == crate::ir::VarKind::Charge)
            .collect();
        newton_tolerance(
            &ode,
            &ode.y0.borrow(),
            &atol,
            &charge,
            outputs,
            atol_pair(opts, c).0,
        )
    };
    let atol_own = atol.clone();
    let problem = problem(ode, tran, rtol, atol, t0, nl_tol)?;
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
    // Their junction inversions, where each has one and `f` follows them
    // exactly: the settling matrix can then be judged by its junctions.
    let inversions = if tape.jacobian_follows_junctions() {
        let of = tape.charge_states();
        charges.iter().map(|&k| of[k]).collect()
    } else {
        None
    };
    let hard = breakpoints(sys, t0, tran.tstop);
    let tmax = match (opts.tmax.or(tran.tmax), sine_step_cap(sys)) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    };
    Ok(Ready {
        problem,
        names: NameTable::default(),
        atol_own,
        atol_current: atol_pair(opts, c).1,
        rtol,
        first: start.row,
        charges,
        inversions,
        hard,
        tmax,
        stats: Stats {
            dc_stages,
            dc_found,
            ..Stats::default()
        },
        warnings,
    })
}

/// Integrate a [`Ready`] run with the method of `parts`.
fn integrate<M, LS>(
    ready: Ready<M>,
    parts: &Parts<'_>,
    sink: Option<RowSink<'_>>,
) -> Result<Waveforms, SimError>
where
    M: Matrix<T = f64> + diffsol::DefaultSolver,
    M::V: HostVec + diffsol::DefaultDenseMatrix<T = f64, C = M::C>,
    LS: LinearSolver<M>,
    for<'b> &'b M::V: diffsol::VectorRef<M::V>,
    for<'b> &'b M: diffsol::matrix::MatrixRef<M>,
{
    let Parts {
        ref tape,
        tran,
        outputs,
        opts,
        method,
        switches,
    } = *parts;
    let Ready {
        problem,
        names,
        atol_own,
        atol_current,
        rtol,
        first,
        charges,
        inversions,
        hard,
        tmax,
        mut stats,
        mut warnings,
    } = ready;
    let t0 = 0.0;
    let rec = Recorder {
        ode: &problem.eqn,
        grid: output_grid(opts, tran),
        next: 0,
        rows: Rows::new(outputs.len(), sink),
        out: vec![0.0; tape.out_regs.len()],
        dc_start: !tran.uic,
        first,
        charges,
        settle: None,
        inversions,
        last: Vec::new(),
    };
    let stops = Stops {
        names: &names,
        problem: &problem,
        hard: &hard,
        opts,
        method,
        tmax,
        switches,
    };
    // The steps a stalled BDF took before ESDIRK34 took over.
    let mut stalled_steps = 0;
    let rec = match method {
        Method::Euler | Method::Rk2 | Method::Rk4 => {
            let h = opts.step.unwrap_or(tran.tstop);
            let y0 = problem.eqn.y0.borrow().clone();
            let bound = super::fixed::eigenvalues(&problem.eqn, t0, &y0)
                .and_then(|eigs| super::fixed::stability_bound(method, &eigs));
            warnings.push(super::fixed::bound_note(method, h, bound));
            stats.stable_step = bound.map(|b| b.0);
            let state_name = |k: usize| names.get(tape.states[k]).to_string();
            let run = super::fixed::Run {
                method,
                h,
                bound: bound.map(|b| b.0),
                names: &state_name,
                hard: &hard,
            };
            super::fixed::drive(&problem.eqn, run, rec, &mut stats)?
        }
        Method::Circuit | Method::Gear2 => {
            let setup = circuit::Setup {
                rtol,
                atol: atol_own,
                atol_current,
                y0: problem.eqn.y0.borrow().clone(),
                h0: problem.h0,
                h_cap: tmax.unwrap_or(f64::INFINITY),
                bdf2: method == Method::Gear2,
            };
            circuit::drive(&problem.eqn, setup, rec, &stops, &mut stats)?
        }
        Method::Bdf => {
            let s = problem.bdf::<LS>().map_err(|e| solver_err(t0, e))?;
            let s = floored_start(&problem, s, &|p, st| p.bdf_solver::<LS>(st))?;
            match drive(&stops, s, |p, st| p.bdf_solver::<LS>(st), rec, &mut stats)? {
                Driven::Done(rec) => rec,
                Driven::Stalled(rec, bdf, h) => {
                    // BDF's orders 3 to 5 are not A-stable: a lightly damped
                    // mode near the imaginary axis holds its step at a
                    // stability limit far below what accuracy needs. The rest
                    // of the run goes to ESDIRK34 (L-stable, 4th order).
                    let t = bdf.state().t;
                    let s = restart(
                        &problem,
                        bdf,
                        &|p, st| p.esdirk34_solver::<LS>(st),
                        t,
                        &mut stats,
                        Method::Esdirk34,
                    )?;
                    warnings.push(stalled_note(t, h, stats.steps, tran));
                    stalled_steps = stats.steps;
                    let stops = Stops {
                        method: Method::Esdirk34,
                        ..stops
                    };
                    stats.switched_at = Some(t);
                    drive(
                        &stops,
                        s,
                        |p, st| p.esdirk34_solver::<LS>(st),
                        rec,
                        &mut stats,
                    )?
                    .recorder()
                }
            }
        }
        Method::TrBdf2 => {
            let s = problem.tr_bdf2::<LS>().map_err(|e| solver_err(t0, e))?;
            let s = floored_start(&problem, s, &|p, st| p.tr_bdf2_solver::<LS>(st))?;
            drive(
                &stops,
                s,
                |p, st| p.tr_bdf2_solver::<LS>(st),
                rec,
                &mut stats,
            )?
            .recorder()
        }
        Method::Esdirk34 => {
            let s = problem.esdirk34::<LS>().map_err(|e| solver_err(t0, e))?;
            let s = floored_start(&problem, s, &|p, st| p.esdirk34_solver::<LS>(st))?;
            drive(
                &stops,
                s,
                |p, st| p.esdirk34_solver::<LS>(st),
                rec,
                &mut stats,
            )?
            .recorder()
        }
        Method::Tsit5 => {
            let s = problem.tsit45().map_err(|e| solver_err(t0, e))?;
            let s = floored_start(&problem, s, &|p, st| p.tsit45_solver(st))?;
            drive(&stops, s, |p, st| p.tsit45_solver(st), rec, &mut stats)?.recorder()
        }
    };
    if !matches!(method, Method::Circuit | Method::Gear2) && !method.is_fixed_step() {
        let counts: EvalCounts = problem.eqn.counts();
        stats.rhs_evals = counts.rhs;
        stats.jac_mul_evals = counts.jac_mul;
        stats.jacobians = counts.jacobians;
    }
    let points = rec.grid.len();
    let steps = stats.steps - stalled_steps;
    if let Some(d) = ringing(&names, &problem.eqn, tran, steps, points, &rec.last) {
        warnings.push(d);
    }
    let mut w = rec.rows.into_waveforms(stats);
    w.warnings = warnings;
    w.events = switches.events.take();
    Ok(w)
}

/// The run's relative tolerance: `--rtol`, else the netlist's RELTOL (at
/// most a thousand times kausal's default), else the default.
pub fn run_rtol(opts: &Options, c: &crate::elab::Circuit) -> f64 {
    opts.rtol.unwrap_or_else(|| {
        c.options
            .reltol
            .map_or(DEFAULT_RTOL, |r| r.min(DEFAULT_RTOL * 1e3))
    })
}

/// The longest step that sees every sine source: a quarter of the shortest
/// period. A step of whole periods samples a sine where it started: a
/// circuit at rest at its DC point (an RLC driven at 20 MHz from its
/// offset) showed no change at the end of a 4 µs first step, the error
/// estimate was zero, and the whole run was that one step.
fn sine_step_cap(sys: &EquationSystem) -> Option<f64> {
    sys.sources
        .iter()
        .filter_map(|(_, s)| match s.wave {
            crate::ir::Waveform::Sin { va, freq, .. } if va != 0.0 && freq > 0.0 => {
                Some(0.25 / freq)
            }
            // SFFM's fastest: its instantaneous frequency fc + mdi·fs.
            crate::ir::Waveform::Sffm {
                va, fc, mdi, fs, ..
            } if va != 0.0 => {
                let f = fc.abs() + (mdi * fs).abs();
                (f > 0.0).then(|| 0.25 / f)
            }
            _ => None,
        })
        .min_by(f64::total_cmp)
}

/// Newton stops when its estimated remaining error is this fraction of the
/// error test's tolerance (CVODE's coefficient, not diffsol's 0.2): a
/// corrector iterate that stops early across a diode's turn-on (on a
/// Jacobian from before it conducted) lets a bridge rectifier's junction
/// charges ring and overcharge its capacitor at rtol 1e-2.
const NEWTON_TOL: f64 = 0.1;
/// The tightest Newton tolerance [`newton_tolerance`] asks for.
const NEWTON_TOL_MIN: f64 = 1e-5;

/// The Newton tolerance that keeps the outputs within their own
/// tolerances, not only the states: an output that amplifies a state by a
/// large gain (a node voltage `v = v1 − Rp·(iL1 − iL2)` behind a 1 MΩ
/// resistor, two 0.1 A inductor currents that differ by a microampere)
/// sees each state's Newton error multiplied by it. The gain of output o
/// from state j, in units of their absolute tolerances, is
/// `|∂o/∂y_j|·atol_j/atol_o` (by finite differences at the start, small
/// circuits, over the node-voltage outputs and the states not marked
/// `skip`); [`NEWTON_TOL`] is divided by the largest, down to
/// [`NEWTON_TOL_MIN`].
fn newton_tolerance<M>(
    ode: &CircuitOde<M>,
    y0: &[f64],
    atol: &[f64],
    skip: &[bool],
    outputs: &[Output],
    atol_v: f64,
) -> f64
where
    M: Matrix<T = f64>,
    M::V: HostVec,
{
    let n_out = outputs.len();
    let mut base = vec![0.0; n_out];
    if n_out == 0 || ode.outputs(0.0, y0, &mut base).is_err() {
        return NEWTON_TOL;
    }
    // Node voltages only: a current output through a resistor below
    // atol_v/atol_i (1 kΩ) would count as a gain at any conductance, though
    // its relative tolerance is what bounds its error there.
    let atol_out: Vec<Option<f64>> = outputs
        .iter()
        .map(|o| match o {
            Output::Current { .. } => None,
            Output::Voltage { .. } => Some(atol_v),
        })
        .collect();
    let mut y = y0.to_vec();
    let mut out = vec![0.0; n_out];
    let mut gain: f64 = 1.0;
    for j in (0..y.len()).filter(|&j| !skip[j]) {
        let d = 1e-6 * y0[j].abs().max(1e3 * atol[j]);
        y[j] = y0[j] + d;
        let ok = ode.outputs(0.0, &y, &mut out).is_ok();
        y[j] = y0[j];
        if !ok {
            continue;
        }
        for k in 0..n_out {
            let Some(atol_o) = atol_out[k] else {
                continue;
            };
            let g = ((out[k] - base[k]) / d).abs() * atol[j] / atol_o;
            if g.is_finite() {
                gain = gain.max(g);
            }
        }
    }
    (NEWTON_TOL / gain).max(NEWTON_TOL_MIN)
}

/// diffsol's problem for `ode` on `tran`, with the options circuits need;
/// `nl_tol` is the Newton tolerance (see [`newton_tolerance`]).
fn problem<M>(
    ode: CircuitOde<M>,
    tran: &crate::elab::Tran,
    rtol: f64,
    atol: Vec<f64>,
    t0: f64,
    nl_tol: f64,
) -> Result<OdeSolverProblem<CircuitOde<M>>, SimError>
where
    M: Matrix<T = f64> + diffsol::DefaultSolver,
    M::V: HostVec,
{
    let mut problem = OdeBuilder::<M>::new()
        .rtol(rtol)
        .atol(atol)
        .t0(t0)
        .h0((tran.tstep / 100.0).min(tran.tstop * 1e-6).max(1e-15))
        .build_from_eqn(ode)
        .map_err(|e| solver_err(t0, e))?;
    // diffsol's default minimum step (1e-13 s) is longer than a nanosecond
    // circuit's steps: scale it to the run.
    problem.ode_options.min_timestep = tran.tstop * 1e-16;
    // diffsol counts Newton failures over the whole run, not per step: a
    // long run of a switching circuit would hit any fixed limit. `drive`
    // moves the limit before every step instead (see [`StepLimits`]).
    problem.ode_options.max_nonlinear_solver_failures = usize::MAX / 2;
    problem.ode_options.nonlinear_solver_tolerance = nl_tol;
    Ok(problem)
}

/// Where the run reports: the requested times, else the `.tran` grid.
fn output_grid(opts: &Options, tran: &crate::elab::Tran) -> Grid {
    match &opts.times {
        Some(t) => Grid::Times(
            t.iter()
                .copied()
                .filter(|&x| x >= 0.0 && x <= tran.tstop)
                .collect(),
        ),
        None => Grid::of(tran),
    }
}

pub(super) fn solver_err(t: f64, e: diffsol::DiffsolError) -> SimError {
    SimError::Solver {
        t,
        source: std::rc::Rc::new(e),
    }
}

/// Where a diffsol run stops: its problem, the hard breakpoints (source
/// corners) at which it restarts, and the options and method it runs with.
pub(super) struct Stops<'p, M: Matrix<T = f64>>
where
    M::V: HostVec,
{
    pub(super) names: &'p NameTable<VarId>,
    pub(super) problem: &'p OdeSolverProblem<CircuitOde<M>>,
    pub(super) hard: &'p [f64],
    pub(super) opts: &'p Options,
    pub(super) method: Method,
    /// The longest step (the `.tran` card's TMAX).
    pub(super) tmax: Option<f64>,
    pub(super) switches: &'p super::events::Switches,
}

/// How [`drive`] ended: at the end of the run, or (BDF only) stalled, with
/// the solver where it stalled and its last step.
pub(super) enum Driven<'p, 's, M: Matrix<T = f64>, S>
where
    M::V: HostVec,
{
    Done(Recorder<'p, 's, M>),
    Stalled(Recorder<'p, 's, M>, S, f64),
}

impl<'p, 's, M: Matrix<T = f64>, S> Driven<'p, 's, M, S>
where
    M::V: HostVec,
{
    /// The recorder of a method that never stalls.
    fn recorder(self) -> Recorder<'p, 's, M> {
        match self {
            Driven::Done(rec) | Driven::Stalled(rec, ..) => rec,
        }
    }
}

/// Steps are counted in windows of this many; BDF has stalled when, after at
/// least [`STALL_MIN_STEPS`], a window's pace would take more than
/// [`STALL_PROJECTED`] steps to cover the run (ten times span/TMAX when
/// that is more).
const STALL_WINDOW: usize = 1_000;
const STALL_MIN_STEPS: usize = 2_000;
const STALL_PROJECTED: f64 = 1e6;

/// A window of consecutive steps, for the stall test.
struct Window {
    /// Where it starts.
    t: f64,
    steps: usize,
    h_min: f64,
    h_max: f64,
    order_min: usize,
}

impl Window {
    fn new(t: f64) -> Window {
        Window {
            t,
            steps: 0,
            h_min: f64::INFINITY,
            h_max: 0.0,
            order_min: usize::MAX,
        }
    }

    fn add(&mut self, h: f64, order: usize) {
        self.steps += 1;
        self.h_min = self.h_min.min(h);
        self.h_max = self.h_max.max(h);
        self.order_min = self.order_min.min(order);
    }

    /// Held at a stability limit: order 3 or above throughout, at a step
    /// that varied less than 4-fold. Steps short for accuracy (a diode
    /// turning on) vary widely and drop BDF to order 1 or 2.
    fn held(&self) -> bool {
        self.order_min >= 3 && self.h_max < 4.0 * self.h_min
    }
}

/// The note that says BDF stalled and what took over.
fn stalled_note(t: f64, h: f64, steps: usize, tran: &crate::elab::Tran) -> crate::diag::Diagnostic {
    crate::diag::Diagnostic::warning(
        crate::diag::codes::BDF_STALLED,
        format!(
            "BDF's steps stalled near {h:.2e} s at t = {t:.4e} s after {steps} steps (at that pace the run to {:.4e} s would take more than {STALL_PROJECTED:.0e}): a lightly damped mode holds BDF's orders 3 to 5, which are not A-stable, at their stability limit; the run went on with ESDIRK34 (L-stable)",
            tran.tstop
        ),
    )
    .with_help("--method esdirk34 or --method tr-bdf2 runs the whole circuit with an L-stable method")
}

/// Step `solver` to the end, stopping on every breakpoint (restarting after
/// the hard ones, with `make` building the new solver) and recording the
/// grid points (and every step with `--all-steps`). A solver that starts
/// past 0 resumes a run: the stops before it are passed. BDF stops early
/// when its steps stall (see [`STALL_WINDOW`]).
pub(super) fn drive<'p, 's, M, S>(
    stops_at: &Stops<'p, M>,
    mut solver: S,
    make: impl Fn(&'p OdeSolverProblem<CircuitOde<M>>, S::State) -> Result<S, diffsol::DiffsolError>,
    mut rec: Recorder<'p, 's, M>,
    stats: &mut Stats,
) -> Result<Driven<'p, 's, M, S>, SimError>
where
    M: Matrix<T = f64>,
    M::V: HostVec,
    S: OdeSolverMethod<'p, CircuitOde<M>>,
    S::Config: StepLimits,
{
    let Stops {
        names,
        problem,
        hard,
        opts,
        method,
        tmax,
        switches,
    } = *stops_at;
    let t_end = rec.grid.last().unwrap_or(0.0);
    let tstart = rec.grid.first().unwrap_or(0.0);
    // Stop points in order: the breakpoints, then the end.
    let mut stops: Vec<f64> = hard.to_vec();
    stops.push(t_end);
    let st = solver.state();
    let resumed = st.t > 0.0;
    let mut k = if resumed {
        stops.partition_point(|&s| s <= st.t).min(stops.len() - 1)
    } else {
        rec.record_start(st.t, st.y.slice())?;
        0
    };
    let span = t_end - st.t;
    let mut window = Window::new(st.t);
    let max_steps = opts.max_steps.unwrap_or(DEFAULT_MAX_STEPS);
    let mut budget = budget::Budget::new(max_steps, stats.steps, st.t, t_end);
    let mut last_report = Instant::now();
    // Restarts after too many error-test failures: (time, how many there).
    let mut rescues: Option<(f64, usize)> = None;
    loop {
        let stop = stops[k];
        problem.eqn.tape.set_slope_end(stop);
        // A stop within diffsol's roundoff of the current time (a PULSE whose
        // corners lie 1e-20 s apart) is reached already.
        let reached = match solver.set_stop_time(stop) {
            Ok(()) => false,
            Err(diffsol::DiffsolError::OdeSolverError(
                diffsol::error::OdeSolverError::StopTimeAtCurrentTime,
            )) => true,
            Err(e) => return Err(solver_err(stop, e)),
        };
        // The stop time set in the solver: `stop`, or a soft stop before it.
        let mut set = stop;
        let reason = if reached {
            stop
        } else {
            loop {
                // TMAX caps the step: a soft stop at most TMAX ahead, which
                // diffsol reaches by shortening its step (no restart there).
                // Only when the next step would exceed TMAX: each stop resets
                // BDF's count of equal steps, and a stop every step would keep
                // its step from ever growing back to TMAX.
                let soft = tmax
                    .filter(|&m| solver.state().h.abs() > m * (1.0 + 1e-9))
                    .and_then(|m| soft_stop(solver.state().t, m, stop));
                let target = soft.unwrap_or(stop);
                if target != set {
                    solver
                        .set_stop_time(target)
                        .map_err(|e| solver_err(target, e))?;
                    set = target;
                }
                // At most NEWTON_FAILS_PER_STEP Newton failures within this step:
                // a NaN error estimate makes diffsol's step NaN, which its
                // step-size floor never catches, and the step would retry for ever.
                let fails = solver.get_statistics().number_of_nonlinear_solver_fails;
                solver
                    .config_mut()
                    .set_newton_fail_limit(fails.saturating_add(NEWTON_FAILS_PER_STEP));
                if let Some(m) = tmax {
                    let cap = m / solver.state().h.abs();
                    solver.config_mut().cap_growth(cap);
                }
                let t_before = solver.state().t;
                let r = solver.step();
                // A NaN error estimate can pass an explicit method's test and
                // give a NaN step: stop there, naming what went non-finite.
                if r.is_ok() && !(solver.state().t.is_finite() && solver.state().h.is_finite()) {
                    return Err(non_finite_step(names, problem, &solver, t_before));
                }
                // An evaluation that failed inside a step made diffsol retry
                // with a smaller step; it is reported only if the solver gives up.
                if r.is_ok() {
                    problem.eqn.error.borrow_mut().take();
                }
                // A switch whose control crossed its threshold within the
                // step: the outputs up to the crossing from this step's
                // interpolant, then a restart there with the new state.
                if r.is_ok()
                    && let Some(c) =
                        switches.locate(&problem.eqn, &solver, t_before, solver.state().t)?
                {
                    let (t_ev, y_ev) = (c.t, c.y);
                    emit_grid(&solver, &mut rec, t_ev, false)?;
                    switches.commit(&problem.eqn, t_ev, &c.controls)?;
                    budget
                        .step(t_ev, t_ev - t_before)
                        .map_err(|e| held_by_newton(e, solver.get_statistics()))?;
                    stats.restarts += 1;
                    solver = restart_at(problem, solver, &make, t_ev, &y_ev, stats, method)?;
                    match solver.set_stop_time(set) {
                        Ok(()) => continue,
                        // The event fell within roundoff of the stop.
                        Err(diffsol::DiffsolError::OdeSolverError(
                            diffsol::error::OdeSolverError::StopTimeAtCurrentTime,
                        )) if set == stop => break stop,
                        // A soft stop there: the next pass sets the next one.
                        Err(diffsol::DiffsolError::OdeSolverError(
                            diffsol::error::OdeSolverError::StopTimeAtCurrentTime,
                        )) => {
                            set = f64::NAN;
                            continue;
                        }
                        Err(e) => return Err(solver_err(set, e)),
                    }
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
                        budget
                            .step(t, h)
                            .map_err(|e| held_by_newton(e, solver.get_statistics()))?;
                        window.add(h, solver.order());
                        if window.steps == STALL_WINDOW {
                            let pace = (t - window.t) / STALL_WINDOW as f64;
                            // TMAX asks for span/TMAX steps: a stall takes
                            // ten times as many.
                            let projected = tmax
                                .map_or(STALL_PROJECTED, |m| STALL_PROJECTED.max(10.0 * span / m));
                            if method == Method::Bdf
                                && budget.taken() >= STALL_MIN_STEPS
                                && span > projected * pace
                                && window.held()
                            {
                                return Ok(Driven::Stalled(rec, solver, pace));
                            }
                            window = Window::new(t);
                        }
                        if let Some(p) = opts.progress
                            && last_report.elapsed() > Duration::from_millis(100)
                        {
                            p(t / t_end.max(1e-300));
                            last_report = Instant::now();
                        }
                    }
                    Ok(OdeSolverStopReason::TstopReached) if soft.is_some() => {
                        let t = solver.state().t;
                        budget
                            .step(t, solver.state().h.abs())
                            .map_err(|e| held_by_newton(e, solver.get_statistics()))?;
                        emit_grid(&solver, &mut rec, t, false)?;
                        if opts.all_steps && t >= tstart {
                            let y = solver.state().y.slice().to_vec();
                            insert_step(&mut rec, t, &y)?;
                        }
                    }
                    Ok(OdeSolverStopReason::TstopReached) => {
                        // A step onto a breakpoint counts too: a PULSE of
                        // femtosecond period is nothing but breakpoints.
                        budget
                            .step(stop, solver.state().h.abs())
                            .map_err(|e| held_by_newton(e, solver.get_statistics()))?;
                        break stop;
                    }
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
                            return Err(diagnose(names, problem, &solver, e));
                        }
                        rescues = Some((t, here + 1));
                        stats.rescues += 1;
                        solver = restart(problem, solver, &make, t, stats, method)?;
                        solver
                            .set_stop_time(stop)
                            .map_err(|e| solver_err(stop, e))?;
                        set = stop;
                    }
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
        // Restart after a corner: fresh history, recomputed slope and step
        // (the right-sided one: the next run's end set first).
        stats.restarts += 1;
        problem.eqn.tape.set_slope_end(stops[k + 1]);
        problem.eqn.tape.set_slope_start(solver.state().t);
        solver = restart(problem, solver, &make, reason, stats, method)?;
        k += 1;
    }
    problem.eqn.tape.set_slope_end(f64::INFINITY);
    problem.eqn.tape.set_slope_start(f64::NEG_INFINITY);
    Ok(Driven::Done(rec))
}

/// A run out of steps, told whether the integrator's Newton held its steps
/// back: the failures of its corrector and of its error test since the
/// last restart.
fn held_by_newton(mut e: SimError, s: &diffsol::ode_solver::OdeSolverStatistics) -> SimError {
    if let SimError::TooManySteps { newton, .. } = &mut e {
        *newton = Some((
            s.number_of_nonlinear_solver_fails,
            s.number_of_error_test_failures,
        ));
    }
    e
}

/// The error of a step that came back with a NaN time or size from
/// `t_before`: what went non-finite there, else an underflow at `t_before`.
fn non_finite_step<'p, M, S>(
    names: &NameTable<VarId>,
    problem: &'p OdeSolverProblem<CircuitOde<M>>,
    solver: &S,
    t_before: f64,
) -> SimError
where
    M: Matrix<T = f64>,
    M::V: HostVec,
    S: OdeSolverMethod<'p, CircuitOde<M>>,
{
    let e = diffsol::DiffsolError::from(diffsol::error::OdeSolverError::StepSizeTooSmall {
        time: t_before,
    });
    match diagnose(names, problem, solver, e) {
        SimError::NonFinite {
            name, value, what, ..
        } => SimError::NonFinite {
            name,
            value,
            t: t_before,
            what,
        },
        SimError::StepUnderflow { state, value, .. } => SimError::StepUnderflow {
            t: t_before,
            state,
            value,
        },
        other => other,
    }
}

/// The soft stop that keeps a step from `t` within `tmax` on the way to the
/// hard `stop`: none when `stop` itself is within reach, halfway when a full
/// `tmax` would leave less than `tmax` (never a sliver before `stop`).
fn soft_stop(t: f64, tmax: f64, stop: f64) -> Option<f64> {
    let left = stop - t;
    if left <= tmax * (1.0 + 1e-9) {
        None
    } else if left < 2.0 * tmax {
        Some(t + 0.5 * left)
    } else {
        Some(t + tmax)
    }
}

/// The shortest first step after a restart, in multiples of the step floor
/// (see [`restart_at`]).
const RESTART_STEP_FLOOR: f64 = 1e3;

/// Newton failures allowed within one step. A step that halves its way from
/// 1e-3 of the span down to diffsol's floor (1e-16 of it) fails about 50
/// times; four times that leaves the floor as what normally ends a step.
const NEWTON_FAILS_PER_STEP: usize = 200;

/// diffsol's default bounds on a step's growth (the same for BDF and the
/// SDIRK methods): a step grows by exactly this factor or not at all.
const STEP_GROWTH: f64 = 2.0;

/// What `drive` moves in the solver's configuration before every step.
pub(super) trait StepLimits {
    fn set_newton_fail_limit(&mut self, limit: usize);
    /// Let the next step grow to at most `cap` times the current one (TMAX
    /// over the step): the step never grows past TMAX only to be cut back
    /// to it. diffsol cuts a step to a stop time without refactoring its
    /// Newton matrix, which was just factored for the longer step: at
    /// `h·λ` of 10^6 (a junction's charge behind its series resistance)
    /// that matrix is off by the ratio of the steps, its Newton diverges,
    /// and the step is taken again with a fresh one. VACASK's graetz
    /// (TMAX 1 µs) failed Newton on 169,322 of 1.2·10^6 steps so.
    fn cap_growth(&mut self, cap: f64);
}

/// The growth bounds for `cap` (see [`StepLimits::cap_growth`]): diffsol's
/// defaults, or exactly `cap` where it is below them (a step that grows
/// grows onto TMAX), or none at TMAX. A cap within rounding of 1 is none:
/// every change of step resets BDF's count of equal steps, and a change by
/// an ulp every step would keep it from ever raising its order.
fn growth_bounds(cap: f64) -> (f64, f64) {
    if cap >= STEP_GROWTH {
        (STEP_GROWTH, STEP_GROWTH)
    } else if cap > 1.0 + 1e-6 {
        (cap, cap)
    } else {
        (1.0, STEP_GROWTH)
    }
}

impl StepLimits for diffsol::BdfConfig<f64> {
    fn set_newton_fail_limit(&mut self, limit: usize) {
        self.maximum_newton_fails = limit;
    }
    fn cap_growth(&mut self, cap: f64) {
        (self.maximum_timestep_growth, self.minimum_timestep_growth) = growth_bounds(cap);
    }
}

impl StepLimits for diffsol::SdirkConfig<f64> {
    fn set_newton_fail_limit(&mut self, limit: usize) {
        self.maximum_newton_fails = limit;
    }
    fn cap_growth(&mut self, cap: f64) {
        (self.maximum_timestep_growth, self.minimum_timestep_growth) = growth_bounds(cap);
    }
}

/// Explicit methods solve no equations, and a step cut to a stop costs
/// them nothing.
impl StepLimits for diffsol::ExplicitRkConfig<f64> {
    fn set_newton_fail_limit(&mut self, _: usize) {}
    fn cap_growth(&mut self, _: f64) {}
}

/// Add the counters of one solver's life (up to a restart or the end).
pub(super) fn add_solver_stats<'p, M, S>(stats: &mut Stats, solver: &S)
where
    M: Matrix<T = f64>,
    M::V: HostVec,
    S: OdeSolverMethod<'p, CircuitOde<M>>,
{
    let s = solver.get_statistics();
    stats.steps += s.number_of_steps;
    stats.rejected += s.number_of_error_test_failures;
    stats.newton_fails += s.number_of_nonlinear_solver_fails;
    stats.lu_factorizations += s.number_of_linear_solver_setups;
}

/// A new solver from `solver`'s state at `t`: fresh history (order 1),
/// recomputed slope and initial step. Its statistics go into `stats`.
pub(super) fn restart<'p, M, S, T>(
    problem: &'p OdeSolverProblem<CircuitOde<M>>,
    solver: S,
    make: &impl Fn(&'p OdeSolverProblem<CircuitOde<M>>, T::State) -> Result<T, diffsol::DiffsolError>,
    t: f64,
    stats: &mut Stats,
    method: Method,
) -> Result<T, SimError>
where
    M: Matrix<T = f64>,
    M::V: HostVec,
    S: OdeSolverMethod<'p, CircuitOde<M>>,
    T: OdeSolverMethod<'p, CircuitOde<M>>,
{
    let y = solver.state().y.slice().to_vec();
    restart_at(problem, solver, make, t, &y, stats, method)
}

/// [`restart`] from `(t, y)`, a point inside the step just taken (a
/// located switch event).
pub(super) fn restart_at<'p, M, S, T>(
    problem: &'p OdeSolverProblem<CircuitOde<M>>,
    solver: S,
    make: &impl Fn(&'p OdeSolverProblem<CircuitOde<M>>, T::State) -> Result<T, diffsol::DiffsolError>,
    t: f64,
    y: &[f64],
    stats: &mut Stats,
    method: Method,
) -> Result<T, SimError>
where
    M: Matrix<T = f64>,
    M::V: HostVec,
    S: OdeSolverMethod<'p, CircuitOde<M>>,
    T: OdeSolverMethod<'p, CircuitOde<M>>,
{
    add_solver_stats(stats, &solver);
    let h_before = solver.state().h.abs();
    let mut common = solver.into_state().into_common();
    common.t = t;
    common.y.slice_mut().copy_from_slice(y);
    let mut dy = vec![0.0; y.len()];
    problem
        .eqn
        .eval(t, y, &mut dy)
        .map_err(|error| SimError::Eval { error })?;
    common.dy.slice_mut().copy_from_slice(&dy);
    let mut state = T::State::new_from_common(common);
    state.as_mut().set_step_size(
        problem.h0,
        &problem.atol,
        problem.rtol,
        &problem.eqn,
        method.start_order(),
    );
    // The SDIRK methods' embedded error estimate let a first step of 300
    // times the one before through, wrong by volts, at a breakpoint where a
    // CMOS inverter chain's junctions turn (`mos1_inverter_chain` under
    // TR-BDF2 and ESDIRK34 at rtol 1e-7: the run then failed, or went on from
    // a wrong state): their first step is at most the one the solver would
    // have taken next. BDF's order-1 start from the same probe was right
    // there (its default run passes), and is left alone.
    let h = state.as_mut().h;
    if matches!(method, Method::TrBdf2 | Method::Esdirk34) && h_before > 0.0 && h.abs() > h_before {
        *h = h_before.copysign(*h);
    }
    // diffsol sizes the first step by an explicit Euler probe, which a fast
    // mode (a floored gate capacitance) can drive to 1e-24 s, below the step
    // floor: the run would end there. Restart at no less than
    // [`RESTART_STEP_FLOOR`] times the floor; above it the probe's step
    // stands (a larger one, a tenth of the step before as ngspice restarts,
    // costs accuracy at a corner on a virtual ground: measured on
    // `opamp_adder_tstart`).
    floor_first_step(problem, state.as_mut().h);
    make(problem, state).map_err(|e| solver_err(t, e))
}

/// A first step `h` raised to [`RESTART_STEP_FLOOR`] times the step floor
/// (see [`restart_at`]).
fn floor_first_step<M: Matrix<T = f64>>(problem: &OdeSolverProblem<CircuitOde<M>>, h: &mut f64)
where
    M::V: HostVec,
{
    let least = RESTART_STEP_FLOOR * problem.ode_options.min_timestep;
    if h.is_finite() && h.abs() < least {
        *h = if *h < 0.0 { -least } else { least };
    }
}

/// `solver` as diffsol started it, its first step raised as after a restart
/// (see [`restart_at`]).
fn floored_start<'p, M, S>(
    problem: &'p OdeSolverProblem<CircuitOde<M>>,
    solver: S,
    make: &impl Fn(&'p OdeSolverProblem<CircuitOde<M>>, S::State) -> Result<S, diffsol::DiffsolError>,
) -> Result<S, SimError>
where
    M: Matrix<T = f64>,
    M::V: HostVec,
    S: OdeSolverMethod<'p, CircuitOde<M>>,
{
    let mut h = solver.state().h;
    floor_first_step(problem, &mut h);
    if h == solver.state().h {
        return Ok(solver);
    }
    let t = solver.state().t;
    let mut state = solver.into_state();
    *state.as_mut().h = h;
    make(problem, state).map_err(|e| solver_err(t, e))
}

/// Record the grid points up to `t` (inclusive when `at_stop`).
pub(super) fn emit_grid<'p, M, S>(
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

/// Evaluates `at` on times from `from` (solved) to `to`: each interval
/// half the last failed one or twice the last solved one, until `to` is
/// solved or an interval falls below `resolution` or 400 evaluations
/// (`Err`: the last failure).
fn approach<E>(
    from: f64,
    to: f64,
    resolution: f64,
    stats: &mut Stats,
    mut at: impl FnMut(f64) -> Result<(), E>,
) -> Result<(), E> {
    let (mut a, mut h) = (from, 0.5 * (to - from));
    let mut last = None;
    for _ in 0..400 {
        let b = if a + h >= to { to } else { a + h };
        stats.rhs_evals += 1;
        match at(b) {
            Ok(()) if b == to => return Ok(()),
            Ok(()) => {
                a = b;
                h *= 2.0;
            }
            Err(e) => {
                last = Some(e);
                h *= 0.5;
                if h < resolution {
                    break;
                }
            }
        }
    }
    match last {
        Some(e) => Err(e),
        None => at(to),
    }
}

/// A circuit without states: every output is a function of time alone, so
/// it is evaluated on the grid (and at the source corners with `--all-steps`).
/// Its switches change state at their controls' crossings, located between
/// the grid's points and the sources' corners by bisection in time (see
/// [`super::events::Switches::first_crossing_stateless`]).
pub(super) fn algebraic(
    sorted: &Sorted,
    tape: Rc<Tape>,
    tran: &crate::elab::Tran,
    outputs: &[Output],
    opts: &Options,
    switches: &super::events::Switches,
    sink: Option<RowSink<'_>>,
) -> Result<Waveforms, SimError> {
    let sys = sorted.system();
    let c = &sorted.elaborated.circuit;
    // The operating point with the `.ic` nodes held, output at t = 0.
    let mut warnings = Vec::new();
    let mut held = None;
    if !tran.uic && !c.ics.is_empty() && switches.is_empty() {
        match ic::held_operating_point(sorted, &[], outputs, opts, &c.ics, ".ic", false) {
            Ok(h) => {
                held = Some(h.row);
                warnings = h.warnings;
            }
            Err(ic::Unheld::Sim(e)) => return Err(ic::held_failure(c, &c.ics, ".ic", e)),
            Err(ic::Unheld::Structure(why)) => warnings.push(ic::unheld_warning(c, &why)),
        }
    }
    let mut times = opts
        .times
        .clone()
        .map_or_else(|| Grid::of(tran), Grid::Times);
    let hard = breakpoints(sys, 0.0, tran.tstop);
    if opts.all_steps {
        let mut all: Vec<f64> = (0..times.len()).map(|k| times.at(k)).collect();
        all.extend(hard.iter().copied().filter(|&t| t >= tran.tstart));
        all.sort_by(f64::total_cmp);
        all.dedup();
        times = Grid::Times(all);
    }
    let ode = CircuitOde::<NalgebraMat<f64>>::new(tape.clone(), Vec::new(), false)?;
    let mut out = vec![0.0; tape.out_regs.len()];
    let mut rows = Rows::new(out.len(), sink);
    let mut stats = Stats::default();
    // The switches' states at the operating point (off unless `on`, then
    // by their controls, as the operating point of a circuit with states).
    let t0 = 0.0;
    switches.apply(&ode);
    if !switches.is_empty() && !tran.uic {
        for _ in 0..=switches.len() {
            if !switches.settle(&ode, t0, &[])? {
                break;
            }
        }
    }
    // The crossings are searched from 0 over every output point and source
    // corner; the search's resolution is that of the time axis.
    let resolution = 1e-12 * tran.tstop.abs().max(f64::MIN_POSITIVE);
    let mut corners = hard.into_iter().filter(|&t| t > t0).peekable();
    let mut searched = t0;
    let mut search_to = |t: f64, ode: &CircuitOde<NalgebraMat<f64>>| -> Result<(), SimError> {
        if switches.is_empty() {
            return Ok(());
        }
        while searched < t {
            let b = match corners.peek() {
                Some(&k) if k < t => {
                    corners.next();
                    k
                }
                _ => t,
            };
            while let Some((te, x)) =
                switches.first_crossing_stateless(ode, searched, b, resolution)?
            {
                switches.commit_chain(ode, te, x)?;
                searched = te;
            }
            searched = b;
        }
        Ok(())
    };
    // The last time whose loops were solved.
    let mut solved: Option<f64> = None;
    for k in 0..times.len() {
        let t = times.at(k);
        let first = k == 0 && t == 0.0;
        if first && let Some(row) = held.take() {
            rows.push(t, &row)?;
            continue;
        }
        search_to(t, &ode)?;
        // The first point is the DC operating point unless `uic`.
        let mode = if first && !tran.uic {
            Mode::Dc
        } else {
            Mode::Transient
        };
        let at = |t: f64, out: &mut [f64]| tape.in_mode(mode, || ode.outputs(t, &[], out));
        stats.rhs_evals += 1;
        if let Err(error) = at(t, &mut out) {
            // A loop whose Newton fails from the last point's solution may
            // follow its solution there in time: shorter intervals from the
            // last point solved, each warm-started from the one before
            // (continuation in time, as a step cut is for a circuit with
            // states).
            let Some(from) = solved.filter(|_| mode == Mode::Transient) else {
                return Err(SimError::Eval { error });
            };
            approach(from, t, resolution, &mut stats, |t| at(t, &mut out))
                .map_err(|_| SimError::Eval { error })?;
        }
        solved = Some(t);
        rows.push(t, &out)?;
    }
    let mut w = rows.into_waveforms(stats);
    w.warnings = warnings;
    w.events = switches.events.take();
    Ok(w)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A loop that converges only from within 0.1 of its last solution:
    /// the approach halves its intervals down to that, then lengthens them.
    #[test]
    fn the_approach_follows_a_loop_in_short_intervals() {
        let mut last = 0.0;
        let mut stats = Stats::default();
        let result = approach(0.0, 1.0, 1e-12, &mut stats, |t: f64| {
            if t - last > 0.1 {
                return Err(t);
            }
            last = t;
            Ok(())
        });
        assert_eq!(result, Ok(()));
        assert_eq!(last, 1.0);
        assert!(stats.rhs_evals < 40, "{} evaluations", stats.rhs_evals);
        // One that converges nowhere past its start ends with its failure.
        let result = approach(0.0, 1.0, 1e-6, &mut stats, |t: f64| Err(t));
        assert!(matches!(result, Err(t) if t < 1e-5), "{result:?}");
    }
}
