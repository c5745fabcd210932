//! Structural analysis: the structure graph, the colour-edge causalizer,
//! algebraic loops (BLT form and tearing), and the [`Schedule`] of sorted
//! assignments.
//!
//! Passes never change the [`EquationSystem`]; they return side tables keyed
//! by its ids. The schedule owns a copy of the expression arena extended with
//! the solved forms. Nothing here knows netlist syntax or numerics.

pub mod colour;
mod error;
pub mod graph;
pub mod matching;
pub mod pantelides;
mod schedule;
pub mod solve;
pub mod tear;

pub use colour::{EdgeColour, Rule, TraceStep};
pub use error::StructuralError;
pub use graph::StructureGraph;
pub use matching::{Blt, BltBlock};
pub use pantelides::{IndexReduction, reduce_index};
pub use schedule::{Assignment, Block, Schedule, Step, schedule};
pub use solve::Solved;
pub use tear::Tear;

use crate::ir::{EqId, EquationSystem, VarId};

/// Options for [`causalize`].
#[derive(Clone, Copy, Debug)]
pub struct Options {
    /// Break algebraic loops by tearing; without it a stall is an error.
    pub tearing: bool,
}

impl Default for Options {
    fn default() -> Self {
        Options { tearing: true }
    }
}

/// A stall of the colouring and the BLT blocks found at that point.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Stall {
    /// Number of assignments made before the stall.
    pub after: usize,
    pub blocks: Vec<BltBlock>,
}

/// The result of colouring: which equation computes which unknown, the sort
/// numbers, the trace, the tears and the stalls.
#[derive(Clone, Debug, Default)]
pub struct Causalization {
    pub graph: StructureGraph,
    eq_var: Vec<u32>,
    var_eq: Vec<u32>,
    numbers: Vec<u32>,
    rules: Vec<u8>,
    pub trace: Vec<TraceStep>,
    pub tears: Vec<Tear>,
    pub stalls: Vec<Stall>,
    /// Final colour of every edge of `graph`.
    pub colours: Vec<EdgeColour>,
}

impl Causalization {
    /// The unknown equation `eq` is solved for (its red edge).
    #[inline]
    pub fn assigned(&self, eq: EqId) -> Option<VarId> {
        let v = self.eq_var[eq.0 as usize];
        (v != u32::MAX).then_some(VarId(v))
    }

    /// The equation computing `v` (`None` for states and aliases).
    #[inline]
    pub fn computed_by(&self, v: VarId) -> Option<EqId> {
        let e = self.var_eq[v.0 as usize];
        (e != u32::MAX).then_some(EqId(e))
    }

    /// The colouring's sort number of `eq` (1..=N).
    #[inline]
    pub fn number(&self, eq: EqId) -> u32 {
        self.numbers[eq.0 as usize]
    }

    /// The rule that assigned `eq`.
    #[inline]
    pub fn rule(&self, eq: EqId) -> Option<Rule> {
        Rule::from_code(self.rules[eq.0 as usize])
    }
}

/// Colour-edge causalization of `sys`: the algorithm of seeds 000/001 with
/// Cellier's tearing when it stalls.
pub fn causalize(sys: &EquationSystem, opts: Options) -> Result<Causalization, StructuralError> {
    let graph = StructureGraph::build(sys);
    let n_unknowns = sys.n_unknowns();
    let (parts, tears, stalls) = {
        let mut c = colour::Colouring::new(&graph);
        let mut tears = Vec::new();
        let mut stalls = Vec::new();
        c.propagate();
        let n_eqs = sys.eqs.len();
        // Blocks of the last BLT decomposition still to tear, in order.
        let mut pending: std::collections::VecDeque<Vec<EqId>> = Default::default();
        let mut current: Option<tear::BlockTearer> = None;
        let mut mates = tear::Mates::new(n_eqs, sys.vars.len());
        while c.constraints.is_empty() && c.orphans.is_empty() && c.n_assigned() < n_eqs {
            if !opts.tearing {
                if stalls.is_empty() {
                    stalls.push(Stall {
                        after: c.n_assigned(),
                        blocks: matching::blt(&c).blocks,
                    });
                }
                break;
            }
            let choice = current.as_mut().and_then(|t| t.choose(&mut c, &mut mates));
            let Some(t) = choice else {
                // The current block is done: go on with the next one.
                current = None;
                while let Some(b) = pending.pop_front() {
                    if b.iter().any(|&e| !c.is_done(e)) {
                        current = Some(tear::BlockTearer::new(&mut c, sys, &b));
                        break;
                    }
                }
                if current.is_none() {
                    let blt = matching::blt(&c);
                    if !blt.unmatched_eqs.is_empty() || !blt.unmatched_vars.is_empty() {
                        c.constraints.extend(blt.unmatched_eqs.iter().copied());
                        c.orphans.extend(blt.unmatched_vars.iter().copied());
                        break;
                    }
                    if blt.blocks.is_empty() {
                        break;
                    }
                    mates.set(&blt.pairs);
                    pending.extend(blt.blocks.iter().map(|b| b.eqs.clone()));
                    stalls.push(Stall {
                        after: c.n_assigned(),
                        blocks: blt.blocks,
                    });
                }
                continue;
            };
            c.tear(t.eq, t.var);
            tears.push(t);
            c.propagate();
            // Tears strict mode made instead of nonlinear inversions.
            for (eq, var) in std::mem::take(&mut c.auto_tears) {
                tears.push(Tear {
                    eq,
                    var,
                    gain: 1,
                    inversions: 0,
                    candidates: 0,
                });
            }
        }
        (c.into_parts(), tears, stalls)
    };
    let (constraints, orphans, trace) = (&parts.constraints, &parts.orphans, &parts.trace);
    if !constraints.is_empty() || !orphans.is_empty() {
        return Err(StructuralError::singular(sys, constraints, orphans));
    }
    if trace.len() < sys.eqs.len() || sys.eqs.len() != n_unknowns {
        if !stalls.is_empty() && trace.len() < sys.eqs.len() {
            return Err(StructuralError::loops(sys, &stalls));
        }
        return Err(StructuralError::Unbalanced {
            n_eqs: sys.eqs.len(),
            n_unknowns,
        });
    }
    Ok(Causalization {
        graph,
        eq_var: parts.eq_var,
        var_eq: parts.var_eq,
        numbers: parts.number,
        rules: parts.rules,
        trace: parts.trace,
        tears,
        stalls,
        colours: parts.colour,
    })
}
