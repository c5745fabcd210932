//! SCAP, the sequential causality assignment procedure, in seed 002's order
//! with seed 003's constraints:
//!
//! 1. fixed causality: every source (Se gives effort, Sf flow; a junction
//!    with a single bond is a source of zero flow or zero effort), each
//!    propagated at once (1a); then ports whose law cannot be inverted: the
//!    windings of a perfectly coupled I-field past its rank, whose inductance
//!    matrix has no inverse, and storage that a loop of junctions alone
//!    fixes (1b, found by [`crate::bondgraph::analyse`]);
//! 2. preferred causality: each storage port in turn gets integral causality
//!    (C gives effort, I takes it) unless propagation has already decided
//!    it, and is propagated;
//! 3. arbitrary causality: each resistor still open gets one (it takes the
//!    flow, `e = R·f`), propagated; a choice here closes an algebraic loop;
//! 4. any bond still open (a loop of junctions only) is chosen the same way.
//!
//! A choice (phases 2 to 4) that leads to a broken constraint, at once or
//! later, is taken back and the other causality tried, latest choice first,
//! as seed 002 says (go back and change it): a storage port then ends in
//! derivative causality, a resistor takes the effort. A search that runs out
//! of its budget, or constraints broken by the sources alone, leave the
//! choices to be made one by one, each turned only if it breaks a
//! constraint at once.
//!
//! Propagation applies the junction constraints (a 0-junction has exactly
//! one bond that sets its effort, a 1-junction exactly one that sets its
//! flow), a transformer's (one port takes effort, the other gives it) and a
//! gyrator's (both ports alike). When every bond is set, each vertex is
//! checked; what breaks a constraint is a causal conflict.
//!
//! A bond's causality is the end its stroke is drawn at: the vertex there
//! receives the effort and gives the flow.

use std::collections::VecDeque;

use super::{BondGraph, BondId, Law, StateKey, Vertex, VertexId, VertexKind};

/// The end of a bond whose vertex receives the effort (where the causal
/// stroke is drawn).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Stroke {
    Head,
    Tail,
}

/// The step of SCAP that set a bond.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Phase {
    /// 1a: a source.
    Source,
    /// 1b: a port whose law cannot be inverted.
    Fixed,
    /// 2: a storage port's integral causality.
    Preferred,
    /// 3: a resistor's arbitrary causality.
    Arbitrary,
    /// 4: a junction bond's arbitrary causality.
    Open,
}

/// One decision of SCAP and the bonds its propagation set.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Decision {
    pub phase: Phase,
    pub vertex: VertexId,
    pub bond: BondId,
    /// Bonds set by propagating this decision, in order.
    pub propagated: Vec<BondId>,
    /// The preferred (or first) causality broke a constraint; this is the
    /// other one.
    pub turned: bool,
}

/// A storage port's outcome.
#[derive(Clone, Debug, serde::Serialize)]
pub struct StoragePort {
    pub vertex: VertexId,
    pub bond: BondId,
    /// Port index at the vertex (a field's winding).
    pub port: usize,
    pub state: Option<StateKey>,
    pub integral: bool,
    /// Set by its own decision (phase 2 or 1b), not by propagation.
    pub chosen: bool,
}

/// What a conflict breaks.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ConflictKind {
    /// A source made to take the variable it should give.
    Source,
    /// A port of fixed causality (past a singular field's rank, or forced
    /// by a loop of junctions) made integral.
    Fixed,
    /// A 0-junction whose effort two bonds set.
    EffortTwice,
    /// A 0-junction whose effort no bond sets.
    EffortUnset,
    /// A 1-junction whose flow two bonds set.
    FlowTwice,
    /// A 1-junction whose flow no bond sets.
    FlowUnset,
    /// A transformer with effort into (or out of) both ports.
    Transformer,
    /// A gyrator with effort into one port and out of the other.
    Gyrator,
}

/// A vertex whose constraint the assignment breaks.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Conflict {
    pub vertex: VertexId,
    pub kind: ConflictKind,
    /// The bonds involved (those that set the variable twice, or all).
    pub bonds: Vec<BondId>,
}

