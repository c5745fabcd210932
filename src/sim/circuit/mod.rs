//! kausal's own integrator for circuits (`--method circuit`): TR-BDF2, the
//! one-step method that Bank et al. designed for circuit and device
//! simulation (IEEE TCAD 1985), on the causal ODE `y' = f(t, y)`, with the
//! error control of a circuit simulator.
//!
//! Each step is a trapezoidal stage to `t + γh` and a BDF2 stage through
//! `t`, `t + γh`, `t + h` (`γ = 2 - √2`); both iterate on the same matrix
//! `I - (γ/2) h J`. The method is L-stable and second order, and as a
//! one-step method it restarts at a source corner and lands on an output
//! point without losing anything.
//!
//! What differs from diffsol's BDF, and why (measured on the bridge
//! rectifiers of `netlists/`, where BDF needs 60–110 steps per diode
//! switching event):
//! - **The error is measured against each state's largest magnitude so
//!   far** (a circuit simulator's "sigglobal" reference), not against its
//!   value now: a junction charge passing through zero, or a diode current
//!   decaying through nanoamperes after the diode turned off, is not
//!   followed to a relative accuracy that no signal of the circuit shows.
//! - **The local error estimate is filtered** through `(I - (γ/2) h J)⁻¹`
//!   (Hosea & Shampine 1996): a stiff component (a reverse-biased
//!   junction's charge, relaxing in picoseconds through its series
//!   resistance) is damped by the method itself, and its raw estimate
//!   overstates its error by the stiffness ratio.
//! - **Newton is measured against each state's own magnitude**, to at
//!   least 1e-3 relative whatever the rtol: a junction charge sets the
//!   current through its series resistance amplified by 1/(C·RS), so a
//!   corrector that stopped at the looser error-test scale lets the junction
//!   currents (and from them every other state) drift. The Jacobian is kept
//!   across steps. Where `f` depends on the states nonlinearly only through
//!   junctions (`Tape::jacobian_follows_junctions`: every circuit of diodes
//!   with charge and linear elements), rescaling each junction's column by
//!   its `Q′` and moving its diagonal by its `g_d` makes the kept Jacobian
//!   the Jacobian of any iterate: Newton then converges as full Newton for
//!   an evaluation per iterate, and one iterate suffices where its
//!   correction barely moves the junctions (measured in the currents
//!   through their series resistances, as a circuit simulator tests each
//!   device's current). Elsewhere, when the kept Jacobian cannot take a
//!   stage (a junction turning on bends `f` faster than one Jacobian
//!   follows), each iterate gets its own.
//! - **With junction charges, steps end on every output point** (and every
//!   source corner): the state there is the solver's own, on its slow
//!   manifold, where an interpolated one needs its charges settled by Newton
//!   steps (`Recorder::settle_charges`) that cost as much as a step. Without,
//!   output points are the step's cubic Hermite interpolant.
//! - **At a step's end the outputs come from the last Newton iterate's
//!   evaluation** where they are affine in the states and junction voltages
//!   (`Tape::outputs_follow_junctions`): `out(x − δ) + (∂out/∂y)·δ`, their
//!   Jacobian computed and followed with `J`, instead of the output program,
//!   which solves the junction charges' inversions and the loops again (18 %
//!   of VACASK's mul, which writes every step).
//!
//! `--method gear2` takes the steps after the first as one variable-step
//! BDF2 stage each (ngspice's gear of order 2), with the same Newton, error
//! scale and junction handling: half the work where TMAX or the output
//! points set the steps, several times TR-BDF2's error there.
//!
//! `--method circuit` (`sim::trbdf2`) measures Newton's corrections against
//! each state's own magnitude but its local error against the state's largest
//! magnitude so far: a junction charge's error reaches its current amplified
//! by 1/(C·RS), so the corrector must converge it locally, while the error
//! test need not follow it through zero. With junction charges every output
//! point is a step (as `settle_charges` would cost a step per point);
//! without, outputs are the step's cubic Hermite interpolant. A junction
//! charge is predicted through its voltage (read from the inversion's memo
//! registers, `CircuitOde::register`), and the kept Jacobian's junction
//! columns are rescaled by `Q′` and its diagonal moved by `g_d`: this is
//! exact when `f` reads a charge only through its junction voltage and `q' =
//! i - i_d(v)` (`build`'s diode law), approximate where index reduction
//! rewrote a junction's equations, and either way only the iteration matrix:
//! Newton's convergence test decides. Where
//! `Tape::jacobian_follows_junctions` proves that exactness (an abstract
//! interpretation of the tape: every register is constant, a function of
//! time, affine in the states, a junction voltage, or affine plus one
//! junction current, which must end in its own charge's derivative), the
//! Jacobian is followed to every iterate and an iterate is accepted on `θ`
//! (how far its correction moves `g_d` and `Q′`) and on each junction's
//! current through RS against its largest current so far; the error test
//! measures a junction charge also as a voltage, `δq/Q′` against its largest
//! junction voltage. Where the proof fails (a resistive diode, a product of
//! signals) Newton falls back to the kept-Jacobian rate test and a Jacobian
//! per iterate.

