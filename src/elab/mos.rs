//! M: ngspice's MOSFET levels 1 (Shichman–Hodges), 2 (Grove–Frohman,
//! `mos/level2.rs`), 3 (the semi-empirical short-channel model) and 6
//! (Sakurai–Newton's n-th power law), with
//! Meyer's gate capacitances and the bulk junctions, at the circuit's
//! temperature (`Thermal`: ngspice's `mos1temp.c`), elaborated into branches
//! named by the device as a BJT is (`bjt.rs`):
//!
//! ```text
//!  D ─rd─ D' ─┬─ ds: id(vgs, vds, vbs) ──┬─ S' ─rs─ S
//!             ├─ bd: ibd + d(qbd)/dt ─ B ─┤
//!             │            bs: ibs + d(qbs)/dt
//!  G ─ gd: Cgd(v)·d(vgd)/dt, gs: Cgs(v)·d(vgs)/dt, gb: Cgb(v)·d(vgb)/dt
//! ```
//!
//! The bulk junctions (bottom and sidewall) are the diode's device
//! functions. The drain current and Meyer's capacitances are expressions of
//! the gate, drain and bulk voltages seen from whichever of D' and S' is the
//! source (ngspice's `mode`): the listing shows them and code generation
//! emits them; the tape differentiates them exactly. Meyer's model gives
//! capacitances, not charges, so each gate branch is a capacitor whose
//! capacitance depends on the device's voltages: `i = C(v)·du/dt`, its
//! voltage the state, as ngspice integrates `C·Δv` each step. A P-channel
//! device's branches point the other way, so that every branch voltage is
//! ngspice's `type · v`.

mod level2;

use super::bjt::{Ex, NextIds, oriented};
use super::thermal::{BOLTZMANN, CELSIUS_K, CHARGE, Thermal};
use super::{Arith, BNode, Elab, ElabError, ElemId, Element, ElementKind, NodeId, Scope};
use crate::front::ast::{self, ElementLetter};
use crate::ir::{Cmp, DiodeParams, DiodePart, Func};

/// ngspice's GMIN, in parallel with each bulk junction.
const GMIN: f64 = 1e-12;
/// ngspice's default channel length and width (`.options defl defw`).
const DEFAULT_LW: f64 = 1e-4;
/// The permittivities ngspice's MOS models use: SiO2's and silicon's.
const EPS_OX: f64 = 3.9 * 8.854_214_871e-12;
const EPS_SI: f64 = 11.7 * 8.854_214_871e-12;
/// The floor of a Meyer capacitance that can vanish (a gate–drain
/// capacitance in saturation without overlap), as a fraction of the gate
/// oxide's: the branch's voltage is a state, which a zero capacitance would
/// leave undetermined. It adds a fast mode that a stiff integrator damps,
/// and a current of the floor times the branch's slew where ngspice has
/// none: at 1e-6 of the oxide's, a power MOSFET's gate–bulk current (Xyce's
/// `power_nmos2`, whose whole range is a nanoampere) was 0.30 of its range
/// off ngspice; at 1e-9, 3.0e-4.
pub(crate) const MEYER_FLOOR: f64 = 1e-9;

/// The model card's values; `None` where ngspice's "given" flag matters.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct MosModel {
    name: String,
    pchannel: bool,
    level: u8,
    vto: Option<f64>,
    kp: Option<f64>,
    gamma: Option<f64>,
    phi: Option<f64>,
    lambda: f64,
    rd: Option<f64>,
    rs: Option<f64>,
    rsh: Option<f64>,
    cbd: Option<f64>,
    cbs: Option<f64>,
    is: f64,
    js: f64,
    pb: f64,
    cgso: f64,
    cgdo: f64,
    cgbo: f64,
    cj: Option<f64>,
    mj: f64,
    cjsw: Option<f64>,
    mjsw: f64,
    tox: Option<f64>,
    nsub: Option<f64>,
    nss: f64,
    nfs: f64,
    tpg: f64,
    ld: f64,
    u0: Option<f64>,
    fc: f64,
    // Levels 2 and 3.
    xj: f64,
    vmax: f64,
    delta: f64,
    theta: f64,
    eta: f64,
    kappa: f64,
    wd: f64,
    xl: f64,
    xw: f64,
    delvto: f64,
    /// The temperature the parameters were measured at, °C (TNOM).
    tnom: Option<f64>,
    // Level 2.
    ucrit: f64,
    uexp: f64,
    neff: f64,
    // Level 6 (Sakurai–Newton): vdsat = KV·vgon^NV, idsat = KC·W/L·vgon^NC,
    // the threshold's GAMMA1 and SIGMA terms, λ = LAMBDA0 − LAMBDA1·vbs.
    kv: f64,
    nv: f64,
    kc: Option<f64>,
    nc: f64,
    gamma1: f64,
    sigma: f64,
    lambda0: Option<f64>,
    lambda1: f64,
}

impl MosModel {
    fn new(name: String, pchannel: bool) -> MosModel {
        MosModel {
            name,
            pchannel,
            level: 1,
            vto: None,
            kp: None,
            gamma: None,
            phi: None,
            lambda: 0.0,
            rd: None,
            rs: None,
            rsh: None,
            cbd: None,
            cbs: None,
            is: 1e-14,
            js: 0.0,
            pb: 0.8,
            cgso: 0.0,
            cgdo: 0.0,
            cgbo: 0.0,
            cj: None,
            mj: 0.5,
            cjsw: None,
            mjsw: 0.5,
            tox: None,
            nsub: None,
            nss: 0.0,
            nfs: 0.0,
            tpg: 1.0,
            ld: 0.0,
            u0: None,
            fc: 0.5,
            xj: 0.0,
            vmax: 0.0,
            delta: 0.0,
            theta: 0.0,
            eta: 0.0,
            kappa: 0.2,
            wd: 0.0,
            xl: 0.0,
            xw: 0.0,
            delvto: 0.0,
            tnom: None,
            ucrit: 1e4,
            uexp: 0.0,
            neff: 1.0,
            kv: 2.0,
            nv: 0.5,
            kc: None,
            nc: 1.0,
            gamma1: 0.0,
            sigma: 0.0,
            lambda0: None,
            lambda1: 0.0,
        }
    }
}

/// What ngspice derives from a model card (its `mos*temp.c`), at the
/// circuit's temperature: in the device's own polarity, so that
/// `vbi + γ·√(φ − vbs)` is the threshold.
#[derive(Clone, Debug)]
struct Derived {
    /// Gate oxide capacitance per area (0 without TOX at level 1).
    cox: f64,
    kp: f64,
    gamma: f64,
    phi: f64,
    /// `type·VTO − γ√φ` at TNOM, moved with the band gap and φ.
    vbi: f64,
    /// The thermal voltage at the circuit's temperature.
    vt: f64,
    /// The bulk junctions: their potential, the factor on IS and JS, and
    /// those on the bottom (MJ) and sidewall (MJSW) capacitances.
    pb: f64,
    sat: f64,
    cap_bottom: f64,
    cap_side: f64,
    /// Levels 2 and 3: surface mobility (cm²/V·s), the depletion-width
    /// coefficient (0 without NSUB); level 3: the narrow-width factor, the
    /// DIBL factor's scale.
    u0: f64,
    /// NSUB given (level 2 derives the channel-length modulation from it).
    nsub: bool,
    xd: f64,
    narrow: f64,
    alpha: f64,
}

