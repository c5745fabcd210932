//! Q: ngspice's bipolar transistor, the Gummel–Poon model of its level 1,
//! at the circuit's temperature (scaled from the model's TNOM as
//! `bjttemp.c` scales it: TLEV 0, 1 and 3, TLEVC 0 and 1), elaborated into
//! two-terminal branches between the terminals and internal nodes, each
//! named by the device:
//!
//! ```text
//!  C ─rc─ C' ─┬─ bc: ibc/BR + ibcn + d(qbc)/dt ─┬─ B' ─rb─ B
//!             ├─ ce: (ibe − ibc)/qb            │
//!  E ─re─ E' ─┴─ be: ibe/BF + iben + d(qbe)/dt ─┘
//! ```
//!
//! and two charges alone: `bx`, the share 1 − XCJC of the B-C depletion
//! charge, from B to C'; `cs`, the substrate's depletion charge, from the
//! substrate to C' (to B' for a lateral device). A PNP's branches point the
//! other way, so that every branch voltage is ngspice's `type · v`.
//!
//! The junction exponentials and depletion charges are the diode's device
//! functions ([`crate::ir::DiodeParams`], in [`super::Circuit::junctions`]),
//! so the tape limits their Newton steps as ngspice limits junctions; the
//! rest (the base charge `qb` with Early effect and high injection, the
//! transit-time charge, the base resistance's modulation) is written out as
//! expressions, which the listing shows and code generation emits.

use super::thermal::{CELSIUS_K, Thermal};
use super::{Arith, BExpr, BNode, Elab, ElabError, ElemId, Element, ElementKind, NodeId, Scope};
use crate::front::ast::{self, ElementLetter, Value};
use crate::ir::{Cmp, DiodeParams, DiodePart, Func};

/// The capacitance a BJT junction with a transit time and no depletion
/// capacitance gets (warning K0297), so that its charge fixes its voltage
/// in reverse bias (see `model.rs`). Measured on an RTL inverter with TF and
/// no CJE (Xyce's TIA circuit 1): 1 pF there (the diodes' floor) puts the
/// output off ngspice by 47 %, 1 fF by 1e-3, 10 aF by 2e-5, with no more
/// steps; a transistor's junction is not a clamp's, whose floating common
/// mode needs the diodes' larger one.
const TRANSIT_CAPACITANCE_FLOOR: f64 = 1e-17;

/// Volts per ampere of the excess-phase network's signal (1 mA is 1 V), and
/// its resistance: currents of milliamperes, capacitances of 1e-13 F for a
/// picosecond delay, so that its states' tolerances are the circuit's.
const EXCESS_SCALE: f64 = 1e3;
const EXCESS_RESISTANCE: f64 = 1e3;

/// ngspice's GMIN, in parallel with each junction.
const GMIN: f64 = 1e-12;

/// The model card's values; `None` where ngspice's "given" flag matters.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct BjtModel {
    name: String,
    pnp: bool,
    is: f64,
    ibe: Option<f64>,
    ibc: Option<f64>,
    bf: f64,
    nf: f64,
    vaf: f64,
    ikf: f64,
    ise: f64,
    ne: f64,
    br: f64,
    nr: f64,
    var: f64,
    ikr: f64,
    isc: f64,
    nc: f64,
    nkf: Option<f64>,
    rb: f64,
    irb: f64,
    rbm: Option<f64>,
    re: f64,
    rc: f64,
    cje: f64,
    vje: f64,
    mje: f64,
    tf: f64,
    xtf: f64,
    vtf: f64,
    itf: f64,
    cjc: f64,
    vjc: f64,
    mjc: f64,
    xcjc: f64,
    tr: f64,
    cjs: f64,
    vjs: f64,
    mjs: f64,
    fc: f64,
    /// Vertical (1) or lateral (-1); by default NPNs are vertical, PNPs lateral.
    subs: Option<f64>,
    /// Excess phase at 1/(2π TF), degrees.
    ptf: f64,
    /// The temperature parameters given on the card (`BJT_TEMPERATURE`),
    /// read by [`Elab::bjt_at_temperature`].
    temperature: Vec<(&'static str, f64)>,
}

impl BjtModel {
    fn new(name: String, pnp: bool) -> BjtModel {
        BjtModel {
            name,
            pnp,
            is: 1e-16,
            ibe: None,
            ibc: None,
            bf: 100.0,
            nf: 1.0,
            vaf: 0.0,
            ikf: 0.0,
            ise: 0.0,
            ne: 1.5,
            br: 1.0,
            nr: 1.0,
            var: 0.0,
            ikr: 0.0,
            isc: 0.0,
            nc: 2.0,
            nkf: None,
            rb: 0.0,
            irb: 0.0,
            rbm: None,
            re: 0.0,
            rc: 0.0,
            cje: 0.0,
            vje: 0.75,
            mje: 0.33,
            tf: 0.0,
            xtf: 0.0,
            vtf: 0.0,
            itf: 0.0,
            cjc: 0.0,
            vjc: 0.75,
            mjc: 0.33,
            xcjc: 1.0,
            tr: 0.0,
            cjs: 0.0,
            vjs: 0.75,
            mjs: 0.0,
            fc: 0.5,
            subs: None,
            ptf: 0.0,
            temperature: Vec::new(),
        }
    }

    /// A temperature parameter as given, else its default.
    fn given(&self, key: &str, default: f64) -> f64 {
        self.temperature
            .iter()
            .find(|(k, _)| *k == key)
            .map_or(default, |&(_, v)| v)
    }

    fn lateral(&self) -> bool {
        match self.subs {
            Some(s) => s < 0.0,
            None => self.pnp,
        }
    }
}

