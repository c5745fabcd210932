//! S and W: ngspice's voltage- and current-controlled switches (models SW
//! and CSW), a resistance of RON or ROFF by the switch's state. The state is
//! not an equation: the simulator keeps it, changes it where the control
//! crosses a threshold (a state event, located in time), and restarts the
//! integration there.

use super::model::name_word;
use super::{
    Elab, ElabError, Element, ElementKind, NodeId, Pending, PendingRef, Scope, SwitchModel,
};
use crate::front::ast::{self, ElementLetter};

/// Switch-model parameters kausal reads, and those it ignores.
const SW_PARAMS: &[&str] = &["vt", "vh", "it", "ih", "ron", "roff", "sw", "csw"];
const SW_IGNORED: &[&str] = &["kf", "af", "lser"];

impl Elab {
    /// S `n+ n- nc+ nc- model [on|off]`, W `n+ n- vctrl model [on|off]`.
    pub(super) fn switch(
        &mut self,
        el: &ast::Element<'_>,
        name: &str,
        nodes: &[NodeId],
        scope: &Scope<'_, '_>,
    ) {
        let ast::ElementBody::Device { words, params } = &el.body else {
            return;
        };
        let current = el.letter == ElementLetter::W;
        let mut rest = words.iter();
        let vsrc = if current {
            name_word(rest.next())
        } else {
            None
        };
        let model = name_word(rest.next());
        let usage = if current {
            "`Wname n+ n- vcontrol model [on|off]`"
        } else {
            "`Sname n+ n- nc+ nc- model [on|off]`"
        };
        let (Some(model), true) = (model, !current || vsrc.is_some()) else {
            self.errors.push(ElabError::BadDevice {
                span: el.span,
                element: name.to_string(),
                why: format!("no model name: write {usage}"),
            });
            return;
        };
        let mut on = false;
        for w in rest {
            match name_word(Some(w)) {
                Some(n) if n.is("on") => on = true,
                Some(n) if n.is("off") => on = false,
                _ => {
                    self.errors.push(ElabError::BadDevice {
                        span: w.span(),
                        element: name.to_string(),
                        why: format!("unexpected word after the model: write {usage}"),
                    });
                    return;
                }
            }
        }
        for p in params {
            self.ignored_param(p, name);
        }
        if !current
            && let Some(def) = scope.model(&model.key())
            && def.kind.is("vswitch")
            && !def
                .params
                .iter()
                .any(|p| p.name.is("vt") || p.name.is("vh"))
        {
            self.smooth_switch(el, name, nodes, def, scope);
            return;
        }
        let Some(mut sw) = self.switch_model(&model, name, current, scope) else {
            return;
        };
        sw.initially_on = on;
        let id = self.circuit.elements.push(Element {
            name: crate::ir::Name::new(name, Some(el.span)),
            kind: ElementKind::Switch {
                sw: Box::new(sw),
                ctrl: current.then_some(super::ElemId(u32::MAX)),
            },
            nodes: nodes.into(),
        });
        if let Some(vsrc) = vsrc {
            self.pending.push(Pending {
                elem: id,
                what: PendingRef::Control {
                    vsrc: format!("{}{}", scope.prefix, vsrc.text).to_ascii_lowercase(),
                    index: 0,
                },
                spans: [vsrc.span, vsrc.span],
            });
        }
    }

    /// An SW (S) or CSW (W) model: VT/VH or IT/IH, RON (1 Ω) and ROFF
    /// (1/GMIN, 10^12 Ω), as ngspice defaults them.
    fn switch_model(
        &mut self,
        model: &ast::Name<'_>,
        element: &str,
        current: bool,
        scope: &Scope<'_, '_>,
    ) -> Option<SwitchModel> {
        // PSpice's VSWITCH with VT and VH is ngspice's SW (its PSpice mode
        // rewrites the card so); with VON and VOFF it is `smooth_switch`.
        let (kinds, expected): (&[&str], _) = if current {
            (&["csw"], "CSW")
        } else {
            (&["sw", "vswitch"], "SW")
        };
        let (def, _) = self.typed_model(model, element, scope, kinds, expected)?;
        let mut sw = SwitchModel {
            vt: 0.0,
            vh: 0.0,
            ron: 1.0,
            roff: 1e12,
            initially_on: false,
        };
        let first_use = self.switch_seen.insert((def.span.file.0, def.span.start));
        let mut ok = true;
        let (t, h) = if current { ("it", "ih") } else { ("vt", "vh") };
        for p in &def.params {
            let key = p.name.key();
            if self.unread_model_param(p, &key, SW_PARAMS, SW_IGNORED, def, first_use) {
                continue;
            }
            let Some(v) = self.value(&p.value, scope) else {
                ok = false;
                continue;
            };
            match key.as_str() {
                k if k == t => sw.vt = v,
                k if k == h => sw.vh = v,
                "ron" => sw.ron = v,
                "roff" => sw.roff = v,
                _ => {}
            }
        }
        if sw.vh < 0.0 {
            self.errors.push(ElabError::UnsupportedModel {
                span: model.span,
                model: def.name.text.to_string(),
                what: format!("a switch with negative hysteresis ({h} = {})", sw.vh),
                help: "kausal's switches have VH ≥ 0: on above VT + VH, off below VT − VH",
            });
            ok = false;
        }
        for (what, r) in [("RON", sw.ron), ("ROFF", sw.roff)] {
            if !(r > 0.0 && r.is_finite()) {
                self.errors.push(ElabError::BadDevice {
                    span: model.span,
                    element: element.to_string(),
                    why: format!(
                        "model `{}` has {what} = {r}: it must be positive",
                        def.name.text
                    ),
                });
                ok = false;
            }
        }
        ok.then_some(sw)
    }