mod junction;
mod newton;

use super::ode::{CircuitOde, HostVec, Regs};
use super::*;
use crate::ir::{NameTable, VarId};
use crate::numeric::dense::{lu_factor_inv, lu_solve_inv};
use crate::tape::{ChargeInverse, EvalError};
use diffsol::Matrix;

/// A step within this fraction of the next stop is taken to the stop.
const STOP_ROUNDING: f64 = 1e-9;

/// `γ = 2 - √2`: both stages then share one iteration matrix, and the
/// method is L-stable.
const GAMMA: f64 = 2.0 - std::f64::consts::SQRT_2;
/// The local error is `C h³ y'''` with `C = (-3γ² + 4γ - 2) / (12 (2 - γ))`.
const ERROR_CONSTANT: f64 = (-3.0 * GAMMA * GAMMA + 4.0 * GAMMA - 2.0) / (12.0 * (2.0 - GAMMA));
/// Newton iterations per stage before the Jacobian is refreshed (or the
/// step cut).
const MAX_ITERATIONS: usize = 4;
/// The corrector stops when its estimated remaining error is this fraction
/// of the error test's tolerance (CVODE's coefficient; see `sim::run`).
const NEWTON_TOLERANCE: f64 = 0.1;
/// The corrector converges to at least this relative accuracy, whatever
/// the error test's rtol (as a circuit simulator's Newton converges to its
/// RELTOL while TRTOL loosens its truncation test): a junction charge left
/// 1e-3 off reaches its current amplified by 1/(C·RS).
const NEWTON_RTOL: f64 = 1e-3;
/// A first correction this small (relative to the tolerance) ends the
/// iteration at once: the predictor is already right. The rate of earlier
/// iterations (CVODE's test) is not trusted for this: at a diode's turn-on
/// it is the rate of the reverse-biased circuit before it.
const FIRST_CORRECTION: f64 = 0.01;
/// The least `θ` of [`TrBdf2::followed_newton`]'s convergence test on the
/// weighted correction: what the junctions' `θ` does not see (rounding in
/// the kept Jacobian, which rescaling accumulates over up to
/// [`JACOBIAN_AGE`] steps) is taken as at most this.
const FOLLOW_FLOOR: f64 = 1e-2;
/// Up to this many states the iteration matrix is refactored whenever a
/// junction moves at all (an LU of a few states costs less than an
/// evaluation).
const EXACT_FOLLOW_STATES: usize = 16;
/// The most a step may grow under `--method gear2`: variable-step BDF2 is
/// zero-stable for step ratios below `1 + √2`.
const BDF2_GROWTH: f64 = 2.0;
/// Steps a Jacobian is kept at most.
const JACOBIAN_AGE: usize = 20;

/// The iteration matrix `I - β J` and the Jacobian it is built from.
struct Newton {
    /// Row-major `J`.
    jac: Vec<f64>,
    /// Row-major LU of `I - β J` and its row order.
    lu: Vec<f64>,
    perm: Vec<usize>,
    beta: f64,
    factored: bool,
    /// `J` no longer describes the circuit well (a stage needed three
    /// iterations; refreshing on a slow rate alone cost more Jacobians than
    /// it saved iterations on the bridges).
    stale: bool,
    /// Accepted steps since `J` was computed.
    age: usize,
    /// Row-major `∂out/∂y` of the outputs after an evaluation, computed
    /// with `J` and followed with it (only where
    /// [`TrBdf2::outputs_follow`]); empty otherwise.
    out_jac: Vec<f64>,
    /// The estimated contraction rate of the iteration (CVODE's `crate`),
    /// carried from stage to stage; 1 after a new Jacobian.
    rate: f64,
    /// The last stage needed a Jacobian at every iterate, three or more:
    /// the next goes there at once (a junction's turn-on or turn-off lasts
    /// several steps, and the kept Jacobian's attempt only cost evaluations).
    full: bool,
}

/// A junction-charge state. Its charge grows exponentially with its
/// junction voltage, which moves smoothly through a diode's turn-on: the
/// predictor extrapolates the voltage and takes its charge, where a
/// polynomial in the charge itself missed by orders of magnitude and sent
/// each stage of a rectifier's conduction to a Jacobian per iteration.
struct Junction {
    /// Index in `y`.
    k: usize,
    ci: ChargeInverse,
    /// The junction voltage at the current and the previous point, and its
    /// slope at the current point (`dv/dt = q'/Q'(v)`).
    v: f64,
    v_prev: f64,
    dv: f64,
    /// `Q′` and `g_d` where the kept Jacobian is now, and at the point it
    /// is to follow to (the predictor's, or the last iterate's).
    cap_j: f64,
    gd_j: f64,
    cap_p: f64,
    gd_p: f64,
    /// The relative curvature of `g_d` and `Q′` at the last iterate,
    /// `max(|g_d′/g_d|, |Q″/Q′|)` (per volt).
    curv: f64,
    /// The largest junction voltage so far (magnitude).
    v_peak: f64,
    /// The junction current `i_d` at the last iterate, and the largest
    /// current through the junction (`q′ + i_d`) so far: the scale of its
    /// error.
    id: f64,
    i_peak: f64,
}

