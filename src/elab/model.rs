//! Diode `.model` cards → [`DiodeModel`]: the level-1 parameters kausal
//! reads, the ones it ignores, and the junction capacitance it adds; and
//! resistor, capacitor and inductor models (ngspice's `res`, `cap` and `ind`
//! devices), which give an R, C or L its value from its geometry and its
//! temperature coefficients.

use super::{DiodeModel, Elab, ElabError, Scope};
use crate::front::ast;

/// The constant junction capacitance kausal gives a diode model with TT and
/// no CJO (warning K0297), so that the junction's charge fixes its voltage.
/// Smaller floors leave the charge too weak a coordinate: with 1 fF a clamp
/// whose two junctions and source form a loop (index reduction keeps one
/// junction's charge) is off ngspice by volts, and a bridge takes minutes.
/// 1 pF is physical, and visible where nothing else sets a voltage: the
/// floating common mode of a bridge (its four junctions' capacitance against
/// a 10 MΩ path), or a clamp's nA current.
pub const JUNCTION_CAPACITANCE_FLOOR: f64 = 1e-12;

/// Level-1 diode parameters kausal models, with their aliases.
const DIODE_PARAMS: &[&str] = &[
    "is", "js", "n", "rs", "cjo", "cj0", "cj", "vj", "pb", "m", "mj", "fc", "tt", "bv", "ibv",
    "eg", "xti", "tnom",
];
/// ngspice diode parameters that do not change kausal's transient result at
/// the nominal temperature (the temperature coefficients TM1, TRS, TT1, TBV1…
/// do away from it; kausal warns of each).
const DIODE_IGNORED: &[&str] = &[
    "kf", "af", "level", "ikf", "ik", "ikr", "isr", "nr", "nbv", "ibvl", "nbvl", "tbv1", "tbv2",
    "trs", "trs1", "trs2", "tt1", "tt2", "tm1", "tm2", "cta", "ctp", "tpb", "tphp", "jsw", "cjsw",
    "cjp", "php", "mjsw", "fcs", "area", "pj", "vp", "lm", "lp", "wm", "wp", "xom", "xoi", "xm",
    "xp", "d", "bvj", "iave", "vrev", "version", "bv_max", "fv_max", "id_max", "pd_max", "te_max",
    "rth0", "cth0", "kms", "tref", "ctc", "tvj", "isw", "ns", "rsw", "ikp", "gap1", "gap2", "tlev",
    "tlevc", "jtun", "jtunsw", "ntun", "xtitun", "keg",
];

/// A resistor model (ngspice's `res` device: `.model NAME R(...)`), as
/// `RESupdate_conduct` reads it; `None` where not given.
#[derive(Clone, Debug)]
pub(super) struct ResistorModel {
    pub rsh: f64,
    pub narrow: f64,
    pub short: f64,
    pub defw: f64,
    pub defl: f64,
    pub r: Option<f64>,
    pub tc1: Option<f64>,
    pub tc2: Option<f64>,
    pub tce: Option<f64>,
    pub tnom: Option<f64>,
}

impl Default for ResistorModel {
    fn default() -> Self {
        ResistorModel {
            rsh: 0.0,
            narrow: 0.0,
            short: 0.0,
            defw: 10e-6,
            defl: 10e-6,
            r: None,
            tc1: None,
            tc2: None,
            tce: None,
            tnom: None,
        }
    }
}

/// Resistor model parameters kausal reads, with their aliases.
const RESISTOR_PARAMS: &[&str] = &[
    "rsh", "narrow", "dw", "short", "dlr", "defw", "w", "l", "r", "res", "tc1", "tc1r", "tc2",
    "tc2r", "tce", "tnom",
];
/// Resistor model parameters that do not change a transient: noise, and
/// the breakdown limit ngspice only warns of.
const RESISTOR_IGNORED: &[&str] = &["kf", "af", "lf", "wf", "ef", "bv_max"];

/// A capacitor model (ngspice's `cap` device: `.model NAME C(...)`), as
/// `capsetup.c` and `captemp.c` read it.
#[derive(Clone, Debug)]
pub(super) struct CapacitorModel {
    pub cap: Option<f64>,
    pub cj: f64,
    pub cjsw: f64,
    pub defw: f64,
    pub narrow: f64,
    pub short: f64,
    pub tc1: Option<f64>,
    pub tc2: Option<f64>,
    pub tnom: Option<f64>,
}

