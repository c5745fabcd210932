//! The netlist front end: loading files (with `.include`), lexing, and parsing
//! ngspice-style netlists into an AST that keeps byte spans.
//!
//! It knows nothing of circuits' meaning: parameter values, subcircuit
//! expansion and models are the business of [`crate::elab`].

pub mod ast;
mod error;
pub mod expr;
pub mod lex;
mod parse;
pub mod print;

use std::path::{Path, PathBuf};

pub use error::ParseError;

use crate::diag::{FileId, SourceMap, Span};

/// Reads files for the front end; the CLI passes [`crate::io::FsLoader`].
pub trait Loader {
    fn load(&self, path: &Path) -> std::io::Result<String>;
}

/// Where `.include PATH` written in `from` points.
pub fn resolve_include(from: &Path, path: &str) -> PathBuf {
    let p = Path::new(path);
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        from.parent().unwrap_or(Path::new("")).join(p)
    }
}

/// Add `root` (already read) to a new [`SourceMap`], then every file it
/// includes, recursively. Problems (missing files, cycles) are returned beside
/// the map; parsing can still proceed without the missing files.
pub fn load(
    name: &str,
    path: &Path,
    text: String,
    loader: &dyn Loader,
) -> (SourceMap, Vec<ParseError>) {
    let mut sources = SourceMap::default();
    let mut errors = Vec::new();
    let root = sources.add(name, path, text);
    let mut stack = vec![root];
    load_includes(&mut sources, root, true, loader, &mut stack, &mut errors);
    (sources, errors)
}

fn load_includes(
    sources: &mut SourceMap,
    file: FileId,
    is_root: bool,
    loader: &dyn Loader,
    stack: &mut Vec<FileId>,
    errors: &mut Vec<ParseError>,
) {
    // Lex to find the include lines (the parse lexes again), but only when
    // some line could be one.
    let may_include = sources.file(file).text.lines().any(|l| {
        let l = l.trim_start().as_bytes();
        l.len() >= 4
            && (l[..4].eq_ignore_ascii_case(b".inc") || l[..4].eq_ignore_ascii_case(b".lib"))
    });
    if !may_include {
        return;
    }
    // `.include PATH` and `.lib PATH SECTION` (`.lib NAME` opens a section).
    let includes: Vec<(String, Span, bool)> = {
        let mut scratch = Vec::new();
        let lexed = lex::lex_file(sources, file, is_root, &mut scratch);
        lexed
            .lines()
            .iter()
            .filter_map(|l| {
                let lib = l.tokens[0].is_word(".lib") && l.tokens.len() >= 3;
                let include = l.tokens[0].is_word(".include") || l.tokens[0].is_word(".inc");
                (lib || include)
                    .then_some(l.tokens.get(1)?)
                    .map(|t| (t.text.trim_matches('"').to_string(), t.span, lib))
            })
            .collect()
    };
    let from = sources.file(file).path.clone();
    for (path, span, lib) in includes {
        let resolved = resolve_include(&from, &path);
        if let Some(existing) = sources.find_path(&resolved) {
            // A library's sections may use each other (the parser checks
            // that no section uses itself).
            if stack.contains(&existing) && !lib {
                errors.push(ParseError::IncludeCycle { span, path });
            }
            continue;
        }
        // Reading includes recurses: a chain deeper than the parser reads is
        // not loaded (the parser says so where it stops).
        if stack.len() > parse::MAX_NESTING {
            continue;
        }
        match loader.load(&resolved) {
            Ok(text) => {
                let id = sources.add(resolved.display().to_string(), resolved, text);
                stack.push(id);
                load_includes(sources, id, false, loader, stack, errors);
                stack.pop();
            }
            Err(e) => errors.push(ParseError::IncludeNotFound {
                span,
                path,
                reason: e.to_string(),
            }),
        }
    }
}

/// Parse the loaded files into an AST. Errors and warnings are collected; the
/// AST holds every statement that parsed.
pub fn parse(sources: &SourceMap) -> (ast::Netlist<'_>, Vec<ParseError>) {
    let mut p = parse::Parser::new(sources);
    let netlist = p.parse_root(FileId(0));
    (netlist, p.errors)
}
