//! [`Error`]: any stage's error, for a caller that runs several stages and
//! reports what stopped them in one place.

use crate::diag::{Diagnostic, ToDiagnostic};

/// An error of one of kausal's stages, kept as that stage's own type.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Parse(#[from] crate::front::ParseError),
    #[error(transparent)]
    Elab(#[from] crate::elab::ElabError),
    #[error(transparent)]
    Topology(#[from] crate::elab::topology::TopologyError),
    #[error(transparent)]
    Structural(#[from] crate::analysis::StructuralError),
    #[error(transparent)]
    BondGraph(#[from] crate::bondgraph::BondGraphError),
    #[error(transparent)]
    Sim(#[from] crate::sim::SimError),
    #[error(transparent)]
    Validate(#[from] crate::validate::ValidateError),
}

impl ToDiagnostic for Error {
    fn to_diagnostic(&self) -> Diagnostic {
        match self {
            Error::Parse(e) => e.to_diagnostic(),
            Error::Elab(e) => e.to_diagnostic(),
            Error::Topology(e) => e.to_diagnostic(),
            Error::Structural(e) => e.to_diagnostic(),
            Error::BondGraph(e) => e.to_diagnostic(),
            Error::Sim(e) => e.to_diagnostic(),
            Error::Validate(e) => e.to_diagnostic(),
        }
    }
}
