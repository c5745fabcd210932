//! Damped Newton's step control, shared by every Newton iteration of the
//! crate: the tape's torn blocks, the DC operating point and the reference
//! interpreter.
//!
//! The damping is Deuflhard's natural monotonicity test (Deuflhard, "Newton
//! Methods for Nonlinear Problems", Springer 2004, §3.3): a step `x − λ d`,
//! with `d = J⁻¹ f(x)` the full correction, is accepted when the simplified
//! correction there, `J⁻¹ f(x − λ d)` with the same `J`, is shorter than
//! `(1 − λ/4)·‖d‖`; otherwise `λ` is halved. Corrections are compared in the
//! unknowns' own units, so the test is affine invariant: residuals of mixed
//! units (amperes beside volts per second) cannot mislead it the way a
//! residual norm can. What counts as converged, and what is done when no
//! damped step helps, stays with each caller.

/// Below this damping factor no step along the correction is taken.
pub const MIN_DAMPING: f64 = 1e-10;

/// Whether a damped step `λ` whose simplified correction has size
/// `simplified` passes the natural monotonicity test against the full
/// correction's size `full`. A zero correction always passes; a non-finite
/// one never does.
pub fn monotone(simplified: f64, full: f64, lambda: f64) -> bool {
    (simplified.is_finite() && simplified <= (1.0 - lambda / 4.0) * full) || simplified == 0.0
}

/// Whether a full step (`λ = 1`) that left a simplified correction of size
/// `simplified` after a full correction of size `full` shows quadratic
/// convergence below rounding: the simplified correction then leaves an
/// error of order `simplified · full`, so applying it ends the iteration.
pub fn converged_quadratically(full: f64, simplified: f64) -> bool {
    simplified <= 1e-10 && simplified <= 1e-2 * full
}

/// The outcome of [`damp`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Damping {
    /// The step `λ` passed, leaving a simplified correction of this size.
    Accepted { lambda: f64, simplified: f64 },
    /// No `λ` down to [`MIN_DAMPING`] passed; the caller's point is the
    /// last one tried.
    Stalled,
}

/// Halve `λ` from 1 until the simplified correction at `x − λ d`, measured
/// by `simplified_at(λ)` (which also moves the caller's point there), passes
/// [`monotone`] against `full`. An error of `simplified_at` ends the search.
pub fn damp<E>(
    full: f64,
    mut simplified_at: impl FnMut(f64) -> Result<f64, E>,
) -> Result<Damping, E> {
    let mut lambda = 1.0;
    loop {
        let simplified = simplified_at(lambda)?;
        if monotone(simplified, full, lambda) {
            return Ok(Damping::Accepted { lambda, simplified });
        }
        lambda *= 0.5;
        if lambda < MIN_DAMPING {
            return Ok(Damping::Stalled);
        }
    }
}

/// `max_k |d_k| / scale(k)`: the size of a correction in its unknowns' own
/// scales.
pub fn scaled_norm(d: &[f64], scale: impl Fn(usize) -> f64) -> f64 {
    d.iter()
        .enumerate()
        .map(|(k, d)| d.abs() / scale(k))
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Newton on `atan(x) = 0`, damped by [`damp`]; the iterations taken.
    fn solve_atan(mut x: f64) -> Result<(f64, usize), &'static str> {
        for it in 0..100 {
            let slope = 1.0 / (1.0 + x * x);
            let d = x.atan() / slope;
            let full = d.abs();
            if full <= 1e-14 {
                return Ok((x, it));
            }
            match damp(full, |lambda| {
                Ok::<_, ()>(((x - lambda * d).atan() / slope).abs())
            }) {
                Ok(Damping::Accepted { lambda, .. }) => x -= lambda * d,
                _ => return Err("stalled"),
            }
        }
        Err("no convergence")
    }

    #[test]
    fn damping_brings_a_diverging_newton_home() {
        // Plain Newton on atan from |x| > 1.39 overshoots further each step.
        let mut plain = 3.0_f64;
        for _ in 0..5 {
            plain -= plain.atan() * (1.0 + plain * plain);
        }
        assert!(plain.abs() > 1e3, "plain Newton diverges: {plain}");
        let (x, its) = solve_atan(3.0).expect("damped Newton converges");
        assert!(x.abs() < 1e-12, "{x}");
        assert!(its < 30, "{its} iterations");
    }

    #[test]
    fn full_steps_pass_where_newton_contracts() {
        // Near the root the full step passes at once.
        let d = 1e-3_f64.atan() * (1.0 + 1e-6);
        let r = damp(d, |_| Ok::<_, ()>(1e-9)).unwrap();
        assert_eq!(
            r,
            Damping::Accepted {
                lambda: 1.0,
                simplified: 1e-9
            }
        );
    }

    #[test]
    fn the_test_halves_until_it_passes_and_reports_a_stall() {
        let mut tried = Vec::new();
        let r = damp(1.0, |lambda| {
            tried.push(lambda);
            Ok::<_, ()>(if lambda > 0.2 { 2.0 } else { 0.5 })
        })
        .unwrap();
        assert_eq!(tried, [1.0, 0.5, 0.25, 0.125]);
        assert!(matches!(r, Damping::Accepted { lambda: 0.125, .. }));
        // Non-finite corrections never pass.
        let r = damp(1.0, |_| Ok::<_, ()>(f64::NAN)).unwrap();
        assert_eq!(r, Damping::Stalled);
        // Errors end the search.
        assert_eq!(damp(1.0, |_| Err::<f64, _>("bad")), Err("bad"));
    }

    #[test]
    fn monotonicity_is_judged_against_the_damped_bound() {
        assert!(monotone(0.74, 1.0, 1.0));
        assert!(!monotone(0.76, 1.0, 1.0));
        assert!(monotone(0.0, f64::NAN, 1.0));
        assert!(!monotone(f64::INFINITY, f64::INFINITY, 0.5));
        assert!(converged_quadratically(1e-6, 1e-11));
        assert!(!converged_quadratically(1e-10, 1e-11));
    }
}
