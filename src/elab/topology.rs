//! Topological faults of a circuit, found on its graph and named by its
//! elements: loops of voltage sources (with or without capacitors), cutsets
//! of current sources (with or without inductors), floating nodes.
//!
//! These are the circuit-level reasons for the structural singularities the
//! causalizer meets. Loops of capacitors and voltage sources and cutsets of
//! inductors and current sources only couple states: index reduction fixes
//! them. Loops of voltage sources alone, cutsets of current sources alone and
//! floating nodes leave the circuit over- or under-determined: errors.

use super::{Circuit, ElemId, ElementKind, GROUND, NodeId};
use crate::diag::codes;
use crate::diag::{Diagnostic, Severity, Span, ToDiagnostic};
use crate::numeric::UnionFind;

/// What fixes an element's branch: its voltage, its current, or neither.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Defines {
    Voltage,
    Current,
    Capacitor,
    Inductor,
    Other,
}

fn defines(k: &ElementKind) -> Defines {
    match k {
        k if k.fixes_voltage() => Defines::Voltage,
        ElementKind::ISource { .. }
        | ElementKind::Vccs { .. }
        | ElementKind::Cccs { .. }
        | ElementKind::Behavioural { current: true, .. }
        | ElementKind::DeviceBranch {
            controlled: true, ..
        } => Defines::Current,
        // A state fixes the voltage of a capacitor, of a junction charge
        // with nothing in series (a diode without RS, a transistor's
        // charge branch) and of a Meyer gate capacitance: in a loop they are
        // capacitors alike.
        ElementKind::Capacitor { .. }
        | ElementKind::DeviceBranch {
            charge: Some(_), ..
        }
        | ElementKind::DeviceBranch {
            capacitance: Some(_),
            ..
        } => Defines::Capacitor,
        ElementKind::Diode { model, .. }
            if model.rs == 0.0 && (model.cjo != 0.0 || model.tt != 0.0) =>
        {
            Defines::Capacitor
        }
        ElementKind::Inductor { .. } => Defines::Inductor,
        _ => Defines::Other,
    }
}

/// A fault and the elements that make it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Fault {
    /// Capacitors and voltage sources in a loop; `fixed` is the capacitor
    /// whose voltage the others fix (it cannot keep a state).
    CapacitorLoop {
        elements: Vec<ElemId>,
        fixed: ElemId,
    },
    /// Inductors and current sources forming a cutset; `fixed` is the
    /// inductor whose current the others fix.
    InductorCutset {
        elements: Vec<ElemId>,
        fixed: ElemId,
    },
    /// Voltage sources alone in a loop: conflicting.
    VoltageLoop { elements: Vec<ElemId> },
    /// Current sources alone forming a cutset around `nodes`: conflicting.
    CurrentCutset {
        elements: Vec<ElemId>,
        nodes: Vec<NodeId>,
    },
    /// Nodes with no path to ground but through current sources (or none).
    Floating {
        nodes: Vec<NodeId>,
        via: Vec<ElemId>,
    },
    /// A diode without series resistance across voltage sources (`sources`,
    /// the path that joins its terminals): they fix its voltage, so its
    /// current is its exponential of whatever they apply. A warning: beyond
    /// 50 N·Vt forward kausal continues the exponential linearly (ngspice
    /// evaluates it: 10^100 A at 13 V), so the two disagree there.
    ForcedJunction { diode: ElemId, sources: Vec<ElemId> },
}

impl Fault {
    /// Only a warning: index reduction removes it, or it is a forced
    /// junction.
    pub fn is_warning(&self) -> bool {
        self.is_fixable() || matches!(self, Fault::ForcedJunction { .. })
    }

    /// Index reduction can remove it (it only couples states).
    pub fn is_fixable(&self) -> bool {
        matches!(
            self,
            Fault::CapacitorLoop { .. } | Fault::InductorCutset { .. }
        )
    }
}

struct Forest {
    parent: Vec<usize>,
    /// The element that joined a node to its parent in the spanning forest.
    via: Vec<Option<ElemId>>,
    sets: UnionFind,
}

impl Forest {
    fn new(n: usize) -> Forest {
        Forest {
            parent: (0..n).collect(),
            via: vec![None; n],
            sets: UnionFind::new(n),
        }
    }