/// The causal strokes and how SCAP came to them.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Causality {
    /// Per bond (removed bonds: `None`).
    pub strokes: Vec<Option<Stroke>>,
    /// Per bond: the index of the decision that set it.
    pub cause: Vec<Option<usize>>,
    pub decisions: Vec<Decision>,
    /// Every storage port, in the order SCAP took them.
    pub storage: Vec<StoragePort>,
    pub conflicts: Vec<Conflict>,
    /// Storage ports fixed in derivative causality because a loop of
    /// junctions alone fixed them ([`Options::force`]).
    pub forced: Vec<StateKey>,
}

/// Options of [`assign`].
#[derive(Clone, Debug, Default)]
pub struct Options {
    /// Storage ports to take last in phase 2 (the cross-check asks whether
    /// index reduction's choice of dependent states is SCAP's too).
    pub defer: Vec<StateKey>,
    /// Storage ports fixed in derivative causality (1b): those a loop of
    /// junctions alone was found to fix.
    pub force: Vec<StateKey>,
}

impl Causality {
    /// Whether vertex `v` receives the effort through bond `b`.
    pub fn effort_into(&self, g: &BondGraph, v: VertexId, b: BondId) -> Option<bool> {
        let s = self.strokes.get(b.0 as usize).copied().flatten()?;
        let bond = &g.bonds[b];
        Some(match s {
            Stroke::Head => bond.head == v,
            Stroke::Tail => bond.tail == v,
        })
    }

    /// Storage ports in derivative causality.
    pub fn derivative(&self) -> impl Iterator<Item = &StoragePort> {
        self.storage.iter().filter(|s| !s.integral)
    }

    /// Storage ports in integral causality.
    pub fn integral(&self) -> impl Iterator<Item = &StoragePort> {
        self.storage.iter().filter(|s| s.integral)
    }

    /// The arbitrary choices (phases 3 and 4).
    pub fn arbitrary(&self) -> impl Iterator<Item = &Decision> {
        self.decisions
            .iter()
            .filter(|d| matches!(d.phase, Phase::Arbitrary | Phase::Open))
    }
}

/// Whether a storage port takes the effort in integral causality (an I's
/// does, a C's gives it).
fn integral_takes_effort(kind: VertexKind) -> bool {
    matches!(kind, VertexKind::I | VertexKind::IField)
}

/// A choice of phases 2 to 4: the phase, the vertex, the bond, and whether
/// the vertex takes the effort in the preferred causality.
type Item = (Phase, VertexId, BondId, bool);

struct Scap<'g> {
    g: &'g BondGraph,
    c: Causality,
    queue: VecDeque<VertexId>,
    queued: Vec<bool>,
    /// Ports of fixed causality (1b): vertex, bond, and whether the vertex
    /// must take the effort there.
    fixed: Vec<(VertexId, BondId, bool)>,
    /// The bonds in the order they were set.
    trail: Vec<BondId>,
}

