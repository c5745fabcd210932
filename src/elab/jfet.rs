//! J: ngspice's JFET level 1 (Shichman–Hodges with the University of
//! Sydney's doping-profile parameter B, as ngspice's jfetload.c computes it)
//! at the circuit's temperature (`jfettemp.c`), elaborated into branches as
//! a BJT is (`bjt.rs`):
//!
//! ```text
//!  D ─rd─ D' ─┬─ gd: igd(vgd) + d(qgd)/dt ─┬─ G
//!             ├─ ds: id(vgs, vgd)         │
//!  S ─rs─ S' ─┴─ gs: igs(vgs) + d(qgs)/dt ─┘
//! ```
//!
//! The gate junctions and their depletion charges (grading ½) are the
//! diode's device functions; the drain current is written out as
//! expressions over both gate voltages, its regions as choices. A P-channel
//! device's branches point the other way.

use super::bjt::{Ex, NextIds, oriented};
use super::thermal::{CELSIUS_K, Thermal};
use super::{Arith, BNode, Elab, ElabError, ElemId, Element, ElementKind, NodeId, Scope};
use crate::front::ast::{self, ElementLetter};
use crate::ir::{Cmp, DiodeParams, DiodePart};

/// ngspice's GMIN, in parallel with each gate junction.
const GMIN: f64 = 1e-12;

/// The model card's values (ngspice's defaults).
#[derive(Clone, Debug, PartialEq)]
pub(super) struct JfetModel {
    pchannel: bool,
    vto: f64,
    beta: f64,
    lambda: f64,
    rd: f64,
    rs: f64,
    cgs: f64,
    cgd: f64,
    pb: f64,
    is: f64,
    n: f64,
    fc: f64,
    b: f64,
    /// The temperature law (`jfettemp.c`): TNOM (°C), the threshold's
    /// (TCV, or VTOTC when given) and β's (BEX, or BETATCE when given)
    /// coefficients, the gate junction's EG and XTI.
    tnom: Option<f64>,
    tcv: f64,
    vtotc: Option<f64>,
    bex: f64,
    betatce: Option<f64>,
    eg: f64,
    xti: Option<f64>,
    /// `(1 − B)/(PB − VTO)` at TNOM (ngspice keeps it per model).
    bfac: f64,
}

/// JFET level-1 parameters kausal models.
const JFET_PARAMS: &[&str] = &[
    "vto", "vt0", "beta", "lambda", "rd", "rs", "cgs", "cgd", "pb", "is", "n", "fc", "b", "level",
    "njf", "pjf", "tnom", "tcv", "vtotc", "bex", "betatce", "xti", "eg",
];
/// Parameters that do not change the transient result (noise).
const JFET_IGNORED: &[&str] = &["kf", "af", "nlev", "gdsnoi", "m"];

impl Elab {
    fn jfet_model(
        &mut self,
        model: &ast::Name<'_>,
        element: &str,
        scope: &Scope<'_, '_>,
    ) -> Option<JfetModel> {
        let (def, kind) = self.typed_model(model, element, scope, &["njf", "pjf"], "NJF or PJF")?;
        let pchannel = kind == 1;
        let first_use = self.jfet_seen.insert((def.span.file.0, def.span.start));
        let mut m = JfetModel {
            pchannel,
            vto: -2.0,
            beta: 1e-4,
            lambda: 0.0,
            rd: 0.0,
            rs: 0.0,
            cgs: 0.0,
            cgd: 0.0,
            pb: 1.0,
            is: 1e-14,
            n: 1.0,
            fc: 0.5,
            b: 1.0,
            tnom: None,
            tcv: 0.0,
            vtotc: None,
            bex: 0.0,
            betatce: None,
            eg: 1.11,
            xti: None,
            bfac: 0.0,
        };
        let mut ok = true;
        for p in &def.params {
            let key = p.name.key();
            if self.unread_model_param(p, &key, JFET_PARAMS, JFET_IGNORED, def, first_use) {
                continue;
            }
            let Some(v) = self.value(&p.value, scope) else {
                ok = false;
                continue;
            };
            match key.as_str() {
                "vto" | "vt0" => m.vto = v,
                "beta" => m.beta = v,
                "lambda" => m.lambda = v,
                "rd" => m.rd = v,
                "rs" => m.rs = v,
                "cgs" => m.cgs = v,
                "cgd" => m.cgd = v,
                "pb" => m.pb = v,
                "is" => m.is = v,
                "n" => m.n = v,
                "fc" => m.fc = v.min(0.95),
                "b" => m.b = v,
                "tnom" => m.tnom = Some(v),
                "tcv" => m.tcv = v,
                "vtotc" => m.vtotc = Some(v),
                "bex" => m.bex = v,
                "betatce" => m.betatce = Some(v),
                "eg" => m.eg = v,
                "xti" => m.xti = Some(v),
                "level" if v != 1.0 => {
                    self.errors.push(ElabError::UnsupportedModel {
                        span: p.value.span(),
                        model: def.name.text.to_string(),
                        what: format!("a level-{v} JFET"),
                        help: "kausal models ngspice's level-1 JFET; the Parker–Skellern model (level 2) would come as a compiled compact model",
                    });
                    ok = false;
                }
                _ => {}
            }
        }
        m.bfac = (1.0 - m.b) / (m.pb - m.vto);
        ok.then_some(m)
    }

