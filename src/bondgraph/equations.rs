//! The equations a causal bond graph stands for (seed 003's block diagram
//! in text), read off vertex by vertex, and sorted.
//!
//! Every bond carries an effort and a flow; a 0-junction's bonds share its
//! effort and a 1-junction's share its flow, so each is one quantity, named
//! as the circuit names it: `v(a)` for a node, `v(a,b)` for a difference, an
//! element's `u_X` or `i_X` where only the element's port has it. Each
//! vertex computes what its causality makes it give: a junction the one
//! balanced variable of its strong bond, a source its variable, a storage
//! port in integral causality its state (and the state's derivative), in
//! derivative causality the other variable from the derivative of the
//! one it takes, a resistor one variable from the other. Derivatives of
//! quantities that are no states are written by differentiating the
//! equation that computes them, as index reduction does.
//!
//! Sorting is topological over what each equation reads; a strongly
//! connected set of equations is an algebraic loop, named by its elements,
//! the arbitrary choices and the derivative causality inside it.

use std::collections::{HashMap, HashSet};

use super::scap::Phase;
use super::{BondGraph, BondId, Causality, Law, Origin, Part, Var, VertexId, VertexKind};
use crate::elab::ElemId;
use crate::ir::IdVec;

crate::entity_id!(
    /// A quantity of the read-off equations.
    QtyId,
    "q"
);

/// Derivatives of higher order than this are not written (a note says so):
/// differentiating along a causality where a storage port in derivative
/// causality sits in a loop with an arbitrary resistor can need the
/// derivative of its own derivative, and so on without end. Index
/// reduction differentiates the loop's constraint instead.
const MAX_ORDER: u8 = 2;

/// What a quantity is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum QtyKind {
    Effort,
    Flow,
    /// A storage port's state in integral causality: known.
    State,
    /// A singular field's magnetizing current that is no state.
    Internal,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct Quantity {
    pub name: String,
    pub kind: QtyKind,
}

/// A quantity or one of its time derivatives.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
pub struct QRef {
    pub q: QtyId,
    pub order: u8,
}

/// A coefficient of a term: a parameter, or a law of signals (a device's
/// capacitance).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Factor {
    Param(String),
    Law {
        name: String,
        args: Vec<(i32, QRef)>,
    },
}

/// What a term multiplies.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Operand {
    Q(QRef),
    /// An independent source's waveform (or a derivative of it).
    Source {
        name: String,
        order: u8,
    },
    /// A nonlinear or modulated law of signed arguments (or a derivative).
    Law {
        name: String,
        args: Vec<(i32, QRef)>,
        order: u8,
    },
}

/// `coef · mul · x / div`.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Term {
    pub coef: i32,
    pub mul: Option<Factor>,
    pub div: Option<Factor>,
    pub x: Operand,
}

/// `lhs := Σ rhs`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Equation {
    pub lhs: QRef,
    pub rhs: Vec<Term>,
    pub vertex: VertexId,
    /// The element whose law this is (`None`: a junction's balance).
    pub element: Option<ElemId>,
    /// The element's constitutive law (not a state handed to a junction).
    pub law: bool,
    /// The equation this one differentiates.
    pub of: Option<usize>,
    /// The derivative of a junction's balance along the chain that fixes a
    /// storage port in derivative causality by states and sources alone
    /// (its constraint).
    pub constraint: bool,
}

/// An algebraic loop of the read-off equations.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Loop {
    pub eqs: Vec<usize>,
    /// Elements whose laws are in the loop.
    pub elements: Vec<ElemId>,
    /// Vertices whose causality was chosen arbitrarily (SCAP phases 3, 4).
    pub arbitrary: Vec<VertexId>,
    /// Storage vertices in derivative causality.
    pub derivative: Vec<VertexId>,
}

/// One step of the sorted equations.
#[derive(Clone, Debug, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Step {
    Assign(usize),
    Loop(Loop),
}

/// The equations of a causal bond graph, sorted.
#[derive(Clone, Debug)]
pub struct ReadOff {
    pub quantities: IdVec<QtyId, Quantity>,
    /// Each live bond's effort and flow: `sign · quantity`.
    pub effort: Vec<Option<(i32, QtyId)>>,
    pub flow: Vec<Option<(i32, QtyId)>>,
    pub equations: Vec<Equation>,
    pub steps: Vec<Step>,
    /// Quantities more than one equation computes (a causal conflict).
    pub twice: Vec<QRef>,
    /// Quantities read but computed by no equation (a causal conflict).
    pub unknown: Vec<QRef>,
    /// Derivatives past [`MAX_ORDER`] that were not written.
    pub too_deep: Vec<QRef>,
    /// The state of each storage port in integral causality: its quantity,
    /// vertex and bond.
    pub state_ports: Vec<(QtyId, VertexId, BondId)>,
}

struct Reader<'a> {
    g: &'a BondGraph,
    c: &'a Causality,
    quantities: IdVec<QtyId, Quantity>,
    by_name: HashMap<String, QtyId>,
    effort: Vec<Option<(i32, QtyId)>>,
    flow: Vec<Option<(i32, QtyId)>>,
    eqs: Vec<Equation>,
    state_ports: Vec<(QtyId, VertexId, BondId)>,
}

/// Read the equations off the causal bond graph and sort them.
pub fn read_off(g: &BondGraph, c: &Causality) -> ReadOff {
    let mut r = Reader {
        g,
        c,
        quantities: IdVec::new(),
        by_name: HashMap::new(),
        effort: vec![None; g.bonds.len()],
        flow: vec![None; g.bonds.len()],
        eqs: Vec::new(),
        state_ports: Vec::new(),
    };
    r.name_bonds();
    // Sources, storage, resistors and two-ports, junctions: the order the
    // listing breaks ties in.
    let mut order: Vec<VertexId> = g.live_vertices().map(|(v, _)| v).collect();
    order.sort_by_key(|&v| {
        let k = g.vertices[v].kind;
        let rank = if k.is_source() {
            0
        } else if k.is_storage() {
            1
        } else if k.is_junction() {
            3
        } else {
            2
        };
        (rank, v)
    });
    for v in order {
        r.vertex(v);
    }
    let too_deep = r.differentiate_needed();
    let (steps, twice, unknown) = r.sort();
    ReadOff {
        quantities: r.quantities,
        effort: r.effort,
        flow: r.flow,
        equations: r.eqs,
        steps,
        twice,
        unknown,
        too_deep,
        state_ports: r.state_ports,
    }
}

fn q(q: QtyId) -> QRef {
    QRef { q, order: 0 }
}

fn der(x: QRef) -> QRef {
    QRef {
        q: x.q,
        order: x.order + 1,
    }
}

