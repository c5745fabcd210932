//! The [`Schedule`]: execution order of the sorted assignments, with torn
//! algebraic loops grouped into blocks. Without tearing it is the colouring's
//! numbering; with tearing, the strongly connected components of the
//! assignment dependency graph in topological order (ties broken by the
//! colouring's numbers, so that the listing reads like the seeds').

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use super::graph::strong_components;
use super::solve::{self, Solved};
use super::{Causalization, Rule};
use crate::ir::{EqId, EquationSystem, ExprArena, VarId};

/// `var := expr` (or an implicit equation for `var`).
#[derive(Clone, Debug)]
pub struct Assignment {
    pub eq: EqId,
    pub var: VarId,
    pub solved: Solved,
    /// The colouring's sort number of the equation.
    pub number: u32,
    pub rule: Rule,
}

/// An algebraic loop, solved by guessing the tearing variables, evaluating
/// the inner assignments in order, and driving the residuals to zero.
#[derive(Clone, Debug)]
pub struct Block {
    /// 1-based, in schedule order.
    pub index: usize,
    pub tears: Vec<VarId>,
    pub inner: Vec<Assignment>,
    /// The residual equation of each tearing variable, solved for it where
    /// possible (for display; numerically `lhs - rhs = 0`).
    pub residuals: Vec<Assignment>,
    /// Every equation is affine in the block's unknowns: one linear solve.
    pub linear: bool,
    /// The circuit elements the block's equations come from.
    pub elements: Vec<String>,
}

/// Linear blocks with more tearing variables than this are solved whole.
pub const WHOLE_ABOVE_TEARS: usize = 48;

impl Block {
    pub fn n_eqs(&self) -> usize {
        self.inner.len() + self.residuals.len()
    }

    /// Whether the evaluator solves this block whole, every unknown a Newton
    /// unknown and every equation a residual, rather than by its tears: a
    /// large linear loop, whose torn Jacobian fills in where the circuit's
    /// own is sparse (a resistor mesh). The order of its assignments is the
    /// listing's either way.
    pub fn solved_whole(&self) -> bool {
        self.linear && self.tears.len() > WHOLE_ABOVE_TEARS
    }
}

#[derive(Clone, Debug)]
pub enum Step {
    Assign(Assignment),
    /// Boxed: a block is five times the size of an assignment, and nearly
    /// every step is an assignment.
    Block(Box<Block>),
}

/// Execution order of a causalized system. Back ends follow it and never
/// reorder it. Its solved forms are expressions of the system's own arena
/// ([`schedule`] adds them there).
#[derive(Clone, Debug, Default)]
pub struct Schedule {
    pub steps: Vec<Step>,
}

impl Schedule {
    pub fn blocks(&self) -> impl Iterator<Item = &Block> {
        self.steps.iter().filter_map(|s| match s {
            Step::Block(b) => Some(&**b),
            Step::Assign(_) => None,
        })
    }

    /// Every assignment, blocks flattened (inner first, then residuals).
    pub fn assignments(&self) -> impl Iterator<Item = &Assignment> {
        self.steps
            .iter()
            .flat_map(|s| -> Box<dyn Iterator<Item = &Assignment>> {
                match s {
                    Step::Assign(a) => Box::new(std::iter::once(a)),
                    Step::Block(b) => Box::new(b.inner.iter().chain(b.residuals.iter())),
                }
            })
    }
}

fn assignment(x: &mut ExprArena, sys: &EquationSystem, c: &Causalization, eq: EqId) -> Assignment {
    let var = c.assigned(eq).expect("scheduled equations are assigned");
    let e = &sys.eqs[eq];
    Assignment {
        eq,
        var,
        solved: solve::solve_for(x, e.lhs, e.rhs, var),
        number: c.number(eq),
        rule: c.rule(eq).unwrap_or(Rule::Equation),
    }
}

/// Priority topological order of `n` nodes given `edges` (a DAG), smallest
/// key first among the ready ones.
fn kahn(n: usize, edges: &[(u32, u32)], key: impl Fn(usize) -> u32) -> Vec<usize> {
    let mut indeg = vec![0u32; n];
    let mut succ_start = vec![0usize; n + 1];
    for &(a, _) in edges {
        succ_start[a as usize + 1] += 1;
    }
    for k in 0..n {
        succ_start[k + 1] += succ_start[k];
    }
    let mut fill = succ_start.clone();
    let mut succ = vec![0u32; edges.len()];
    for &(a, b) in edges {
        succ[fill[a as usize]] = b;
        fill[a as usize] += 1;
        indeg[b as usize] += 1;
    }
    let mut heap: BinaryHeap<Reverse<(u32, usize)>> = (0..n)
        .filter(|&i| indeg[i] == 0)
        .map(|i| Reverse((key(i), i)))
        .collect();
    let mut order = Vec::with_capacity(n);
    while let Some(Reverse((_, i))) = heap.pop() {
        order.push(i);
        for &s in &succ[succ_start[i]..succ_start[i + 1]] {
            indeg[s as usize] -= 1;
            if indeg[s as usize] == 0 {
                heap.push(Reverse((key(s as usize), s as usize)));
            }
        }
    }
    order
}

