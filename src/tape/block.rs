//! Solving a tape block: a junction-charge inversion, an affine block with
//! a constant Jacobian, Newton on one tear, or damped Newton on many, with
//! the work buffers they share.
//!
//! A tape block is solved one of four ways, decided at compile time: a
//! junction-charge inversion `0 = q − Q(x)` (`charge_inverse`: Halley's
//! method on the device's own derivatives, accepted when a bound on what the
//! step leaves is below rounding; it starts from the last point it evaluated,
//! whose `Q, Q′, Q″` it keeps in four registers of its own, so its first step
//! costs no evaluation), affine in its tears with coefficients no code writes
//! (`constant_jacobian`: the Jacobian is factored once, then one correction
//! per call), one tear (a Newton step per tangent run; where it fails, the
//! root is bracketed between tears of opposite residual and found by
//! safeguarded Newton; its corrections are measured against the tear's
//! floor, a nanoampere for a current, and its rounding exits against a
//! thousand times that), or the damped block Newton. Up to 48 tears a
//! block's Jacobian is dense: one multi-direction tangent pass of its body,
//! each instruction decoded once for all tears (a pass per tear makes an
//! inverter chain's run a third longer). Past 48 tears it is sparse: which
//! tears each residual depends on is followed through the body once, the tears are
//! coloured so that no residual sees two of one colour, each colour is one
//! tangent run, and the entries are factored by the circuit sparse LU (a
//! resistive ladder tears every few sections, and a dense LU is cubic in
//! the tears). Tearing keeps those tears: one guess swept down a
//! long ladder would amplify its error by the section gain each section. A
//! linear loop of more than 48 tears is compiled whole instead (every unknown
//! a Newton unknown, every equation a residual, same order;
//! `Block::solved_whole`, which the listing reports): its Jacobian has the
//! circuit's sparsity, where the torn one fills in (a 100×100 resistor mesh:
//! 2 s, ngspice 156 s; torn, 6.6 s). The listing still shows the tearing.

use super::*;

impl Tape {
    /// The registers of a charge-inversion block `0 = ±(target - Q(x))`:
    /// (x, q = Q(x), residual), and the sign of `∂residual/∂x = ±Q′(x)`.
    pub(super) fn charge_regs(b: &TapeBlock) -> (usize, usize, usize, f64) {
        let [Instr::Device { d: q, .. }, Instr::Sub { d: res, a: l, .. }] = b.body[..] else {
            unreachable!("a charge inversion is [Device, Sub]")
        };
        let sign = if l == q { 1.0 } else { -1.0 };
        (b.tears[0].idx(), q.idx(), res.idx(), sign)
    }

    /// ∂residuals/∂tears at the current point into `jac` (row-major n×n),
    /// evaluating the body there too; leaves `dr` (or `wide`) of the body
    /// registers dirty. All tears are seeded in one multi-direction pass
    /// (each instruction decoded once, its slope applied to every column)
    /// unless the registers times the tears exceed [`WIDE_TANGENT_LIMIT`];
    /// then a pass a column in `dr`.
    pub(super) fn block_jacobian(
        &self,
        b: &TapeBlock,
        r: &mut [f64],
        dr: &mut [f64],
        wide: &mut Vec<f64>,
        t: f64,
        jac: &mut [f64],
    ) -> Result<(), EvalError> {
        let n = b.tears.len();
        if n == 0 {
            return self.run(&b.body, r, t);
        }
        if n > 1 && r.len() * n <= WIDE_TANGENT_LIMIT {
            if wide.len() < r.len() * n {
                wide.resize(r.len() * n, 0.0);
            }
            // Registers read by the body but not written are constants here.
            for &x in &b.touched {
                super::tangent::zero(&mut wide[x.idx() * n..(x.idx() + 1) * n]);
            }
            for (j, &x) in b.tears.iter().enumerate() {
                wide[x.idx() * n + j] = 1.0;
            }
            self.run_tangents(&b.body, r, wide, n, t)?;
            for (i, &res) in b.residuals.iter().enumerate() {
                jac[i * n..(i + 1) * n].copy_from_slice(&wide[res.idx() * n..(res.idx() + 1) * n]);
            }
            return Ok(());
        }
        for j in 0..n {
            for &x in &b.touched {
                dr[x] = 0.0;
            }
            dr[b.tears[j]] = 1.0;
            self.run_tangent(&b.body, r, dr, t, None)?;
            for (i, &res) in b.residuals.iter().enumerate() {
                jac[i * n + j] = dr[res];
            }
        }
        Ok(())
    }

    /// Damped Newton on a block's tearing variables, warm-started from their
    /// current values; on failure the warm start is left for the solver's
    /// retry.
    pub(super) fn solve_block(&self, k: usize, r: &mut [f64], t: f64) -> Result<(), EvalError> {
        let b = &self.blocks[k];
        if let Some(ci) = b.charge_inverse
            && self.invert_charge(b, ci, r)
        {
            return self.settle(b, r, t);
        }
        let mut w = Work::take(b.tears.len(), r.len());
        w.start.extend(b.tears.iter().map(|&x| r[x]));
        let result = if b.constant_jacobian {
            self.solve_affine(b, r, t, &mut w)
        } else if b.tears.len() == 1 {
            self.newton_scalar(b, r, t, &mut w)
        } else {
            self.newton_iterate(b, r, t, &mut w)
        };
        if result.is_err() {
            for (j, &x) in b.tears.iter().enumerate() {
                r[x] = w.start[j];
            }
        }
        w.give();
        result
    }

    /// After the last correction of `b`'s tears: bring its body up to date
    /// unless nothing outside reads it (`private`).
    pub(super) fn settle(&self, b: &TapeBlock, r: &mut [f64], t: f64) -> Result<(), EvalError> {
        if b.private {
            Ok(())
        } else {
            self.run(&b.body, r, t)
        }
    }