/// Gummel–Poon parameters kausal models, with their aliases.
const BJT_PARAMS: &[&str] = &[
    "is", "ibe", "ibc", "bf", "nf", "vaf", "va", "ikf", "ik", "ise", "c2", "ne", "br", "nr", "var",
    "vb", "ikr", "isc", "c4", "nc", "nkf", "rb", "irb", "rbm", "re", "rc", "cje", "vje", "pe",
    "mje", "me", "tf", "xtf", "vtf", "itf", "ptf", "cjc", "vjc", "pc", "mjc", "mc", "xcjc", "tr",
    "cjs", "csub", "ccs", "vjs", "ps", "mjs", "ms", "fc", "subs", "ptf", "level", "npn", "pnp",
];
/// The temperature parameters of `bjttemp.c` (TLEV 0, 1 and 3; TLEVC 0
/// and 1): TNOM, β's exponent XTB, the saturation current's EG and XTI, the
/// capacitances' and potentials' linear coefficients, and the linear and
/// quadratic coefficients of the rest.
const BJT_TEMPERATURE: &[&str] = &[
    "tnom", "xtb", "eg", "xti", "tlev", "tlevc", "cte", "ctc", "cts", "tvje", "tvjc", "tvjs",
    "tbf1", "tbf2", "tbr1", "tbr2", "tikf1", "tikf2", "tikr1", "tikr2", "tirb1", "tirb2", "tnc1",
    "tnc2", "tne1", "tne2", "tnf1", "tnf2", "tnr1", "tnr2", "trb1", "trb2", "trc1", "trc2", "tre1",
    "tre2", "trm1", "trm2", "tvaf1", "tvaf2", "tvar1", "tvar2", "titf1", "titf2", "ttf1", "ttf2",
    "ttr1", "ttr2", "tmje1", "tmje2", "tmjc1", "tmjc2", "tmjs1", "tmjs2", "tis1", "tis2", "tise1",
    "tise2", "tisc1", "tisc2",
];
/// ngspice BJT parameters that do not change kausal's transient result
/// (noise, safe operating area, the substrate current's emission and its
/// temperature coefficients) or that only matter with parameters kausal
/// refuses.
const BJT_IGNORED: &[&str] = &[
    "kf", "af", "tns1", "tns2", "tiss1", "tiss2", "ns", "vbe_max", "vbc_max", "vce_max", "pd_max",
    "ic_max", "ib_max", "te_max", "rth0", "bv", "bvcbo", "bvceo", "bvebo", "vceo", "icrating",
    "mfg", "type", "iave", "vpk", "quasimod", "vg", "cn", "d",
];
/// Parameters whose effect kausal does not model: refused when not zero.
const BJT_REFUSED: &[(&str, &str)] = &[
    ("iss", "a substrate junction current (ISS)"),
    ("rco", "Kull's quasi-saturation (RCO)"),
    ("qco", "Kull's quasi-saturation (QCO)"),
];

impl Elab {
    /// The BJT model `model` (an NPN or PNP card of level 1).
    fn bjt_model(
        &mut self,
        model: &ast::Name<'_>,
        element: &str,
        scope: &Scope<'_, '_>,
    ) -> Option<BjtModel> {
        let (def, kind) = self.typed_model(model, element, scope, &["npn", "pnp"], "NPN or PNP")?;
        let pnp = kind == 1;
        let cache_key = (def.span.file.0, def.span.start, scope.prefix.clone());
        if let Some(m) = self.bjt_cache.get(&cache_key) {
            return m.clone();
        }
        let first_use = !self
            .bjt_cache
            .keys()
            .any(|k| k.0 == cache_key.0 && k.1 == cache_key.1);
        let mut m = BjtModel::new(def.name.key(), pnp);
        let mut ok = true;
        for p in &def.params {
            let key = p.name.key();
            if let Some(&(_, what)) = BJT_REFUSED.iter().find(|r| r.0 == key) {
                if self.value(&p.value, scope).is_some_and(|v| v != 0.0) {
                    self.errors.push(ElabError::UnsupportedModel {
                        span: p.name.span,
                        model: def.name.text.to_string(),
                        what: format!("a BJT with {what}"),
                        help: "kausal models ngspice's level-1 BJT without a substrate current or quasi-saturation; remove the parameter (or set it to 0) to simulate without it",
                    });
                    ok = false;
                }
                continue;
            }
            if let Some(&k) = BJT_TEMPERATURE.iter().find(|k| **k == key) {
                match self.value(&p.value, scope) {
                    Some(v) if matches!(k, "tlev" | "tlevc") && !tlev_supported(k, v) => {
                        self.errors.push(ElabError::UnsupportedModel {
                            span: p.value.span(),
                            model: def.name.text.to_string(),
                            what: format!("a BJT with {} = {v}", k.to_ascii_uppercase()),
                            help: "kausal scales BJTs with temperature as ngspice's TLEV 0, 1 and 3 and TLEVC 0 and 1 do",
                        });
                        ok = false;
                    }
                    Some(v) => m.temperature.push((k, v)),
                    None => ok = false,
                }
                continue;
            }
            if self.unread_model_param(p, &key, BJT_PARAMS, BJT_IGNORED, def, first_use) {
                continue;
            }
            let Some(v) = self.value(&p.value, scope) else {
                ok = false;
                continue;
            };
            match key.as_str() {
                "is" => m.is = v,
                "ibe" => m.ibe = Some(v),
                "ibc" => m.ibc = Some(v),
                "bf" => m.bf = v,
                "nf" => m.nf = v,
                "vaf" | "va" => m.vaf = v,
                "ikf" | "ik" => m.ikf = v,
                "ise" | "c2" => m.ise = v,
                "ne" => m.ne = v,
                "br" => m.br = v,
                "nr" => m.nr = v,
                "var" | "vb" => m.var = v,
                "ikr" => m.ikr = v,
                "isc" | "c4" => m.isc = v,
                "nc" => m.nc = v,
                "nkf" => m.nkf = Some(v.min(1.0)),
                "rb" => m.rb = v,
                "irb" => m.irb = v,
                "rbm" => m.rbm = Some(v),
                "re" => m.re = v,
                "rc" => m.rc = v,
                "cje" => m.cje = v,
                "vje" | "pe" => m.vje = v,
                "mje" | "me" => m.mje = v.min(0.999),
                "tf" => m.tf = v,
                "xtf" => m.xtf = v,
                "vtf" => m.vtf = v,
                "itf" => m.itf = v,
                "cjc" => m.cjc = v,
                "vjc" | "pc" => m.vjc = v,
                "mjc" | "mc" => m.mjc = v.min(0.999),
                "xcjc" => m.xcjc = v,
                "tr" => m.tr = v,
                "cjs" | "csub" | "ccs" => m.cjs = v,
                "vjs" | "ps" => m.vjs = v,
                "mjs" | "ms" => m.mjs = v.min(0.999),
                "fc" => m.fc = v.min(0.9999),
                "subs" => m.subs = Some(v),
                "ptf" => m.ptf = v,
                "level" if v != 1.0 => {
                    self.errors.push(ElabError::UnsupportedModel {
                        span: p.value.span(),
                        model: def.name.text.to_string(),
                        what: format!("a level-{v} BJT"),
                        help: "kausal models ngspice's level-1 BJT (Gummel–Poon); VBIC (4), HICUM (8) and MEXTRAM (6) would come as compiled compact models",
                    });
                    ok = false;
                }
                _ => {}
            }
        }
        // ngspice reads ISE and ISC above 1e-4 as multiples of IS.
        if m.ise > 1e-4 {
            m.ise *= m.is;
        }
        if m.isc > 1e-4 {
            m.isc *= m.is;
        }
        let floored = |cj: &mut f64, t: f64| {
            let floor = *cj == 0.0 && t > 0.0;
            if floor {
                *cj = TRANSIT_CAPACITANCE_FLOOR;
            }
            floor
        };
        // As for diodes (`model.rs`): a transit-time charge alone cannot fix
        // a junction's voltage in reverse bias.
        let mut floors = Vec::new();
        if floored(&mut m.cje, m.tf) {
            m.mje = 0.0;
            floors.push(("tf", "TF", "CJE"));
        }
        if floored(&mut m.cjc, m.tr) {
            m.mjc = 0.0;
            m.xcjc = 1.0;
            floors.push(("tr", "TR", "CJC"));
        }
        if first_use {
            for (key, tt, cj) in floors {
                if let Some(p) = def.params.iter().find(|p| p.name.key() == key) {
                    self.errors.push(ElabError::TransitTimeWithoutCapacitance {
                        span: p.name.span,
                        model: def.name.text.to_string(),
                        tt,
                        cj,
                        cap: "10 aF",
                    });
                }
            }
        }
        let m = ok.then_some(m);
        self.bjt_cache.insert(cache_key, m.clone());
        m
    }

