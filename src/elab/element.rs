//! Element lines → [`ElementKind`]: values evaluated and checked, `m=`
//! multipliers applied, sources' transient functions made waveforms; one
//! function per element kind. Diode models are read in `model.rs`.

use super::{Elab, ElabError, ElemId, Element, ElementKind, NodeId, Pending, PendingRef, Scope};
use crate::diag::Span;
use crate::front::ast::{self, ElementBody, ElementLetter, TranFnKind, Value};
use crate::ir::Waveform;

impl Elab {
    pub(super) fn element<'s, 'a>(
        &mut self,
        el: &'s ast::Element<'a>,
        scope: &Scope<'s, 'a>,
        stack: &mut Vec<String>,
    ) {
        let mut name = String::with_capacity(scope.prefix.len() + el.name.text.len());
        name.push_str(&scope.prefix);
        name.push_str(el.name.text);
        if stack.is_empty() {
            self.top_line = el.name.span;
        }
        if let ElementBody::Instance { subckt, params } = &el.body {
            self.instance(el, &name, subckt, params, scope, stack);
            return;
        }
        if self.n_flattened >= super::MAX_ELEMENTS {
            self.errors.push(ElabError::TooManyElements {
                span: self.top_line,
                element: name,
                limit: super::MAX_ELEMENTS,
            });
            self.too_many = true;
            return;
        }
        self.n_flattened += 1;
        let key = name.to_ascii_lowercase();
        if let Some(&(_, first)) = self.elem_map.get(&key) {
            self.errors.push(ElabError::DuplicateElement {
                span: el.name.span,
                name,
                first,
            });
            return;
        }
        let nodes: Vec<NodeId> = el.nodes.iter().map(|n| self.node(n, scope)).collect();
        // A transistor's terminals may share a node (a diode-connected BJT).
        let device = matches!(el.body, ElementBody::Device { .. });
        // A resistor, capacitor, inductor or diode with both terminals on one
        // node carries no current, and a current source (I, G, F, B with
        // `I=`) between a node and itself puts none into it: ngspice keeps
        // it, kausal leaves it out.
        let passive = matches!(
            el.body,
            ElementBody::Passive { .. }
                | ElementBody::Diode { .. }
                | ElementBody::Behavioural { current: true, .. }
        ) || matches!(
            el.letter,
            ElementLetter::I | ElementLetter::G | ElementLetter::F
        );
        if passive && nodes.len() >= 2 && nodes[0] == nodes[1] {
            self.errors.push(ElabError::ShortedElement {
                span: el.nodes[0].span.to(el.nodes[1].span),
                name: name.clone(),
                node: self.circuit.nodes[nodes[0]].name.to_string(),
            });
            return;
        }
        if !device && nodes.len() >= 2 && nodes[0] == nodes[1] {
            self.errors.push(ElabError::SingleNode {
                span: el.nodes[0].span.to(el.nodes[1].span),
                name: name.clone(),
                node: self.circuit.nodes[nodes[0]].name.to_string(),
            });
            return;
        }
        if let ElementBody::Device { .. } = &el.body {
            let Some(inherited) = self.inherited_multiplier(el, &name, scope) else {
                return;
            };
            let first = self.circuit.elements.len();
            match el.letter {
                ElementLetter::J => self.jfet(el, &name, &nodes, inherited, scope),
                ElementLetter::M => self.mosfet(el, &name, &nodes, inherited, scope),
                ElementLetter::S | ElementLetter::W => self.switch(el, &name, &nodes, scope),
                _ => self.bjt(el, &name, &nodes, inherited, scope),
            }
            if first < self.circuit.elements.len() {
                self.elem_map
                    .insert(key, (ElemId(first as u32), el.name.span));
            }
            return;
        }
        let letter = el.letter;
        let Some(kind) = self.kind(el, &name, letter, scope) else {
            return;
        };
        let id = self.circuit.elements.push(Element {
            name: crate::ir::Name::new(&name, Some(el.span)),
            kind,
            nodes: nodes.into(),
        });
        self.elem_map.insert(key, (id, el.name.span));
        match &el.body {
            ElementBody::CurrentControlled { vsrc, .. } => self.pending.push(Pending {
                elem: id,
                what: PendingRef::Control {
                    vsrc: format!("{}{}", scope.prefix, vsrc.text).to_ascii_lowercase(),
                    index: 0,
                },
                spans: [vsrc.span, vsrc.span],
            }),
            ElementBody::Behavioural { span, .. } => {
                for (index, vsrc) in std::mem::take(&mut self.b_controls).into_iter().enumerate() {
                    self.pending.push(Pending {
                        elem: id,
                        what: PendingRef::Control { vsrc, index },
                        spans: [*span, *span],
                    });
                }
            }
            ElementBody::Coupling { l1, l2, .. } => self.pending.push(Pending {
                elem: id,
                what: PendingRef::Coupling {
                    l1: format!("{}{}", scope.prefix, l1.text).to_ascii_lowercase(),
                    l2: format!("{}{}", scope.prefix, l2.text).to_ascii_lowercase(),
                },
                spans: [l1.span, l2.span],
            }),
            _ => {}
        }
    }