    /// Add edge `e` between `a` and `b`; if it closes a loop, return the
    /// forest path from `a` to `b` (the loop's other elements).
    fn add(&mut self, a: usize, b: usize, e: ElemId) -> Option<Vec<ElemId>> {
        if self.sets.find(a) == self.sets.find(b) {
            return Some(self.path(a, b));
        }
        // Re-root b's tree at b, then hang it under a.
        self.reroot(b);
        self.parent[b] = a;
        self.via[b] = Some(e);
        self.sets.union(b, a);
        None
    }

    fn reroot(&mut self, x: usize) {
        let mut prev = x;
        let mut prev_via = None;
        let mut cur = x;
        loop {
            let next = self.parent[cur];
            let next_via = self.via[cur];
            self.parent[cur] = prev;
            self.via[cur] = prev_via;
            if next == cur {
                break;
            }
            prev = cur;
            prev_via = next_via;
            cur = next;
        }
        self.parent[x] = x;
        self.via[x] = None;
    }

    fn ancestors(&self, mut x: usize) -> Vec<usize> {
        let mut out = vec![x];
        while self.parent[x] != x {
            x = self.parent[x];
            out.push(x);
        }
        out
    }

    fn path(&self, a: usize, b: usize) -> Vec<ElemId> {
        let pa = self.ancestors(a);
        let pb = self.ancestors(b);
        let common = pa.iter().find(|n| pb.contains(n)).copied().unwrap_or(a);
        let mut out = Vec::new();
        for p in [&pa, &pb] {
            for &n in p.iter() {
                if n == common {
                    break;
                }
                if let Some(e) = self.via[n] {
                    out.push(e);
                }
            }
        }
        out
    }
}

fn components(n: usize, edges: impl Iterator<Item = (usize, usize)>) -> Vec<usize> {
    let mut sets = UnionFind::new(n);
    for (a, b) in edges {
        sets.union(a, b);
    }
    sets.representatives()
}

/// Which storage elements are directly tied to a source: a capacitor
/// across the same two nodes as a voltage source, an inductor sharing a
/// two-element node with a current source. One pass over the elements (a
/// scan per element would be quadratic: 3·10^4 inductors in a cutset).
fn tied_to_sources(c: &Circuit, degree: &[usize]) -> Vec<bool> {
    let pair = |x: &super::Element| {
        let (a, b) = (x.nodes[0], x.nodes[1]);
        if a < b { (a, b) } else { (b, a) }
    };
    let mut voltage_pairs = std::collections::HashSet::new();
    let mut current_at = vec![false; degree.len()];
    for x in c.elements.values() {
        if x.nodes.len() < 2 {
            continue;
        }
        match defines(&x.kind) {
            Defines::Voltage => {
                voltage_pairs.insert(pair(x));
            }
            Defines::Current => {
                for n in &x.nodes[..2] {
                    current_at[n.0 as usize] = true;
                }
            }
            _ => {}
        }
    }
    c.elements
        .values()
        .map(|el| {
            el.nodes.len() >= 2
                && match defines(&el.kind) {
                    Defines::Capacitor => voltage_pairs.contains(&pair(el)),
                    Defines::Inductor => el.nodes[..2].iter().any(|n| {
                        *n != GROUND && degree[n.0 as usize] == 2 && current_at[n.0 as usize]
                    }),
                    _ => false,
                }
        })
        .collect()
}

/// How readily a storage element gives up its state in a loop: a Meyer
/// gate capacitance first (it can vanish to its floor, and a state behind a
/// vanishing capacitance is ill-conditioned), then a capacitor or inductor,
/// a junction charge last (its voltage, solved from the charge, is what the
/// operating point's Newton limits as ngspice limits junctions).
fn fix_rank(k: &ElementKind) -> u8 {
    match k {
        ElementKind::DeviceBranch {
            capacitance: Some(_),
            ..
        } => 0,
        ElementKind::DeviceBranch { .. } | ElementKind::Diode { .. } => 2,
        _ => 1,
    }
}

/// A device's storage that counts as a capacitor in loops (a junction
/// charge, a gate capacitance), not a capacitor itself.
fn device_storage(k: &ElementKind) -> bool {
    defines(k) == Defines::Capacitor && !matches!(k, ElementKind::Capacitor { .. })
}