/// Level-1 MOS parameters kausal models, with their aliases.
const MOS1_PARAMS: &[&str] = &[
    "level", "vto", "vt0", "kp", "gamma", "phi", "lambda", "rd", "rs", "rsh", "cbd", "cbs", "is",
    "js", "pb", "cgso", "cgdo", "cgbo", "cj", "mj", "cjsw", "mjsw", "tox", "nsub", "nss", "tpg",
    "ld", "uo", "u0", "fc", "tnom", "nmos", "pmos",
];
/// Level 2's: level 1's and the Grove–Frohman ones.
const MOS2_PARAMS: &[&str] = &[
    "level", "vto", "vt0", "kp", "gamma", "phi", "lambda", "rd", "rs", "rsh", "cbd", "cbs", "is",
    "js", "pb", "cgso", "cgdo", "cgbo", "cj", "mj", "cjsw", "mjsw", "tox", "nsub", "nss", "nfs",
    "tpg", "ld", "uo", "u0", "fc", "xj", "vmax", "delta", "ucrit", "uexp", "neff", "tnom", "nmos",
    "pmos",
];
/// Level 3's: level 1's (but λ) and the short-channel ones.
const MOS3_PARAMS: &[&str] = &[
    "level", "vto", "vt0", "kp", "gamma", "phi", "rd", "rs", "rsh", "cbd", "cbs", "is", "js", "pb",
    "cgso", "cgdo", "cgbo", "cj", "mj", "cjsw", "mjsw", "tox", "nsub", "nss", "nfs", "tpg", "ld",
    "uo", "u0", "fc", "xj", "vmax", "delta", "theta", "eta", "kappa", "wd", "xl", "xw", "delvto",
    "delvt0", "tnom", "nmos", "pmos",
];
/// Level 6's: level 1's (KC in place of KP) and Sakurai and Newton's. NVTH
/// and PS are read by ngspice's `mos6` but used by none of its equations.
const MOS6_PARAMS: &[&str] = &[
    "level", "vto", "vt0", "kv", "nv", "kc", "nc", "nvth", "ps", "gamma", "gamma1", "sigma", "phi",
    "lambda", "lambda0", "lambda1", "rd", "rs", "rsh", "cbd", "cbs", "is", "js", "pb", "cgso",
    "cgdo", "cgbo", "cj", "mj", "cjsw", "mjsw", "tox", "nsub", "nss", "tpg", "ld", "uo", "u0",
    "fc", "tnom", "nmos", "pmos",
];
/// Parameters that do not change the transient result (noise, and
/// ngspice's flags).
const MOS_IGNORED: &[&str] = &["kf", "af", "nlev", "gdsnoi", "version"];
/// Level 2's: also SPICE2's UTRA (a transverse-field mobility coefficient),
/// which ngspice's level 2 does not read either (it warns and ignores it).
const MOS2_IGNORED: &[&str] = &["kf", "af", "nlev", "gdsnoi", "version", "utra"];

/// The families ngspice's other MOS levels belong to, for the refusal.
fn level_family(level: f64) -> &'static str {
    match level as i64 {
        4 => "BSIM1",
        5 => "BSIM2",
        6 => "Sakurai–Newton (level 6)",
        8 | 49 => "BSIM3",
        9 => "BSIM3 SOI",
        10 | 58 => "BSIM SOI",
        14 | 54 => "BSIM4",
        44 => "EKV",
        _ => "a MOS model kausal does not have",
    }
}

impl Elab {
    /// The MOS model `model` (an NMOS or PMOS card of level 1, 2, 3 or 6).
    fn mos_model(
        &mut self,
        model: &ast::Name<'_>,
        element: &str,
        scope: &Scope<'_, '_>,
    ) -> Option<MosModel> {
        let (def, kind) =
            self.typed_model(model, element, scope, &["nmos", "pmos"], "NMOS or PMOS")?;
        let pchannel = kind == 1;
        let cache_key = (def.span.file.0, def.span.start, scope.prefix.clone());
        if let Some(m) = self.mos_cache.get(&cache_key) {
            return m.clone();
        }
        let first_use = !self
            .mos_cache
            .keys()
            .any(|k| k.0 == cache_key.0 && k.1 == cache_key.1);
        let mut m = MosModel::new(def.name.key(), pchannel);
        let mut ok = true;
        // The level first: it decides what the other parameters mean.
        for p in def.params.iter().filter(|p| p.name.is("level")) {
            let Some(v) = self.value(&p.value, scope) else {
                ok = false;
                continue;
            };
            if v == 1.0 || v == 2.0 || v == 3.0 || v == 6.0 {
                m.level = v as u8;
            } else {
                self.errors.push(ElabError::UnsupportedModel {
                    span: p.value.span(),
                    model: def.name.text.to_string(),
                    what: format!("a level-{v} MOSFET ({})", level_family(v)),
                    help: "kausal models ngspice's MOS levels 1, 2, 3 and 6; BSIM and the other compact models would come as compiled (OSDI) devices, see ARCHITECTURE.md",
                });
                ok = false;
            }
        }
        if !ok {
            self.mos_cache.insert(cache_key, None);
            return None;
        }
        if m.level == 2 || m.level == 3 {
            m.tox = Some(1e-7);
            m.mjsw = 0.33;
        }
        for p in &def.params {
            let key = p.name.key();
            if key == "level" {
                continue;
            }
            let (known, ignored) = match m.level {
                6 => (MOS6_PARAMS, MOS_IGNORED),
                3 => (MOS3_PARAMS, MOS_IGNORED),
                2 => (MOS2_PARAMS, MOS2_IGNORED),
                _ => (MOS1_PARAMS, MOS_IGNORED),
            };
            if self.unread_model_param(p, &key, known, ignored, def, first_use) {
                continue;
            }
            let Some(v) = self.value(&p.value, scope) else {
                ok = false;
                continue;
            };
            match key.as_str() {
                "vto" | "vt0" => m.vto = Some(v),
                "kp" => m.kp = Some(v),
                "gamma" => m.gamma = Some(v),
                "phi" => m.phi = Some(v),
                "lambda" => m.lambda = v,
                "rd" => m.rd = Some(v),
                "rs" => m.rs = Some(v),
                "rsh" => m.rsh = Some(v),
                "cbd" => m.cbd = Some(v),
                "cbs" => m.cbs = Some(v),
                "is" => m.is = v,
                "js" => m.js = v,
                "pb" => m.pb = v,
                "cgso" => m.cgso = v,
                "cgdo" => m.cgdo = v,
                "cgbo" => m.cgbo = v,
                "cj" => m.cj = Some(v),
                "mj" => m.mj = v,
                "cjsw" => m.cjsw = Some(v),
                "mjsw" => m.mjsw = v,
                "tox" => m.tox = Some(v),
                "nsub" => m.nsub = Some(v),
                "nss" => m.nss = v,
                "nfs" => m.nfs = v,
                "tpg" => m.tpg = v,
                "ld" => m.ld = v,
                "uo" | "u0" => m.u0 = Some(v),
                "fc" => m.fc = v,
                "xj" => m.xj = v,
                "vmax" => m.vmax = v,
                "delta" => m.delta = v,
                "theta" => m.theta = v,
                "eta" => m.eta = v,
                "kappa" => m.kappa = v,
                "wd" => m.wd = v,
                "xl" => m.xl = v,
                "xw" => m.xw = v,
                "delvto" | "delvt0" => m.delvto = v,
                "tnom" => m.tnom = Some(v),
                "ucrit" => m.ucrit = v,
                "uexp" => m.uexp = v,
                "neff" => m.neff = v,
                "kv" => m.kv = v,
                "nv" => m.nv = v,
                "kc" => m.kc = Some(v),
                "nc" => m.nc = v,
                "gamma1" => m.gamma1 = v,
                "sigma" => m.sigma = v,
                "lambda0" => m.lambda0 = Some(v),
                "lambda1" => m.lambda1 = v,
                _ => {}
            }
        }
        let m = ok.then_some(m);
        self.mos_cache.insert(cache_key, m.clone());
        m
    }