/// A stage's implicit equation `x = c + β f(t, x)` and what its Newton
/// iteration works with, `n` each.
struct Stage {
    /// The iterate, and `f` at it.
    x: Vec<f64>,
    f: Vec<f64>,
    /// The stage's constant part `c`.
    c: Vec<f64>,
    /// The predictor, kept to restart the iteration from.
    pred: Vec<f64>,
    /// A Newton correction, or the step's local error estimate.
    delta: Vec<f64>,
    /// Newton's weights: one over each state's convergence tolerance.
    weight: Vec<f64>,
    /// Scratch of the LU solves.
    scratch: Vec<f64>,
}

impl Stage {
    fn new(n: usize) -> Stage {
        Stage {
            x: vec![0.0; n],
            f: vec![0.0; n],
            c: vec![0.0; n],
            pred: vec![0.0; n],
            delta: vec![0.0; n],
            weight: vec![0.0; n],
            scratch: vec![0.0; n],
        }
    }
}

/// The end of a step's TR stage, `t + γh`: its state, `f` there and the
/// junction voltages, which the BDF2 stage's predictor and the error
/// estimate read.
struct Gamma {
    y: Vec<f64>,
    f: Vec<f64>,
    v: Vec<f64>,
}

/// How Newton with the kept Jacobian ended.
enum Iteration {
    Converged,
    /// Converging, but too slowly to finish in the iterations allowed.
    Slow,
    /// Diverging, or an evaluation failed.
    Failed,
}

/// Why an attempted step did not end.
enum Attempt {
    Accepted,
    /// The error test failed; `h` holds the step to try next.
    Rejected,
    /// A stage's Newton iteration failed.
    NoConvergence,
}

/// The integrator's state between steps.
pub(super) struct TrBdf2<'a, M: Matrix<T = f64>>
where
    M::V: HostVec,
{
    ode: &'a CircuitOde<M>,
    n: usize,
    rtol: f64,
    atol: Vec<f64>,
    /// The absolute tolerance of a current.
    atol_i: f64,
    /// The last accepted point and `f` there.
    pub t: f64,
    pub y: Vec<f64>,
    f: Vec<f64>,
    /// The point before it, for the first stage's predictor (none after a
    /// restart).
    prev: Option<f64>,
    y_prev: Vec<f64>,
    /// `f` at the previous point (the step's cubic Hermite interpolant).
    f_prev: Vec<f64>,
    /// The next step to try, and the longest step allowed.
    h: f64,
    h_cap: f64,
    h_min: f64,
    /// Each state's largest magnitude so far: the scale of its error.
    peak: Vec<f64>,
    newton: Newton,
    pub stats: Stats,
    /// The first evaluation error of the step being tried.
    error: Option<EvalError>,
    /// The state whose error limited the last rejected step.
    worst: usize,
    /// The stage being solved.
    stage: Stage,
    /// The end of the step's TR stage.
    gamma: Gamma,
    /// Every state index (the columns of a whole Jacobian).
    columns: Vec<usize>,
    /// The junction charges among the states, predicted through their
    /// junction voltages (see [`Junction`]).
    junctions: Vec<Junction>,
    /// Each junction charge's error scale as a voltage error (`Q′` times
    /// its largest voltage); infinite for the other states.
    jscale: Vec<f64>,
    no_growth: bool,
    /// Steps with history are one BDF2 stage (`--method gear2`), not
    /// TR-BDF2's two.
    bdf2: bool,
    /// `f` depends on the states nonlinearly only through junctions that
    /// [`TrBdf2::follow_junctions`] follows exactly
    /// ([`crate::tape::Tape::jacobian_follows_junctions`]).
    exact: bool,
    /// With `exact`, the outputs after an evaluation are affine in the
    /// states and junction voltages
    /// ([`crate::tape::Tape::outputs_follow_junctions`]): at a step's end
    /// they are read from the last iterate's registers and carried through
    /// its correction by their followed Jacobian, not computed again.
    outputs_follow: bool,
}