    /// Q: the words after the terminals told apart (`[substrate] model
    /// [area]`: the model is the word that names one), the model read, and
    /// the device's branches added to the circuit.
    pub(super) fn bjt(
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
        let text = |w: &Value<'_>| -> Option<(String, crate::diag::Span)> {
            match w {
                Value::Ident(n) => Some((n.text.to_string(), n.span)),
                Value::Num { text, span, .. } => Some((text.to_string(), *span)),
                Value::Expr { .. } => None,
            }
        };
        let names_model = |w: &Value<'_>| {
            text(w).is_some_and(|(k, _)| scope.model(&k.to_ascii_lowercase()).is_some())
        };
        let at = words.iter().take(2).position(names_model);
        let Some(at) = at else {
            // The word that should have named a model: the second of
            // `substrate model`, else the first.
            let guess = match words.as_slice() {
                [] => None,
                [_, second, ..] if !matches!(second, Value::Num { .. }) => text(second),
                [first, ..] => text(first),
            };
            self.errors.push(match guess {
                Some((word, span)) => ElabError::UndefinedModel { span, name: word },
                None => ElabError::BadDevice {
                    span: el.span,
                    element: name.to_string(),
                    why: "no model name after the terminals".into(),
                },
            });
            return;
        };
        let substrate = match at {
            1 => match &words[0] {
                Value::Ident(n) => Some(self.node(n, scope)),
                Value::Num { text, span, .. } => {
                    Some(self.node(&ast::Name { text, span: *span }, scope))
                }
                Value::Expr { span, .. } => {
                    self.errors.push(ElabError::BadDevice {
                        span: *span,
                        element: name.to_string(),
                        why: "the substrate must be a node name".into(),
                    });
                    return;
                }
            },
            _ => None,
        };
        let Some((model_key, model_span)) = text(&words[at]) else {
            return;
        };
        let Some((area, m)) =
            self.device_scale(el, name, &words[at + 1..], params, inherited, scope)
        else {
            return;
        };
        let model_name = ast::Name {
            text: &model_key,
            span: model_span,
        };
        let Some(model) = self.bjt_model(&model_name, name, scope) else {
            return;
        };
        let (model, vt) = self.bjt_at_temperature(&model);
        self.expand_bjt(el, name, nodes, substrate, &model, area, m, vt);
    }

    /// `md` at the circuit's temperature, as ngspice's `bjttemp.c` scales it
    /// from the model's TNOM, and the thermal voltage there; `md` itself at
    /// TNOM.
    fn bjt_at_temperature(&self, md: &BjtModel) -> (BjtModel, f64) {
        let options = &self.circuit.options;
        let tnom = md.given("tnom", options.tnom.unwrap_or(27.0));
        let temp = options.temp.unwrap_or(27.0);
        if temp == tnom {
            return (md.clone(), crate::ir::thermal_voltage(temp));
        }
        let th = Thermal::new(tnom + CELSIUS_K, temp + CELSIUS_K);
        let dt = th.temp - th.tnom;
        // `1 + t1·dt + t2·dt²` of the coefficients `t1`, `t2` named `t…1`, `t…2`.
        let poly = |stem: &str| {
            1.0 + md.given(&format!("t{stem}1"), 0.0) * dt
                + md.given(&format!("t{stem}2"), 0.0) * dt * dt
        };
        let (tlev, tlevc) = (md.given("tlev", 0.0), md.given("tlevc", 0.0));
        let ratio = th.temp / th.tnom;
        let (eg, xti) = (md.given("eg", 1.11), md.given("xti", 3.0));
        let xtb = md.given("xtb", 0.0);
        let bfactor = match tlev {
            0.0 => ratio.powf(xtb),
            1.0 => 1.0 + xtb * dt,
            _ => 1.0,
        };
        // A diode's law over the emission coefficient `n` (TLEV 0, 1); TLEV 3
        // raises the saturation currents to a power instead.
        let saturation = |is: f64, n: f64, stem: &str| match tlev {
            3.0 => is.powf(poly(stem)),
            _ => th.diode_saturation(is, n, eg, xti),
        };
        let beta = |b: f64, stem: &str| {
            let given = ["1", "2"].iter().any(|k| {
                md.temperature
                    .iter()
                    .any(|(g, _)| *g == format!("t{stem}{k}"))
            });
            b * if given { poly(stem) } else { bfactor }
        };
        let (mje, mjc, mjs) = (
            (md.mje * poly("mje")).min(0.999),
            (md.mjc * poly("mjc")).min(0.999),
            (md.mjs * poly("mjs")).min(0.999),
        );
        // A depletion capacitance and its potential: from the band gap
        // (TLEVC 0) or linear coefficients (TLEVC 1).
        let junction = |cj: f64, pb: f64, m: f64, ct: &str, tv: &str| match tlevc {
            1.0 => (
                cj * (1.0 + md.given(ct, 0.0) * dt),
                pb - md.given(tv, 0.0) * dt,
            ),
            _ => (cj * th.capacitance(m, pb), th.potential(pb)),
        };
        let (cje, vje) = junction(md.cje, md.vje, mje, "cte", "tvje");
        let (cjc, vjc) = junction(md.cjc, md.vjc, mjc, "ctc", "tvjc");
        let (cjs, vjs) = junction(md.cjs, md.vjs, mjs, "cts", "tvjs");
        let tf = md.tf * poly("tf");
        let t = BjtModel {
            is: saturation(md.is, 1.0, "is"),
            ibe: md.ibe.map(|i| saturation(i, md.nf, "is")),
            ibc: md.ibc.map(|i| saturation(i, md.nr, "is")),
            // (bfactor is 1 under TLEV 3.)
            ise: saturation(md.ise, md.ne, "ise") / bfactor,
            isc: saturation(md.isc, md.nc, "isc") / bfactor,
            bf: beta(md.bf, "bf"),
            br: beta(md.br, "br"),
            nf: md.nf * poly("nf"),
            nr: md.nr * poly("nr"),
            ne: md.ne * poly("ne"),
            nc: md.nc * poly("nc"),
            vaf: md.vaf * poly("vaf"),
            var: md.var * poly("var"),
            ikf: md.ikf * poly("ikf"),
            ikr: md.ikr * poly("ikr"),
            rb: md.rb * poly("rb"),
            rbm: Some(md.rbm.unwrap_or(md.rb) * poly("rm")),
            irb: md.irb * poly("irb"),
            rc: md.rc * poly("rc"),
            re: md.re * poly("re"),
            itf: md.itf * poly("itf"),
            tf,
            tr: md.tr * poly("tr"),
            // The excess phase's delay is PTF times the model's TF, not
            // TF at temperature.
            ptf: if tf > 0.0 {
                md.ptf * md.tf / tf
            } else {
                md.ptf
            },
            mje,
            mjc,
            mjs,
            cje,
            vje,
            cjc,
            vjc,
            cjs,
            vjs,
            ..md.clone()
        };
        (t, th.vt)
    }

    /// The branches of one transistor (see the module documentation).
    #[allow(clippy::too_many_arguments)]
    fn expand_bjt(
        &mut self,
        el: &ast::Element<'_>,
        name: &str,
        nodes: &[NodeId],
        substrate: Option<NodeId>,
        md: &BjtModel,
        area: f64,
        m: f64,
        vt: f64,
    ) {
        let span = el.span;
        let (c, b, e) = (nodes[0], nodes[1], nodes[2]);
        let s = substrate.unwrap_or(super::GROUND);
        let rbm = md.rbm.unwrap_or(md.rb);
        let cp = self.behind(c, md.rc, name, "c", span);
        let bp = self.behind(b, md.rb, name, "b", span);
        let ep = self.behind(e, md.re, name, "e", span);
        // Branches from `a` to `b` for an NPN, reversed for a PNP.
        let orient = |a, b| oriented(md.pnp, a, b);
        let be_nodes = orient(bp, ep);
        let bc_nodes = orient(bp, cp);
        let ce_nodes = orient(cp, ep);
        let bx_nodes = orient(b, cp).filter(|_| md.cjc * (1.0 - md.xcjc) > 0.0);
        let sub_to = if md.lateral() { bp } else { cp };
        // ngspice's substrate voltage is `type · (v(s) − v(s'))`.
        let cs_nodes = orient(s, sub_to).filter(|_| md.cjs > 0.0);
        // The ids the branches will get, in the order they are pushed.
        let mut ids = NextIds(self.circuit.elements.len() as u32);
        let be_id = ids.take(be_nodes.is_some());
        let bc_id = ids.take(bc_nodes.is_some());
        let _ce = ids.take(ce_nodes.is_some());
        let bx_id = ids.take(bx_nodes.is_some());
        let cs_id = ids.take(cs_nodes.is_some());
        let nonlinear_rb = md.rb > 0.0 && (md.irb > 0.0 || rbm != md.rb);
        let rb_id = ids.take(nonlinear_rb);

        // Junction functions, area applied (ngspice's bjttemp.c: the B-C
        // saturation current is IS·area, again times the base area, which
        // defaults to the area).
        let j0 = self.circuit.junctions.len() as u32;
        let jn = |suffix: &str| format!("{name}.{suffix}");
        let exp_junction = |n: String, is: f64, vte: f64, gmin: f64| DiodeParams {
            name: n,
            is,
            vte,
            bv: None,
            gmin,
            cjo: 0.0,
            vj: 1.0,
            m: 0.5,
            fc: 0.5,
            tt: 0.0,
            fwd: DiodeParams::forward_constants(1.0, 0.5, 0.5),
        };
        let depletion = |n: String, cjo: f64, vj: f64, mj: f64, fc: f64| DiodeParams {
            name: n,
            is: 0.0,
            vte: vt,
            bv: None,
            gmin: 0.0,
            cjo,
            vj,
            m: mj,
            fc,
            tt: 0.0,
            fwd: DiodeParams::forward_constants(vj, mj, fc),
        };
        let (is_be, is_bc) = match (md.ibe, md.ibc) {
            (Some(ibe), Some(ibc)) => (ibe * area, ibc * area),
            _ => (md.is * area, md.is * area * area),
        };
        let js = &mut self.circuit.junctions;
        js.push(exp_junction(jn("be"), is_be, md.nf * vt, 0.0)); // j0
        js.push(exp_junction(jn("ben"), md.ise * area, md.ne * vt, GMIN)); // j0+1
        js.push(exp_junction(jn("bc"), is_bc, md.nr * vt, 0.0)); // j0+2
        js.push(exp_junction(jn("bcn"), md.isc * area, md.nc * vt, GMIN)); // j0+3
        let (czbc, czbx) = (md.cjc * md.xcjc * area, md.cjc * (1.0 - md.xcjc) * area);
        js.push(depletion(jn("be"), md.cje * area, md.vje, md.mje, md.fc)); // j0+4
        js.push(depletion(jn("bc"), czbc, md.vjc, md.mjc, md.fc)); // j0+5
        js.push(depletion(jn("bx"), czbx, md.vjc, md.mjc, md.fc)); // j0+6
        // The substrate charge is ngspice's own: depletion in reverse bias,
        // its tangent's quadratic continuation in forward bias (fc = 0).
        js.push(depletion(jn("cs"), md.cjs * area, md.vjs, md.mjs, 0.0)); // j0+7

        // The expressions, over the branch voltages of `ctl`.
        let g = Gp {
            md,
            area,
            m,
            j0,
            be: be_id,
            bc: bc_id,
        };
        let add = |this: &mut Elab,
                   tag: &str,
                   nodes: Option<[NodeId; 2]>,
                   current: Option<Ex>,
                   charge: Option<Ex>| {
            let controlled = tag == "ce";
            this.push_branch(
                ElementLetter::Q,
                name,
                tag,
                nodes,
                controlled,
                current,
                charge,
                span,
            );
        };
        // be: ibe/BF + iben, and qbe = TF·ibe·(1 + XTF·…)/qb + depletion.
        let be_current = {
            let mut x = Ex::default();
            let vbe = g.vbe(&mut x);
            let ibe = x.junction(j0, DiodePart::Current, vbe);
            let bf = x.num(md.bf);
            let a = x.arith(Arith::Div, ibe, bf);
            let leak = x.junction(j0 + 1, DiodePart::Current, vbe);
            let r = x.arith(Arith::Add, a, leak);
            g.scaled(x, r)
        };
        let be_charge = (md.cje > 0.0 || md.tf > 0.0).then(|| {
            let mut x = Ex::default();
            let vbe = g.vbe(&mut x);
            let dep = x.junction(j0 + 4, DiodePart::Charge, vbe);
            let r = if md.tf > 0.0 {
                let diff = g.transit_charge(&mut x, vbe);
                x.arith(Arith::Add, diff, dep)
            } else {
                dep
            };
            g.scaled(x, r)
        });
        add(self, "be", be_nodes, Some(be_current), be_charge);
        // bc: ibc/BR + ibcn, and qbc = TR·ibc + depletion (share XCJC).
        let bc_current = {
            let mut x = Ex::default();
            let vbc = g.vbc(&mut x);
            let ibc = x.junction(j0 + 2, DiodePart::Current, vbc);
            let br = x.num(md.br);
            let a = x.arith(Arith::Div, ibc, br);
            let leak = x.junction(j0 + 3, DiodePart::Current, vbc);
            let r = x.arith(Arith::Add, a, leak);
            g.scaled(x, r)
        };
        let bc_charge = (czbc > 0.0 || md.tr > 0.0).then(|| {
            let mut x = Ex::default();
            let vbc = g.vbc(&mut x);
            let dep = x.junction(j0 + 5, DiodePart::Charge, vbc);
            let r = if md.tr > 0.0 {
                let ibc = x.junction(j0 + 2, DiodePart::Current, vbc);
                let tr = x.num(md.tr);
                let diff = x.arith(Arith::Mul, tr, ibc);
                x.arith(Arith::Add, diff, dep)
            } else {
                dep
            };
            g.scaled(x, r)
        });
        add(self, "bc", bc_nodes, Some(bc_current), bc_charge);
        // Excess phase (PTF): the forward transport current ibe/qb through
        // the second-order lowpass of Weil's approximation, `td² x″ + 3 td x′
        // + 3 x = 3 ibe/qb` with `td = PTF·TF` (PTF in radians), which
        // ngspice discretizes with its own backward-Euler step. Here it is a
        // network of its own: a source of EXCESS_SCALE·ibe/qb volts, then R,
        // L and C with `RC = td` and `LC = td²/3`; `x` is the capacitor's
        // voltage over EXCESS_SCALE, and at DC it is ibe/qb.
        let td = md.ptf.to_radians() * md.tf;
        let excess = (td > 0.0)
            .then(|| ["xp1", "xp2", "xp3"].map(|tag| self.internal_node(name, tag, span)));
        // ce: the transport current (ibe − ibc)/qb.
        let ce_current = {
            let mut x = Ex::default();
            let vbe = g.vbe(&mut x);
            let vbc = g.vbc(&mut x);
            let ibc = x.junction(j0 + 2, DiodePart::Current, vbc);
            let qb = g.qb(&mut x, vbe, vbc);
            let r = match excess {
                None => {
                    let ibe = x.junction(j0, DiodePart::Current, vbe);
                    let d = x.arith(Arith::Sub, ibe, ibc);
                    x.arith(Arith::Div, d, qb)
                }
                Some([_, _, out]) => {
                    let v = x.push(BNode::Pot(out));
                    let k = x.num(1.0 / EXCESS_SCALE);
                    let fwd = x.arith(Arith::Mul, v, k);
                    let rev = x.arith(Arith::Div, ibc, qb);
                    x.arith(Arith::Sub, fwd, rev)
                }
            };
            g.scaled(x, r)
        };
        add(self, "ce", ce_nodes, Some(ce_current), None);
        // The charges alone: B to C', and the substrate.
        for (tag, nodes, id, k) in [("bx", bx_nodes, bx_id, 6), ("cs", cs_nodes, cs_id, 7)] {
            let Some(id) = id else { continue };
            let mut x = Ex::default();
            let v = x.volt(id);
            let r = x.junction(j0 + k, DiodePart::Charge, v);
            let q = g.scaled(x, r);
            add(self, tag, nodes, None, Some(q));
        }
        // rb: RBM + (RB − RBM)/qb, or with IRB ngspice's current-crowding
        // formula over the base current.
        if let Some(id) = rb_id {
            let mut x = Ex::default();
            let v = x.volt(id);
            let rbb = g.base_resistance(&mut x, rbm);
            let r = x.arith(Arith::Div, v, rbb);
            let i = g.scaled(x, r);
            add(self, "rb", Some([b, bp]), Some(i), None);
        }
        // The constant resistances.
        let resistor = |this: &mut Elab, tag: &str, a: NodeId, z: NodeId, r: f64| {
            if a != z {
                this.circuit.elements.push(Element {
                    name: crate::ir::Name::new(&format!("{name}:{tag}"), Some(span)),
                    kind: ElementKind::Resistor { r: r / (area * m) },
                    nodes: Box::new([a, z]),
                });
            }
        };
        if !nonlinear_rb {
            resistor(self, "rb", b, bp, md.rb);
        }
        resistor(self, "rc", c, cp, md.rc);
        resistor(self, "re", e, ep, md.re);
        if let Some([p1, p2, p3]) = excess {
            let mut x = Ex::default();
            let vbe = g.vbe(&mut x);
            let vbc = g.vbc(&mut x);
            let ibe = x.junction(j0, DiodePart::Current, vbe);
            let qb = g.qb(&mut x, vbe, vbc);
            let u = x.arith(Arith::Div, ibe, qb);
            let k = x.num(EXCESS_SCALE);
            x.arith(Arith::Mul, u, k);
            let mut controls = Vec::new();
            let expr = Box::new(x.finish(&mut controls));
            let r = EXCESS_RESISTANCE;
            for (tag, kind, nodes) in [
                (
                    "xv",
                    ElementKind::Behavioural {
                        current: false,
                        expr,
                        controls,
                    },
                    [p1, super::GROUND],
                ),
                ("xr", ElementKind::Resistor { r }, [p1, p2]),
                (
                    "xl",
                    ElementKind::Inductor {
                        l: td * r / 3.0,
                        ic: None,
                    },
                    [p2, p3],
                ),
                (
                    "xc",
                    ElementKind::Capacitor {
                        c: td / r,
                        ic: None,
                    },
                    [p3, super::GROUND],
                ),
            ] {
                self.circuit.elements.push(Element {
                    name: crate::ir::Name::new(&format!("{name}:{tag}"), Some(span)),
                    kind,
                    nodes: nodes.into(),
                });
            }
        }
    }
}

