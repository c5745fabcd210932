//! Output points between solver steps: outputs from the interpolant (through
//! few Chebyshev nodes per step when few states are read), junction charges
//! settled on their slow manifold first.
//!
//! Output points of an interpolated state have their junction charges put on
//! their slow manifold (`Recorder::settle_charges`: three Newton steps on
//! `f_q = q̇` of the interpolant with one factored matrix, shifted by `100/h`
//! so that only directions far faster than the step move), because a charge's
//! error reaches the current through RS amplified by 1/(C·RS). These side
//! evaluations use their own registers: they never move the solver's warm
//! starts, so the solver's path is the same with or without them.
//!
//! Outputs that read few states (a probe on a large circuit without junction
//! charges, which are settled instead) take them from the solver's
//! interpolant at six Chebyshev nodes per step (`StepPolynomial`): within one
//! step every solver's interpolant is a polynomial of degree ≤ 5, so this is
//! exact to rounding, and the whole state is interpolated six times per step
//! instead of at every output point.

use super::*;

pub(super) struct Recorder<'a, 's, M: Matrix<T = f64>>
where
    M::V: HostVec,
{
    pub(super) ode: &'a CircuitOde<M>,
    pub(super) grid: Grid,
    pub(super) next: usize,
    pub(super) rows: Rows<'s>,
    pub(super) out: Vec<f64>,
    /// The first point is the DC operating point (no `uic`): it is output in
    /// DC mode, as ngspice reports its operating point at t = 0.
    pub(super) dc_start: bool,
    /// The first point's outputs when they are not the initial state's (the
    /// `.ic` nodes held; see [`Start::row`]).
    pub(super) first: Option<Vec<f64>>,
    /// The junction-charge states (indices in `y`).
    pub(super) charges: Vec<usize>,
    /// The factored shifted Jacobian of the charges in the current step.
    pub(super) settle: Option<Settle>,
    /// Each charge's junction inversion, where every charge has one and
    /// `f` follows them exactly (see [`Recorder::settle_charges`]).
    pub(super) inversions: Option<Vec<crate::tape::ChargeInverse>>,
    /// The state at the end of the run.
    pub(super) last: Vec<f64>,
}

/// What [`Recorder::settle_charges`] keeps for the output points of a step,
/// and of later steps of the same size while its junctions hold.
pub(super) struct Settle {
    /// The step: the solver's (time, step size).
    pub(super) step: (f64, f64),
    /// `J_qq - σ I` factored (LU, row order); `None` when singular.
    pub(super) lu: Option<(Vec<f64>, Vec<usize>)>,
    /// Each charge's diagonal entry `J_kk`, its junction's `Q′` and `g_d`
    /// where the matrix was factored; empty where the matrix cannot be
    /// judged by its junctions (see [`Recorder::settle_charges`]).
    pub(super) at: Vec<(f64, f64, f64)>,
    /// Steps since it was factored.
    pub(super) age: usize,
}

/// The most steps of one size whose output points reuse one factored matrix.
const SETTLE_REUSE: usize = 64;

/// How far a charge's `J_kk` may have moved from the kept matrix's,
/// relatively, for the matrix to be kept: three passes then leave
/// (2 %)³ of a stiff residual. Measured on VACASK graetz's first 40 ms
/// against a tight reference: 1.15e-7 of the range at 2 % (as with a fresh
/// matrix at every point), 6.4e-7 at 5 %, 1.5e-4 at 10 %.
const SETTLE_DRIFT: f64 = 0.02;

