//! The cross-check of the two views of one circuit: the bond graph's
//! causality (SCAP) against the equations' (colouring, tearing, index
//! reduction). Five comparisons, each a [`Finding`]:
//!
//! 1. states: storage ports in integral causality against the states left
//!    after index reduction (less the states of B sources' `ddt()`, which
//!    the graph draws as signals);
//! 2. dependent states: ports in derivative causality against the states
//!    Pantelides removed (and the windings a perfectly coupled field cannot
//!    keep, which the build removed). Where they differ in name only, SCAP
//!    is run again taking index reduction's choice last; if it then lands on
//!    that choice, the two are equally valid and the report names both;
//! 3. arbitrary causality: every resistor SCAP had to choose lies in an
//!    algebraic block of the colouring;
//! 4. algebraic loops: the elements whose laws lie in a loop of the
//!    read-off equations lie in a block of the colouring, and every block
//!    holds one of them (a block may hold more: the nodal formulation's node
//!    potentials and per-element KCL can pull an element in that the bond
//!    graph, summing a difference or a parallel group's current, solves
//!    outside any loop; the report names them and why);
//! 5. laws: outside loops, each simple element's law is solved for the same
//!    kind of variable (effort, flow or a derivative) in both views.

use std::collections::{BTreeSet, HashMap};

use super::equations::{QtyKind, ReadOff};
use super::scap::{self, Causality};
use super::{Analysis, BondGraph, Law, StateKey, StateKind, VertexKind};
use crate::elab::{ElemId, ElementKind};
use crate::ir::{EquationSystem, OriginKind, VarId, VarKind};
use crate::pipeline::Sorted;

/// One of the five comparisons.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Item {
    States,
    Dependent,
    Arbitrary,
    Loops,
    Laws,
}

impl Item {
    pub fn title(self) -> &'static str {
        match self {
            Item::States => "states",
            Item::Dependent => "dependent states",
            Item::Arbitrary => "arbitrary causality",
            Item::Loops => "algebraic loops",
            Item::Laws => "laws",
        }
    }
}

/// The outcome of one comparison, with what each view says and why they
/// differ where they do.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Finding {
    pub item: Item,
    pub agrees: bool,
    pub text: String,
}

/// How an element's law is solved: for its effort, its flow, or a
/// derivative (a state's, in integral causality).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Solved {
    Effort,
    Flow,
    Derivative,
}

/// The cross-check of one circuit.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Check {
    pub findings: Vec<Finding>,
    /// SCAP's assignment with index reduction's dependent states, where it
    /// differs from the first but is equally valid (the later findings use it).
    #[serde(skip)]
    pub alternative: Option<(Causality, ReadOff)>,
}

impl Check {
    pub fn agrees(&self) -> bool {
        self.findings.iter().all(|f| f.agrees)
    }
}

/// Cross-check `a` (the bond graph of `sorted`'s circuit) against `sorted`.
pub fn check(sorted: &Sorted, a: &Analysis) -> Check {
    check_with(sorted, &a.graph, &a.causality, &a.equations)
}

