//! Back ends: everything that follows the [`crate::analysis::Schedule`] —
//! listings, the reference interpreter, generated code. Back ends follow the
//! schedule and never reorder it.

pub mod codegen;
pub mod interp;
pub mod listing;