/// The storage element of a loop or cutset that loses its state: not one the
/// user keeps, then one tied to a source, then by [`fix_rank`], then the
/// last in netlist order.
fn pick_fixed(
    c: &Circuit,
    storage: &[ElemId],
    keep: &[ElemId],
    tied: &[bool],
    taken: &mut [bool],
) -> Option<ElemId> {
    // One element per fault: one already fixed by another fault goes last.
    let e = storage.iter().copied().min_by_key(|&e| {
        (
            taken[e.0 as usize],
            keep.contains(&e),
            !tied[e.0 as usize],
            fix_rank(&c.elements[e].kind),
            std::cmp::Reverse(e),
        )
    })?;
    taken[e.0 as usize] = true;
    Some(e)
}

/// Every fault of `c`, loops first, then cutsets, then floating nodes.
/// `keep` lists storage elements the user wants to keep their state.
pub fn faults(c: &Circuit, keep: &[ElemId]) -> Vec<Fault> {
    let mut degree = vec![0usize; c.nodes.len()];
    for e in c.elements.values() {
        for n in &e.nodes {
            degree[n.0 as usize] += 1;
        }
    }
    let n = c.nodes.len();
    let two = |e: &super::Element| (e.nodes[0].0 as usize, e.nodes[1].0 as usize);
    let mut out = Vec::new();
    let mut taken = vec![false; c.elements.len()];
    let tied = tied_to_sources(c, &degree);
    // Nodes joined by voltage sources alone, and so those whose potential
    // they fix against ground.
    let joined = components(
        n,
        c.elements
            .values()
            .filter(|e| defines(&e.kind) == Defines::Voltage)
            .map(two),
    );
    let fixed_node = |k: NodeId| joined[k.0 as usize] == joined[GROUND.0 as usize];
    // Loops: voltage sources first, then capacitors.
    let mut f = Forest::new(n);
    for pass in [Defines::Voltage, Defines::Capacitor] {
        if pass == Defines::Capacitor {
            // The forest holds the voltage sources alone: a diode without
            // series resistance whose terminals it joins is forced.
            for (id, e) in c.elements.iter() {
                if let ElementKind::Diode { model, .. } = &e.kind
                    && model.rs == 0.0
                    && e.nodes.len() >= 2
                {
                    let (a, b) = two(e);
                    if joined[a] == joined[b] {
                        let mut sources = f.path(a, b);
                        sources.sort();
                        out.push(Fault::ForcedJunction { diode: id, sources });
                    }
                }
            }
        }
        for (id, e) in c.elements.iter() {
            if defines(&e.kind) != pass {
                continue;
            }
            let (a, b) = two(e);
            if let Some(path) = f.add(a, b, id) {
                let mut elements = path;
                elements.push(id);
                elements.sort();
                // A loop through a device's charges or gate capacitances
                // that touches ground or a source-fixed node is left to
                // index reduction, which sees its constraint on the node
                // potentials (every MOSFET with grounded bulk and source
                // has one); only a loop that would hide it is written as
                // KVL here.
                let device = elements
                    .iter()
                    .any(|&e| device_storage(&c.elements[e].kind));
                if device
                    && elements
                        .iter()
                        .flat_map(|&e| &c.elements[e].nodes[..2])
                        .any(|&k| fixed_node(k))
                {
                    continue;
                }
                let caps: Vec<ElemId> = elements
                    .iter()
                    .copied()
                    .filter(|&e| defines(&c.elements[e].kind) == Defines::Capacitor)
                    .collect();
                match pick_fixed(c, &caps, keep, &tied, &mut taken) {
                    Some(fixed) => out.push(Fault::CapacitorLoop { elements, fixed }),
                    None => out.push(Fault::VoltageLoop { elements }),
                }
            }
        }
    }
    // Floating parts: no path to ground except through current sources.
    let comp_all = components(
        n,
        c.elements
            .values()
            .filter(|e| !matches!(defines(&e.kind), Defines::Current) && e.nodes.len() >= 2)
            .map(two),
    );
    let ground = comp_all[GROUND.0 as usize];
    let islands = component_groups(
        c,
        &comp_all,
        |_, k| k != ground,
        |e| defines(&e.kind) == Defines::Current,
    );
    for (nodes, via) in islands {
        out.push(Fault::Floating { nodes, via });
    }
    // Cutsets: parts cut off from ground when inductors and current
    // sources are removed (and not already floating).
    let comp = components(
        n,
        c.elements
            .values()
            .filter(|e| {
                !matches!(defines(&e.kind), Defines::Current | Defines::Inductor)
                    && e.nodes.len() >= 2
            })
            .map(two),
    );
    let root = comp[GROUND.0 as usize];
    let parts = component_groups(
        c,
        &comp,
        |id, k| k != root && comp_all[id.0 as usize] == ground,
        |e| matches!(defines(&e.kind), Defines::Current | Defines::Inductor),
    );
    // Each cutset fixes a different inductor: those with fewest inductors
    // choose first (a cutset of L2 alone fixes L2, and a wider one through
    // L1, L2 and L3 is left L1 or L3, not L2 a second time).
    let inductors_of = |cut: &[ElemId]| -> Vec<ElemId> {
        cut.iter()
            .copied()
            .filter(|&e| defines(&c.elements[e].kind) == Defines::Inductor)
            .collect()
    };
    let mut parts: Vec<(Vec<NodeId>, Vec<ElemId>, Vec<ElemId>)> = parts
        .into_iter()
        .map(|(nodes, cut)| {
            let inductors = inductors_of(&cut);
            (nodes, cut, inductors)
        })
        .collect();
    parts.sort_by_key(|(_, _, inductors)| inductors.len());
    for (part_nodes, cut, inductors) in parts {
        match pick_fixed(c, &inductors, keep, &tied, &mut taken) {
            Some(fixed) => out.push(Fault::InductorCutset {
                elements: cut,
                fixed,
            }),
            None => out.push(Fault::CurrentCutset {
                elements: cut,
                nodes: part_nodes,
            }),
        }
    }
    out
}