/// [`check`] of a given assignment (a test can hand it a wrong one).
pub fn check_with(
    sorted: &Sorted,
    g: &BondGraph,
    causality: &Causality,
    equations: &ReadOff,
) -> Check {
    let c = &sorted.elaborated.circuit;
    let sys = sorted.system();
    let names: HashMap<&str, ElemId> = c
        .elements
        .iter()
        .map(|(id, e)| (e.name.as_str(), id))
        .collect();
    let key_of = |sys: &EquationSystem, v: VarId| -> Option<StateKey> {
        let var = &sys.vars[v];
        let OriginKind::Element { name } = &var.origin.kind else {
            return None;
        };
        let elem = *names.get(&**name)?;
        let kind = match var.kind {
            VarKind::BranchVoltage | VarKind::Potential => StateKind::Voltage,
            VarKind::BranchCurrent => StateKind::Current,
            VarKind::Charge => StateKind::Charge,
            VarKind::Derivative => return None,
        };
        Some(StateKey { elem, kind })
    };
    let mut findings = Vec::new();
    let name = |e: ElemId| g.element_name(e).to_string();
    let key_name = |k: &StateKey| {
        let prefix = match k.kind {
            StateKind::Voltage => "u_",
            StateKind::Current => "i_",
            StateKind::Charge => "q_",
        };
        format!("{prefix}{}", name(k.elem))
    };
    let list = |ks: &BTreeSet<StateKey>| capped(ks.iter().map(key_name).collect());

    // 1. States.
    let mut hidden = Vec::new();
    let mut states = 0;
    for v in sys.states() {
        match key_of(sys, v) {
            Some(k) if !matches!(c.elements[k.elem].kind, ElementKind::Behavioural { .. }) => {
                states += 1
            }
            _ => hidden.push(sys.var_name(v).to_string()),
        }
    }
    let integral = causality.integral().count();
    let mut text = format!(
        "{integral} storage port{} in integral causality; {states} state{} after index reduction",
        plural(integral),
        plural(states)
    );
    if !hidden.is_empty() {
        text.push_str(&format!(
            " (besides {}: B sources' ddt(), drawn as signals)",
            hidden.join(", ")
        ));
    }
    findings.push(Finding {
        item: Item::States,
        agrees: integral == states,
        text,
    });

    // 2. Dependent states.
    let bg: BTreeSet<StateKey> = causality.derivative().filter_map(|s| s.state).collect();
    let mut removed: BTreeSet<StateKey> = BTreeSet::new();
    if let Some(red) = &sorted.reduction {
        for r in &red.removed {
            if let Some(k) = key_of(&sorted.built.system, r.state) {
                removed.insert(k);
            }
        }
    }
    let mut by_build: BTreeSet<StateKey> = BTreeSet::new();
    for group in &sorted.built.reduced {
        for (k, &m) in group.members.iter().enumerate() {
            if !group.pivots.contains(&k) {
                by_build.insert(StateKey {
                    elem: m,
                    kind: StateKind::Current,
                });
            }
        }
    }
    let eq: BTreeSet<StateKey> = removed.union(&by_build).copied().collect();
    let mut alternative = None;
    let why_eq = || {
        let mut parts = Vec::new();
        if !removed.is_empty() {
            parts.push(format!("Pantelides removed {}", list(&removed)));
        }
        if !by_build.is_empty() {
            parts.push(format!(
                "a perfectly coupled field keeps no flux of {} (K0330)",
                list(&by_build)
            ));
        }
        if parts.is_empty() {
            "index reduction removed none".to_string()
        } else {
            parts.join("; ")
        }
    };
    let (agrees, text) = if bg == eq {
        (
            true,
            format!(
                "derivative causality: {}; the equations: {}",
                list(&bg),
                why_eq()
            ),
        )
    } else if bg.len() == eq.len() {
        let opts = scap::Options {
            defer: eq.iter().copied().collect(),
            ..Default::default()
        };
        let (alt, alt_equations) = super::assign(g, opts);
        let alt_set: BTreeSet<StateKey> = alt.derivative().filter_map(|s| s.state).collect();
        if alt_set == eq && alt.conflicts.len() <= causality.conflicts.len() {
            let only_bg: BTreeSet<StateKey> = bg.difference(&eq).copied().collect();
            let only_eq: BTreeSet<StateKey> = eq.difference(&bg).copied().collect();
            let text = format!(
                "derivative causality: {} by SCAP in netlist order; the equations: {}. They differ in {} (SCAP) against {} (the equations), an equally valid choice: SCAP taking the equations' dependent states last puts exactly them in derivative causality, every other storage port integral",
                list(&bg),
                why_eq(),
                list(&only_bg),
                list(&only_eq)
            );
            alternative = Some((alt, alt_equations));
            (true, text)
        } else {
            (
                false,
                format!(
                    "derivative causality: {}; the equations: {}; SCAP cannot put {} in derivative causality (taking them last gives {})",
                    list(&bg),
                    why_eq(),
                    list(&eq),
                    list(&alt_set)
                ),
            )
        }
    } else {
        (
            false,
            format!(
                "derivative causality: {}; the equations: {}",
                list(&bg),
                why_eq()
            ),
        )
    };
    findings.push(Finding {
        item: Item::Dependent,
        agrees,
        text,
    });
    let (causality, equations) = match &alternative {
        Some((c, r)) => (c, r),
        None => (causality, equations),
    };

    // The colouring's blocks: the elements whose laws lie in them.
    let law_element = |sys: &EquationSystem, eq: crate::ir::EqId| -> Option<ElemId> {
        let mut e = eq;
        // A differentiated equation is its original's law.
        for _ in 0..sys.eqs.len() {
            match &sys.eqs[e].origin.kind {
                OriginKind::Derivative { of, .. } => e = *of,
                OriginKind::Element { name } => return names.get(&**name).copied(),
                _ => return None,
            }
        }
        None
    };
    let signal_only = |e: ElemId| matches!(c.elements[e].kind, ElementKind::Intermediate { .. });
    let in_blocks = |s: &Sorted| -> BTreeSet<ElemId> {
        let sys = s.system();
        let mut out = BTreeSet::new();
        for b in s.schedule.blocks() {
            for a in b.inner.iter().chain(&b.residuals) {
                if let Some(e) = law_element(sys, a.eq)
                    && !signal_only(e)
                {
                    out.insert(e);
                }
            }
        }
        out
    };
    let eq_loops = in_blocks(sorted);
    let bg_loops: BTreeSet<ElemId> = equations
        .loops()
        .flat_map(|l| l.elements.iter().copied())
        .collect();
    let elems = |s: &mut dyn Iterator<Item = ElemId>| capped(s.map(name).collect());

    // 3. Arbitrary causality.
    let mut outside = Vec::new();
    let mut chosen = Vec::new();
    for d in causality.arbitrary() {
        let x = &g.vertices[d.vertex];
        if x.kind.is_junction() {
            chosen.push(format!("bond {} at {}", d.bond, g.vertex_name(d.vertex)));
            if eq_loops.is_empty() {
                outside.push(format!("the junction bond {}", d.bond));
            }
            continue;
        }
        chosen.push(g.vertex_name(d.vertex));
        if !g.elements_of(d.vertex).iter().any(|e| eq_loops.contains(e)) {
            outside.push(g.vertex_name(d.vertex));
        }
    }
    let text = if chosen.is_empty() {
        "none chosen arbitrarily".to_string()
    } else if outside.is_empty() {
        format!(
            "chosen arbitrarily: {}; each in an algebraic block of the colouring",
            capped(chosen)
        )
    } else {
        format!(
            "chosen arbitrarily: {}; not in any algebraic block of the colouring: {}",
            capped(chosen),
            capped(outside.clone())
        )
    };
    findings.push(Finding {
        item: Item::Arbitrary,
        agrees: outside.is_empty(),
        text,
    });

    // 4. Algebraic loops. Every loop of the bond graph must be in a block of
    // the colouring, and every block must hold a loop of the bond graph. A
    // block may hold more: the nodal formulation solves node potentials the
    // bond graph does not hold (its junctions keep differences) and sums
    // element currents at each node where the bond graph sums a parallel
    // group's, which can pull an element into a block. Where the views
    // differ, the loop formulation (KVL on a tree's loops, no potentials) is
    // asked as well.
    let only_bg: Vec<ElemId> = bg_loops.difference(&eq_loops).copied().collect();
    let only_eq: Vec<ElemId> = eq_loops.difference(&bg_loops).copied().collect();
    let loop_form = (!only_bg.is_empty() || !only_eq.is_empty())
        .then(|| loop_formulation(sorted))
        .flatten()
        .map(|s| in_blocks(&s));
    let explained = |e: &ElemId| {
        loop_form
            .as_ref()
            .is_some_and(|l| l.contains(e) == bg_loops.contains(e))
    };
    let (only_bg, bg_explained): (Vec<ElemId>, Vec<ElemId>) =
        only_bg.into_iter().partition(|e| !explained(e));
    let (only_eq, eq_explained): (Vec<ElemId>, Vec<ElemId>) =
        only_eq.into_iter().partition(|e| !explained(e));
    // Blocks of the colouring with no element of a bond-graph loop.
    let unmatched: Vec<usize> = sorted
        .schedule
        .blocks()
        .filter(|b| {
            let laws: Vec<ElemId> = b
                .inner
                .iter()
                .chain(&b.residuals)
                .filter_map(|a| law_element(sys, a.eq))
                .filter(|&e| !signal_only(e))
                .collect();
            !laws.is_empty() && !laws.iter().any(|e| bg_loops.contains(e))
        })
        .map(|b| b.index)
        .collect();
    let n_bg = equations.loops().count();
    let n_eq = sorted.schedule.blocks().count();
    let mut text = format!(
        "{n_bg} loop{} of the read-off equations through {}; {n_eq} block{} of the colouring through {}",
        plural(n_bg),
        elems(&mut bg_loops.iter().copied()),
        plural(n_eq),
        elems(&mut eq_loops.iter().copied())
    );
    if !only_bg.is_empty() {
        text.push_str(&format!(
            "; in a loop of the bond graph only (in either formulation): {}",
            elems(&mut only_bg.iter().copied())
        ));
    }
    if !unmatched.is_empty() {
        let ks: Vec<String> = unmatched.iter().map(|k| k.to_string()).collect();
        text.push_str(&format!(
            "; block{} {} of the colouring hold{} no loop of the bond graph",
            plural(ks.len()),
            ks.join(", "),
            if ks.len() == 1 { "s" } else { "" }
        ));
    }
    if !eq_explained.is_empty() {
        text.push_str(&format!(
            ". {} in a block of the nodal colouring only because the node potentials it reads are solved there (the bond graph holds only their difference); with KVL on loops (no potentials) the colouring has {} outside every block too",
            elems(&mut eq_explained.iter().copied()),
            if eq_explained.len() == 1 { "it" } else { "them" }
        ));
    }
    if !only_eq.is_empty() {
        text.push_str(&format!(
            ". {} in a block of the colouring only, in either formulation: the equations sum each element's current at its nodes, inside the block, where the bond graph sums the current of the parallel group it belongs to, outside any loop",
            elems(&mut only_eq.iter().copied())
        ));
    }
    if !bg_explained.is_empty() {
        text.push_str(&format!(
            ". {} in a loop of the bond graph and in a block of the colouring with KVL on loops, not of the nodal one",
            elems(&mut bg_explained.iter().copied())
        ));
    }
    findings.push(Finding {
        item: Item::Loops,
        agrees: only_bg.is_empty() && unmatched.is_empty(),
        text,
    });

    // 5. Laws outside loops.
    let bg_solved = solved_in_graph(g, equations);
    let eq_solved = solved_in_equations(sorted, &law_element);
    let mut compared = 0;
    let mut differ = Vec::new();
    for (e, s) in &bg_solved {
        if bg_loops.contains(e) || eq_loops.contains(e) {
            continue;
        }
        let Some(t) = eq_solved.get(e) else {
            continue;
        };
        compared += 1;
        if s != t {
            differ.push(format!(
                "{} (bond graph: {}; equations: {})",
                name(*e),
                solved_name(*s),
                solved_name(*t)
            ));
        }
    }
    let text = if differ.is_empty() {
        format!(
            "{compared} element law{} outside loops solved for the same variable in both views",
            plural(compared)
        )
    } else {
        format!(
            "{} of {compared} element laws outside loops solved differently: {}",
            differ.len(),
            capped(differ.clone())
        )
    };
    findings.push(Finding {
        item: Item::Laws,
        agrees: differ.is_empty(),
        text,
    });
    Check {
        findings,
        alternative,
    }
}