    /// M: `model` after the four terminals, the instance's geometry
    /// (`L= W= AD= AS= PD= PS= NRD= NRS= m=`), the model read, and the
    /// device's branches added to the circuit.
    pub(super) fn mosfet(
        &mut self,
        el: &ast::Element<'_>,
        name: &str,
        nodes: &[NodeId],
        inherited: f64,
        scope: &Scope<'_, '_>,
    ) {
        let ast::ElementBody::Device { words, params } = &el.body else {
            return;
        };
        let Some(model_name) = super::model::name_word(words.first()) else {
            self.errors.push(ElabError::BadDevice {
                span: el.span,
                element: name.to_string(),
                why: "no model name after the four terminals".into(),
            });
            return;
        };
        if let Some(extra) = words.get(1) {
            self.errors.push(ElabError::BadDevice {
                span: extra.span(),
                element: name.to_string(),
                why: "unexpected word after the model (a fifth terminal is not read: kausal's MOS levels have four)".into(),
            });
            return;
        }
        let mut g = Geometry {
            l: DEFAULT_LW,
            w: DEFAULT_LW,
            ad: 0.0,
            as_: 0.0,
            pd: 0.0,
            ps: 0.0,
            nrd: 1.0,
            nrs: 1.0,
            m: inherited,
        };
        let mut ok = true;
        // `.options scale`: lengths on the line scale by it, areas by its
        // square (as ngspice's instance parameters; L and W's defaults not).
        let scale = self.circuit.options.scale.unwrap_or(1.0);
        for p in params {
            let key = p.name.key();
            let factor = match key.as_str() {
                "l" | "w" | "pd" | "ps" => scale,
                "ad" | "as" => scale * scale,
                _ => 1.0,
            };
            let slot = match key.as_str() {
                "l" => &mut g.l,
                "w" => &mut g.w,
                "ad" => &mut g.ad,
                "as" => &mut g.as_,
                "pd" => &mut g.pd,
                "ps" => &mut g.ps,
                "nrd" => &mut g.nrd,
                "nrs" => &mut g.nrs,
                "m" => {
                    g.m *= self.multiplier(p, name, scope).unwrap_or(f64::NAN);
                    continue;
                }
                _ => {
                    self.ignored_param(p, name);
                    continue;
                }
            };
            match self.value(&p.value, scope) {
                Some(v) => *slot = v * factor,
                None => ok = false,
            }
        }
        if !ok || !g.m.is_finite() {
            return;
        }
        let Some(model) = self.mos_model(&model_name, name, scope) else {
            return;
        };
        let Some(dv) = self.derive_mos(&model, name, el) else {
            return;
        };
        let leff = g.l - 2.0 * model.ld + if model.level == 3 { model.xl } else { 0.0 };
        let weff = if model.level == 3 {
            g.w - 2.0 * model.wd + model.xw
        } else {
            g.w
        };
        if !(leff > 0.0 && weff > 0.0) {
            self.errors.push(ElabError::BadDevice {
                span: el.span,
                element: name.to_string(),
                why: format!(
                    "its effective channel is {leff:e} m long and {weff:e} m wide (L − 2·LD, W − 2·WD): both must be positive"
                ),
            });
            return;
        }
        self.expand_mos(el, name, nodes, &model, &dv, &g, leff, weff);
    }

    /// The model's derived values (ngspice's `mos1temp.c`, `mos2temp.c`,
    /// `mos3temp.c`): KP from UO and TOX, and φ, γ and VTO from NSUB, each
    /// where not given, at TNOM (the model's, else `.options`'); then KP,
    /// UO, φ, the threshold and the bulk junctions at the circuit's TEMP.
    fn derive_mos(
        &mut self,
        md: &MosModel,
        element: &str,
        el: &ast::Element<'_>,
    ) -> Option<Derived> {
        let t = if md.pchannel { -1.0 } else { 1.0 };
        let options = &self.circuit.options;
        let tnom_k = md.tnom.or(options.tnom).unwrap_or(27.0) + CELSIUS_K;
        let th = Thermal::new(tnom_k, options.temp.unwrap_or(27.0) + CELSIUS_K);
        let (vtnom, egfet1) = (th.vtnom, th.egfet1);
        let mut phi = md.phi.unwrap_or(0.6);
        let mut gamma = md.gamma.unwrap_or(0.0);
        let mut vto = md.vto.unwrap_or(0.0);
        let mut kp = md.kp.unwrap_or(2e-5);
        let u0 = md.u0.unwrap_or(600.0);
        let cox = match md.tox {
            Some(tox) if tox != 0.0 => EPS_OX / tox,
            _ => 0.0,
        };
        if md.level == 2 && !(cox > 0.0 && cox.is_finite()) {
            self.errors.push(ElabError::BadDevice {
                span: el.span,
                element: element.to_string(),
                why: format!(
                    "model `{}` is level 2 with TOX = {}: its equations divide by the oxide capacitance, so TOX must be positive",
                    md.name,
                    md.tox.unwrap_or(0.0)
                ),
            });
            return None;
        }
        if phi.is_nan() || phi <= 0.0 {
            self.errors.push(ElabError::BadDevice {
                span: el.span,
                element: element.to_string(),
                why: format!("model `{}` has PHI = {phi}: it must be positive", md.name),
            });
            return None;
        }
        if md.level == 6 {
            // `mos6temp.c`: KC in KP's place, 0.5·UO·Cox where not given.
            kp = match md.kc {
                Some(kc) => kc,
                None if cox > 0.0 => 0.5 * u0 * cox * 1e-4,
                None => 5e-5,
            };
        }
        if cox > 0.0 {
            if md.kp.is_none() && md.level != 6 {
                kp = u0 * cox * 1e-4;
            }
            if let Some(nsub) = md.nsub {
                // The intrinsic density at TNOM: level 3 scales ngspice's
                // 1.45e10 cm⁻³ (at 300 K) to it, level 1 does not.
                let ni = if md.level == 3 {
                    let r = tnom_k / 300.0;
                    1.45e16
                        * r
                        * r.sqrt()
                        * (0.5 * egfet1 * (1.0 / 300.0 - 1.0 / tnom_k) / (BOLTZMANN / CHARGE)).exp()
                } else {
                    1.45e16
                };
                if nsub * 1e6 <= ni {
                    self.errors.push(ElabError::BadDevice {
                        span: el.span,
                        element: element.to_string(),
                        why: format!(
                            "model `{}` has NSUB = {nsub} cm⁻³, below silicon's intrinsic density (ngspice refuses it too)",
                            md.name
                        ),
                    });
                    return None;
                }
                if md.phi.is_none() {
                    phi = (2.0 * vtnom * (nsub * 1e6 / ni).ln()).max(0.1);
                }
                let fermis = t * 0.5 * phi;
                let mut wkfng = 3.2;
                if md.tpg != 0.0 {
                    let fermig = t * md.tpg * 0.5 * egfet1;
                    wkfng = 3.25 + 0.5 * egfet1 - fermig;
                }
                let wkfngs = wkfng - (3.25 + 0.5 * egfet1 + fermis);
                if md.gamma.is_none() {
                    gamma = (2.0 * EPS_SI * CHARGE * nsub * 1e6).sqrt() / cox;
                }
                if md.vto.is_none() {
                    let vfb = wkfngs - md.nss * 1e4 * CHARGE / cox;
                    vto = vfb + t * (gamma * phi.sqrt() + phi);
                }
            }
        }
        // Levels 2 and 3: the depletion-width coefficient (0 without
        // NSUB); level 3's narrow-width factor and DIBL scale (mos3temp.c).
        let xd = match md.nsub {
            Some(n) if n > 0.0 && md.level >= 2 => (2.0 * EPS_SI / (CHARGE * n * 1e6)).sqrt(),
            _ => 0.0,
        };
        let (narrow, alpha) = if md.level == 3 {
            let narrow = if cox > 0.0 {
                md.delta * 0.5 * std::f64::consts::PI * EPS_SI / cox
            } else {
                0.0
            };
            (narrow, xd * xd)
        } else {
            (0.0, 0.0)
        };
        // At TEMP: mobility as T^-1.5, φ and the junction potential with
        // the band gap, the threshold with both (`mos1temp.c`).
        let mobility = th.mobility();
        let tphi = th.potential(phi);
        let pb = th.potential(md.pb);
        Some(Derived {
            cox,
            kp: kp * mobility,
            gamma,
            phi: tphi,
            vbi: t * (vto + md.delvto) - gamma * phi.sqrt()
                + t * 0.5 * (egfet1 - th.egfet)
                + 0.5 * (tphi - phi),
            vt: th.vt,
            pb,
            sat: th.saturation(),
            cap_bottom: th.capacitance(md.mj, md.pb),
            cap_side: th.capacitance(md.mjsw, md.pb),
            u0: u0 * mobility,
            nsub: md.nsub.is_some(),
            xd,
            narrow,
            alpha,
        })
    }