/// The components of `comp` that `take` accepts (asked at each one's first
/// node), in order of their first node: their nodes, and the elements of the
/// kinds `crosses` selects with one terminal inside and one outside. One pass
/// over nodes and elements (a scan of the elements per component would be
/// quadratic: 3·10^4 inductors in series make 3·10^4 parts).
fn component_groups(
    c: &Circuit,
    comp: &[usize],
    take: impl Fn(NodeId, usize) -> bool,
    crosses: impl Fn(&super::Element) -> bool,
) -> Vec<(Vec<NodeId>, Vec<ElemId>)> {
    let mut slot = vec![usize::MAX; comp.len()];
    let mut groups: Vec<(Vec<NodeId>, Vec<ElemId>)> = Vec::new();
    let mut asked = vec![false; comp.len()];
    for (id, _) in c.nodes.iter() {
        let k = comp[id.0 as usize];
        if !asked[k] {
            asked[k] = true;
            if take(id, k) {
                slot[k] = groups.len();
                groups.push((Vec::new(), Vec::new()));
            }
        }
        if slot[k] != usize::MAX {
            groups[slot[k]].0.push(id);
        }
    }
    for (id, e) in c.elements.iter() {
        if e.nodes.len() < 2 || !crosses(e) {
            continue;
        }
        let (a, b) = (comp[e.nodes[0].0 as usize], comp[e.nodes[1].0 as usize]);
        if a != b {
            for k in [a, b] {
                if slot[k] != usize::MAX {
                    groups[slot[k]].1.push(id);
                }
            }
        }
    }
    groups
}

/// A diagnostic names and labels this many elements of a fault, then counts
/// the rest (a loop of 3000 capacitors printed 3000 labelled lines).
const SHOWN: usize = 24;

fn list(names: &[String]) -> String {
    match names.len() {
        0 => String::new(),
        1 => names[0].clone(),
        n if n > SHOWN => format!("{}, and {} more", names[..SHOWN].join(", "), n - SHOWN),
        n => format!("{} and {}", names[..n - 1].join(", "), names[n - 1]),
    }
}

/// A fault with what its report needs of the circuit: the name, span and
/// kind of each element it involves and the name and span of each node. It
/// stays data until [`ToDiagnostic`] writes it.
#[derive(Clone, Debug, PartialEq)]
pub struct TopologyError {
    pub fault: Fault,
    elements: rustc_hash::FxHashMap<ElemId, Part>,
    nodes: rustc_hash::FxHashMap<NodeId, (String, Span)>,
}

/// An element as a fault's report names it.
#[derive(Clone, Debug, PartialEq)]
struct Part {
    name: String,
    span: Span,
    defines: Defines,
    /// A device's storage (a junction charge or a gate capacitance), not
    /// a capacitor.
    device: bool,
}

