//! The bond-graph stage's problems as data: a causal conflict (no causal
//! assignment fits the circuit: two sources fix one quantity, or nothing
//! fixes it) and a cross-check whose two views disagree. Turned into
//! diagnostics in one place, by [`ToDiagnostic`].

use super::BondGraph;
use super::check::Check;
use super::scap::{Causality, ConflictKind};
use crate::diag::{Diagnostic, Span, ToDiagnostic, codes};

#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum BondGraphError {
    /// A vertex whose causal constraint SCAP could not meet.
    #[error("causal conflict at {vertex}: {what}")]
    Conflict {
        vertex: String,
        what: String,
        /// The elements at the bonds involved, where the netlist has them.
        elements: Vec<(String, Option<Span>)>,
    },
    /// The cross-check found the two views disagreeing.
    #[error("the bond graph and the equations disagree on {}", items.join(", "))]
    Disagrees {
        items: Vec<String>,
        findings: Vec<String>,
    },
}

impl BondGraphError {
    /// One error per causal conflict of `c`.
    pub fn conflicts(g: &BondGraph, c: &Causality) -> Vec<BondGraphError> {
        c.conflicts
            .iter()
            .map(|x| {
                let what = match x.kind {
                    ConflictKind::Source => "a source is made to take the variable it sets",
                    ConflictKind::Fixed => {
                        "a winding past a perfectly coupled field's rank is made integral"
                    }
                    ConflictKind::EffortTwice => "two bonds set its effort",
                    ConflictKind::EffortUnset => "no bond sets its effort",
                    ConflictKind::FlowTwice => "two bonds set its flow",
                    ConflictKind::FlowUnset => "no bond sets its flow",
                    ConflictKind::Transformer => "effort goes into both ports (or out of both)",
                    ConflictKind::Gyrator => "effort goes into one port and out of the other",
                }
                .to_string();
                let mut elements = Vec::new();
                for &b in &x.bonds {
                    let bond = &g.bonds[b];
                    for v in [bond.tail, bond.head] {
                        for e in g.elements_of(v) {
                            let name = g.element_name(e).to_string();
                            if !elements.iter().any(|(n, _)| *n == name) {
                                elements.push((name, g.element_span(e)));
                            }
                        }
                    }
                }
                BondGraphError::Conflict {
                    vertex: g.vertex_name(x.vertex),
                    what,
                    elements,
                }
            })
            .collect()
    }

    /// The disagreement of a check, if it found one.
    pub fn disagreement(check: &Check) -> Option<BondGraphError> {
        let bad: Vec<_> = check.findings.iter().filter(|f| !f.agrees).collect();
        (!bad.is_empty()).then(|| BondGraphError::Disagrees {
            items: bad.iter().map(|f| f.item.title().to_string()).collect(),
            findings: bad.iter().map(|f| f.text.clone()).collect(),
        })
    }
}

impl ToDiagnostic for BondGraphError {
    fn to_diagnostic(&self) -> Diagnostic {
        match self {
            BondGraphError::Conflict { elements, .. } => {
                let mut d = Diagnostic::warning(codes::CAUSAL_CONFLICT, self.to_string());
                for (name, span) in elements {
                    if let Some(span) = span {
                        d = d.with_label(*span, format!("{name} is on a bond of the conflict"));
                    }
                }
                d.with_help("sources fix the same quantity twice, or nothing fixes it: the equations cannot be sorted either")
            }
            BondGraphError::Disagrees { findings, .. } => {
                let mut d = Diagnostic::error(codes::VIEWS_DISAGREE, self.to_string());
                for f in findings {
                    d = d.with_note(f.clone());
                }
                d.with_help("this is a kausal bug in one of the two views: please report it with the netlist")
            }
        }
    }
}