    /// The branches of one MOSFET (see the module documentation), after
    /// its intermediates.
    #[allow(clippy::too_many_arguments)]
    fn expand_mos(
        &mut self,
        el: &ast::Element<'_>,
        name: &str,
        nodes: &[NodeId],
        md: &MosModel,
        dv: &Derived,
        g: &Geometry,
        leff: f64,
        weff: f64,
    ) {
        let span = el.span;
        let (d, gate, s, b) = (nodes[0], nodes[1], nodes[2], nodes[3]);
        let m = g.m;
        // Terminal resistances: RD (RS) or RSH times the squares, over m.
        let series = |r: Option<f64>, squares: f64| match r {
            Some(r) => r,
            None => md.rsh.unwrap_or(0.0) * squares,
        };
        let (rd, rs) = (series(md.rd, g.nrd), series(md.rs, g.nrs));
        let dp = self.behind(d, rd, name, "d", span);
        let sp = self.behind(s, rs, name, "s", span);
        let p = md.pchannel;
        let cox = dv.cox * leff * weff * m;
        let overlap = [md.cgso * m * weff, md.cgdo * m * weff, md.cgbo * m * leff];
        let dev = Device {
            md,
            dv,
            beta: dv.kp * m * weff / leff,
            leff,
            weff,
            cox,
            m,
            vt: dv.vt,
            sign: if p { -1.0 } else { 1.0 },
        };
        // The intermediates, each a variable of its own in the listing.
        let mut def = |tag: &str, x: Ex| -> ElemId {
            let mut controls = Vec::new();
            let expr = Box::new(x.finish(&mut controls));
            self.circuit.elements.push(Element {
                name: crate::ir::Name::new(&format!("{name}:{tag}"), Some(span)),
                kind: ElementKind::Intermediate {
                    device: ElementLetter::M,
                    expr,
                    controls,
                },
                nodes: Box::new([]),
            })
        };
        let f = dev.frame(&mut def, [gate, dp, sp, b]);
        let ch = match md.level {
            6 => dev.level6(&mut def, &f),
            3 => dev.level3(&mut def, &f),
            2 => dev.level2(&mut def, &f),
            _ => dev.level1(&mut def, &f),
        };
        let meyer = (cox > 0.0).then(|| dev.meyer(&mut def, &f, &ch));

        let bd_nodes = oriented(p, b, dp);
        let bs_nodes = oriented(p, b, sp);
        let gate_nodes = [
            oriented(p, gate, sp).filter(|_| cox > 0.0 || overlap[0] > 0.0),
            oriented(p, gate, dp).filter(|_| cox > 0.0 || overlap[1] > 0.0),
            oriented(p, gate, b).filter(|_| cox > 0.0 || overlap[2] > 0.0),
        ];
        let ds_nodes = oriented(p, dp, sp);
        let mut ids = NextIds(self.circuit.elements.len() as u32);
        let bd_id = ids.take(bd_nodes.is_some());
        let bs_id = ids.take(bs_nodes.is_some());

        // The bulk junctions: saturation currents from IS or JS times the
        // areas, bottom and sidewall capacitances from CBD/CBS or CJ times
        // the areas, CJSW times the perimeters.
        let (isd, iss) = if md.js == 0.0 || g.ad == 0.0 || g.as_ == 0.0 {
            (md.is * m, md.is * m)
        } else {
            (md.js * m * g.ad, md.js * m * g.as_)
        };
        let (isd, iss) = (isd * dv.sat, iss * dv.sat);
        let bottom = |cgiven: Option<f64>, area: f64| {
            dv.cap_bottom
                * match (cgiven, md.cj) {
                    (Some(c), _) => c * m,
                    (None, Some(cj)) => cj * area * m,
                    _ => 0.0,
                }
        };
        let side = |perimeter: f64| dv.cap_side * md.cjsw.map_or(0.0, |c| c * perimeter * m);
        let j0 = self.circuit.junctions.len() as u32;
        let junction = |suffix: &str, is: f64, cj: f64, mj: f64| DiodeParams {
            name: format!("{name}.{suffix}"),
            is,
            vte: dv.vt,
            bv: None,
            gmin: GMIN,
            cjo: cj,
            vj: dv.pb,
            m: mj,
            fc: md.fc,
            tt: 0.0,
            fwd: DiodeParams::forward_constants(dv.pb, mj, md.fc),
        };
        let caps = [
            (isd, bottom(md.cbd, g.ad), side(g.pd)),
            (iss, bottom(md.cbs, g.as_), side(g.ps)),
        ];
        for (tag, (is, cb, csw)) in ["bd", "bs"].into_iter().zip(caps) {
            self.circuit.junctions.push(junction(tag, is, cb, md.mj));
            self.circuit
                .junctions
                .push(junction(&format!("{tag}sw"), 0.0, csw, md.mjsw));
        }
        let volt = |x: &mut Ex, id: Option<ElemId>| match id {
            Some(id) => x.volt(id),
            None => x.num(0.0),
        };
        for (tag, nodes, id, k, (is, cb, csw)) in [
            ("bd", bd_nodes, bd_id, j0, caps[0]),
            ("bs", bs_nodes, bs_id, j0 + 2, caps[1]),
        ] {
            let mut x = Ex::default();
            let v = volt(&mut x, id);
            if is > 0.0 {
                x.junction(k, DiodePart::Current, v);
            } else {
                let gm = x.num(GMIN);
                x.arith(Arith::Mul, gm, v);
            }
            let q = (cb > 0.0 || csw > 0.0).then(|| {
                let mut q = Ex::default();
                let v = volt(&mut q, id);
                let parts: Vec<u32> = [(k, cb), (k + 1, csw)]
                    .into_iter()
                    .filter(|&(_, c)| c > 0.0)
                    .map(|(j, _)| q.junction(j, DiodePart::Charge, v))
                    .collect();
                if let [a, b] = parts[..] {
                    q.arith(Arith::Add, a, b);
                }
                q
            });
            self.push_branch(ElementLetter::M, name, tag, nodes, false, Some(x), q, span);
        }
        // Meyer's gate capacitances: twice the frame's half-capacitance,
        // swapped back to the terminals, plus the overlap; floored where it
        // can vanish (see [`MEYER_FLOOR`]).
        for (k, tag) in ["gs", "gd", "gb"].into_iter().enumerate() {
            let Some(nodes) = gate_nodes[k] else { continue };
            let mut x = Ex::default();
            let half = match (&meyer, k) {
                (Some(h), 2) => Some(x.volt(h.cb)),
                (Some(h), _) => {
                    let (a, b) = if k == 0 { (h.cs, h.cd) } else { (h.cd, h.cs) };
                    let normal = f.normal(&mut x);
                    let (a, b) = (x.volt(a), x.volt(b));
                    Some(x.push(BNode::Select(normal, a, b)))
                }
                (None, _) => None,
            };
            let constant = if overlap[k] <= 0.0 && cox > 0.0 {
                x.push(BNode::Floor(MEYER_FLOOR * cox))
            } else {
                x.num(overlap[k])
            };
            if let Some(half) = half {
                let two = x.num(2.0);
                let full = x.arith(Arith::Mul, two, half);
                x.arith(Arith::Add, full, constant);
            }
            let mut controls = Vec::new();
            let capacitance = Box::new(x.finish(&mut controls));
            self.circuit.elements.push(Element {
                name: crate::ir::Name::new(&format!("{name}:{tag}"), Some(span)),
                kind: ElementKind::DeviceBranch {
                    device: ElementLetter::M,
                    controlled: false,
                    current: None,
                    charge: None,
                    capacitance: Some(capacitance),
                    controls,
                },
                nodes: nodes.into(),
            });
        }
        // ds: the drain current, signed by the mode.
        let mut x = Ex::default();
        let normal = f.normal(&mut x);
        let id = x.volt(ch.id);
        let neg = x.push(BNode::Neg(id));
        x.push(BNode::Select(normal, id, neg));
        self.push_branch(
            ElementLetter::M,
            name,
            "ds",
            ds_nodes,
            true,
            Some(x),
            None,
            span,
        );

        for (tag, a, z, r) in [("rd", d, dp, rd), ("rs", s, sp, rs)] {
            if a != z {
                self.circuit.elements.push(Element {
                    name: crate::ir::Name::new(&format!("{name}:{tag}"), Some(span)),
                    kind: ElementKind::Resistor { r: r / m },
                    nodes: Box::new([a, z]),
                });
            }
        }
    }
}

