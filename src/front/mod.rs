//! The netlist front end: loading files (with `.include`), lexing, and parsing
//! ngspice-style netlists into an AST that keeps byte spans.
//!
//! It knows nothing of circuits' meaning: parameter values, subcircuit
//! expansion and models are the business of [`crate::elab`].

mod ako;
pub mod ast;
mod error;
pub mod expr;
pub mod lex;
mod load;
mod parse;
pub mod print;

pub use error::{ParseError, ReadError};
pub use load::{FileKind, LoadError, Loader, load, load_bytes, mib, resolve_include};

use crate::diag::{FileId, SourceMap};

/// Parse the loaded files into an AST. Errors and warnings are collected; the
/// AST holds every statement that parsed.
pub fn parse(sources: &SourceMap) -> (ast::Netlist<'_>, Vec<ParseError>) {
    let mut p = parse::Parser::new(sources);
    let mut netlist = p.parse_root(FileId(0));
    ako::resolve(&mut netlist.stmts, &mut p.errors);
    (netlist, p.errors)
}