    /// S with PSpice's VSWITCH model (VON, VOFF, RON, ROFF): no state, a
    /// resistance that moves smoothly from ROFF to RON as the control
    /// voltage goes from VOFF to VON. ngspice's PSpice mode makes it its
    /// `pswitch` code model with `log=TRUE`: with `s` the control's fraction
    /// of the way from VOFF to VON and `m = s − ½` held to [−½, ½],
    /// `ln r = ½·ln(RON·ROFF) + ln(RON/ROFF)·(3m/2 − 2m³)`, a cubic in `m`
    /// whose slope vanishes at both ends; RON at least 1 mΩ, ROFF at most
    /// 1 TΩ, VON and VOFF moved 1 mV apart where they are closer than
    /// 1e-12 V. It is elaborated as a B source's current `v(n+, n-)/r`,
    /// and a 1 TΩ resistor across the control nodes, as `pswitch` has.
    fn smooth_switch(
        &mut self,
        el: &ast::Element<'_>,
        name: &str,
        nodes: &[NodeId],
        def: &ast::Model<'_>,
        scope: &Scope<'_, '_>,
    ) {
        const READ: &[&str] = &["von", "voff", "ron", "roff"];
        let first_use = self.switch_seen.insert((def.span.file.0, def.span.start));
        let (mut von, mut voff, mut ron, mut roff) = (1.0, 0.0, 1.0, 1e6);
        let mut ok = true;
        for p in &def.params {
            let key = p.name.key();
            if self.unread_model_param(p, &key, READ, SW_IGNORED, def, first_use) {
                continue;
            }
            let Some(v) = self.value(&p.value, scope) else {
                ok = false;
                continue;
            };
            match key.as_str() {
                "von" => von = v,
                "voff" => voff = v,
                "ron" => ron = v,
                _ => roff = v,
            }
        }
        for (what, r) in [("RON", ron), ("ROFF", roff)] {
            if !(r > 0.0 && r.is_finite()) {
                self.errors.push(ElabError::BadDevice {
                    span: def.name.span,
                    element: name.to_string(),
                    why: format!(
                        "model `{}` has {what} = {r}: it must be positive",
                        def.name.text
                    ),
                });
                ok = false;
            }
        }
        if !ok || el.nodes.len() < 4 {
            return;
        }
        let (ron, roff) = (ron.max(1e-3), roff.min(1e12));
        if (von - voff).abs() < 1e-12 {
            von += 1e-3;
            voff -= 1e-3;
        }
        use crate::front::expr::{BinOp, PExpr};
        let num = PExpr::Num;
        let bin = |op, a, b| PExpr::Bin(op, Box::new(a), Box::new(b));
        let call = |f: &str, args: Vec<PExpr>| PExpr::Call(f.to_string(), args);
        let volt = |a: &ast::Name<'_>, b: &ast::Name<'_>| PExpr::Probe {
            current: false,
            args: vec![a.text.to_string(), b.text.to_string()],
        };
        // m = min(max((v(c+, c-) − VOFF)/(VON − VOFF) − ½, −½), ½)
        let s = bin(
            BinOp::Div,
            bin(BinOp::Sub, volt(&el.nodes[2], &el.nodes[3]), num(voff)),
            num(von - voff),
        );
        let m = call(
            "min",
            vec![
                call("max", vec![bin(BinOp::Sub, s, num(0.5)), num(-0.5)]),
                num(0.5),
            ],
        );
        let l = (ron / roff).ln();
        let cubic = bin(
            BinOp::Sub,
            bin(BinOp::Mul, num(1.5 * l), m.clone()),
            bin(
                BinOp::Mul,
                num(2.0 * l),
                bin(BinOp::Mul, m.clone(), bin(BinOp::Mul, m.clone(), m)),
            ),
        );
        let ln_r = bin(BinOp::Add, num(0.5 * (ron * roff).ln()), cubic);
        let current = bin(
            BinOp::Mul,
            volt(&el.nodes[0], &el.nodes[1]),
            call("exp", vec![PExpr::Neg(Box::new(ln_r))]),
        );
        let text = format!("{name}: VSWITCH `{}`", def.name.text);
        if let Some(kind) = self.behavioural(true, &current, &text, el.span, scope) {
            self.b_controls.clear();
            self.circuit.elements.push(Element {
                name: crate::ir::Name::new(name, Some(el.span)),
                kind,
                nodes: nodes[..2].into(),
            });
            // `pswitch`'s control input is a 1 TΩ resistance (`r_cntl_in`):
            // picoamperes that a supply's current shows.
            if nodes[2] != nodes[3] {
                self.circuit.elements.push(Element {
                    name: crate::ir::Name::new(&format!("{name}:ctrl"), Some(el.span)),
                    kind: ElementKind::Resistor { r: 1e12 },
                    nodes: nodes[2..4].into(),
                });
            }
        }
    }
}