/// An instance's geometry (ngspice's defaults).
struct Geometry {
    l: f64,
    w: f64,
    ad: f64,
    as_: f64,
    pd: f64,
    ps: f64,
    nrd: f64,
    nrs: f64,
    m: f64,
}

/// One device's values, for building its expressions.
struct Device<'a> {
    md: &'a MosModel,
    dv: &'a Derived,
    beta: f64,
    leff: f64,
    weff: f64,
    /// The gate oxide's capacitance, W·L·m·Cox.
    cox: f64,
    m: f64,
    vt: f64,
    /// ngspice's `type`: 1 for N-channel, -1 for P-channel.
    sign: f64,
}

/// The voltages seen from the source of the moment (ngspice's `mode`: D'
/// and S' trade places when `vds < 0`), as intermediates.
struct Frame {
    /// `vds` in the device's polarity.
    vds: ElemId,
    /// Gate, bulk and drain voltages over the source of the moment.
    vg: ElemId,
    vb: ElemId,
    vd: ElemId,
}

impl Frame {
    /// `vds ≥ 0` into `x`.
    fn normal(&self, x: &mut Ex) -> u32 {
        let vds = x.volt(self.vds);
        let zero = x.num(0.0);
        x.push(BNode::Cmp(Cmp::Ge, vds, zero))
    }
}

/// The channel's intermediates Meyer's capacitances read.
struct Channel {
    id: ElemId,
    von: ElemId,
    vdsat: ElemId,
}

/// Meyer's half-capacitances in the frame: source side, drain side, bulk.
struct Meyer {
    cs: ElemId,
    cd: ElemId,
    cb: ElemId,
}

type Def<'d> = dyn FnMut(&str, Ex) -> ElemId + 'd;

