//! Seed 004's fixed-step methods: forward Euler, Runge–Kutta 2 (the
//! midpoint rule) and Runge–Kutta 4, at the step the user gives, with no
//! error control. They are there to teach what the adaptive methods hide: a
//! step too long for the circuit's fastest mode makes an explicit method
//! blow up, whatever the accuracy asked. So before the run, the Jacobian's
//! eigenvalues at the start give the longest stable step (each method's
//! amplification factor `|R(hλ)| ≤ 1` for every mode λ), which the run
//! states; a run whose states grow past any circuit's range stops with the
//! step, the bound and the mode that broke it.

use nalgebra::Complex;

use super::HostVec;
use super::ode::CircuitOde;
use super::record::Recorder;
use super::{DENSE_STATES, Method, SimError, Stats};
use crate::diag::{Diagnostic, codes};
use diffsol::Matrix;

/// A state above this (in volts or amperes, or their charges) is a blow-up.
const BLOWN_UP: f64 = 1e30;

/// `R(z)`, the factor a step multiplies a mode `y' = λy` by (`z = hλ`).
fn amplification(method: Method, z: Complex<f64>) -> Complex<f64> {
    let one = Complex::new(1.0, 0.0);
    match method {
        Method::Euler => one + z,
        Method::Rk2 => one + z + z * z / 2.0,
        _ => one + z + z * z / 2.0 + z * z * z / 6.0 + z * z * z * z / 24.0,
    }
}

/// The longest step for which `|R(hλ)| ≤ 1`, scanning `h` from 0 along the
/// ray of `λ` (stability regions of explicit methods are bounded: the scan
/// ends); `None` for a mode that grows by itself (Re λ ≥ 0 and λ ≠ 0
/// outside every region but at h = 0) or is zero.
fn mode_bound(method: Method, lambda: Complex<f64>) -> Option<f64> {
    let r = lambda.norm();
    if r == 0.0 || lambda.re > 0.0 {
        return None;
    }
    // |z| up to 4 covers every region here (RK4's reaches 2.83).
    let stable = |s: f64| amplification(method, lambda / r * s).norm() <= 1.0 + 1e-12;
    let n = 4000;
    let mut last = 0.0;
    for k in 1..=n {
        let s = 4.0 * k as f64 / n as f64;
        if !stable(s) {
            // Bisect between the last stable |z| and this one.
            let (mut lo, mut hi) = (last, s);
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                if stable(mid) {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            return Some(lo / r);
        }
        last = s;
    }
    Some(4.0 / r)
}

/// The longest stable step of `method` over `eigenvalues`, and the mode that
/// sets it; `None` when no mode limits the step.
pub fn stability_bound(
    method: Method,
    eigenvalues: &[Complex<f64>],
) -> Option<(f64, Complex<f64>)> {
    eigenvalues
        .iter()
        .filter_map(|&l| mode_bound(method, l).map(|h| (h, l)))
        .min_by(|a, b| a.0.total_cmp(&b.0))
}

/// The Jacobian's eigenvalues at `(t, y)` (small circuits: a dense
/// eigenvalue solve).
pub(super) fn eigenvalues<M>(ode: &CircuitOde<M>, t: f64, y: &[f64]) -> Option<Vec<Complex<f64>>>
where
    M: Matrix<T = f64>,
    M::V: HostVec,
{
    let j = super::modes::balanced_jacobian(ode, t, y)?;
    Some(j.complex_eigenvalues().iter().copied().collect())
}

/// What the run is told before it starts: the bound, the mode and where the
/// step stands.
pub(super) fn bound_note(method: Method, h: f64, bound: Option<(f64, Complex<f64>)>) -> Diagnostic {
    let name = method.name();
    match bound {
        Some((hmax, l)) => {
            let mode = if l.im.abs() > 1e-9 * l.norm() {
                format!(
                    "λ = {:.3e} ± {:.3e}i /s, {:.3e} Hz",
                    l.re,
                    l.im.abs(),
                    l.im.abs() / (2.0 * std::f64::consts::PI)
                )
            } else {
                format!(
                    "λ = {:.3e} /s, a time constant of {:.3e} s",
                    l.re,
                    -1.0 / l.re
                )
            };
            let verdict = if h <= hmax {
                "within it".to_string()
            } else {
                format!("{:.2}× above it: expect the run to blow up", h / hmax)
            };
            Diagnostic::warning(
                codes::FIXED_STEP_BOUND,
                format!(
                    "{name} is stable on this circuit for steps up to {hmax:.4e} s, set by its stiffest mode ({mode}); --step {h:.4e} s is {verdict}"
                ),
            )
            .with_help("a stiff circuit needs an implicit method (bdf, tr-bdf2): their steps follow accuracy, not the fastest mode")
        }
        None => Diagnostic::warning(
            codes::FIXED_STEP_BOUND,
            format!(
                "{name}'s stability bound is not estimated here (a circuit of more than {DENSE_STATES} states, or no decaying mode); --step {h:.4e} s runs unchecked"
            ),
        ),
    }
}

/// A fixed-step run: the method, its step, the stability bound stated
/// before it, the states' names (for a blow-up) and the sources' corners.
pub(super) struct Run<'a> {
    pub method: Method,
    pub h: f64,
    pub bound: Option<f64>,
    pub names: &'a dyn Fn(usize) -> String,
    pub hard: &'a [f64],
}