    /// `md` at the circuit's temperature, as ngspice's `jfettemp.c` scales
    /// it from TNOM: the gate junction's saturation current (EG, XTI),
    /// potential and capacitances, the threshold and β; and the thermal
    /// voltage there.
    fn jfet_at_temperature(&self, md: &JfetModel) -> (JfetModel, f64) {
        let options = &self.circuit.options;
        let th = Thermal::new(
            md.tnom.or(options.tnom).unwrap_or(27.0) + CELSIUS_K,
            options.temp.unwrap_or(27.0) + CELSIUS_K,
        );
        let dt = th.temp - th.tnom;
        let ratio = th.temp / th.tnom;
        let cap = th.capacitance(0.5, md.pb);
        let t = JfetModel {
            is: md.is
                * ((ratio - 1.0) * md.eg / (md.n * th.vt)).exp()
                * md.xti.map_or(1.0, |x| ratio.powf(x)),
            cgs: md.cgs * cap,
            cgd: md.cgd * cap,
            pb: th.potential(md.pb),
            vto: match md.vtotc {
                Some(c) => md.vto + c * dt,
                None => md.vto - md.tcv * dt,
            },
            beta: match md.betatce {
                Some(c) => md.beta * 1.01f64.powf(c * dt),
                None => md.beta * ratio.powf(md.bex),
            },
            ..md.clone()
        };
        (t, th.vt)
    }

    /// J: `model [area]` after the terminals, the model read, and the
    /// device's branches added to the circuit.
    pub(super) fn jfet(
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
                why: "no model name after the terminals (`Jname drain gate source model [area]`)"
                    .into(),
            });
            return;
        };
        let Some((area, m)) = self.device_scale(el, name, &words[1..], params, inherited, scope)
        else {
            return;
        };
        let Some(model) = self.jfet_model(&model_name, name, scope) else {
            return;
        };
        let (model, vt) = self.jfet_at_temperature(&model);
        self.expand_jfet(el, name, nodes, &model, area * m, vt);
    }

    /// The branches of one JFET (see the module documentation); `scale` is
    /// the area times the multiplier (ngspice scales every current, charge
    /// and conductance by both).
    fn expand_jfet(
        &mut self,
        el: &ast::Element<'_>,
        name: &str,
        nodes: &[NodeId],
        md: &JfetModel,
        scale: f64,
        vt: f64,
    ) {
        let span = el.span;
        let (d, g, s) = (nodes[0], nodes[1], nodes[2]);
        let dp = self.behind(d, md.rd, name, "d", span);
        let sp = self.behind(s, md.rs, name, "s", span);
        let gs_nodes = oriented(md.pchannel, g, sp);
        let gd_nodes = oriented(md.pchannel, g, dp);
        let ds_nodes = oriented(md.pchannel, dp, sp);
        let mut ids = NextIds(self.circuit.elements.len() as u32);
        let gs_id = ids.take(gs_nodes.is_some());
        let gd_id = ids.take(gd_nodes.is_some());

        let j0 = self.circuit.junctions.len() as u32;
        let junction = |suffix: &str, cj: f64| DiodeParams {
            name: format!("{name}.{suffix}"),
            is: md.is * scale,
            vte: md.n * vt,
            bv: None,
            gmin: GMIN,
            cjo: cj * scale,
            vj: md.pb,
            m: 0.5,
            fc: md.fc,
            tt: 0.0,
            fwd: DiodeParams::forward_constants(md.pb, 0.5, md.fc),
        };
        self.circuit.junctions.push(junction("gs", md.cgs)); // j0
        self.circuit.junctions.push(junction("gd", md.cgd)); // j0+1

        let volt = |x: &mut Ex, id: Option<ElemId>| match id {
            Some(id) => x.volt(id),
            None => x.num(0.0),
        };
        let add = |this: &mut Elab,
                   tag: &str,
                   nodes: Option<[NodeId; 2]>,
                   controlled: bool,
                   current: Ex,
                   charge: Option<Ex>| {
            let letter = ElementLetter::J;
            this.push_branch(
                letter,
                name,
                tag,
                nodes,
                controlled,
                Some(current),
                charge,
                span,
            );
        };
        // The gate junctions: current and depletion charge.
        for (tag, nodes, id, k, cj) in [
            ("gs", gs_nodes, gs_id, j0, md.cgs),
            ("gd", gd_nodes, gd_id, j0 + 1, md.cgd),
        ] {
            let mut x = Ex::default();
            let v = volt(&mut x, id);
            x.junction(k, DiodePart::Current, v);
            let q = (cj > 0.0).then(|| {
                let mut q = Ex::default();
                let v = volt(&mut q, id);
                q.junction(k, DiodePart::Charge, v);
                q
            });
            add(self, tag, nodes, false, x, q);
        }
        // ds: the drain current over vgs and vgd.
        let mut x = Ex::default();
        let vgs = volt(&mut x, gs_id);
        let vgd = volt(&mut x, gd_id);
        drain_current(&mut x, md, scale, vgs, vgd);
        add(self, "ds", ds_nodes, true, x, None);
        // The terminal resistances (ngspice scales their conductance by the
        // area and the multiplier).
        for (tag, a, z, r) in [("rd", d, dp, md.rd), ("rs", s, sp, md.rs)] {
            if a != z {
                self.circuit.elements.push(Element {
                    name: crate::ir::Name::new(&format!("{name}:{tag}"), Some(span)),
                    kind: ElementKind::Resistor { r: r / scale },
                    nodes: Box::new([a, z]),
                });
            }
        }
    }
}