fn term(coef: i32, x: QRef) -> Term {
    Term {
        coef,
        mul: None,
        div: None,
        x: Operand::Q(x),
    }
}

fn param(p: &str) -> Option<Factor> {
    Some(Factor::Param(p.to_string()))
}

impl Reader<'_> {
    fn qty(&mut self, name: &str, kind: QtyKind) -> QtyId {
        if let Some(&id) = self.by_name.get(name) {
            if kind == QtyKind::State {
                self.quantities[id].kind = QtyKind::State;
            }
            return id;
        }
        let id = self.quantities.push(Quantity {
            name: name.to_string(),
            kind,
        });
        self.by_name.insert(name.to_string(), id);
        id
    }

    fn takes(&self, v: VertexId, b: BondId) -> bool {
        self.c.effort_into(self.g, v, b).unwrap_or(false)
    }

    /// The port names of element vertex `v` on bond `b`.
    fn port(&self, v: VertexId, b: BondId) -> Option<&super::PortNames> {
        let x = &self.g.vertices[v];
        let k = x.bonds.iter().position(|&c| c == b)?;
        x.ports.get(k)
    }

    /// Name every live bond's effort and flow.
    fn name_bonds(&mut self) {
        let g = self.g;
        let mut zero: HashMap<VertexId, (i32, QtyId)> = HashMap::new();
        let mut one: HashMap<VertexId, (i32, QtyId)> = HashMap::new();
        for (v, x) in g.live_vertices() {
            match x.kind {
                VertexKind::Zero => {
                    let (name, s) = x.name.clone().unwrap_or((format!("e({})", x.label), 1));
                    let id = self.qty(&name, QtyKind::Effort);
                    zero.insert(v, (s as i32, id));
                }
                VertexKind::One => {
                    let (name, s) = self.one_name(v);
                    let id = self.qty(&name, QtyKind::Flow);
                    one.insert(v, (s, id));
                }
                _ => {}
            }
        }
        // A bond between two elements is named after the one whose name
        // says most: a storage element's (its state), a resistor's, then
        // a source's or two-port's.
        let rank = |v: VertexId| match g.vertices[v].kind {
            VertexKind::C | VertexKind::I | VertexKind::IField => 0,
            VertexKind::R | VertexKind::MR => 1,
            _ => 2,
        };
        for (b, bond) in g.live_bonds() {
            let mut ends = [bond.tail, bond.head];
            if rank(ends[1]) < rank(ends[0]) {
                ends.swap(0, 1);
            }
            let e = match ends.iter().find_map(|v| zero.get(v)) {
                Some(&x) => x,
                None => match ends.iter().find_map(|&v| self.port(v, b)).cloned() {
                    Some(p) => (p.effort_sign as i32, self.qty(&p.effort, QtyKind::Effort)),
                    None => (1, self.qty(&format!("e{}", b.0), QtyKind::Effort)),
                },
            };
            let f = match ends.iter().find_map(|v| one.get(v)) {
                Some(&x) => x,
                None => match ends.iter().find_map(|&v| self.port(v, b)).cloned() {
                    Some(p) => (p.flow_sign as i32, self.qty(&p.flow, QtyKind::Flow)),
                    None => (1, self.qty(&format!("f{}", b.0), QtyKind::Flow)),
                },
            };
            self.effort[b.0 as usize] = Some(e);
            self.flow[b.0 as usize] = Some(f);
        }
    }

    /// A 1-junction's flow: named after an inductor in integral causality
    /// on it (its state), else after an element on it, else its own name.
    fn one_name(&self, v: VertexId) -> (String, i32) {
        let g = self.g;
        let x = &g.vertices[v];
        if let Some((n, s)) = &x.name
            && !matches!(x.origin, Origin::Difference(..))
        {
            return (n.clone(), *s as i32);
        }
        let mut best: Option<(u8, String, i32)> = None;
        for &b in &x.bonds {
            let y = g.bonds[b].other(v);
            let Some(p) = self.port(y, b) else {
                continue;
            };
            let kind = g.vertices[y].kind;
            let integral_i = kind == VertexKind::I && self.takes(y, b);
            let rank = match (integral_i, p.flow_sign > 0) {
                (true, _) => 0,
                (false, true) => 1,
                (false, false) => 2,
            };
            if best.as_ref().is_none_or(|(r, ..)| rank < *r) {
                best = Some((rank, p.flow.clone(), p.flow_sign as i32));
            }
        }
        match (best, &x.name) {
            (Some((_, n, s)), _) => (n, s),
            (None, Some((n, s))) => (n.clone(), *s as i32),
            (None, None) => (format!("f({})", x.label), 1),
        }
    }

    fn e(&self, b: BondId) -> (i32, QtyId) {
        self.effort[b.0 as usize].unwrap_or((1, QtyId(0)))
    }

    fn f(&self, b: BondId) -> (i32, QtyId) {
        self.flow[b.0 as usize].unwrap_or((1, QtyId(0)))
    }

    /// An element port's `u` and `i` as signed quantities.
    fn ui(&self, v: VertexId, b: BondId) -> ((i32, QtyId), (i32, QtyId)) {
        let (se, qe) = self.e(b);
        let (sf, qf) = self.f(b);
        let (pe, pf) = self
            .port(v, b)
            .map_or((1, 1), |p| (p.effort_sign as i32, p.flow_sign as i32));
        ((pe * se, qe), (pf * sf, qf))
    }

    /// The signals vertex `v` reads, as signed quantities.
    fn signals(&self, v: VertexId) -> Vec<(i32, QRef)> {
        let mut out: Vec<(i32, QRef)> = Vec::new();
        for &(k, s) in &self.g.vertices[v].signals {
            for (c, a) in self.g.signal(s).unwrap_or_default() {
                let (sign, id) = match a.var {
                    Var::Effort => self.e(a.bond),
                    Var::Flow => self.f(a.bond),
                };
                let x = q(id);
                let coef = k * c * sign;
                match out.iter_mut().find(|(_, y)| *y == x) {
                    Some(t) => t.0 += coef,
                    None => out.push((coef, x)),
                }
            }
        }
        out.retain(|&(c, _)| c != 0);
        out
    }

    fn emit(
        &mut self,
        lhs: (i32, QRef),
        mut rhs: Vec<Term>,
        v: VertexId,
        element: Option<ElemId>,
        law: bool,
    ) {
        if lhs.0 < 0 {
            for t in &mut rhs {
                t.coef = -t.coef;
            }
        }
        self.eqs.push(Equation {
            lhs: lhs.1,
            rhs,
            vertex: v,
            element,
            law,
            of: None,
            constraint: false,
        });
    }

    fn vertex(&mut self, v: VertexId) {
        let g = self.g;
        let x = &g.vertices[v];
        let elem = g.element_of(v);
        match x.kind {
            VertexKind::Zero | VertexKind::One => {
                let zero = x.kind == VertexKind::Zero;
                let Some(&s) = x.bonds.iter().find(|&&b| self.takes(v, b) == zero) else {
                    return;
                };
                let var = |r: &Self, b| if zero { r.f(b) } else { r.e(b) };
                let s_in = g.bonds[s].head == v;
                let rhs = x
                    .bonds
                    .iter()
                    .filter(|&&b| b != s)
                    .map(|&b| {
                        let (sign, id) = var(self, b);
                        let side = if (g.bonds[b].head == v) == s_in {
                            -1
                        } else {
                            1
                        };
                        term(side * sign, q(id))
                    })
                    .collect();
                let (sign, id) = var(self, s);
                self.emit((sign, q(id)), rhs, v, None, false);
            }
            VertexKind::Se | VertexKind::Sf | VertexKind::MSe | VertexKind::MSf => {
                let Some(&b) = x.bonds.first() else {
                    return;
                };
                let (u, i) = self.ui(v, b);
                let out = if matches!(x.kind, VertexKind::Se | VertexKind::MSe) {
                    u
                } else {
                    i
                };
                let rhs = match &x.law {
                    Law::Source { name } => vec![Term {
                        coef: 1,
                        mul: None,
                        div: None,
                        x: Operand::Source {
                            name: name.clone(),
                            order: 0,
                        },
                    }],
                    Law::Controlled { param: p, .. } => self
                        .signals(v)
                        .into_iter()
                        .map(|(c, s)| Term {
                            coef: c,
                            mul: param(p),
                            div: None,
                            x: Operand::Q(s),
                        })
                        .collect(),
                    Law::Nonlinear { name } => vec![Term {
                        coef: 1,
                        mul: None,
                        div: None,
                        x: Operand::Law {
                            name: name.clone(),
                            args: self.signals(v),
                            order: 0,
                        },
                    }],
                    _ => Vec::new(),
                };
                self.emit((out.0, q(out.1)), rhs, v, elem, true);
            }
            VertexKind::R | VertexKind::MR => {
                let Some(&b) = x.bonds.first() else {
                    return;
                };
                let (u, i) = self.ui(v, b);
                let takes = self.takes(v, b);
                let (out, inp) = if takes { (i, u) } else { (u, i) };
                let rhs = match &x.law {
                    Law::Linear { param: p, .. } => vec![Term {
                        coef: inp.0,
                        mul: (!takes).then(|| param(p)).flatten(),
                        div: takes.then(|| param(p)).flatten(),
                        x: Operand::Q(q(inp.1)),
                    }],
                    Law::Switch { param: p } => vec![Term {
                        coef: inp.0,
                        mul: takes.then(|| param(p)).flatten(),
                        div: (!takes).then(|| param(p)).flatten(),
                        x: Operand::Q(q(inp.1)),
                    }],
                    Law::Nonlinear { name } => {
                        let mut args = vec![(inp.0, q(inp.1))];
                        args.extend(self.signals(v));
                        vec![Term {
                            coef: 1,
                            mul: None,
                            div: None,
                            x: Operand::Law {
                                name: if takes {
                                    name.clone()
                                } else {
                                    format!("{name}^-1")
                                },
                                args,
                                order: 0,
                            },
                        }]
                    }
                    _ => Vec::new(),
                };
                self.emit((out.0, q(out.1)), rhs, v, elem, true);
            }
            VertexKind::C | VertexKind::I => {
                let Some(&b) = x.bonds.first() else {
                    return;
                };
                self.storage(v, b, elem);
            }
            VertexKind::IField => self.field(v),
            VertexKind::Tf | VertexKind::Gy => self.two_port(v),
        }
    }

    /// A C or I port.
    fn storage(&mut self, v: VertexId, b: BondId, elem: Option<ElemId>) {
        let g = self.g;
        let x = &g.vertices[v];
        let (u, i) = self.ui(v, b);
        let is_c = x.kind == VertexKind::C;
        let integral = self.takes(v, b) != is_c;
        // C: gives u (integral), takes u (derivative); I: the dual.
        let (given, taken) = if is_c { (u, i) } else { (i, u) };
        let state_name = x
            .states
            .first()
            .copied()
            .flatten()
            .map(|k| {
                let prefix = match k.kind {
                    super::StateKind::Voltage => "u_",
                    super::StateKind::Current => "i_",
                    super::StateKind::Charge => "q_",
                };
                format!("{prefix}{}", g.element_name(k.elem))
            })
            .unwrap_or_else(|| format!("x_{}", x.label));
        let part = match x.origin {
            Origin::Element { part, .. } => part,
            _ => Part::Whole,
        };
        let signals = self.signals(v);
        let name = match &x.law {
            Law::Linear { param, .. } => param.clone(),
            Law::Nonlinear { name } => name.clone(),
            _ => x.label.clone(),
        };
        if integral {
            let state = self.qty(&state_name, QtyKind::State);
            self.state_ports.push((state, v, b));
            match part {
                // A charge: the effort from the charge (the law inverted).
                Part::Charge => {
                    let mut args = vec![(1, q(state))];
                    args.extend(signals.iter().copied());
                    let rhs = vec![Term {
                        coef: 1,
                        mul: None,
                        div: None,
                        x: Operand::Law {
                            name: format!("{name}^-1"),
                            args,
                            order: 0,
                        },
                    }];
                    self.emit((given.0, q(given.1)), rhs, v, elem, true);
                    self.emit(
                        (1, der(q(state))),
                        vec![term(taken.0, q(taken.1))],
                        v,
                        elem,
                        true,
                    );
                }
                _ => {
                    if given.1 != state {
                        self.emit(
                            (given.0, q(given.1)),
                            vec![term(1, q(state))],
                            v,
                            elem,
                            false,
                        );
                    }
                    let div = if part == Part::Capacitance {
                        Some(Factor::Law {
                            name: name.clone(),
                            args: signals,
                        })
                    } else {
                        param(&name)
                    };
                    let rhs = vec![Term {
                        coef: taken.0,
                        mul: None,
                        div,
                        x: Operand::Q(q(taken.1)),
                    }];
                    self.emit((1, der(q(state))), rhs, v, elem, true);
                }
            }
        } else {
            // Derivative causality: the roles swap; a C gives its current
            // from the derivative of its voltage, an I its voltage from the
            // derivative of its current.
            let rhs = match part {
                Part::Charge => {
                    let mut args = vec![(given.0, q(given.1))];
                    args.extend(signals.iter().copied());
                    vec![Term {
                        coef: 1,
                        mul: None,
                        div: None,
                        x: Operand::Law {
                            name,
                            args,
                            order: 1,
                        },
                    }]
                }
                Part::Capacitance => vec![Term {
                    coef: given.0,
                    mul: Some(Factor::Law {
                        name,
                        args: signals,
                    }),
                    div: None,
                    x: Operand::Q(der(q(given.1))),
                }],
                _ => vec![Term {
                    coef: given.0,
                    mul: param(&name),
                    div: None,
                    x: Operand::Q(der(q(given.1))),
                }],
            };
            self.emit((taken.0, q(taken.1)), rhs, v, elem, true);
        }
    }

    /// Coupled inductors, as the equations write them: per winding
    /// `u_k = L_k·der(i_k) + Σ M_kj·der(i_j)`, solved for `der(i_k)` in
    /// integral causality and for `u_k` in derivative; a perfectly coupled
    /// field by its pivots' fluxes.
    fn field(&mut self, v: VertexId) {
        let g = self.g;
        let x = &g.vertices[v];
        let (Law::Field(law), Origin::Field { members, .. }) = (&x.law, &x.origin) else {
            return;
        };
        let n = x.bonds.len().min(members.len());
        let mut volt = Vec::new();
        let mut cur = Vec::new();
        let mut integral = Vec::new();
        for k in 0..n {
            let b = x.bonds[k];
            let (u, i) = self.ui(v, b);
            volt.push(u);
            integral.push(self.takes(v, b));
            cur.push(i);
        }
        let elem = |k: usize| Some(members[k]);
        if let Some(s) = &law.singular {
            for (j, &p) in s.pivots.iter().enumerate() {
                if p >= n {
                    continue;
                }
                let name = format!("im_{}", g.element_name(members[p]));
                let flux = &s.flux[j];
                if integral[p] {
                    let im = self.qty(&name, QtyKind::State);
                    self.state_ports.push((im, v, x.bonds[p]));
                    // der(im_p) := u_p/L_p; i_p := im_p − Σ n_pk·i_k.
                    let rhs = vec![Term {
                        coef: volt[p].0,
                        mul: None,
                        div: param(&law.inductance[p]),
                        x: Operand::Q(q(volt[p].1)),
                    }];
                    self.emit((1, der(q(im))), rhs, v, elem(p), true);
                    let mut rhs = vec![term(1, q(im))];
                    for (k, c) in flux {
                        if let (Some(c), true) = (c, *k < n) {
                            rhs.push(Term {
                                coef: -cur[*k].0,
                                mul: param(c),
                                div: None,
                                x: Operand::Q(q(cur[*k].1)),
                            });
                        }
                    }
                    self.emit((cur[p].0, q(cur[p].1)), rhs, v, elem(p), true);
                } else {
                    let im = self.qty(&name, QtyKind::Internal);
                    let rhs = flux
                        .iter()
                        .filter(|(k, _)| *k < n)
                        .map(|(k, c)| Term {
                            coef: cur[*k].0,
                            mul: c.as_deref().and_then(param),
                            div: None,
                            x: Operand::Q(q(cur[*k].1)),
                        })
                        .collect();
                    self.emit((1, q(im)), rhs, v, elem(p), true);
                    let rhs = vec![Term {
                        coef: 1,
                        mul: param(&law.inductance[p]),
                        div: None,
                        x: Operand::Q(der(q(im))),
                    }];
                    self.emit((volt[p].0, q(volt[p].1)), rhs, v, elem(p), true);
                }
            }
            for (k, row) in &s.ratio {
                if *k >= n {
                    continue;
                }
                let rhs = row
                    .iter()
                    .filter_map(|(j, c)| {
                        let p = *s.pivots.get(*j)?;
                        (p < n).then(|| Term {
                            coef: volt[p].0,
                            mul: param(c),
                            div: None,
                            x: Operand::Q(q(volt[p].1)),
                        })
                    })
                    .collect();
                self.emit((volt[*k].0, q(volt[*k].1)), rhs, v, elem(*k), true);
            }
            return;
        }
        // The derivative of each winding's current: its state's, or its
        // flow's.
        let mut dcur = Vec::new();
        for k in 0..n {
            if integral[k] {
                let state = self.qty(&format!("i_{}", g.element_name(members[k])), QtyKind::State);
                self.state_ports.push((state, v, x.bonds[k]));
                if cur[k].1 != state {
                    self.emit(
                        (cur[k].0, q(cur[k].1)),
                        vec![term(1, q(state))],
                        v,
                        elem(k),
                        false,
                    );
                }
                dcur.push((1, der(q(state))));
            } else {
                dcur.push((cur[k].0, der(q(cur[k].1))));
            }
        }
        for k in 0..n {
            let mutual: Vec<(usize, &String)> = law
                .mutual
                .iter()
                .filter_map(|(a, b, m)| {
                    if *a == k {
                        Some((*b, m))
                    } else if *b == k {
                        Some((*a, m))
                    } else {
                        None
                    }
                })
                .filter(|(j, _)| *j < n)
                .collect();
            let lk = &law.inductance[k];
            if integral[k] {
                let mut rhs = vec![Term {
                    coef: volt[k].0,
                    mul: None,
                    div: param(lk),
                    x: Operand::Q(q(volt[k].1)),
                }];
                for (j, m) in mutual {
                    rhs.push(Term {
                        coef: -dcur[j].0,
                        mul: param(&format!("{m}/{lk}")),
                        div: None,
                        x: Operand::Q(dcur[j].1),
                    });
                }
                self.emit((1, dcur[k].1), rhs, v, elem(k), true);
            } else {
                let mut rhs = vec![Term {
                    coef: dcur[k].0,
                    mul: param(lk),
                    div: None,
                    x: Operand::Q(dcur[k].1),
                }];
                for (j, m) in mutual {
                    rhs.push(Term {
                        coef: dcur[j].0,
                        mul: param(m),
                        div: None,
                        x: Operand::Q(dcur[j].1),
                    });
                }
                self.emit((volt[k].0, q(volt[k].1)), rhs, v, elem(k), true);
            }
        }
    }

    /// A transformer (`e2 = n·e1`, `f1 = n·f2`) or gyrator (`f1 = g·e2`,
    /// `f2 = g·e1`). Each relation is one element's law, whichever way it is
    /// solved: a transformer's efforts E's, its flows F's; a gyrator's
    /// `f1 = g·e2` the first G's, `f2 = g·e1` the second's.
    fn two_port(&mut self, v: VertexId) {
        let g = self.g;
        let x = &g.vertices[v];
        let (
            Law::Linear {
                param: p, negated, ..
            },
            [b1, b2],
            Origin::Pair { first, second },
        ) = (&x.law, x.bonds.as_slice(), &x.origin)
        else {
            return;
        };
        let (b1, b2) = (*b1, *b2);
        let k = if *negated { -1 } else { 1 };
        let (e1, f1, e2, f2) = (self.e(b1), self.f(b1), self.e(b2), self.f(b2));
        let times = |out: (i32, QtyId), inp: (i32, QtyId), over: bool| {
            (
                (out.0, q(out.1)),
                vec![Term {
                    coef: k * inp.0,
                    mul: (!over).then(|| param(p)).flatten(),
                    div: over.then(|| param(p)).flatten(),
                    x: Operand::Q(q(inp.1)),
                }],
            )
        };
        let t1 = self.takes(v, b1);
        let eqs = match (x.kind, t1) {
            (VertexKind::Tf, true) => [
                (times(e2, e1, false), *second),
                (times(f1, f2, false), *first),
            ],
            (VertexKind::Tf, false) => [
                (times(e1, e2, true), *second),
                (times(f2, f1, true), *first),
            ],
            (_, true) => [
                (times(f1, e2, false), *first),
                (times(f2, e1, false), *second),
            ],
            (_, false) => [
                (times(e2, f1, true), *first),
                (times(e1, f2, true), *second),
            ],
        };
        for ((lhs, rhs), elem) in eqs {
            self.emit(lhs, rhs, v, Some(elem), true);
        }
    }

    /// Write the derivatives the equations read and no equation gives, by
    /// differentiating the equations of what they are derivatives of.
    fn differentiate_needed(&mut self) -> Vec<QRef> {
        self.constraints();
        let mut computed: HashMap<QRef, usize> = HashMap::new();
        for (k, e) in self.eqs.iter().enumerate() {
            computed.entry(e.lhs).or_insert(k);
        }
        let mut too_deep = Vec::new();
        let mut k = 0;
        while k < self.eqs.len() {
            for r in deps(&self.eqs[k]) {
                if r.order == 0 || computed.contains_key(&r) {
                    continue;
                }
                let base = QRef {
                    q: r.q,
                    order: r.order - 1,
                };
                let Some(&j) = computed.get(&base) else {
                    continue;
                };
                if r.order > MAX_ORDER {
                    if !too_deep.contains(&r) {
                        too_deep.push(r);
                    }
                    continue;
                }
                let d = differentiate(&self.eqs[j], j);
                computed.insert(r, self.eqs.len());
                self.eqs.push(d);
            }
            k += 1;
        }
        too_deep
    }

    /// The derivative of what each storage port in derivative causality
    /// takes, written as index reduction writes it: from the junction
    /// balances that fix it by states and sources alone (a loop of
    /// capacitors and voltage sources, a cutset of inductors and current
    /// sources), one equation per junction along the chain. Differentiating
    /// along the causality instead can run through a resistor whose
    /// causality was chosen, and need ever higher derivatives. Where no
    /// such chain exists, the closure differentiates along the causality.
    fn constraints(&mut self) {
        let g = self.g;
        let mut known: HashSet<QtyId> = self
            .quantities
            .iter()
            .filter(|(_, x)| x.kind == QtyKind::State)
            .map(|(q, _)| q)
            .collect();
        // And what follows from states and sources without a loop (a
        // state handed to a junction, a resistor's current from it): its
        // derivative comes by differentiating that chain, which ends.
        loop {
            let before = known.len();
            for e in &self.eqs {
                if e.lhs.order == 0
                    && !known.contains(&e.lhs.q)
                    && deps(e).iter().all(|d| d.order == 0 && known.contains(&d.q))
                {
                    known.insert(e.lhs.q);
                }
            }
            if known.len() == before {
                break;
            }
        }
        let ports: Vec<(VertexId, BondId)> =
            self.c.derivative().map(|s| (s.vertex, s.bond)).collect();
        for (v, b) in ports {
            let effort = g.vertices[v].kind == VertexKind::C;
            let var = |r: &Self, b: BondId| if effort { r.e(b) } else { r.f(b) };
            let target = var(self, b).1;
            // Fixed by states and sources along the causality already (a
            // capacitor beside one in integral causality): differentiating
            // that chain ends, and is written so unless its terms cancel.
            if known.contains(&target) {
                if self.eqs.iter().any(|e| e.lhs == der(q(target))) {
                    continue;
                }
                let def = self.eqs.iter().find(|e| e.lhs == q(target)).and_then(|e| {
                    let sum: Option<Vec<(i32, QtyId)>> = e
                        .rhs
                        .iter()
                        .map(|t| match (&t.mul, &t.div, &t.x) {
                            (None, None, Operand::Q(x)) if x.order == 0 => Some((t.coef, x.q)),
                            _ => None,
                        })
                        .collect();
                    Some((e.vertex, sum?))
                });
                if let Some((j, sum)) = def
                    && let Some(terms) = self.cancelled(&sum)
                {
                    self.eqs.push(Equation {
                        lhs: der(q(target)),
                        rhs: terms.into_iter().map(|(k, y)| term(k, der(q(y)))).collect(),
                        vertex: j,
                        element: None,
                        law: false,
                        of: None,
                        constraint: true,
                    });
                }
                continue;
            }
            // Efforts balance at 1-junctions, flows at 0-junctions: each
            // balance as Σ coef·quantity = 0.
            let kind = if effort {
                VertexKind::One
            } else {
                VertexKind::Zero
            };
            let mut relations: Vec<(VertexId, Vec<(i32, QtyId)>)> = Vec::new();
            for (j, x) in g.live_vertices().filter(|(_, x)| x.kind == kind) {
                let mut terms: Vec<(i32, QtyId)> = Vec::new();
                for &c in &x.bonds {
                    let side = if g.bonds[c].head == j { 1 } else { -1 };
                    let (sign, q) = var(self, c);
                    match terms.iter_mut().find(|(_, y)| *y == q) {
                        Some(t) => t.0 += side * sign,
                        None => terms.push((side * sign, q)),
                    }
                }
                terms.retain(|&(k, _)| k != 0);
                relations.push((j, terms));
            }
            let unknowns = |terms: &[(i32, QtyId)]| -> Option<Vec<QtyId>> {
                let u: Vec<(i32, QtyId)> = terms
                    .iter()
                    .copied()
                    .filter(|(_, q)| !known.contains(q))
                    .collect();
                (u.len() <= 2 && u.iter().all(|(k, _)| k.abs() == 1))
                    .then(|| u.into_iter().map(|(_, q)| q).collect())
            };
            // Breadth first from the target over balances with at most two
            // unknowns, to one whose only unknown is the last reached.
            let mut parent: HashMap<QtyId, (usize, QtyId)> = HashMap::new();
            let mut queue = std::collections::VecDeque::from([target]);
            let mut end = None;
            'search: while let Some(q) = queue.pop_front() {
                for (r, (_, terms)) in relations.iter().enumerate() {
                    if !terms.iter().any(|&(_, y)| y == q) {
                        continue;
                    }
                    let Some(u) = unknowns(terms) else {
                        continue;
                    };
                    match u.iter().find(|&&y| y != q) {
                        None => {
                            end = Some((q, r));
                            break 'search;
                        }
                        Some(&next) if next != target && !parent.contains_key(&next) => {
                            parent.insert(next, (r, q));
                            queue.push_back(next);
                        }
                        Some(_) => {}
                    }
                }
            }
            let Some((mut q, r)) = end else {
                // A capacitor between two nodes neither source nor state
                // fixes (a loop of capacitors away from every source): its
                // balance holds the two potentials, whose difference the
                // chain of balances from one to the other gives.
                if let Some(rhs) = difference_chain(&relations, &known, target) {
                    let j = relations
                        .iter()
                        .find(|(_, t)| t.iter().any(|&(_, y)| y == target))
                        .map_or(v, |(j, _)| *j);
                    let lhs = QRef {
                        q: target,
                        order: 1,
                    };
                    if !self.eqs.iter().any(|e| e.lhs == lhs) {
                        self.eqs.push(Equation {
                            lhs,
                            rhs,
                            vertex: j,
                            element: None,
                            law: false,
                            of: None,
                            constraint: true,
                        });
                    }
                }
                continue;
            };
            // From the far end back to the target: each balance solved for
            // the derivative of the quantity nearer the target.
            let mut chain = vec![(q, r)];
            while let Some(&(r, prev)) = parent.get(&q) {
                chain.push((prev, r));
                q = prev;
            }
            for (q, r) in chain {
                let lhs = QRef { q, order: 1 };
                if self.eqs.iter().any(|e| e.lhs == lhs) {
                    continue;
                }
                let (j, terms) = &relations[r];
                let Some(&(c, _)) = terms.iter().find(|(_, y)| *y == q) else {
                    continue;
                };
                let sum: Vec<(i32, QtyId)> = terms
                    .iter()
                    .filter(|(_, y)| *y != q)
                    .map(|&(k, y)| (-k * c, y))
                    .collect();
                let rhs = self
                    .cancelled(&sum)
                    .unwrap_or(sum)
                    .into_iter()
                    .map(|(k, y)| term(k, QRef { q: y, order: 1 }))
                    .collect();
                self.eqs.push(Equation {
                    lhs,
                    rhs,
                    vertex: *j,
                    element: None,
                    law: false,
                    of: None,
                    constraint: true,
                });
            }
        }
    }

    /// `sum` with its quantities written out through the balances and
    /// hand-overs that compute them (sums of other quantities, coefficients
    /// ±1), where that makes terms cancel: `v(3) − v(1)` with `v(1) = u_C3`
    /// and `v(3) = u_C3 − u_C0 − u_C1` is `−u_C0 − u_C1`, whose derivative
    /// does not read C3's. `None` where nothing cancels (the sum as it is
    /// names the junctions along the way, as the seeds write them).
    fn cancelled(&self, sum: &[(i32, QtyId)]) -> Option<Vec<(i32, QtyId)>> {
        let mut defs: HashMap<QtyId, Vec<(i32, QtyId)>> = HashMap::new();
        for e in &self.eqs {
            if e.lhs.order != 0 || self.quantities[e.lhs.q].kind == QtyKind::State {
                continue;
            }
            let unit: Option<Vec<(i32, QtyId)>> = e
                .rhs
                .iter()
                .map(|t| match (&t.mul, &t.div, &t.x) {
                    (None, None, Operand::Q(x)) if x.order == 0 && t.coef.abs() == 1 => {
                        Some((t.coef, x.q))
                    }
                    _ => None,
                })
                .collect();
            if let Some(unit) = unit {
                defs.entry(e.lhs.q).or_insert(unit);
            }
        }
        let mut expr: Vec<(i32, QtyId)> = sum.to_vec();
        // Each round writes out every quantity that has a definition; the
        // definitions may loop (an algebraic loop of balances), so the
        // rounds are bounded.
        for _ in 0..self.eqs.len().min(64) {
            let mut next: Vec<(i32, QtyId)> = Vec::new();
            let mut changed = false;
            for &(k, q) in &expr {
                match defs.get(&q) {
                    Some(d) => {
                        changed = true;
                        next.extend(d.iter().map(|&(c, y)| (k * c, y)));
                    }
                    None => next.push((k, q)),
                }
            }
            expr = next;
            if !changed {
                break;
            }
        }
        let mut merged: Vec<(i32, QtyId)> = Vec::new();
        for (k, q) in expr {
            match merged.iter_mut().find(|(_, y)| *y == q) {
                Some(t) => t.0 += k,
                None => merged.push((k, q)),
            }
        }
        let before = merged.len();
        merged.retain(|&(k, _)| k != 0);
        (merged.len() < before).then(|| {
            merged.sort_by_key(|&(_, q)| q);
            merged
        })
    }

    /// Sort: strongly connected components of "computes what reads".
    fn sort(&self) -> (Vec<Step>, Vec<QRef>, Vec<QRef>) {
        let mut computed: HashMap<QRef, usize> = HashMap::new();
        let mut twice = Vec::new();
        for (k, e) in self.eqs.iter().enumerate() {
            if computed.insert(e.lhs, k).is_some() && !twice.contains(&e.lhs) {
                twice.push(e.lhs);
            }
        }
        // The first equation of a quantity computed twice computes it.
        for (k, e) in self.eqs.iter().enumerate().rev() {
            computed.insert(e.lhs, k);
        }
        let mut edges = Vec::new();
        let mut unknown = Vec::new();
        let mut self_loop = vec![false; self.eqs.len()];
        for (k, e) in self.eqs.iter().enumerate() {
            for r in deps(e) {
                match computed.get(&r) {
                    Some(&j) => {
                        if j == k {
                            self_loop[k] = true;
                        }
                        edges.push((j as u32, k as u32));
                    }
                    None => {
                        let known = r.order == 0 && self.quantities[r.q].kind == QtyKind::State;
                        if !known && r.order <= MAX_ORDER && !unknown.contains(&r) {
                            unknown.push(r);
                        }
                    }
                }
            }
        }
        let comps =
            crate::analysis::graph::strong_components(self.eqs.len(), edges.iter().copied());
        let mut steps = Vec::new();
        for comp in in_order(&comps, &edges) {
            let comp: Vec<usize> = comps[comp].iter().map(|&k| k as usize).collect();
            if comp.len() == 1 && !self_loop[comp[0]] {
                steps.push(Step::Assign(comp[0]));
                continue;
            }
            steps.push(Step::Loop(self.describe_loop(comp)));
        }
        (steps, twice, unknown)
    }

    fn describe_loop(&self, eqs: Vec<usize>) -> Loop {
        let mut elements: Vec<ElemId> = eqs
            .iter()
            .filter(|&&k| self.eqs[k].law)
            .filter_map(|&k| self.eqs[k].element)
            .collect();
        elements.sort();
        elements.dedup();
        let vertices: Vec<VertexId> = eqs.iter().map(|&k| self.eqs[k].vertex).collect();
        let mut arbitrary: Vec<VertexId> = self
            .c
            .decisions
            .iter()
            .filter(|d| matches!(d.phase, Phase::Arbitrary | Phase::Open))
            .map(|d| d.vertex)
            .filter(|v| vertices.contains(v))
            .collect();
        arbitrary.sort();
        arbitrary.dedup();
        let mut derivative: Vec<VertexId> = self
            .c
            .derivative()
            .map(|s| s.vertex)
            .filter(|v| vertices.contains(v))
            .collect();
        derivative.sort();
        derivative.dedup();
        Loop {
            eqs,
            elements,
            arbitrary,
            derivative,
        }
    }
}