impl<'a, M: Matrix<T = f64>> TrBdf2<'a, M>
where
    M::V: HostVec,
{
    /// The integrator at `t0` from `setup`, with steps no shorter than
    /// `h_min`.
    pub fn new(
        ode: &'a CircuitOde<M>,
        setup: Setup,
        t0: f64,
        h_min: f64,
    ) -> Result<Self, SimError> {
        let Setup {
            rtol,
            atol,
            atol_current: atol_i,
            y0,
            h0,
            h_cap,
            bdf2,
        } = setup;
        let n = y0.len();
        let mut f = vec![0.0; n];
        ode.eval(t0, &y0, &mut f)
            .map_err(|error| SimError::Eval { error })?;
        let peak = y0.iter().map(|v| v.abs()).collect();
        let junctions: Vec<Junction> = ode
            .tape
            .charge_states()
            .into_iter()
            .enumerate()
            .filter_map(|(k, ci)| {
                Some(Junction {
                    k,
                    ci: ci?,
                    v: f64::NAN,
                    v_prev: f64::NAN,
                    dv: f64::NAN,
                    cap_j: f64::NAN,
                    gd_j: f64::NAN,
                    cap_p: f64::NAN,
                    gd_p: f64::NAN,
                    curv: f64::NAN,
                    v_peak: 0.0,
                    id: f64::NAN,
                    i_peak: 0.0,
                })
            })
            .collect();
        let vz = vec![f64::NAN; junctions.len()];
        let exact = ode.tape.jacobian_follows_junctions();
        let outputs_follow = exact && ode.tape.outputs_follow_junctions();
        let n_out = if outputs_follow {
            ode.tape.tail_regs.len()
        } else {
            0
        };
        let mut s = TrBdf2 {
            ode,
            n,
            rtol,
            atol,
            atol_i,
            t: t0,
            y: y0,
            f,
            prev: None,
            y_prev: vec![0.0; n],
            f_prev: vec![0.0; n],
            h: h0.min(h_cap),
            h_cap,
            h_min,
            peak,
            newton: Newton {
                jac: vec![0.0; n * n],
                lu: vec![0.0; n * n],
                perm: vec![0; n],
                beta: f64::NAN,
                factored: false,
                stale: true,
                age: 0,
                out_jac: vec![0.0; n_out * n],
                rate: 1.0,
                full: false,
            },
            stats: Stats::default(),
            error: None,
            worst: 0,
            stage: Stage::new(n),
            gamma: Gamma {
                y: vec![0.0; n],
                f: vec![0.0; n],
                v: vz,
            },
            columns: (0..n).collect(),
            junctions,
            jscale: vec![f64::INFINITY; n],
            no_growth: false,
            bdf2,
            exact,
            outputs_follow,
        };
        s.read_junctions(false);
        Ok(s)
    }

    /// The outputs at the end of the step just accepted, from the
    /// registers of its last Newton iterate `x − δ` (the output program
    /// would solve the junction charges' inversions and the loops again):
    /// `out(x − δ) + (∂out/∂y)·δ`. The outputs are affine in the states and
    /// junction voltages (`outputs_follow`), and `∂out/∂y` was followed to
    /// the iterate's junctions with `J`, so what is left is second order
    /// in `δ`, as the state's own Newton error is. Read as they are, the
    /// iterate's outputs were first order off: a junction's charge
    /// correction reaches the current through its series resistance
    /// amplified by `1/(C·RS)` (a clamp's nA current 12 times its range
    /// off at rtol 1e-7).
    fn outputs_at_end(&self, t: f64, out: &mut [f64]) -> Result<(), EvalError> {
        self.ode.outputs_after_rhs(t, out)?;
        let n = self.n;
        // δ: the accepted state less the iterate's, which the evaluation
        // left in the state registers.
        let regs = &self.ode.tape.state_regs;
        for (o, v) in out.iter_mut().enumerate() {
            let row = &self.newton.out_jac[o * n..(o + 1) * n];
            *v += row
                .iter()
                .zip(self.y.iter().zip(regs))
                .map(|(g, (y, &r))| g * (y - self.ode.register(r)))
                .sum::<f64>();
        }
        Ok(())
    }

    /// Start afresh from the current point (a source corner): `f` there,
    /// and no history for the predictor.
    pub fn restart(&mut self) -> Result<(), SimError> {
        self.ode
            .eval(self.t, &self.y, &mut self.f)
            .map_err(|error| SimError::Eval { error })?;
        self.prev = None;
        self.read_junctions(false);
        self.stats.restarts += 1;
        Ok(())
    }

    /// One accepted step of at most `h_max`; a step that reaches
    /// `t + h_max` lands on it exactly.
    pub fn step(&mut self, h_max: f64, names: &NameTable<VarId>) -> Result<(), SimError> {
        let mut failures = 0usize;
        loop {
            let mut h = self.h.min(self.h_cap).min(h_max);
            if h < h_max {
                if h_max - h <= STOP_ROUNDING * h_max {
                    // Short of the stop by rounding only (a TMAX equal to
                    // the output spacing, whose points are products and
                    // sums of it): land on it.
                    h = h_max;
                } else if h > 0.5 * h_max {
                    // No sliver before the stop: two even steps instead.
                    h = 0.5 * h_max;
                }
            }
            if h.is_nan() || h < self.h_min {
                return Err(self.underflow(names));
            }
            self.error = None;
            let attempt = self.attempt(h);
            if matches!(attempt, Attempt::Accepted) {
                return Ok(());
            }
            failures += 1;
            if matches!(attempt, Attempt::NoConvergence) {
                self.stats.newton_fails += 1;
                self.h = 0.25 * h;
                self.no_growth = true;
            } else {
                self.stats.rejected += 1;
            }
            if failures >= 3 {
                // A kink in the history (a diode that switched): predict
                // from this point alone, with a fresh Jacobian.
                self.prev = None;
                self.newton.stale = true;
            }
        }
    }

    /// The step size underflowed: name the state that kept it small.
    fn underflow(&self, names: &NameTable<VarId>) -> SimError {
        if let Some(error) = self.error.clone() {
            return SimError::Eval { error };
        }
        let k = self.worst.min(self.n.saturating_sub(1));
        SimError::StepUnderflow {
            t: self.t,
            state: self
                .ode
                .tape
                .states
                .get(k)
                .map_or_else(String::new, |&v| names.get(v).to_string()),
            value: self.y.get(k).copied().unwrap_or(f64::NAN),
        }
    }

    /// Try one step of `h` from the current point.
    fn attempt(&mut self, h: f64) -> Attempt {
        match self.prev {
            Some(tp) if self.bdf2 => self.attempt_bdf2(h, tp),
            _ => self.attempt_tr_bdf2(h),
        }
    }

    /// One TR-BDF2 step of `h`.
    fn attempt_tr_bdf2(&mut self, h: f64) -> Attempt {
        let n = self.n;
        let beta = 0.5 * GAMMA * h;
        let s = GAMMA * h;
        let (tg, t1) = (self.t + s, self.t + h);
        // Stage 1, the trapezoidal rule to t + γh, predicted by the
        // quadratic through the previous point with the slope here.
        for i in 0..n {
            self.stage.c[i] = self.y[i] + beta * self.f[i];
            self.stage.x[i] = self.y[i] + s * self.f[i];
        }
        if let Some(tp) = self.prev {
            let hp = self.t - tp;
            for i in 0..n {
                let c2 = (self.y_prev[i] - self.y[i] + hp * self.f[i]) / (hp * hp);
                self.stage.x[i] += s * s * c2;
            }
            self.predict_junctions(-hp, s, |_, jn| jn.v_prev);
        } else {
            // The line: a quadratic through v(0) twice.
            self.predict_junctions(1.0, s, |_, jn| jn.v + jn.dv);
        }
        if !self.stage(tg, beta) {
            return Attempt::NoConvergence;
        }
        for i in 0..n {
            self.gamma.y[i] = self.stage.x[i];
            self.gamma.f[i] = (self.stage.x[i] - self.stage.c[i]) / beta;
        }
        for j in 0..self.junctions.len() {
            let Junction { k, ci, .. } = self.junctions[j];
            self.gamma.v[j] = self
                .junction_voltage(ci, self.gamma.y[k])
                .map_or(f64::NAN, |(v, _)| v);
        }
        // Stage 2, BDF2 through t, t + γh and t + h, predicted by the
        // quadratic through y, y' here and the first stage.
        let a = 1.0 / (GAMMA * (2.0 - GAMMA));
        let b = (1.0 - GAMMA) * (1.0 - GAMMA) / (GAMMA * (2.0 - GAMMA));
        for i in 0..n {
            self.stage.c[i] = a * self.gamma.y[i] - b * self.y[i];
            let c2 = (self.gamma.y[i] - self.y[i] - s * self.f[i]) / (s * s);
            self.stage.x[i] = self.y[i] + h * self.f[i] + h * h * c2;
        }
        let vz = std::mem::take(&mut self.gamma.v);
        self.predict_junctions(s, h, |j, _| vz[j]);
        self.gamma.v = vz;
        if !self.stage(t1, beta) {
            return Attempt::NoConvergence;
        }
        for i in 0..n {
            self.stage.f[i] = (self.stage.x[i] - self.stage.c[i]) / beta;
        }
        // The local error C h³ y''', y''' from 2·f[t, t + γh, t + h],
        // filtered through (I - βJ)⁻¹.
        for i in 0..n {
            let dd0 = (self.gamma.f[i] - self.f[i]) / s;
            let dd1 = (self.stage.f[i] - self.gamma.f[i]) / (h - s);
            self.stage.delta[i] = 2.0 * ERROR_CONSTANT * h * h * (dd1 - dd0);
        }
        // Under gear2 the BDF2 step after it grows by no more than its own.
        self.conclude(h, if self.bdf2 { BDF2_GROWTH } else { 4.0 })
    }

    /// One variable-step BDF2 step of `h` through the previous point `tp`:
    /// `y₊ = α₁ y - α₂ y₋ + β f(t + h, y₊)` with `ω = h / (t - tp)`,
    /// `α₁ = (1+ω)²/(1+2ω)`, `α₂ = ω²/(1+2ω)`, `β = h (1+ω)/(1+2ω)`. One
    /// implicit stage per step where TR-BDF2 has two: a step bound by TMAX
    /// or the output spacing (ngspice's gear of order 2 on VACASK's graetz)
    /// costs half as much. Its local error is
    /// `(1+ω)² / (6ω(1+2ω)) h³ y'''` (2/9 h³ y''' at equal steps, 5.5 times
    /// TR-BDF2's), with `y'''` from the divided differences of `f` over the
    /// three points. The step grows by at most [`BDF2_GROWTH`].
    fn attempt_bdf2(&mut self, h: f64, tp: f64) -> Attempt {
        let n = self.n;
        let hp = self.t - tp;
        let w = h / hp;
        let d = 1.0 + 2.0 * w;
        let (a1, a2, beta) = ((1.0 + w) * (1.0 + w) / d, w * w / d, h * (1.0 + w) / d);
        let t1 = self.t + h;
        // The predictor: the quadratic through the previous point with the
        // slope here (as TR-BDF2's first stage).
        // Reciprocals, not divisions per state: at a step per TMAX interval
        // the divisions' latency showed in the profile.
        let (h2_hp2, inv_beta, inv_h, inv_hp) =
            ((h * h) / (hp * hp), 1.0 / beta, 1.0 / h, 1.0 / hp);
        for i in 0..n {
            self.stage.c[i] = a1 * self.y[i] - a2 * self.y_prev[i];
            let c2 = self.y_prev[i] - self.y[i] + hp * self.f[i];
            self.stage.x[i] = self.y[i] + h * self.f[i] + h2_hp2 * c2;
        }
        self.predict_junctions(-hp, h, |_, jn| jn.v_prev);
        if !self.stage(t1, beta) {
            return Attempt::NoConvergence;
        }
        let k = (1.0 + w) * (1.0 + w) / (6.0 * w * d) * h * h * h * 2.0 / (h + hp);
        for i in 0..n {
            self.stage.f[i] = (self.stage.x[i] - self.stage.c[i]) * inv_beta;
            let dd0 = (self.f[i] - self.f_prev[i]) * inv_hp;
            let dd1 = (self.stage.f[i] - self.f[i]) * inv_h;
            self.stage.delta[i] = k * (dd1 - dd0);
        }
        self.conclude(h, BDF2_GROWTH)
    }

    /// The error test of a step of `h` whose end is `stage.x` (with `f`
    /// there in `stage.f`) and whose raw local error estimate is
    /// `stage.delta`: accepted, the step is taken and the next may grow by
    /// `grow` at most.
    fn conclude(&mut self, h: f64, grow: f64) -> Attempt {
        let t1 = self.t + h;
        self.solve_delta();
        // A junction charge's error is also a voltage error, `δq / Q′`, on
        // the scale of the largest junction voltage so far: a reverse-biased
        // junction's depletion charge is orders of magnitude below the
        // diffusion charge of its conduction (its peak), and a floating
        // bridge's nodes are set by those charges at the zero crossing: on
        // the charge's own scale alone their error would not shrink with
        // rtol.
        for jn in &self.junctions {
            let cap = self.ode.register(jn.ci.memo.offset(2));
            let v = jn.v_peak * cap;
            self.jscale[jn.k] = if v.is_finite() && v > 0.0 {
                v
            } else {
                f64::INFINITY
            };
        }
        let (err, worst) = weighted_error(&self.stage.delta, &self.atol, self.rtol, |i| {
            self.peak[i]
                .max(self.y[i].abs())
                .max(self.stage.x[i].abs())
                .min(self.jscale[i])
        });
        self.worst = worst.unwrap_or(self.worst);
        let grow = if self.no_growth { 1.0 } else { grow };
        match next_step(h, err, grow) {
            Control::Reject(h_next) => {
                self.h = h_next;
                return Attempt::Rejected;
            }
            Control::Accept(h_next) => {
                self.no_growth = false;
                self.h = h_next;
            }
        }
        std::mem::swap(&mut self.y_prev, &mut self.y);
        std::mem::swap(&mut self.f_prev, &mut self.f);
        self.prev = Some(self.t);
        self.t = t1;
        self.y.copy_from_slice(&self.stage.x);
        self.f.copy_from_slice(&self.stage.f);
        for (p, y) in self.peak.iter_mut().zip(&self.y) {
            *p = p.max(y.abs());
        }
        self.read_junctions(true);
        for jn in &mut self.junctions {
            let i = (self.f[jn.k] + jn.id).abs();
            if i.is_finite() {
                jn.i_peak = jn.i_peak.max(i);
            }
        }
        self.stats.steps += 1;
        self.newton.age += 1;
        Attempt::Accepted
    }
}