    /// The factored constant Jacobian of `b`, computed at the first call
    /// that finds it finite and regular (a failure is not remembered: the
    /// registers it was computed from may have held a failed trial point),
    /// by [`Tape::factor_jacobian`]: dense up to [`DENSE_TEARS`] tears,
    /// sparse beyond (a ladder torn every few sections couples each residual
    /// to a few neighbouring tears, and a dense LU is cubic in the tears).
    pub(super) fn constant_lu<'t>(
        &self,
        b: &'t TapeBlock,
        r: &mut [f64],
        t: f64,
        w: &mut Work,
    ) -> Result<&'t Factored, EvalError> {
        if let Some(lu) = b.lu.get() {
            return Ok(lu);
        }
        let mut dr = std::mem::take(&mut w.dr);
        let factored = self.factor_jacobian(b, r, &mut dr, t, w);
        w.dr = dr;
        let lu = match factored? {
            Some(sparse) => Factored::Sparse(sparse),
            None => Factored::Dense(DenseLu {
                lu: w.jac.clone(),
                perm: w.perm.clone(),
            }),
        };
        Ok(b.lu.get_or_init(|| lu))
    }

    /// `b`'s Jacobian at the current point, factored (the body is evaluated
    /// there too; `dr`'s tangents of the body are left dirty): dense into
    /// `w.jac` and `w.perm` (`None`), or past [`DENSE_TEARS`] sparse.
    pub(super) fn factor_jacobian(
        &self,
        b: &TapeBlock,
        r: &mut [f64],
        dr: &mut [f64],
        t: f64,
        w: &mut Work,
    ) -> Result<Option<TripletLu>, EvalError> {
        let n = b.tears.len();
        if n > DENSE_TEARS {
            let pattern = b.pattern.get_or_init(|| Pattern::of(b));
            return match pattern {
                Some(p) => {
                    let val = self.pattern_values(b, p, r, dr, t)?;
                    if !val.iter().all(|v| v.is_finite()) {
                        return Err(b.singular(t));
                    }
                    p.sparse.factor(&val).map(Some).ok_or_else(|| b.singular(t))
                }
                None => {
                    let entries = self.dense_columns(b, r, dr, t)?;
                    match entries.iter().all(|e| e.2.is_finite()) {
                        true => TripletLu::new(n, entries)
                            .map(Some)
                            .ok_or_else(|| b.singular(t)),
                        false => Err(b.singular(t)),
                    }
                }
            };
        }
        w.dense_jac(n);
        self.block_jacobian(b, r, dr, &mut w.wide, t, &mut w.jac)?;
        if !(w.jac.iter().all(|v| v.is_finite()) && lu_factor(n, &mut w.jac, &mut w.perm)) {
            return Err(b.singular(t));
        }
        Ok(None)
    }

    /// The values of `b`'s Jacobian at the current point in the slots of its
    /// pattern: the columns of one colour (which share no residual) in one
    /// tangent run, each residual's derivative put where its one tear of
    /// that colour goes.
    fn pattern_values(
        &self,
        b: &TapeBlock,
        p: &Pattern,
        r: &mut [f64],
        dr: &mut [f64],
        t: f64,
    ) -> Result<Vec<f64>, EvalError> {
        let mut val = vec![0.0; p.sparse.nnz()];
        for (members, entries) in p.members.iter().zip(&p.by_colour) {
            for &x in &b.touched {
                dr[x] = 0.0;
            }
            for &j in members {
                dr[b.tears[j as usize]] = 1.0;
            }
            self.run_tangent(&b.body, r, dr, t, None)?;
            for &(i, slot) in entries {
                val[slot as usize] = dr[b.residuals[i as usize]];
            }
        }
        Ok(val)
    }

    /// The nonzero entries `(residual, tear, ∂)` of `b`'s Jacobian at the
    /// current point, one tangent run a column (a block too dense for
    /// [`tear_pattern`]).
    fn dense_columns(
        &self,
        b: &TapeBlock,
        r: &mut [f64],
        dr: &mut [f64],
        t: f64,
    ) -> Result<Vec<(usize, usize, f64)>, EvalError> {
        let mut entries = Vec::new();
        for (c, &tear) in b.tears.iter().enumerate() {
            for &x in &b.touched {
                dr[x] = 0.0;
            }
            dr[tear] = 1.0;
            self.run_tangent(&b.body, r, dr, t, None)?;
            for (i, &res) in b.residuals.iter().enumerate() {
                let v = dr[res];
                if v != 0.0 {
                    entries.push((i, c, v));
                }
            }
        }
        Ok(entries)
    }

    /// A block whose residuals are affine in the tears with a constant
    /// Jacobian: one correction from the current tears solves it.
    pub(super) fn solve_affine(
        &self,
        b: &TapeBlock,
        r: &mut [f64],
        t: f64,
        w: &mut Work,
    ) -> Result<(), EvalError> {
        let lu = self.constant_lu(b, r, t, w)?;
        self.run(&b.body, r, t)?;
        for (j, &x) in b.residuals.iter().enumerate() {
            w.step[j] = r[x];
        }
        if w.step.iter().all(|v| *v == 0.0) {
            return Ok(());
        }
        lu.solve_in_place(&mut w.step, &mut w.tmp);
        if w.step.iter().any(|v| !v.is_finite()) {
            return Err(b.singular(t));
        }
        for (j, &x) in b.tears.iter().enumerate() {
            r[x] -= w.step[j];
        }
        self.settle(b, r, t)
    }

    /// Halley's method on `Q(x) = q` with the device's `Q′` and `Q″`, from the
    /// warm start in the tear. What a Halley step leaves is about its cube
    /// times `Q″²/(4Q′²) - Q‴/(6Q′)`, bounded here from the junction's
    /// parameters: a warm start within a few microvolts converges in one
    /// evaluation where Newton needs two. Far steps are limited as ngspice
    /// limits junctions. `false` (the tear as it was) when the iteration
    /// cannot proceed: the damped Newton takes over.
    pub(super) fn invert_charge(&self, b: &TapeBlock, ci: ChargeInverse, r: &mut [f64]) -> bool {
        let p = &self.diodes[ci.diode as usize];
        let (x_reg, target) = (b.tears[0].idx(), r[ci.target]);
        let memo = ci.memo;
        let start = r[x_reg];
        // From the last evaluated point when there is one: its values are
        // known, so the first step is free.
        let mut x = if r[memo].is_finite() { r[memo] } else { start };
        for _ in 0..100 {
            let [q, c, c2] = if x == r[memo] {
                [r[memo.offset(1)], r[memo.offset(2)], r[memo.offset(3)]]
            } else {
                let v = p.charge(x);
                r[memo] = x;
                r[memo.idx() + 1..memo.idx() + 4].copy_from_slice(&v);
                v
            };
            let f = q - target;
            if f == 0.0 {
                r[x_reg] = x;
                return true;
            }
            if !(c > 0.0 && f.is_finite() && c2.is_finite()) {
                break;
            }
            let newton = f / c;
            let k = c2 / c;
            let h = 0.5 * newton * k;
            let (step, left) = if h.abs() <= 0.5 {
                let step = newton / (1.0 - h);
                let constant = 0.25 * k * k + p.third_derivative_bound(x);
                (step, step.abs().powi(3) * constant)
            } else {
                (newton, 0.5 * newton * newton * k.abs())
            };
            let next = x - step;
            let limited = limit_junction(next, x, p.vte, p.bv.unwrap_or(f64::INFINITY));
            if limited != next {
                x = limited;
                continue;
            }
            x = next;
            if left <= 1e-13 * (1.0 + x.abs()) {
                r[x_reg] = x;
                return true;
            }
        }
        r[x_reg] = start;
        false
    }

    /// Newton on a one-tear block: each iteration is one tangent run of the
    /// body, which gives the residual and its slope together. The step is
    /// damped by the same natural monotonicity test as [`Self::newton_iterate`]
    /// (checked with the residual the next iteration computes anyway) and
    /// junction tears are limited as ngspice limits them. A block affine in
    /// its tear takes the full step and one refinement, undamped.
    pub(super) fn newton_scalar(
        &self,
        b: &TapeBlock,
        r: &mut [f64],
        t: f64,
        w: &mut Work,
    ) -> Result<(), EvalError> {
        let (x, res) = (b.tears[0].idx(), b.residuals[0].idx());
        let floor = b.floor;
        // The scale of the rounding exits: a thousand times the floor, a
        // volt at most (a torn current's exits at 1e-9 of a microampere).
        let rounding = (1e3 * floor).min(1.0);
        let vt = b.junctions.first().map(|&(_, vt, bv)| (vt.idx(), bv));
        let finish = |r: &mut [f64], value: f64| {
            r[x] = value;
            self.settle(b, r, t)
        };
        // The last full step: start, correction, slope, scaled size, damping.
        let mut last: Option<(f64, f64, f64, f64, f64)> = None;
        // The last tear seen with a negative and with a positive residual:
        // where Newton fails between them, a bracketed search does not.
        let mut bracket = Bracket::default();
        for _ in 0..400 {
            if self.over_budget() {
                return Err(b.no_convergence(r[res].abs(), t));
            }
            let (fx, slope) = self.scalar_tangent(b, r, t, w)?;
            let xv = r[x];
            bracket.see(xv, fx);
            if let Some((x0, step0, slope0, full0, lambda)) = last {
                let simplified = (fx / slope0).abs() / (floor + x0.abs());
                if !newton::monotone(simplified, full0, lambda) {
                    // A correction below 1e-9 of a thousand times the
                    // tear's floor (a volt, or a microampere for a current;
                    // of the tear itself, if larger) that no longer shrinks
                    // is rounding: this point (its body evaluated by the
                    // tangent run) is the solution. Halving on would spend
                    // the iterations at rounding level. Against the floor
                    // itself, a current summed from amperes (a MOSFET's drain
                    // at KP = 10, `cmos_buffer_algebraic.cir`) stalled at a
                    // residual of 1e-14 A and failed; against a volt, a
                    // picoampere torn through 1 TΩ stopped 19 mV off on the
                    // node it holds (`leakage_divider.cir`).
                    let coarse = step0.abs() / (rounding + x0.abs());
                    if coarse <= 1e-9 {
                        return Ok(());
                    }
                    let lambda = lambda * 0.5;
                    if lambda < newton::MIN_DAMPING {
                        // No step along the exact slope lowers a residual
                        // that is rounding: the start is the solution (as
                        // in `newton_iterate`).
                        if (slope0 * step0).abs() <= STALL_FLOOR && coarse <= 1e-6 {
                            return finish(r, x0);
                        }
                        let fail = b.no_convergence(fx.abs(), t);
                        return self.scalar_bracketed(b, r, t, w, bracket, fail);
                    }
                    r[x] = x0 - lambda * step0;
                    last = Some((x0, step0, slope0, full0, lambda));
                    continue;
                }
            }
            if fx == 0.0 {
                return Ok(());
            }
            let step = fx / slope;
            let full = step.abs() / (floor + xv.abs());
            if !full.is_finite() {
                // A flat residual (a MOSFET cut off in the loop) is not a
                // singular block where another tear brackets a root.
                return self.scalar_bracketed(b, r, t, w, bracket, b.singular(t));
            }
            bracket.scale = bracket.scale.max(step.abs());
            if b.affine() {
                // Affine in its tear: the full step solves it, and one more
                // with the same slope refines it where that helps, as in
                // `newton_iterate`. A damping test would compare rounding:
                // the residual of a loop of junction charges is the
                // difference of terms 10^10 times larger.
                r[x] = xv - step;
                self.run(&b.body, r, t)?;
                let refine = r[res] / slope;
                if refine.is_finite() && refine.abs() < step.abs() {
                    r[x] -= refine;
                    self.run(&b.body, r, t)?;
                }
                return Ok(());
            }
            // The residual is rounding and the correction small, if not
            // below 1e-13 relative: a derivative tear at DC, whose 1e-9 V/s
            // correction is large only beside its value of ~0, and whose
            // steps would bounce at rounding level.
            if full <= 1e-13
                || (fx.abs() <= RESIDUAL_FLOOR && step.abs() / (rounding + xv.abs()) <= 1e-6)
            {
                return finish(r, xv - step);
            }
            if let Some((_, _, _, full0, 1.0)) = last
                && newton::converged_quadratically(full0, full)
            {
                // Quadratic convergence: what this step leaves is below rounding.
                return finish(r, xv - step);
            }
            if let Some((vt, bv)) = vt {
                let vt = r[vt].abs();
                // A junction's residual curves like exp(x/vt): Newton's error
                // after this step is about step²/(2 vt). Below rounding, the
                // step is the last one.
                if vt > 0.0 && step * step <= 2e-13 * vt * (1.0 + xv.abs()) {
                    return finish(r, xv - step);
                }
                if vt > 0.0 {
                    let limited = limit_junction(xv - step, xv, vt, bv);
                    if limited != xv - step {
                        r[x] = limited;
                        last = None;
                        continue;
                    }
                }
            }
            r[x] = xv - step;
            last = Some((xv, step, slope, full, 1.0));
        }
        let fail = b.no_convergence(r[res].abs(), t);
        self.scalar_bracketed(b, r, t, w, bracket, fail)
    }

    /// One tangent run of a one-tear block at its tear's current value:
    /// the residual and its slope (the body evaluated there too).
    fn scalar_tangent(
        &self,
        b: &TapeBlock,
        r: &mut [f64],
        t: f64,
        w: &mut Work,
    ) -> Result<(f64, f64), EvalError> {
        let (x, res) = (b.tears[0].idx(), b.residuals[0].idx());
        for &z in &b.touched {
            w.dr[z] = 0.0;
        }
        w.dr[x] = 1.0;
        self.run_tangent(&b.body, r, &mut w.dr, t, None)?;
        Ok((r[res], w.dr[res]))
    }

    /// Every residual seen was of one sign: search both ways from the
    /// smallest one for the other sign, in steps doubling from the largest
    /// Newton correction seen, as far as the residual stays finite.
    fn widen(&self, b: &TapeBlock, r: &mut [f64], t: f64, bracket: &mut Bracket) {
        let Some((x0, f0)) = bracket.best else {
            return;
        };
        let (x, res) = (b.tears[0].idx(), b.residuals[0].idx());
        let h0 = bracket.scale.max(1e-9 * (b.floor + x0.abs()));
        let mut open = [true, true];
        for k in 0..64 {
            let h = h0 * f64::powi(2.0, k);
            for (side, dir) in [-1.0, 1.0].into_iter().enumerate() {
                if !open[side] {
                    continue;
                }
                if self.over_budget() {
                    return;
                }
                let xv = x0 + dir * h;
                r[x] = xv;
                let f = match self.run(&b.body, r, t) {
                    Ok(()) => r[res],
                    Err(_) => f64::NAN,
                };
                if !f.is_finite() || !xv.is_finite() {
                    open[side] = false;
                } else if f.signum() != f0.signum() {
                    bracket.see(xv, f);
                    return;
                }
            }
            if open == [false, false] {
                return;
            }
        }
    }

    /// Where Newton on one tear fails (a kink or a flat stretch of the
    /// residual, as a MOSFET's cutoff gives a high-gain loop), the root is
    /// searched between the tears of opposite residual seen so far: Newton
    /// steps that stay inside the bracket and halve the last step, bisection
    /// otherwise (safeguarded Newton, Press et al., Numerical Recipes §9.4).
    /// A continuous residual always has a root there. The bracket shrinks to
    /// rounding; its end of smaller residual is the solution when that
    /// residual is what the slope there gives over the bracket's width. No
    /// bracket (every residual of one sign): `fail`, Newton's own error.
    fn scalar_bracketed(
        &self,
        b: &TapeBlock,
        r: &mut [f64],
        t: f64,
        w: &mut Work,
        mut bracket: Bracket,
        fail: EvalError,
    ) -> Result<(), EvalError> {
        let x = b.tears[0].idx();
        if bracket.neg.is_none() || bracket.pos.is_none() {
            self.widen(b, r, t, &mut bracket);
        }
        let (Some(mut lo), Some(mut hi)) = (bracket.neg, bracket.pos) else {
            return Err(fail);
        };
        let mut best = (f64::INFINITY, f64::NAN, 0.0);
        let mut xv = 0.5 * (lo + hi);
        let mut step_before = (hi - lo).abs();
        let mut step = step_before;
        for _ in 0..200 {
            if self.over_budget() {
                break;
            }
            r[x] = xv;
            let (f, slope) = self.scalar_tangent(b, r, t, w)?;
            if f == 0.0 {
                return Ok(());
            }
            if !f.is_finite() {
                return Err(fail);
            }
            if f.abs() < best.0 {
                best = (f.abs(), xv, slope);
            }
            if f < 0.0 {
                lo = xv;
            } else {
                hi = xv;
            }
            let width = (hi - lo).abs();
            if width <= 4.0 * f64::EPSILON * xv.abs().max(f64::MIN_POSITIVE) {
                break;
            }
            let newton = xv - f / slope;
            let inside = (newton - lo) * (newton - hi) < 0.0;
            if inside && (2.0 * f).abs() <= (step_before * slope).abs() {
                step_before = step;
                step = f / slope;
                if step.abs() <= 1e-13 * (b.floor + xv.abs()) {
                    r[x] = newton;
                    return self.settle(b, r, t);
                }
                xv = newton;
            } else {
                step_before = step;
                step = 0.5 * width;
                xv = 0.5 * (lo + hi);
            }
        }
        // The bracket closed on a residual that the slope over its width
        // accounts for (a root between neighbouring floats), or on a jump.
        let (f, xb, slope) = best;
        let width = (hi - lo).abs().max(f64::EPSILON * xb.abs());
        if f.is_finite() && f <= 16.0 * (slope * width).abs() + RESIDUAL_FLOOR {
            r[x] = xb;
            return self.settle(b, r, t);
        }
        Err(b.no_convergence(f, t))
    }

    /// Damped Newton with the natural monotonicity test (Deuflhard): a step
    /// is accepted when the simplified Newton correction at the new point,
    /// `J⁻¹ r(x_new)` with the old `J`, is shorter than the full correction.
    /// Affine invariant, so badly scaled residuals (amperes beside volts)
    /// do not mislead the damping. Allocation-free: `w` holds the buffers.
    pub(super) fn newton_iterate(
        &self,
        b: &TapeBlock,
        r: &mut [f64],
        t: f64,
        w: &mut Work,
    ) -> Result<(), EvalError> {
        let no_convergence = |r: &[f64]| {
            let residual = b.residuals.iter().map(|&x| r[x].abs()).fold(0.0, f64::max);
            b.no_convergence(residual, t)
        };
        let scaled = |d: &[f64], x: &[f64]| newton::scaled_norm(d, |k| 1.0 + x[k].abs());
        let set = |r: &mut [f64], x0: &[f64], step: &[f64], lambda: f64| {
            for (j, &x) in b.tears.iter().enumerate() {
                r[x] = x0[j] - lambda * step[j];
            }
        };
        // The Jacobian's tangent runs evaluate the body too.
        for _ in 0..200 {
            if self.over_budget() {
                return Err(no_convergence(r));
            }
            let mut dr = std::mem::take(&mut w.dr);
            let factored = self.factor_jacobian(b, r, &mut dr, t, w);
            w.dr = dr;
            let sparse = factored?;
            for (j, &x) in b.residuals.iter().enumerate() {
                w.step[j] = r[x];
            }
            if w.step.iter().all(|v| *v == 0.0) {
                return Ok(());
            }
            let residual0 = w.step.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            solve_factored(sparse.as_ref(), &w.jac, &w.perm, &mut w.step, &mut w.tmp);
            for (j, &x) in b.tears.iter().enumerate() {
                w.x0[j] = r[x];
            }
            let full = scaled(&w.step, &w.x0);
            if !full.is_finite() {
                return Err(b.singular(t));
            }
            if full <= 1e-13 {
                // Converged to rounding: take the last correction and stop.
                set(r, &w.x0, &w.step, 1.0);
                return self.settle(b, r, t);
            }
            if b.affine() {
                // Affine in its tears: the full correction solves the block
                // up to its Jacobian's conditioning, and one more with the
                // same factors refines it where that helps. A damping test
                // would compare rounding noise: near equilibrium a charge's
                // derivative is the difference of terms 10^11 times larger
                // (a femtofarad gate capacitance on microamperes).
                set(r, &w.x0, &w.step, 1.0);
                self.run(&b.body, r, t)?;
                for (j, &x) in b.residuals.iter().enumerate() {
                    w.bar[j] = r[x];
                }
                solve_factored(sparse.as_ref(), &w.jac, &w.perm, &mut w.bar, &mut w.tmp);
                for (j, &x) in b.tears.iter().enumerate() {
                    w.x0[j] = r[x];
                }
                let refine = scaled(&w.bar, &w.x0);
                if refine.is_finite() && refine < full {
                    for (j, &x) in b.tears.iter().enumerate() {
                        r[x] -= w.bar[j];
                    }
                    self.run(&b.body, r, t)?;
                }
                return Ok(());
            }
            // Junction limiting (ngspice's pnjlim) on tears inside an exp().
            // A limited step is taken as it is, as SPICE does.
            let mut limited = false;
            for &(j, vt, bv) in &b.junctions {
                let vt = r[vt].abs();
                if vt > 0.0 {
                    let new = limit_junction(w.x0[j] - w.step[j], w.x0[j], vt, bv);
                    if new != w.x0[j] - w.step[j] {
                        limited = true;
                    }
                    w.step[j] = w.x0[j] - new;
                }
            }
            if limited {
                set(r, &w.x0, &w.step, 1.0);
                continue;
            }
            let damping = newton::damp(full, |lambda| {
                set(r, &w.x0, &w.step, lambda);
                self.run(&b.body, r, t)?;
                for (j, &x) in b.residuals.iter().enumerate() {
                    w.bar[j] = r[x];
                }
                solve_factored(sparse.as_ref(), &w.jac, &w.perm, &mut w.bar, &mut w.tmp);
                // The same scaling as the full correction: a scale that moved
                // with x would make a shrinking |x| look like no progress.
                Ok(scaled(&w.bar, &w.x0))
            })?;
            let Damping::Accepted { lambda, simplified } = damping else {
                if full <= 1e-9 {
                    // Stalled at rounding level: converged as far as f64 allows.
                    return Ok(());
                }
                if residual0 <= STALL_FLOOR && full <= 1e-6 {
                    // No damped step lowers residuals that are rounding (see
                    // `newton_scalar` and [`STALL_FLOOR`]): the point the
                    // step started from is the solution.
                    set(r, &w.x0, &w.step, 0.0);
                    return self.settle(b, r, t);
                }
                set(r, &w.x0, &w.step, 0.0);
                match self.rounding(b, r, t, sparse.as_ref(), w)? {
                    Some(at) if at.solved() => return self.settle(b, r, t),
                    Some(at) if self.full_step_lowers(b, r, t, sparse.as_ref(), w, at)? => {
                        continue;
                    }
                    _ => return Err(no_convergence(r)),
                }
            };
            if lambda < CREEP_DAMPING {
                // A step this short passes the monotonicity test by less
                // than a correction's rounding can move it: where the
                // correction is rounding, Newton would creep by it for
                // ever (measured: 200 steps of λ ≈ 1e-10 on a MOSFET
                // driver's loop, each moving a tear by 5e-18; under TR-BDF2,
                // 200 of λ ≈ 3e-5 on corrections of 1.8e-10 of their tear).
                if full <= 1e-9 {
                    // As where the damping stalls.
                    return Ok(());
                }
                set(r, &w.x0, &w.step, 0.0);
                match self.rounding(b, r, t, sparse.as_ref(), w)? {
                    Some(at) if at.solved() => return self.settle(b, r, t),
                    Some(at) if self.full_step_lowers(b, r, t, sparse.as_ref(), w, at)? => {}
                    _ => set(r, &w.x0, &w.step, lambda),
                }
                continue;
            }
            if b.affine() && lambda == 1.0 {
                return Ok(());
            }
            if lambda == 1.0 && newton::converged_quadratically(full, simplified) {
                // Quadratic convergence has set in: the simplified correction
                // leaves an error of order `simplified * full`, below rounding.
                for (j, &x) in b.tears.iter().enumerate() {
                    r[x] -= w.bar[j];
                }
                return self.settle(b, r, t);
            }
            // Otherwise go on: the next correction (at most 1e-13) is applied
            // at the top, so the solution is as exact as f64 allows; the
            // integrator's Newton needs f to be smooth to its own tolerance.
        }
        Err(no_convergence(r))
    }
}