/// Newton steps of [`Recorder::settle_charges`]. One left a clamp's reverse
/// leakage (range 1e-9 A) off ngspice by 3.5e-11 A; three, 3.6e-13 A (each
/// further step moves a slow direction by at most h/100 of its residual). It
/// costs the bridge rectifiers 7–15 % of their solve at rtol 1e-3..1e-4.
pub(super) const SETTLE_STEPS: usize = 3;

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
    ///
    /// The matrix is also kept for later steps of the same size (σ with
    /// it), up to [`SETTLE_REUSE`] of them, where `f` depends on the states
    /// nonlinearly only through junction charges it can follow
    /// ([`crate::tape::Tape::jacobian_follows_junctions`]): there a charge's
    /// diagonal entry is `J_kk = −(g_d + G)/Q′` with `G` fixed by the rest
    /// of the circuit, so its move is known from the junction's `g_d` and
    /// `Q′` at the new point, and the matrix is kept while no `J_kk` moved
    /// by more than [`SETTLE_DRIFT`]. Under TMAX = TSTEP every step has one
    /// output point, and a Jacobian for each took VACASK's graetz bridge
    /// half its run.
    pub(super) fn settle_charges(&mut self, t: f64, y: &mut [f64], dy: &[f64], step: (f64, f64)) {
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
        if self.settle_kept(t, y, &mut f, step) {
            // `f` is at `y` already (the junctions were read from it).
        } else if self.settle.as_ref().is_none_or(|s| s.step != step) {
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
            // Each charge's `(J_kk, Q′, g_d)` here, where its junction can judge the
            // matrix later (see `settle_kept`).
            let at = self.inversions.as_ref().map_or_else(Vec::new, |inv| {
                let jkk = |r: usize| jac[self.charges[r] * m + r];
                inv.iter()
                    .enumerate()
                    .map(|(r, ci)| {
                        let (cap, gd) = self.junction(ci);
                        (jkk(r), cap, gd)
                    })
                    .collect()
            });
            let mut perm = vec![0; m];
            let regular = a.iter().all(|v| v.is_finite()) && lu_factor(m, &mut a, &mut perm);
            self.settle = Some(Settle {
                step,
                lu: regular.then_some((a, perm)),
                at,
                age: 0,
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

    /// A junction's `Q′` and `g_d` at the voltage its inversion last found
    /// on the output side's registers.
    fn junction(&self, ci: &crate::tape::ChargeInverse) -> (f64, f64) {
        let x = self.ode.side_register(ci.memo);
        let cap = self.ode.side_register(ci.memo.offset(2));
        let [_, gd, _] = self.ode.tape.diodes[ci.diode as usize].current(x);
        (cap, gd)
    }

    /// Whether the kept matrix serves the point `(t, y)` of a later step of
    /// the same size (see [`Recorder::settle_charges`]); if so `f` is
    /// evaluated there into `f`.
    fn settle_kept(&mut self, t: f64, y: &[f64], f: &mut [f64], step: (f64, f64)) -> bool {
        let Some(s) = self.settle.as_ref() else {
            return false;
        };
        if s.step == step
            || s.step.1 != step.1
            || s.age >= SETTLE_REUSE
            || s.lu.is_none()
            || s.at.is_empty()
        {
            return false;
        }
        if self.ode.side_eval(t, y, f).is_err() {
            return false;
        }
        let Some(inv) = &self.inversions else {
            return false;
        };
        let held = s.at.iter().zip(inv).all(|(&(jkk, cap0, gd0), ci)| {
            let (cap, gd) = self.junction(ci);
            let g = -jkk * cap0 - gd0;
            let moved = -(gd + g) / cap;
            ((moved - jkk) / jkk).abs() <= SETTLE_DRIFT
        });
        if held && let Some(s) = self.settle.as_mut() {
            s.step = step;
            s.age += 1;
        }
        held
    }

    /// The first output row at `t`, the run's start, when the grid
    /// begins there: the row the operating point computed, or the outputs
    /// at `y` in DC mode (transient with `uic`).
    pub(super) fn record_start(&mut self, t: f64, y: &[f64]) -> Result<(), SimError> {
        if self.grid.first() != Some(t) {
            return Ok(());
        }
        if let Some(row) = self.first.take() {
            self.rows.push(t, &row)?;
        } else {
            let mode = if self.dc_start {
                Mode::Dc
            } else {
                Mode::Transient
            };
            let tape = &self.ode.tape;
            tape.in_mode(mode, || self.record(t, y))?;
        }
        self.next = 1;
        Ok(())
    }

    /// The row at `t` that `outputs` computes (the circuit integrator's
    /// outputs at a step's end).
    pub(super) fn record_with(
        &mut self,
        t: f64,
        outputs: impl FnOnce(&mut [f64]) -> Result<(), crate::tape::EvalError>,
    ) -> Result<(), SimError> {
        outputs(&mut self.out).map_err(|error| SimError::Eval { error })?;
        self.rows.push(t, &self.out)
    }

    pub(super) fn record(&mut self, t: f64, y: &[f64]) -> Result<(), SimError> {
        self.ode
            .outputs(t, y, &mut self.out)
            .map_err(|error| SimError::Eval { error })?;
        self.rows.push(t, &self.out)
    }
}

/// Interpolation nodes per step: every solver's interpolant within one step
/// is a polynomial in t of degree at most 5 (BDF: its order ≤ 5; the
/// Runge–Kutta dense outputs: ≤ 4; Hermite: 3), which six nodes determine.
pub(super) const NODES: usize = 6;

/// The solver's interpolant within one step, for a few components, as its
/// values at Chebyshev nodes (barycentric Lagrange form: stable, exact for
/// the polynomial up to rounding).
pub(super) struct StepPolynomial {
    pub(super) nodes: [f64; NODES],
    /// Barycentric weights of first-kind Chebyshev points,
    /// `(-1)^j sin((2j+1)π/2N)` (common factors cancel).
    pub(super) weights: [f64; NODES],
    /// Row-major: the components at node 0, then at node 1, …
    pub(super) values: Vec<f64>,
}

impl StepPolynomial {
    /// The angles of the Chebyshev points of the first kind.
    pub(super) fn angle(j: usize) -> f64 {
        (2 * j + 1) as f64 * std::f64::consts::PI / (2 * NODES) as f64
    }

    /// Chebyshev points of the first kind on `[a, b]`.
    pub(super) fn nodes(a: f64, b: f64) -> [f64; NODES] {
        std::array::from_fn(|j| 0.5 * (a + b) + 0.5 * (b - a) * Self::angle(j).cos())
    }

    pub(super) fn new(nodes: [f64; NODES], values: Vec<f64>) -> StepPolynomial {
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
    pub(super) fn eval(&self, t: f64, out: &mut [f64]) {
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
pub(super) fn insert_step<M>(
    rec: &mut Recorder<'_, '_, M>,
    t: f64,
    y: &[f64],
) -> Result<(), SimError>
where
    M: Matrix<T = f64>,
    M::V: HostVec,
{
    if rec.rows.last.is_some_and(|l| l >= t) {
        return Ok(());
    }
    rec.record(t, y)
}