/// Capacitor model parameters kausal reads, with their aliases.
const CAPACITOR_PARAMS: &[&str] = &[
    "cap", "cj", "cox", "cjsw", "capsw", "defw", "w", "narrow", "short", "del", "tc1", "tc2",
    "tnom", "di", "thick",
];
/// Capacitor model parameters that do not change a transient.
const CAPACITOR_IGNORED: &[&str] = &["bv_max", "defl", "l"];

/// An inductor model (ngspice's `ind` device: `.model NAME L(...)`), as
/// `indsetup.c` reads it: `ind` is the model's inductance (IND, else NT
/// turns on the coil's inductance per squared turn), `per_turn2` that
/// inductance per squared turn, for an instance's own `nt=`.
#[derive(Clone, Debug, Default)]
pub(super) struct InductorModel {
    pub ind: f64,
    pub per_turn2: f64,
    pub tc1: Option<f64>,
    pub tc2: Option<f64>,
    pub tnom: Option<f64>,
}

/// Inductor model parameters kausal reads. `l` only says that the model is
/// an inductor's: ngspice reads no value from it, nor does kausal.
const INDUCTOR_PARAMS: &[&str] = &[
    "ind", "tc1", "tc2", "tnom", "csect", "dia", "length", "nt", "mu", "l",
];

/// The vacuum permeability ngspice uses, H/m.
const MU_ZERO: f64 = 4.0 * std::f64::consts::PI * 1e-7;

/// Lundin's correction of a long solenoid's inductance for a coil of
/// `length` and cross-section `csect` (H. Lundin, "A handbook formula for
/// the inductance of a single-layer circular coil", Proc. IEEE 73, 1985),
/// with x = diameter / length; 1 for coils below a micrometre, as ngspice.
fn lundin(length: f64, csect: f64) -> f64 {
    use std::f64::consts::PI;
    if csect < 1e-12 || length < 1e-6 {
        return 1.0;
    }
    let x = 2.0 * (csect / PI).sqrt() / length;
    let (x2, x4) = (x * x, x * x * x * x);
    if x < 1.0 {
        (1.0 + 0.383901 * x2 + 0.017108 * x4) / (1.0 + 0.258952 * x2) - 4.0 * x / (3.0 * PI)
    } else {
        let ratio =
            ((4.0 * x).ln() - 0.5) * (1.0 + 0.383901 / x2 + 0.017108 / x4) / (1.0 + 0.258952 / x2);
        let k = 0.093842 / x2 + 0.002029 / x4 - 0.000801 / (x2 * x4);
        2.0 * (ratio + k) / (PI * x)
    }
}

impl Elab {
    /// The inductor model `model` names (type L).
    pub(super) fn inductor_model(
        &mut self,
        model: &ast::Name<'_>,
        element: &str,
        scope: &Scope<'_, '_>,
    ) -> Option<InductorModel> {
        let params = self.passive_model_params(
            model,
            element,
            scope,
            (&["l"], "L"),
            (INDUCTOR_PARAMS, &[]),
        )?;
        let mut m = InductorModel::default();
        let (mut ind, mut csect, mut dia, mut length, mut nt, mut mu) =
            (None, None, None, None, 0.0, 1.0);
        for (key, v) in params {
            match key.as_str() {
                "ind" => ind = Some(v),
                "tc1" => m.tc1 = Some(v),
                "tc2" => m.tc2 = Some(v),
                "tnom" => m.tnom = Some(v),
                "csect" => csect = Some(v),
                "dia" => dia = Some(v),
                "length" => length = Some(v),
                "nt" => nt = v,
                "mu" => mu = v,
                _ => {}
            }
        }
        // The diameter before the cross-section; a coil's inductance per
        // squared turn μ·μ0·A/ℓ, corrected by Lundin's factor where both
        // its length and its section are given.
        let area = match dia {
            Some(d) => std::f64::consts::PI * d * d / 4.0,
            None => csect.unwrap_or(0.0),
        };
        if let Some(len) = length.filter(|&l| l > 0.0) {
            m.per_turn2 = mu * MU_ZERO * area / len;
            if dia.is_some() || csect.is_some() {
                m.per_turn2 *= lundin(len, area);
            }
        }
        m.ind = ind.unwrap_or(nt * nt * m.per_turn2);
        Some(m)
    }

