//! Bond graphs (seeds 002 and 003): the circuit seen from the energy side.
//!
//! [`draw`] follows seed 003's procedure: a 0-junction for every node
//! potential, a 1-junction with a 0-junction for every potential difference
//! an element needs, the element ports attached (Se, Sf, R, C, I, TF, GY,
//! modulated sources, a multiport I-field for coupled inductors), then the
//! simplification rules of step 8, each removal logged with its rule
//! (`build.rs`, `simplify.rs`). [`scap::assign`] puts the causal strokes on
//! by SCAP in seed 002's order: sources, propagated through the junction
//! constraints; storage in preferred integral causality, one at a time;
//! resistors arbitrarily, last. [`equations::read_off`] writes the equations
//! the causal graph stands for and sorts them; [`check::check`] compares all
//! of it with the colouring and index reduction of the same circuit. The
//! printers (`print.rs`: text and JSON; `dot.rs`: Graphviz) draw it.
//!
//! It knows the elaborated circuit and, for the cross-check only, the sorted
//! equations ([`crate::pipeline::Sorted`]); it changes neither and runs no
//! program (the command line turns the DOT text into SVG).

mod build;
pub mod check;
mod dot;
pub mod equations;
mod error;
mod print;
pub mod scap;
mod simplify;

use std::collections::HashMap;

pub use check::{Check, check};
pub use dot::dot;
pub use equations::{ReadOff, read_off};
pub use error::BondGraphError;
pub use print::{json, text};
pub use scap::{Causality, Stroke};

use crate::elab::{Circuit, ElemId, NodeId};

crate::entity_id!(
    /// A vertex of a bond graph: a junction or an element (port group).
    VertexId,
    "g"
);
crate::entity_id!(
    /// A bond: one power connection between two vertices, its half-arrow
    /// pointing at `head` (power positive from tail to head).
    BondId,
    "b"
);

/// What a vertex is, by the bond-graph alphabet.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum VertexKind {
    /// Common effort; flows sum to zero.
    Zero,
    /// Common flow; efforts sum to zero.
    One,
    Se,
    Sf,
    /// A source modulated by signals (a controlled source, a B source).
    MSe,
    MSf,
    R,
    /// A resistor modulated by a signal (a switch).
    MR,
    C,
    I,
    /// Coupled inductors: one port per winding.
    IField,
    Tf,
    Gy,
}

impl VertexKind {
    /// The symbol a textbook writes (`Se`, `0`, `TF`).
    pub fn symbol(self) -> &'static str {
        match self {
            VertexKind::Zero => "0",
            VertexKind::One => "1",
            VertexKind::Se => "Se",
            VertexKind::Sf => "Sf",
            VertexKind::MSe => "MSe",
            VertexKind::MSf => "MSf",
            VertexKind::R => "R",
            VertexKind::MR => "MR",
            VertexKind::C => "C",
            VertexKind::I => "I",
            VertexKind::IField => "IF",
            VertexKind::Tf => "TF",
            VertexKind::Gy => "GY",
        }
    }

    pub fn is_junction(self) -> bool {
        matches!(self, VertexKind::Zero | VertexKind::One)
    }

    /// Sources, whose causality is fixed.
    pub fn is_source(self) -> bool {
        matches!(
            self,
            VertexKind::Se | VertexKind::Sf | VertexKind::MSe | VertexKind::MSf
        )
    }

    /// Storage, whose causality is preferred (integral).
    pub fn is_storage(self) -> bool {
        matches!(self, VertexKind::C | VertexKind::I | VertexKind::IField)
    }

    /// Resistors, whose causality is arbitrary.
    pub fn is_resistor(self) -> bool {
        matches!(self, VertexKind::R | VertexKind::MR)
    }
}

/// The part of an element a vertex stands for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum Part {
    /// The whole element.
    Whole,
    /// A diode's or device branch's current.
    Current,
    /// A junction's or device branch's charge (a nonlinear C).
    Charge,
    /// A device branch's capacitance (Meyer's gate capacitances).
    Capacitance,
    /// A diode's series resistance RS.
    Series,
}