impl Elab {
    /// A device's area (`rest`: at most one word after the model, or
    /// `area=`) and multiplier (`m=`, times the enclosing instances'
    /// `inherited`); other instance parameters are ignored with a warning.
    /// `None` (reported) for a stray word or an area that is not positive.
    pub(super) fn device_scale(
        &mut self,
        el: &ast::Element<'_>,
        name: &str,
        rest: &[Value<'_>],
        params: &[ast::Assign<'_>],
        inherited: f64,
        scope: &Scope<'_, '_>,
    ) -> Option<(f64, f64)> {
        if let Some(extra) = rest.get(1) {
            self.errors.push(ElabError::BadDevice {
                span: extra.span(),
                element: name.to_string(),
                why: "unexpected word after the area".into(),
            });
            return None;
        }
        let mut area = match rest.first() {
            Some(a) => self.value(a, scope),
            None => Some(1.0),
        };
        let mut m = inherited;
        for p in params {
            if p.name.is("area") {
                area = self.value(&p.value, scope);
            } else if p.name.is("m") {
                m *= self.multiplier(p, name, scope).unwrap_or(f64::NAN);
            } else {
                self.ignored_param(p, name);
            }
        }
        let area = area?;
        if !(area > 0.0 && area.is_finite() && m.is_finite()) {
            self.errors.push(ElabError::BadElementValue {
                span: el.span,
                element: name.to_string(),
                what: "area",
                value: area,
            });
            return None;
        }
        Some((area, m))
    }

    /// `node`, or where a resistance `r` separates the device from it, its
    /// internal node `device#tag`.
    pub(super) fn behind(
        &mut self,
        node: NodeId,
        r: f64,
        device: &str,
        tag: &str,
        span: crate::diag::Span,
    ) -> NodeId {
        if r == 0.0 {
            node
        } else {
            self.internal_node(device, tag, span)
        }
    }

    /// A device's internal node `device#tag` (lower-case; not among the
    /// default output vectors).
    pub(super) fn internal_node(
        &mut self,
        device: &str,
        tag: &str,
        span: crate::diag::Span,
    ) -> NodeId {
        let n = format!("{device}#{tag}").to_ascii_lowercase();
        let id = self.circuit.nodes.push(super::Node {
            name: crate::ir::Name::new(&n, Some(span)),
            internal: true,
        });
        self.node_map.insert(n, id);
        id
    }

    /// A device's branch `device:tag` from `nodes[0]` to `nodes[1]`, its
    /// expressions finished over one list of controls; nothing when the
    /// branch's ends are one node (`None`).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn push_branch(
        &mut self,
        letter: ElementLetter,
        device: &str,
        tag: &str,
        nodes: Option<[NodeId; 2]>,
        controlled: bool,
        current: Option<Ex>,
        charge: Option<Ex>,
        span: crate::diag::Span,
    ) {
        let Some(nodes) = nodes else { return };
        let mut controls = Vec::new();
        let mut fin = |x: Option<Ex>| x.map(|x| Box::new(x.finish(&mut controls)));
        let (current, charge) = (fin(current), fin(charge));
        self.circuit.elements.push(Element {
            name: crate::ir::Name::new(&format!("{device}:{tag}"), Some(span)),
            kind: ElementKind::DeviceBranch {
                device: letter,
                controlled,
                current,
                charge,
                capacitance: None,
                controls,
            },
            nodes: nodes.into(),
        });
    }
}

/// A branch from `a` to `b`, or from `b` to `a` for a device of the other
/// polarity (PNP, P-channel), so that its voltage is ngspice's `type · v`;
/// `None` when both ends are one node (its voltage is then 0).
pub(super) fn oriented(reversed: bool, a: NodeId, b: NodeId) -> Option<[NodeId; 2]> {
    (a != b).then_some(if reversed { [b, a] } else { [a, b] })
}

/// The ids a device's branches will get, in the order they are pushed.
pub(super) struct NextIds(pub(super) u32);

impl NextIds {
    /// The next id if the branch is `present`.
    pub(super) fn take(&mut self, present: bool) -> Option<ElemId> {
        present.then(|| {
            self.0 += 1;
            ElemId(self.0 - 1)
        })
    }
}

/// One expression being built, with the elements whose branch voltages it
/// reads (indices into `controls` once finished).
#[derive(Default)]
pub(super) struct Ex {
    e: BExpr,
    reads: Vec<ElemId>,
}

impl Ex {
    pub(super) fn push(&mut self, n: BNode) -> u32 {
        self.e.nodes.push(n);
        (self.e.nodes.len() - 1) as u32
    }
    pub(super) fn num(&mut self, v: f64) -> u32 {
        self.push(BNode::Num(v))
    }
    pub(super) fn arith(&mut self, op: Arith, a: u32, b: u32) -> u32 {
        self.push(BNode::Arith(op, a, b))
    }
    pub(super) fn junction(&mut self, junction: u32, part: DiodePart, arg: u32) -> u32 {
        self.push(BNode::Junction {
            junction,
            part,
            arg,
        })
    }
    pub(super) fn volt(&mut self, of: ElemId) -> u32 {
        let k = match self.reads.iter().position(|&r| r == of) {
            Some(k) => k,
            None => {
                self.reads.push(of);
                self.reads.len() - 1
            }
        };
        self.push(BNode::Volt(k as u32))
    }
    /// `max(a, 0)`.
    pub(super) fn positive(&mut self, a: u32) -> u32 {
        let zero = self.num(0.0);
        let c = self.push(BNode::Cmp(Cmp::Gt, a, zero));
        self.push(BNode::Select(c, a, zero))
    }
    /// The arena, its `Volt` indices made indices into `controls` (which
    /// gains the elements it reads).
    pub(super) fn finish(mut self, controls: &mut Vec<ElemId>) -> BExpr {
        let map: Vec<u32> = self
            .reads
            .iter()
            .map(|r| match controls.iter().position(|c| c == r) {
                Some(k) => k as u32,
                None => {
                    controls.push(*r);
                    (controls.len() - 1) as u32
                }
            })
            .collect();
        for n in &mut self.e.nodes {
            if let BNode::Volt(k) = n {
                *k = map[*k as usize];
            }
        }
        self.e
    }
}

/// The Gummel–Poon expressions of one device.
struct Gp<'m> {
    md: &'m BjtModel,
    area: f64,
    m: f64,
    j0: u32,
    be: Option<ElemId>,
    bc: Option<ElemId>,
}