/// Assign causality to every bond of `g` by SCAP.
pub fn assign(g: &BondGraph, opts: &Options) -> Causality {
    let n = g.bonds.len();
    let mut s = Scap {
        g,
        c: Causality {
            strokes: vec![None; n],
            cause: vec![None; n],
            decisions: Vec::new(),
            storage: Vec::new(),
            conflicts: Vec::new(),
            forced: Vec::new(),
        },
        queue: VecDeque::new(),
        queued: vec![false; g.vertices.len()],
        fixed: fixed_ports(g, &opts.force),
        trail: Vec::new(),
    };
    // 1a: sources.
    for (v, x) in g.live_vertices() {
        if x.kind.is_source()
            && let Some(&b) = x.bonds.first()
        {
            let takes = matches!(x.kind, VertexKind::Sf | VertexKind::MSf);
            s.decide(Phase::Source, v, b, takes);
        }
    }
    // A junction with one bond (a node that only one element reaches)
    // carries no flow (0) or no effort (1) on it: a source of zero.
    for (v, x) in g.live_vertices() {
        if x.kind.is_junction()
            && let [b] = x.bonds[..]
        {
            s.decide(Phase::Source, v, b, x.kind == VertexKind::Zero);
        }
    }
    // 1b: ports that cannot be integral.
    for (v, b, takes) in s.fixed.clone() {
        s.decide(Phase::Fixed, v, b, takes);
    }
    // 2: storage, one port at a time; deferred ones last.
    let mut ports: Vec<(VertexId, BondId, Option<StateKey>)> = Vec::new();
    for (v, x) in g.live_vertices() {
        if !x.kind.is_storage() {
            continue;
        }
        for (k, &b) in x.bonds.iter().enumerate() {
            ports.push((v, b, x.states.get(k).copied().flatten()));
        }
    }
    // A field's pivots (the windings that keep a flux) first.
    ports.sort_by_key(|&(v, b, st)| {
        let deferred = st.and_then(|k| opts.defer.iter().position(|&d| d == k));
        (
            deferred.is_some(),
            deferred,
            v,
            field_rank(&g.vertices[v], b),
        )
    });
    let mut items: Vec<Item> = ports
        .into_iter()
        .map(|(v, b, _)| {
            let takes = integral_takes_effort(g.vertices[v].kind);
            (Phase::Preferred, v, b, takes)
        })
        .collect();
    // 3: resistors.
    for (v, x) in g.live_vertices() {
        if x.kind.is_resistor() {
            for &b in &x.bonds {
                items.push((Phase::Arbitrary, v, b, false));
            }
        }
    }
    // 4: whatever is left.
    for (b, bond) in g.live_bonds() {
        items.push((Phase::Open, bond.head, b, true));
    }
    if !s.search(&items) {
        for &(phase, v, b, takes) in &items {
            s.decide(phase, v, b, takes);
        }
    }
    s.c.forced = opts.force.clone();
    s.finish();
    s.c
}

/// The storage outcomes and conflicts of given strokes (no decisions): how
/// the cross-check's tests hand it an assignment SCAP would not make.
pub fn evaluate(g: &BondGraph, strokes: Vec<Option<Stroke>>) -> Causality {
    let n = g.bonds.len();
    let mut s = Scap {
        g,
        c: Causality {
            strokes,
            cause: vec![None; n],
            decisions: Vec::new(),
            storage: Vec::new(),
            conflicts: Vec::new(),
            forced: Vec::new(),
        },
        queue: VecDeque::new(),
        queued: vec![false; g.vertices.len()],
        fixed: fixed_ports(g, &[]),
        trail: Vec::new(),
    };
    s.c.strokes.resize(n, None);
    s.finish();
    s.c
}

/// A field port's place in phase 2: pivots first, in pivot order.
fn field_rank(x: &Vertex, b: BondId) -> usize {
    let k = x.bonds.iter().position(|&c| c == b).unwrap_or(0);
    match &x.law {
        Law::Field(f) => match &f.singular {
            Some(s) => s.pivots.iter().position(|&p| p == k).unwrap_or(usize::MAX),
            None => k,
        },
        _ => k,
    }
}

/// The ports of 1b: a singular field's windings that hold no flux, and the
/// storage ports `forced` into derivative causality (by a loop of junctions
/// alone, see [`crate::bondgraph::analyse`]). Each with whether its vertex
/// takes the effort (a C in derivative causality does, an I does not).
fn fixed_ports(g: &BondGraph, forced: &[StateKey]) -> Vec<(VertexId, BondId, bool)> {
    let mut out = Vec::new();
    for (v, x) in g.live_vertices() {
        if !x.kind.is_storage() {
            continue;
        }
        for (k, &b) in x.bonds.iter().enumerate() {
            let past_rank = match &x.law {
                Law::Field(f) => f.singular.as_ref().is_some_and(|s| !s.pivots.contains(&k)),
                _ => false,
            };
            let state = x.states.get(k).copied().flatten();
            if past_rank || state.is_some_and(|st| forced.contains(&st)) {
                out.push((v, b, x.kind == VertexKind::C));
            }
        }
    }
    out
}

