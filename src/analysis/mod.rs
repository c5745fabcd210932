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

use crate::ir::{EqId, EquationSystem, IdVec, VarId};

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
#[derive(Clone, Debug)]
pub struct Causalization {
    pub graph: StructureGraph,
    /// The unknown each equation is solved for (red edge).
    pub assigned: IdVec<EqId, Option<VarId>>,
    /// The equation computing each unknown (`None` for states and aliases).
    pub computed_by: IdVec<VarId, Option<EqId>>,
    /// Sort numbers from the colouring (1..=N).
    pub number: IdVec<EqId, u32>,
    /// The rule that assigned each equation.
    pub rule: IdVec<EqId, Option<Rule>>,
    pub trace: Vec<TraceStep>,
    pub tears: Vec<Tear>,
    pub stalls: Vec<Stall>,
    /// Final colour of every edge of `graph`.
    pub colours: Vec<EdgeColour>,
}

/// Colour-edge causalization of `sys`: the algorithm of seeds 000/001 with
/// Cellier's tearing when it stalls.
pub fn causalize(sys: &EquationSystem, opts: Options) -> Result<Causalization, StructuralError> {
    let graph = StructureGraph::build(sys);
    let n_unknowns = sys.n_unknowns();
    let (colours, trace, number_vec, tears, stalls, constraints, orphans) = {
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
        let parts = c.into_parts();
        (
            parts.colour,
            parts.trace,
            parts.number,
            tears,
            stalls,
            parts.constraints,
            parts.orphans,
        )
    };
    let mut assigned = IdVec::filled(sys.eqs.len(), None);
    let mut computed_by = IdVec::filled(sys.vars.len(), None);
    let mut rule = IdVec::filled(sys.eqs.len(), None);
    for step in &trace {
        assigned[step.eq] = Some(step.var);
        computed_by[step.var] = Some(step.eq);
        rule[step.eq] = Some(step.rule);
    }
    let mut number = IdVec::filled(sys.eqs.len(), 0u32);
    for (k, n) in number_vec.into_iter().enumerate() {
        number[EqId(k as u32)] = n;
    }
    if !constraints.is_empty() || !orphans.is_empty() {
        return Err(StructuralError::singular(sys, &constraints, &orphans));
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
        assigned,
        computed_by,
        number,
        rule,
        trace,
        tears,
        stalls,
        colours,
    })
}