impl Tape {
    /// The block at the point in `r` (which this evaluates again) against
    /// the rounding of its residuals, bounded by [`Tape::run_rounding`]:
    /// whether the Newton correction in `w.step` is rounding (each tear's
    /// correction at most what those bounds, carried through the factored
    /// `J⁻¹`, move it by: the two sign patterns of the bounds give `|J⁻¹|·e`
    /// exactly for two tears and a lower estimate beyond), and the residuals'
    /// size in their bounds, `max |rᵢ|/eᵢ`. A huge slope (a picofarad gate
    /// capacitance's `∂(dq/dt)/∂i`) carries a residual's last bit into a
    /// correction far above any fixed floor, which only this sees. `None`
    /// where the bounds are not known (a nested block, a non-finite bound).
    fn rounding(
        &self,
        b: &TapeBlock,
        r: &mut [f64],
        t: f64,
        sparse: Option<&TripletLu>,
        w: &mut Work,
    ) -> Result<Option<Rounding>, EvalError> {
        let mut e = std::mem::take(&mut w.dr);
        for &x in &b.touched {
            e[x] = 0.0;
        }
        let bounded = self.run_rounding(&b.body, r, &mut e, t);
        let mut floor = std::mem::take(&mut w.floor);
        floor.clear();
        floor.extend(b.residuals.iter().map(|&x| e[x]));
        w.dr = e;
        let result = match bounded {
            Ok(true) if floor.iter().all(|v| v.is_finite()) => {
                Ok(Some(Self::rounding_at(b, r, &floor, sparse, w)))
            }
            Ok(_) => Ok(None),
            Err(err) => Err(err),
        };
        w.floor = floor;
        result
    }

