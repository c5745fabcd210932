//! Device functions with memory of their model: the ngspice level-1 diode's
//! current and charge as functions of the junction voltage, with their
//! derivatives up to second order (Jacobians, tangents, index reduction).

/// Thermal voltage kT/q at ngspice's default 27 °C.
pub const VT_27C: f64 = 1.380_648_52e-23 * 300.15 / 1.602_176_620_8e-19;

/// kT/q at `celsius` (ngspice's constants).
pub fn thermal_voltage(celsius: f64) -> f64 {
    VT_27C * (celsius + 273.15) / 300.15
}

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
            // Deep in breakdown the exponential continues linearly too (a
            // DC Newton step to the full supply across a zener would
            // otherwise overflow to infinity).
            let x = -(bv + v);
            if x > vlin {
                let e = (vlin / vte).exp();
                return [
                    -is * e * (1.0 + (x - vlin) / vte) + g * v,
                    is * e / vte + g,
                    0.0,
                ];
            }
            let e = (x / vte).exp();
            [-is * e + g * v, is * e / vte + g, -is * e / (vte * vte)]
        }
    }

    /// `[q, q' = capacitance, q'']` at `v`.
    pub fn charge(&self, v: f64) -> [f64; 3] {
        let (cjo, vj, m, fc, tt) = (self.cjo, self.vj, self.m, self.fc, self.tt);
        // A depletion charge alone (a transistor's) needs no exponential.
        let mut q = if tt != 0.0 {
            let [id, gd, gd2] = self.current(v);
            [tt * id, tt * gd, tt * gd2]
        } else {
            [0.0; 3]
        };
        if cjo == 0.0 {
            return q;
        }
        let vd_dep = fc * vj;
        if v < vd_dep {
            let arg = 1.0 - v / vj;
            // arg^-m; the default grading (a step junction, m = 1/2) is a
            // square root, a fifth of the logarithm and exponential's cost.
            let sarg = if m == 0.5 {
                1.0 / arg.sqrt()
            } else {
                (-m * arg.ln()).exp()
            };
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

    /// A Newton iterate of the junction voltage from `old` to `new`, limited as
    /// ngspice limits it (dioload.c, DEVpnjlim): a forward step beyond the
    /// critical voltage, or a step deeper into breakdown, advances by the
    /// logarithm of what the exponential would have grown by.
    pub fn limit(&self, new: f64, old: f64) -> f64 {
        junction_limit(
            new,
            old,
            self.vte,
            self.vcrit(),
            self.bv.unwrap_or(f64::INFINITY),
        )
    }

    /// ngspice's critical voltage `vte ln(vte / (√2 IS))`: where limiting
    /// starts, and where its first Newton iterate puts a junction.
    pub fn vcrit(&self) -> f64 {
        self.vte * (self.vte / (std::f64::consts::SQRT_2 * self.is)).ln()
    }

    /// The junction voltage whose charge is `q` (the charge grows with the
    /// voltage), from `guess`; `None` when no voltage has that charge.
    pub fn voltage_at_charge(&self, q: f64, guess: f64) -> Option<f64> {
        let at = |v: f64| self.charge(v)[0] - q;
        // Bracket, then Newton kept inside the bracket (bisection otherwise).
        let (mut lo, mut hi) = (guess - 0.1, guess + 0.1);
        let mut width = 0.1;
        while at(lo) > 0.0 {
            width *= 2.0;
            lo -= width;
            if lo < -1e6 {
                return None;
            }
        }
        width = 0.1;
        while at(hi) < 0.0 {
            width *= 2.0;
            hi += width;
            if hi > 1e6 {
                return None;
            }
        }
        let mut v = guess.clamp(lo, hi);
        for _ in 0..200 {
            let [qv, c, _] = self.charge(v);
            let r = qv - q;
            if r == 0.0 {
                return Some(v);
            }
            if r > 0.0 {
                hi = v
            } else {
                lo = v
            }
            let next = v - r / c;
            let next = if c > 0.0 && next > lo && next < hi {
                next
            } else {
                0.5 * (lo + hi)
            };
            if (next - v).abs() <= 1e-15 * (1.0 + v.abs()) || hi - lo <= 1e-15 * (1.0 + v.abs()) {
                return Some(next);
            }
            v = next;
        }
        Some(v)
    }

    /// Whether the charge is used at all (a junction with capacitance).
    pub fn has_charge(&self) -> bool {
        self.cjo != 0.0 || self.tt != 0.0
    }
}

/// A diode junction's step limited as ngspice's diode limits it: forward by
/// [`pnjlim`], and past breakdown `bv` (below `-bv + 10 vte`; infinite:
/// none) the same on the mirrored voltage `-(v + bv)`, where the reverse
/// current grows as `exp(-(v + bv)/vte)`.
pub fn junction_limit(new: f64, old: f64, vte: f64, vcrit: f64, bv: f64) -> f64 {
    if bv.is_finite() && new < (10.0 * vte - bv).min(0.0) {
        -(pnjlim(-(new + bv), -(old + bv), vte, vcrit) + bv)
    } else {
        pnjlim(new, old, vte, vcrit)
    }
}

/// ngspice's junction voltage limiting (DEVpnjlim): a step to `new` from
/// `old` beyond the critical voltage `vcrit` that is longer than two
/// thermal voltages `vt` advances by the logarithm of what the exponential
/// would have grown by.
pub fn pnjlim(new: f64, old: f64, vt: f64, vcrit: f64) -> f64 {
    if new > vcrit && (new - old).abs() > 2.0 * vt {
        if old > 0.0 {
            let arg = 1.0 + (new - old) / vt;
            if arg > 0.0 {
                old + vt * arg.ln()
            } else {
                vcrit
            }
        } else {
            vt * (new / vt).ln()
        }
    } else {
        new
    }
}

/// A MOSFET's gate voltage step limited as ngspice limits it (DEVfetlim):
/// around the threshold `von` the step is bounded by regions (off: at most
/// to half a volt above threshold; within 3.5 V above it: at most to 4 V
/// above and half a volt below; far on: by twice the overdrive plus 2 V), so
/// that a channel far from its operating region turns on or off over a few
/// iterations instead of one step out of its square law's reach.
pub fn fet_limit(new: f64, old: f64, von: f64) -> f64 {
    let hi = (2.0 * (old - von)).abs() + 2.0;
    let lo = (old - von).abs() + 1.0;
    let on_far = von + 3.5;
    let delta = new - old;
    if old >= von {
        if old >= on_far {
            if delta <= 0.0 {
                if new >= on_far {
                    if -delta > lo { old - lo } else { new }
                } else {
                    new.max(von + 2.0)
                }
            } else if delta >= hi {
                old + hi
            } else {
                new
            }
        } else if delta <= 0.0 {
            new.max(von - 0.5)
        } else {
            new.min(von + 4.0)
        }
    } else if delta <= 0.0 {
        if -delta > hi { old - hi } else { new }
    } else if new <= von + 0.5 {
        if delta > lo { old + lo } else { new }
    } else {
        von + 0.5
    }
}

/// A MOSFET's drain–source step limited as ngspice limits it (DEVlimvds):
/// from above 3.5 V up to three times the old value plus 2 V and down to
/// 2 V at most; from below, up to 4 V and down to −0.5 V at most.
pub fn vds_limit(new: f64, old: f64) -> f64 {
    if old >= 3.5 {
        if new > old {
            new.min(3.0 * old + 2.0)
        } else if new < 3.5 {
            new.max(2.0)
        } else {
            new
        }
    } else if new > old {
        new.min(4.0)
    } else {
        new.max(-0.5)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fet_limit_bounds_each_region_as_ngspice() {
        let von = 1.0;
        // Off: up to half a volt above threshold, down by at most
        // 2|old − von| + 2.
        assert_eq!(fet_limit(5.0, 0.0, von), 1.5);
        assert_eq!(fet_limit(1.2, 0.0, von), 1.2);
        assert_eq!(fet_limit(-20.0, 0.0, von), -4.0);
        // A rise that stays within half a volt above threshold is taken.
        assert_eq!(fet_limit(1.4, -5.0, von), 1.4);
        assert_eq!(fet_limit(1.4, -0.5, von), 1.4);
        // Within 3.5 V above threshold: up to 4 V above, down to 0.5 V below.
        assert_eq!(fet_limit(10.0, 2.0, von), 5.0);
        assert_eq!(fet_limit(-3.0, 2.0, von), 0.5);
        assert_eq!(fet_limit(3.0, 2.0, von), 3.0);
        // Far on: rises by at most 2|old − von| + 2; a fall out of the far
        // region stops 2 V above threshold.
        assert_eq!(fet_limit(30.0, 6.0, von), 18.0);
        assert_eq!(fet_limit(0.0, 6.0, von), 3.0);
        assert_eq!(fet_limit(5.0, 9.0, von), 5.0);
        assert_eq!(fet_limit(4.5, 12.0, von), 4.5);
        assert_eq!(fet_limit(4.6, 16.0, von), 4.6);
        assert_eq!(fet_limit(4.4, 6.0, von), 4.4);
    }

    #[test]
    fn vds_limit_bounds_each_region_as_ngspice() {
        assert_eq!(vds_limit(10.0, 1.0), 4.0);
        assert_eq!(vds_limit(-3.0, 1.0), -0.5);
        assert_eq!(vds_limit(50.0, 5.0), 17.0);
        assert_eq!(vds_limit(0.0, 5.0), 2.0);
        assert_eq!(vds_limit(4.0, 5.0), 4.0);
        assert_eq!(vds_limit(2.5, 1.0), 2.5);
    }

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
        for v in [-10.4, -10.0, -5.0, -0.05, 0.0, 0.3, 0.34, 0.5, 0.7] {
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

    /// Far beyond the breakdown voltage (a DC Newton step to a whole supply
    /// across a zener) the current stays finite, continuous and monotone.
    #[test]
    fn deep_breakdown_is_finite_and_continuous() {
        let p = d();
        let bv = p.bv.expect("breakdown");
        let edge = -bv - 50.0 * p.vte;
        let (below, above) = (p.current(edge - 1e-9), p.current(edge + 1e-9));
        assert!((below[0] - above[0]).abs() <= 1e-6 * above[0].abs());
        assert!((below[1] - above[1]).abs() <= 1e-6 * above[1]);
        let mut last = p.current(edge)[0];
        for k in 1..100 {
            let i = p.current(edge - 10.0 * k as f64)[0];
            assert!(
                i.is_finite() && i < last,
                "at {} V: {i}",
                edge - 10.0 * k as f64
            );
            last = i;
        }
    }

    /// Charges invert to their voltages, from far guesses too.
    #[test]
    fn charges_invert_to_their_voltages() {
        let p = d();
        for v in [-9.0, -2.0, -0.1, 0.0, 0.2, 0.5, 0.65, 0.8] {
            let q = p.charge(v)[0];
            for guess in [0.0, -5.0, 0.7, v] {
                let got = p.voltage_at_charge(q, guess).expect("a voltage");
                assert!((got - v).abs() <= 1e-9, "Q⁻¹(Q({v})) from {guess} = {got}");
            }
        }
    }

    /// Junction limiting: a forward step beyond the critical voltage grows
    /// logarithmically, and so does a step deeper into breakdown; steps
    /// elsewhere pass unchanged.
    #[test]
    fn junction_steps_are_limited() {
        let p = d();
        let bv = p.bv.expect("breakdown");
        let fwd = p.limit(5.0, 0.6);
        assert!(fwd > 0.6 && fwd < 0.8, "{fwd}");
        let deep = p.limit(-bv - 5.0, -bv);
        assert!(deep < -bv && deep > -bv - 0.3, "{deep}");
        assert_eq!(p.limit(0.3, 0.2), 0.3);
        assert_eq!(p.limit(-3.0, -1.0), -3.0);
    }

    #[test]
    fn breakdown_current_is_matched() {
        let p = d();
        let i = p.current(-10.0)[0];
        assert!((i + 1e-3).abs() < 1e-5, "{i}");
    }
}
