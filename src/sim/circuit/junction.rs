//! Junction charges in the circuit integrator: their voltages, predicted
//! through the junction law, and the kept Jacobian's junction columns and
//! diagonal moved to where the junctions are.

use super::*;

impl<M: Matrix<T = f64>> TrBdf2<'_, M>
where
    M::V: HostVec,
{
    /// The junction voltage whose charge is `q`, and `Q′` there, from the
    /// last point the evaluator's inversion evaluated (its registers): one
    /// Newton step, which is all a predictor needs. `None` before any.
    pub(super) fn junction_voltage(&self, ci: ChargeInverse, q: f64) -> Option<(f64, f64)> {
        let x = self.ode.register(ci.memo);
        let (qm, c) = (
            self.ode.register(ci.memo.offset(1)),
            self.ode.register(ci.memo.offset(2)),
        );
        let v = x + (q - qm) / c;
        (v.is_finite() && c > 0.0).then_some((v, c))
    }

    /// The junctions' voltages and slopes at the current point (after an
    /// evaluation near it); `shift` keeps the old ones as the previous.
    pub(super) fn read_junctions(&mut self, shift: bool) {
        for j in 0..self.junctions.len() {
            let Junction { k, ci, .. } = self.junctions[j];
            let got = self.junction_voltage(ci, self.y[k]);
            let jn = &mut self.junctions[j];
            jn.v_prev = if shift { jn.v } else { f64::NAN };
            (jn.v, jn.dv) = got.map_or((f64::NAN, f64::NAN), |(v, c)| (v, self.f[k] / c));
            if jn.v.is_finite() {
                jn.v_peak = jn.v_peak.max(jn.v.abs());
            }
        }
    }

    /// Each junction's `Q′` and `g_d` at `y`, where the Jacobian was just
    /// computed (the evaluator's registers are from there).
    pub(super) fn note_jacobian_point(&mut self, y: &[f64]) {
        for j in 0..self.junctions.len() {
            let Junction { k, ci, .. } = self.junctions[j];
            let (cap, gd) = match self.junction_voltage(ci, y[k]) {
                Some((v, _)) => {
                    let p = &self.ode.tape.diodes[ci.diode as usize];
                    (p.charge(v)[1], p.current(v)[1])
                }
                None => (f64::NAN, f64::NAN),
            };
            let jn = &mut self.junctions[j];
            (jn.cap_j, jn.gd_j) = (cap, gd);
        }
    }

    /// Move the kept Jacobian to the predicted junction states. `f` reads a
    /// junction's charge only through its voltage `v = Q⁻¹(q)`, so its
    /// column is `∂f/∂v / Q′(v)`; and its own row's `∂f/∂v` holds `-g_d(v)`
    /// (`q' = i - i_d(v)`), the rest of it the circuit's. Both follow the
    /// device from where the Jacobian was computed: a decaying junction's
    /// `Q′` falls by orders of magnitude over a few steps, and without this
    /// each stage of a rectifier's turn-off needs a Jacobian per iteration.
    /// A junction whose `Q′` and `g_d` moved by at most `skip` (relative)
    /// keeps its entries (and the factored matrix its factors).
    pub(super) fn follow_junctions(&mut self, skip: f64) {
        let n = self.n;
        for jn in &mut self.junctions {
            let (k, ratio) = (jn.k, jn.cap_j / jn.cap_p);
            if !(ratio.is_finite() && jn.gd_p.is_finite() && jn.gd_j.is_finite()) {
                continue;
            }
            if (ratio - 1.0).abs() <= skip && (jn.gd_p - jn.gd_j).abs() <= skip * jn.gd_j.abs() {
                continue;
            }
            let jac = &mut self.newton.jac;
            for i in 0..n {
                jac[i * n + k] *= ratio;
            }
            // The outputs read the charge through its voltage alone.
            for row in self.newton.out_jac.chunks_exact_mut(n) {
                row[k] *= ratio;
            }
            jac[k * n + k] += (jn.gd_j - jn.gd_p) / jn.cap_p;
            (jn.cap_j, jn.gd_j) = (jn.cap_p, jn.gd_p);
            self.newton.factored = false;
        }
    }

    /// Replace the predictor of each junction charge in `y1` by the charge
    /// at the voltage the quadratic `v(0) = v0`, `v'(0) = dv0`,
    /// `v(l) = vl` takes at `x` (at `t + x` from the current point).
    pub(super) fn predict_junctions(
        &mut self,
        l: f64,
        x: f64,
        at_l: impl Fn(usize, &Junction) -> f64,
    ) {
        for j in 0..self.junctions.len() {
            let jn = &self.junctions[j];
            let vl = at_l(j, jn);
            let (v0, dv0) = (jn.v, jn.dv);
            let c2 = (vl - v0 - l * dv0) / (l * l);
            let v = if c2.is_finite() {
                v0 + x * dv0 + x * x * c2
            } else {
                v0 + x * dv0
            };
            if !v.is_finite() {
                continue;
            }
            let p = &self.ode.tape.diodes[jn.ci.diode as usize];
            let [q, cap, _] = p.charge(v);
            let gd = p.current(v)[1];
            if q.is_finite() {
                let k = jn.k;
                self.stage.x[k] = q;
                let jn = &mut self.junctions[j];
                (jn.cap_p, jn.gd_p) = (cap, gd);
            }
        }
    }
}