/// What a vertex stands for in the circuit.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Origin {
    /// The 0-junction of a node potential.
    Node(NodeId),
    /// A junction of the potential difference `v(a) − v(b)`.
    Difference(NodeId, NodeId),
    /// An element, or a part of one.
    Element { elem: ElemId, part: Part },
    /// Two controlled sources that together are one transformer or
    /// gyrator: `first` owns port 1, `second` port 2.
    Pair { first: ElemId, second: ElemId },
    /// Inductors joined by K elements: one port per member.
    Field {
        members: Vec<ElemId>,
        couplings: Vec<ElemId>,
    },
    /// A junction inside an element (a diode's, behind RS).
    Inner { elem: ElemId },
}

/// Which way an element port's half-arrow points: power into the element
/// (consumed or stored) or out of it (supplied).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Power {
    In,
    Out,
}

/// The circuit names of one element port's effort and flow: the bond's
/// effort is `effort_sign · effort`, its flow `flow_sign · flow`.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct PortNames {
    pub effort: String,
    pub flow: String,
    pub effort_sign: i8,
    pub flow_sign: i8,
}

/// A state of the equations a storage port stands for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
pub struct StateKey {
    pub elem: ElemId,
    pub kind: StateKind,
}

/// The kind of state: a capacitor's voltage, an inductor's current (or a
/// winding's magnetizing current), a junction's charge.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StateKind {
    Voltage,
    Current,
    Charge,
}

/// A signal a modulated vertex reads (no power flows along it).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Signal {
    /// A node's potential.
    Potential(NodeId),
    /// An element's current (`i(v1)`).
    Current(ElemId),
    /// An element's branch voltage (device branches read each other's).
    Voltage(ElemId),
}

/// An element's constitutive law, as far as the bond graph needs it.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Law {
    /// Junctions: balances only.
    Junction,
    /// A constant: resistance, capacitance, inductance, a transformer's
    /// modulus or a gyrator's conductance, named as the equations name it
    /// (`negated`: the coefficient is `−param`).
    Linear {
        param: String,
        value: f64,
        negated: bool,
    },
    /// An independent source's waveform, `V1(t)`.
    Source { name: String },
    /// A controlled source: `param · Σ coef·signal`.
    Controlled { param: String, value: f64 },
    /// A nonlinear or modulated law named `name` (`id_D1`, `B1`) of the
    /// port's own variable and the vertex's signals.
    Nonlinear { name: String },
    /// A switch: `i = g·u`, `g` set by the simulator as the switch turns.
    Switch { param: String },
    /// Coupled inductors.
    Field(Box<FieldLaw>),
}

/// The law of an I-field: `u = L·di/dt`, `L` the inductance matrix.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct FieldLaw {
    /// Self-inductance parameter of each port (`L1`).
    pub inductance: Vec<String>,
    /// Mutual inductances between ports `j`, `k` (`M_K1`).
    pub mutual: Vec<(usize, usize, String)>,
    /// A singular matrix (perfect coupling, seen by the build's
    /// `coupling`): the pivots, whose fluxes are the states.
    pub singular: Option<SingularField>,
}

/// A perfectly coupled field: `rank` windings carry the fluxes.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct SingularField {
    /// Ports whose magnetizing currents are the states.
    pub pivots: Vec<usize>,
    /// `im_p = Σ_k n_pk·i_k` for each pivot: its terms, by port, with the
    /// coefficient's name (`None`: the pivot's own current, coefficient 1).
    pub flux: Vec<Vec<(usize, Option<String>)>>,
    /// `u_q = Σ_j c_qj·u_pivot(j)` for each other port `q`: its terms, by
    /// index into `pivots`, with the coefficient's name.
    pub ratio: Vec<(usize, Vec<(usize, String)>)>,
}

