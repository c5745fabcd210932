//! Seed 003's steps 1–7: the circuit's elements as bond-graph ports, a
//! 0-junction for every node potential, and for every potential difference an
//! element needs a 1-junction with a 0-junction on it (the difference's
//! effort), the element attached to that 0-junction. Rule 8d (equal
//! differences are one) is applied here, as each element asks for its
//! difference; the other rules are `simplify.rs`'s.
//!
//! Orientation: a difference is taken from the element's first node to its
//! second, or towards ground when ground is its first; a passive port's
//! half-arrow points into the element, a source's out of it. The signs that
//! relate each bond's effort and flow to the element's `u_X` and `i_X`
//! (ngspice's: `u` from the first node to the second, `i` entering the first)
//! are recorded in the port's [`PortNames`].

use std::collections::HashMap;

use super::{
    Atom, Bond, BondGraph, BondId, ElementPorts, FieldLaw, Law, Lin, Note, Origin, Part, PortNames,
    Power, Rule, Signal, Simplification, SingularField, StateKey, StateKind, Var, Vertex, VertexId,
    VertexKind,
};
use crate::elab::{BNode, Circuit, ElemId, ElementKind, GROUND, NodeId};

/// Two controlled sources drawn as one two-port.
#[derive(Clone, Copy, Debug)]
struct Pair {
    kind: VertexKind,
    /// Port 1's element (F of a transformer, the first G of a gyrator).
    first: ElemId,
    /// Port 2's element (E, the second G).
    second: ElemId,
    /// How port 1's control reads port 2's nodes (or the other way): ±1.
    c1: i32,
}

struct Builder<'c> {
    c: &'c Circuit,
    g: BondGraph,
    node_junction: Vec<VertexId>,
    /// The 0-junction of each difference, and the element that made it.
    diffs: HashMap<(NodeId, NodeId), (VertexId, ElemId)>,
    pairs: Vec<Pair>,
    pair_of: HashMap<ElemId, usize>,
    /// Coupled inductors: the members of each field, its K elements.
    fields: Vec<(Vec<ElemId>, Vec<ElemId>)>,
    field_of: HashMap<ElemId, usize>,
}

/// Steps 1–7 (and 8d) on `c`.
pub(super) fn build(c: &Circuit) -> BondGraph {
    let mut b = Builder {
        c,
        g: BondGraph {
            title: c.title.clone(),
            vertices: Default::default(),
            bonds: Default::default(),
            simplified: Vec::new(),
            notes: Vec::new(),
            element_names: c.elements.values().map(|e| e.name.to_string()).collect(),
            node_names: c
                .nodes
                .iter()
                .map(|(id, n)| {
                    if id == GROUND {
                        "0".to_string()
                    } else {
                        n.name.to_string()
                    }
                })
                .collect(),
            elements: vec![ElementPorts::default(); c.elements.len()],
            element_spans: c.elements.values().map(|e| e.span()).collect(),
            witness: Vec::new(),
            forward: HashMap::new(),
        },
        node_junction: Vec::with_capacity(c.nodes.len()),
        diffs: HashMap::new(),
        pairs: Vec::new(),
        pair_of: HashMap::new(),
        fields: Vec::new(),
        field_of: HashMap::new(),
    };
    b.find_pairs();
    b.find_fields();
    // Step 5: a 0-junction per node potential, the reference's included
    // (rule 8a drops it).
    for (id, _) in c.nodes.iter() {
        let label = b.g.node_names[id.0 as usize].clone();
        let v = b.vertex(
            VertexKind::Zero,
            label.clone(),
            Origin::Node(id),
            Law::Junction,
        );
        b.g.vertices[v].name = Some((format!("v({label})"), 1));
        b.node_junction.push(v);
    }
    // Steps 1, 3, 6, 7: the elements, their differences, their ports.
    for (id, _) in c.elements.iter() {
        b.element(id);
    }
    b.g.witness = c
        .nodes
        .ids()
        .map(|n| {
            let j = b.node_junction[n.0 as usize];
            (n != GROUND)
                .then(|| b.g.vertices[j].bonds.first().copied())
                .flatten()
        })
        .collect();
    for (n, w) in b.g.witness.iter().enumerate() {
        if n != GROUND.0 as usize && w.is_none() {
            let name = &b.g.node_names[n];
            b.g.notes.push(Note {
                elem: None,
                text: format!(
                    "node {name} carries no element's current (a control input only): its 0-junction has no bond, and v({name}) is not a quantity of the graph"
                ),
            });
        }
    }
    b.g
}

