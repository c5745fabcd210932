//! Device functions with memory of their model: the ngspice level-1 diode's
//! current and charge as functions of the junction voltage, with their
//! derivatives up to second order (Jacobians, tangents, index reduction).

/// A diode model, with the area factor applied (ngspice's level 1 at 27 °C).
#[derive(Clone, Debug, PartialEq)]
pub struct DiodeParams {
    pub name: String,
    pub is: f64,
    /// `N * kT/q`.
    pub vte: f64,
    /// The breakdown voltage as ngspice matches it to IBV (`None`: no breakdown).
    pub bv: Option<f64>,
    pub gmin: f64,
    pub cjo: f64,
    pub vj: f64,
    pub m: f64,
    pub fc: f64,
    pub tt: f64,
    /// ngspice's `F1` and `F2` of the depletion charge above `fc·vj`, from
    /// [`DiodeParams::forward_constants`] (two `powf` per charge otherwise).
    pub fwd: [f64; 2],
}

/// Which function of the diode.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum DiodePart {
    /// Junction current `id(v)`.
    Current,
    /// Junction charge `q(v)` (depletion plus diffusion).
    Charge,
}

/// `f^(order)(v)` for a device function.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct DeviceFn {
    pub diode: u32,
    pub part: DiodePart,
    pub order: u8,
}

impl DiodeParams {
    /// `F1 = vj (1 - (1 - fc)^(1 - m)) / (1 - m)` and `F2 = (1 - fc)^(1 + m)`.
    pub fn forward_constants(vj: f64, m: f64, fc: f64) -> [f64; 2] {
        [
            vj * (1.0 - (1.0 - fc).powf(1.0 - m)) / (1.0 - m),
            (1.0 - fc).powf(1.0 + m),
        ]
    }

    /// ngspice's breakdown voltage matched to the current `ibv` at `bv`
    /// (diotemp.c), given IS and the thermal voltage.
    pub fn match_breakdown(bv: f64, ibv: f64, is: f64, vt: f64) -> f64 {
        if ibv < is * bv / vt {
            return bv;
        }
        let tol = 1e-9 * ibv;
        let mut xbv = bv - vt * (1.0 + ibv / is).ln();
        for _ in 0..25 {
            xbv = bv - vt * (ibv / is + 1.0 - xbv / vt).ln();
            let xcbv = is * (((bv - xbv) / vt).exp() - 1.0 + xbv / vt);
            if (xcbv - ibv).abs() <= tol {
                break;
            }
        }
        xbv
    }

    /// `[id, id', id'']` at `v` (ngspice dioload.c, with GMIN in parallel).
    pub fn current(&self, v: f64) -> [f64; 3] {
        let (is, vte, g) = (self.is, self.vte, self.gmin);
        // Far beyond any physical forward bias (the current is astronomical),
        // the exponential continues linearly so that a Newton excursion there
        // cannot overflow; nothing changes within the device's range.
        let vlin = 50.0 * vte;
        if v > vlin {
            let e = (vlin / vte).exp();
            return [
                is * (e * (1.0 + (v - vlin) / vte) - 1.0) + g * v,
                is * e / vte + g,
                0.0,
            ];
        }
        if v >= -3.0 * vte {
            let e = (v / vte).exp();
            [
                is * (e - 1.0) + g * v,
                is * e / vte + g,
                is * e / (vte * vte),
            ]
        } else if self.bv.is_none_or(|bv| v >= -bv) {
            // A smooth reverse region: -is (1 + (3 vte / (e v))^3).
            let a = 3.0 * vte / (v * std::f64::consts::E);
            let arg = a * a * a;
            [
                -is * (1.0 + arg) + g * v,
                3.0 * is * arg / v + g,
                -12.0 * is * arg / (v * v),
            ]
        } else {
            let bv = self.bv.unwrap_or(f64::INFINITY);
            let e = (-(bv + v) / vte).exp();
            [-is * e + g * v, is * e / vte + g, -is * e / (vte * vte)]
        }
    }

    /// `[q, q' = capacitance, q'']` at `v`.
    pub fn charge(&self, v: f64) -> [f64; 3] {
        let [id, gd, gd2] = self.current(v);
        let (cjo, vj, m, fc, tt) = (self.cjo, self.vj, self.m, self.fc, self.tt);
        let mut q = [tt * id, tt * gd, tt * gd2];
        if cjo == 0.0 {
            return q;
        }
        let vd_dep = fc * vj;
        if v < vd_dep {
            let arg = 1.0 - v / vj;
            let sarg = (-m * arg.ln()).exp();
            q[0] += vj * cjo * (1.0 - arg * sarg) / (1.0 - m);
            q[1] += cjo * sarg;
            q[2] += cjo * m / vj * sarg / arg;
        } else {
            let [f1, f2] = self.fwd;
            let f3 = 1.0 - fc * (1.0 + m);
            let czof2 = cjo / f2;
            q[0] +=
                cjo * f1 + czof2 * (f3 * (v - vd_dep) + m / (2.0 * vj) * (v * v - vd_dep * vd_dep));
            q[1] += czof2 * (f3 + m * v / vj);
            q[2] += czof2 * m / vj;
        }
        q
    }