/// The check of a circuit whose equations cannot be sorted (a loop of
/// voltage sources, a cutset of current sources): the views agree when the
/// bond graph has a causal conflict too.
pub fn check_unsorted(a: &Analysis, why: &str) -> Check {
    let n = a.causality.conflicts.len();
    let agrees = n > 0;
    let text = if agrees {
        format!(
            "the equations cannot be sorted ({why}); the bond graph has {n} causal conflict{}",
            plural(n)
        )
    } else {
        format!("the equations cannot be sorted ({why}); the bond graph has no causal conflict")
    };
    Check {
        findings: vec![Finding {
            item: Item::States,
            agrees,
            text,
        }],
        alternative: None,
    }
}

/// The same circuit sorted with KVL on a tree's loops (no node potentials).
fn loop_formulation(sorted: &Sorted) -> Option<Sorted> {
    let el = crate::pipeline::Elaborated {
        sources: sorted.elaborated.sources.clone(),
        circuit: sorted.elaborated.circuit.clone(),
        warnings: Vec::new(),
    };
    let opts = crate::pipeline::SortOptions {
        build: crate::build::Options {
            kvl: crate::build::Kvl::Loops,
            alias: false,
            algebraic_charges: false,
        },
        ..Default::default()
    };
    let built = crate::build::build(&el.circuit, opts.build);
    crate::pipeline::sort_built(el, built, &opts).ok()
}