impl<M: Matrix<T = f64>> TrBdf2<'_, M>
where
    M::V: HostVec,
{
    /// The state at `t` inside the last step: the cubic with the step's end
    /// values and slopes (third order, one above the method's).
    fn interpolate(&self, t: f64, out: &mut [f64]) {
        let t0 = self.prev.unwrap_or(self.t);
        let l = self.t - t0;
        if l <= 0.0 {
            out.copy_from_slice(&self.y);
            return;
        }
        let x = (t - t0) / l;
        let (h00, h10) = (
            (1.0 + 2.0 * x) * (1.0 - x) * (1.0 - x),
            x * (1.0 - x) * (1.0 - x),
        );
        let (h01, h11) = (x * x * (3.0 - 2.0 * x), x * x * (x - 1.0));
        for (i, o) in out.iter_mut().enumerate() {
            *o = h00 * self.y_prev[i]
                + h10 * l * self.f_prev[i]
                + h01 * self.y[i]
                + h11 * l * self.f[i];
        }
    }
}

/// Integrate from the recorder's start to its last output point, landing
/// on every output point and every breakpoint in `hard` (restarting there).
/// The largest of `|d_i| / (atol_i + rtol · scale(i))`, the local error
/// estimate `d` weighted by each state's tolerance, and the state where it
/// is (none while every error is zero). A NaN error is the worst of all.
fn weighted_error(
    d: &[f64],
    atol: &[f64],
    rtol: f64,
    scale: impl Fn(usize) -> f64,
) -> (f64, Option<usize>) {
    let (mut err, mut worst) = (0.0_f64, None);
    for (i, (d, a)) in d.iter().zip(atol).enumerate() {
        let e = (d / (a + rtol * scale(i))).abs();
        if e > err || e.is_nan() && !err.is_nan() {
            err = e;
            worst = Some(i);
        }
    }
    (err, worst)
}

