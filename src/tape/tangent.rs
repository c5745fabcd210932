//! Forward-mode tangents through the tape: `J v` and Jacobian columns,
//! with blocks differentiated by the implicit function theorem.
//!
//! The columns of one Jacobian share their blocks' solutions and factored
//! Jacobians (`TangentCache`); any other use of the registers (`f`, outputs,
//! another point) invalidates them. A dense Jacobian is one multi-direction
//! tangent pass (`Tape::jacobian_columns`: each instruction's value and slope
//! once for all columns); a charge inversion's tangent is `dx = dq/Q′(x)`,
//! without running its body.

use super::*;

/// Zero a register's few tangent slots in place. `fill` calls `memset` for
/// a length known only at run time, and per instruction that call costs
/// more than the stores (a tenth of an inverter chain's run).
#[inline]
pub(super) fn zero(s: &mut [f64]) {
    let mut chunks = s.chunks_exact_mut(4);
    for c in &mut chunks {
        c.copy_from_slice(&[0.0; 4]);
    }
    match chunks.into_remainder() {
        [] => {}
        [a] => *a = 0.0,
        [a, b] => (*a, *b) = (0.0, 0.0),
        [a, b, c] => (*a, *b, *c) = (0.0, 0.0, 0.0),
        _ => unreachable!("chunks of four leave at most three"),
    }
}

/// What the tangent runs of one point share: each block's factored
/// Jacobian, so that the columns of a Jacobian solve the blocks once.
#[derive(Debug, Default)]
pub struct TangentCache {
    /// The registers hold the last tangent run (set by [`Tape::jac_mul`]);
    /// whoever else writes them, or moves to another point, clears this.
    pub valid: bool,
    lus: Vec<Option<Factored>>,
}

impl TangentCache {
    /// Keep block `k`'s dense factors (copied into the slot's own buffers).
    fn keep(&mut self, k: usize, n_blocks: usize, jac: &[f64], perm: &[usize]) {
        let slot = self.slot(k, n_blocks);
        if !matches!(slot, Some(Factored::Dense(..))) {
            *slot = Some(Factored::Dense(DenseLu::default()));
        }
        if let Some(Factored::Dense(d)) = slot {
            d.lu.clear();
            d.lu.extend_from_slice(jac);
            d.perm.clear();
            d.perm.extend_from_slice(perm);
        }
    }

    fn slot(&mut self, k: usize, n_blocks: usize) -> &mut Option<Factored> {
        if self.lus.len() < n_blocks {
            self.lus.resize(n_blocks, None);
        }
        &mut self.lus[k]
    }
}