impl Scap<'_> {
    /// Decide bond `b` at vertex `v` (`v` takes the effort when `takes`),
    /// unless propagation has already, and propagate.
    fn decide(&mut self, phase: Phase, v: VertexId, b: BondId, takes: bool) {
        if self.c.strokes[b.0 as usize].is_some() {
            return;
        }
        self.c.decisions.push(Decision {
            phase,
            vertex: v,
            bond: b,
            propagated: Vec::new(),
            turned: false,
        });
        // A choice whose propagation breaks a constraint is taken back and
        // the other causality tried; if that breaks one too, the first
        // stands and the conflict is reported.
        let mark = self.trail.len();
        self.set(b, v, takes);
        self.propagate();
        if phase != Phase::Source && self.broken_since(mark) {
            self.retry(mark, b, v, !takes);
            if self.broken_since(mark) {
                self.retry(mark, b, v, takes);
                if let Some(d) = self.c.decisions.last_mut() {
                    d.turned = false;
                }
            }
        }
    }

    /// Take back what the last decision set and set its bond the other way.
    fn retry(&mut self, mark: usize, b: BondId, v: VertexId, takes: bool) {
        self.undo(mark);
        if let Some(d) = self.c.decisions.last_mut() {
            d.propagated.clear();
            d.turned = true;
        }
        self.set(b, v, takes);
        self.propagate();
    }

    /// Phases 2 to 4 as a search: each choice is made as preferred and
    /// propagated; where that leads to a broken constraint, the latest
    /// choice not yet turned is taken back and turned (seed 002: go back and
    /// change it), so that a resistor chosen early cannot leave a junction
    /// that nothing can set later. `false` (and nothing changed) when the
    /// constraints are broken before any choice (a loop of sources) or the
    /// search runs out of its budget: the choices are then made one by one.
    fn search(&mut self, items: &[Item]) -> bool {
        if self.g.live_vertices().any(|(v, _)| self.broken(v)) {
            return false;
        }
        struct Frame {
            item: usize,
            mark: usize,
            decisions: usize,
            turned: bool,
        }
        let (mark0, decisions0) = (self.trail.len(), self.c.decisions.len());
        let mut stack: Vec<Frame> = Vec::new();
        let mut budget = 10_000 + 50 * items.len();
        let mut next = 0;
        loop {
            while next < items.len() && self.c.strokes[items[next].2.0 as usize].is_some() {
                next += 1;
            }
            let Some(&(phase, v, b, takes)) = items.get(next) else {
                return true;
            };
            let mut frame = Frame {
                item: next,
                mark: self.trail.len(),
                decisions: self.c.decisions.len(),
                turned: false,
            };
            self.c.decisions.push(Decision {
                phase,
                vertex: v,
                bond: b,
                propagated: Vec::new(),
                turned: false,
            });
            self.set(b, v, takes);
            self.propagate();
            while self.broken_since(frame.mark) {
                // Back to the latest choice with another causality left.
                while frame.turned {
                    self.undo(frame.mark);
                    self.c.decisions.truncate(frame.decisions);
                    match stack.pop() {
                        Some(f) if budget > 0 => frame = f,
                        _ => {
                            self.undo(mark0);
                            self.c.decisions.truncate(decisions0);
                            return false;
                        }
                    }
                }
                budget -= 1;
                self.undo(frame.mark);
                self.c.decisions.truncate(frame.decisions);
                let (phase, v, b, takes) = items[frame.item];
                self.c.decisions.push(Decision {
                    phase,
                    vertex: v,
                    bond: b,
                    propagated: Vec::new(),
                    turned: true,
                });
                self.set(b, v, !takes);
                self.propagate();
                frame.turned = true;
            }
            next = frame.item + 1;
            stack.push(frame);
        }
    }

    /// Take back every bond set since the trail was `mark` long.
    fn undo(&mut self, mark: usize) {
        for b in self.trail.drain(mark..) {
            self.c.strokes[b.0 as usize] = None;
            self.c.cause[b.0 as usize] = None;
        }
    }

    /// Whether a vertex at a bond set since `mark` breaks its constraint
    /// already (with the bonds still open as they are).
    fn broken_since(&self, mark: usize) -> bool {
        self.trail[mark..].iter().any(|&b| {
            let bond = &self.g.bonds[b];
            self.broken(bond.tail) || self.broken(bond.head)
        })
    }

    fn broken(&self, v: VertexId) -> bool {
        let x = &self.g.vertices[v];
        let takes: Vec<Option<bool>> = x.bonds.iter().map(|&b| self.takes(v, b)).collect();
        match x.kind {
            VertexKind::Zero | VertexKind::One => {
                let one = x.kind == VertexKind::One;
                let setters = takes.iter().filter(|t| **t == Some(!one)).count();
                let open = takes.iter().any(Option::is_none);
                setters > 1 || (setters == 0 && !open)
            }
            VertexKind::Se | VertexKind::MSe => takes.first() == Some(&Some(true)),
            VertexKind::Sf | VertexKind::MSf => takes.first() == Some(&Some(false)),
            VertexKind::Tf | VertexKind::Gy => match takes.as_slice() {
                [Some(a), Some(b)] => (a == b) != (x.kind == VertexKind::Gy),
                _ => false,
            },
            _ => x
                .bonds
                .iter()
                .zip(&takes)
                .any(|(&b, t)| t.is_some_and(|t| self.fixed.contains(&(v, b, !t)))),
        }
    }

    /// Set bond `b` so that vertex `v` takes (or gives) the effort.
    fn set(&mut self, b: BondId, v: VertexId, takes: bool) {
        self.trail.push(b);
        let bond = &self.g.bonds[b];
        let at_head = bond.head == v;
        let stroke = if at_head == takes {
            Stroke::Head
        } else {
            Stroke::Tail
        };
        self.c.strokes[b.0 as usize] = Some(stroke);
        let d = self.c.decisions.len() - 1;
        self.c.cause[b.0 as usize] = Some(d);
        if self.c.decisions[d].bond != b {
            self.c.decisions[d].propagated.push(b);
        }
        for end in [bond.tail, bond.head] {
            if !self.queued[end.0 as usize] {
                self.queued[end.0 as usize] = true;
                self.queue.push_back(end);
            }
        }
    }

    fn takes(&self, v: VertexId, b: BondId) -> Option<bool> {
        self.c.effort_into(self.g, v, b)
    }

    /// Apply the constraints of every vertex reached until nothing follows.
    fn propagate(&mut self) {
        while let Some(v) = self.queue.pop_front() {
            self.queued[v.0 as usize] = false;
            let x = &self.g.vertices[v];
            match x.kind {
                // One bond sets a 0-junction's effort: the others take it
                // from the junction (give it the effort: `takes` false at
                // the junction); the last open bond of a junction nobody
                // sets yet must. A 1-junction is the dual.
                VertexKind::Zero | VertexKind::One => {
                    let strong = x.kind == VertexKind::One;
                    let mut set = 0;
                    let mut open = Vec::new();
                    for &b in &x.bonds {
                        match self.takes(v, b) {
                            Some(t) if t != strong => set += 1,
                            Some(_) => {}
                            None => open.push(b),
                        }
                    }
                    if set >= 1 {
                        for b in open {
                            self.set(b, v, strong);
                        }
                    } else if open.len() == 1 {
                        self.set(open[0], v, !strong);
                    }
                }
                VertexKind::Tf | VertexKind::Gy if x.bonds.len() == 2 => {
                    let same = x.kind == VertexKind::Gy;
                    let (b1, b2) = (x.bonds[0], x.bonds[1]);
                    match (self.takes(v, b1), self.takes(v, b2)) {
                        (Some(t), None) => self.set(b2, v, t == same),
                        (None, Some(t)) => self.set(b1, v, t == same),
                        _ => {}
                    }
                }
                _ => {}
            }
        }
    }

    /// Record every storage port's outcome and check every constraint.
    fn finish(&mut self) {
        let g = self.g;
        let mut storage = Vec::new();
        let chosen: Vec<BondId> = self
            .c
            .decisions
            .iter()
            .filter(|d| matches!(d.phase, Phase::Preferred | Phase::Fixed))
            .map(|d| d.bond)
            .collect();
        for (v, x) in g.live_vertices() {
            if !x.kind.is_storage() {
                continue;
            }
            for (k, &b) in x.bonds.iter().enumerate() {
                let takes = self.takes(v, b).unwrap_or(false);
                storage.push(StoragePort {
                    vertex: v,
                    bond: b,
                    port: k,
                    state: x.states.get(k).copied().flatten(),
                    integral: takes == integral_takes_effort(x.kind),
                    chosen: chosen.contains(&b)
                        && self.c.cause[b.0 as usize]
                            .is_some_and(|d| self.c.decisions[d].bond == b),
                });
            }
        }
        // In the order SCAP took them: by the decision that set each.
        storage.sort_by_key(|s| (self.c.cause[s.bond.0 as usize], !s.chosen, s.bond));
        self.c.storage = storage;
        let mut conflicts = Vec::new();
        for (v, x) in g.live_vertices() {
            let takes: Vec<(BondId, bool)> = x
                .bonds
                .iter()
                .map(|&b| (b, self.takes(v, b).unwrap_or(false)))
                .collect();
            let mut conflict = |kind, bonds: Vec<BondId>| {
                conflicts.push(Conflict {
                    vertex: v,
                    kind,
                    bonds,
                })
            };
            match x.kind {
                VertexKind::Zero | VertexKind::One => {
                    let one = x.kind == VertexKind::One;
                    let setters: Vec<BondId> = takes
                        .iter()
                        .filter(|&&(_, t)| t != one)
                        .map(|&(b, _)| b)
                        .collect();
                    let all = takes.iter().map(|&(b, _)| b).collect();
                    match (setters.len(), one) {
                        (0, false) => conflict(ConflictKind::EffortUnset, all),
                        (0, true) => conflict(ConflictKind::FlowUnset, all),
                        (1, _) => {}
                        (_, false) => conflict(ConflictKind::EffortTwice, setters),
                        (_, true) => conflict(ConflictKind::FlowTwice, setters),
                    }
                }
                VertexKind::Se | VertexKind::MSe => {
                    if let Some(&(b, true)) = takes.first() {
                        conflict(ConflictKind::Source, vec![b]);
                    }
                }
                VertexKind::Sf | VertexKind::MSf => {
                    if let Some(&(b, false)) = takes.first() {
                        conflict(ConflictKind::Source, vec![b]);
                    }
                }
                VertexKind::Tf if takes.len() == 2 && takes[0].1 == takes[1].1 => {
                    conflict(ConflictKind::Transformer, vec![takes[0].0, takes[1].0]);
                }
                VertexKind::Gy if takes.len() == 2 && takes[0].1 != takes[1].1 => {
                    conflict(ConflictKind::Gyrator, vec![takes[0].0, takes[1].0]);
                }
                _ => {
                    for &(b, t) in &takes {
                        if self.fixed.contains(&(v, b, !t)) {
                            conflict(ConflictKind::Fixed, vec![b]);
                        }
                    }
                }
            }
        }
        self.c.conflicts = conflicts;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bondgraph::{Bond, Origin, Part, StateKind};
    use crate::elab::ElemId;

    /// A graph of the given vertices (vertex `k` is element `k`) and bonds
    /// `(tail, head)`.
    fn graph(vs: &[VertexKind], bonds: &[(u32, u32)]) -> BondGraph {
        let mut g = BondGraph {
            title: "test".into(),
            vertices: Default::default(),
            bonds: Default::default(),
            simplified: Vec::new(),
            notes: Vec::new(),
            element_names: (0..vs.len()).map(|k| format!("x{k}")).collect(),
            node_names: Vec::new(),
            elements: Vec::new(),
            element_spans: Vec::new(),
            witness: Vec::new(),
            forward: Default::default(),
        };
        for (k, &kind) in vs.iter().enumerate() {
            let elem = ElemId(k as u32);
            g.vertices.push(Vertex {
                kind,
                label: format!("x{k}"),
                origin: Origin::Element {
                    elem,
                    part: Part::Whole,
                },
                bonds: Vec::new(),
                ports: Vec::new(),
                states: vec![kind.is_storage().then_some(StateKey {
                    elem,
                    kind: StateKind::Voltage,
                })],
                law: Law::Junction,
                signals: Vec::new(),
                name: None,
                removed: false,
            });
        }
        for &(t, h) in bonds {
            let b = g.bonds.push(Bond {
                tail: VertexId(t),
                head: VertexId(h),
                removed: false,
            });
            g.vertices[VertexId(t)].bonds.push(b);
            g.vertices[VertexId(h)].bonds.push(b);
        }
        g
    }

    fn derivative(c: &Causality) -> Vec<u32> {
        let mut v: Vec<u32> = c.derivative().map(|s| s.vertex.0).collect();
        v.sort();
        v
    }

    use VertexKind::*;

    #[test]
    fn capacitors_across_a_voltage_source_are_dependent() {
        // Se → 0 → C, C: the source sets the junction's effort, which both
        // capacitors take.
        let g = graph(&[Se, Zero, C, C], &[(0, 1), (1, 2), (1, 3)]);
        let c = assign(&g, &Options::default());
        assert_eq!(derivative(&c), [2, 3]);
        assert!(c.conflicts.is_empty());
        assert!(c.storage.iter().all(|s| !s.chosen));
    }

    #[test]
    fn one_of_two_parallel_capacitors_is_dependent() {
        // R → 0 with C, C: the first capacitor takes integral causality and
        // sets the junction's effort, the second takes it; deferring the
        // first gives the other choice.
        let g = graph(
            &[Se, One, R, Zero, C, C],
            &[(0, 1), (1, 2), (1, 3), (3, 4), (3, 5)],
        );
        let c = assign(&g, &Options::default());
        assert_eq!(derivative(&c), [5]);
        let defer = vec![StateKey {
            elem: ElemId(4),
            kind: StateKind::Voltage,
        }];
        let c = assign(
            &g,
            &Options {
                defer,
                ..Default::default()
            },
        );
        assert_eq!(derivative(&c), [4]);
    }

    #[test]
    fn inductors_behind_a_current_source_are_dependent() {
        let g = graph(&[Sf, One, I, I], &[(0, 1), (1, 2), (1, 3)]);
        let c = assign(&g, &Options::default());
        assert_eq!(derivative(&c), [2, 3]);
    }

    #[test]
    fn resistors_alone_need_an_arbitrary_choice() {
        // Seed C's loop: Se → 1 with R1, on to 0 with R2 and R3.
        let g = graph(
            &[Se, One, R, Zero, R, R],
            &[(0, 1), (1, 2), (1, 3), (3, 4), (3, 5)],
        );
        let c = assign(&g, &Options::default());
        let chosen: Vec<u32> = c.arbitrary().map(|d| d.vertex.0).collect();
        assert_eq!(chosen, [2]);
        // R1 takes the flow (gives e = R·f); the 1-junction then gives the
        // 0-junction its effort, which R2 and R3 take.
        assert_eq!(c.effort_into(&g, VertexId(2), BondId(1)), Some(false));
        assert_eq!(c.effort_into(&g, VertexId(4), BondId(3)), Some(true));
        assert_eq!(c.effort_into(&g, VertexId(5), BondId(4)), Some(true));
        assert!(c.conflicts.is_empty());
    }

    #[test]
    fn two_voltage_sources_on_one_junction_conflict() {
        // The first source sets the junction's effort; propagation makes
        // the second take it, against its fixed causality.
        let g = graph(&[Se, Zero, Se, R], &[(0, 1), (2, 1), (1, 3)]);
        let c = assign(&g, &Options::default());
        let found: Vec<(u32, ConflictKind)> =
            c.conflicts.iter().map(|x| (x.vertex.0, x.kind)).collect();
        assert_eq!(found, [(2, ConflictKind::Source)]);
    }

    #[test]
    fn a_transformer_passes_causality_on_and_a_gyrator_turns_it() {
        // Se → TF → C: effort in at port 1, out at port 2: C takes it.
        let g = graph(&[Se, Tf, C], &[(0, 1), (1, 2)]);
        assert_eq!(derivative(&assign(&g, &Options::default())), [2]);
        // Se → GY → C: effort in at both ports: C gives its effort.
        let g = graph(&[Se, Gy, C], &[(0, 1), (1, 2)]);
        let c = assign(&g, &Options::default());
        assert_eq!(derivative(&c), Vec::<u32>::new());
        assert!(c.conflicts.is_empty());
    }

    #[test]
    fn evaluate_reports_what_an_assignment_breaks() {
        let g = graph(&[Se, Zero, C], &[(0, 1), (1, 2)]);
        // C given integral causality against the source: the junction's
        // effort is set twice.
        let c = evaluate(&g, vec![Some(Stroke::Head), Some(Stroke::Tail)]);
        assert_eq!(derivative(&c), Vec::<u32>::new());
        assert_eq!(c.conflicts.len(), 1);
        assert_eq!(c.conflicts[0].kind, ConflictKind::EffortTwice);
    }
}
