//! The circuit integrator's Newton iteration on a stage: the iteration
//! matrix `I - βJ` and its kept Jacobian, the modified Newton with a
//! convergence-rate test, Newton on a Jacobian followed to every iterate's
//! junctions, and Newton with a Jacobian per iterate.

use super::*;

impl<M: Matrix<T = f64>> TrBdf2<'_, M>
where
    M::V: HostVec,
{
    /// `J` at `(t, y)`; the iteration matrix is refactored at next use.
    pub(super) fn jacobian(&mut self, t: f64, y: &[f64]) -> bool {
        // `f` there comes with it; the stages evaluate their own.
        let r = self.ode.jacobian_columns(
            Regs::Solver,
            t,
            y,
            &self.columns,
            &mut self.newton.jac,
            &mut self.stage.scratch,
        );
        self.stats.jacobians += 1;
        let r = match r {
            Ok(()) if self.outputs_follow => {
                self.ode
                    .output_jacobian(t, self.n, &mut self.newton.out_jac)
            }
            r => r,
        };
        let nw = &mut self.newton;
        nw.factored = false;
        nw.stale = false;
        nw.age = 0;
        nw.rate = 1.0;
        match r {
            Ok(()) => {
                self.note_jacobian_point(y);
                true
            }
            Err(e) => {
                self.error.get_or_insert(e);
                false
            }
        }
    }

    /// Factor `I - β J`.
    pub(super) fn factor(&mut self, beta: f64) -> bool {
        let n = self.n;
        let nw = &mut self.newton;
        for (l, &j) in nw.lu.iter_mut().zip(&nw.jac) {
            *l = -beta * j;
        }
        for i in 0..n {
            nw.lu[i * n + i] += 1.0;
        }
        self.stats.lu_factorizations += 1;
        nw.beta = beta;
        nw.factored = all_finite(&nw.lu) && lu_factor_inv(n, &mut nw.lu, &mut nw.perm);
        nw.factored
    }

    /// `delta := (I - βJ)⁻¹ delta` with the factored iteration matrix.
    pub(super) fn solve_delta(&mut self) {
        let nw = &self.newton;
        lu_solve_inv(
            self.n,
            &nw.lu,
            &nw.perm,
            &mut self.stage.delta,
            &mut self.stage.scratch,
        );
    }

    /// One Newton correction of `y1` from `f1 = f(t1, y1)` with the factored
    /// iteration matrix; its size in the Newton weights.
    pub(super) fn correct(&mut self, beta: f64) -> f64 {
        let n = self.n;
        for i in 0..n {
            self.stage.delta[i] = self.stage.c[i] + beta * self.stage.f[i] - self.stage.x[i];
        }
        self.solve_delta();
        let mut norm: f64 = 0.0;
        for i in 0..n {
            self.stage.x[i] += self.stage.delta[i];
            let v = (self.stage.delta[i] * self.stage.weight[i]).abs();
            // `max` passes NaN over: a NaN correction is infinitely large.
            norm = if v.is_nan() {
                f64::INFINITY
            } else {
                norm.max(v)
            };
        }
        norm
    }

    /// Newton iterations on `y1 = c + β f(t1, y1)` with the kept Jacobian,
    /// from the predictor in `y1`.
    pub(super) fn iterate(&mut self, t1: f64, beta: f64) -> Iteration {
        let mut last = f64::INFINITY;
        for it in 0..MAX_ITERATIONS {
            if let Err(e) = self.ode.eval(t1, &self.stage.x, &mut self.stage.f) {
                self.error.get_or_insert(e);
                return Iteration::Failed;
            }
            self.stats.rhs_evals += 1;
            let norm = self.correct(beta);
            if !norm.is_finite() {
                return Iteration::Failed;
            }
            if it == 0 {
                if norm <= FIRST_CORRECTION {
                    return Iteration::Converged;
                }
            } else {
                let ratio = norm / last;
                if ratio > 2.0 {
                    return Iteration::Failed;
                }
                let nw = &mut self.newton;
                nw.rate = (0.3 * nw.rate).max(ratio);
                if norm * nw.rate.min(1.0) <= NEWTON_TOLERANCE {
                    return Iteration::Converged;
                }
                // Converging too slowly to finish in the iterations left.
                let left = (MAX_ITERATIONS - 1 - it) as i32;
                if norm * nw.rate.powi(left) > NEWTON_TOLERANCE {
                    return Iteration::Slow;
                }
            }
            last = norm;
        }
        Iteration::Slow
    }

    /// Solve a stage `y1 = c + β f(t1, y1)` from the predictor in `y1`: the
    /// kept Jacobian first, a fresh one at the predictor when it is stale,
    /// old or the iteration fails.
    pub(super) fn stage(&mut self, t1: f64, beta: f64) -> bool {
        let n = self.n;
        for i in 0..n {
            self.stage.weight[i] = 1.0
                / (self.atol[i]
                    + self.rtol.min(NEWTON_RTOL) * self.y[i].abs().max(self.stage.x[i].abs()));
        }
        self.stage.pred.copy_from_slice(&self.stage.x);
        if self.exact {
            return self.followed_newton(t1, beta);
        }
        if self.newton.full {
            return self.full_newton(t1, beta);
        }
        if self.needs_jacobian() {
            if !self.jacobian_at_predictor(t1) {
                return false;
            }
        } else {
            self.follow_junctions(1e-3);
        }
        let ready = (self.newton.factored && self.newton.beta == beta) || self.factor(beta);
        if ready {
            let before = self.stats.rhs_evals;
            match self.iterate(t1, beta) {
                Iteration::Converged => {
                    if self.stats.rhs_evals - before >= 3 {
                        self.newton.stale = true;
                    }
                    return true;
                }
                // Slow or failing: the iterate is no better a start than
                // the predictor (going on from it failed more steps).
                Iteration::Slow | Iteration::Failed => {}
            }
        }
        // The kept Jacobian does not take the iteration there (a junction
        // turning on bends f faster than one Jacobian follows): Newton
        // with the Jacobian of every iterate, from the predictor.
        self.stage.x.copy_from_slice(&self.stage.pred);
        self.full_newton(t1, beta)
    }

    /// The kept Jacobian is stale or too old.
    pub(super) fn needs_jacobian(&self) -> bool {
        self.newton.stale || self.newton.age >= JACOBIAN_AGE
    }

    /// A fresh Jacobian at the stage's predictor.
    pub(super) fn jacobian_at_predictor(&mut self, t1: f64) -> bool {
        let p = std::mem::take(&mut self.stage.pred);
        let ok = self.jacobian(t1, &p);
        self.stage.pred = p;
        ok
    }

    /// Newton where the kept Jacobian follows the junctions exactly
    /// (`exact`): moved to each iterate's junctions it is that iterate's own
    /// Jacobian, so the iteration converges as full Newton does for an
    /// evaluation per iterate. What an iterate leaves is about its
    /// correction times `θ`, the relative change of the junctions' `g_d` and
    /// `Q′` over it: one iterate suffices where the junctions barely move
    /// (and always in a linear circuit), where the kept Jacobian needed a
    /// second to measure its rate.
    pub(super) fn followed_newton(&mut self, t1: f64, beta: f64) -> bool {
        if self.needs_jacobian() && !self.jacobian_at_predictor(t1) {
            return false;
        }
        let mut last = f64::INFINITY;
        for it in 0..2 * MAX_ITERATIONS {
            if let Err(e) = self.ode.eval(t1, &self.stage.x, &mut self.stage.f) {
                self.error.get_or_insert(e);
                return false;
            }
            self.stats.rhs_evals += 1;
            self.follow_iterate();
            let ready = (self.newton.factored && self.newton.beta == beta) || self.factor(beta);
            if !ready {
                return false;
            }
            let norm = self.correct(beta);
            if !norm.is_finite() {
                return false;
            }
            if self.followed_converged(norm) {
                return true;
            }
            if it >= 1 && norm > 2.0 * last {
                return false;
            }
            last = norm;
        }
        false
    }

    /// Move the kept Jacobian to the junctions of the iterate `f` was just
    /// evaluated at (the inversion's registers hold each junction's voltage
    /// there, its `Q′` and `Q″`).
    pub(super) fn follow_iterate(&mut self) {
        for jn in &mut self.junctions {
            let ci = jn.ci;
            let (x, cap, cap2) = (
                self.ode.register(ci.memo),
                self.ode.register(ci.memo.offset(2)),
                self.ode.register(ci.memo.offset(3)),
            );
            let [id, gd, gd2] = self.ode.tape.diodes[ci.diode as usize].current(x);
            (jn.cap_p, jn.gd_p, jn.id) = (cap, gd, id);
            jn.curv = (gd2 / gd).abs().max((cap2 / cap).abs());
        }
        // A small matrix is refactored for every move: the Jacobian is then
        // the iterate's own, and a junction current converges in one
        // iterate where a Jacobian 1e-3 off needs two.
        let skip = if self.n <= EXACT_FOLLOW_STATES {
            0.0
        } else {
            1e-3
        };
        self.follow_junctions(skip);
    }

    /// `θ` of junction `jn`: how far the Jacobian is from the Jacobian
    /// after the last correction, relatively, at this junction: the change
    /// of its `g_d` and `Q′` over the correction (its charge correction over
    /// `Q′`, times their curvature), plus how far the kept entries were from
    /// the iterate's when following skipped them. What the correction
    /// leaves is about `θ` times it. NaN where the junction was not followed.
    /// `jkk`: the junction's diagonal entry, in magnitude.
    pub(super) fn junction_theta(&self, jn: &Junction, jkk: f64) -> f64 {
        let k = jn.k;
        let kept = (jn.cap_j / jn.cap_p - 1.0)
            .abs()
            .max(((jn.gd_j - jn.gd_p) / (jn.cap_p * jkk)).abs());
        (self.stage.delta[k] / jn.cap_p).abs() * jn.curv + kept
    }

    /// The iteration has converged: what the last correction leaves (`θ`
    /// times it, at least [`FOLLOW_FLOOR`] times it) is within the Newton
    /// tolerance, and what it leaves of each junction's charge reaches the
    /// current through the junction's series resistance amplified by the
    /// junction's own rate `|∂q′/∂q| ≈ 1/(Q′·RS)`: that current error within
    /// the Newton tolerance of the largest current the junction carried so
    /// far (a circuit simulator's per-device current test). Without it one
    /// iterate left a clamp's nA reverse current 0.7 % of its range off at
    /// rtol 1e-7; a rectifier's amperes do not ask for more.
    pub(super) fn followed_converged(&self, norm: f64) -> bool {
        let n = self.n;
        let tol = self.rtol.min(NEWTON_RTOL);
        let mut theta_max: f64 = 0.0;
        for jn in &self.junctions {
            let k = jn.k;
            let jkk = self.newton.jac[k * n + k].abs();
            let theta = self.junction_theta(jn, jkk);
            if !theta.is_finite() {
                return norm <= NEWTON_TOLERANCE;
            }
            theta_max = theta_max.max(theta);
            let di = theta * self.stage.delta[k].abs() * jkk;
            // The current `q` itself carries, rounded.
            let rounding = 8.0 * f64::EPSILON * self.stage.x[k].abs() * jkk;
            if di > NEWTON_TOLERANCE * (self.atol_i + tol * jn.i_peak) + rounding {
                return false;
            }
        }
        norm * theta_max.max(FOLLOW_FLOOR) <= NEWTON_TOLERANCE
    }

    /// Newton with a fresh Jacobian (and `f` with it) at every iterate.
    pub(super) fn full_newton(&mut self, t1: f64, beta: f64) -> bool {
        let mut last = f64::INFINITY;
        for it in 0..2 * MAX_ITERATIONS {
            let r = self.ode.jacobian_columns(
                Regs::Solver,
                t1,
                &self.stage.x,
                &self.columns,
                &mut self.newton.jac,
                &mut self.stage.f,
            );
            self.stats.jacobians += 1;
            if let Err(e) = r {
                self.error.get_or_insert(e);
                return false;
            }
            self.newton.factored = false;
            let y1 = std::mem::take(&mut self.stage.x);
            self.note_jacobian_point(&y1);
            self.stage.x = y1;
            if !self.factor(beta) {
                return false;
            }
            let norm = self.correct(beta);
            if !norm.is_finite() {
                return false;
            }
            let rate = if it == 0 { 1.0 } else { norm / last };
            if it >= 2 && rate > 2.0 {
                return false;
            }
            if norm * rate.min(1.0) <= NEWTON_TOLERANCE || norm <= FIRST_CORRECTION {
                let nw = &mut self.newton;
                nw.full = it >= 2;
                nw.stale = false;
                nw.age = 0;
                nw.rate = rate.min(1.0);
                return true;
            }
            last = norm;
        }
        false
    }
}

