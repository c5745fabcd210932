//! Index reduction by Pantelides' algorithm, as seed 001 teaches it: a
//! constraint equation (all its edges blue) is differentiated and added; one
//! state of the constraint loses its integrator (it and its derivative become
//! algebraic unknowns); every equation that defines a variable whose
//! derivative the new equation needs is differentiated too, until no new
//! variables appear. Repeat while the colouring finds constraints.
//!
//! The pass returns a new, augmented system; the input is not changed.

use std::collections::{HashMap, HashSet};

use super::error::{Culprit, StructuralError};
use super::graph::StructureGraph;
use super::matching::hopcroft_karp;
use crate::ir::{
    EqId, EquationSystem, ExprId, Origin, OriginKind, VarId, VarKind, VarRole, derive,
};

/// How to choose the state that loses its integrator.
#[derive(Clone, Debug, Default)]
pub struct Options {
    /// States the user wants kept (`--prefer-state C1`): demoted last.
    pub keep: Vec<VarId>,
    /// States directly tied to a source (a capacitor across a voltage
    /// source, an inductor in series with a current source): demoted first.
    pub tied: Vec<VarId>,
    /// At most this many rounds (default: the number of equations + 8).
    pub max_rounds: Option<usize>,
}

/// An equation added by differentiating another.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Differentiated {
    pub eq: EqId,
    pub of: EqId,
}

/// A state whose integrator was removed.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct RemovedIntegrator {
    pub state: VarId,
    pub der: VarId,
    /// The constraint that fixed it.
    pub constraint: EqId,
}

/// The augmented system and what was done to get it.
#[derive(Clone, Debug)]
pub struct IndexReduction {
    pub system: EquationSystem,
    pub differentiated: Vec<Differentiated>,
    pub removed: Vec<RemovedIntegrator>,
    /// Constraint equations found, in the order handled.
    pub constraints: Vec<EqId>,
}

/// Reduce the index of `sys` until the colouring finds no constraint.
/// Returns `Ok(None)` when there was nothing to do.
///
/// Each round takes an equation left without an unknown in a maximum
/// matching (the seeds' all-blue constraint) and the equations reachable
/// from it by alternating paths: the structurally over-determined set, one
/// equation more than its unknowns. Those equations are differentiated (once
/// each), which introduces the derivatives of their unknowns, and one state
/// whose derivative they contain loses its integrator.
pub fn reduce_index(
    sys: &EquationSystem,
    opts: &Options,
) -> Result<Option<IndexReduction>, StructuralError> {
    let mut aug = sys.clone();
    let mut red = IndexReduction {
        system: EquationSystem::default(),
        differentiated: Vec::new(),
        removed: Vec::new(),
        constraints: Vec::new(),
    };
    // d/dt of each variable that has one (states: their derivative).
    let mut derivs: HashMap<VarId, VarId> = HashMap::new();
    for (v, var) in aug.vars.iter() {
        if let VarRole::State { der } = var.role {
            derivs.insert(v, der);
        }
    }
    // The derivative of each equation differentiated so far.
    let mut deq: HashMap<EqId, EqId> = HashMap::new();
    let limit = opts.max_rounds.unwrap_or(sys.eqs.len() + 8);
    let keep: HashSet<VarId> = opts.keep.iter().copied().collect();
    let tied: HashSet<VarId> = opts.tied.iter().copied().collect();
    for iteration in 0.. {
        let err = match super::causalize(&aug, super::Options::default()) {
            Ok(_) => break,
            Err(e) => e,
        };
        let StructuralError::Singular { constraints, .. } = &err else {
            return Err(err);
        };
        if constraints.is_empty() {
            // Under-determined only: nothing to differentiate.
            return Err(err);
        }
        if iteration >= limit {
            return Err(StructuralError::IndexLimit {
                iterations: iteration,
                limit,
            });
        }
        // The colouring's first all-blue equation, as the seeds find it.
        let prefer = constraints
            .iter()
            .filter_map(|c| c.eq)
            .find(|&e| !matches!(aug.eqs[e].origin.kind, OriginKind::Derivative { .. }));
        let sets = overdetermined_sets(&aug, prefer);
        if sets.is_empty() {
            return Err(err);
        }
        // Handling a set adds equations and turns one state into an unknown;
        // a later set whose equations do not contain that state keeps its
        // unknowns, so it is still over-determined, and is handled in the
        // same round (one set a round would make 3000 inductors in a cutset
        // cost 3000 matchings of the whole system). The others wait a round.
        // When the first set's state is in all the others (parallel
        // capacitors whose matching runs through one of them), the rest are
        // found again at once, without the preferred constraint: their own
        // constraints then give up their own states.
        let mut sets = sets;
        for pass in 0..2 {
            let mut skipped = 0;
            let mut demoted: HashSet<VarId> = HashSet::new();
            let (mut vars, mut stack) = (Vec::new(), Vec::new());
            for (g, set) in sets {
                let touches_demoted = !demoted.is_empty()
                    && set.iter().any(|&e| {
                        aug.eq_vars(e, &mut vars, &mut stack);
                        vars.iter().any(|v| demoted.contains(v))
                    });
                if touches_demoted {
                    skipped += 1;
                    continue;
                }
                // Differentiate every equation of the set not differentiated yet.
                for &eq in &set {
                    if deq.contains_key(&eq) {
                        continue;
                    }
                    let new_eq = differentiate(&mut aug, &mut derivs, eq);
                    deq.insert(eq, new_eq);
                    red.differentiated
                        .push(Differentiated { eq: new_eq, of: eq });
                    if red.differentiated.len() > 4 * sys.eqs.len() + 16 {
                        return Err(StructuralError::IndexLimit {
                            iterations: iteration,
                            limit,
                        });
                    }
                }
                // A state whose derivative the differentiated set contains.
                let derived: Vec<EqId> = set.iter().map(|e| deq[e]).collect();
                let Some(state) = choose_state(&aug, g, &derived, &keep, &tied) else {
                    return Err(StructuralError::NoStateInConstraint {
                        constraint: Box::new(Culprit::eq(&aug, g)),
                    });
                };
                let der = derivs[&state];
                aug.demote_state(state, der);
                demoted.insert(state);
                red.removed.push(RemovedIntegrator {
                    state,
                    der,
                    constraint: g,
                });
                red.constraints.push(g);
            }
            // The new derivative unknowns are pushed directly; their flags are
            // refreshed once per batch (once per set would be quadratic).
            aug.refresh_unknown();
            if skipped == 0 || pass == 1 {
                break;
            }
            sets = overdetermined_sets(&aug, None);
        }
    }
    if red.removed.is_empty() {
        return Ok(None);
    }
    red.system = aug;
    Ok(Some(red))
}