/// `d/dt` of `target` from the balance that holds it and two unknowns `a`,
/// `b` (`target = ±a ∓ b + known`), with `a − b` eliminated along a chain
/// of balances of two unknowns each, or each of them along a chain to a
/// balance where it is the only unknown. `None` where no such chain leaves
/// only known quantities.
fn difference_chain(
    relations: &[(VertexId, Vec<(i32, QtyId)>)],
    known: &HashSet<QtyId>,
    target: QtyId,
) -> Option<Vec<Term>> {
    let unknown = |terms: &[(i32, QtyId)]| -> Vec<(i32, QtyId)> {
        terms
            .iter()
            .copied()
            .filter(|(_, q)| !known.contains(q))
            .collect()
    };
    let (r0, terms0) = relations.iter().enumerate().find_map(|(r, (_, t))| {
        let u = unknown(t);
        (u.len() == 3 && u.iter().all(|(k, _)| k.abs() == 1) && u.iter().any(|&(_, q)| q == target))
            .then_some((r, t))
    })?;
    let ct = terms0.iter().find(|(_, q)| *q == target)?.0;
    // target = −ct · Σ k·q over the rest.
    let mut expr: HashMap<QtyId, i32> = HashMap::new();
    for &(k, q) in terms0.iter().filter(|(_, q)| *q != target) {
        *expr.entry(q).or_default() -= ct * k;
    }
    let ends: Vec<QtyId> = unknown(terms0)
        .into_iter()
        .map(|(_, q)| q)
        .filter(|&q| q != target)
        .collect();
    // Breadth first from the first unknown over balances of two unknowns
    // (not the first balance) to the second unknown or to a balance of one.
    let eliminate = |start: QtyId, stop: Option<QtyId>, expr: &mut HashMap<QtyId, i32>| {
        let mut parent: HashMap<QtyId, (usize, QtyId)> = HashMap::new();
        let mut queue = std::collections::VecDeque::from([start]);
        let mut end: Option<(QtyId, Option<usize>)> = None;
        'search: while let Some(q) = queue.pop_front() {
            if Some(q) == stop {
                end = Some((q, None));
                break;
            }
            for (r, (_, terms)) in relations.iter().enumerate() {
                if r == r0 || !terms.iter().any(|&(_, y)| y == q) {
                    continue;
                }
                let u = unknown(terms);
                if u.len() > 2 || u.iter().any(|(k, _)| k.abs() != 1) {
                    continue;
                }
                match u.iter().find(|&&(_, y)| y != q) {
                    None if stop.is_none() => {
                        end = Some((q, Some(r)));
                        break 'search;
                    }
                    Some(&(_, next)) if next != start && !parent.contains_key(&next) => {
                        parent.insert(next, (r, q));
                        queue.push_back(next);
                    }
                    _ => {}
                }
            }
        }
        let (last, last_r) = end?;
        // The relations from `start` on, in order.
        let mut steps: Vec<(QtyId, usize)> = Vec::new();
        let mut q = last;
        while let Some(&(r, prev)) = parent.get(&q) {
            steps.push((prev, r));
            q = prev;
        }
        steps.reverse();
        if let Some(r) = last_r {
            steps.push((last, r));
        }
        for (cur, r) in steps {
            let a = expr.remove(&cur).unwrap_or(0);
            let terms = &relations[r].1;
            let c = terms.iter().find(|(_, y)| *y == cur)?.0;
            for &(k, y) in terms.iter().filter(|(_, y)| *y != cur) {
                *expr.entry(y).or_default() -= a * c * k;
            }
        }
        expr.retain(|_, k| *k != 0);
        Some(())
    };
    let (a, b) = (ends[0], ends[1]);
    if eliminate(a, Some(b), &mut expr).is_none() {
        eliminate(a, None, &mut expr)?;
        eliminate(b, None, &mut expr)?;
    }
    if expr.keys().any(|q| !known.contains(q)) {
        return None;
    }
    let mut terms: Vec<(QtyId, i32)> = expr.into_iter().collect();
    terms.sort();
    Some(
        terms
            .into_iter()
            .map(|(q, k)| term(k, QRef { q, order: 1 }))
            .collect(),
    )
}