impl TopologyError {
    pub fn new(c: &Circuit, f: &Fault) -> TopologyError {
        let (elements, nodes): (&[ElemId], &[NodeId]) = match f {
            Fault::CapacitorLoop { elements, .. }
            | Fault::InductorCutset { elements, .. }
            | Fault::VoltageLoop { elements } => (elements, &[]),
            Fault::CurrentCutset { elements, nodes } => (elements, nodes),
            Fault::Floating { nodes, via } => (via, nodes),
            Fault::ForcedJunction { sources, .. } => (sources, &[]),
        };
        let part = |&e: &ElemId| {
            let x = &c.elements[e];
            let part = Part {
                name: x.name.to_string(),
                span: x.span(),
                defines: defines(&x.kind),
                device: device_storage(&x.kind),
            };
            (e, part)
        };
        let node = |&n: &NodeId| (n, (c.nodes[n].name.to_string(), c.nodes[n].span()));
        let mut parts: rustc_hash::FxHashMap<ElemId, Part> = elements.iter().map(part).collect();
        if let Fault::CapacitorLoop { fixed, .. }
        | Fault::InductorCutset { fixed, .. }
        | Fault::ForcedJunction { diode: fixed, .. } = f
        {
            parts.extend([part(fixed)]);
        }
        TopologyError {
            fault: f.clone(),
            elements: parts,
            nodes: nodes.iter().map(node).collect(),
        }
    }

    /// Index reduction can remove the fault (a warning, not an error).
    pub fn is_fixable(&self) -> bool {
        self.fault.is_fixable()
    }

    fn name(&self, e: &ElemId) -> String {
        self.elements[e].name.clone()
    }

    fn names(&self, v: &[ElemId]) -> Vec<String> {
        v.iter().map(|e| self.name(e)).collect()
    }

    fn node_names(&self, v: &[NodeId]) -> Vec<String> {
        v.iter().map(|n| self.nodes[n].0.clone()).collect()
    }

    /// Labels `what` on the first [`SHOWN`] of `v`.
    fn labels_of(&self, v: &[ElemId], what: &str) -> Vec<(Span, String)> {
        v.iter()
            .take(SHOWN)
            .map(|e| (self.elements[e].span, what.to_string()))
            .collect()
    }

    /// The elements of `elements` other than `fixed`.
    fn others(elements: &[ElemId], fixed: &ElemId) -> Vec<ElemId> {
        elements.iter().copied().filter(|e| e != fixed).collect()
    }

    /// The sentence that states the fault.
    pub fn message(&self) -> String {
        match &self.fault {
            Fault::CapacitorLoop { elements, fixed } => {
                let others = Self::others(elements, fixed);
                let sources = others
                    .iter()
                    .any(|e| self.elements[e].defines == Defines::Voltage);
                let device = elements.iter().any(|e| self.elements[e].device);
                let kind = match (device, sources) {
                    (false, false) => "a loop of capacitors",
                    (false, true) => "a loop of capacitors and voltage sources",
                    (true, false) => "a loop of capacitors and device charges",
                    (true, true) => "a loop of capacitors, device charges and voltage sources",
                };
                format!(
                    "{} form {kind}: {}'s voltage is fixed by {}, so {} cannot hold an independent state (derivative causality)",
                    list(&self.names(elements)),
                    self.name(fixed),
                    list(&self.names(&others)),
                    self.name(fixed)
                )
            }
            Fault::InductorCutset { elements, fixed } => {
                let others = Self::others(elements, fixed);
                let (sources, inductors): (Vec<ElemId>, Vec<ElemId>) = others
                    .iter()
                    .partition(|e| self.elements[e].defines == Defines::Current);
                let (sources, inductors) = (self.names(&sources), self.names(&inductors));
                let src = |v: &[String]| {
                    format!(
                        "current source{} {}",
                        if v.len() == 1 { "" } else { "s" },
                        list(v)
                    )
                };
                let with = match (inductors.is_empty(), sources.is_empty()) {
                    (true, true) => "alone (no other element carries its current)".to_string(),
                    (false, true) => format!("with {}", list(&inductors)),
                    (true, false) => format!("with {}", src(&sources)),
                    (false, false) => format!("with {} and {}", list(&inductors), src(&sources)),
                };
                let by = if others.len() == 1 { "it" } else { "them" };
                format!(
                    "{} is in a cutset {with}: its current is fixed by {by}, so {} cannot hold an independent state (derivative causality)",
                    self.name(fixed),
                    self.name(fixed)
                )
            }
            Fault::VoltageLoop { elements } => format!(
                "{} form a loop of voltage sources (conflicting)",
                list(&self.names(elements))
            ),
            Fault::CurrentCutset { elements, nodes } => format!(
                "current sources {} form a cutset around node{} {} (conflicting currents)",
                list(&self.names(elements)),
                if nodes.len() == 1 { "" } else { "s" },
                list(&self.node_names(nodes))
            ),
            Fault::Floating { nodes, via } => {
                let node_names = self.node_names(nodes);
                let around = if nodes.len() == 1 {
                    format!("node {}", node_names[0])
                } else {
                    format!("nodes {}", list(&node_names))
                };
                let (what, how) = if via.is_empty() {
                    let (verb, it) = if nodes.len() == 1 {
                        ("is", "it")
                    } else {
                        ("are", "them")
                    };
                    (
                        format!("{around} {verb} floating"),
                        format!("no element connects {it} to ground"),
                    )
                } else {
                    (
                        format!(
                            "current sources {} form a cutset around {around}",
                            list(&self.names(via))
                        ),
                        "their currents must balance and nothing sets the voltage".to_string(),
                    )
                };
                format!("{what}: {how}, so the circuit is under-determined")
            }
            Fault::ForcedJunction { diode, sources } => format!(
                "{} has no series resistance and {} fix{} its voltage: its current is the exponential of that voltage, which kausal continues linearly beyond 50 N·Vt forward where ngspice evaluates it (10^100 A at 13 V)",
                self.name(diode),
                list(&self.names(sources)),
                if sources.len() == 1 { "es" } else { "" }
            ),
        }
    }