/// The drain current of ngspice's level-1 JFET into `x` (its root): with
/// `vds = vgs − vgd`, the normal mode (`vds ≥ 0`) over `vgst = vgs − VTO`,
/// the inverse mode over `vgdt = vgd − VTO`; each zero below threshold,
/// `β (1 ± λ vds)` times a cubic in the linear region and
/// `v² (B + Bfac·v)` in saturation, `Bfac = (1 − B)/(PB − VTO)`.
fn drain_current(x: &mut Ex, md: &JfetModel, scale: f64, vgs: u32, vgd: u32) {
    let beta = md.beta * scale;
    let bfac = md.bfac;
    let vds = x.arith(Arith::Sub, vgs, vgd);
    let zero = x.num(0.0);
    let vto = x.num(md.vto);
    let b = x.num(md.b);
    let bf = x.num(bfac);
    let two_b = x.num(2.0 * md.b);
    let three_bf = x.num(3.0 * bfac);
    let one = x.num(1.0);
    let lambda_vds = {
        let l = x.num(md.lambda);
        x.arith(Arith::Mul, l, vds)
    };
    // Saturation: v² (B + Bfac v).
    let sat = |x: &mut Ex, v: u32| {
        let t = x.arith(Arith::Mul, bf, v);
        let t = x.arith(Arith::Add, b, t);
        let v2 = x.arith(Arith::Mul, v, v);
        x.arith(Arith::Mul, v2, t)
    };
    // Normal mode.
    let vgst = x.arith(Arith::Sub, vgs, vto);
    let betap_n = {
        let t = x.arith(Arith::Add, one, lambda_vds);
        let bn = x.num(beta);
        x.arith(Arith::Mul, bn, t)
    };
    // The linear region's cubic `d (d (Bfac d − B) + v (2B + 3 Bfac (v − d)))`
    // of the gate overdrive `v` and the drain-source voltage `d` seen from
    // the source (the normal mode's `vds`, the inverse mode's `−vds`).
    let cubic = |x: &mut Ex, v: u32, d: u32| {
        let t = x.arith(Arith::Sub, v, d);
        let t = x.arith(Arith::Mul, three_bf, t);
        let apart = x.arith(Arith::Add, two_b, t);
        let t = x.arith(Arith::Mul, bf, d);
        let t = x.arith(Arith::Sub, t, b);
        let t = x.arith(Arith::Mul, d, t);
        let u = x.arith(Arith::Mul, v, apart);
        let t = x.arith(Arith::Add, t, u);
        x.arith(Arith::Mul, d, t)
    };
    let lin_n = cubic(x, vgst, vds);
    let sat_n = sat(x, vgst);
    let c = x.push(BNode::Cmp(Cmp::Ge, vgst, vds));
    let cpart_n = x.push(BNode::Select(c, lin_n, sat_n));
    let on_n = x.arith(Arith::Mul, betap_n, cpart_n);
    let c = x.push(BNode::Cmp(Cmp::Le, vgst, zero));
    let normal = x.push(BNode::Select(c, zero, on_n));
    // Inverse mode.
    let vgdt = x.arith(Arith::Sub, vgd, vto);
    let betap_i = {
        let t = x.arith(Arith::Sub, one, lambda_vds);
        let bn = x.num(beta);
        x.arith(Arith::Mul, bn, t)
    };
    let s = x.arith(Arith::Add, vgdt, vds);
    let lin_i = {
        // ngspice's `vds (vds (Bfac vds + B) + vgdt (2B + 3 Bfac (vgdt + vds)))`,
        // the normal mode's cubic seen from the drain, negated.
        let sd = x.push(BNode::Neg(vds));
        let c = cubic(x, vgdt, sd);
        let cpart = x.push(BNode::Neg(c));
        x.arith(Arith::Mul, betap_i, cpart)
    };
    let sat_i = {
        let cpart = sat(x, vgdt);
        let t = x.arith(Arith::Mul, betap_i, cpart);
        x.push(BNode::Neg(t))
    };
    let c = x.push(BNode::Cmp(Cmp::Ge, s, zero));
    let on_i = x.push(BNode::Select(c, lin_i, sat_i));
    let c = x.push(BNode::Cmp(Cmp::Le, vgdt, zero));
    let inverse = x.push(BNode::Select(c, zero, on_i));
    let c = x.push(BNode::Cmp(Cmp::Ge, vds, zero));
    x.push(BNode::Select(c, normal, inverse));
}