    /// [`Tape::rounding`] from the residuals' rounding bounds `floor`.
    fn rounding_at(
        b: &TapeBlock,
        r: &[f64],
        floor: &[f64],
        sparse: Option<&TripletLu>,
        w: &mut Work,
    ) -> Rounding {
        let size = b
            .residuals
            .iter()
            .zip(floor)
            .map(|(&x, &f)| match (r[x].abs(), f) {
                (0.0, _) => 0.0,
                (v, f) => v / f,
            })
            .fold(0.0, f64::max);
        w.reach.clear();
        w.reach.resize(floor.len(), 0.0);
        for flip in [false, true] {
            for (j, v) in floor.iter().enumerate() {
                w.bar[j] = if flip && j % 2 == 1 { -v } else { *v };
            }
            solve_factored(sparse, &w.jac, &w.perm, &mut w.bar, &mut w.tmp);
            for (m, v) in w.reach.iter_mut().zip(&w.bar) {
                *m = m.max(v.abs());
            }
        }
        let correction = w.step.iter().zip(&w.reach).all(|(d, m)| d.abs() <= *m);
        Rounding { correction, size }
    }

    /// Whether the full Newton step from the point in `r`, `x0 − d` with
    /// `d` in `w.step`, lowers the residuals measured in their rounding
    /// bounds below `at`'s, where those are within [`NEAR_ROUNDING`] of
    /// them; it is left in `r` where tried. The damping
    /// compares corrections, and where one tear's is rounding carried
    /// through a large slope, that noise (far above its tear's scale) hides
    /// the real correction of another: a high-side driver's loop took steps
    /// of λ ≈ 1e-7 whose full step would have lowered both residuals 50-fold.
    fn full_step_lowers(
        &self,
        b: &TapeBlock,
        r: &mut [f64],
        t: f64,
        sparse: Option<&TripletLu>,
        w: &mut Work,
        at: Rounding,
    ) -> Result<bool, EvalError> {
        if at.size > NEAR_ROUNDING {
            return Ok(false);
        }
        for (j, &x) in b.tears.iter().enumerate() {
            r[x] = w.x0[j] - w.step[j];
        }
        Ok(self
            .rounding(b, r, t, sparse, w)?
            .is_some_and(|next| next.size < at.size))
    }

