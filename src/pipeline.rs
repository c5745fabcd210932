//! The stages strung together: netlist file → circuit → equations, with
//! every stage's problems collected as diagnostics. Used by the CLI and tests.

use crate::diag::codes;
use std::path::Path;

use crate::analysis::IndexReduction;
use crate::build::{self, Built};
use crate::diag::{Diagnostic, SourceMap, Span, ToDiagnostic};
use crate::elab::topology::{self, Fault, TopologyError};
use crate::elab::{self, Circuit};
use crate::front::{self, Loader};
use crate::ir::EquationSystem;

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
    elaborate_loaded(sources, load_errors)
}

/// Parse and elaborate the files `front::load` gave, with its errors.
fn elaborate_loaded(
    sources: SourceMap,
    load_errors: Vec<front::ParseError>,
) -> Result<Elaborated, Box<Failed>> {
    let mut diags: Vec<Diagnostic> = load_errors.iter().map(|e| e.to_diagnostic()).collect();
    // A byte that is not text has been reported: what the parser makes of
    // the U+FFFD standing for it (`1k\u{fffd}` is not a number) is not.
    let not_text: Vec<Span> = load_errors
        .iter()
        .filter(|e| matches!(e, front::ParseError::NotUtf8 { .. }))
        .map(|e| e.span())
        .collect();
    let overlaps = |a: Span, b: Span| a.file == b.file && a.start < b.end && b.start < a.end;
    let circuit = {
        let (ast, parse_errors) = front::parse(&sources);
        diags.extend(
            parse_errors
                .iter()
                .filter(|e| !not_text.iter().any(|&s| overlaps(s, e.span())))
                .map(|e| e.to_diagnostic()),
        );
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
        Ok(bytes) => {
            let (sources, load_errors) = front::load_bytes(&name, path, bytes, loader);
            elaborate_loaded(sources, load_errors)
        }
        Err(error) => Err(Box::new(Failed {
            sources: SourceMap::default(),
            diagnostics: vec![front::ReadError { path: name, error }.to_diagnostic()],
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

/// Options of [`sort`].
#[derive(Clone, Debug, Default)]
pub struct SortOptions {
    pub build: build::Options,
    pub analysis: crate::analysis::Options,
    /// Storage elements whose state index reduction should keep (`--prefer-state`).
    pub prefer_state: Vec<String>,
}

/// Everything `kausal sort` shows: the system, the index reduction (when the
/// circuit needed one), the causalization and the schedule.
pub struct Sorted {
    pub elaborated: Elaborated,
    pub built: Built,
    /// Circuit faults that index reduction fixed (reported as warnings).
    pub faults: Vec<TopologyError>,
    pub reduction: Option<IndexReduction>,
    pub causal: crate::analysis::Causalization,
    pub schedule: crate::analysis::Schedule,
}

impl Sorted {
    /// The system that was sorted: the index-reduced one when there is one.
    pub fn system(&self) -> &EquationSystem {
        match &self.reduction {
            Some(r) => &r.system,
            None => &self.built.system,
        }
    }

    /// Drop the equation system, the sort and the circuit, keeping the
    /// sources (to render diagnostics), the warnings and the circuit's
    /// title: what a simulation that has compiled its tape and found its
    /// operating point no longer reads (see `sim::run_prepared_releasing`).
    /// Returns the sorted system's variable names, which its diagnostics
    /// still print.
    pub fn release_ir(&mut self) -> crate::ir::NameTable<crate::ir::VarId> {
        let names = match &mut self.reduction {
            Some(r) => std::mem::take(&mut r.system.names),
            None => std::mem::take(&mut self.built.system.names),
        };
        self.built = Built::default();
        self.reduction = None;
        self.causal = Default::default();
        self.schedule = Default::default();
        let c = &mut self.elaborated.circuit;
        *c = crate::elab::Circuit {
            title: std::mem::take(&mut c.title),
            title_span: c.title_span,
            ..Default::default()
        };
        names
    }
}

/// What was done to a group of coupled inductors whose inductance matrix
/// is singular (see [`crate::build::coupling`]).
fn coupling_note(c: &crate::elab::Circuit, g: &crate::build::coupling::Reduced) -> Diagnostic {
    let name = |k: usize| c.elements[g.members[k]].name.as_str();
    let list = |ks: &mut dyn Iterator<Item = usize>| ks.map(name).collect::<Vec<_>>().join(", ");
    let pivots = list(&mut g.pivots.iter().copied());
    let rest = list(&mut g.ratio.iter().map(|(q, _)| *q));
    let mut d = Diagnostic::warning(
        codes::PERFECT_COUPLING,
        format!(
            "the inductance matrix of {} is singular (rank {} of {}): their fluxes are not independent. The states are the fluxes of {pivots}, as magnetizing currents `im_…` (flux / self inductance); the voltage of {rest} follows from theirs by fixed ratios, as in an ideal transformer",
            list(&mut (0..g.members.len())),
            g.pivots.len(),
            g.members.len(),
        ),
    );
    for &k in &g.couplings {
        d = d.with_label(c.elements[k].span(), "coupling");
    }
    d.with_help("this is what ngspice simulates too; a coupling below 1 (k = 0.999) keeps one state per inductor, with a leakage inductance")
}

/// A group of coupled inductors whose inductance matrix is indefinite.
fn indefinite_note(c: &crate::elab::Circuit, couplings: &[crate::elab::ElemId]) -> Diagnostic {
    let names: Vec<&str> = couplings
        .iter()
        .map(|&k| c.elements[k].name.as_str())
        .collect();
    let mut d = Diagnostic::warning(
        codes::INDEFINITE_COUPLING,
        format!(
            "the coupling coefficients of {} make an inductance matrix that is not positive semidefinite: some combination of the currents has negative magnetic energy, which no magnetic circuit has, and along it the currents can grow without bound",
            names.join(", ")
        ),
    );
    for &k in couplings {
        d = d.with_label(c.elements[k].span(), "coupling");
    }
    d.with_help("each winding's couplings must fit one magnetic circuit: for three windings, k12² + k13² + k23² − 2·k12·k13·k23 ≤ 1 (with k12 = 1, k13 must equal k23)")
}

fn fail(el: Elaborated, extra: Vec<Diagnostic>) -> Box<Failed> {
    let mut diagnostics = el.warnings;
    diagnostics.extend(extra);
    Box::new(Failed {
        sources: el.sources,
        diagnostics,
    })
}

/// Elaborate, build and causalize, reducing the index first when states are
/// coupled. Unfixable circuit faults and structural errors are reported as
/// diagnostics that point at the elements involved.
pub fn sort(path: &Path, loader: &dyn Loader, opts: &SortOptions) -> Result<Sorted, Box<Failed>> {
    let (el, built) = equations(path, loader, opts.build)?;
    sort_built(el, built, opts)
}

/// [`sort`] of netlist text that has no file (generated circuits); includes
/// are read relative to the working directory.
pub fn sort_text(name: &str, text: String, opts: &SortOptions) -> Result<Sorted, Box<Failed>> {
    let el = elaborate_text(name, Path::new(name), text, &crate::io::FsLoader)?;
    let built = crate::build::build(&el.circuit, opts.build);
    sort_built(el, built, opts)
}

/// [`sort`] from an elaborated circuit and its equations.
pub fn sort_built(
    mut el: Elaborated,
    built: Built,
    opts: &SortOptions,
) -> Result<Sorted, Box<Failed>> {
    for g in &built.reduced {
        el.warnings.push(coupling_note(&el.circuit, g));
    }
    for couplings in &built.indefinite {
        el.warnings.push(indefinite_note(&el.circuit, couplings));
    }
    let c = &el.circuit;
    let mut keep = Vec::new();
    for name in &opts.prefer_state {
        match c.find_element(name) {
            Some(e)
                if !matches!(
                    c.elements[e].kind,
                    crate::elab::ElementKind::Capacitor { .. }
                        | crate::elab::ElementKind::Inductor { .. }
                ) =>
            {
                let d = Diagnostic::error(
                    codes::PREFER_STATE_NOT_STORAGE,
                    format!(
                        "--prefer-state names `{name}`, which is not a capacitor or inductor: it has no state"
                    ),
                )
                .with_label(c.elements[e].span(), "this element")
                .with_help("name a capacitor or inductor, e.g. --prefer-state C1");
                return Err(fail(el, vec![d]));
            }
            Some(e) => keep.push(e),
            None => {
                let d = Diagnostic::error(
                    codes::PREFER_STATE_UNKNOWN,
                    format!(
                        "--prefer-state names `{name}`, which is not an element of the circuit"
                    ),
                )
                .with_help("name a capacitor or inductor, e.g. --prefer-state C1");
                return Err(fail(el, vec![d]));
            }
        }
    }
    // The build's, when no state is kept by choice (the same computation).
    let faults = match &built.faults {
        Some(f) if keep.is_empty() => f.clone(),
        _ => topology::faults(c, &keep),
    };
    let errors: Vec<TopologyError> = faults.iter().map(|f| TopologyError::new(c, f)).collect();
    let (fixable, fatal): (Vec<TopologyError>, Vec<TopologyError>) =
        errors.into_iter().partition(|e| e.fault.is_warning());
    if !fatal.is_empty() {
        let diags = fatal
            .iter()
            .chain(&fixable)
            .map(|e| e.to_diagnostic())
            .collect();
        return Err(fail(el, diags));
    }
    let state_of = |e: crate::elab::ElemId| -> Option<crate::ir::VarId> {
        if let Some(&q) = built.charges.get(&e) {
            return Some(q);
        }
        let ev = built.elem_vars.get(e.0 as usize).copied().flatten()?;
        [ev.u, ev.i]
            .into_iter()
            .find(|&v| built.system.vars[v].is_state())
    };
    let fixed: Vec<crate::ir::VarId> = faults
        .iter()
        .filter_map(|f| match f {
            Fault::CapacitorLoop { fixed, .. } | Fault::InductorCutset { fixed, .. } => {
                state_of(*fixed)
            }
            _ => None,
        })
        .collect();
    let popts = crate::analysis::pantelides::Options {
        keep: keep.iter().filter_map(|&e| state_of(e)).collect(),
        tied: fixed,
        max_rounds: None,
    };
    let first = crate::analysis::causalize(&built.system, opts.analysis);
    let (reduction, causal) = match first {
        Ok(causal) => (None, causal),
        Err(crate::analysis::StructuralError::Singular {
            ref constraints, ..
        }) if !constraints.is_empty() => {
            let red = match crate::analysis::reduce_index(&built.system, &popts) {
                Ok(Some(r)) => r,
                Ok(None) => unreachable!("a constraint was found"),
                Err(e) => {
                    let mut diags: Vec<Diagnostic> =
                        fixable.iter().map(|e| e.to_diagnostic()).collect();
                    diags.push(e.to_diagnostic());
                    return Err(fail(el, diags));
                }
            };
            match crate::analysis::causalize(&red.system, opts.analysis) {
                Ok(causal) => (Some(red), causal),
                Err(e) => {
                    let mut diags: Vec<Diagnostic> =
                        fixable.iter().map(|e| e.to_diagnostic()).collect();
                    diags.push(e.to_diagnostic());
                    return Err(fail(el, diags));
                }
            }
        }
        Err(e) => {
            let mut diags: Vec<Diagnostic> = fixable.iter().map(|e| e.to_diagnostic()).collect();
            diags.push(e.to_diagnostic());
            return Err(fail(el, diags));
        }
    };
    let (mut built, mut reduction) = (built, reduction);
    let system = match reduction.as_mut() {
        Some(r) => &mut r.system,
        None => &mut built.system,
    };
    let schedule = crate::analysis::schedule(system, &causal);
    Ok(Sorted {
        elaborated: el,
        built,
        faults: fixable,
        reduction,
        causal,
        schedule,
    })
}
