//! Temperature: ngspice's scaling of junction and MOSFET parameters from
//! the model's TNOM to the circuit's TEMP, on the band gap
//! `Eg(T) = 1.16 − 7.02e-4·T²/(T + 1108)` eV.

/// 0 °C in kelvin.
pub(crate) const CELSIUS_K: f64 = 273.15;
/// ngspice's REFTEMP (27 °C), where its band-gap and junction-potential
/// temperature formulas are anchored.
const REFTEMP: f64 = 300.15;
/// The elementary charge and Boltzmann's constant as ngspice has them.
pub(crate) const CHARGE: f64 = 1.602_176_620_8e-19;
pub(crate) const BOLTZMANN: f64 = 1.380_648_52e-23;

/// ngspice's temperature model of junctions (`mos1temp.c`, `diotemp.c`):
/// the band gap at TNOM and at TEMP (kelvin), and the junction-potential
/// shifts built on it.
pub(crate) struct Thermal {
    pub(crate) temp: f64,
    pub(crate) tnom: f64,
    pub(crate) vt: f64,
    pub(crate) vtnom: f64,
    pub(crate) egfet: f64,
    pub(crate) egfet1: f64,
    /// `-2 vt (1.5 ln(T/REFTEMP) + q·arg)` at TEMP and at TNOM.
    pbfact: f64,
    pbfact1: f64,
}

impl Thermal {
    pub(crate) fn new(tnom: f64, temp: f64) -> Thermal {
        let gap = |t: f64| 1.16 - 7.02e-4 * t * t / (t + 1108.0);
        let vt = |t: f64| BOLTZMANN * t / CHARGE;
        let pbfact = |t: f64| {
            let arg = -gap(t) / (2.0 * BOLTZMANN * t) + 1.1150877 / (BOLTZMANN * 2.0 * REFTEMP);
            -2.0 * vt(t) * (1.5 * (t / REFTEMP).ln() + CHARGE * arg)
        };
        Thermal {
            temp,
            tnom,
            vt: vt(temp),
            vtnom: vt(tnom),
            egfet: gap(temp),
            egfet1: gap(tnom),
            pbfact: pbfact(temp),
            pbfact1: pbfact(tnom),
        }
    }

    /// A potential given at TNOM (φ, PB) at TEMP.
    pub(crate) fn potential(&self, p: f64) -> f64 {
        // Exactly `p` at TNOM (the formula's round trip moves the last bit),
        // so that every other factor here is exactly 1 there.
        if self.temp == self.tnom {
            return p;
        }
        let at_ref = (p - self.pbfact1) / (self.tnom / REFTEMP);
        self.temp / REFTEMP * at_ref + self.pbfact
    }

    /// The factor on a MOSFET's mobility (KP, UO): `(T/TNOM)^-1.5`.
    pub(crate) fn mobility(&self) -> f64 {
        let ratio = self.temp / self.tnom;
        1.0 / (ratio * ratio.sqrt())
    }

    /// The factor on a junction's saturation current.
    pub(crate) fn saturation(&self) -> f64 {
        (-self.egfet / self.vt + self.egfet1 / self.vtnom).exp()
    }

    /// The factor on a zero-bias junction capacitance of grading `m`
    /// whose potential at TNOM is `pb`.
    pub(crate) fn capacitance(&self, m: f64, pb: f64) -> f64 {
        let pbo = (pb - self.pbfact1) / (self.tnom / REFTEMP);
        let old = (pb - pbo) / pbo;
        let new = (self.potential(pb) - pbo) / pbo;
        (1.0 + m * (4e-4 * (self.temp - REFTEMP) - new))
            / (1.0 + m * (4e-4 * (self.tnom - REFTEMP) - old))
    }

    /// A diode's saturation current at TEMP (`diotemp.c`, TLEV 0): the
    /// activation energy EG over the emission voltage, and `T^(XTI/N)`.
    pub(crate) fn diode_saturation(&self, is: f64, n: f64, eg: f64, xti: f64) -> f64 {
        let ratio = self.temp / self.tnom;
        is * ((ratio - 1.0) * eg / (n * self.vt) + xti / n * ratio.ln()).exp()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn at_the_nominal_temperature_nothing_moves() {
        for tnom in [300.15, 250.0, 400.0] {
            let th = Thermal::new(tnom, tnom);
            for p in [0.6, 0.8, 1.1] {
                assert_eq!(th.potential(p), p, "potential at {tnom} K");
                assert_eq!(th.capacitance(0.5, p), 1.0);
            }
            assert_eq!(th.saturation(), 1.0);
            assert_eq!(th.diode_saturation(1e-14, 1.8, 1.11, 3.0), 1e-14);
        }
    }

    #[test]
    fn a_hot_junction_leaks_more_at_a_lower_potential() {
        // 27 °C → 125 °C: ngspice's band gap shrinks from 1.1151 to 1.0861
        // eV, and the saturation current grows about 10^4-fold.
        let th = Thermal::new(300.15, 398.15);
        assert!(
            (1.0e4..1.0e5).contains(&th.saturation()),
            "{}",
            th.saturation()
        );
        assert!(th.potential(0.8) < 0.8 && th.potential(0.8) > 0.5);
        assert!(th.capacitance(0.5, 0.8) > 1.0);
    }
}
