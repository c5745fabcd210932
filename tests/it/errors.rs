//! Every malformed netlist in `netlists/errors/` carries its expected
//! diagnostics as comments under the offending line:
//!
//! ```text
//! R1 a b 1k5
//! *      ^^^ K0108: `1k5` is not a number
//! ```
//!
//! The first caret marks the column where the diagnostic's span starts (a
//! caret right after the `*` stands for column 1); the text after the code
//! must occur in the message. Every error must be annotated; warnings only
//! when they are. The rendered diagnostics are also kept as goldens.

use kausal::diag::{self, Diagnostic, SourceMap};
use kausal::io::FsLoader;

use crate::{goldens, root, stem};

#[derive(Debug)]
struct Expect {
    file: String,
    line: usize,
    col: usize,
    code: String,
    text: String,
}

fn annotations(sources: &SourceMap, file: kausal::diag::FileId) -> Vec<Expect> {
    let f = sources.file(file);
    let mut out = Vec::new();
    let mut target_line = 0;
    for (k, line) in f.text.lines().enumerate() {
        let Some(rest) = line.strip_prefix('*') else {
            target_line = k + 1;
            continue;
        };
        let Some(caret) = rest.find('^') else {
            target_line = k + 1;
            continue;
        };
        if !rest[..caret].chars().all(|c| c == ' ') {
            target_line = k + 1;
            continue;
        }
        // `rest` starts one column after the `*`.
        let col = if caret == 0 { 1 } else { caret + 2 };
        let after = rest[caret..].trim_start_matches('^').trim();
        let (code, text) = after.split_once(':').expect("annotation is `CODE: text`");
        out.push(Expect {
            file: f.name.clone(),
            line: target_line,
            col,
            code: code.trim().to_string(),
            text: text.trim().to_string(),
        });
    }
    out
}

fn check_file(path: &std::path::Path) -> String {
    let (sources, diags): (SourceMap, Vec<Diagnostic>) =
        match kausal::pipeline::elaborate_file(path, &FsLoader) {
            Ok(el) => (el.sources, el.warnings),
            Err(f) => (f.sources, f.diagnostics),
        };
    check_annotations(path, &sources, &diags)
}

/// Match the annotations of every file in `sources` against `diags`; every
/// error must be annotated. Returns the rendered diagnostics.
pub fn check_annotations(
    path: &std::path::Path,
    sources: &SourceMap,
    diags: &[Diagnostic],
) -> String {
    let mut expects = Vec::new();
    for id in sources.ids() {
        expects.extend(annotations(sources, id));
    }
    let located: Vec<(String, usize, usize, &Diagnostic)> = diags
        .iter()
        .map(|d| {
            let span = d.span().expect("fixture diagnostics have spans");
            let (line, col) = sources.line_col(span.file, span.start);
            (sources.file(span.file).name.clone(), line, col, d)
        })
        .collect();
    for e in &expects {
        let found = located.iter().any(|(f, l, c, d)| {
            *f == e.file
                && *l == e.line
                && *c == e.col
                && d.code == e.code.as_str()
                && d.message.contains(&e.text)
        });
        assert!(
            found,
            "{}: expected {} `{}` at {}:{}, got:\n{}",
            path.display(),
            e.code,
            e.text,
            e.line,
            e.col,
            located
                .iter()
                .map(|(f, l, c, d)| format!("  {f}:{l}:{c} {} {}", d.code, d.message))
                .collect::<Vec<_>>()
                .join("\n")
        );
    }
    for (f, l, c, d) in &located {
        if d.is_error() {
            assert!(
                expects.iter().any(|e| e.file == *f
                    && e.line == *l
                    && e.col == *c
                    && d.code == e.code.as_str()),
                "{}: unexpected error {f}:{l}:{c} {} {}",
                path.display(),
                d.code,
                d.message
            );
        }
    }
    assert!(!expects.is_empty(), "{}: no annotations", path.display());
    diags
        .iter()
        .map(|d| diag::render(sources, d, Default::default()))
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
fn error_fixtures_report_what_they_annotate() {
    let files = crate::cir_files("netlists/errors");
    assert!(files.len() >= 15);
    for path in files {
        // Relative names keep the rendered goldens independent of the checkout.
        let rel = path.strip_prefix(root()).unwrap().to_path_buf();
        let cwd = std::env::current_dir().unwrap();
        assert_eq!(cwd, root(), "tests run from the crate root");
        let rendered = check_file(&rel);
        goldens("errors").bind(|| insta::assert_snapshot!(stem(&rel), rendered));
    }
}
