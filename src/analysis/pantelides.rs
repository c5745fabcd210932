//! Index reduction by Pantelides' algorithm, as seed 001 teaches it: a
//! constraint equation (all its edges blue) is differentiated and added; one
//! state of the constraint loses its integrator (it and its derivative become
//! algebraic unknowns); every equation that defines a variable whose
//! derivative the new equation needs is differentiated too, until no new
//! variables appear. Repeat while the colouring finds constraints.
//!
//! The pass returns a new, augmented system; the input is not changed.

use std::collections::HashMap;

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
        let Some((g, set)) = overdetermined_set(&aug, prefer) else {
            return Err(err);
        };
        // Differentiate every equation of the set not differentiated yet.
        for &eq in &set {
            if deq.contains_key(&eq) {
                continue;
            }
            let e = aug.eqs[eq].clone();
            let mut memo = HashMap::new();
            let mut dvar = |x: VarId, arena: &mut crate::ir::ExprArena| -> ExprId {
                let d = *derivs
                    .entry(x)
                    .or_insert_with(|| new_derivative(&mut aug.vars, x));
                arena.var(d)
            };
            let dl = derive::time_derivative(&mut aug.exprs, e.lhs, &mut dvar, &mut memo);
            let dr = derive::time_derivative(&mut aug.exprs, e.rhs, &mut dvar, &mut memo);
            let new_eq = aug.add_eq(
                dl,
                dr,
                Origin {
                    kind: OriginKind::Derivative { of: eq },
                    span: e.origin.span,
                },
            );
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
        aug.refresh_unknown();
        // A state whose derivative the differentiated set contains.
        let derived: Vec<EqId> = set.iter().map(|e| deq[e]).collect();
        let Some(state) = choose_state(&aug, g, &derived, opts) else {
            return Err(StructuralError::NoStateInConstraint {
                constraint: Box::new(Culprit::eq(&aug, g)),
            });
        };
        let der = derivs[&state];
        aug.demote_state(state, der);
        red.removed.push(RemovedIntegrator {
            state,
            der,
            constraint: g,
        });
        red.constraints.push(g);
    }
    if red.removed.is_empty() {
        return Ok(None);
    }
    red.system = aug;
    Ok(Some(red))
}

/// An equation no maximum matching can give an unknown (`prefer` when it is
/// one), and the equations reachable from it by alternating paths (it first,
/// then ascending).
fn overdetermined_set(sys: &EquationSystem, prefer: Option<EqId>) -> Option<(EqId, Vec<EqId>)> {
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
    // The preferred equation, else original equations before differentiated ones.
    let g = (0..n_eqs).filter(|&l| m[l] == u32::MAX).min_by_key(|&l| {
        (
            Some(EqId(l as u32)) != prefer,
            matches!(
                sys.eqs[EqId(l as u32)].origin.kind,
                OriginKind::Derivative { .. }
            ),
            l,
        )
    })?;
    let mut seen_eq = vec![false; n_eqs];
    let mut seen_var = vec![false; vars.len()];
    let mut stack = vec![g];
    seen_eq[g] = true;
    let mut set = Vec::new();
    while let Some(l) = stack.pop() {
        set.push(EqId(l as u32));
        for &r in &adj[l] {
            if seen_var[r as usize] {
                continue;
            }
            seen_var[r as usize] = true;
            let o = owner[r as usize];
            if o != u32::MAX && !seen_eq[o as usize] {
                seen_eq[o as usize] = true;
                stack.push(o as usize);
            }
        }
    }
    set[1..].sort();
    Some((EqId(g as u32), set))
}

/// A fresh algebraic unknown `der(x)` (the caller refreshes the system's
/// unknown flags).
fn new_derivative(vars: &mut crate::ir::IdVec<VarId, crate::ir::Var>, x: VarId) -> VarId {
    let base = &vars[x];
    vars.push(crate::ir::Var {
        name: format!("der({})", base.name),
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
fn choose_state(sys: &EquationSystem, g: EqId, derived: &[EqId], opts: &Options) -> Option<VarId> {
    let (mut vars, mut stack) = (Vec::new(), Vec::new());
    sys.eq_vars(g, &mut vars, &mut stack);
    let in_g: Vec<VarId> = vars.clone();
    let mut states: Vec<VarId> = Vec::new();
    for &e in derived {
        sys.eq_vars(e, &mut vars, &mut stack);
        for &v in &vars {
            if let VarRole::Derivative { of } = sys.vars[v].role
                && !states.contains(&of)
            {
                states.push(of);
            }
        }
    }
    states.into_iter().min_by_key(|s| {
        (
            opts.keep.contains(s),
            !opts.tied.contains(s),
            !in_g.contains(s),
            std::cmp::Reverse(s.0),
        )
    })
}
