//! The stages strung together: netlist file → circuit → equations, with
//! every stage's problems collected as diagnostics. Used by the CLI and tests.

use std::path::Path;

use crate::build::{self, Built};
use crate::diag::{Diagnostic, SourceMap, ToDiagnostic};
use crate::elab::{self, Circuit};
use crate::front::{self, Loader};

/// A netlist taken through the front end and elaboration.
pub struct Elaborated {
    pub sources: SourceMap,
    pub circuit: Circuit,
    /// Warnings of all stages so far.
    pub warnings: Vec<Diagnostic>,
}

/// What stopped the pipeline: the sources (for rendering) and the diagnostics,
/// errors and warnings in the order found.
pub struct Failed {
    pub sources: SourceMap,
    pub diagnostics: Vec<Diagnostic>,
}

impl Failed {
    pub fn errors(&self) -> impl Iterator<Item = &Diagnostic> {
        self.diagnostics.iter().filter(|d| d.is_error())
    }
}

/// Parse and elaborate netlist `text` read from `path`.
pub fn elaborate_text(
    name: &str,
    path: &Path,
    text: String,
    loader: &dyn Loader,
) -> Result<Elaborated, Box<Failed>> {
    let (sources, load_errors) = front::load(name, path, text, loader);
    let mut diags: Vec<Diagnostic> = load_errors.iter().map(|e| e.to_diagnostic()).collect();
    let circuit = {
        let (ast, parse_errors) = front::parse(&sources);
        diags.extend(parse_errors.iter().map(|e| e.to_diagnostic()));
        if diags.iter().any(Diagnostic::is_error) {
            None
        } else {
            let (circuit, elab_errors) = elab::elaborate(&ast);
            diags.extend(elab_errors.iter().map(|e| e.to_diagnostic()));
            Some(circuit)
        }
    };
    match circuit {
        Some(circuit) if !diags.iter().any(Diagnostic::is_error) => Ok(Elaborated {
            sources,
            circuit,
            warnings: diags,
        }),
        _ => Err(Box::new(Failed {
            sources,
            diagnostics: diags,
        })),
    }
}

/// Read a netlist file and elaborate it.
pub fn elaborate_file(path: &Path, loader: &dyn Loader) -> Result<Elaborated, Box<Failed>> {
    let name = path.display().to_string();
    match loader.load(path) {
        Ok(text) => elaborate_text(&name, path, text, loader),
        Err(e) => Err(Box::new(Failed {
            sources: SourceMap::default(),
            diagnostics: vec![
                Diagnostic::error("K0001", format!("cannot read `{name}`: {e}"))
                    .with_help("check the path"),
            ],
        })),
    }
}

/// Elaborate, then build the equations.
pub fn equations(
    path: &Path,
    loader: &dyn Loader,
    opts: build::Options,
) -> Result<(Elaborated, Built), Box<Failed>> {
    let el = elaborate_file(path, loader)?;
    let built = build::build(&el.circuit, opts);
    Ok((el, built))
}

/// Everything `kausal sort` shows: the system, its causalization and schedule.
pub struct Sorted {
    pub elaborated: Elaborated,
    pub built: Built,
    pub causal: crate::analysis::Causalization,
    pub schedule: crate::analysis::Schedule,
}

/// Elaborate, build and causalize. A structural error is reported as a
/// diagnostic that points at the elements involved.
pub fn sort(
    path: &Path,
    loader: &dyn Loader,
    opts: build::Options,
    analysis: crate::analysis::Options,
) -> Result<Sorted, Box<Failed>> {
    let (el, built) = equations(path, loader, opts)?;
    match crate::analysis::causalize(&built.system, analysis) {
        Ok(causal) => {
            let schedule = crate::analysis::schedule(&built.system, &causal);
            Ok(Sorted {
                elaborated: el,
                built,
                causal,
                schedule,
            })
        }
        Err(e) => {
            let mut diagnostics = el.warnings;
            diagnostics.push(e.to_diagnostic());
            Err(Box::new(Failed {
                sources: el.sources,
                diagnostics,
            }))
        }
    }
}