impl Tape {
    /// Tangents of `code` given tangents of its inputs in `dr` (registers not
    /// written by `code` keep their tangent).
    pub(super) fn run_tangent(
        &self,
        code: &[Instr],
        r: &mut [f64],
        dr: &mut [f64],
        t: f64,
        mut cache: Option<&mut TangentCache>,
    ) -> Result<(), EvalError> {
        self.count_work(code.len());
        for ins in code {
            match *ins {
                Instr::Neg { d, a } => {
                    r[d] = -r[a];
                    dr[d] = -dr[a];
                }
                Instr::Add { d, a, b } => {
                    r[d] = r[a] + r[b];
                    dr[d] = dr[a] + dr[b];
                }
                Instr::Sub { d, a, b } => {
                    r[d] = r[a] - r[b];
                    dr[d] = dr[a] - dr[b];
                }
                Instr::Mul { d, a, b } => {
                    let (x, y) = (r[a], r[b]);
                    r[d] = x * y;
                    dr[d] = dr[a] * y + x * dr[b];
                }
                Instr::Div { d, a, b } => {
                    let (x, y) = (r[a], r[b]);
                    let q = x / y;
                    r[d] = q;
                    dr[d] = (dr[a] - q * dr[b]) / y;
                }
                Instr::Pow { d, a, b } => {
                    let (x, y) = (r[a], r[b]);
                    let p = x.powf(y);
                    r[d] = p;
                    let (dx, dy) = (dr[a], dr[b]);
                    let mut dp = y * x.powf(y - 1.0) * dx;
                    if dy != 0.0 {
                        dp += p * x.ln() * dy;
                    }
                    dr[d] = dp;
                }
                Instr::Call { d, f, a } => {
                    let x = r[a];
                    let fx = f.apply(x);
                    r[d] = fx;
                    dr[d] = f.derivative(x, fx) * dr[a];
                }
                Instr::Cmp { d, op, a, b, m } => {
                    r[d] = self.compare(op, m, r[a], r[b]);
                    dr[d] = 0.0;
                }
                Instr::Select { d, c, a, b } => {
                    let pick = if r[c] != 0.0 { a } else { b };
                    r[d] = r[pick];
                    dr[d] = dr[pick];
                }
                Instr::Device { d, f, a } => {
                    let (v, slope) = self.device(f, r[a]);
                    r[d] = v;
                    dr[d] = slope * dr[a];
                }
                Instr::Src { d, s, order } => {
                    r[d] = self.source(s, t, order);
                    dr[d] = 0.0;
                }
                Instr::Time { d } => {
                    r[d] = t;
                    dr[d] = 0.0;
                }
                Instr::TimeRate { d } => {
                    r[d] = self.time_rate();
                    dr[d] = 0.0;
                }
                Instr::Block { k } => {
                    // Value first (Newton), then the tangent of the solution by
                    // the implicit function theorem: J dt = -(dR/dx) dx.
                    let k = k as usize;
                    let b = &self.blocks[k];
                    if let Some(ci) = b.charge_inverse {
                        // Q(x) = target: dx = d(target)/Q′(x), no body runs.
                        let (x, q, res, sign) = Self::charge_regs(b);
                        let kept = match cache.as_deref() {
                            Some(c) if c.valid => c.lus.get(k).and_then(|l| l.as_ref()),
                            _ => None,
                        };
                        let slope = match kept {
                            Some(Factored::Dense(d)) => sign * d.lu[0],
                            Some(Factored::Sparse(_)) => {
                                unreachable!("a charge block has one tear")
                            }
                            None => {
                                self.solve_block(k, r, t)?;
                                let [_, c, _] = self.diodes[ci.diode as usize].charge(r[x]);
                                if let Some(cache) = cache.as_deref_mut() {
                                    cache.keep(k, self.blocks.len(), &[sign * c], &[0]);
                                }
                                c
                            }
                        };
                        if !(slope.is_finite() && slope != 0.0) {
                            return Err(b.singular(t));
                        }
                        let dq = dr[ci.target];
                        dr[x] = dq / slope;
                        dr[q] = dq;
                        dr[res] = 0.0;
                        continue;
                    }
                    let n = b.tears.len();
                    let mut w = Work::take(n, r.len());
                    // Another column at the point of the last run: the block
                    // is solved and its Jacobian factored already.
                    let kept = match cache.as_deref() {
                        Some(c) if c.valid => c.lus.get(k).is_some_and(|l| l.is_some()),
                        _ => false,
                    };
                    let mut sparse = None;
                    // Whether the factors to solve with are in the cache.
                    let mut cached = kept;
                    if !kept {
                        self.solve_block(k, r, t)?;
                        if !b.constant_jacobian {
                            w.saved.extend(b.touched.iter().map(|&x| dr[x]));
                            let factored = self.factor_jacobian(b, r, dr, t, &mut w);
                            for (&x, &v) in b.touched.iter().zip(&w.saved) {
                                dr[x] = v;
                            }
                            sparse = factored?;
                        }
                        if let Some(c) = cache.as_deref_mut() {
                            cached = true;
                            // A constant Jacobian has its own factorization.
                            match sparse.take() {
                                Some(lu) => {
                                    *c.slot(k, self.blocks.len()) = Some(Factored::Sparse(lu));
                                }
                                None if b.constant_jacobian => {
                                    c.keep(k, self.blocks.len(), &[], &[])
                                }
                                None => c.keep(k, self.blocks.len(), &w.jac, &w.perm),
                            }
                        }
                    }
                    for &x in &b.tears {
                        dr[x] = 0.0;
                    }
                    self.run_tangent(&b.body, r, dr, t, None)?;
                    w.res.extend(b.residuals.iter().map(|&x| -dr[x]));
                    if b.constant_jacobian {
                        self.constant_lu(b, r, t, &mut w)?
                            .solve_in_place(&mut w.res, &mut w.tmp);
                    } else if cached
                        && let Some(lu) = cache.as_deref().and_then(|c| c.lus.get(k)?.as_ref())
                    {
                        lu.solve_in_place(&mut w.res, &mut w.tmp);
                    } else {
                        solve_factored(sparse.as_ref(), &w.jac, &w.perm, &mut w.res, &mut w.tmp);
                    }
                    for (j, &x) in b.tears.iter().enumerate() {
                        dr[x] = w.res[j];
                    }
                    w.give();
                    self.run_tangent(&b.body, r, dr, t, None)?;
                }
            }
        }
        Ok(())
    }