/// The components in a topological order that takes, of those ready, the
/// one with the lowest equation first: the listing follows the order the
/// graph was read in wherever the dependencies leave a choice.
fn in_order(comps: &[Vec<u32>], edges: &[(u32, u32)]) -> Vec<usize> {
    use std::cmp::Reverse;
    use std::collections::BinaryHeap;
    let n: usize = comps.iter().map(Vec::len).sum();
    let mut comp_of = vec![0usize; n];
    for (c, comp) in comps.iter().enumerate() {
        for &k in comp {
            comp_of[k as usize] = c;
        }
    }
    let mut succ: Vec<Vec<usize>> = vec![Vec::new(); comps.len()];
    let mut preds = vec![0usize; comps.len()];
    for &(a, b) in edges {
        let (ca, cb) = (comp_of[a as usize], comp_of[b as usize]);
        if ca != cb {
            succ[ca].push(cb);
            preds[cb] += 1;
        }
    }
    let first = |c: usize| comps[c].iter().copied().min().unwrap_or(0);
    let mut ready: BinaryHeap<Reverse<(u32, usize)>> = (0..comps.len())
        .filter(|&c| preds[c] == 0)
        .map(|c| Reverse((first(c), c)))
        .collect();
    let mut out = Vec::with_capacity(comps.len());
    while let Some(Reverse((_, c))) = ready.pop() {
        out.push(c);
        for &d in &succ[c] {
            preds[d] -= 1;
            if preds[d] == 0 {
                ready.push(Reverse((first(d), d)));
            }
        }
    }
    out
}