/// Equations no maximum matching can give an unknown (`prefer` first when
/// it is one, then original equations before differentiated ones), each
/// with the equations reachable from it by alternating paths (it first,
/// then ascending): the structurally over-determined sets, one per equation
/// left unmatched, from one matching.
fn overdetermined_sets(sys: &EquationSystem, prefer: Option<EqId>) -> Vec<(EqId, Vec<EqId>)> {
    let graph = StructureGraph::build(sys);
    let n_eqs = sys.eqs.len();
    let mut index: HashMap<VarId, u32> = HashMap::new();
    let mut vars: Vec<VarId> = Vec::new();
    let adj: Vec<Vec<u32>> = sys
        .eqs
        .ids()
        .map(|e| {
            graph
                .eq_vars(e)
                .map(|v| {
                    *index.entry(v).or_insert_with(|| {
                        vars.push(v);
                        (vars.len() - 1) as u32
                    })
                })
                .collect()
        })
        .collect();
    let mut m = hopcroft_karp(n_eqs, vars.len(), &adj);
    let size = |m: &[u32]| m.iter().filter(|&&r| r != u32::MAX).count();
    if let Some(p) = prefer {
        // A maximum matching that leaves `p` out, if `p` is over-determined.
        let mut without = adj.clone();
        without[p.0 as usize].clear();
        let m2 = hopcroft_karp(n_eqs, vars.len(), &without);
        if size(&m2) == size(&m) {
            m = m2;
        }
    }
    let mut owner = vec![u32::MAX; vars.len()];
    for (l, &r) in m.iter().enumerate() {
        if r != u32::MAX {
            owner[r as usize] = l as u32;
        }
    }
    let key = |l: usize| {
        (
            Some(EqId(l as u32)) != prefer,
            matches!(
                sys.eqs[EqId(l as u32)].origin.kind,
                OriginKind::Derivative { .. }
            ),
            l,
        )
    };
    let mut free: Vec<usize> = (0..n_eqs).filter(|&l| m[l] == u32::MAX).collect();
    free.sort_by_key(|&l| key(l));
    // Searches may overlap (parallel capacitors all reach the node voltage
    // and the first capacitor's equation); their total work is bounded by a
    // few passes over the graph, the rest waits for the next round.
    let budget = 4 * adj.iter().map(Vec::len).sum::<usize>() + n_eqs;
    let mut work = 0;
    let mut eq_mark = vec![0u32; n_eqs];
    let mut var_mark = vec![0u32; vars.len()];
    let mut sets = Vec::new();
    for (search, &g) in free.iter().enumerate() {
        if work > budget && !sets.is_empty() {
            break;
        }
        let stamp = search as u32 + 1;
        let mut stack = vec![g];
        eq_mark[g] = stamp;
        let mut set = Vec::new();
        while let Some(l) = stack.pop() {
            set.push(EqId(l as u32));
            work += adj[l].len() + 1;
            for &r in &adj[l] {
                if var_mark[r as usize] == stamp {
                    continue;
                }
                var_mark[r as usize] = stamp;
                let o = owner[r as usize];
                if o != u32::MAX && eq_mark[o as usize] != stamp {
                    eq_mark[o as usize] = stamp;
                    stack.push(o as usize);
                }
            }
        }
        set[1..].sort();
        sets.push((EqId(g as u32), set));
    }
    sets
}

