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
//! Next, an unknown that a select on other unknowns flips in sign (a
//! MOSFET's current in its own frame, `vds ≥ 0 ? id : −id`) comes after
//! the rest: torn, it keeps its value while the condition flips, and
//! the residual jumps. And in a block of at most [`SMALL_BLOCK`] equations
//! with such an unknown, every unknown with each of its equations as the
//! residual is a candidate (a CMOS inverter's output loop: one tear where
//! Cellier's candidates take four). On linear blocks this is exactly
//! Cellier's rule.

use super::EdgeColour;
use super::colour::Colouring;
use super::solve;
use crate::ir::{EqId, EquationSystem, VarId};

/// At most this many equations and candidates are tried per tear, so that a
/// tear costs O(block) even when a huge block ties everywhere.
const MAX_TRIED: usize = 24;

/// Up to this many equations, a block with a MOSFET's frame (a switched
/// unknown) tries every unknown as a tear: Cellier's candidates (the widest
/// equations' unknowns) tear the frame's own quantities, whose residual
/// jumps where the frame flips; a CMOS inverter's loop is computed forward
/// from one node potential instead of four such tears. Blocks without one
/// keep Cellier's candidates: on a BJT block (Xyce's bug_138_2) the greedy
/// gain through the junctions' exponentials tore half as often, and the
/// integrator's Newton no longer converged.
const SMALL_BLOCK: usize = 160;

/// How a candidate tear ranks, smallest first: nonlinear inversions, then
/// whether a select flips it in sign, then the most equations causalized.
type TearKey = (usize, bool, std::cmp::Reverse<usize>);

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
    /// The block's unknowns that a select of one of its equations flips in
    /// sign on other unknowns ([`solve::switched_vars`]): torn, they make
    /// the residual jump; chosen after the others.
    switched: Vec<VarId>,
    /// The equations of a small block with a switched unknown (else
    /// empty): every unknown of them, with each of its equations as the
    /// residual, is a candidate.
    small: Vec<EqId>,
    nonlinear_edges: Vec<u32>,
    nl_cursor: usize,
}