/// A vertex of the graph.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Vertex {
    pub kind: VertexKind,
    /// `a` (a node), `a,b` (a difference), `R1`, `D1.rs`, `F1·E1`, `L1·L2`.
    pub label: String,
    pub origin: Origin,
    /// The bonds at this vertex; for an element its ports in order (a
    /// transformer's primary first, a field's windings in circuit order).
    pub bonds: Vec<BondId>,
    /// An element's port names, one per bond.
    pub ports: Vec<PortNames>,
    /// A storage element's state, one per port (a perfectly coupled field's
    /// windings past its rank too: the states the equations never have).
    pub states: Vec<Option<StateKey>>,
    pub law: Law,
    /// Signals read: a controlled source's control (with coefficients), a
    /// modulated element's inputs.
    pub signals: Vec<(i32, Signal)>,
    /// A junction's effort (0) or flow (1) name, with its sign.
    pub name: Option<(String, i8)>,
    /// Taken out by a simplification rule.
    pub removed: bool,
}

/// A bond.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct Bond {
    pub tail: VertexId,
    pub head: VertexId,
    pub removed: bool,
}

impl Bond {
    /// The other end from `v`.
    pub fn other(&self, v: VertexId) -> VertexId {
        if self.tail == v { self.head } else { self.tail }
    }
}

/// The simplification rules of seed 003's step 8.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum Rule {
    /// 8a: the reference node's 0-junction is dropped (its effort is zero).
    A,
    /// 8b: a junction with one bond in and one out is dropped.
    B,
    /// 8c: two equal junctions joined by a bond are merged.
    C,
    /// 8d: two equal differences are one.
    D,
}

/// One application of a rule.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Simplification {
    pub rule: Rule,
    /// The vertex removed (8a, 8b, 8c) or the difference reused (8d).
    pub vertex: VertexId,
    /// 8b: the bond that now joins the two neighbours; 8c: the bond removed.
    pub bond: Option<BondId>,
    /// 8b: the two neighbours the bond joins (tail, head), as it was done.
    pub joins: Option<(VertexId, VertexId)>,
    /// 8c: the junction merged into.
    pub into: Option<VertexId>,
    /// 8d: the element whose difference was already there.
    pub elem: Option<ElemId>,
    /// Bonds removed with the vertex (8a).
    pub dropped: Vec<BondId>,
}

/// A remark on how an element was drawn (an element with no bond-graph
/// form of its own, a degenerate connection).
#[derive(Clone, Debug, serde::Serialize)]
pub struct Note {
    pub elem: Option<ElemId>,
    pub text: String,
}

/// An effort or a flow of a bond.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
pub enum Var {
    Effort,
    Flow,
}

/// One bond variable.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
pub struct Atom {
    pub bond: BondId,
    pub var: Var,
}

/// A sum of bond variables with integer coefficients.
pub type Lin = Vec<(i32, Atom)>;

/// An element's branch voltage and current in bond variables, as drawn
/// (before simplification; [`BondGraph::resolve`] follows the rules).
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct ElementPorts {
    pub vertices: Vec<VertexId>,
    pub voltage: Lin,
    pub current: Lin,
}

/// A circuit as a bond graph.
#[derive(Clone, Debug)]
pub struct BondGraph {
    pub title: String,
    pub vertices: crate::ir::IdVec<VertexId, Vertex>,
    pub bonds: crate::ir::IdVec<BondId, Bond>,
    /// The rules applied, in order.
    pub simplified: Vec<Simplification>,
    pub notes: Vec<Note>,
    /// Element names, by element id.
    pub element_names: Vec<String>,
    /// Node names, by node id (ground is `0`).
    pub node_names: Vec<String>,
    /// How each element's voltage and current are drawn, by element id.
    pub elements: Vec<ElementPorts>,
    /// Each element's netlist line, by element id.
    pub element_spans: Vec<crate::diag::Span>,
    /// A bond of each node's 0-junction as built (its effort is the node's
    /// potential); `None` for ground and for nodes no element's power
    /// reaches.
    witness: Vec<Option<BondId>>,
    /// Bond variables removed by simplification, in variables that were
    /// still there: a DAG, since a removal only names living bonds.
    forward: HashMap<Atom, Lin>,
}