/// What an equation reads.
pub fn deps(e: &Equation) -> Vec<QRef> {
    let mut out = Vec::new();
    let mut args = |args: &[(i32, QRef)], order: u8| {
        for &(_, a) in args {
            for d in 0..=order {
                out.push(QRef {
                    q: a.q,
                    order: a.order + d,
                });
            }
        }
    };
    for t in &e.rhs {
        for f in [&t.mul, &t.div].into_iter().flatten() {
            if let Factor::Law { args: a, .. } = f {
                args(a, 0);
            }
        }
        match &t.x {
            Operand::Q(x) => args(&[(1, *x)], 0),
            Operand::Source { .. } => {}
            Operand::Law { args: a, order, .. } => args(a, *order),
        }
    }
    out.sort();
    out.dedup();
    out
}

/// `d/dt` of equation `e` (number `of`): parameters are constant; a term
/// with a law for a coefficient becomes the derivative of the whole term.
fn differentiate(e: &Equation, of: usize) -> Equation {
    let rhs = e
        .rhs
        .iter()
        .map(|t| {
            let law_factor = [&t.mul, &t.div]
                .into_iter()
                .flatten()
                .any(|f| matches!(f, Factor::Law { .. }));
            if law_factor {
                let mut args: Vec<(i32, QRef)> = Vec::new();
                for f in [&t.mul, &t.div].into_iter().flatten() {
                    if let Factor::Law { args: a, .. } = f {
                        args.extend(a.iter().copied());
                    }
                }
                if let Operand::Q(x) = t.x {
                    args.push((1, x));
                }
                let single = Term {
                    coef: 1,
                    ..t.clone()
                };
                return Term {
                    coef: t.coef,
                    mul: None,
                    div: None,
                    x: Operand::Law {
                        name: format!("({})", print_terms(&[single], &|_| String::new())),
                        args,
                        order: 1,
                    },
                };
            }
            let x = match &t.x {
                Operand::Q(x) => Operand::Q(der(*x)),
                Operand::Source { name, order } => Operand::Source {
                    name: name.clone(),
                    order: order + 1,
                },
                Operand::Law { name, args, order } => Operand::Law {
                    name: name.clone(),
                    args: args.clone(),
                    order: order + 1,
                },
            };
            Term { x, ..t.clone() }
        })
        .collect();
    Equation {
        lhs: der(e.lhs),
        rhs,
        vertex: e.vertex,
        element: e.element,
        law: e.law,
        of: Some(of),
        constraint: false,
    }
}