/// Add `d/dt` of equation `eq` to `aug`, with a fresh `der(x)` for each
/// variable that has none yet (`derivs`); the caller refreshes the unknown
/// flags.
fn differentiate(aug: &mut EquationSystem, derivs: &mut HashMap<VarId, VarId>, eq: EqId) -> EqId {
    let e = aug.eqs[eq].clone();
    let mut memo = HashMap::new();
    let (vars, names) = (&mut aug.vars, &mut aug.names);
    let mut dvar = |x: VarId, arena: &mut crate::ir::ExprArena| -> ExprId {
        let d = *derivs
            .entry(x)
            .or_insert_with(|| new_derivative(vars, names, x));
        arena.var(d)
    };
    let dl = derive::time_derivative(&mut aug.exprs, e.lhs, &mut dvar, &mut memo);
    let dr = derive::time_derivative(&mut aug.exprs, e.rhs, &mut dvar, &mut memo);
    aug.add_eq(
        dl,
        dr,
        Origin {
            kind: OriginKind::Derivative {
                of: eq,
                from: e.origin.entity().cloned(),
            },
        },
    )
}

/// A fresh algebraic unknown `der(x)` (the caller refreshes the system's
/// unknown flags).
fn new_derivative(
    vars: &mut crate::ir::IdVec<VarId, crate::ir::Var>,
    names: &mut crate::ir::NameTable<VarId>,
    x: VarId,
) -> VarId {
    let name = crate::ir::joined(&["der(", names.get(x), ")"]);
    names.push(&name);
    let base = &vars[x];
    vars.push(crate::ir::Var {
        kind: VarKind::Derivative,
        role: VarRole::Unknown,
        origin: base.origin.clone(),
        alias: None,
    })
}

/// The state that loses its integrator: among the states whose derivative
/// occurs in the differentiated equations `derived` — not one the user
/// keeps, then one tied to a source (the circuit-level diagnosis names it),
/// then one in the constraint `g` itself, then the last in netlist order.
fn choose_state(
    sys: &EquationSystem,
    g: EqId,
    derived: &[EqId],
    keep: &HashSet<VarId>,
    tied: &HashSet<VarId>,
) -> Option<VarId> {
    let (mut vars, mut stack) = (Vec::new(), Vec::new());
    sys.eq_vars(g, &mut vars, &mut stack);
    let in_g: HashSet<VarId> = vars.iter().copied().collect();
    let mut states: Vec<VarId> = Vec::new();
    let mut seen: HashSet<VarId> = HashSet::new();
    for &e in derived {
        sys.eq_vars(e, &mut vars, &mut stack);
        for &v in &vars {
            if let VarRole::Derivative { of } = sys.vars[v].role
                && seen.insert(of)
            {
                states.push(of);
            }
        }
    }
    states.into_iter().min_by_key(|s| {
        (
            keep.contains(s),
            !tied.contains(s),
            !in_g.contains(s),
            std::cmp::Reverse(s.0),
        )
    })
}
