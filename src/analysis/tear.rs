//! Cellier's tearing heuristic (seed 001): among the equations with the most
//! unknowns, take their unknowns that occur in the most unused equations, and
//! of those the one that, assumed known, lets the colouring causalize the most
//! further equations. Ties go to the first in equation and occurrence order.
//!
//! One refinement for numerics: candidates are ranked first by how many of
//! the assignments they cause would invert a nonlinear function (solving a
//! diode law for its voltage through `ln`, say), fewest first, and the
//! arguments of nonlinear functions in the block join the candidates. Such an
//! inversion is only defined on part of the range (`ln` of a negative
//! number), so a Newton iteration on the tearing variables could leave it.
//! On linear blocks this is exactly Cellier's rule.

use super::colour::Colouring;
use super::solve;
use crate::ir::{EqId, EquationSystem, VarId};

/// At most this many equations and candidates are tried per tear, so that a
/// tear costs O(block) even when a huge block ties everywhere.
const MAX_TRIED: usize = 24;

/// The tearing decision: `var` is guessed and `eq` becomes its residual.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Tear {
    pub eq: EqId,
    pub var: VarId,
    /// Equations causalized by this tear (including the residual).
    pub gain: usize,
    /// Of those, how many are solved through a nonlinear inversion.
    pub inversions: usize,
    /// How many candidates were compared.
    pub candidates: usize,
}

/// Mark the edges of `block` along which solving needs a nonlinear inversion.
pub fn mark_nonlinear(c: &mut Colouring<'_>, sys: &EquationSystem, block: &[EqId]) {
    for &e in block {
        let eq = &sys.eqs[e];
        for k in c.g.eq_edges(e) {
            let v = c.g.edge_var[k as usize];
            let linear = solve::is_linear_in(&sys.exprs, eq.lhs, &|w| w == v)
                && solve::is_linear_in(&sys.exprs, eq.rhs, &|w| w == v);
            c.nonlinear[k as usize] = !linear;
        }
    }
}

/// Pick a tearing variable among the unassigned equations `block`.
pub fn choose(c: &mut Colouring<'_>, block: &[EqId]) -> Option<Tear> {
    let live: Vec<EqId> = block.iter().copied().filter(|&e| !c.is_done(e)).collect();
    let max_deg = live.iter().map(|&e| c.eq_black[e.0 as usize]).max()?;
    if max_deg == 0 {
        return None;
    }
    let widest: Vec<EqId> = live
        .iter()
        .copied()
        .filter(|&e| c.eq_black[e.0 as usize] == max_deg)
        .take(MAX_TRIED)
        .collect();
    let mut candidates: Vec<(EqId, VarId)> = Vec::new();
    for &e in &widest {
        let vars: Vec<VarId> = c.black_vars(e).collect();
        let most = vars
            .iter()
            .map(|v| c.var_black[v.0 as usize])
            .max()
            .unwrap_or(0);
        for v in vars {
            if c.var_black[v.0 as usize] == most && !candidates.iter().any(|&(_, w)| w == v) {
                candidates.push((e, v));
            }
        }
        if candidates.len() >= MAX_TRIED {
            break;
        }
    }
    candidates.truncate(MAX_TRIED);
    // Arguments of nonlinear functions, each paired with a live equation it
    // occurs in linearly (so that the nonlinear law is evaluated forward).
    let mut extra = 0;
    'outer: for &e in &live {
        for k in c.g.eq_edges(e) {
            if extra >= MAX_TRIED {
                break 'outer;
            }
            let v = c.g.edge_var[k as usize];
            if !c.nonlinear[k as usize]
                || c.colour[k as usize] != super::EdgeColour::Black
                || candidates.iter().any(|&(_, w)| w == v)
            {
                continue;
            }
            let partner = c.g.var_edge_ids(v).iter().copied().find(|&j| {
                c.colour[j as usize] == super::EdgeColour::Black && !c.nonlinear[j as usize]
            });
            if let Some(j) = partner {
                candidates.push((c.g.edge_eq[j as usize], v));
                extra += 1;
            }
        }
    }
    let mut best: Option<Tear> = None;
    for &(e, v) in &candidates {
        let (gain, inversions) = c.trial_tear(e, v);
        let better = match best {
            None => true,
            Some(b) => (inversions, std::cmp::Reverse(gain)) < (b.inversions, std::cmp::Reverse(b.gain)),
        };
        if better {
            best = Some(Tear {
                eq: e,
                var: v,
                gain,
                inversions,
                candidates: candidates.len(),
            });
        }
    }
    best
}