fn wrap_der(s: String, order: u8) -> String {
    (0..order).fold(s, |s, _| format!("der({s})"))
}

/// A quantity reference as text, given the names.
pub fn print_ref(x: QRef, name: &dyn Fn(QtyId) -> String) -> String {
    wrap_der(name(x.q), x.order)
}

fn print_args(args: &[(i32, QRef)], name: &dyn Fn(QtyId) -> String) -> String {
    args.iter()
        .map(|&(c, x)| {
            let s = print_ref(x, name);
            match c {
                1 => s,
                -1 => format!("-{s}"),
                c => format!("{c}*{s}"),
            }
        })
        .collect::<Vec<_>>()
        .join(", ")
}

fn print_factor(f: &Factor, name: &dyn Fn(QtyId) -> String) -> String {
    match f {
        Factor::Param(p) => p.clone(),
        Factor::Law { name: n, args } => format!("{n}({})", print_args(args, name)),
    }
}

/// A sum of terms as text (`0` when empty).
pub fn print_terms(terms: &[Term], name: &dyn Fn(QtyId) -> String) -> String {
    let mut s = String::new();
    for (k, t) in terms.iter().enumerate() {
        let neg = t.coef < 0;
        match (k, neg) {
            (0, true) => s.push('-'),
            (0, false) => {}
            (_, true) => s.push_str(" - "),
            (_, false) => s.push_str(" + "),
        }
        if t.coef.abs() != 1 {
            s.push_str(&format!("{}*", t.coef.abs()));
        }
        if let Some(m) = &t.mul {
            s.push_str(&print_factor(m, name));
            s.push('*');
        }
        s.push_str(&match &t.x {
            Operand::Q(x) => print_ref(*x, name),
            Operand::Source { name: n, order } => wrap_der(format!("{n}(t)"), *order),
            Operand::Law {
                name: n,
                args,
                order,
            } => wrap_der(format!("{n}({})", print_args(args, name)), *order),
        });
        if let Some(d) = &t.div {
            s.push('/');
            s.push_str(&print_factor(d, name));
        }
    }
    if s.is_empty() {
        s.push('0');
    }
    s
}