impl Device<'_> {
    /// `type·(v(a) − v(b))` into `x` (0 when `a` is `b`).
    fn diff(&self, x: &mut Ex, a: NodeId, b: NodeId) -> u32 {
        if a == b {
            return x.num(0.0);
        }
        let (a, b) = if self.sign < 0.0 { (b, a) } else { (a, b) };
        let (a, b) = (x.push(BNode::Pot(a)), x.push(BNode::Pot(b)));
        x.arith(Arith::Sub, a, b)
    }

    /// `vds`, and the gate, bulk and drain voltages over the source of the
    /// moment: `[gate, d', s', bulk]`.
    fn frame(&self, def: &mut Def<'_>, [g, dp, sp, b]: [NodeId; 4]) -> Frame {
        let mut x = Ex::default();
        self.diff(&mut x, dp, sp);
        let vds = def("vds", x);
        let over_source = |dev: &Self, def: &mut Def<'_>, tag: &str, node: NodeId| {
            let mut x = Ex::default();
            let vds_ = x.volt(vds);
            let zero = x.num(0.0);
            let normal = x.push(BNode::Cmp(Cmp::Ge, vds_, zero));
            let from_s = dev.diff(&mut x, node, sp);
            let from_d = dev.diff(&mut x, node, dp);
            x.push(BNode::Select(normal, from_s, from_d));
            def(tag, x)
        };
        let vg = over_source(self, def, "vg", g);
        let vb = over_source(self, def, "vb", b);
        let mut x = Ex::default();
        let v = x.volt(vds);
        x.push(BNode::Call(Func::Abs, v));
        let vd = def("vd", x);
        Frame { vds, vg, vb, vd }
    }

    /// Level 1's threshold, `vbi + γ·√(φ − vbs)` (ngspice's linear
    /// continuation of the root above vbs = 0), which level 6 extends.
    fn body_threshold(&self, x: &mut Ex, f: &Frame) -> u32 {
        let vb = x.volt(f.vb);
        let sarg = sqrt_phi_minus(x, self.dv.phi, vb);
        let vbi = x.num(self.dv.vbi);
        let gamma = x.num(self.dv.gamma);
        let t = x.arith(Arith::Mul, gamma, sarg);
        x.arith(Arith::Add, vbi, t)
    }

    /// Shichman–Hodges: `β(1 + λ vds)` times `vgst²/2` in saturation,
    /// `vds (vgst − vds/2)` below it; zero below threshold.
    fn level1(&self, def: &mut Def<'_>, f: &Frame) -> Channel {
        let mut x = Ex::default();
        self.body_threshold(&mut x, f);
        let von = def("von", x);

        let vgst = |x: &mut Ex| {
            let (vg, von) = (x.volt(f.vg), x.volt(von));
            x.arith(Arith::Sub, vg, von)
        };
        let mut x = Ex::default();
        let v = vgst(&mut x);
        x.positive(v);
        let vdsat = def("vdsat", x);

        let mut x = Ex::default();
        let vgst = vgst(&mut x);
        let vd = x.volt(f.vd);
        let one = x.num(1.0);
        let lambda = x.num(self.md.lambda);
        let t = x.arith(Arith::Mul, lambda, vd);
        let t = x.arith(Arith::Add, one, t);
        let beta = x.num(self.beta);
        let betap = x.arith(Arith::Mul, beta, t);
        let half = x.num(0.5);
        let sat = {
            let t = x.arith(Arith::Mul, vgst, vgst);
            x.arith(Arith::Mul, half, t)
        };
        let lin = {
            let t = x.arith(Arith::Mul, half, vd);
            let t = x.arith(Arith::Sub, vgst, t);
            x.arith(Arith::Mul, vd, t)
        };
        let c = x.push(BNode::Cmp(Cmp::Le, vgst, vd));
        let part = x.push(BNode::Select(c, sat, lin));
        let on = x.arith(Arith::Mul, betap, part);
        let zero = x.num(0.0);
        let c = x.push(BNode::Cmp(Cmp::Le, vgst, zero));
        x.push(BNode::Select(c, zero, on));
        let id = def("id", x);
        Channel { id, von, vdsat }
    }

    /// Sakurai and Newton's n-th power law (ngspice's `mos6load.c`): the
    /// threshold `vbi + γ√(φ − vbs) − γ1·vbs − σ·vds`; above it, with
    /// `vgon = vgs − von`, `vdsat = KV·vgon^NV` and the saturation current
    /// `β·vgon^NC·(1 + λ·vds)`, λ = LAMBDA0 − LAMBDA1·vbs, times
    /// `(2 − vds/vdsat)·vds/vdsat` below vdsat; zero below threshold.
    fn level6(&self, def: &mut Def<'_>, f: &Frame) -> Channel {
        let md = self.md;
        let mut x = Ex::default();
        let von = self.body_threshold(&mut x, f);
        let vb = x.volt(f.vb);
        let g1 = x.num(md.gamma1);
        let t = x.arith(Arith::Mul, g1, vb);
        let von = x.arith(Arith::Sub, von, t);
        let vd = x.volt(f.vd);
        let sigma = x.num(md.sigma);
        let t = x.arith(Arith::Mul, sigma, vd);
        x.arith(Arith::Sub, von, t);
        let von = def("von", x);

        // vgon held at 1 V where it is not positive, so that no power of
        // zero (whose slope is infinite for NV < 1) enters the tangents of
        // a choice that gives 0 there.
        let vgon = |x: &mut Ex| {
            let (vg, von) = (x.volt(f.vg), x.volt(von));
            let v = x.arith(Arith::Sub, vg, von);
            let zero = x.num(0.0);
            let off = x.push(BNode::Cmp(Cmp::Le, v, zero));
            let one = x.num(1.0);
            (x.push(BNode::Select(off, one, v)), off)
        };
        let mut x = Ex::default();
        let (v, off) = vgon(&mut x);
        let (kv, nv) = (x.num(md.kv), x.num(md.nv));
        let t = x.arith(Arith::Pow, v, nv);
        let on = x.arith(Arith::Mul, kv, t);
        let zero = x.num(0.0);
        x.push(BNode::Select(off, zero, on));
        let vdsat = def("vdsat", x);

        let mut x = Ex::default();
        let (v, off) = vgon(&mut x);
        let nc = x.num(md.nc);
        let t = x.arith(Arith::Pow, v, nc);
        let beta = x.num(self.beta);
        let idsat = x.arith(Arith::Mul, beta, t);
        let vb = x.volt(f.vb);
        let (l0, l1) = (x.num(md.lambda0.unwrap_or(md.lambda)), x.num(md.lambda1));
        let t = x.arith(Arith::Mul, l1, vb);
        let lambda = x.arith(Arith::Sub, l0, t);
        let vd = x.volt(f.vd);
        let t = x.arith(Arith::Mul, lambda, vd);
        let one = x.num(1.0);
        let t = x.arith(Arith::Add, one, t);
        let sat = x.arith(Arith::Mul, idsat, t);
        let vdsat_ = x.volt(vdsat);
        let below = x.push(BNode::Cmp(Cmp::Gt, vdsat_, vd));
        // Below vdsat: (2 − r)·r with r = vds/vdsat (vdsat > vds ≥ 0 there).
        let safe = x.push(BNode::Select(below, vdsat_, one));
        let r = x.arith(Arith::Div, vd, safe);
        let two = x.num(2.0);
        let t = x.arith(Arith::Sub, two, r);
        let t = x.arith(Arith::Mul, t, r);
        let lin = x.arith(Arith::Mul, sat, t);
        let on = x.push(BNode::Select(below, lin, sat));
        let zero = x.num(0.0);
        x.push(BNode::Select(off, zero, on));
        let id = def("id", x);
        Channel { id, von, vdsat }
    }

    /// The level-3 drain current (ngspice's mos3load.c): threshold with the
    /// short-channel (XJ), narrow-width (DELTA) and static-feedback (ETA)
    /// effects, mobility modulation (THETA), velocity saturation (VMAX),
    /// channel-length modulation (KAPPA) with punch-through, and weak
    /// inversion (NFS).
    fn level3(&self, def: &mut Def<'_>, f: &Frame) -> Channel {
        let md = self.md;
        let dv = self.dv;
        let (leff, weff) = (self.leff, self.weff);
        let c = |x: &mut Ex, v: f64| x.num(v);

        // √(φ − vbs), and its continuation above vbs = 0: √φ/(1 + vbs/2φ).
        let mut x = Ex::default();
        let vb = x.volt(f.vb);
        sqrt_phi_over(&mut x, dv.phi, vb);
        let sqphbs = def("sqphbs", x);

        // The short-channel factor.
        let fshort = (md.xj != 0.0 && dv.xd != 0.0).then(|| {
            let mut x = Ex::default();
            let (coeff0, coeff1, coeff2) = (0.0631353, 0.8013292, -0.01110777);
            let one = c(&mut x, 1.0);
            let sq = x.volt(sqphbs);
            let djonxj = md.ld / md.xj;
            let k = c(&mut x, dv.xd / md.xj);
            let wponxj = x.arith(Arith::Mul, k, sq);
            let c2 = c(&mut x, coeff2);
            let t = x.arith(Arith::Mul, c2, wponxj);
            let c1 = c(&mut x, coeff1);
            let t = x.arith(Arith::Add, c1, t);
            let t = x.arith(Arith::Mul, t, wponxj);
            let c0 = c(&mut x, coeff0 + djonxj);
            let arga = x.arith(Arith::Add, c0, t);
            let t = x.arith(Arith::Add, one, wponxj);
            let argc = x.arith(Arith::Div, wponxj, t);
            let t = x.arith(Arith::Mul, argc, argc);
            let t = x.arith(Arith::Sub, one, t);
            let argb = x.push(BNode::Call(Func::Sqrt, t));
            let t = x.arith(Arith::Mul, arga, argb);
            let k = c(&mut x, djonxj);
            let t = x.arith(Arith::Sub, t, k);
            let k = c(&mut x, md.xj / leff);
            let t = x.arith(Arith::Mul, k, t);
            x.arith(Arith::Sub, one, t);
            def("fshort", x)
        });
        // γ·fshort and the body factor `fbody`.
        let gammas = |x: &mut Ex| {
            let g = c(x, dv.gamma);
            match fshort {
                Some(fs) => {
                    let fs = x.volt(fs);
                    x.arith(Arith::Mul, g, fs)
                }
                None => g,
            }
        };
        let narrow = dv.narrow / weff;
        let mut x = Ex::default();
        {
            let gs = gammas(&mut x);
            let sq = x.volt(sqphbs);
            let k = c(&mut x, 0.25);
            let t = x.arith(Arith::Mul, k, gs);
            let t = x.arith(Arith::Div, t, sq);
            let nw = c(&mut x, narrow);
            x.arith(Arith::Add, t, nw);
        }
        let fbody = def("fbody", x);
        // The bulk charge over Cox, `γs·√φbs + narrow·φbs`.
        let qbonco = |x: &mut Ex| {
            let gs = gammas(x);
            let sq = x.volt(sqphbs);
            let t = x.arith(Arith::Mul, gs, sq);
            let ph = x.arith(Arith::Mul, sq, sq);
            let nw = c(x, narrow);
            let u = x.arith(Arith::Mul, nw, ph);
            x.arith(Arith::Add, t, u)
        };
        // The threshold, with static feedback.
        let eta = if dv.cox > 0.0 {
            md.eta * 8.15e-22 / (dv.cox * leff * leff * leff)
        } else {
            0.0
        };
        let mut x = Ex::default();
        {
            let vbi = c(&mut x, dv.vbi);
            let e = c(&mut x, eta);
            let vd = x.volt(f.vd);
            let t = x.arith(Arith::Mul, e, vd);
            let vbix = x.arith(Arith::Sub, vbi, t);
            let q = qbonco(&mut x);
            x.arith(Arith::Add, vbix, q);
        }
        let vth = def("vth", x);
        // Weak inversion's slope factor `xn` and the turn-on voltage.
        let xn = (md.nfs != 0.0).then(|| {
            let csonco = CHARGE * md.nfs * 1e4 * leff * weff * self.m / self.cox;
            let mut x = Ex::default();
            let q = qbonco(&mut x);
            let sq = x.volt(sqphbs);
            let ph = x.arith(Arith::Mul, sq, sq);
            let two = c(&mut x, 2.0);
            let t = x.arith(Arith::Mul, two, ph);
            let cdonco = x.arith(Arith::Div, q, t);
            let k = c(&mut x, 1.0 + csonco);
            x.arith(Arith::Add, k, cdonco);
            def("xn", x)
        });
        let mut x = Ex::default();
        {
            let vth = x.volt(vth);
            if let Some(xn) = xn {
                let xn = x.volt(xn);
                let vt = c(&mut x, self.vt);
                let t = x.arith(Arith::Mul, vt, xn);
                x.arith(Arith::Add, vth, t);
            }
        }
        let von = def("von", x);
        // `vgsx − vth` with `vgsx = max(vg, von)`, the mobility factor
        // `fgate = 1/(1 + θ·vgt)` and, with velocity saturation, `vdsc =
        // Leff·VMAX/µs` with `µs = UO·fgate`.
        let mut x = Ex::default();
        {
            let (vg, vn, vt) = (x.volt(f.vg), x.volt(von), x.volt(vth));
            let cnd = x.push(BNode::Cmp(Cmp::Gt, vg, vn));
            let vgsx = x.push(BNode::Select(cnd, vg, vn));
            x.arith(Arith::Sub, vgsx, vt);
        }
        let vgt_id = def("vgt", x);
        let vgt = |x: &mut Ex| x.volt(vgt_id);
        let mut x = Ex::default();
        {
            let v = vgt(&mut x);
            let th = c(&mut x, md.theta);
            let t = x.arith(Arith::Mul, th, v);
            let one = c(&mut x, 1.0);
            let t = x.arith(Arith::Add, one, t);
            x.arith(Arith::Div, one, t);
        }
        let fgate_id = def("fgate", x);
        let fgate = |x: &mut Ex| x.volt(fgate_id);
        let vdsc_id = (md.vmax > 0.0).then(|| {
            let mut x = Ex::default();
            let fg = fgate(&mut x);
            let k = c(&mut x, leff * md.vmax / (dv.u0 * 1e-4));
            x.arith(Arith::Div, k, fg);
            def("vdsc", x)
        });
        let vdsc = |x: &mut Ex| x.volt(vdsc_id.expect("velocity saturation"));
        let mut x = Ex::default();
        {
            let v = vgt(&mut x);
            let fb = x.volt(fbody);
            let one = c(&mut x, 1.0);
            let t = x.arith(Arith::Add, one, fb);
            let arga = x.arith(Arith::Div, v, t);
            if md.vmax > 0.0 {
                let vdsc = vdsc(&mut x);
                let a2 = x.arith(Arith::Mul, arga, arga);
                let v2 = x.arith(Arith::Mul, vdsc, vdsc);
                let t = x.arith(Arith::Add, a2, v2);
                let argb = x.push(BNode::Call(Func::Sqrt, t));
                let t = x.arith(Arith::Add, arga, vdsc);
                x.arith(Arith::Sub, t, argb);
            }
        }
        let vdsat = def("vdsat", x);
        // The current below the length modulation: `β·fgate·(vgt −
        // (1 + fbody)·vdsx/2)·vdsx`, `vdsx = min(vds, vdsat)`, over the
        // velocity-saturation factor `1 + vdsx/vdsc`.
        let mut x = Ex::default();
        {
            let (vd, vs) = (x.volt(f.vd), x.volt(vdsat));
            let cnd = x.push(BNode::Cmp(Cmp::Lt, vd, vs));
            x.push(BNode::Select(cnd, vd, vs));
        }
        let vdsx_id = def("vdsx", x);
        let vdsx = |x: &mut Ex| x.volt(vdsx_id);
        let mut x = Ex::default();
        {
            let vdsx = vdsx(&mut x);
            let fb = x.volt(fbody);
            let one = c(&mut x, 1.0);
            let t = x.arith(Arith::Add, one, fb);
            let half = c(&mut x, 0.5);
            let t = x.arith(Arith::Mul, half, t);
            let t = x.arith(Arith::Mul, t, vdsx);
            let v = vgt(&mut x);
            let cdo = x.arith(Arith::Sub, v, t);
            let cdnorm = x.arith(Arith::Mul, cdo, vdsx);
            let fg = fgate(&mut x);
            let b = c(&mut x, self.beta);
            let t = x.arith(Arith::Mul, b, fg);
            let cd = x.arith(Arith::Mul, t, cdnorm);
            if md.vmax > 0.0 {
                let vdsc = vdsc(&mut x);
                let t = x.arith(Arith::Div, vdsx, vdsc);
                let t = x.arith(Arith::Add, one, t);
                x.arith(Arith::Div, cd, t);
            }
        }
        let ilin = def("ilin", x);
        // Channel-length modulation: the shortening `delxl`.
        let delxl = (dv.alpha != 0.0).then(|| {
            let mut x = Ex::default();
            let (vd, vs) = (x.volt(f.vd), x.volt(vdsat));
            if md.vmax > 0.0 {
                // From the lateral field at the pinch-off point, `Emax =
                // κ·id/(Leff·gdsat)` with `gdsat = id·(1 − fdrain)/vdsc`.
                let id = x.volt(ilin);
                let vdsc = vdsc(&mut x);
                let vdsx = vdsx(&mut x);
                let one = c(&mut x, 1.0);
                let t = x.arith(Arith::Div, vdsx, vdsc);
                let t = x.arith(Arith::Add, one, t);
                let fdrain = x.arith(Arith::Div, one, t);
                let t = x.arith(Arith::Sub, one, fdrain);
                let t = x.arith(Arith::Mul, id, t);
                let t = x.arith(Arith::Div, t, vdsc);
                let floor = c(&mut x, 1e-12);
                let cnd = x.push(BNode::Cmp(Cmp::Gt, t, floor));
                let gdsat = x.push(BNode::Select(cnd, t, floor));
                let k = c(&mut x, md.kappa / leff);
                let t = x.arith(Arith::Mul, k, id);
                let emax = x.arith(Arith::Div, t, gdsat);
                let k = c(&mut x, 0.5 * dv.alpha);
                let arga = x.arith(Arith::Mul, k, emax);
                let a2 = x.arith(Arith::Mul, arga, arga);
                let over = x.arith(Arith::Sub, vd, vs);
                let over = x.positive(over);
                let k = c(&mut x, md.kappa * dv.alpha);
                let t = x.arith(Arith::Mul, k, over);
                let t = x.arith(Arith::Add, a2, t);
                let argb = x.push(BNode::Call(Func::Sqrt, t));
                x.arith(Arith::Sub, argb, arga);
            } else {
                // ngspice's `vds − vdsat + vdsat/8` under the root in
                // saturation, a fourth-power blend below it.
                let ka = md.kappa * dv.alpha;
                let over = x.arith(Arith::Sub, vd, vs);
                let eighth = c(&mut x, 0.125);
                let t = x.arith(Arith::Mul, eighth, vs);
                let t = x.arith(Arith::Add, over, t);
                let t = x.positive(t);
                let k = c(&mut x, ka);
                let t = x.arith(Arith::Mul, k, t);
                let sat = x.push(BNode::Call(Func::Sqrt, t));
                let pos = x.positive(vs);
                let k = c(&mut x, ka / 8.0);
                let t = x.arith(Arith::Mul, k, pos);
                let dl = x.push(BNode::Call(Func::Sqrt, t));
                let tiny = c(&mut x, f64::MIN_POSITIVE);
                let one = c(&mut x, 1.0);
                let cnd = x.push(BNode::Cmp(Cmp::Gt, vs, tiny));
                let den = x.push(BNode::Select(cnd, vs, one));
                let r = x.arith(Arith::Div, vd, den);
                let r2 = x.arith(Arith::Mul, r, r);
                let r4 = x.arith(Arith::Mul, r2, r2);
                let lin = x.arith(Arith::Mul, dl, r4);
                let cnd = x.push(BNode::Cmp(Cmp::Le, vd, vs));
                x.push(BNode::Select(cnd, lin, sat));
            }
            def("delxl", x)
        });
        // The drain current: shortened by `1/(1 − delxl/Leff)` (with
        // punch-through past half the channel; with velocity saturation
        // only in saturation), times the weak-inversion factor below von,
        // zero below threshold without NFS, and at vds = 0.
        let mut x = Ex::default();
        {
            let zero = c(&mut x, 0.0);
            let mut id = x.volt(ilin);
            if let Some(dl) = delxl {
                let dl = x.volt(dl);
                let halfl = c(&mut x, 0.5 * leff);
                let k = c(&mut x, leff * leff / 4.0);
                let t = x.arith(Arith::Div, k, dl);
                let l = c(&mut x, leff);
                let punch = x.arith(Arith::Sub, l, t);
                let cnd = x.push(BNode::Cmp(Cmp::Gt, dl, halfl));
                let dl = x.push(BNode::Select(cnd, punch, dl));
                let one = c(&mut x, 1.0);
                let k = c(&mut x, 1.0 / leff);
                let t = x.arith(Arith::Mul, dl, k);
                let t = x.arith(Arith::Sub, one, t);
                let shortened = x.arith(Arith::Div, id, t);
                id = if md.vmax > 0.0 {
                    let (vd, vs) = (x.volt(f.vd), x.volt(vdsat));
                    let cnd = x.push(BNode::Cmp(Cmp::Le, vd, vs));
                    x.push(BNode::Select(cnd, id, shortened))
                } else {
                    shortened
                };
            }
            let (vg, vn) = (x.volt(f.vg), x.volt(von));
            if let Some(xn) = xn {
                let below = x.push(BNode::Cmp(Cmp::Lt, vg, vn));
                let t = x.arith(Arith::Sub, vg, vn);
                let xn = x.volt(xn);
                let vt = c(&mut x, self.vt);
                let d = x.arith(Arith::Mul, vt, xn);
                let t = x.arith(Arith::Div, t, d);
                let t = x.push(BNode::Select(below, t, zero));
                let wfact = x.push(BNode::Call(Func::Exp, t));
                id = x.arith(Arith::Mul, id, wfact);
            } else {
                let cnd = x.push(BNode::Cmp(Cmp::Le, vg, vn));
                id = x.push(BNode::Select(cnd, zero, id));
            }
            let vd = x.volt(f.vd);
            let cnd = x.push(BNode::Cmp(Cmp::Eq, vd, zero));
            x.push(BNode::Select(cnd, zero, id));
        }
        let id = def("id", x);
        Channel { id, von, vdsat }
    }

    /// Meyer's half-capacitances in the frame (ngspice's `DEVqmeyer`): by
    /// `vgst = vg − von` the bulk side takes Cox/2 in accumulation, falling
    /// to 0 at threshold; the source and drain sides rise to Cox/3 in
    /// strong inversion, shared by `vds` against `vdsat` (at least 25 mV)
    /// below saturation.
    fn meyer(&self, def: &mut Def<'_>, f: &Frame, ch: &Channel) -> Meyer {
        let cox = self.cox;
        let phi = self.dv.phi;
        let c = |x: &mut Ex, v: f64| x.num(v);
        let vgst = |x: &mut Ex| {
            let (vg, von) = (x.volt(f.vg), x.volt(ch.von));
            x.arith(Arith::Sub, vg, von)
        };
        let side = |def: &mut Def<'_>, drain: bool| {
            let mut x = Ex::default();
            let zero = c(&mut x, 0.0);
            let one = c(&mut x, 1.0);
            let vgst = vgst(&mut x);
            let vd = x.volt(f.vd);
            let vdsat = {
                let v = x.volt(ch.vdsat);
                let magic = c(&mut x, 0.025);
                let cnd = x.push(BNode::Cmp(Cmp::Gt, v, magic));
                x.push(BNode::Select(cnd, v, magic))
            };
            // Below saturation the shares `1 − vdsat²/(2vdsat − vds)²`
            // (drain) and `1 − (vdsat − vds)²/(2vdsat − vds)²` (source).
            let below = x.push(BNode::Cmp(Cmp::Lt, vd, vdsat));
            let two = c(&mut x, 2.0);
            let t = x.arith(Arith::Mul, two, vdsat);
            let vddif = x.arith(Arith::Sub, t, vd);
            // Guarded where the share is not selected (vds ≥ vdsat).
            let vddif = x.push(BNode::Select(below, vddif, one));
            let vddif2 = x.arith(Arith::Mul, vddif, vddif);
            let num = if drain {
                x.arith(Arith::Mul, vdsat, vdsat)
            } else {
                let t = x.arith(Arith::Sub, vdsat, vd);
                x.arith(Arith::Mul, t, t)
            };
            let t = x.arith(Arith::Div, num, vddif2);
            let share = x.arith(Arith::Sub, one, t);
            let share = x.push(BNode::Select(below, share, if drain { zero } else { one }));
            let third = c(&mut x, cox / 3.0);
            let k = c(&mut x, cox / (1.5 * phi));
            let t = x.arith(Arith::Mul, k, vgst);
            let rising = x.arith(Arith::Add, t, third);
            let weak = x.push(BNode::Cmp(Cmp::Le, vgst, zero));
            let base = x.push(BNode::Select(weak, rising, third));
            let on = x.arith(Arith::Mul, base, share);
            let nhalf = c(&mut x, -phi / 2.0);
            let depl = x.push(BNode::Cmp(Cmp::Le, vgst, nhalf));
            x.push(BNode::Select(depl, zero, on));
            def(if drain { "cd" } else { "cs" }, x)
        };
        let cs = side(def, false);
        let cd = side(def, true);
        let mut x = Ex::default();
        {
            let zero = c(&mut x, 0.0);
            let vgst = vgst(&mut x);
            let full = c(&mut x, cox / 2.0);
            let k = c(&mut x, -cox / (2.0 * phi));
            let ramp = x.arith(Arith::Mul, k, vgst);
            let weak = x.push(BNode::Cmp(Cmp::Le, vgst, zero));
            let t = x.push(BNode::Select(weak, ramp, zero));
            let nphi = c(&mut x, -phi);
            let deep = x.push(BNode::Cmp(Cmp::Le, vgst, nphi));
            x.push(BNode::Select(deep, full, t));
        }
        let cb = def("cb", x);
        Meyer { cs, cd, cb }
    }
}

