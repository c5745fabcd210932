//! kausal: SPICE netlists → acausal equations → causal assignments.
//!
//! A tour of the pipeline, one module per stage:
//!
//! 1. [`front`] loads a netlist (with `.include`s) into a [`diag::SourceMap`]
//!    and parses it into an AST that keeps byte spans ([`front::parse`]).
//! 2. [`elab`] flattens subcircuits, evaluates parameters and resolves models
//!    into a [`elab::Circuit`] ([`elab::elaborate`]).
//! 3. [`build`] writes the element and Kirchhoff equations as an
//!    [`ir::EquationSystem`] ([`build::build`]).
//!
//! Every stage reports problems as [`diag::Diagnostic`]s pointing at the
//! netlist; [`diag::render`] draws them with file, line, column and a caret.
//! [`pipeline`] strings the stages together for the CLI and tests.

pub mod build;
pub mod diag;
pub mod elab;
pub mod front;
pub mod generate;
pub mod io;
pub mod ir;
pub mod pipeline;