impl BlockTearer {
    /// Start tearing `block`; marks its nonlinear edges in `c`.
    pub fn new(c: &mut Colouring<'_>, sys: &EquationSystem, block: &[EqId]) -> BlockTearer {
        c.strict = true;
        let mut buckets: Vec<Vec<EqId>> = Vec::new();
        let mut nonlinear_edges = Vec::new();
        let mut switched = Vec::new();
        for &e in block {
            let eq = &sys.eqs[e];
            // Affine in all its unknowns together is affine in each: one pass
            // over the equation instead of one per unknown (which would be
            // quadratic in a KVL loop of 10^4 elements).
            let affine = solve::is_linear_in(&sys.exprs, eq.lhs, &|_| true)
                && solve::is_linear_in(&sys.exprs, eq.rhs, &|_| true);
            if !affine {
                for side in [eq.lhs, eq.rhs] {
                    switched.extend(solve::switched_vars(&sys.exprs, side));
                }
            }
            for k in c.g.eq_edges(e) {
                let v = c.g.edge_var[k as usize];
                let linear = affine
                    || (solve::is_linear_in(&sys.exprs, eq.lhs, &|w| w == v)
                        && solve::is_linear_in(&sys.exprs, eq.rhs, &|w| w == v));
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
        switched.sort_unstable();
        switched.dedup();
        // A MOSFET's frame in a small block: every unknown is a candidate.
        let small = if !switched.is_empty() && block.len() <= SMALL_BLOCK {
            block.to_vec()
        } else {
            Vec::new()
        };
        BlockTearer {
            buckets,
            switched,
            small,
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
    /// `mates` is a perfect matching of what is left (kept up to date here),
    /// so that the residual chosen always leaves the rest solvable.
    pub fn choose(&mut self, c: &mut Colouring<'_>, mates: &mut Mates) -> Option<Tear> {
        let widest = self.widest(c, MAX_TRIED);
        let &first = widest.first()?;
        if c.eq_black[first.0 as usize] == 0 {
            return None;
        }
        // The first MAX_TRIED unknowns of the widest equations that occur in
        // the most unused equations. Gathering stops there: each unknown is
        // checked against those gathered, which over all the tied terms of a
        // KCL of 10^6 currents would be quadratic.
        let mut candidates: Vec<(EqId, VarId)> = Vec::with_capacity(2 * MAX_TRIED);
        'eqs: for &e in &widest {
            let most = c
                .black_vars(e)
                .map(|v| c.var_black[v.0 as usize])
                .max()
                .unwrap_or(0);
            for v in c.black_vars(e) {
                if candidates.len() >= MAX_TRIED {
                    break 'eqs;
                }
                if c.var_black[v.0 as usize] == most && !candidates.iter().any(|&(_, w)| w == v) {
                    candidates.push((e, v));
                }
            }
        }
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
        for &e in &self.small {
            if c.is_done(e) {
                continue;
            }
            // Each of its unknowns with each equation as the residual: the
            // residual decides what the tear computes forward.
            for v in c.black_vars(e) {
                if !candidates.contains(&(e, v)) {
                    candidates.push((e, v));
                }
            }
        }
        let mut best: Option<(Tear, TearKey)> = None;
        for &(e, v) in &candidates {
            // The residual a perfect matching allows (the candidate's own
            // equation when possible).
            let e = if mates.path(c, e, v) {
                e
            } else {
                mates.mate(v).unwrap_or(e)
            };
            let (gain, inversions) = c.trial_tear(e, v);
            let switched = self.switched.binary_search(&v).is_ok();
            let key = (inversions, switched, std::cmp::Reverse(gain));
            if best.is_none_or(|(_, k)| key < k) {
                let tear = Tear {
                    eq: e,
                    var: v,
                    gain,
                    inversions,
                    candidates: candidates.len(),
                };
                best = Some((tear, key));
            }
        }
        let (mut t, _) = best?;
        t.eq = mates.pair(c, t.eq, t.var);
        Some(t)
    }
}

/// A perfect matching of the unassigned part (equation ↔ unknown), from the
/// last BLT decomposition. Forced colouring moves belong to every perfect
/// matching, so it stays valid as long as tears agree with it.
pub struct Mates {
    of_eq: Vec<u32>,
    of_var: Vec<u32>,
    /// Scratch of [`Mates::path`], valid where stamped with the current
    /// search: the equation each unknown was reached from, and which
    /// equations were queued (arrays, not hash maps: a block torn 10^4
    /// times runs 10^5 searches).
    prev_var: Vec<u32>,
    var_stamp: Vec<u32>,
    eq_stamp: Vec<u32>,
    stamp: u32,
    queue: std::collections::VecDeque<u32>,
}

const NONE: u32 = u32::MAX;

impl Mates {
    pub fn new(n_eqs: usize, n_vars: usize) -> Mates {
        Mates {
            of_eq: vec![NONE; n_eqs],
            of_var: vec![NONE; n_vars],
            prev_var: vec![NONE; n_vars],
            var_stamp: vec![0; n_vars],
            eq_stamp: vec![0; n_eqs],
            stamp: 0,
            queue: Default::default(),
        }
    }

    pub fn set(&mut self, pairs: &[(EqId, VarId)]) {
        for &(e, v) in pairs {
            self.of_eq[e.0 as usize] = v.0;
            self.of_var[v.0 as usize] = e.0;
        }
    }

    fn mate(&self, v: VarId) -> Option<EqId> {
        let e = self.of_var[v.0 as usize];
        (e != NONE).then_some(EqId(e))
    }

    /// The residual equation for tearing `v`: `e` when some perfect matching
    /// pairs them (the matching is moved onto it along an alternating path),
    /// else the equation `v` is matched to.
    fn pair(&mut self, c: &Colouring<'_>, e: EqId, v: VarId) -> EqId {
        let e0 = self.of_var[v.0 as usize];
        if e0 == NONE || e0 == e.0 {
            return e;
        }
        if !self.path(c, e, v) {
            return EqId(e0);
        }
        let w = self.of_eq[e.0 as usize];
        // Shift the matching along the path, then pair (e, v).
        let mut x = w;
        loop {
            let q = self.prev_var[x as usize];
            let old = self.of_eq[q as usize];
            self.of_eq[q as usize] = x;
            self.of_var[x as usize] = q;
            if q == e0 {
                break;
            }
            x = old;
        }
        self.of_eq[e.0 as usize] = v.0;
        self.of_var[v.0 as usize] = e.0;
        e
    }

    /// Whether an alternating path lets `e` take `v`: from `v`'s equation to
    /// `e`'s unknown, left in `prev_var` (trivially true when `e` already
    /// has `v` or `v` has no mate).
    fn path(&mut self, c: &Colouring<'_>, e: EqId, v: VarId) -> bool {
        let e0 = self.of_var[v.0 as usize];
        if e0 == NONE || e0 == e.0 {
            return true;
        }
        let w = self.of_eq[e.0 as usize];
        if w == NONE {
            return false;
        }
        self.stamp = self.stamp.wrapping_add(1);
        if self.stamp == 0 {
            self.var_stamp.fill(0);
            self.eq_stamp.fill(0);
            self.stamp = 1;
        }
        let stamp = self.stamp;
        // Breadth-first from e0 (which gives up v) to var w (which gives up e):
        // e0 -x1- M(x1) -x2- ... -w, along black edges of unassigned nodes.
        self.queue.clear();
        self.queue.push_back(e0);
        self.eq_stamp[e0 as usize] = stamp;
        self.eq_stamp[e.0 as usize] = stamp;
        while let Some(q) = self.queue.pop_front() {
            for k in c.g.eq_edges(EqId(q)) {
                if c.colour[k as usize] != EdgeColour::Black {
                    continue;
                }
                let x = c.g.edge_var[k as usize].0;
                if x == v.0 || self.var_stamp[x as usize] == stamp {
                    continue;
                }
                self.var_stamp[x as usize] = stamp;
                self.prev_var[x as usize] = q;
                if x == w {
                    return true;
                }
                let next = self.of_var[x as usize];
                if next != NONE && self.eq_stamp[next as usize] != stamp {
                    self.eq_stamp[next as usize] = stamp;
                    self.queue.push_back(next);
                }
            }
        }
        false
    }
}
