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

use super::EdgeColour;
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

/// Tearing state for one BLT block: its live equations bucketed by black
/// degree (degrees only fall, so stale entries are moved down lazily), and
/// the block's nonlinear edges. Each tear then costs O(what it touches), not
/// O(block): a block torn k times costs O(block + k * trials).
pub struct BlockTearer {
    buckets: Vec<Vec<EqId>>,
    nonlinear_edges: Vec<u32>,
    nl_cursor: usize,
}

impl BlockTearer {
    /// Start tearing `block`; marks its nonlinear edges in `c`.
    pub fn new(c: &mut Colouring<'_>, sys: &EquationSystem, block: &[EqId]) -> BlockTearer {
        let mut buckets: Vec<Vec<EqId>> = Vec::new();
        let mut nonlinear_edges = Vec::new();
        for &e in block {
            let eq = &sys.eqs[e];
            for k in c.g.eq_edges(e) {
                let v = c.g.edge_var[k as usize];
                let linear = solve::is_linear_in(&sys.exprs, eq.lhs, &|w| w == v)
                    && solve::is_linear_in(&sys.exprs, eq.rhs, &|w| w == v);
                c.nonlinear[k as usize] = !linear;
                if !linear {
                    nonlinear_edges.push(k);
                }
            }
            if c.is_done(e) {
                continue;
            }
            let d = c.eq_black[e.0 as usize] as usize;
            if buckets.len() <= d {
                buckets.resize(d + 1, Vec::new());
            }
            buckets[d].push(e);
        }
        // Pop order within a bucket is ascending equation id.
        for b in &mut buckets {
            b.reverse();
        }
        BlockTearer {
            buckets,
            nonlinear_edges,
            nl_cursor: 0,
        }
    }

    /// Up to `n` live equations of the highest black degree, in id order.
    fn widest(&mut self, c: &Colouring<'_>, n: usize) -> Vec<EqId> {
        while let Some(top) = self.buckets.len().checked_sub(1) {
            let mut found: Vec<EqId> = Vec::new();
            let mut moved: Vec<EqId> = Vec::new();
            while let Some(e) = self.buckets[top].pop() {
                if c.is_done(e) {
                    continue;
                }
                let d = c.eq_black[e.0 as usize] as usize;
                if d < top {
                    moved.push(e);
                    continue;
                }
                found.push(e);
                if found.len() >= n {
                    break;
                }
            }
            for e in moved {
                let d = c.eq_black[e.0 as usize] as usize;
                self.buckets[d].push(e);
            }
            if found.is_empty() {
                self.buckets.pop();
                continue;
            }
            // Keep them live for later tears (they are popped again then).
            for &e in found.iter().rev() {
                self.buckets[top].push(e);
            }
            return found;
        }
        Vec::new()
    }

    /// Pick a tearing variable; `None` when the block is fully assigned.
    pub fn choose(&mut self, c: &mut Colouring<'_>) -> Option<Tear> {
        let widest = self.widest(c, MAX_TRIED);
        let &first = widest.first()?;
        if c.eq_black[first.0 as usize] == 0 {
            return None;
        }
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
        // Arguments of nonlinear functions, each paired with an equation it
        // occurs in linearly (so that the nonlinear law is evaluated forward).
        while self.nl_cursor < self.nonlinear_edges.len()
            && c.colour[self.nonlinear_edges[self.nl_cursor] as usize] != EdgeColour::Black
        {
            self.nl_cursor += 1;
        }
        let mut extra = 0;
        for &k in &self.nonlinear_edges[self.nl_cursor..] {
            if extra >= MAX_TRIED {
                break;
            }
            if c.colour[k as usize] != EdgeColour::Black {
                continue;
            }
            let v = c.g.edge_var[k as usize];
            if candidates.iter().any(|&(_, w)| w == v) {
                continue;
            }
            let partner =
                c.g.var_edge_ids(v).iter().copied().find(|&j| {
                    c.colour[j as usize] == EdgeColour::Black && !c.nonlinear[j as usize]
                });
            if let Some(j) = partner {
                candidates.push((c.g.edge_eq[j as usize], v));
                extra += 1;
            }
        }
        let mut best: Option<Tear> = None;
        for &(e, v) in &candidates {
            let (gain, inversions) = c.trial_tear(e, v);
            let better = match best {
                None => true,
                Some(b) => {
                    (inversions, std::cmp::Reverse(gain))
                        < (b.inversions, std::cmp::Reverse(b.gain))
                }
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
}
