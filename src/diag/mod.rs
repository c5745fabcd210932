//! Source files, byte spans and diagnostics, with their one renderer.
//!
//! Every stage reports problems as [`Diagnostic`]s that point into the netlist
//! by [`Span`] (byte ranges). Line and column are only computed when rendering,
//! which happens here and nowhere else. This module knows nothing about
//! circuits or equations.

pub mod codes;

pub use codes::Code;

use std::fmt;
use std::path::{Path, PathBuf};

/// Index of a file in a [`SourceMap`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
pub struct FileId(pub u32);

/// A byte range `start..end` in one source file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub struct Span {
    pub file: FileId,
    pub start: u32,
    pub end: u32,
}

impl Span {
    pub fn new(file: FileId, start: usize, end: usize) -> Span {
        Span {
            file,
            start: start as u32,
            end: end as u32,
        }
    }

    /// The smallest span covering both (same file assumed; `self`'s file wins).
    pub fn to(self, other: Span) -> Span {
        if other.file != self.file {
            return self;
        }
        Span {
            file: self.file,
            start: self.start.min(other.start),
            end: self.end.max(other.end),
        }
    }

    pub fn range(self) -> std::ops::Range<usize> {
        self.start as usize..self.end as usize
    }
}

/// One loaded source file.
#[derive(Debug, Clone)]
pub struct SourceFile {
    /// The name shown in diagnostics (the path as the user wrote it).
    pub name: String,
    /// The path used to resolve `.include` lines relative to this file.
    pub path: PathBuf,
    pub text: String,
}

/// All files of one netlist: the root first, then its includes in load order.
#[derive(Debug, Clone, Default)]
pub struct SourceMap {
    files: Vec<SourceFile>,
}

impl SourceMap {
    pub fn add(
        &mut self,
        name: impl Into<String>,
        path: impl Into<PathBuf>,
        text: String,
    ) -> FileId {
        let id = FileId(self.files.len() as u32);
        self.files.push(SourceFile {
            name: name.into(),
            path: path.into(),
            text,
        });
        id
    }

    pub fn len(&self) -> usize {
        self.files.len()
    }

    pub fn is_empty(&self) -> bool {
        self.files.is_empty()
    }

    pub fn ids(&self) -> impl Iterator<Item = FileId> + use<> {
        (0..self.files.len() as u32).map(FileId)
    }

    pub fn file(&self, id: FileId) -> &SourceFile {
        &self.files[id.0 as usize]
    }

    pub fn find_path(&self, path: &Path) -> Option<FileId> {
        self.files
            .iter()
            .position(|f| f.path == path)
            .map(|i| FileId(i as u32))
    }

    pub fn text(&self, span: Span) -> &str {
        self.file(span.file)
            .text
            .get(span.range())
            .unwrap_or_default()
    }

    /// 1-based line and column (in characters) of a byte offset.
    pub fn line_col(&self, file: FileId, offset: u32) -> (usize, usize) {
        let text = &self.file(file).text;
        let offset = (offset as usize).min(text.len());
        let before = &text[..offset];
        let line = before.bytes().filter(|&b| b == b'\n').count() + 1;
        let line_start = before.rfind('\n').map_or(0, |i| i + 1);
        let col = before[line_start..].chars().count() + 1;
        (line, col)
    }