    /// A bound on `|Q‴(v)| / (6 Q′(v))`: each part of the charge has its own
    /// ratio (`1/vte²` for the exponentials, at most `20/(3 vte)²` for the
    /// smooth reverse current, `m (m+1) / (vj - v)²` for the depletion charge
    /// below `fc·vj`, none above), and the sum's ratio is a weighted mean.
    pub fn third_derivative_bound(&self, v: f64) -> f64 {
        let exp = 2.5 / (self.vte * self.vte);
        let dep = if self.cjo != 0.0 && v < self.fc * self.vj {
            let d = self.vj - v;
            self.m * (self.m + 1.0) / (d * d)
        } else {
            0.0
        };
        exp.max(dep) / 6.0
    }

    /// `f^(order)(v)`; orders above 2 are not needed by any pass (NaN).
    pub fn eval(&self, part: DiodePart, order: u8, v: f64) -> f64 {
        self.eval_with_slope(part, order, v).0
    }

    /// `(f^(order)(v), f^(order+1)(v))` from one evaluation of the device.
    pub fn eval_with_slope(&self, part: DiodePart, order: u8, v: f64) -> (f64, f64) {
        let vals = match part {
            DiodePart::Current => self.current(v),
            DiodePart::Charge => self.charge(v),
        };
        let get = |k: usize| vals.get(k).copied().unwrap_or(f64::NAN);
        (get(order as usize), get(order as usize + 1))
    }

    /// Whether the charge is used at all (a junction with capacitance).
    pub fn has_charge(&self) -> bool {
        self.cjo != 0.0 || self.tt != 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn d() -> DiodeParams {
        DiodeParams {
            name: "d".into(),
            is: 1e-14,
            vte: 0.02586,
            bv: Some(DiodeParams::match_breakdown(10.0, 1e-3, 1e-14, 0.02586)),
            gmin: 1e-12,
            cjo: 2e-12,
            vj: 0.7,
            m: 0.4,
            fc: 0.5,
            tt: 1e-9,
            fwd: DiodeParams::forward_constants(0.7, 0.4, 0.5),
        }
    }

    #[test]
    fn derivatives_match_finite_differences() {
        let p = d();
        for v in [-12.0, -10.5, -5.0, -0.05, 0.0, 0.3, 0.34, 0.5, 0.7] {
            for part in [DiodePart::Current, DiodePart::Charge] {
                for order in 0..2u8 {
                    let h = 1e-7;
                    let fd = (p.eval(part, order, v + h) - p.eval(part, order, v - h)) / (2.0 * h);
                    let an = p.eval(part, order + 1, v);
                    assert!(
                        (fd - an).abs() <= 1e-4 * an.abs().max(1e-12),
                        "{part:?} order {order} at {v}: {fd} vs {an}"
                    );
                }
            }
        }
    }

    /// `third_derivative_bound` bounds `|Q‴| / (6 Q′)` (by differences of
    /// `Q″`) from deep reverse bias to strong forward bias.
    #[test]
    fn third_derivative_bound_holds() {
        let mut p = d();
        for (cjo, gmin) in [(2e-12, 1e-12), (0.0, 0.0)] {
            (p.cjo, p.gmin) = (cjo, gmin);
            let mut v: f64 = -9.0;
            while v < 0.9 {
                let h = 1e-6 * (1.0 + v.abs());
                let [_, c, _] = p.charge(v);
                let q3 = (p.charge(v + h)[2] - p.charge(v - h)[2]) / (2.0 * h);
                let ratio = (q3 / (6.0 * c)).abs();
                assert!(
                    ratio <= 1.05 * p.third_derivative_bound(v),
                    "cjo {cjo} v {v}: |Q'''/6Q'| = {ratio:e} > {:e}",
                    p.third_derivative_bound(v)
                );
                v += 0.0137;
            }
        }
    }

    #[test]
    fn breakdown_current_is_matched() {
        let p = d();
        let i = p.current(-10.0)[0];
        assert!((i + 1e-3).abs() < 1e-5, "{i}");
    }
}