    /// Runs `code` at `r` and bounds, to first order, the rounding error of
    /// each register it writes (running error analysis: Higham, "Accuracy
    /// and Stability of Numerical Algorithms", §3.1): `e[d]` is
    /// `Σ |∂d/∂a|·e[a]` over the operands plus the operation's own rounding,
    /// `u·|d|` (a few `u` for a library or device function). Registers it
    /// does not write keep their `e` (a tear's is 0: its value is exact).
    /// `false` where the body holds a nested block, whose error this does
    /// not follow.
    pub(super) fn run_rounding(
        &self,
        code: &[Instr],
        r: &mut [f64],
        e: &mut [f64],
        t: f64,
    ) -> Result<bool, EvalError> {
        const U: f64 = f64::EPSILON / 2.0;
        self.count_work(code.len());
        for ins in code {
            match *ins {
                Instr::Neg { d, a } => {
                    r[d] = -r[a];
                    e[d] = e[a];
                }
                Instr::Add { d, a, b } => {
                    r[d] = r[a] + r[b];
                    e[d] = e[a] + e[b] + U * r[d].abs();
                }
                Instr::Sub { d, a, b } => {
                    r[d] = r[a] - r[b];
                    e[d] = e[a] + e[b] + U * r[d].abs();
                }
                Instr::Mul { d, a, b } => {
                    let (x, y) = (r[a], r[b]);
                    r[d] = x * y;
                    e[d] = y.abs() * e[a] + x.abs() * e[b] + U * r[d].abs();
                }
                Instr::Div { d, a, b } => {
                    let (x, y) = (r[a], r[b]);
                    let q = x / y;
                    r[d] = q;
                    e[d] = (e[a] + q.abs() * e[b]) / y.abs() + U * q.abs();
                }
                Instr::Pow { d, a, b } => {
                    let (x, y) = (r[a], r[b]);
                    let p = x.powf(y);
                    r[d] = p;
                    let mut bound = (y * x.powf(y - 1.0)).abs() * e[a] + 4.0 * U * p.abs();
                    if e[b] != 0.0 {
                        bound += (p * x.ln()).abs() * e[b];
                    }
                    e[d] = bound;
                }
                Instr::Call { d, f, a } => {
                    let x = r[a];
                    let fx = f.apply(x);
                    r[d] = fx;
                    e[d] = f.derivative(x, fx).abs() * e[a] + 2.0 * U * fx.abs();
                }
                Instr::Cmp { d, op, a, b, m } => {
                    r[d] = self.compare(op, m, r[a], r[b]);
                    e[d] = 0.0;
                }
                Instr::Select { d, c, a, b } => {
                    let pick = if r[c] != 0.0 { a } else { b };
                    r[d] = r[pick];
                    e[d] = e[pick];
                }
                Instr::Device { d, f, a } => {
                    let (v, slope) = self.device(f, r[a]);
                    r[d] = v;
                    // A device function scales its argument before its
                    // exponential: that rounding, carried by the slope.
                    e[d] = slope.abs() * (e[a] + U * r[a].abs()) + 8.0 * U * v.abs();
                }
                Instr::Src { d, s, order } => {
                    r[d] = self.source(s, t, order);
                    e[d] = 0.0;
                }
                Instr::Time { d } => {
                    r[d] = t;
                    e[d] = 0.0;
                }
                Instr::TimeRate { d } => {
                    r[d] = self.time_rate();
                    e[d] = 0.0;
                }
                Instr::Block { .. } => return Ok(false),
            }
        }
        Ok(true)
    }
}

/// A torn block's point against its residuals' rounding ([`Tape::rounding`]).
#[derive(Clone, Copy)]
struct Rounding {
    /// The Newton correction is within what rounding moves it by.
    correction: bool,
    /// `max |rᵢ|/eᵢ`: the residuals in their rounding bounds.
    size: f64,
}

impl Rounding {
    /// No f64 Newton step gets closer: the correction is rounding, or every
    /// residual is within its rounding bound, whatever the units.
    fn solved(self) -> bool {
        self.correction || self.size <= 1.0
    }
}

/// How far above their rounding bounds the residuals may be for
/// [`Tape::full_step_lowers`] to try the full step: 2^13, the last quarter
/// of f64's bits. Farther off, the damping's caution is not rounding's doing:
/// a BJT inverter on a 1.48e22 V supply, its residuals 7e14 times their
/// bounds at the operating point, took a full step there to a base node at
/// 14.6 kV.
const NEAR_ROUNDING: f64 = 8192.0;

/// A damping factor below which an accepted step is checked for a
/// correction that is rounding ([`Tape::rounding`]): 200 steps of it move
/// the tears by less than a fifth of their correction, so a Newton that
/// creeps at it does not converge within its budget.
const CREEP_DAMPING: f64 = 1e-3;