    /// The labelled spans: the element that loses its state first, then
    /// the others, then nodes (the first [`SHOWN`] of each list).
    fn labels(&self) -> Vec<(Span, String)> {
        match &self.fault {
            Fault::CapacitorLoop { elements, fixed }
            | Fault::InductorCutset { elements, fixed } => {
                let within = match self.fault {
                    Fault::CapacitorLoop { .. } => "in the loop",
                    _ => "in the cutset",
                };
                let mut labels = self.labels_of(
                    std::slice::from_ref(fixed),
                    "cannot hold an independent state",
                );
                labels.extend(self.labels_of(&Self::others(elements, fixed), within));
                labels
            }
            Fault::VoltageLoop { elements } => self.labels_of(elements, "in the loop"),
            Fault::CurrentCutset { elements, .. } => self.labels_of(elements, "in the cutset"),
            Fault::Floating { nodes, via } => {
                let node_label = if via.is_empty() {
                    "floating"
                } else {
                    "inside the cutset"
                };
                let mut labels = self.labels_of(via, "in the cutset");
                labels.extend(
                    nodes
                        .iter()
                        .take(SHOWN)
                        .map(|n| (self.nodes[n].1, node_label.to_string())),
                );
                labels
            }
            Fault::ForcedJunction { diode, sources } => {
                let mut labels =
                    self.labels_of(std::slice::from_ref(diode), "its voltage is forced");
                labels.extend(self.labels_of(sources, "fixes it"));
                labels
            }
        }
    }

    fn help(&self) -> &'static str {
        match &self.fault {
            Fault::CapacitorLoop { .. } => {
                "kausal removes the integrator by index reduction (Pantelides); --prefer-state chooses which capacitor keeps its state"
            }
            Fault::InductorCutset { .. } => {
                "kausal removes the integrator by index reduction (Pantelides); --prefer-state chooses which inductor keeps its state"
            }
            Fault::VoltageLoop { .. } => "put a resistor in the loop, or remove one of the sources",
            Fault::CurrentCutset { .. } => {
                "give the node a path for current, e.g. a resistor to ground"
            }
            Fault::Floating { .. } => {
                "give every node a path to ground, e.g. a resistor (ngspice needs a DC path too)"
            }
            Fault::ForcedJunction { .. } => {
                "give the diode's model a series resistance (RS), or put a resistor in series"
            }
        }
    }
}

impl std::fmt::Display for TopologyError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message())
    }
}

impl std::error::Error for TopologyError {}

impl ToDiagnostic for TopologyError {
    fn to_diagnostic(&self) -> Diagnostic {
        let code = match self.fault {
            Fault::ForcedJunction { .. } => codes::FORCED_JUNCTION,
            _ if self.is_fixable() => codes::COUPLED_STATES,
            _ => codes::CONFLICTING_TOPOLOGY,
        };
        let mut d = Diagnostic::error(code, self.message()).with_help(self.help());
        if self.fault.is_warning() {
            d.severity = Severity::Warning;
        }
        for (span, label) in self.labels() {
            d = d.with_label(span, label);
        }
        d
    }
}
