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
//! 4. [`analysis`] colours the bipartite structure graph into causal
//!    assignments, tears algebraic loops ([`analysis::causalize`]) and orders
//!    them into a [`analysis::Schedule`] ([`analysis::schedule`]).
//! 5. [`back`] prints schedules ([`back::listing`]), interprets them
//!    ([`back::interp`], the reference) and writes them as Rust or C
//!    ([`back::codegen`]).
//! 6. [`tape`] compiles a schedule into a register program
//!    ([`tape::compile`]) that evaluates `f`, its Jacobian by forward-mode
//!    tangents, and the outputs; algebraic loops become blocks solved by
//!    Newton on their tears.
//! 7. [`sim`] integrates the tape from its operating point with diffsol or
//!    kausal's own TR-BDF2 ([`sim::simulate`]), on top of the numerical
//!    kernels of [`numeric`] (dense and sparse LU, damped Newton).
//! 8. [`bondgraph`] draws the same circuit as a bond graph (seed 003's
//!    procedure), puts causal strokes on it by SCAP and cross-checks them
//!    against the colouring and index reduction ([`bondgraph::analyse`],
//!    [`bondgraph::check()`]).
//! 9. [`validate`] runs ngspice on the same netlist and compares the
//!    waveforms ([`validate::validate`]); [`bench`] measures speed against
//!    error, beside ngspice.
//!
//! Every stage reports problems as [`diag::Diagnostic`]s pointing at the
//! netlist; [`diag::render`] draws them with file, line, column and a caret.
//! [`pipeline`] strings the stages up to the schedule together for the CLI,
//! the simulator and tests; [`Error`] holds any stage's error for a
//! caller that runs several. The layers and their order are stated in
//! `ARCHITECTURE.md` and checked by a test.

pub mod analysis;
pub mod back;
pub mod bench;
pub mod bondgraph;
pub mod build;
pub mod diag;
pub mod elab;
pub mod error;
pub mod front;
pub mod generate;
pub mod io;
pub mod ir;
pub mod numeric;
pub mod pipeline;
pub mod sim;
pub mod tape;
pub mod validate;

pub use error::Error;