/// Whether every entry is finite, in one pass the compiler vectorizes
/// (`x · 0` is NaN exactly where `x` is infinite or NaN, and so is a sum
/// that meets one), where `all(is_finite)` tests entry by entry: at a
/// factorization per step it showed in the circuit integrator's profile.
fn all_finite(a: &[f64]) -> bool {
    let mut acc = [0.0f64; 4];
    let chunks = a.chunks_exact(4);
    let rest = chunks.remainder();
    for c in chunks {
        for k in 0..4 {
            acc[k] += c[k] * 0.0;
        }
    }
    let tail: f64 = rest.iter().map(|x| x * 0.0).sum();
    (acc[0] + acc[1] + acc[2] + acc[3] + tail) == 0.0
}

#[cfg(test)]
mod tests {
    use super::all_finite;

    /// Every length, a non-finite value at every place, each kind of it.
    #[test]
    fn all_finite_finds_every_infinity_and_nan() {
        for n in 0..11 {
            let mut a: Vec<f64> = (0..n).map(|k| (k as f64 - 4.5) * 1e300).collect();
            assert!(all_finite(&a), "{a:?}");
            for k in 0..n {
                for bad in [f64::INFINITY, f64::NEG_INFINITY, f64::NAN] {
                    let keep = std::mem::replace(&mut a[k], bad);
                    assert!(!all_finite(&a), "{a:?}");
                    a[k] = keep;
                }
            }
        }
    }
}