/// The step size control's verdict on a step, with the next step size.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Control {
    Accept(f64),
    Reject(f64),
}

/// Step size control after a step of size `h` with weighted error `err`
/// (1: at the tolerance). TR-BDF2's local error is O(h³), so the next step
/// is `h · 0.9 · err^(-1/3)`: shrunk to within 0.1..0.9 of `h` after a
/// rejection (a quarter when the error is not finite), within 0.2..`grow`
/// after an acceptance.
fn next_step(h: f64, err: f64, grow: f64) -> Control {
    if !err.is_finite() {
        Control::Reject(0.25 * h)
    } else if err > 1.0 {
        Control::Reject(h * (0.9 * err.powf(-1.0 / 3.0)).clamp(0.1, 0.9))
    } else {
        Control::Accept(h * (0.9 * err.max(1e-12).powf(-1.0 / 3.0)).clamp(0.2, grow))
    }
}

/// How a run of the circuit integrator starts: its tolerances (per state,
/// and the absolute tolerance of junction currents), initial state and
/// first step.
pub struct Setup {
    pub rtol: f64,
    pub atol: Vec<f64>,
    pub atol_current: f64,
    pub y0: Vec<f64>,
    pub h0: f64,
    /// The longest step (the `.tran` card's TMAX; infinite without).
    pub h_cap: f64,
    /// One BDF2 stage per step after the first (`--method gear2`).
    pub bdf2: bool,
}