/// Order the assignments of a causalization and solve each for its unknown,
/// adding the solved forms to the system's arena (not to a copy of it: on a
/// 10^5-section ladder the copy and its growth were a fifth of the sort's
/// peak memory).
pub fn schedule(sys: &mut EquationSystem, c: &Causalization) -> Schedule {
    let mut x = std::mem::take(&mut sys.exprs);
    let steps = order(&mut x, sys, c);
    sys.exprs = x;
    Schedule { steps }
}

/// [`schedule`]'s steps, solved into `x` (the system's arena, taken out of
/// `sys` meanwhile: nothing here reads `sys.exprs`).
fn order(x: &mut ExprArena, sys: &EquationSystem, c: &Causalization) -> Vec<Step> {
    let n = sys.eqs.len();
    if c.tears.is_empty() {
        // The colouring's numbers are already a topological order.
        let mut by_number = vec![EqId(0); n];
        for eq in sys.eqs.ids() {
            by_number[c.number(eq) as usize - 1] = eq;
        }
        return by_number
            .into_iter()
            .map(|eq| Step::Assign(assignment(x, sys, c, eq)))
            .collect();
    }
    // Dependency edges producer -> consumer between equations.
    let mut edges: Vec<(u32, u32)> = Vec::new();
    for eq in sys.eqs.ids() {
        let own = c.assigned(eq);
        for w in c.graph.eq_vars(eq) {
            if Some(w) == own {
                continue;
            }
            if let Some(p) = c.computed_by(w) {
                edges.push((p.0, eq.0));
            }
        }
    }
    let comps = strong_components(n, edges.iter().copied());
    let mut comp_of = vec![0u32; n];
    for (k, comp) in comps.iter().enumerate() {
        for &e in comp {
            comp_of[e as usize] = k as u32;
        }
    }
    let comp_key: Vec<u32> = comps
        .iter()
        .map(|comp| comp.iter().map(|&e| c.number(EqId(e))).min().unwrap_or(0))
        .collect();
    let mut comp_edges: Vec<(u32, u32)> = edges
        .iter()
        .map(|&(a, b)| (comp_of[a as usize], comp_of[b as usize]))
        .filter(|(a, b)| a != b)
        .collect();
    comp_edges.sort_unstable();
    comp_edges.dedup();
    let order = kahn(comps.len(), &comp_edges, |k| comp_key[k]);
    // Each block's inner edges (its residuals' outgoing edges dropped: the
    // tears are guessed, so the rest is acyclic), numbered within the
    // block, bucketed in one pass over the edges: a scan of every edge per
    // block was quadratic (add20's 372 blocks: 70 % of its check).
    let is_tear = |e: u32| c.rule(EqId(e)) == Some(Rule::Tear);
    let mut local = vec![0u32; n];
    for comp in &comps {
        for (i, &e) in comp.iter().enumerate() {
            local[e as usize] = i as u32;
        }
    }
    let mut inner_edges: Vec<Vec<(u32, u32)>> = vec![Vec::new(); comps.len()];
    for &(a, b) in &edges {
        let k = comp_of[a as usize];
        if k == comp_of[b as usize] && !is_tear(a) {
            inner_edges[k as usize].push((local[a as usize], local[b as usize]));
        }
    }
    let mut steps = Vec::with_capacity(n);
    let mut n_blocks = 0;
    for k in order {
        let comp = &comps[k];
        if comp.len() == 1 && !is_tear(comp[0]) {
            steps.push(Step::Assign(assignment(x, sys, c, EqId(comp[0]))));
            continue;
        }
        n_blocks += 1;
        steps.push(Step::Block(Box::new(block(
            x,
            sys,
            c,
            comp,
            &inner_edges[k],
            n_blocks,
        ))));
    }
    steps
}

fn block(
    x: &mut ExprArena,
    sys: &EquationSystem,
    c: &Causalization,
    comp: &[u32],
    inner_edges: &[(u32, u32)],
    index: usize,
) -> Block {
    let is_residual = |e: u32| c.rule(EqId(e)) == Some(Rule::Tear);
    let order = kahn(comp.len(), inner_edges, |i| c.number(EqId(comp[i])));
    let mut inner = Vec::new();
    let mut residuals = Vec::new();
    for i in order {
        let eq = EqId(comp[i]);
        if is_residual(eq.0) {
            residuals.push(assignment(x, sys, c, eq));
        } else {
            inner.push(assignment(x, sys, c, eq));
        }
    }
    residuals.sort_by_key(|a| a.number);
    let tears: Vec<VarId> = residuals.iter().map(|a| a.var).collect();
    let block_vars: rustc_hash::FxHashSet<VarId> =
        comp.iter().filter_map(|&e| c.assigned(EqId(e))).collect();
    let linear = comp.iter().all(|&e| {
        let eq = &sys.eqs[EqId(e)];
        let f = x.sub(eq.lhs, eq.rhs);
        solve::is_piecewise_affine_in(x, f, &|v| block_vars.contains(&v))
    });
    // The elements in equation order, each once (a set: a loop can hold
    // 10^5 of them).
    let mut elements: Vec<String> = Vec::new();
    let mut seen: rustc_hash::FxHashSet<&str> = rustc_hash::FxHashSet::default();
    let mut sorted: Vec<u32> = comp.to_vec();
    sorted.sort_unstable();
    for e in sorted {
        for name in sys.eqs[EqId(e)].origin.elements() {
            if seen.insert(name) {
                elements.push(name.to_string());
            }
        }
    }
    Block {
        index,
        tears,
        inner,
        residuals,
        linear,
        elements,
    }
}