/// A control node of `e` (E, G, S: the third and fourth), ground if absent.
fn control(e: &crate::elab::Element, k: usize) -> NodeId {
    e.nodes.get(k).copied().unwrap_or(GROUND)
}

fn atom(bond: BondId, var: Var) -> Atom {
    Atom { bond, var }
}

impl Builder<'_> {
    fn vertex(&mut self, kind: VertexKind, label: String, origin: Origin, law: Law) -> VertexId {
        self.g.vertices.push(Vertex {
            kind,
            label,
            origin,
            bonds: Vec::new(),
            ports: Vec::new(),
            states: Vec::new(),
            law,
            signals: Vec::new(),
            name: None,
            removed: false,
        })
    }

    fn element_vertex(&mut self, kind: VertexKind, elem: ElemId, part: Part, law: Law) -> VertexId {
        let name = &self.c.elements[elem].name;
        let label = match part {
            Part::Series => format!("{name}.rs"),
            _ => name.to_string(),
        };
        let v = self.vertex(kind, label, Origin::Element { elem, part }, law);
        self.g.elements[elem.0 as usize].vertices.push(v);
        v
    }

    fn bond(&mut self, tail: VertexId, head: VertexId) -> BondId {
        let b = self.g.bonds.push(Bond {
            tail,
            head,
            removed: false,
        });
        self.g.vertices[tail].bonds.push(b);
        self.g.vertices[head].bonds.push(b);
        b
    }

    /// The 0-junction holding `v(a) − v(b)`: made with its 1-junction on
    /// first use (arrows as `power` asks), reused after (rule 8d).
    fn difference(&mut self, a: NodeId, b: NodeId, power: Power, elem: ElemId) -> VertexId {
        if let Some(&(z, first)) = self.diffs.get(&(a, b)) {
            if first != elem {
                self.g.simplified.push(Simplification {
                    rule: Rule::D,
                    vertex: z,
                    bond: None,
                    into: None,
                    elem: Some(elem),
                    dropped: Vec::new(),
                    joins: None,
                });
            }
            return z;
        }
        let label = format!(
            "{},{}",
            self.g.node_names[a.0 as usize], self.g.node_names[b.0 as usize]
        );
        let one = self.vertex(
            VertexKind::One,
            label.clone(),
            Origin::Difference(a, b),
            Law::Junction,
        );
        let zero = self.vertex(
            VertexKind::Zero,
            label.clone(),
            Origin::Difference(a, b),
            Law::Junction,
        );
        self.g.vertices[zero].name = Some((format!("v({label})"), 1));
        self.g.vertices[one].name = Some((format!("i({label})"), 1));
        let (za, zb) = (
            self.node_junction[a.0 as usize],
            self.node_junction[b.0 as usize],
        );
        // e(a) = e(b) + e(a,b): power from a through the difference to b
        // (passive) or from b to a (a source's).
        match power {
            Power::In => {
                self.bond(za, one);
                self.bond(one, zb);
                self.bond(one, zero);
            }
            Power::Out => {
                self.bond(one, za);
                self.bond(zb, one);
                self.bond(zero, one);
            }
        }
        self.diffs.insert((a, b), (zero, elem));
        zero
    }

    /// Attach port `v` of `elem` across the element's first two nodes:
    /// returns the bond and the signs of `u` and `i` in its effort and flow.
    fn attach(
        &mut self,
        elem: ElemId,
        nodes: (NodeId, NodeId),
        power: Power,
        v: VertexId,
        names: (&str, &str),
    ) -> Option<(BondId, i8, i8)> {
        let (p, n) = nodes;
        if p == n {
            self.g.notes.push(Note {
                elem: Some(elem),
                text: format!(
                    "{} has both terminals on one node: its port has no bond",
                    self.c.elements[elem].name
                ),
            });
            return None;
        }
        let (a, b) = if p == GROUND { (n, p) } else { (p, n) };
        // v(b) − v(a) is the difference v(a) − v(b) with its sign turned.
        let (a, b) = if !self.diffs.contains_key(&(a, b)) && self.diffs.contains_key(&(b, a)) {
            (b, a)
        } else {
            (a, b)
        };
        let se: i8 = if (a, b) == (p, n) { 1 } else { -1 };
        let sf = match power {
            Power::In => se,
            Power::Out => -se,
        };
        let z = self.difference(a, b, power, elem);
        let bond = match power {
            Power::In => self.bond(z, v),
            Power::Out => self.bond(v, z),
        };
        if !self.g.vertices[v].kind.is_junction() {
            self.g.vertices[v].ports.push(PortNames {
                effort: names.0.to_string(),
                flow: names.1.to_string(),
                effort_sign: se,
                flow_sign: sf,
            });
        }
        Some((bond, se, sf))
    }

    /// Record `elem`'s voltage and current as a port's effort and flow.
    fn record(&mut self, elem: ElemId, port: Option<(BondId, i8, i8)>) {
        if let Some((b, se, sf)) = port {
            let ep = &mut self.g.elements[elem.0 as usize];
            ep.voltage = vec![(se as i32, atom(b, Var::Effort))];
            ep.current = vec![(sf as i32, atom(b, Var::Flow))];
        }
    }

    fn names(&self, elem: ElemId) -> (String, String) {
        let n = &self.c.elements[elem].name;
        (format!("u_{n}"), format!("i_{n}"))
    }

    fn ends(&self, elem: ElemId) -> (NodeId, NodeId) {
        let e = &self.c.elements[elem];
        // Elaboration gives every element with a port two nodes; a missing
        // one reads as ground (and a port on one node gets no bond).
        let node = |k: usize| e.nodes.get(k).copied().unwrap_or(GROUND);
        (node(0), node(1))
    }

    /// A one-port element across its first two nodes.
    fn one_port(
        &mut self,
        elem: ElemId,
        kind: VertexKind,
        law: Law,
        power: Power,
        state: Option<StateKind>,
    ) -> VertexId {
        let v = self.element_vertex(kind, elem, Part::Whole, law);
        let (u, i) = self.names(elem);
        let port = self.attach(elem, self.ends(elem), power, v, (&u, &i));
        if port.is_some() {
            self.g.vertices[v]
                .states
                .push(state.map(|kind| StateKey { elem, kind }));
        }
        self.record(elem, port);
        v
    }

    fn element(&mut self, id: ElemId) {
        let e = &self.c.elements[id];
        let name = e.name.to_string();
        let linear = |value: f64| Law::Linear {
            param: name.clone(),
            value,
            negated: false,
        };
        match &e.kind {
            ElementKind::Resistor { r } => {
                self.one_port(id, VertexKind::R, linear(*r), Power::In, None);
            }
            ElementKind::Capacitor { c, .. } => {
                self.one_port(
                    id,
                    VertexKind::C,
                    linear(*c),
                    Power::In,
                    Some(StateKind::Voltage),
                );
            }
            ElementKind::Inductor { l, .. } => match self.field_of.get(&id) {
                Some(&f) if self.fields[f].0[0] == id => self.field(f),
                Some(_) => {}
                None => {
                    self.one_port(
                        id,
                        VertexKind::I,
                        linear(*l),
                        Power::In,
                        Some(StateKind::Current),
                    );
                }
            },
            ElementKind::Coupling { .. } => {
                let text = match self.field_of.get(&id) {
                    Some(&f) => {
                        format!("{name}: a coupling of the I-field {}", self.field_label(f))
                    }
                    None => format!("{name} couples no pair of inductors: not drawn"),
                };
                self.g.notes.push(Note {
                    elem: Some(id),
                    text,
                });
            }
            ElementKind::VSource { .. } => {
                let law = Law::Source { name: name.clone() };
                self.one_port(id, VertexKind::Se, law, Power::Out, None);
            }
            ElementKind::ISource { .. } => {
                let law = Law::Source { name: name.clone() };
                self.one_port(id, VertexKind::Sf, law, Power::Out, None);
            }
            ElementKind::Vcvs { gain } | ElementKind::Vccs { gm: gain } => {
                if let Some(&p) = self.pair_of.get(&id) {
                    self.pair(p, id);
                    return;
                }
                let kind = if matches!(e.kind, ElementKind::Vcvs { .. }) {
                    VertexKind::MSe
                } else {
                    VertexKind::MSf
                };
                let law = Law::Controlled {
                    param: name.clone(),
                    value: *gain,
                };
                let ctrl = [(1, control(e, 2)), (-1, control(e, 3))];
                let v = self.one_port(id, kind, law, Power::Out, None);
                self.g.vertices[v].signals = ctrl
                    .iter()
                    .filter(|(_, n)| *n != GROUND)
                    .map(|&(k, n)| (k, Signal::Potential(n)))
                    .collect();
            }
            ElementKind::Cccs { gain, ctrl } | ElementKind::Ccvs { r: gain, ctrl } => {
                if let Some(&p) = self.pair_of.get(&id) {
                    self.pair(p, id);
                    return;
                }
                let kind = if matches!(e.kind, ElementKind::Ccvs { .. }) {
                    VertexKind::MSe
                } else {
                    VertexKind::MSf
                };
                let law = Law::Controlled {
                    param: name.clone(),
                    value: *gain,
                };
                let ctrl = *ctrl;
                let v = self.one_port(id, kind, law, Power::Out, None);
                self.g.vertices[v].signals = vec![(1, Signal::Current(ctrl))];
            }
            ElementKind::Diode { model, area } => {
                let charge = model.cjo * area != 0.0 || model.tt != 0.0;
                let rs = (model.rs > 0.0).then_some(model.rs / area);
                self.diode(id, charge, rs);
            }
            ElementKind::Behavioural {
                current,
                expr,
                controls,
            } => {
                let kind = if *current {
                    VertexKind::MSf
                } else {
                    VertexKind::MSe
                };
                if expr.nodes.iter().any(|n| matches!(n, BNode::Ddt(_))) {
                    self.g.notes.push(Note {
                        elem: Some(id),
                        text: format!(
                            "{name} reads ddt(): the equations hold a state for it inside the source's signal, which the bond graph does not draw as storage"
                        ),
                    });
                }
                let signals = self.expr_signals(&expr.nodes, controls);
                let law = Law::Nonlinear { name: name.clone() };
                let v = self.one_port(id, kind, law, Power::Out, None);
                self.g.vertices[v].signals = signals;
            }
            ElementKind::DeviceBranch {
                controlled,
                current,
                charge,
                capacitance,
                controls,
                ..
            } => {
                let parts = [current.is_some(), charge.is_some(), capacitance.is_some()];
                self.device(id, *controlled, parts, controls);
            }
            ElementKind::Switch { ctrl, .. } => {
                let law = Law::Switch {
                    param: format!("g_{name}"),
                };
                let signals = match ctrl {
                    Some(c) => vec![(1, Signal::Current(*c))],
                    None => [(1, control(e, 2)), (-1, control(e, 3))]
                        .into_iter()
                        .filter(|(_, n)| *n != GROUND)
                        .map(|(k, n)| (k, Signal::Potential(n)))
                        .collect(),
                };
                let v = self.one_port(id, VertexKind::MR, law, Power::In, None);
                self.g.vertices[v].signals = signals;
            }
            ElementKind::Intermediate { .. } => {
                self.g.notes.push(Note {
                    elem: Some(id),
                    text: format!(
                        "{name}: a device's intermediate quantity, a signal only (no terminals, no bond); the branches that read it read its inputs"
                    ),
                });
            }
        }
    }

    /// The signals of a B source's expression, each once.
    fn expr_signals(&self, nodes: &[BNode], controls: &[ElemId]) -> Vec<(i32, Signal)> {
        let mut out: Vec<(i32, Signal)> = Vec::new();
        for n in nodes {
            let s = match *n {
                BNode::Pot(p) if p != GROUND => vec![Signal::Potential(p)],
                BNode::Current(k) => controls
                    .get(k as usize)
                    .map(|&c| vec![Signal::Current(c)])
                    .unwrap_or_default(),
                BNode::Volt(k) => controls
                    .get(k as usize)
                    .map(|&c| self.voltages(c))
                    .unwrap_or_default(),
                _ => Vec::new(),
            };
            for s in s {
                if !out.iter().any(|&(_, x)| x == s) {
                    out.push((1, s));
                }
            }
        }
        out
    }

    /// The branch voltages `Volt(c)` stands for: `c`'s own, or, for a
    /// device's intermediate quantity, those it is computed from.
    fn voltages(&self, c: ElemId) -> Vec<Signal> {
        let mut out = Vec::new();
        let mut seen = vec![c];
        let mut stack = vec![c];
        while let Some(x) = stack.pop() {
            match &self.c.elements[x].kind {
                ElementKind::Intermediate { controls, .. } => {
                    for &k in controls {
                        if !seen.contains(&k) {
                            seen.push(k);
                            stack.push(k);
                        }
                    }
                }
                _ => out.push(Signal::Voltage(x)),
            }
        }
        out
    }

    /// ngspice's diode: a nonlinear R (the junction current) and, with CJO
    /// or TT, a nonlinear C (the junction charge) on the junction voltage;
    /// with RS, in series with R:RS behind a 1-junction.
    fn diode(&mut self, id: ElemId, charge: bool, rs: Option<f64>) {
        let name = self.c.elements[id].name.to_string();
        let (u, i) = self.names(id);
        let current_law = Law::Nonlinear {
            name: format!("id_{name}"),
        };
        let charge_law = Law::Nonlinear {
            name: format!("Q_{name}"),
        };
        let r = self.element_vertex(VertexKind::R, id, Part::Current, current_law);
        let c = charge.then(|| self.element_vertex(VertexKind::C, id, Part::Charge, charge_law));
        let ij = if charge {
            format!("ij_{name}")
        } else {
            i.clone()
        };
        let iq = format!("iq_{name}");
        let charge_state = StateKey {
            elem: id,
            kind: StateKind::Charge,
        };
        let ends = self.ends(id);
        let Some(rs) = rs else {
            let pr = self.attach(id, ends, Power::In, r, (&u, &ij));
            if pr.is_some() {
                self.g.vertices[r].states.push(None);
            }
            self.record(id, pr);
            if let (Some(c), Some(_)) = (c, pr)
                && let Some((bc, _, sf)) = self.attach(id, ends, Power::In, c, (&u, &iq))
            {
                self.g.vertices[c].states.push(Some(charge_state));
                self.g.elements[id.0 as usize]
                    .current
                    .push((sf as i32, atom(bc, Var::Flow)));
            }
            return;
        };
        let one = self.vertex(
            VertexKind::One,
            name.clone(),
            Origin::Inner { elem: id },
            Law::Junction,
        );
        self.g.elements[id.0 as usize].vertices.push(one);
        let Some((outer, se, sf)) = self.attach(id, ends, Power::In, one, (&u, &i)) else {
            return;
        };
        self.g.vertices[one].name = Some((i.clone(), sf));
        self.record(id, Some((outer, se, sf)));
        let series = self.element_vertex(
            VertexKind::R,
            id,
            Part::Series,
            Law::Linear {
                param: format!("{name}.rs"),
                value: rs,
                negated: false,
            },
        );
        self.bond(one, series);
        self.port(series, &format!("urs_{name}"), &i, se, sf, None);
        let zero = self.vertex(
            VertexKind::Zero,
            format!("{name}.j"),
            Origin::Inner { elem: id },
            Law::Junction,
        );
        self.g.elements[id.0 as usize].vertices.push(zero);
        let uj = format!("uj_{name}");
        self.g.vertices[zero].name = Some((uj.clone(), se));
        self.bond(one, zero);
        self.bond(zero, r);
        self.port(r, &uj, &ij, se, sf, None);
        if let Some(c) = c {
            self.bond(zero, c);
            self.port(c, &uj, &iq, se, sf, Some(charge_state));
        }
    }

    fn port(&mut self, v: VertexId, e: &str, f: &str, se: i8, sf: i8, state: Option<StateKey>) {
        let x = &mut self.g.vertices[v];
        x.ports.push(PortNames {
            effort: e.to_string(),
            flow: f.to_string(),
            effort_sign: se,
            flow_sign: sf,
        });
        x.states.push(state);
    }

    /// A transistor's branch: its current (a nonlinear R, or a modulated
    /// flow source when other branches' voltages alone set it), its charge
    /// and its capacitance (nonlinear Cs), in parallel on its difference.
    fn device(&mut self, id: ElemId, controlled: bool, parts: [bool; 3], controls: &[ElemId]) {
        let name = self.c.elements[id].name.to_string();
        let n_parts = parts.iter().filter(|&&p| p).count();
        if n_parts == 0 {
            self.g.notes.push(Note {
                elem: Some(id),
                text: format!("{name} carries no current: not drawn"),
            });
            return;
        }
        let mut signals: Vec<(i32, Signal)> = Vec::new();
        for &c in controls {
            for s in self.voltages(c) {
                if s != Signal::Voltage(id) && !signals.iter().any(|&(_, x)| x == s) {
                    signals.push((1, s));
                }
            }
        }
        let u = format!("u_{name}");
        let flow = |short: &str| {
            if n_parts == 1 {
                format!("i_{name}")
            } else {
                format!("{short}_{name}")
            }
        };
        let ends = self.ends(id);
        let current_kind = if controlled {
            VertexKind::MSf
        } else {
            VertexKind::R
        };
        let specs = [
            (
                parts[0],
                current_kind,
                Part::Current,
                format!("I_{name}"),
                flow("ir"),
                None,
            ),
            (
                parts[1],
                VertexKind::C,
                Part::Charge,
                format!("Q_{name}"),
                flow("iq"),
                Some(StateKind::Charge),
            ),
            (
                parts[2],
                VertexKind::C,
                Part::Capacitance,
                format!("C_{name}"),
                flow("ic"),
                Some(StateKind::Voltage),
            ),
        ];
        let mut current: Lin = Vec::new();
        for (present, kind, part, law, f, state) in specs {
            if !present {
                continue;
            }
            let v = self.element_vertex(kind, id, part, Law::Nonlinear { name: law });
            self.g.vertices[v].signals = signals.clone();
            let power = if kind == VertexKind::MSf {
                Power::Out
            } else {
                Power::In
            };
            let Some((b, se, sf)) = self.attach(id, ends, power, v, (&u, &f)) else {
                return;
            };
            self.g.vertices[v]
                .states
                .push(state.map(|kind| StateKey { elem: id, kind }));
            let ep = &mut self.g.elements[id.0 as usize];
            if ep.voltage.is_empty() {
                ep.voltage = vec![(se as i32, atom(b, Var::Effort))];
            }
            current.push((sf as i32, atom(b, Var::Flow)));
        }
        self.g.elements[id.0 as usize].current = current;
    }

    /// E with F (an ideal transformer), or two cross-coupled G (a
    /// gyrator): one two-port, made when its first element comes.
    fn pair(&mut self, p: usize, elem: ElemId) {
        let pair = self.pairs[p];
        if elem != pair.first.min(pair.second) {
            return;
        }
        let (f, e) = (pair.first, pair.second);
        let label = format!("{}·{}", self.c.elements[f].name, self.c.elements[e].name);
        let v = self.vertex(
            pair.kind,
            label,
            Origin::Pair {
                first: f,
                second: e,
            },
            Law::Junction,
        );
        self.g.elements[f.0 as usize].vertices.push(v);
        self.g.elements[e.0 as usize].vertices.push(v);
        let (u1, i1) = self.names(f);
        let (u2, i2) = self.names(e);
        let p1 = self.attach(f, self.ends(f), Power::In, v, (&u1, &i1));
        let p2 = self.attach(e, self.ends(e), Power::Out, v, (&u2, &i2));
        self.record(f, p1);
        self.record(e, p2);
        self.g.vertices[v].states = vec![None; self.g.vertices[v].ports.len()];
        let (Some((_, se1, _)), Some((_, se2, _))) = (p1, p2) else {
            return;
        };
        // A transformer: port 2's effort is n times port 1's (e2 = n·e1,
        // f1 = n·f2). A gyrator: port 1's flow is g times port 2's effort
        // (f1 = g·e2, f2 = g·e1). n and g in the bonds' signs.
        let s = (se1 as i32 * se2 as i32 * pair.c1) as f64;
        let (param, gain) = match (self.c.elements[e].kind.clone(), &self.c.elements[f].kind) {
            (ElementKind::Vcvs { gain }, _) => (self.c.elements[e].name.to_string(), gain),
            (_, ElementKind::Vccs { gm }) => (self.c.elements[f].name.to_string(), *gm),
            _ => (String::new(), 1.0),
        };
        let value = s * gain;
        self.g.vertices[v].law = Law::Linear {
            param,
            value,
            negated: (value < 0.0) != (gain < 0.0),
        };
    }

    /// E and F that together are an ideal transformer, and G pairs that are
    /// a gyrator. E (gain `gE`) copies `c1·u_F` to its output; F (gain
    /// `gF`) carries `gF·i_V` where V is in series with E's output (so
    /// `i_V = s·i_E`): power in, `gF·s·c1·u·i_E`, equals power out,
    /// `−gE·u·i_E`, when `c1·gF·s = −gE`.
    fn find_pairs(&mut self) {
        let c = self.c;
        let mut terminals = vec![0usize; c.nodes.len()];
        for e in c.elements.values() {
            if !matches!(
                e.kind,
                ElementKind::Coupling { .. } | ElementKind::Intermediate { .. }
            ) && e.nodes.len() >= 2
                && e.nodes[..2]
                    .iter()
                    .all(|n| (n.0 as usize) < terminals.len())
            {
                terminals[e.nodes[0].0 as usize] += 1;
                terminals[e.nodes[1].0 as usize] += 1;
            }
        }
        let orient = |x: (NodeId, NodeId), y: (NodeId, NodeId)| {
            if x == y {
                Some(1)
            } else if x == (y.1, y.0) {
                Some(-1)
            } else {
                None
            }
        };
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * a.abs().max(b.abs());
        let mut used: Vec<ElemId> = Vec::new();
        for (fid, fe) in c.elements.iter() {
            let ElementKind::Cccs { gain: gf, ctrl } = fe.kind else {
                continue;
            };
            let Some(v) = c.elements.get(ctrl) else {
                continue;
            };
            if fe.nodes.len() < 2 || v.nodes.len() < 2 {
                continue;
            }
            for (eid, ee) in c.elements.iter() {
                let ElementKind::Vcvs { gain: ge } = ee.kind else {
                    continue;
                };
                if used.contains(&eid) || used.contains(&fid) || ee.nodes.len() < 4 {
                    continue;
                }
                let Some(c1) = orient((fe.nodes[0], fe.nodes[1]), (ee.nodes[2], ee.nodes[3]))
                else {
                    continue;
                };
                let mut s = None;
                for (k, &x) in ee.nodes[..2].iter().enumerate() {
                    if x == GROUND || terminals.get(x.0 as usize) != Some(&2) || ctrl == eid {
                        continue;
                    }
                    let first = v.nodes[0] == x;
                    if !first && v.nodes[1] != x {
                        continue;
                    }
                    s = Some(if (k == 0) == first { -1 } else { 1 });
                }
                let Some(s) = s else {
                    continue;
                };
                if close((c1 * s) as f64 * gf, -ge) {
                    used.extend([fid, eid]);
                    self.pair_of.insert(fid, self.pairs.len());
                    self.pair_of.insert(eid, self.pairs.len());
                    self.pairs.push(Pair {
                        kind: VertexKind::Tf,
                        first: fid,
                        second: eid,
                        c1,
                    });
                }
            }
        }
        // G1 drives port 1 from port 2's voltage, G2 port 2 from port 1's:
        // lossless when g1·c1 + g2·c2 = 0.
        for (g1, e1) in c.elements.iter() {
            let ElementKind::Vccs { gm: gm1 } = e1.kind else {
                continue;
            };
            for (g2, e2) in c.elements.iter().skip(g1.0 as usize + 1) {
                let ElementKind::Vccs { gm: gm2 } = e2.kind else {
                    continue;
                };
                if e1.nodes.len() < 4 || e2.nodes.len() < 4 {
                    continue;
                }
                if used.contains(&g1) || used.contains(&g2) {
                    continue;
                }
                let (Some(c1), Some(c2)) = (
                    orient((e1.nodes[2], e1.nodes[3]), (e2.nodes[0], e2.nodes[1])),
                    orient((e2.nodes[2], e2.nodes[3]), (e1.nodes[0], e1.nodes[1])),
                ) else {
                    continue;
                };
                if close(gm1 * c1 as f64, -gm2 * c2 as f64) {
                    used.extend([g1, g2]);
                    self.pair_of.insert(g1, self.pairs.len());
                    self.pair_of.insert(g2, self.pairs.len());
                    self.pairs.push(Pair {
                        kind: VertexKind::Gy,
                        first: g1,
                        second: g2,
                        c1,
                    });
                }
            }
        }
    }

    /// Inductors joined by K elements, as groups.
    fn find_fields(&mut self) {
        let c = self.c;
        let mut sets = crate::numeric::UnionFind::new(c.elements.len());
        let mut joined = false;
        for e in c.elements.values() {
            if let ElementKind::Coupling { l1, l2, .. } = e.kind
                && l1 != l2
            {
                sets.union(l1.0 as usize, l2.0 as usize);
                joined = true;
            }
        }
        if !joined {
            return;
        }
        let mut by_root: HashMap<usize, usize> = HashMap::new();
        for (id, e) in c.elements.iter() {
            if let ElementKind::Coupling { l1, .. } = e.kind {
                let root = sets.find(l1.0 as usize);
                let f = *by_root.entry(root).or_insert_with(|| {
                    self.fields.push((Vec::new(), Vec::new()));
                    self.fields.len() - 1
                });
                self.fields[f].1.push(id);
            }
        }
        for (id, e) in c.elements.iter() {
            if matches!(e.kind, ElementKind::Inductor { .. })
                && let Some(&f) = by_root.get(&sets.find(id.0 as usize))
            {
                self.fields[f].0.push(id);
                self.field_of.insert(id, f);
            }
        }
        for (f, (_, ks)) in self.fields.iter().enumerate() {
            for &k in ks {
                self.field_of.insert(k, f);
            }
        }
    }

    fn field_label(&self, f: usize) -> String {
        self.fields[f]
            .0
            .iter()
            .map(|&m| self.c.elements[m].name.as_str())
            .collect::<Vec<_>>()
            .join("·")
    }

    /// A multiport I-field: one port per winding; its law names the
    /// parameters as the equations do (self inductances by the inductor,
    /// mutuals `M_K`; a singular group's flux and ratio coefficients).
    fn field(&mut self, f: usize) {
        let (members, couplings) = self.fields[f].clone();
        let c = self.c;
        let name = |e: ElemId| c.elements[e].name.to_string();
        let index = |e: ElemId| members.iter().position(|&m| m == e);
        let singular = crate::build::coupling::singular_groups(c)
            .into_iter()
            .find(|g| g.members == members);
        let mut mutual = Vec::new();
        if singular.is_none() {
            for &k in &couplings {
                if let ElementKind::Coupling { l1, l2, .. } = c.elements[k].kind
                    && let (Some(a), Some(b)) = (index(l1), index(l2))
                {
                    mutual.push((a, b, format!("M_{}", name(k))));
                }
            }
        }
        let singular = singular.map(|g| {
            let nm = |k: usize| name(g.members[k]);
            SingularField {
                pivots: g.pivots.clone(),
                flux: g
                    .pivots
                    .iter()
                    .enumerate()
                    .map(|(j, &p)| {
                        g.flux[j]
                            .iter()
                            .enumerate()
                            .filter(|&(k, &a)| k == p || a != 0.0)
                            .map(|(k, _)| (k, (k != p).then(|| format!("n_{}_{}", nm(p), nm(k)))))
                            .collect()
                    })
                    .collect(),
                ratio: g
                    .ratio
                    .iter()
                    .map(|(q, row)| {
                        let terms = row
                            .iter()
                            .enumerate()
                            .filter(|&(_, &cq)| cq != 0.0)
                            .map(|(j, _)| (j, format!("c_{}_{}", nm(*q), nm(g.pivots[j]))))
                            .collect();
                        (*q, terms)
                    })
                    .collect(),
            }
        });
        let law = Law::Field(Box::new(FieldLaw {
            inductance: members.iter().map(|&m| name(m)).collect(),
            mutual,
            singular,
        }));
        let v = self.vertex(
            VertexKind::IField,
            self.field_label(f),
            Origin::Field {
                members: members.clone(),
                couplings,
            },
            law,
        );
        for &m in &members {
            self.g.elements[m.0 as usize].vertices.push(v);
            let (u, i) = self.names(m);
            let port = self.attach(m, self.ends(m), Power::In, v, (&u, &i));
            if port.is_some() {
                self.g.vertices[v].states.push(Some(StateKey {
                    elem: m,
                    kind: StateKind::Current,
                }));
            }
            self.record(m, port);
        }
    }
}