/// Integrate to the end of `rec`'s grid with kausal's TR-BDF2, stopping on
/// the hard breakpoints of `stops_at` (restarting there) and on every output
/// point when junction charges are present.
pub(super) fn drive<'p, 's, M>(
    ode: &'p CircuitOde<M>,
    setup: Setup,
    mut rec: Recorder<'p, 's, M>,
    stops_at: &Stops<'p, M>,
    stats: &mut Stats,
) -> Result<Recorder<'p, 's, M>, SimError>
where
    M: Matrix<T = f64>,
    M::V: HostVec,
{
    let t0 = 0.0;
    let t_end = rec.grid.last().unwrap_or(0.0);
    let tstart = rec.grid.first().unwrap_or(0.0);
    let h_min = 1e-15 * t_end.abs().max(f64::MIN_POSITIVE);
    let Stops {
        names, hard, opts, ..
    } = *stops_at;
    let (all_steps, progress) = (opts.all_steps, opts.progress);
    let mut s = TrBdf2::new(ode, setup, t0, h_min)?;
    rec.record_start(t0, &s.y)?;
    // Junction charges are the solver's own only at its steps (an
    // interpolated one is off its slow manifold, and its error reaches the
    // current through RS amplified by 1/(C·RS)): with them, every output
    // point is a step; without, the steps are the error test's and the
    // output points are interpolated.
    let land = !rec.charges.is_empty();
    let mut y = vec![0.0; s.n];
    let mut k = 0;
    let mut last_report = std::time::Instant::now();
    let max_steps = opts.max_steps.unwrap_or(super::DEFAULT_MAX_STEPS);
    let mut budget = super::budget::Budget::new(max_steps, 0, t0, t_end);
    while s.t < t_end {
        while k < hard.len() && hard[k] <= s.t {
            k += 1;
        }
        let next_point = if rec.next < rec.grid.len() {
            rec.grid.at(rec.next)
        } else {
            t_end
        };
        let corner = hard.get(k).copied().unwrap_or(f64::INFINITY);
        let stop = if land { next_point } else { t_end }.min(corner).min(t_end);
        // Whether the solver's registers hold the last Newton iterate of a
        // step that ends here (see [`TrBdf2::outputs_at_end`]).
        let mut fresh = false;
        // A stop within rounding of here (an output point an ulp before a
        // source corner) is reached without a step.
        if stop - s.t > 1e-12 * t_end.abs() {
            s.step(stop - s.t, names)?;
            budget.step(s.t, s.h)?;
            fresh = true;
        }
        // `t + (stop - t)` may miss `stop` by an ulp.
        if s.t >= stop - 1e-12 * t_end.abs() {
            s.t = stop;
        }
        let mut recorded = false;
        while rec.next < rec.grid.len() && rec.grid.at(rec.next) <= s.t {
            let tg = rec.grid.at(rec.next);
            if tg == s.t {
                if fresh && s.outputs_follow {
                    rec.record_with(tg, |out| s.outputs_at_end(tg, out))?;
                } else {
                    rec.record(tg, &s.y)?;
                }
                recorded = true;
            } else {
                // The output program loads the interpolated states into
                // the solver's registers.
                s.interpolate(tg, &mut y);
                rec.record(tg, &y)?;
                fresh = false;
            }
            rec.next += 1;
        }
        if all_steps && !recorded && s.t >= tstart && rec.rows.last.is_none_or(|l| l < s.t) {
            rec.record(s.t, &s.y)?;
        }
        if s.t == corner {
            s.restart()?;
        }
        if let Some(p) = progress
            && last_report.elapsed() > std::time::Duration::from_millis(100)
        {
            p(s.t / t_end.max(1e-300));
            last_report = std::time::Instant::now();
        }
    }
    stats.steps += s.stats.steps;
    stats.rejected += s.stats.rejected;
    stats.newton_fails += s.stats.newton_fails;
    stats.rhs_evals += s.stats.rhs_evals;
    stats.jacobians += s.stats.jacobians;
    stats.lu_factorizations += s.stats.lu_factorizations;
    stats.restarts += s.stats.restarts;
    rec.last = s.y.clone();
    Ok(rec)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steps_shrink_on_rejection_and_grow_within_bounds() {
        // At the tolerance the step passes and shrinks by the safety factor.
        assert_eq!(next_step(1.0, 1.0, 4.0), Control::Accept(0.9));
        // Eight times the tolerance: h·0.9/2.
        assert_eq!(next_step(1.0, 8.0, 4.0), Control::Reject(0.45));
        // Far too large an error shrinks by a tenth at most per try.
        assert_eq!(next_step(1.0, 1e9, 4.0), Control::Reject(0.1));
        assert_eq!(next_step(2.0, f64::NAN, 4.0), Control::Reject(0.5));
        assert_eq!(next_step(2.0, f64::INFINITY, 4.0), Control::Reject(0.5));
        // A tiny error grows the step by `grow` at most, and not at all
        // where growth is held back.
        assert_eq!(next_step(1.0, 1e-9, 4.0), Control::Accept(4.0));
        assert_eq!(next_step(1.0, 0.0, 1.0), Control::Accept(1.0));
        // In between, the third root: a thousandth of the tolerance gives
        // 0.9 · 10.
        let Control::Accept(h) = next_step(1.0, 1e-3, 20.0) else {
            panic!("accepted")
        };
        assert!((h - 9.0).abs() < 1e-12, "{h}");
    }

    #[test]
    fn errors_are_weighted_by_each_states_own_tolerance() {
        let d = [1e-6, 1e-9, 0.0];
        let atol = [1e-9, 1e-12, 1e-9];
        // State 0: a 1 V signal at rtol 1e-6 is at the tolerance; state 1: a
        // 1 mA current at rtol 1e-6 is one unit too.
        let scale = [1.0, 1e-3, 5.0];
        let (err, worst) = weighted_error(&d, &atol, 1e-6, |i| scale[i]);
        assert!((err - 1e-6 / (1e-9 + 1e-6)).abs() < 1e-12, "{err}");
        assert_eq!(worst, Some(0));
        // A smaller scale (a junction voltage's) makes the same error worse.
        let (err, worst) = weighted_error(&d, &atol, 1e-6, |i| [1.0, 1e-6, 5.0][i]);
        assert!(err > 400.0, "{err}");
        assert_eq!(worst, Some(1));
        // NaN wins; no error at all names no state.
        let (err, worst) = weighted_error(&[1.0, f64::NAN], &[1.0, 1.0], 0.0, |_| 1.0);
        assert!(err.is_nan());
        assert_eq!(worst, Some(1));
        assert_eq!(weighted_error(&[0.0], &[1.0], 1e-3, |_| 1.0), (0.0, None));
    }
}
