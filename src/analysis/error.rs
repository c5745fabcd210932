//! Structural errors: what stops the causalizer, named by equations,
//! unknowns and the circuit elements they come from.

use crate::diag::codes;
use crate::diag::{Diagnostic, Span, ToDiagnostic};
use crate::ir::{EqId, EquationSystem, VarId, print};

/// An equation or unknown involved in a structural problem, with what is
/// needed to show it without the system at hand.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Culprit {
    /// `eq7` or `x3`.
    pub id: String,
    /// The equation's text or the unknown's name.
    pub text: String,
    /// Where it comes from in circuit terms (`KCL at node 1`, `R1`).
    pub origin: String,
    pub elements: Vec<String>,
    #[serde(skip)]
    pub span: Option<Span>,
    #[serde(skip)]
    pub eq: Option<EqId>,
    #[serde(skip)]
    pub var: Option<VarId>,
}

impl Culprit {
    pub fn eq(sys: &EquationSystem, eq: EqId) -> Culprit {
        let e = &sys.eqs[eq];
        Culprit {
            id: eq.to_string(),
            text: print::equation(sys, eq),
            origin: e.origin.describe(),
            elements: e.origin.elements().into_iter().map(String::from).collect(),
            span: e.origin.span(),
            eq: Some(eq),
            var: None,
        }
    }

    pub fn var(sys: &EquationSystem, v: VarId) -> Culprit {
        let var = &sys.vars[v];
        Culprit {
            id: v.to_string(),
            text: sys.var_name(v).to_string(),
            origin: var.origin.describe(),
            elements: var
                .origin
                .elements()
                .into_iter()
                .map(String::from)
                .collect(),
            span: var.origin.span(),
            eq: None,
            var: Some(v),
        }
    }
}

#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum StructuralError {
    #[error("structural singularity: {}", summary(constraints, orphans))]
    Singular {
        /// Equations with no unknown left (constraints between states).
        constraints: Vec<Culprit>,
        /// Unknowns no equation is left to compute.
        orphans: Vec<Culprit>,
    },
    #[error("algebraic loop of {} equations (tearing is off)", blocks.first().map_or(0, |b| b.len()))]
    Loops { blocks: Vec<Vec<Culprit>> },
    #[error("{n_eqs} equations for {n_unknowns} unknowns")]
    Unbalanced { n_eqs: usize, n_unknowns: usize },
    #[error("index reduction did not finish after {iterations} differentiations (limit {limit})")]
    IndexLimit { iterations: usize, limit: usize },
    #[error("constraint {} cannot be removed by differentiation: it involves no state", constraint.text)]
    NoStateInConstraint { constraint: Box<Culprit> },
}

fn summary(constraints: &[Culprit], orphans: &[Culprit]) -> String {
    let mut parts = Vec::new();
    if !constraints.is_empty() {
        let names: Vec<String> = constraints
            .iter()
            .map(|c| format!("`{}` ({})", c.text, c.origin))
            .collect();
        parts.push(format!("{} has no unknown left", names.join(", ")));
    }
    if !orphans.is_empty() {
        let names: Vec<String> = orphans.iter().map(|c| format!("`{}`", c.text)).collect();
        parts.push(format!(
            "no equation is left to compute {}",
            names.join(", ")
        ));
    }
    parts.join("; ")
}

impl StructuralError {
    pub fn singular(
        sys: &EquationSystem,
        constraints: &[EqId],
        orphans: &[VarId],
    ) -> StructuralError {
        let mut cs: Vec<EqId> = constraints.to_vec();
        cs.sort();
        cs.dedup();
        let mut os: Vec<VarId> = orphans.to_vec();
        os.sort();
        os.dedup();
        StructuralError::Singular {
            constraints: cs.iter().map(|&e| Culprit::eq(sys, e)).collect(),
            orphans: os.iter().map(|&v| Culprit::var(sys, v)).collect(),
        }
    }

    pub fn loops(sys: &EquationSystem, stalls: &[super::Stall]) -> StructuralError {
        StructuralError::Loops {
            blocks: stalls
                .last()
                .map(|s| {
                    s.blocks
                        .iter()
                        .map(|b| b.eqs.iter().map(|&e| Culprit::eq(sys, e)).collect())
                        .collect()
                })
                .unwrap_or_default(),
        }
    }
}

impl ToDiagnostic for StructuralError {
    fn to_diagnostic(&self) -> Diagnostic {
        match self {
            StructuralError::Singular {
                constraints,
                orphans,
            } => {
                let mut d = Diagnostic::error(codes::STRUCTURALLY_SINGULAR, self.to_string());
                for c in constraints {
                    if let Some(span) = c.span {
                        d = d.with_label(span, format!("{}: {}", c.id, c.text));
                    }
                }
                for o in orphans {
                    if let Some(span) = o.span {
                        d = d.with_label(span, format!("{} cannot be computed", o.text));
                    }
                }
                d.with_help(
                    "states are algebraically coupled or a part of the circuit is undetermined",
                )
            }
            StructuralError::Loops { blocks } => {
                let mut d = Diagnostic::error(codes::ALGEBRAIC_LOOPS, self.to_string());
                for c in blocks.iter().flatten() {
                    if let Some(span) = c.span {
                        d = d.with_label(span, format!("{}: {}", c.id, c.text));
                    }
                }
                d.with_help("enable tearing to solve the loop numerically")
            }
            StructuralError::Unbalanced { .. } => {
                Diagnostic::error(codes::UNBALANCED, self.to_string())
                    .with_help("this is a kausal bug: the equation builder must balance the system")
            }
            StructuralError::IndexLimit { .. } => {
                Diagnostic::error(codes::INDEX_LIMIT, self.to_string()).with_help(
                    "the circuit's structure keeps producing constraints; please report it",
                )
            }
            StructuralError::NoStateInConstraint { constraint } => {
                let mut d = Diagnostic::error(codes::NO_STATE_IN_CONSTRAINT, self.to_string());
                if let Some(span) = constraint.span {
                    d = d.with_label(span, format!("{}: {}", constraint.id, constraint.text));
                }
                d.with_help("sources or ideal elements fix the same quantity twice")
            }
        }
    }
}