    /// Tangents of `code` in `m` directions at once: the tangent of register
    /// `x` in direction `j` is `dr[x * m + j]`. Each instruction's value and
    /// slope are computed once for all directions (a device's exponential
    /// once, not once per column).
    pub(super) fn run_tangents(
        &self,
        code: &[Instr],
        r: &mut [f64],
        dr: &mut [f64],
        m: usize,
        t: f64,
    ) -> Result<(), EvalError> {
        self.count_work(code.len() * m);
        // dr[d] = ka·dr[a] (+ kb·dr[b]) in every direction.
        #[inline(always)]
        fn lin(dr: &mut [f64], m: usize, d: Reg, a: (Reg, f64), b: Option<(Reg, f64)>) {
            let (d, a0, ka) = (d.idx() * m, a.0.idx() * m, a.1);
            match b {
                Some((b, kb)) => {
                    let b0 = b.idx() * m;
                    for j in 0..m {
                        dr[d + j] = ka * dr[a0 + j] + kb * dr[b0 + j];
                    }
                }
                None => {
                    for j in 0..m {
                        dr[d + j] = ka * dr[a0 + j];
                    }
                }
            }
        }
        for ins in code {
            match *ins {
                Instr::Neg { d, a } => {
                    r[d] = -r[a];
                    lin(dr, m, d, (a, -1.0), None);
                }
                Instr::Add { d, a, b } => {
                    r[d] = r[a] + r[b];
                    lin(dr, m, d, (a, 1.0), Some((b, 1.0)));
                }
                Instr::Sub { d, a, b } => {
                    r[d] = r[a] - r[b];
                    lin(dr, m, d, (a, 1.0), Some((b, -1.0)));
                }
                Instr::Mul { d, a, b } => {
                    let (x, y) = (r[a], r[b]);
                    r[d] = x * y;
                    lin(dr, m, d, (a, y), Some((b, x)));
                }
                Instr::Div { d, a, b } => {
                    let (x, y) = (r[a], r[b]);
                    let q = x / y;
                    r[d] = q;
                    lin(dr, m, d, (a, 1.0 / y), Some((b, -q / y)));
                }
                Instr::Pow { d, a, b } => {
                    let (x, y) = (r[a], r[b]);
                    let p = x.powf(y);
                    r[d] = p;
                    let ka = y * x.powf(y - 1.0);
                    let b0 = b.idx() * m;
                    if dr[b0..b0 + m].iter().all(|v| *v == 0.0) {
                        lin(dr, m, d, (a, ka), None);
                    } else {
                        lin(dr, m, d, (a, ka), Some((b, p * x.ln())));
                    }
                }
                Instr::Call { d, f, a } => {
                    let x = r[a];
                    let fx = f.apply(x);
                    r[d] = fx;
                    lin(dr, m, d, (a, f.derivative(x, fx)), None);
                }
                Instr::Cmp {
                    d,
                    op,
                    a,
                    b,
                    m: mode,
                } => {
                    r[d] = self.compare(op, mode, r[a], r[b]);
                    zero(&mut dr[d.idx() * m..(d.idx() + 1) * m]);
                }
                Instr::Select { d, c, a, b } => {
                    let pick = if r[c] != 0.0 { a } else { b };
                    r[d] = r[pick];
                    lin(dr, m, d, (pick, 1.0), None);
                }
                Instr::Device { d, f, a } => {
                    let (v, slope) = self.device(f, r[a]);
                    r[d] = v;
                    lin(dr, m, d, (a, slope), None);
                }
                Instr::Src { d, s, order } => {
                    r[d] = self.source(s, t, order);
                    zero(&mut dr[d.idx() * m..(d.idx() + 1) * m]);
                }
                Instr::Time { d } => {
                    r[d] = t;
                    zero(&mut dr[d.idx() * m..(d.idx() + 1) * m]);
                }
                Instr::TimeRate { d } => {
                    r[d] = self.time_rate();
                    zero(&mut dr[d.idx() * m..(d.idx() + 1) * m]);
                }
                Instr::Block { k } => {
                    // The value (Newton), the block's Jacobian factored once,
                    // then the implicit function theorem in each direction.
                    let b = &self.blocks[k as usize];
                    if let Some(ci) = b.charge_inverse {
                        self.solve_block(k as usize, r, t)?;
                        let (x, q, res, _) = Self::charge_regs(b);
                        let [_, c, _] = self.diodes[ci.diode as usize].charge(r[x]);
                        if !(c.is_finite() && c != 0.0) {
                            return Err(b.singular(t));
                        }
                        let target = ci.target.idx() * m;
                        for j in 0..m {
                            let dq = dr[target + j];
                            dr[x * m + j] = dq / c;
                            dr[q * m + j] = dq;
                            dr[res * m + j] = 0.0;
                        }
                        continue;
                    }
                    let n = b.tears.len();
                    let mut w = Work::take(n, r.len());
                    self.solve_block(k as usize, r, t)?;
                    let result = (|| {
                        let mut sparse = None;
                        let constant = if b.constant_jacobian {
                            Some(self.constant_lu(b, r, t, &mut w)?)
                        } else {
                            let mut scratch = std::mem::take(&mut w.dr);
                            let got = self.factor_jacobian(b, r, &mut scratch, t, &mut w);
                            w.dr = scratch;
                            sparse = got?;
                            None
                        };
                        for &x in &b.tears {
                            zero(&mut dr[x.idx() * m..(x.idx() + 1) * m]);
                        }
                        self.run_tangents(&b.body, r, dr, m, t)?;
                        // Direction by direction; a tear's slot in direction
                        // j is not read by the other directions' solves.
                        for j in 0..m {
                            for (i, &res) in b.residuals.iter().enumerate() {
                                w.step[i] = -dr[res.idx() * m + j];
                            }
                            match constant {
                                Some(lu) => lu.solve_in_place(&mut w.step, &mut w.tmp),
                                None => solve_factored(
                                    sparse.as_ref(),
                                    &w.jac,
                                    &w.perm,
                                    &mut w.step,
                                    &mut w.tmp,
                                ),
                            }
                            for (i, &x) in b.tears.iter().enumerate() {
                                dr[x.idx() * m + j] = w.step[i];
                            }
                        }
                        self.run_tangents(&b.body, r, dr, m, t)
                    })();
                    w.give();
                    result?;
                }
            }
        }
        Ok(())
    }