/// Names joined, at most [`SHOWN`] of them, then how many more.
fn capped(names: Vec<String>) -> String {
    match names.len() {
        0 => "none".to_string(),
        n if n <= SHOWN => names.join(", "),
        n => format!("{}, … ({} more)", names[..SHOWN].join(", "), n - SHOWN),
    }
}

/// Names a finding lists before it counts the rest.
const SHOWN: usize = 12;

fn plural(n: usize) -> &'static str {
    if n == 1 { "" } else { "s" }
}

fn solved_name(s: Solved) -> &'static str {
    match s {
        Solved::Effort => "its voltage",
        Solved::Flow => "its current",
        Solved::Derivative => "a derivative",
    }
}

/// Whether an element is simple enough to compare laws one to one: one
/// constitutive equation in both views.
fn simple(g: &BondGraph, e: ElemId) -> bool {
    let vs = &g.elements[e.0 as usize].vertices;
    vs.len() == 1
        && match &g.vertices[vs[0]].law {
            Law::Linear { .. }
            | Law::Source { .. }
            | Law::Controlled { .. }
            | Law::Switch { .. } => true,
            Law::Nonlinear { .. } => {
                matches!(g.vertices[vs[0]].kind, VertexKind::MSe | VertexKind::MSf)
                    && matches!(
                        g.vertices[vs[0]].origin,
                        super::Origin::Element {
                            part: super::Part::Whole,
                            ..
                        }
                    )
            }
            _ => false,
        }
}