/// The largest multi-direction tangent buffer (registers × tears) a dense
/// block Jacobian uses, 8 MiB; a larger product takes a pass a column.
const WIDE_TANGENT_LIMIT: usize = 1 << 20;

/// A residual at the floor rounding leaves on currents of milliamperes, far
/// below ngspice's ABSTOL (1e-12 A), VNTOL (1e-6 V) and CHGTOL (1e-14 C):
/// with a correction below 1e-6 relative, a block is solved.
const RESIDUAL_FLOOR: f64 = 1e-17;

/// The same for a block where no damped step along the exact slope lowers
/// the residual (the damping stalled; one tear or many): rounding on sums of
/// milliampere currents leaves 2e-16 A on an ECL Schmitt trigger's emitter
/// node. Only after a stall: as the floor of every test above it ended
/// solves that would still converge, early enough that an op-amp
/// follower's operating point was lost.
const STALL_FLOOR: f64 = 1e-15;

/// [`crate::ir::junction_limit`] where the saturation current is not known
/// (tears inside an `exp()`): the critical voltage taken as 12 thermal
/// voltages. A tear's step is limited forward and past its diode's
/// breakdown `bv`.
pub(super) fn limit_junction(new: f64, old: f64, vt: f64, bv: f64) -> f64 {
    crate::ir::junction_limit(new, old, vt, 12.0 * vt, bv)
}

/// The last tear seen with a negative and with a positive residual in a
/// one-tear Newton iteration.
#[derive(Clone, Copy, Default)]
pub(super) struct Bracket {
    neg: Option<f64>,
    pos: Option<f64>,
    /// The tear of smallest residual seen, and that residual.
    best: Option<(f64, f64)>,
    /// The largest Newton correction seen: the scale of a search.
    scale: f64,
}

impl Bracket {
    fn see(&mut self, x: f64, f: f64) {
        if !(x.is_finite() && f.is_finite()) {
            return;
        }
        if self.best.is_none_or(|(_, fb)| f.abs() < fb.abs()) {
            self.best = Some((x, f));
        }
        if f < 0.0 {
            self.neg = Some(x);
        } else if f > 0.0 {
            self.pos = Some(x);
        }
    }
}

/// Buffers of one Newton solve, pooled per thread so that evaluating `f`
/// allocates nothing once warm (blocks can nest, so it is a pool).
#[derive(Default)]
pub(super) struct Work {
    pub(super) jac: Vec<f64>,
    pub(super) perm: Vec<usize>,
    pub(super) step: Vec<f64>,
    pub(super) x0: Vec<f64>,
    pub(super) bar: Vec<f64>,
    pub(super) tmp: Vec<f64>,
    /// The tears on entry (empty until filled).
    pub(super) start: Vec<f64>,
    /// Saved tangents (empty until filled).
    pub(super) saved: Vec<f64>,
    /// Residual right-hand side (empty until filled).
    pub(super) res: Vec<f64>,
    /// Register-sized tangents.
    pub(super) dr: Vec<f64>,
    /// Tangents in every tear's direction at once (registers × tears).
    pub(super) wide: Vec<f64>,
    /// The residuals' rounding bounds, and what they move each tear by
    /// (empty until filled; [`Tape::rounding`]).
    pub(super) floor: Vec<f64>,
    pub(super) reach: Vec<f64>,
}

thread_local! {
    // Boxed so that taking and giving back moves a pointer, not ten vectors.
    #[allow(clippy::vec_box)]
    static WORK: std::cell::RefCell<Vec<Box<Work>>> = const { std::cell::RefCell::new(Vec::new()) };
}

impl Work {
    /// Buffers for an `n`-tear block and `regs` tangent registers.
    pub(super) fn take(n: usize, regs: usize) -> Box<Work> {
        let mut w = WORK.with(|p| p.borrow_mut().pop()).unwrap_or_default();
        for v in [&mut w.step, &mut w.x0, &mut w.bar, &mut w.tmp] {
            v.clear();
            v.resize(n, 0.0);
        }
        w.perm.clear();
        w.perm.resize(n, 0);
        w.start.clear();
        w.saved.clear();
        w.res.clear();
        if w.dr.len() < regs {
            w.dr.resize(regs, 0.0);
        }
        w
    }

    /// The dense `n`×`n` Jacobian buffer, zeroed (only blocks that factor
    /// a Jacobian per call pay for it: a constant one is factored once).
    pub(super) fn dense_jac(&mut self, n: usize) -> &mut Vec<f64> {
        self.jac.clear();
        self.jac.resize(n * n, 0.0);
        &mut self.jac
    }

    pub(super) fn give(self: Box<Work>) {
        WORK.with(|p| p.borrow_mut().push(self));
    }
}

/// Which tears each residual of `b` depends on (sorted), followed through
/// the body as sets per register; `None` when a set grows past
/// [`PATTERN_MAX`] (dense enough for one column per run) or the body holds a
/// nested block.
pub(super) fn tear_pattern(b: &TapeBlock) -> Option<Vec<Vec<u32>>> {
    let mut deps: HashMap<Reg, Vec<u32>> = HashMap::new();
    for (j, &x) in b.tears.iter().enumerate() {
        deps.insert(x, vec![j as u32]);
    }
    for ins in &b.body {
        if matches!(ins, Instr::Block { .. }) {
            return None;
        }
        let mut set: Vec<u32> = Vec::new();
        for a in ins.operands() {
            if let Some(s) = deps.get(&a) {
                set.extend_from_slice(s);
            }
        }
        set.sort_unstable();
        set.dedup();
        if set.len() > PATTERN_MAX {
            return None;
        }
        let d = ins.dest();
        if set.is_empty() {
            deps.remove(&d);
        } else {
            deps.insert(d, set);
        }
    }
    Some(
        b.residuals
            .iter()
            .map(|r| deps.get(r).cloned().unwrap_or_default())
            .collect(),
    )
}

/// Dependency sets larger than this make [`tear_pattern`] give up.
pub(super) const PATTERN_MAX: usize = 64;

/// Blocks with more tears than this factor a constant Jacobian as sparse.
pub(super) const DENSE_TEARS: usize = 48;

/// Which tears each residual of a block depends on ([`tear_pattern`]), a
/// colouring of the tears in which no residual sees two of one colour, and
/// the Jacobian's sparse pattern.
#[derive(Clone, Debug)]
pub(super) struct Pattern {
    /// The tears of each colour.
    members: Vec<Vec<u32>>,
    /// For each colour, `(residual, slot)`: the residuals that see a tear
    /// of it, and where in the pattern that entry goes.
    by_colour: Vec<Vec<(u32, u32)>>,
    sparse: SparsePattern,
}

impl Pattern {
    /// `b`'s pattern; `None` when a residual depends on too many tears.
    fn of(b: &TapeBlock) -> Option<Pattern> {
        let rows = tear_pattern(b)?;
        let n = b.tears.len();
        let (colour, n_colours) = colour_columns(n, &rows);
        let positions = rows
            .iter()
            .enumerate()
            .flat_map(|(i, row)| row.iter().map(move |&j| (i, j as usize)))
            .collect();
        let sparse = SparsePattern::new(n, positions);
        let mut by_colour = vec![Vec::new(); n_colours as usize];
        for (i, row) in rows.iter().enumerate() {
            for &j in row {
                let slot = sparse
                    .slot(i, j as usize)
                    .expect("a position of the pattern");
                by_colour[colour[j as usize] as usize].push((i as u32, slot as u32));
            }
        }
        Some(Pattern {
            members: members(&colour, n_colours),
            by_colour,
            sparse,
        })
    }
}

