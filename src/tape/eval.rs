//! Running the tape: `f(t, y)`, the outputs, the sources and the register
//! file.

use super::*;

impl Tape {
    #[inline]
    pub(super) fn source(&self, s: u32, t: f64, order: u8) -> f64 {
        if order > 0 && self.mode.get() == Mode::Dc {
            0.0
        } else {
            let value = if order == 0 {
                let memo = &self.source_memo[s as usize];
                let (at, v) = memo.get();
                if at == t {
                    v
                } else {
                    let v = self.sources[s as usize].eval(t, 0);
                    memo.set((t, v));
                    v
                }
            } else {
                // At a corner the waveforms give the right-sided slope, the
                // one the integrator steps on with from there; the step that
                // ends there needs the one before it (a capacitor across a
                // PULSE source: its current jumps at the corner, and seen
                // from the left it would fail the step's error test at any
                // step size but one too short to reach the corner).
                // The run that starts at a corner needs the slope after it,
                // though the corner as a breakpoint (TD + k PER + TR + PW)
                // and as the waveform finds it (t - TD modulo PER) may
                // round an ulp apart (the slope before it made every first
                // step fail its error test).
                let (start, end) = (self.slope_start.get(), self.slope_end.get());
                let t = if t >= end {
                    end - 1e-12 * end.abs()
                } else if t <= start {
                    (start + 1e-12 * start.abs()).min(0.5 * (start + end))
                } else {
                    t
                };
                self.sources[s as usize].eval(t, order)
            };
            value * self.source_scale.get()
        }
    }

    /// d/dt of time: 0 at the operating point, as a source's derivative.
    pub(super) fn time_rate(&self) -> f64 {
        if self.mode.get() == Mode::Dc {
            0.0
        } else {
            1.0
        }
    }

    /// Fresh registers (parameters and constants set).
    pub fn registers(&self) -> Vec<f64> {
        self.init.clone()
    }

    /// Set the conductance the DC solve's GMIN stepping adds across every
    /// junction that has GMIN (diodes, a BJT's leakage junctions).
    pub fn set_gmin_step(&self, g: f64) {
        self.gmin_step.set(g);
    }

    /// `(f^(order)(x), f^(order+1)(x))` of a device function, with the
    /// stepped GMIN across junction currents.
    #[inline]
    pub(super) fn device(&self, f: crate::ir::DeviceFn, x: f64) -> (f64, f64) {
        let p = &self.diodes[f.diode as usize];
        let (v, slope) = p.eval_with_slope(f.part, f.order, x);
        let g = self.gmin_step.get();
        if g == 0.0 || p.gmin == 0.0 || f.part != crate::ir::DiodePart::Current {
            return (v, slope);
        }
        match f.order {
            0 => (v + g * x, slope + g),
            1 => (v + g, slope),
            _ => (v, slope),
        }
    }

    /// A comparison's value: as it falls, or the one its mode `m` holds
    /// (its operands' difference noted for the event search).
    #[inline]
    pub(super) fn compare(&self, op: crate::ir::Cmp, m: u32, a: f64, b: f64) -> f64 {
        if m == NO_MODE {
            return op.apply(a, b);
        }
        let mode = &self.modes[m as usize];
        mode.control.set(a - b);
        let held = mode.held.get();
        if held.is_nan() { op.apply(a, b) } else { held }
    }

    /// Set switch `k`'s conductance in `regs`.
    pub fn set_switch(&self, regs: &mut [f64], k: usize, g: f64) {
        if let Some(&r) = self.switch_regs.get(k)
            && r != NONE
        {
            regs[r] = g;
        }
    }

    /// Scale every independent source by `s`: the waveforms (through
    /// `source_scale`) and the DC values held in `regs`.
    /// Instructions run so far.
    pub fn work(&self) -> u64 {
        self.work.get()
    }

    /// Let blocks' Newton iterations give up (as not converged) once `limit`
    /// instructions have run in all; `u64::MAX` lifts it.
    pub fn limit_work(&self, limit: u64) {
        self.work_limit.set(limit);
    }

    #[inline]
    pub(super) fn count_work(&self, n: usize) {
        self.work.set(self.work.get().wrapping_add(n as u64));
    }

    /// Whether the work limit is passed (checked once per block iteration).
    #[inline]
    pub fn over_budget(&self) -> bool {
        self.work.get() > self.work_limit.get()
    }

    /// Put every block's tears back at their first guesses: a Newton that
    /// starts over from another point (the DC solve's last fallback) should
    /// not start its blocks where a failed one left them.
    pub fn reset_tears(&self, regs: &mut [f64]) {
        for b in &self.blocks {
            for &t in &b.tears {
                regs[t.idx()] = self.init[t.idx()];
            }
        }
    }