/// `√(φ − v)` for `v ≤ 0`, and its continuation above, `√φ/(1 + v/2φ)`,
/// as ngspice's levels 2 and 3 write it (level 1's is
/// [`sqrt_phi_minus`]).
fn sqrt_phi_over(x: &mut Ex, phi: f64, v: u32) -> u32 {
    let zero = x.num(0.0);
    let one = x.num(1.0);
    let p = x.num(phi);
    let cnd = x.push(BNode::Cmp(Cmp::Lt, v, zero));
    let v_neg = x.push(BNode::Select(cnd, v, zero));
    let t = x.arith(Arith::Sub, p, v_neg);
    let rev = x.push(BNode::Call(Func::Sqrt, t));
    let sqphi = x.num(phi.sqrt());
    let twophi = x.num(2.0 * phi);
    let v_pos = x.positive(v);
    let t = x.arith(Arith::Div, v_pos, twophi);
    let t = x.arith(Arith::Add, one, t);
    let fwd = x.arith(Arith::Div, sqphi, t);
    let cnd = x.push(BNode::Cmp(Cmp::Le, v, zero));
    x.push(BNode::Select(cnd, rev, fwd))
}

/// `√(φ − vbs)` for `vbs ≤ 0`, and ngspice's linear continuation
/// `max(0, √φ − vbs/(2√φ))` above.
fn sqrt_phi_minus(x: &mut Ex, phi: f64, vb: u32) -> u32 {
    let zero = x.num(0.0);
    let neg = {
        let c = x.push(BNode::Cmp(Cmp::Lt, vb, zero));
        x.push(BNode::Select(c, vb, zero))
    };
    let p = x.num(phi);
    let t = x.arith(Arith::Sub, p, neg);
    let rev = x.push(BNode::Call(Func::Sqrt, t));
    let sq = x.num(phi.sqrt());
    let k = x.num(1.0 / (2.0 * phi.sqrt()));
    let t = x.arith(Arith::Mul, k, vb);
    let t = x.arith(Arith::Sub, sq, t);
    let fwd = x.positive(t);
    let c = x.push(BNode::Cmp(Cmp::Le, vb, zero));
    x.push(BNode::Select(c, rev, fwd))
}