/// Solve with a sparse factorization when there is one, else with the
/// dense factors of [`lu_factor`] in the block's work buffers.
pub(super) fn solve_factored(
    sparse: Option<&TripletLu>,
    jac: &[f64],
    perm: &[usize],
    b: &mut [f64],
    tmp: &mut [f64],
) {
    match sparse {
        Some(lu) => lu.solve_in_place(b, tmp),
        None => lu_solve(perm.len(), jac, perm, b, tmp),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tape of `n_regs` registers (initialized from `init`) holding
    /// `blocks` and nothing else.
    fn tape_of(init: Vec<f64>, blocks: Vec<TapeBlock>) -> Tape {
        Tape {
            n_regs: init.len(),
            state_regs: Vec::new(),
            states: Vec::new(),
            deriv_regs: Vec::new(),
            init,
            code: Vec::new(),
            blocks,
            tangent_inputs: Vec::new(),
            out_code: Vec::new(),
            out_inputs: Vec::new(),
            out_regs: Vec::new(),
            tail_code: Vec::new(),
            tail_regs: Vec::new(),
            memo_links: Vec::new(),
            sources: Vec::new(),
            diodes: Vec::new(),
            coverage: Coverage::default(),
            reg_var: Vec::new(),
            var_regs: Vec::new(),
            floor_reg: None,
            mode: std::cell::Cell::new(Mode::Transient),
            source_scale: std::cell::Cell::new(1.0),
            slope_end: std::cell::Cell::new(f64::INFINITY),
            slope_start: std::cell::Cell::new(f64::NEG_INFINITY),
            gmin_step: std::cell::Cell::new(0.0),
            source_params: Vec::new(),
            switch_regs: Vec::new(),
            modes: Vec::new(),
            source_memo: Vec::new(),
            work: std::cell::Cell::new(0),
            work_limit: std::cell::Cell::new(u64::MAX),
        }
    }

    /// A block with `tears`, `residuals` and `body`; what it touches is
    /// everything its body reads or writes.
    fn block(tears: Vec<u32>, residuals: Vec<u32>, body: Vec<Instr>) -> TapeBlock {
        let regs = |v: Vec<u32>| v.into_iter().map(Reg).collect();
        let mut touched: Vec<Reg> = body
            .iter()
            .flat_map(|i| i.operands().into_iter().chain([i.dest()]))
            .collect();
        touched.sort_unstable();
        touched.dedup();
        let mut b = TapeBlock::new(
            1,
            (regs(tears), regs(residuals)),
            body,
            false,
            vec!["R1".into(), "D1".into()],
        );
        b.touched = touched;
        b
    }

    /// x² into register 1 and x³ into register 2, of x in register 0.
    fn cube() -> Vec<Instr> {
        let mul = |d, a| Instr::Mul {
            d: Reg(d),
            a: Reg(a),
            b: Reg(0),
        };
        vec![mul(1, 0), mul(2, 1)]
    }

    /// `x³ + x - 10 = 0` on tear register 0 (root 2); registers 1-3 hold
    /// x², x³ + x and the residual, register 4 the constant 10.
    fn cubic() -> Tape {
        use Instr::*;
        let mut body = cube();
        body.extend([
            Add {
                d: Reg(2),
                a: Reg(2),
                b: Reg(0),
            },
            Sub {
                d: Reg(3),
                a: Reg(2),
                b: Reg(4),
            },
        ]);
        tape_of(
            vec![0.5, 0.0, 0.0, 0.0, 10.0],
            vec![block(vec![0], vec![3], body)],
        )
    }

    /// Block 0 of `tape` solved from the tape's initial registers.
    fn solved(tape: &Tape) -> Result<Vec<f64>, EvalError> {
        let mut r = tape.registers();
        tape.solve_block(0, &mut r, 1e-3).map(|()| r)
    }

    #[test]
    fn newton_on_one_tear_finds_the_root() {
        let r = solved(&cubic()).expect("converges");
        assert!((r[0] - 2.0).abs() < 1e-14, "x = {}", r[0]);
        // The body is left consistent with the tear.
        assert!(r[3].abs() < 1e-12, "residual {}", r[3]);
    }

    /// `x² + y² - 4 = 0`, `x - y = 0` on tears 0 and 1 (root x = y = √2).
    fn circle_and_line(x0: f64, y0: f64) -> Tape {
        use Instr::*;
        let body = vec![
            Mul {
                d: Reg(2),
                a: Reg(0),
                b: Reg(0),
            },
            Mul {
                d: Reg(3),
                a: Reg(1),
                b: Reg(1),
            },
            Add {
                d: Reg(4),
                a: Reg(2),
                b: Reg(3),
            },
            Sub {
                d: Reg(5),
                a: Reg(4),
                b: Reg(7),
            },
            Sub {
                d: Reg(6),
                a: Reg(0),
                b: Reg(1),
            },
        ];
        tape_of(
            vec![x0, y0, 0.0, 0.0, 0.0, 0.0, 0.0, 4.0],
            vec![block(vec![0, 1], vec![5, 6], body)],
        )
    }

    #[test]
    fn a_block_jacobian_in_one_pass_equals_its_columns_one_by_one() {
        let tape = circle_and_line(1.5, -0.25);
        let b = &tape.blocks[0];
        let mut r = tape.registers();
        let (mut dr, mut wide) = (vec![0.0; r.len()], Vec::new());
        let mut one_pass = vec![0.0; 4];
        tape.block_jacobian(b, &mut r, &mut dr, &mut wide, 0.0, &mut one_pass)
            .expect("evaluates");
        // Column by column, as past the wide buffer's limit.
        let mut by_column = vec![0.0; 4];
        for j in 0..2 {
            dr.iter_mut().for_each(|v| *v = 0.0);
            dr[b.tears[j]] = 1.0;
            tape.run_tangent(&b.body, &mut r, &mut dr, 0.0, None)
                .expect("evaluates");
            for (i, &res) in b.residuals.iter().enumerate() {
                by_column[i * 2 + j] = dr[res];
            }
        }
        // ∂(x² + y² - 4, x - y)/∂(x, y) at (1.5, -0.25).
        assert_eq!(one_pass, [3.0, -0.5, 1.0, -1.0]);
        assert_eq!(one_pass, by_column);
    }

    #[test]
    fn damped_newton_on_many_tears_converges_from_far_away() {
        for (x0, y0) in [(1.0, 0.5), (30.0, -20.0), (1e-3, 1e3)] {
            let r = solved(&circle_and_line(x0, y0)).expect("converges");
            let s = std::f64::consts::SQRT_2;
            assert!(
                (r[0] - s).abs() < 1e-14 && (r[1] - s).abs() < 1e-14,
                "from ({x0}, {y0}): ({}, {})",
                r[0],
                r[1]
            );
        }
    }

    #[test]
    fn an_affine_block_is_solved_by_one_correction_of_its_kept_factors() {
        use Instr::*;
        // 2x + y - 3 = 0, x - y = 0: x = y = 1.
        let body = vec![
            Mul {
                d: Reg(2),
                a: Reg(0),
                b: Reg(5),
            },
            Add {
                d: Reg(3),
                a: Reg(2),
                b: Reg(1),
            },
            Sub {
                d: Reg(3),
                a: Reg(3),
                b: Reg(6),
            },
            Sub {
                d: Reg(4),
                a: Reg(0),
                b: Reg(1),
            },
        ];
        let mut b = block(vec![0, 1], vec![3, 4], body);
        b.constant_jacobian = true;
        let tape = tape_of(vec![7.0, -2.0, 0.0, 0.0, 0.0, 2.0, 3.0], vec![b]);
        let mut r = tape.registers();
        tape.solve_block(0, &mut r, 0.0).expect("solves");
        assert!((r[0] - 1.0).abs() < 1e-15 && (r[1] - 1.0).abs() < 1e-15);
        assert!(tape.blocks[0].lu.get().is_some(), "the factors are kept");
        // Another right-hand side reuses them.
        r[6] = 6.0;
        tape.solve_block(0, &mut r, 0.0).expect("solves");
        assert!((r[0] - 2.0).abs() < 1e-15 && (r[1] - 2.0).abs() < 1e-15);
    }

    #[test]
    fn a_singular_block_names_its_elements_and_keeps_its_start() {
        use Instr::*;
        // x - y - 1 = 0 twice: no unique solution.
        let body = vec![
            Sub {
                d: Reg(2),
                a: Reg(0),
                b: Reg(1),
            },
            Sub {
                d: Reg(2),
                a: Reg(2),
                b: Reg(4),
            },
            Sub {
                d: Reg(3),
                a: Reg(0),
                b: Reg(1),
            },
            Sub {
                d: Reg(3),
                a: Reg(3),
                b: Reg(4),
            },
        ];
        let tape = tape_of(
            vec![0.25, 0.5, 0.0, 0.0, 1.0],
            vec![block(vec![0, 1], vec![2, 3], body)],
        );
        let mut r = tape.registers();
        let e = tape.solve_block(0, &mut r, 1e-3).expect_err("singular");
        assert_eq!(
            e,
            EvalError::Singular {
                block: 1,
                elements: vec!["R1".into(), "D1".into()],
                t: 1e-3
            }
        );
        assert_eq!(
            (r[0], r[1]),
            (0.25, 0.5),
            "the warm start is left for a retry"
        );
    }

    /// `max(x, 0)² − 1 = 0` on tear register 0 from `x0` (root 1): flat
    /// for x ≤ 0, as a loop's residual is where its MOSFET is cut off.
    fn cut_off(x0: f64) -> Tape {
        use Instr::*;
        let body = vec![
            Call {
                d: Reg(1),
                f: Func::Abs,
                a: Reg(0),
            },
            Add {
                d: Reg(2),
                a: Reg(0),
                b: Reg(1),
            },
            Mul {
                d: Reg(3),
                a: Reg(2),
                b: Reg(6),
            },
            Mul {
                d: Reg(4),
                a: Reg(3),
                b: Reg(3),
            },
            Sub {
                d: Reg(5),
                a: Reg(4),
                b: Reg(7),
            },
        ];
        tape_of(
            vec![x0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5, 1.0],
            vec![block(vec![0], vec![5], body)],
        )
    }

    #[test]
    fn one_tear_on_a_flat_residual_is_found_by_bracketing() {
        // From x = -3 the slope is 0: Newton has no step, and the search
        // outwards brackets the root.
        let r = solved(&cut_off(-3.0)).expect("converges");
        assert!((r[0] - 1.0).abs() < 1e-13, "x = {}", r[0]);
        assert!(r[5].abs() < 1e-12, "residual {}", r[5]);
        // From just above the kink Newton's first step overshoots by
        // hundreds, and the root is found either way.
        let r = solved(&cut_off(1e-3)).expect("converges");
        assert!((r[0] - 1.0).abs() < 1e-13, "x = {}", r[0]);
    }

    /// A current torn through 100 MΩ: `1e8·x + 1e25·x³ = 0.7` (a resistor and
    /// a cubic element in series across 0.7 V), its root 3.3 nA. Measured
    /// against a volt (`1 + |x|`), Newton stopped 2.6e-12 V off on the
    /// resistor; against a nanoampere it solves to rounding.
    fn series_current() -> Tape {
        use Instr::*;
        let mut body = cube();
        body.extend([
            Mul {
                d: Reg(3),
                a: Reg(2),
                b: Reg(7),
            },
            Mul {
                d: Reg(4),
                a: Reg(0),
                b: Reg(8),
            },
            Add {
                d: Reg(5),
                a: Reg(3),
                b: Reg(4),
            },
            Sub {
                d: Reg(6),
                a: Reg(5),
                b: Reg(9),
            },
        ]);
        let mut b = block(vec![0], vec![6], body);
        b.floor = tear_floor(crate::ir::VarKind::BranchCurrent);
        let mut init = vec![0.0; 10];
        init[7] = 1e25;
        init[8] = 1e8;
        init[9] = 0.7;
        tape_of(init, vec![b])
    }

    #[test]
    fn a_nanoampere_tear_is_solved_to_its_own_scale() {
        // The root by bisection on the same arithmetic.
        let f = |x: f64| 1e25 * (x * x * x) + 1e8 * x - 0.7;
        let (mut lo, mut hi) = (0.0f64, 1e-8f64);
        for _ in 0..200 {
            let m = 0.5 * (lo + hi);
            if f(m) < 0.0 { lo = m } else { hi = m }
        }
        let r = solved(&series_current()).expect("converges");
        let volts = 1e8 * (r[0] - lo).abs();
        assert!(
            volts < 1e-14,
            "x = {:e}, off by {volts:e} V on the resistor",
            r[0]
        );
    }

    /// A torn nanoampere `x` summed with an ampere (`(A + x) − A = c`: the
    /// sum resolves `x` only to A's last bit, 2.2e-16) and a slope of
    /// 3.8e11 from it into a second residual over `y`,
    /// `G·x + k·y² + a·y = B`, whose exact root is `y = 1`: the rounding of
    /// the first residual moves `y`'s correction by `G·2.2e-16/(a + 2k)`,
    /// about 2e-2, which no Newton step removes. Registers: tears 0 (`x`)
    /// and 1 (`y`), residuals 4 and 16; constants from 10.
    fn rounding_through_a_slope() -> Tape {
        use Instr::*;
        let (a, b, d) = (Reg, Reg, Reg);
        let body = vec![
            Add {
                d: d(2),
                a: a(10),
                b: b(0),
            },
            Sub {
                d: d(3),
                a: a(2),
                b: b(10),
            },
            Sub {
                d: d(4),
                a: a(3),
                b: b(11),
            },
            Mul {
                d: d(5),
                a: a(12),
                b: b(0),
            },
            Mul {
                d: d(6),
                a: a(1),
                b: b(1),
            },
            Mul {
                d: d(7),
                a: a(6),
                b: b(13),
            },
            Add {
                d: d(8),
                a: a(5),
                b: b(7),
            },
            Mul {
                d: d(9),
                a: a(1),
                b: b(14),
            },
            Add {
                d: d(15),
                a: a(8),
                b: b(9),
            },
            Sub {
                d: d(16),
                a: a(15),
                b: b(17),
            },
        ];
        let (big, c, g, k, slope) = (1.0, 1e-11, 3.8e11, 1e-3, 2.43e-3);
        let mut init = vec![0.0; 18];
        init[..2].copy_from_slice(&[0.0, 0.5]);
        init[10..15].copy_from_slice(&[big, c, g, k, slope]);
        init[17] = g * c + k + slope;
        tape_of(init, vec![block(vec![0, 1], vec![4, 16], body)])
    }

    #[test]
    fn a_correction_that_is_rounding_through_a_large_slope_ends_newton() {
        let r = solved(&rounding_through_a_slope()).expect("converges");
        assert!(r[4].abs() <= f64::EPSILON, "first residual {:e}", r[4]);
        assert!((r[1] - 1.0).abs() < 0.05, "y = {}", r[1]);
    }

    #[test]
    fn a_block_without_a_root_fails_to_converge() {
        use Instr::*;
        // x² + 1 = 0 has no real root: Newton wanders, damping stalls.
        let body = vec![
            Mul {
                d: Reg(1),
                a: Reg(0),
                b: Reg(0),
            },
            Add {
                d: Reg(2),
                a: Reg(1),
                b: Reg(3),
            },
        ];
        let tape = tape_of(
            vec![0.3, 0.0, 0.0, 1.0],
            vec![block(vec![0], vec![2], body)],
        );
        let mut r = tape.registers();
        match tape.solve_block(0, &mut r, 0.0) {
            Err(EvalError::NoConvergence { block: 1, .. } | EvalError::Singular { .. }) => {}
            other => panic!("{other:?}"),
        }
    }
}