    /// The capacitor model `model` names (type C).
    pub(super) fn capacitor_model(
        &mut self,
        model: &ast::Name<'_>,
        element: &str,
        scope: &Scope<'_, '_>,
    ) -> Option<CapacitorModel> {
        let mut m = CapacitorModel {
            cap: None,
            cj: 0.0,
            cjsw: 0.0,
            defw: 10e-6,
            narrow: 0.0,
            short: 0.0,
            tc1: None,
            tc2: None,
            tnom: None,
        };
        let (mut cj, mut del, mut di, mut thick) = (None, None, None, 0.0);
        let (mut narrow, mut short) = (None, None);
        let params = self.passive_model_params(
            model,
            element,
            scope,
            (&["c"], "C"),
            (CAPACITOR_PARAMS, CAPACITOR_IGNORED),
        )?;
        for (key, v) in params {
            match key.as_str() {
                "cap" => m.cap = Some(v),
                "cj" | "cox" => cj = Some(v),
                "cjsw" | "capsw" => m.cjsw = v,
                "defw" | "w" => m.defw = v,
                "narrow" => narrow = Some(v),
                "short" => short = Some(v),
                "del" => del = Some(v),
                "tc1" => m.tc1 = Some(v),
                "tc2" => m.tc2 = Some(v),
                "di" => di = Some(v),
                "thick" => thick = v,
                _ => m.tnom = Some(v),
            }
        }
        // CJ from the insulator where not given: its relative permittivity
        // (DI, else SiO2's 3.9) over its thickness; DEL narrows and shortens
        // by twice itself where NARROW and SHORT are not given.
        const EPS_ZERO: f64 = 8.854_187_817e-12;
        m.cj = cj.unwrap_or(if thick > 0.0 {
            di.unwrap_or(3.9) * EPS_ZERO / thick
        } else {
            0.0
        });
        m.narrow = narrow.or(del.map(|d| 2.0 * d)).unwrap_or(0.0);
        m.short = short.or(del.map(|d| 2.0 * d)).unwrap_or(0.0);
        Some(m)
    }

    /// The resistor model `model` names (type R or RES).
    pub(super) fn resistor_model(
        &mut self,
        model: &ast::Name<'_>,
        element: &str,
        scope: &Scope<'_, '_>,
    ) -> Option<ResistorModel> {
        let mut m = ResistorModel::default();
        let params = self.passive_model_params(
            model,
            element,
            scope,
            (&["r", "res"], "R"),
            (RESISTOR_PARAMS, RESISTOR_IGNORED),
        )?;
        for (key, v) in params {
            match key.as_str() {
                "rsh" => m.rsh = v,
                "narrow" | "dw" => m.narrow = v,
                "short" | "dlr" => m.short = v,
                "defw" | "w" => m.defw = v,
                "l" => m.defl = v,
                "r" | "res" => m.r = Some(v),
                "tc1" | "tc1r" => m.tc1 = Some(v),
                "tc2" | "tc2r" => m.tc2 = Some(v),
                "tce" => m.tce = Some(v),
                _ => m.tnom = Some(v),
            }
        }
        Some(m)
    }