    /// `file:line:col` of a span's start.
    pub fn location(&self, span: Span) -> String {
        let (line, col) = self.line_col(span.file, span.start);
        format!("{}:{}:{}", self.file(span.file).name, line, col)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Severity {
    Error,
    Warning,
}

/// A text attached to a span.
#[derive(Clone, Debug, PartialEq)]
pub struct Label {
    pub span: Span,
    pub message: String,
}

/// A finished diagnostic: what every stage's error turns into for display.
#[derive(Clone, Debug, PartialEq)]
pub struct Diagnostic {
    pub severity: Severity,
    /// Stable code such as `K0102`.
    pub code: Code,
    pub message: String,
    /// The first label is the primary one.
    pub labels: Vec<Label>,
    /// A one-line hint on how to fix it.
    pub help: Option<String>,
    pub notes: Vec<String>,
}

impl Diagnostic {
    pub fn error(code: Code, message: impl Into<String>) -> Diagnostic {
        Diagnostic {
            severity: Severity::Error,
            code,
            message: message.into(),
            labels: Vec::new(),
            help: None,
            notes: Vec::new(),
        }
    }

    pub fn warning(code: Code, message: impl Into<String>) -> Diagnostic {
        Diagnostic {
            severity: Severity::Warning,
            ..Diagnostic::error(code, message)
        }
    }

    pub fn with_label(mut self, span: Span, message: impl Into<String>) -> Diagnostic {
        self.labels.push(Label {
            span,
            message: message.into(),
        });
        self
    }

    pub fn with_help(mut self, help: impl Into<String>) -> Diagnostic {
        self.help = Some(help.into());
        self
    }

    pub fn with_note(mut self, note: impl Into<String>) -> Diagnostic {
        self.notes.push(note.into());
        self
    }

    pub fn is_error(&self) -> bool {
        self.severity == Severity::Error
    }

    /// The primary span, if any.
    pub fn span(&self) -> Option<Span> {
        self.labels.first().map(|l| l.span)
    }
}

/// Types that can be shown as a [`Diagnostic`] (every stage's error enum).
pub trait ToDiagnostic {
    fn to_diagnostic(&self) -> Diagnostic;
}

/// Rendering options: colour on a terminal, none in tests and pipes.
#[derive(Clone, Copy, Debug, Default)]
pub struct RenderOptions {
    pub color: bool,
}

/// Render a diagnostic with file, line, column, the source line and a caret
/// under the offending text.
pub fn render(sources: &SourceMap, diag: &Diagnostic, opts: RenderOptions) -> String {
    use miette::{GraphicalReportHandler, GraphicalTheme, ThemeCharacters, ThemeStyles};
    let mut characters = ThemeCharacters::unicode();
    characters.underline = '^';
    characters.underbar = '^';
    let styles = if opts.color {
        ThemeStyles::ansi()
    } else {
        ThemeStyles::none()
    };
    let handler = GraphicalReportHandler::new_themed(GraphicalTheme { characters, styles })
        .with_width(100)
        .with_links(false);
    let report = MietteDiag::new(sources, diag);
    let mut out = String::new();
    if handler.render_report(&mut out, &report).is_err() {
        out = format!("{}: {}", diag.code, diag.message);
    }
    out
}

/// One line per diagnostic: `file:line:col: error[K0102]: message`. For logs and tests.
pub fn render_short(sources: &SourceMap, diag: &Diagnostic) -> String {
    let sev = match diag.severity {
        Severity::Error => "error",
        Severity::Warning => "warning",
    };
    match diag.span() {
        Some(span) => format!(
            "{}: {sev}[{}]: {}",
            sources.location(span),
            diag.code,
            diag.message
        ),
        None => format!("{sev}[{}]: {}", diag.code, diag.message),
    }
}

/// Adapter from our [`Diagnostic`] to miette's trait. Labels in the file of the
/// primary label are drawn on it; labels in other files become related reports.
struct MietteDiag {
    severity: Severity,
    code: Code,
    message: String,
    help: Option<String>,
    source: Option<miette::NamedSource<String>>,
    labels: Vec<miette::LabeledSpan>,
    related: Vec<MietteDiag>,
}

impl MietteDiag {
    fn new(sources: &SourceMap, diag: &Diagnostic) -> MietteDiag {
        let mut help = diag.help.clone();
        for note in &diag.notes {
            let h = help.get_or_insert_with(String::new);
            if !h.is_empty() {
                h.push('\n');
            }
            h.push_str("note: ");
            h.push_str(note);
        }
        let Some(primary) = diag.span() else {
            return MietteDiag {
                severity: diag.severity,
                code: diag.code,
                message: diag.message.clone(),
                help,
                source: None,
                labels: Vec::new(),
                related: Vec::new(),
            };
        };
        let mut by_file: Vec<(FileId, Vec<&Label>)> = Vec::new();
        for label in &diag.labels {
            match by_file.iter_mut().find(|(f, _)| *f == label.span.file) {
                Some((_, v)) => v.push(label),
                None => by_file.push((label.span.file, vec![label])),
            }
        }
        let make = |file: FileId, labels: &[&Label], message: String| {
            let f = sources.file(file);
            MietteDiag {
                severity: diag.severity,
                code: diag.code,
                message,
                help: None,
                source: Some(miette::NamedSource::new(f.name.clone(), f.text.clone())),
                labels: labels
                    .iter()
                    .enumerate()
                    .map(|(k, l)| {
                        let len = l.span.end.saturating_sub(l.span.start).max(1) as usize;
                        let start = (l.span.start as usize).min(f.text.len());
                        let len = len.min(f.text.len().saturating_sub(start));
                        let msg = (!l.message.is_empty()).then(|| l.message.clone());
                        if k == 0 {
                            miette::LabeledSpan::new_primary_with_span(msg, (start, len))
                        } else {
                            miette::LabeledSpan::new(msg, start, len)
                        }
                    })
                    .collect(),
                related: Vec::new(),
            }
        };
        let mut main = make(primary.file, &by_file[0].1, diag.message.clone());
        main.help = help;
        for (file, labels) in &by_file[1..] {
            main.related.push(make(
                *file,
                labels,
                format!("see also `{}`", sources.file(*file).name),
            ));
        }
        main
    }
}

impl fmt::Debug for MietteDiag {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.message)
    }
}

impl fmt::Display for MietteDiag {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for MietteDiag {}

impl miette::Diagnostic for MietteDiag {
    fn code<'a>(&'a self) -> Option<Box<dyn fmt::Display + 'a>> {
        Some(Box::new(self.code))
    }

    fn severity(&self) -> Option<miette::Severity> {
        Some(match self.severity {
            Severity::Error => miette::Severity::Error,
            Severity::Warning => miette::Severity::Warning,
        })
    }

    fn help<'a>(&'a self) -> Option<Box<dyn fmt::Display + 'a>> {
        self.help
            .as_ref()
            .map(|h| Box::new(h) as Box<dyn fmt::Display>)
    }

    fn source_code(&self) -> Option<&dyn miette::SourceCode> {
        self.source.as_ref().map(|s| s as &dyn miette::SourceCode)
    }

    fn labels(&self) -> Option<Box<dyn Iterator<Item = miette::LabeledSpan> + '_>> {
        if self.labels.is_empty() {
            None
        } else {
            Some(Box::new(self.labels.iter().cloned()))
        }
    }

    fn related<'a>(&'a self) -> Option<Box<dyn Iterator<Item = &'a dyn miette::Diagnostic> + 'a>> {
        if self.related.is_empty() {
            None
        } else {
            Some(Box::new(
                self.related.iter().map(|r| r as &dyn miette::Diagnostic),
            ))
        }
    }
}