    /// `J(t, y) v`, by forward-mode tangents. `dregs` is scratch. With a
    /// valid `cache` (the registers hold the last run at this same point),
    /// blocks are not solved again and their factored Jacobians are reused.
    #[allow(clippy::too_many_arguments)]
    pub fn jac_mul(
        &self,
        regs: &mut [f64],
        dregs: &mut [f64],
        t: f64,
        y: &[f64],
        v: &[f64],
        jv: &mut [f64],
        cache: Option<&mut TangentCache>,
    ) -> Result<(), EvalError> {
        dregs.iter_mut().for_each(|x| *x = 0.0);
        for (k, &s) in self.state_regs.iter().enumerate() {
            regs[s] = y[k];
            dregs[s] = v[k];
        }
        let mut cache = cache;
        let r = self.run_tangent(&self.code, regs, dregs, t, cache.as_deref_mut());
        if let Some(c) = cache {
            c.valid = r.is_ok();
        }
        r?;
        for (k, &d) in self.deriv_regs.iter().enumerate() {
            jv[k] = dregs[d];
        }
        Ok(())
    }

    /// Columns `cols` of `∂f/∂y` at `(t, y)` in one pass (row-major into
    /// `jac`: `jac[i * cols.len() + j] = ∂f_i/∂y_cols[j]`), `f` into `dy`.
    /// `dregs` is scratch.
    #[allow(clippy::too_many_arguments)]
    pub fn jacobian_columns(
        &self,
        regs: &mut [f64],
        dregs: &mut Vec<f64>,
        t: f64,
        y: &[f64],
        cols: &[usize],
        jac: &mut [f64],
        dy: &mut [f64],
    ) -> Result<(), EvalError> {
        let mut colour = vec![u32::MAX; self.states.len()];
        for (j, &c) in cols.iter().enumerate() {
            colour[c] = j as u32;
        }
        self.jacobian_compressed(regs, dregs, t, y, &colour, 0..cols.len(), jac, dy)
    }