    /// The parameters a resistor's, capacitor's or inductor's model reads
    /// (`read`: the known and the ignored ones), for the model `model` names,
    /// which must have one of `kinds` (the type `expected` in messages); its
    /// other parameters are reported on its first use.
    fn passive_model_params(
        &mut self,
        model: &ast::Name<'_>,
        element: &str,
        scope: &Scope<'_, '_>,
        (kinds, expected): (&[&str], &'static str),
        (known, ignored): (&[&str], &[&str]),
    ) -> Option<Vec<(String, f64)>> {
        let (def, _) = self.typed_model(model, element, scope, kinds, expected)?;
        let first_use = self
            .passive_models_seen
            .insert((def.span.file.0, def.span.start));
        self.read_model_params(def, known, ignored, first_use, scope)
    }

    /// Whether model parameter `p` (its key `key`) is not one of `known`:
    /// then, on the model's first use, a warning that it is ignored (one of
    /// `ignored`, which does not change the transient result) or unknown.
    pub(super) fn unread_model_param(
        &mut self,
        p: &ast::Assign<'_>,
        key: &str,
        known: &[&str],
        ignored: &[&str],
        def: &ast::Model<'_>,
        first_use: bool,
    ) -> bool {
        if known.contains(&key) {
            return false;
        }
        if first_use {
            self.errors.push(if ignored.contains(&key) {
                ElabError::IgnoredModelParam {
                    span: p.name.span,
                    name: p.name.text.to_string(),
                }
            } else {
                ElabError::UnknownModelParam {
                    span: p.name.span,
                    name: p.name.text.to_string(),
                    model: def.name.text.to_string(),
                }
            });
        }
        true
    }

    /// The parameters of `def` among `known`, by key, with their values;
    /// the others reported on the model's first use (see
    /// [`Elab::unread_model_param`]).
    fn read_model_params(
        &mut self,
        def: &ast::Model<'_>,
        known: &[&str],
        ignored: &[&str],
        first_use: bool,
        scope: &Scope<'_, '_>,
    ) -> Option<Vec<(String, f64)>> {
        let mut out = Vec::with_capacity(def.params.len());
        for p in &def.params {
            let key = p.name.key();
            if !self.unread_model_param(p, &key, known, ignored, def, first_use) {
                out.push((key, self.value(&p.value, scope)?));
            }
        }
        Some(out)
    }

    /// The model `model` names, if it is of one of `kinds` (its index
    /// there); an undefined model or one of another type is reported
    /// (`expected` names the types `element` takes).
    pub(super) fn typed_model<'s, 'a>(
        &mut self,
        model: &ast::Name<'_>,
        element: &str,
        scope: &Scope<'s, 'a>,
        kinds: &[&str],
        expected: &'static str,
    ) -> Option<(&'s ast::Model<'a>, usize)> {
        let Some(def) = scope.model(&model.key()) else {
            self.errors.push(ElabError::UndefinedModel {
                span: model.span,
                name: model.text.to_string(),
            });
            return None;
        };
        match kinds.iter().position(|k| def.kind.is(k)) {
            Some(k) => Some((def, k)),
            None => {
                self.errors.push(ElabError::WrongModelType {
                    span: model.span,
                    name: model.text.to_string(),
                    found: def.kind.text.to_string(),
                    expected,
                    element: element.to_string(),
                });
                None
            }
        }
    }

    pub(super) fn diode_model(
        &mut self,
        model: &ast::Name<'_>,
        element: &str,
        scope: &Scope<'_, '_>,
    ) -> Option<DiodeModel> {
        let (def, _) = self.typed_model(model, element, scope, &["d"], "D")?;
        let cache_key = (def.span.file.0, def.span.start, scope.prefix.clone());
        if let Some(m) = self.model_cache.get(&cache_key) {
            return Some(m.clone());
        }
        let first_use = !self
            .model_cache
            .keys()
            .any(|k| k.0 == cache_key.0 && k.1 == cache_key.1);
        let mut m = DiodeModel {
            name: def.name.key(),
            ..DiodeModel::default()
        };
        let params = self.read_model_params(def, DIODE_PARAMS, DIODE_IGNORED, first_use, scope)?;
        for (key, v) in params {
            match key.as_str() {
                "is" | "js" => m.is = v,
                "n" => m.n = v,
                "rs" => m.rs = v,
                "cjo" | "cj0" | "cj" => m.cjo = v,
                "vj" | "pb" => m.vj = v,
                "m" | "mj" => m.m = v,
                "fc" => m.fc = v,
                "tt" => m.tt = v,
                "bv" => m.bv = Some(v.abs()),
                "ibv" => m.ibv = v,
                "eg" => m.eg = v,
                "xti" => m.xti = v,
                "tnom" => m.tnom = Some(v),
                _ => {}
            }
        }
        // A junction's charge is its state (`build::diode`): with diffusion
        // charge alone, a reverse-biased junction holds ~TT·GMIN·v, so its
        // charge cannot fix its voltage (1e-21 C moves it by 0.1 V at TT =
        // 10 ns, and a half-wave rectifier would turn on 0.5 V early).
        if m.cjo == 0.0 && m.tt > 0.0 {
            m.cjo = JUNCTION_CAPACITANCE_FLOOR;
            m.m = 0.0;
            if first_use && let Some(tt) = def.params.iter().find(|p| p.name.key() == "tt") {
                self.errors.push(ElabError::TransitTimeWithoutCapacitance {
                    span: tt.name.span,
                    model: def.name.text.to_string(),
                    tt: "TT",
                    cj: "CJO",
                    cap: "1 pF",
                });
            }
        }
        self.model_cache.insert(cache_key, m.clone());
        Some(m)
    }
}

/// A bare word as a name (a model's, or a node's), number-like ones such as
/// `2n3904` included.
pub(super) fn name_word<'a>(w: Option<&ast::Value<'a>>) -> Option<ast::Name<'a>> {
    match w {
        Some(ast::Value::Ident(n)) => Some(*n),
        Some(ast::Value::Num { text, span, .. }) => Some(ast::Name { text, span: *span }),
        _ => None,
    }
}