impl Gp<'_> {
    fn vbe(&self, x: &mut Ex) -> u32 {
        match self.be {
            Some(id) => x.volt(id),
            None => x.num(0.0),
        }
    }
    fn vbc(&self, x: &mut Ex) -> u32 {
        match self.bc {
            Some(id) => x.volt(id),
            None => x.num(0.0),
        }
    }

    /// `r` times the multiplier `m` (devices in parallel).
    fn scaled(&self, mut x: Ex, r: u32) -> Ex {
        if self.m != 1.0 {
            let m = x.num(self.m);
            x.arith(Arith::Mul, r, m);
        }
        x
    }

    /// The normalized base charge `qb = q1 (1 + √(1 + 4 q2)) / 2`, with
    /// `q1 = 1 / (1 − vbc/VAF − vbe/VAR)` and `q2 = ibe/IKF + ibc/IKR`.
    fn qb(&self, x: &mut Ex, vbe: u32, vbc: u32) -> u32 {
        let md = self.md;
        let mut den = x.num(1.0);
        for (va, v) in [(md.vaf, vbc), (md.var, vbe)] {
            if va != 0.0 {
                let inv = x.num(1.0 / va);
                let t = x.arith(Arith::Mul, inv, v);
                den = x.arith(Arith::Sub, den, t);
            }
        }
        let one = x.num(1.0);
        let q1 = x.arith(Arith::Div, one, den);
        if md.ikf == 0.0 && md.ikr == 0.0 {
            return q1;
        }
        let mut q2 = x.num(0.0);
        for (ik, k) in [(md.ikf, self.j0), (md.ikr, self.j0 + 2)] {
            if ik != 0.0 {
                let v = if k == self.j0 { vbe } else { vbc };
                let i = x.junction(k, DiodePart::Current, v);
                let inv = x.num(1.0 / (ik * self.area));
                let t = x.arith(Arith::Mul, inv, i);
                q2 = x.arith(Arith::Add, q2, t);
            }
        }
        let four = x.num(4.0);
        let t = x.arith(Arith::Mul, four, q2);
        let arg = x.arith(Arith::Add, one, t);
        let arg = x.positive(arg);
        let sq = match md.nkf {
            None => x.push(BNode::Call(Func::Sqrt, arg)),
            Some(nkf) => {
                let p = x.num(nkf);
                x.arith(Arith::Pow, arg, p)
            }
        };
        let s = x.arith(Arith::Add, one, sq);
        let half = x.num(0.5);
        let h = x.arith(Arith::Mul, s, half);
        x.arith(Arith::Mul, q1, h)
    }

    /// `TF · ibe · (1 + XTF · exp(vbc / (1.44 VTF)) · (ibe / (ibe + ITF))²) / qb`.
    fn transit_charge(&self, x: &mut Ex, vbe: u32) -> u32 {
        let md = self.md;
        let ibe = x.junction(self.j0, DiodePart::Current, vbe);
        let vbc = self.vbc(x);
        let mut factor = x.num(1.0);
        if md.xtf != 0.0 {
            let mut arg = x.num(md.xtf);
            if md.vtf != 0.0 {
                let k = x.num(1.0 / (1.44 * md.vtf));
                let t = x.arith(Arith::Mul, vbc, k);
                let e = x.push(BNode::Call(Func::Exp, t));
                arg = x.arith(Arith::Mul, arg, e);
            }
            if md.itf != 0.0 {
                let itf = x.num(md.itf * self.area);
                let den = x.arith(Arith::Add, ibe, itf);
                let r = x.arith(Arith::Div, ibe, den);
                let r2 = x.arith(Arith::Mul, r, r);
                arg = x.arith(Arith::Mul, arg, r2);
            }
            factor = x.arith(Arith::Add, factor, arg);
        }
        let tf = x.num(md.tf);
        let a = x.arith(Arith::Mul, tf, ibe);
        let a = x.arith(Arith::Mul, a, factor);
        let qb = self.qb(x, vbe, vbc);
        x.arith(Arith::Div, a, qb)
    }

    /// The base resistance: `RBM + (RB − RBM)/qb`, or with IRB
    /// `RBM + 3 (RB − RBM) (tan z − z) / (z tan² z)` where
    /// `z = (√(1 + 14.59025 x) − 1) / (2.4317 √x)`, `x = max(ib/IRB, 1e-9)`
    /// (ngspice's bjtload.c, over its DC base current `ib`).
    fn base_resistance(&self, x: &mut Ex, rbm: f64) -> u32 {
        let md = self.md;
        let (rb, rbm) = (md.rb / self.area, rbm / self.area);
        let vbe = self.vbe(x);
        let vbc = self.vbc(x);
        let rbm_n = x.num(rbm);
        let rbpi = x.num(rb - rbm);
        if md.irb == 0.0 {
            let qb = self.qb(x, vbe, vbc);
            let t = x.arith(Arith::Div, rbpi, qb);
            return x.arith(Arith::Add, rbm_n, t);
        }
        let mut ib = x.num(0.0);
        for (k, v, beta) in [(self.j0, vbe, md.bf), (self.j0 + 2, vbc, md.br)] {
            let i = x.junction(k, DiodePart::Current, v);
            let b = x.num(beta);
            let t = x.arith(Arith::Div, i, b);
            let leak = x.junction(k + 1, DiodePart::Current, v);
            let t = x.arith(Arith::Add, t, leak);
            ib = x.arith(Arith::Add, ib, t);
        }
        let irb = x.num(md.irb * self.area);
        let r = x.arith(Arith::Div, ib, irb);
        let floor = x.num(1e-9);
        let c = x.push(BNode::Cmp(Cmp::Gt, r, floor));
        let xr = x.push(BNode::Select(c, r, floor));
        let k = x.num(14.59025);
        let t = x.arith(Arith::Mul, k, xr);
        let one = x.num(1.0);
        let t = x.arith(Arith::Add, one, t);
        let t = x.push(BNode::Call(Func::Sqrt, t));
        let num = x.arith(Arith::Sub, t, one);
        let sx = x.push(BNode::Call(Func::Sqrt, xr));
        let k2 = x.num(2.4317);
        let den = x.arith(Arith::Mul, k2, sx);
        let z = x.arith(Arith::Div, num, den);
        let tz = x.push(BNode::Call(Func::Tan, z));
        let d = x.arith(Arith::Sub, tz, z);
        let three = x.num(3.0);
        let top = x.arith(Arith::Mul, three, rbpi);
        let top = x.arith(Arith::Mul, top, d);
        let bot = x.arith(Arith::Mul, z, tz);
        let bot = x.arith(Arith::Mul, bot, tz);
        let q = x.arith(Arith::Div, top, bot);
        x.arith(Arith::Add, rbm_n, q)
    }
}

/// Whether ngspice's `bjttemp.c` has the temperature law `TLEV = v` (or
/// `TLEVC = v`).
fn tlev_supported(key: &str, v: f64) -> bool {
    match key {
        "tlev" => [0.0, 1.0, 3.0].contains(&v),
        _ => [0.0, 1.0].contains(&v),
    }
}