    /// `∂out/∂y` of the outputs after an evaluation (`tail_code`) in the
    /// `m` directions of the tangent pass [`Tape::jacobian_compressed`] just
    /// made on `regs` and `dregs` (row-major, `m` wide).
    pub fn output_jacobian(
        &self,
        regs: &mut [f64],
        dregs: &mut [f64],
        m: usize,
        t: f64,
        jac: &mut [f64],
    ) -> Result<(), EvalError> {
        self.run_tangents(&self.tail_code, regs, dregs, m, t)?;
        for (i, &d) in self.tail_regs.iter().enumerate() {
            jac[i * m..(i + 1) * m].copy_from_slice(&dregs[d.idx() * m..(d.idx() + 1) * m]);
        }
        Ok(())
    }

    /// The compressed `∂f/∂y` of the colours `colours` of a column colouring
    /// in one pass: direction `j` seeds every state `k` with `colour[k] ==
    /// colours.start + j` (`u32::MAX`: none), so `jac[i * m + j]` (`m` the
    /// colours' count) sums those columns' entries of row `i`, which is the
    /// one entry there when columns of a colour share no row. `f` into `dy`;
    /// `dregs` is scratch.
    #[allow(clippy::too_many_arguments)]
    pub fn jacobian_compressed(
        &self,
        regs: &mut [f64],
        dregs: &mut Vec<f64>,
        t: f64,
        y: &[f64],
        colour: &[u32],
        colours: std::ops::Range<usize>,
        jac: &mut [f64],
        dy: &mut [f64],
    ) -> Result<(), EvalError> {
        let m = colours.len();
        // Every register but the inputs has its tangent written before it
        // is read: clearing the whole buffer (registers × directions) cost
        // more than the pass on a circuit of 10^5 registers.
        if dregs.len() < self.n_regs * m {
            dregs.resize(self.n_regs * m, 0.0);
        }
        for &x in &self.tangent_inputs {
            zero(&mut dregs[x.idx() * m..(x.idx() + 1) * m]);
        }
        // The states the code reads are inputs, cleared above.
        for (k, &s) in self.state_regs.iter().enumerate() {
            regs[s] = y[k];
            if let Some(&c) = colour.get(k)
                && colours.contains(&(c as usize))
            {
                dregs[s.idx() * m + c as usize - colours.start] = 1.0;
            }
        }
        self.run_tangents(&self.code, regs, dregs, m, t)?;
        for (i, &d) in self.deriv_regs.iter().enumerate() {
            jac[i * m..(i + 1) * m].copy_from_slice(&dregs[d.idx() * m..(d.idx() + 1) * m]);
            dy[i] = regs[d];
        }
        Ok(())
    }
}
