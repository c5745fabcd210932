//! The errors that stop a subcommand, and the one place that prints them.
//! Netlist and stage errors are shown as rendered diagnostics; the others as
//! one `error: ...` line. Every error exits with status 1.

use std::path::PathBuf;
use std::process::ExitCode;

use kausal::diag::{SourceMap, ToDiagnostic};
use kausal::pipeline::Failed;

use crate::output::print_diags;

/// Why a subcommand stopped.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The netlist has errors: its diagnostics are shown, then their count.
    #[error("{}", errors_found(&.0.0))]
    Netlist(NetlistErrors),
    /// A stage stopped (the simulation, the comparison with ngspice): its
    /// diagnostic is shown.
    #[error(transparent)]
    Stage(Box<WithSources<kausal::Error>>),
    #[error("cannot write `{}`: {source}", path.display())]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot create `{}`: {source}", path.display())]
    CreateDir {
        path: PathBuf,
        source: std::io::Error,
    },
    /// Standard output could not be written (a closed pipe is no error).
    #[error("{0}")]
    Stdout(std::io::Error),
    #[error("{0}")]
    Json(#[from] serde_json::Error),
    /// A plot could not be drawn.
    #[error("{0}")]
    Plot(String),
    /// Graphviz's `dot` could not draw the bond graph.
    #[error("{0}")]
    Dot(String),
    /// The benchmark cannot go on (ngspice is missing).
    #[error("{0}")]
    Bench(kausal::bench::BenchError),
    /// The scratch directory of the benchmark's generated ladders.
    #[error("{0}")]
    Scratch(std::io::Error),
    /// The scaling benchmark over generated ladders failed.
    #[error("scaling: {0}")]
    Scaling(kausal::bench::BenchError),
}

/// The pipeline's [`Failed`] (which has no `Debug` of its own).
pub struct NetlistErrors(pub Box<Failed>);

impl std::fmt::Debug for NetlistErrors {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Failed")
            .field("sources", &self.0.sources)
            .field("diagnostics", &self.0.diagnostics)
            .finish()
    }
}

/// `3 errors found`, `1 error found`.
fn errors_found(failed: &Failed) -> String {
    let n = failed.errors().count();
    format!("{n} error{} found", if n == 1 { "" } else { "s" })
}

/// A stage's error and the netlist's sources, which its diagnostic points
/// into.
#[derive(Debug, thiserror::Error)]
#[error("{error}")]
pub struct WithSources<E: std::error::Error> {
    pub sources: SourceMap,
    pub error: E,
}

impl Error {
    /// The pipeline stopped on the netlist's errors.
    pub fn netlist(failed: Box<Failed>) -> Self {
        Error::Netlist(NetlistErrors(failed))
    }

    /// A stage's error, with the sources its diagnostic points into.
    pub fn stage(sources: SourceMap, error: impl Into<kausal::Error>) -> Self {
        Error::Stage(Box::new(WithSources {
            sources,
            error: error.into(),
        }))
    }

    /// A file `path` could not be written.
    pub fn write(path: impl Into<PathBuf>) -> impl FnOnce(std::io::Error) -> Self {
        let path = path.into();
        move |source| Error::Write { path, source }
    }

    /// A directory `path` could not be created.
    pub fn create_dir(path: impl Into<PathBuf>) -> impl FnOnce(std::io::Error) -> Self {
        let path = path.into();
        move |source| Error::CreateDir { path, source }
    }
}

/// Print `error` on standard error; the exit code of a failed run.
pub fn report(error: Error) -> ExitCode {
    match &error {
        Error::Netlist(NetlistErrors(failed)) => {
            print_diags(&failed.sources, &failed.diagnostics);
            eprintln!("error: {error}");
        }
        Error::Stage(e) => print_diags(&e.sources, &[e.error.to_diagnostic()]),
        _ => eprintln!("error: {error}"),
    }
    ExitCode::FAILURE
}