    /// Set the factor on capacitance floors in `regs`.
    pub fn set_floor_factor(&self, regs: &mut [f64], s: f64) {
        if let Some(r) = self.floor_reg {
            regs[r] = s;
        }
    }

    /// Where the integrator's current run stops: source derivatives at and
    /// past `t` are the left-sided ones at `t` (`f64::INFINITY`: none).
    pub fn set_slope_end(&self, t: f64) {
        self.slope_end.set(t);
    }

    /// Where the integrator's current run starts: source derivatives at and
    /// before `t` are the right-sided ones at `t` (`f64::NEG_INFINITY`: none).
    pub fn set_slope_start(&self, t: f64) {
        self.slope_start.set(t);
    }

    pub fn scale_sources(&self, regs: &mut [f64], s: f64) {
        self.source_scale.set(s);
        for &(r, v) in &self.source_params {
            regs[r] = v * s;
        }
    }

    pub(super) fn run(&self, code: &[Instr], r: &mut [f64], t: f64) -> Result<(), EvalError> {
        self.count_work(code.len());
        for ins in code {
            match *ins {
                Instr::Neg { d, a } => r[d] = -r[a],
                Instr::Add { d, a, b } => r[d] = r[a] + r[b],
                Instr::Sub { d, a, b } => r[d] = r[a] - r[b],
                Instr::Mul { d, a, b } => r[d] = r[a] * r[b],
                Instr::Div { d, a, b } => r[d] = r[a] / r[b],
                Instr::Pow { d, a, b } => r[d] = r[a].powf(r[b]),
                Instr::Call { d, f, a } => r[d] = f.apply(r[a]),
                Instr::Cmp { d, op, a, b, m } => r[d] = self.compare(op, m, r[a], r[b]),
                Instr::Select { d, c, a, b } => r[d] = crate::ir::select(r[c], r[a], r[b]),
                Instr::Device { d, f, a } => r[d] = self.device(f, r[a]).0,
                Instr::Src { d, s, order } => r[d] = self.source(s, t, order),
                Instr::Time { d } => r[d] = t,
                Instr::TimeRate { d } => r[d] = self.time_rate(),
                Instr::Block { k } => self.solve_block(k as usize, r, t)?,
            }
        }
        Ok(())
    }

    /// `f(t, y)`: load the states, run the program, read the derivatives.
    pub fn rhs(
        &self,
        regs: &mut [f64],
        t: f64,
        y: &[f64],
        dy: &mut [f64],
    ) -> Result<(), EvalError> {
        for (k, &s) in self.state_regs.iter().enumerate() {
            regs[s] = y[k];
        }
        self.run(&self.code, regs, t)?;
        for (k, &d) in self.deriv_regs.iter().enumerate() {
            dy[k] = regs[d];
        }
        Ok(())
    }

    /// The outputs at `(t, y)` (independent of [`Tape::rhs`]), as many as
    /// `out` holds.
    pub fn outputs(
        &self,
        regs: &mut [f64],
        t: f64,
        y: &[f64],
        out: &mut [f64],
    ) -> Result<(), EvalError> {
        for &(k, s) in &self.out_inputs {
            regs[s] = y[k];
        }
        for &(from, to) in &self.memo_links {
            let (from, to) = (from.idx(), to.idx());
            if regs[from].is_finite() {
                regs.copy_within(from..from + 4, to);
            }
        }
        self.run(&self.out_code, regs, t)?;
        // A shorter `out` takes the first outputs (the user's, without the
        // switches' controls after them).
        for (o, &r) in out.iter_mut().zip(&self.out_regs) {
            *o = regs[r];
        }
        Ok(())
    }

    /// The outputs at the point of the last [`Tape::rhs`] on `regs` (its
    /// time `t`), from what that evaluation left in them: the output-only
    /// steps alone are computed. Equal to [`Tape::outputs`] there up to the
    /// blocks' convergence.
    pub fn outputs_after_rhs(
        &self,
        regs: &mut [f64],
        t: f64,
        out: &mut [f64],
    ) -> Result<(), EvalError> {
        self.run(&self.tail_code, regs, t)?;
        for (o, &r) in out.iter_mut().zip(&self.tail_regs) {
            *o = regs[r];
        }
        Ok(())
    }

    /// The first register of `code` that became NaN or infinite from finite
    /// operands, and the variable it holds (if any).
    pub fn first_non_finite(&self, regs: &[f64]) -> Option<(usize, Option<VarId>)> {
        for ins in self
            .code
            .iter()
            .chain(self.blocks.iter().flat_map(|b| b.body.iter()))
        {
            let d = ins.dest();
            if d == NONE || regs[d].is_finite() {
                continue;
            }
            let inputs_finite = ins.operands().into_iter().all(|s| regs[s].is_finite());
            if inputs_finite {
                return Some((d.idx(), self.reg_var[d]));
            }
        }
        None
    }
}