impl ReadOff {
    /// A quantity's name.
    pub fn name(&self, q: QtyId) -> String {
        self.quantities
            .get(q)
            .map_or_else(|| "?".to_string(), |x| x.name.clone())
    }

    /// Equation `k` as `lhs := rhs`.
    pub fn print(&self, k: usize) -> String {
        let e = &self.equations[k];
        let name = |q: QtyId| self.name(q);
        format!(
            "{} := {}",
            print_ref(e.lhs, &name),
            print_terms(&e.rhs, &name)
        )
    }

    /// A bond's effort or flow as text: `v(a)`, `-i_V1`.
    pub fn bond_var(&self, b: BondId, var: Var) -> String {
        let x = match var {
            Var::Effort => self.effort.get(b.0 as usize),
            Var::Flow => self.flow.get(b.0 as usize),
        };
        match x.copied().flatten() {
            Some((s, q)) if s < 0 => format!("-{}", self.name(q)),
            Some((_, q)) => self.name(q),
            None => "?".to_string(),
        }
    }

    /// The loops of the sorted equations.
    pub fn loops(&self) -> impl Iterator<Item = &Loop> {
        self.steps.iter().filter_map(|s| match s {
            Step::Loop(l) => Some(l),
            Step::Assign(_) => None,
        })
    }
}