/// Integrate to the end of `rec`'s grid with `method` at step `h`, a step
/// shortened where it would pass a source's corner in `hard` (a kink inside
/// a step costs an explicit method its order) or the end; the grid points
/// are recorded by cubic Hermite interpolation between steps.
pub(super) fn drive<'p, 's, M>(
    ode: &'p CircuitOde<M>,
    run: Run<'_>,
    mut rec: Recorder<'p, 's, M>,
    stats: &mut Stats,
) -> Result<Recorder<'p, 's, M>, SimError>
where
    M: Matrix<T = f64>,
    M::V: HostVec,
{
    let Run {
        method,
        h,
        bound,
        names,
        hard,
    } = run;
    let t_end = rec.grid.last().unwrap_or(0.0);
    let mut t = 0.0;
    let mut y = ode.y0.borrow().clone();
    let n = y.len();
    rec.record_start(t, &y)?;
    let eval = |t: f64, y: &[f64], dy: &mut [f64], stats: &mut Stats| {
        stats.rhs_evals += 1;
        ode.eval(t, y, dy).map_err(|error| SimError::Eval { error })
    };
    let (mut k1, mut k2, mut k3, mut k4) = (vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    let (mut tmp, mut y_new, mut f_new, mut out) =
        (vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    eval(t, &y, &mut k1, stats)?;
    let steps_total = (t_end / h).ceil();
    if steps_total > 1e9 {
        return Err(SimError::TooManySteps {
            steps: 0,
            max: 1_000_000_000,
            t,
            h,
            tstop: t_end,
            projected: Some(steps_total),
            newton: None,
        });
    }
    let mut corner = 0;
    while t < t_end {
        while corner < hard.len() && hard[corner] <= t + 1e-12 * t_end {
            corner += 1;
        }
        let stop = hard.get(corner).map_or(t_end, |&c| c.min(t_end));
        let step = h.min(stop - t);
        // k1 = f(t, y) is carried over from the last step's end.
        match method {
            Method::Euler => {
                for i in 0..n {
                    y_new[i] = y[i] + step * k1[i];
                }
            }
            Method::Rk2 => {
                for i in 0..n {
                    tmp[i] = y[i] + 0.5 * step * k1[i];
                }
                eval(t + 0.5 * step, &tmp, &mut k2, stats)?;
                for i in 0..n {
                    y_new[i] = y[i] + step * k2[i];
                }
            }
            _ => {
                for i in 0..n {
                    tmp[i] = y[i] + 0.5 * step * k1[i];
                }
                eval(t + 0.5 * step, &tmp, &mut k2, stats)?;
                for i in 0..n {
                    tmp[i] = y[i] + 0.5 * step * k2[i];
                }
                eval(t + 0.5 * step, &tmp, &mut k3, stats)?;
                for i in 0..n {
                    tmp[i] = y[i] + step * k3[i];
                }
                eval(t + step, &tmp, &mut k4, stats)?;
                for i in 0..n {
                    y_new[i] = y[i] + step / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
                }
            }
        }
        let t_new = if stop - (t + step) <= 1e-12 * t_end {
            stop
        } else {
            t + step
        };
        stats.steps += 1;
        if let Some(k) = y_new.iter().position(|v| v.is_nan() || v.abs() >= BLOWN_UP) {
            return Err(SimError::BlewUp {
                method: method.name(),
                t: t_new,
                state: names(k),
                value: y_new[k],
                h,
                bound,
            });
        }
        eval(t_new, &y_new, &mut f_new, stats)?;
        // Grid points in (t, t_new]: cubic Hermite from both ends' values
        // and slopes.
        let dt = t_new - t;
        while rec.next < rec.grid.len() && rec.grid.at(rec.next) <= t_new {
            let tg = rec.grid.at(rec.next);
            let s = ((tg - t) / dt).clamp(0.0, 1.0);
            let (h00, h10) = (
                (1.0 + 2.0 * s) * (1.0 - s) * (1.0 - s),
                s * (1.0 - s) * (1.0 - s),
            );
            let (h01, h11) = (s * s * (3.0 - 2.0 * s), s * s * (s - 1.0));
            for i in 0..n {
                out[i] = h00 * y[i] + h10 * dt * k1[i] + h01 * y_new[i] + h11 * dt * f_new[i];
            }
            rec.record(tg, &out)?;
            rec.next += 1;
        }
        t = t_new;
        std::mem::swap(&mut y, &mut y_new);
        std::mem::swap(&mut k1, &mut f_new);
    }
    rec.last = y;
    Ok(rec)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On the negative real axis the bounds are the textbook ones: 2/|λ|
    /// for Euler and the midpoint rule, 2.785/|λ| for RK4; on the imaginary
    /// axis only RK4 is stable (up to 2√2/|λ|).
    #[test]
    fn stability_bounds_are_the_textbook_ones() {
        let real = Complex::new(-1e3, 0.0);
        let b = |m| mode_bound(m, real).expect("bounded");
        assert!((b(Method::Euler) * 1e3 - 2.0).abs() < 1e-6);
        assert!((b(Method::Rk2) * 1e3 - 2.0).abs() < 1e-6);
        assert!(
            (b(Method::Rk4) * 1e3 - 2.785293563).abs() < 1e-6,
            "{}",
            b(Method::Rk4)
        );
        let imag = Complex::new(-1e-12, 1.0);
        // Euler: stable only within the 1e-12 slack the test allows.
        assert!(mode_bound(Method::Euler, imag).expect("bounded") < 1e-5);
        let rk4 = mode_bound(Method::Rk4, imag).expect("bounded");
        assert!((rk4 - 2.0 * 2f64.sqrt()).abs() < 1e-3, "{rk4}");
        // The stiffest mode sets the bound.
        let eigs = [Complex::new(-1.0, 0.0), Complex::new(-1e6, 0.0)];
        let (h, l) = stability_bound(Method::Euler, &eigs).expect("bounded");
        assert_eq!(l, eigs[1]);
        assert!((h - 2e-6).abs() < 1e-12);
    }
}