    /// What the element is, with its values evaluated; `None` (reported)
    /// when a value is missing or out of range. Dispatches on the element's
    /// body, one function per kind.
    fn kind(
        &mut self,
        el: &ast::Element<'_>,
        name: &str,
        letter: ElementLetter,
        scope: &Scope<'_, '_>,
    ) -> Option<ElementKind> {
        let inherited = self.inherited_multiplier(el, name, scope)?;
        match &el.body {
            ElementBody::Passive {
                value,
                model,
                params,
            } => self.passive(
                value,
                model.as_ref(),
                params,
                name,
                letter,
                inherited,
                scope,
            ),
            ElementBody::Coupling { k, .. } => self.coupling(k, name, scope),
            ElementBody::Source { dc, tran, .. } => {
                self.source(dc.as_ref(), tran.as_ref(), name, letter, scope)
            }
            ElementBody::VoltageControlled { gain } => {
                let g = self.value(gain, scope)?;
                Some(if letter == ElementLetter::E {
                    ElementKind::Vcvs { gain: g }
                } else {
                    ElementKind::Vccs { gm: g }
                })
            }
            ElementBody::CurrentControlled { gain, .. } => {
                let g = self.value(gain, scope)?;
                // The controlling source is filled in once every element exists.
                let ctrl = ElemId(u32::MAX);
                Some(if letter == ElementLetter::F {
                    ElementKind::Cccs { gain: g, ctrl }
                } else {
                    ElementKind::Ccvs { r: g, ctrl }
                })
            }
            ElementBody::Diode {
                model,
                area,
                params,
            } => self.diode(model, area.as_ref(), params, name, inherited, scope),
            ElementBody::Behavioural {
                current,
                expr,
                text,
                span,
            } => self.behavioural(*current, expr, text, *span, scope),
            ElementBody::Instance { .. } | ElementBody::Device { .. } => {
                unreachable!("instances and devices are expanded before")
            }
        }
    }

    /// The multiplier of enclosing instances: R, C, L and D scale with it;
    /// a source or controlled source inside cannot be multiplied (`None`,
    /// reported).
    fn inherited_multiplier(
        &mut self,
        el: &ast::Element<'_>,
        name: &str,
        scope: &Scope<'_, '_>,
    ) -> Option<f64> {
        let (inherited, from) = scope.multiplier();
        if let Some(from) = from
            && inherited != 1.0
            && !matches!(
                el.body,
                ElementBody::Passive { .. }
                    | ElementBody::Diode { .. }
                    | ElementBody::Device { .. }
                    | ElementBody::Coupling { .. }
            )
        {
            self.errors.push(ElabError::UnscalableElement {
                span: el.name.span,
                element: name.to_string(),
                instance: from,
            });
            return None;
        }
        Some(inherited)
    }

    /// `v` if it is finite and not zero, else `None` (reported as the
    /// element's `what`).
    fn nonzero(&mut self, v: f64, span: Span, element: &str, what: &'static str) -> Option<f64> {
        if v == 0.0 || !v.is_finite() {
            self.errors.push(ElabError::BadElementValue {
                span,
                element: element.to_string(),
                what,
                value: v,
            });
            None
        } else {
            Some(v)
        }
    }