/// Draw `circuit` as a bond graph: seed 003's procedure, then its
/// simplification rules.
pub fn draw(circuit: &Circuit) -> BondGraph {
    let mut g = build::build(circuit);
    simplify::simplify(&mut g);
    g
}

/// Everything `kausal bondgraph` shows: the graph, its causality, and the
/// equations read off it.
pub struct Analysis {
    pub graph: BondGraph,
    pub causality: Causality,
    pub equations: ReadOff,
}

/// Draw the graph, assign causality by SCAP and read the equations off.
pub fn analyse(circuit: &Circuit) -> Analysis {
    let graph = draw(circuit);
    let (causality, equations) = assign(&graph, scap::Options::default());
    Analysis {
        graph,
        causality,
        equations,
    }
}

/// SCAP and the equations read off, until no loop of junctions alone is
/// left. Such a loop (its equations balances only, no element's law) is a
/// constraint between the states that feed it: a loop of capacitors or a
/// cutset of inductors away from every source, where propagation finds one
/// bond setting each junction's variable and yet the efforts (or flows)
/// around the loop add up to nothing. The storage port SCAP took last among
/// those feeding it is fixed in derivative causality (SCAP's 1b) and SCAP
/// runs again; each round fixes one more port, so the rounds end.
pub fn assign(g: &BondGraph, mut opts: scap::Options) -> (Causality, ReadOff) {
    loop {
        let c = scap::assign(g, &opts);
        let r = read_off(g, &c);
        match junction_loop_state(g, &c, &r) {
            Some(k) if !opts.force.contains(&k) => opts.force.push(k),
            _ => return (c, r),
        }
    }
}

/// The state a loop of junctions alone is to be broken at: of the states
/// reaching the loop through balances, hand-overs and storage laws only,
/// the one whose port SCAP decided last.
fn junction_loop_state(g: &BondGraph, c: &Causality, r: &ReadOff) -> Option<StateKey> {
    let computed: HashMap<equations::QRef, usize> = r
        .equations
        .iter()
        .enumerate()
        .map(|(k, e)| (e.lhs, k))
        .collect();
    for l in r.loops().filter(|l| l.elements.is_empty()) {
        let mut seen: Vec<usize> = l.eqs.clone();
        let mut stack: Vec<usize> = l.eqs.clone();
        let mut best: Option<(Option<usize>, BondId, StateKey)> = None;
        while let Some(k) = stack.pop() {
            for d in equations::deps(&r.equations[k]) {
                if let Some(&(_, v, b)) = r.state_ports.iter().find(|(q, ..)| *q == d.q) {
                    let x = &g.vertices[v];
                    let port = x.bonds.iter().position(|&y| y == b).unwrap_or(0);
                    if let Some(key) = x.states.get(port).copied().flatten() {
                        let cause = c.cause.get(b.0 as usize).copied().flatten();
                        if best.is_none_or(|(bc, bb, _)| (cause, b) > (bc, bb)) {
                            best = Some((cause, b, key));
                        }
                    }
                    continue;
                }
                if let Some(&j) = computed.get(&d) {
                    let e = &r.equations[j];
                    // Balances and hand-overs, and a storage port's own
                    // law from its state (a junction charge's voltage
                    // `Q^-1(q)`), lead back to the states.
                    let through =
                        e.element.is_none() || !e.law || g.vertices[e.vertex].kind.is_storage();
                    if through && !seen.contains(&j) {
                        seen.push(j);
                        stack.push(j);
                    }
                }
            }
        }
        if let Some((_, _, key)) = best {
            return Some(key);
        }
    }
    None
}

impl BondGraph {
    /// The vertices still in the graph.
    pub fn live_vertices(&self) -> impl Iterator<Item = (VertexId, &Vertex)> {
        self.vertices.iter().filter(|(_, v)| !v.removed)
    }

    /// The bonds still in the graph.
    pub fn live_bonds(&self) -> impl Iterator<Item = (BondId, &Bond)> {
        self.bonds.iter().filter(|(_, b)| !b.removed)
    }