fn solved_in_graph(g: &BondGraph, r: &ReadOff) -> Vec<(ElemId, Solved)> {
    let mut out: Vec<(ElemId, Solved)> = Vec::new();
    for e in &r.equations {
        let Some(elem) = e.element else {
            continue;
        };
        if !e.law || e.of.is_some() || !simple(g, elem) || out.iter().any(|(x, _)| *x == elem) {
            continue;
        }
        let s = if e.lhs.order > 0 {
            Solved::Derivative
        } else {
            match r.quantities[e.lhs.q].kind {
                QtyKind::Effort => Solved::Effort,
                QtyKind::Flow => Solved::Flow,
                QtyKind::State | QtyKind::Internal => continue,
            }
        };
        out.push((elem, s));
    }
    out
}

fn solved_in_equations(
    sorted: &Sorted,
    law_element: &dyn Fn(&EquationSystem, crate::ir::EqId) -> Option<ElemId>,
) -> HashMap<ElemId, Solved> {
    let sys = sorted.system();
    let mut out = HashMap::new();
    for a in sorted.schedule.assignments() {
        if matches!(sys.eqs[a.eq].origin.kind, OriginKind::Derivative { .. }) {
            continue;
        }
        let Some(e) = law_element(sys, a.eq) else {
            continue;
        };
        let s = match sys.vars[a.var].kind {
            VarKind::BranchVoltage | VarKind::Potential => Solved::Effort,
            VarKind::BranchCurrent => Solved::Flow,
            VarKind::Derivative | VarKind::Charge => Solved::Derivative,
        };
        out.entry(e).or_insert(s);
    }
    out
}
