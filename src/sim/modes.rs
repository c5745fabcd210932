//! Warnings and diagnoses from the circuit's modes: a lightly damped mode
//! that keeps steps short or that BDF at a loose tolerance can amplify, and
//! why a step size underflowed.

use super::*;
use crate::diag::codes;

/// Steps this many times more numerous than the output points, in a run of at
/// least [`RINGING_MIN_STEPS`], make kausal look for the mode that kept them
/// short.
pub(super) const RINGING_STEPS_PER_POINT: usize = 20;
pub(super) const RINGING_MIN_STEPS: usize = 20_000;

/// When the steps were far shorter than the output interval and the circuit
/// is small (dense): the least damped oscillatory mode of the Jacobian at the
/// end of the run that is fast against TSTEP, named by the states that take
/// part in it. A high-Q LC loop (a transformer's leakage inductance with a
/// diode's junction capacitance) rings at MHz through a run of seconds: the
/// error test makes the solver follow every cycle.
pub(super) fn ringing<M>(
    names: &NameTable<VarId>,
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
    let m = least_damped_mode(names, ode, tran.tstop, y, fast, 5.0)?;
    Some(
        crate::diag::Diagnostic::warning(
            codes::RINGING,
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
pub(super) fn oscillation_at_loose_rtol<M>(
    names: &NameTable<VarId>,
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
    let m = least_damped_mode(names, ode, t0, y0, ten_cycles, 20.0)?;
    Some(
        crate::diag::Diagnostic::warning(
            codes::BDF_ON_LIGHT_DAMPING,
            format!(
                "BDF at rtol {rtol:e} on a lightly damped mode at {:.3e} Hz (Q ≈ {}) in {}: BDF's orders above 2 are not A-stable, and over many cycles the amplitude can grow",
                m.freq, m.quality(), m.states
            ),
        )
        .with_help("use --method tr-bdf2 (A-stable), or an rtol of 1e-3 or tighter"),
    )
}

/// An oscillatory mode of the circuit's Jacobian.
pub(super) struct Mode {
    pub(super) freq: f64,
    pub(super) q: f64,
    /// The states that take part, with their share, most first.
    pub(super) states: String,
}

impl Mode {
    pub(super) fn quality(&self) -> String {
        if self.q < 1e6 {
            format!("{:.0}", self.q)
        } else {
            "10^6 or more".into()
        }
    }
}

/// `J(t, y)` as a dense matrix balanced for an eigenvalue solve
/// (`D⁻¹ J D`, [`crate::numeric::balance`]: the same eigenvalues and
/// participation factors), for a small circuit (at most `DENSE_STATES`
/// states); `None` where it is larger or not finite. Unbalanced, a MOS
/// inverter chain's Jacobian (junction charges in coulombs beside node
/// voltages, entries from 1e-3 to 1e25) gave a fast complex pair with Q in
/// the thousands where every eigenvalue is real and negative, and the
/// ringing diagnosis (K0409) named it.
pub(super) fn balanced_jacobian<M>(
    ode: &CircuitOde<M>,
    t: f64,
    y: &[f64],
) -> Option<nalgebra::DMatrix<f64>>
where
    M: Matrix<T = f64>,
    M::V: HostVec,
{
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
    crate::numeric::balance::balance(n, &mut jac);
    Some(nalgebra::DMatrix::from_row_slice(n, n, &jac))
}

/// The least damped oscillatory mode of `J(t, y)` with angular frequency
/// above `min_omega` and quality factor above `min_q`, for a small (dense)
/// circuit; the states in it by modal participation factors `|w_k v_k|`
/// (right and left eigenvectors by inverse iteration: dimensionless whatever
/// the states' units).
pub(super) fn least_damped_mode<M>(
    names: &NameTable<VarId>,
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
    let j = balanced_jacobian(ode, t, y)?;
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
                names.get(ode.tape.states[k]),
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

/// Turn a solver failure into a message that names what went wrong.
pub(super) fn diagnose<'p, M, S>(
    names: &NameTable<VarId>,
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
                var.map_or_else(|| format!("register {reg}"), |v| names.get(v).to_string());
            return SimError::NonFinite {
                name: sys_name.clone(),
                value: regs[reg],
                t,
                what: sys_name,
            };
        }
    }
    // diffsol says so by a variant, and in the text of errors from its
    // Newton line search and its interpolation when a step can shrink no
    // further.
    // The per-step limit on Newton failures (see `StepLimits`) ends a
    // step that could not converge however it shrank: an underflow too.
    let underflow = matches!(
        &e,
        diffsol::DiffsolError::OdeSolverError(
            diffsol::error::OdeSolverError::StepSizeTooSmall { .. }
                | diffsol::error::OdeSolverError::TooManyNonlinearSolverFailures { .. }
        )
    ) || e.to_string().to_ascii_lowercase().contains("step size");
    if underflow {
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
                .map_or_else(String::new, |&v| names.get(v).to_string()),
            value: y.get(k).copied().unwrap_or(f64::NAN),
        };
    }
    SimError::Solver {
        t,
        source: std::rc::Rc::new(e),
    }
}