    /// A vertex's name as a textbook writes it: `0:a`, `1:a,b`, `R:R1`.
    pub fn vertex_name(&self, v: VertexId) -> String {
        let x = &self.vertices[v];
        format!("{}:{}", x.kind.symbol(), x.label)
    }

    /// An element's netlist line.
    pub fn element_span(&self, e: ElemId) -> Option<crate::diag::Span> {
        self.element_spans.get(e.0 as usize).copied()
    }

    /// An element's name.
    pub fn element_name(&self, e: ElemId) -> &str {
        self.element_names
            .get(e.0 as usize)
            .map_or("?", String::as_str)
    }

    /// The element a vertex belongs to, if it is one (a pair or field: the
    /// first).
    pub fn element_of(&self, v: VertexId) -> Option<ElemId> {
        match &self.vertices[v].origin {
            Origin::Element { elem, .. } | Origin::Inner { elem } => Some(*elem),
            Origin::Pair { first, .. } => Some(*first),
            Origin::Field { members, .. } => members.first().copied(),
            Origin::Node(_) | Origin::Difference(..) => None,
        }
    }

    /// The elements a vertex stands for (both of a pair, every winding of a
    /// field).
    pub fn elements_of(&self, v: VertexId) -> Vec<ElemId> {
        match &self.vertices[v].origin {
            Origin::Element { elem, .. } | Origin::Inner { elem } => vec![*elem],
            Origin::Pair { first, second } => vec![*first, *second],
            Origin::Field { members, .. } => members.clone(),
            Origin::Node(_) | Origin::Difference(..) => Vec::new(),
        }
    }

    /// `lin` in variables of bonds still in the graph: removed bonds are
    /// replaced by what the rules made of them. Terms that cancel are
    /// dropped; the result is sorted by bond.
    pub fn resolve(&self, lin: &Lin) -> Lin {
        let mut out: std::collections::BTreeMap<Atom, i32> = Default::default();
        // The forward map is a DAG; this budget only bounds the work on a
        // graph whose forwards grew unusually long.
        let mut budget = 1_000_000usize;
        let mut stack: Vec<(i32, Atom)> = lin.clone();
        while let Some((c, a)) = stack.pop() {
            if budget == 0 {
                break;
            }
            budget -= 1;
            if !self.bonds[a.bond].removed {
                *out.entry(a).or_default() += c;
            } else if let Some(f) = self.forward.get(&a) {
                stack.extend(f.iter().map(|&(k, b)| (c * k, b)));
            }
        }
        out.into_iter()
            .filter(|&(_, c)| c != 0)
            .map(|(a, c)| (c, a))
            .collect()
    }

    /// A signal in variables of bonds still in the graph (`None`: the node
    /// carries no bond, so the graph does not know its potential).
    pub fn signal(&self, s: Signal) -> Option<Lin> {
        match s {
            Signal::Potential(n) if n == crate::elab::GROUND => Some(Vec::new()),
            Signal::Potential(n) => {
                let b = self.witness.get(n.0 as usize).copied().flatten()?;
                Some(self.resolve(&vec![(
                    1,
                    Atom {
                        bond: b,
                        var: Var::Effort,
                    },
                )]))
            }
            Signal::Current(e) => Some(self.resolve(&self.elements.get(e.0 as usize)?.current)),
            Signal::Voltage(e) => Some(self.resolve(&self.elements.get(e.0 as usize)?.voltage)),
        }
    }

    /// A signal's name as the netlist writes it (`v(a)`, `i(v1)`, `u_Q1:be`).
    pub fn signal_name(&self, s: Signal) -> String {
        match s {
            Signal::Potential(n) => format!(
                "v({})",
                self.node_names
                    .get(n.0 as usize)
                    .map_or("?", String::as_str)
            ),
            Signal::Current(e) => format!("i({})", self.element_name(e).to_ascii_lowercase()),
            Signal::Voltage(e) => format!("u_{}", self.element_name(e)),
        }
    }
}