    /// R, C, L: the value scaled by `m` (that many elements in parallel,
    /// times the enclosing instances' `inherited`), and C's and L's `ic=`.
    #[allow(clippy::too_many_arguments)]
    fn passive(
        &mut self,
        value: &Value<'_>,
        model: Option<&ast::Name<'_>>,
        params: &[ast::Assign<'_>],
        name: &str,
        letter: ElementLetter,
        inherited: f64,
        scope: &Scope<'_, '_>,
    ) -> Option<ElementKind> {
        // A model: named beside the value, or in its place (a name that is
        // a model's, as ngspice takes a value that is no number for a model
        // name).
        let (model, value) = match (model, value) {
            (Some(m), v) => (Some(m), Some(v)),
            (None, Value::Ident(n)) if scope.model(&n.key()).is_some() => (Some(n), None),
            (None, v) => (None, Some(v)),
        };
        // Where a model stands in place of the value, errors point at it.
        let model_span = model.map(|m| m.span);
        let (mut rmodel, mut cmodel, mut lmodel) = (None, None, None);
        match (model, letter) {
            (Some(m), ElementLetter::R) => rmodel = Some(self.resistor_model(m, name, scope)?),
            (Some(m), ElementLetter::C) => cmodel = Some(self.capacitor_model(m, name, scope)?),
            (Some(m), _) => lmodel = Some(self.inductor_model(m, name, scope)?),
            (None, _) => {}
        }
        let mut v = match value {
            Some(value) => Some(self.value(value, scope)?),
            None => None,
        };
        let mut ic = None;
        let mut m = inherited;
        // Temperature: ngspice's `restemp.c`, `captemp.c`, `indtemp.c`.
        let (mut tc1, mut tc2, mut tce, mut temp, mut dtemp, mut scale) =
            (None, None, None, None, 0.0, 1.0);
        let (mut length, mut width, mut turns) = (None, None, None);
        let (r_model, c_model) = (rmodel.is_some(), cmodel.is_some());
        for p in params {
            if p.name.is("ic") && letter != ElementLetter::R {
                ic = Some(self.value(&p.value, scope)?);
            } else if p.name.is("m") {
                m *= self.multiplier(p, name, scope)?;
            } else if p.name.is("tc1") || (p.name.is("tc") && letter == ElementLetter::R) {
                tc1 = Some(self.value(&p.value, scope)?);
            } else if p.name.is("tc2") {
                tc2 = Some(self.value(&p.value, scope)?);
            } else if p.name.is("tce") && letter == ElementLetter::R {
                tce = Some(self.value(&p.value, scope)?);
            } else if p.name.is("temp") {
                temp = Some(self.value(&p.value, scope)?);
            } else if p.name.is("dtemp") {
                dtemp = self.value(&p.value, scope)?;
            } else if p.name.is("scale") {
                scale = self.value(&p.value, scope)?;
            } else if v.is_none()
                && ((r_model && (p.name.is("r") || p.name.is("resistance")))
                    || (c_model
                        && (p.name.is("c") || p.name.is("cap") || p.name.is("capacitance"))))
            {
                // The value given as a parameter beside a model.
                v = Some(self.value(&p.value, scope)?);
            } else if (r_model || c_model) && p.name.is("l") {
                length = Some(self.value(&p.value, scope)?);
            } else if (r_model || c_model) && p.name.is("w") {
                width = Some(self.value(&p.value, scope)?);
            } else if letter == ElementLetter::L && p.name.is("nt") {
                turns = Some(self.value(&p.value, scope)?);
            } else {
                self.ignored_param(p, name);
            }
        }
        // Without a value: a capacitor's model's CAP, else its plates' area
        // and perimeter on the model's CJ and CJSW (ngspice's `captemp.c`;
        // the length defaults to 0, as there); a resistor's geometry on its
        // model's sheet resistance, else the model's value, else 1 mΩ
        // (ngspice's `RESupdate_conduct`); an inductor's turns (its own
        // NT, else its model's) on its model's coil (`indtemp.c`).
        let v = match (v, &rmodel, &cmodel) {
            (Some(v), _, _) => v,
            (None, _, _) if letter == ElementLetter::L => {
                let lm = lmodel.as_ref();
                match turns {
                    Some(nt) => lm.map_or(0.0, |lm| lm.per_turn2) * nt * nt,
                    None => lm.map_or(0.0, |lm| lm.ind),
                }
            }
            (None, _, Some(cm)) => cm.cap.unwrap_or_else(|| {
                let w = width.unwrap_or(cm.defw) - cm.narrow;
                let l = length.unwrap_or(0.0) - cm.short;
                cm.cj * w * l + cm.cjsw * 2.0 * (l + w)
            }),
            (None, rm, None) => {
                let rm = rm.clone().unwrap_or_default();
                let (l, w) = (length.unwrap_or(rm.defl), width.unwrap_or(rm.defw));
                if l * w * rm.rsh > 0.0 {
                    (l - 2.0 * rm.short) / (w - 2.0 * rm.narrow) * rm.rsh
                } else {
                    rm.r.unwrap_or(1e-3)
                }
            }
        };
        // The model's temperature coefficients and TNOM.
        let (m_tc1, m_tc2, m_tce, m_tnom) = match (&rmodel, &cmodel, &lmodel) {
            (Some(r), _, _) => (r.tc1, r.tc2, r.tce, r.tnom),
            (_, Some(c), _) => (c.tc1, c.tc2, None, c.tnom),
            (_, _, Some(l)) => (l.tc1, l.tc2, None, l.tnom),
            _ => (None, None, None, None),
        };
        // The value holds at TNOM (the model's, else the circuit's); at the
        // element's temperature (its own `temp`, else the circuit's plus
        // `dtemp`) it is scaled by `1 + tc1·Δ + tc2·Δ²`, or a resistor's by
        // `1.01^(tce·Δ)` (a resistor's `tc` is its `tc1`; the instance's
        // coefficients before the model's).
        let options = &self.circuit.options;
        let delta = temp.unwrap_or(options.temp.unwrap_or(27.0) + dtemp)
            - m_tnom.or(options.tnom).unwrap_or(27.0);
        let (tc1, tc2) = (tc1.or(m_tc1).unwrap_or(0.0), tc2.or(m_tc2).unwrap_or(0.0));
        let factor = match tce.or(m_tce) {
            Some(tce) => 1.01f64.powf(tce * delta),
            None => 1.0 + (tc1 + tc2 * delta) * delta,
        } * scale;
        let v = v * factor;
        let span = value.map_or(model_span.unwrap_or_default(), |v| v.span());
        Some(match letter {
            ElementLetter::R => ElementKind::Resistor {
                r: self.nonzero(v, span, name, "resistance")? / m,
            },
            ElementLetter::C => {
                let c = self.nonzero(v, span, name, "capacitance")? * m;
                if c < 0.0 {
                    self.errors.push(ElabError::NegativeCapacitance {
                        span,
                        element: name.to_string(),
                        value: c,
                    });
                }
                ElementKind::Capacitor { c, ic }
            }
            _ => ElementKind::Inductor {
                l: self.nonzero(v, span, name, "inductance")? / m,
                ic,
            },
        })
    }

    /// An element parameter kausal does not read (a warning).
    pub(super) fn ignored_param(&mut self, p: &ast::Assign<'_>, element: &str) {
        self.errors.push(ElabError::IgnoredElementParam {
            span: p.name.span,
            name: p.name.text.to_string(),
            element: element.to_string(),
        });
    }

    /// K: the coupling coefficient, in (0, 1].
    fn coupling(
        &mut self,
        k: &Value<'_>,
        name: &str,
        scope: &Scope<'_, '_>,
    ) -> Option<ElementKind> {
        let kv = self.value(k, scope)?;
        if !(kv > 0.0 && kv <= 1.0) {
            self.errors.push(ElabError::CouplingRange {
                span: k.span(),
                element: name.to_string(),
                k: kv,
            });
            return None;
        }
        // The inductors are filled in once every element exists.
        Some(ElementKind::Coupling {
            l1: ElemId(u32::MAX),
            l2: ElemId(u32::MAX),
            k: kv,
        })
    }

    /// V, I: the transient function, else the DC value (0 when absent).
    fn source(
        &mut self,
        dc: Option<&Value<'_>>,
        tran: Option<&ast::TranFn<'_>>,
        name: &str,
        letter: ElementLetter,
        scope: &Scope<'_, '_>,
    ) -> Option<ElementKind> {
        let wave = match tran {
            Some(f) => self.waveform(f, name, scope)?,
            None => Waveform::Dc {
                value: match dc {
                    Some(v) => self.value(v, scope)?,
                    None => 0.0,
                },
            },
        };
        if letter == ElementLetter::V {
            return Some(ElementKind::VSource {
                wave: Box::new(wave),
            });
        }
        // ngspice 39: "for now available only with the voltage source".
        if let Some(f) = tran {
            for (param, v) in [("r", &f.repeat), ("td", &f.delay)] {
                if let Some(v) = v {
                    self.errors.push(ElabError::PwlParamOnCurrent {
                        span: v.span(),
                        name: name.to_string(),
                        param,
                    });
                }
            }
        }
        Some(ElementKind::ISource {
            wave: Box::new(wave),
        })
    }

    /// D: the model, and the area scaled by `m` (junctions in parallel) and
    /// the enclosing instances' `inherited`.
    fn diode(
        &mut self,
        model: &ast::Name<'_>,
        area: Option<&Value<'_>>,
        params: &[ast::Assign<'_>],
        name: &str,
        inherited: f64,
        scope: &Scope<'_, '_>,
    ) -> Option<ElementKind> {
        let mut area = match area {
            Some(a) => self.value(a, scope)?,
            None => 1.0,
        };
        let mut m = inherited;
        for p in params {
            if p.name.is("m") {
                // `m` junctions in parallel: as `m` times the area.
                m *= self.multiplier(p, name, scope)?;
            } else if p.name.is("area") {
                // ngspice's `area=`, the positional area by name.
                area = self.value(&p.value, scope)?;
            } else {
                self.ignored_param(p, name);
            }
        }
        let area = area * m;
        let model = self.diode_model(model, name, scope)?;
        Some(ElementKind::Diode {
            model: Box::new(model),
            area,
        })
    }

    /// The value of an element's `m=` (parallel multiplier): positive and finite.
    pub(super) fn multiplier(
        &mut self,
        p: &ast::Assign<'_>,
        element: &str,
        scope: &Scope<'_, '_>,
    ) -> Option<f64> {
        let m = self.value(&p.value, scope)?;
        if m > 0.0 && m.is_finite() {
            Some(m)
        } else {
            self.errors.push(ElabError::BadElementValue {
                span: p.value.span(),
                element: element.to_string(),
                what: "multiplier m =",
                value: m,
            });
            None
        }
    }

    /// The waveform of a source's transient function: its argument count
    /// checked, zero or absent optional arguments defaulted as ngspice does.
    fn waveform(
        &mut self,
        f: &ast::TranFn<'_>,
        element: &str,
        scope: &Scope<'_, '_>,
    ) -> Option<Waveform> {
        let mut args = Vec::with_capacity(f.args.len());
        for a in &f.args {
            args.push(self.value(a, scope)?);
        }
        let (min, max) = match f.kind {
            TranFnKind::Pulse => (2, 8),
            TranFnKind::Sin => (2, 6),
            TranFnKind::Exp => (2, 6),
            TranFnKind::Pwl => (2, usize::MAX),
            TranFnKind::Sffm => (2, 5),
        };
        if args.len() < min || args.len() > max {
            let want = if max == usize::MAX {
                format!("at least {min}")
            } else {
                format!("{min} to {max}")
            };
            let mut problem = format!("takes {want} values, found {}", args.len());
            if f.kind == TranFnKind::Sffm && args.len() > max {
                // ngspice-39 reads a sixth and seventh as phases, later
                // versions a delay and phases: SPICE3's five mean the same.
                problem.push_str(
                    " (after SPICE3's five, ngspice's versions differ: phases in ngspice-39, a delay and phases later)",
                );
            }
            return self.bad_source_args(f, element, problem);
        }
        // Optional argument k, with 0 or absence meaning `default`.
        let arg = |k: usize, default: f64| match args.get(k) {
            Some(&v) if v != 0.0 => v,
            _ => default,
        };
        let (tstep, tstop) = (self.tstep, self.tstop);
        Some(match f.kind {
            TranFnKind::Pulse => Waveform::Pulse {
                v1: args[0],
                v2: args[1],
                td: args.get(2).copied().unwrap_or(0.0),
                tr: arg(3, tstep),
                tf: arg(4, tstep),
                pw: arg(5, tstop),
                per: arg(6, tstop),
            },
            TranFnKind::Sin => Waveform::Sin {
                vo: args[0],
                va: args[1],
                freq: arg(2, 1.0 / tstop),
                td: args.get(3).copied().unwrap_or(0.0),
                theta: args.get(4).copied().unwrap_or(0.0),
                phase: args.get(5).copied().unwrap_or(0.0),
            },
            TranFnKind::Exp => {
                // ngspice (vsrcload.c) reads a zero or absent TD1 as TSTEP,
                // not 0 as its manual says: the rise starts one step late.
                let td1 = arg(2, tstep);
                Waveform::Exp {
                    v1: args[0],
                    v2: args[1],
                    td1,
                    tau1: arg(3, tstep),
                    td2: arg(4, td1 + tstep),
                    tau2: arg(5, tstep),
                }
            }
            TranFnKind::Pwl => return self.pwl(f, &args, element, scope),
            // ngspice-39's defaults (`vsrcload.c`): FC and FS 1/TSTOP where
            // zero or absent (later versions default them otherwise).
            TranFnKind::Sffm => Waveform::Sffm {
                vo: args[0],
                va: args[1],
                fc: arg(2, 1.0 / tstop),
                mdi: args.get(3).copied().unwrap_or(0.0),
                fs: arg(4, 1.0 / tstop),
            },
        })
    }

    /// A transient function's arguments do not make a waveform (`problem`).
    fn bad_source_args(
        &mut self,
        f: &ast::TranFn<'_>,
        element: &str,
        problem: String,
    ) -> Option<Waveform> {
        self.errors.push(ElabError::BadSourceArgs {
            span: f.span,
            element: element.to_string(),
            kind: f.kind.name(),
            problem,
        });
        None
    }

    /// PWL: time-value pairs in time order, with its `td=` delay and the
    /// time point `r=` it repeats from.
    fn pwl(
        &mut self,
        f: &ast::TranFn<'_>,
        args: &[f64],
        element: &str,
        scope: &Scope<'_, '_>,
    ) -> Option<Waveform> {
        if !args.len().is_multiple_of(2) {
            return self.bad_source_args(
                f,
                element,
                "needs time-value pairs (an even count)".into(),
            );
        }
        let points: Vec<(f64, f64)> = args.chunks(2).map(|c| (c[0], c[1])).collect();
        if points.windows(2).any(|w| w[1].0 < w[0].0) {
            return self.bad_source_args(f, element, "has times that decrease".into());
        }
        let delay = match &f.delay {
            Some(v) => self.value(v, scope)?,
            None => 0.0,
        };
        let repeat = match &f.repeat {
            Some(v) => Some(self.value(v, scope)?),
            None => None,
        };
        if let Some(r) = repeat {
            // ngspice repeats from one of the sequence's own points,
            // and the part repeated must last.
            let last = points[points.len() - 1].0;
            let near = |t: f64| (t - r).abs() <= 1e-12 * last.abs().max(r.abs());
            if !points.iter().any(|p| near(p.0)) || near(last) || r > last {
                self.errors.push(ElabError::BadSourceArgs {
                    span: f.repeat.as_ref().map_or(f.span, |v| v.span()),
                    element: element.to_string(),
                    kind: f.kind.name(),
                    problem: format!(
                        "repeats from r={r:e}, which must be one of its time points before the last ({last:e})"
                    ),
                });
                return None;
            }
        }
        Some(Waveform::Pwl {
            points,
            repeat,
            delay,
        })
    }
}
