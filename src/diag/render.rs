//! The one renderer of [`Diagnostic`]s: miette's graphical report, fed
//! through [`Excerpt`], a view of a source file that shows only what the
//! labels need. It must stay fast and small on any input: a diagnostic
//! draws at most [`MAX_LABELS`] labels, a long line is shown as a window
//! around its labels, and looking up a span never scans the file.

use std::fmt;

use super::{Diagnostic, FileId, Label, Severity, SourceFile, SourceMap};

/// Rendering options: colour on a terminal, none in tests and pipes.
#[derive(Clone, Copy, Debug, Default)]
pub struct RenderOptions {
    pub color: bool,
}

/// Labels drawn per diagnostic; a note counts the rest. Drawing is linear in
/// the labels shown, and a report of thousands of spans helps no one.
const MAX_LABELS: usize = 64;

/// A line longer than this many bytes is shown as a window around its
/// labels, not whole (miette's underline cannot reach past column 65,535,
/// and a 70,000-character line is no help on a terminal anyway). Shorter
/// lines are shown whole.
const LONG_LINE: usize = 160;

/// Bytes of a long line shown on each side of its labels.
const MARGIN: usize = 40;

/// A label on a long line is drawn over at most this many bytes.
const MAX_LABEL: usize = 80;

/// Marks the text a window leaves out of a long line.
const ELLIPSIS: &str = "…";

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
struct MietteDiag<'s> {
    severity: Severity,
    code: super::Code,
    message: String,
    help: Option<String>,
    source: Option<Excerpt<'s>>,
    labels: Vec<miette::LabeledSpan>,
    related: Vec<MietteDiag<'s>>,
}

impl<'s> MietteDiag<'s> {
    fn new(sources: &'s SourceMap, diag: &Diagnostic) -> MietteDiag<'s> {
        let mut help = diag.help.clone();
        let mut notes: Vec<String> = diag.notes.clone();
        let shown = &diag.labels[..diag.labels.len().min(MAX_LABELS)];
        if shown.len() < diag.labels.len() {
            let n = diag.labels.len() - shown.len();
            notes.push(format!(
                "{n} more place{} not shown",
                if n == 1 { " is" } else { "s are" }
            ));
        }
        for note in &notes {
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
        for label in shown {
            match by_file.iter_mut().find(|(f, _)| *f == label.span.file) {
                Some((_, v)) => v.push(label),
                None => by_file.push((label.span.file, vec![label])),
            }
        }
        let make = |file: FileId, labels: &[&Label], message: String| {
            let f = sources.file(file);
            let spans: Vec<(usize, usize)> = labels.iter().map(|l| clip(f, l)).collect();
            MietteDiag {
                severity: diag.severity,
                code: diag.code,
                message,
                help: None,
                source: Some(Excerpt::new(f, &spans)),
                labels: labels
                    .iter()
                    .zip(&spans)
                    .enumerate()
                    .map(|(k, (l, &(start, end)))| {
                        let msg = (!l.message.is_empty()).then(|| l.message.clone());
                        if k == 0 {
                            miette::LabeledSpan::new_primary_with_span(msg, (start, end - start))
                        } else {
                            miette::LabeledSpan::new(msg, start, end - start)
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

/// The byte range a label is drawn over: inside the file, at least one byte
/// where the file has one, and, where it touches a long line, on its first
/// line and at most [`MAX_LABEL`] bytes (windows show one line each).
fn clip(f: &SourceFile, label: &Label) -> (usize, usize) {
    let len = f.text.len();
    let start = floor_char(&f.text, (label.span.start as usize).min(len));
    let end = (label.span.end as usize).max(start + 1).min(len);
    let (first, last) = (
        f.line_of(start),
        f.line_of(end.saturating_sub(1).max(start)),
    );
    if !(first..=last).any(|l| is_long(f, l)) {
        return (start, ceil_char(&f.text, end));
    }
    let line_end = f.line_range(first).end;
    let end = end
        .min(line_end.max(start + 1))
        .min(start + MAX_LABEL)
        .min(len);
    (start, ceil_char(&f.text, end))
}

fn is_long(f: &SourceFile, line: usize) -> bool {
    f.line_range(line).len() > LONG_LINE
}

/// The largest char boundary of `s` at or before `i`.
fn floor_char(s: &str, mut i: usize) -> usize {
    while !s.is_char_boundary(i) {
        i -= 1;
    }
    i
}

/// The smallest char boundary of `s` at or after `i`.
fn ceil_char(s: &str, mut i: usize) -> usize {
    while !s.is_char_boundary(i) {
        i += 1;
    }
    i
}

/// The part of one long line shown for the labels on it.
struct Window {
    line: usize,
    /// File offset that `shown[0]` stands for.
    offset: usize,
    /// The line's bytes `offset..offset + shown.len()`, with an [`ELLIPSIS`]
    /// standing for the (at least as long) text it leaves out at either end.
    shown: String,
}

/// A source file as miette reads it: spans are looked up in the file's line
/// index (never by scanning from its start), long lines are replaced by
/// their [`Window`]s, and a long line never serves as a context line.
struct Excerpt<'s> {
    file: &'s SourceFile,
    windows: Vec<Window>,
}

impl<'s> Excerpt<'s> {
    /// The view for labels drawn over `spans` (clipped by [`clip`]).
    fn new(file: &'s SourceFile, spans: &[(usize, usize)]) -> Excerpt<'s> {
        let mut on_long: Vec<(usize, usize, usize)> = spans
            .iter()
            .map(|&(s, e)| (file.line_of(s), s, e))
            .filter(|&(line, _, _)| is_long(file, line))
            .collect();
        on_long.sort_unstable();
        // Labels close together on a line share a window.
        let mut groups: Vec<(usize, usize, usize)> = Vec::new();
        for (line, s, e) in on_long {
            match groups.last_mut() {
                Some(g) if g.0 == line && s <= g.2 + 2 * MARGIN && e <= g.1 + LONG_LINE => {
                    g.2 = g.2.max(e)
                }
                _ => groups.push((line, s, e)),
            }
        }
        let windows = groups
            .into_iter()
            .map(|(line, s, e)| window(file, line, s, e))
            .collect();
        Excerpt { file, windows }
    }
}

/// The window of `line` showing bytes `s..e` with [`MARGIN`] bytes around.
fn window(f: &SourceFile, line: usize, s: usize, e: usize) -> Window {
    let text = &f.text;
    let range = f.line_range(line);
    let from = floor_char(text, s.saturating_sub(MARGIN).max(range.start));
    let to = ceil_char(text, (e + MARGIN).min(range.end).max(e));
    // An ellipsis stands for as many bytes of the line as it has itself, so
    // that every shown byte keeps its offset in the file.
    let (offset, mut shown) = if from - range.start >= ELLIPSIS.len() {
        (
            from - ELLIPSIS.len(),
            format!("{ELLIPSIS}{}", &text[from..to]),
        )
    } else {
        (range.start, text[range.start..to].to_string())
    };
    if to < range.end && range.end - to >= ELLIPSIS.len() {
        shown.push_str(ELLIPSIS);
    } else if to < range.end {
        shown.push_str(&text[to..range.end]);
    }
    Window {
        line,
        offset,
        shown,
    }
}

impl miette::SourceCode for Excerpt<'_> {
    fn read_span<'a>(
        &'a self,
        span: &miette::SourceSpan,
        before: usize,
        after: usize,
    ) -> Result<Box<dyn miette::SpanContents<'a> + 'a>, miette::MietteError> {
        let f = self.file;
        let (start, end) = (span.offset(), span.offset() + span.len());
        if end > f.text.len() {
            return Err(miette::MietteError::OutOfBounds);
        }
        let first = f.line_of(start);
        let last = f.line_of(end.saturating_sub(1).max(start));
        let line_start = f.line_starts()[first] as usize;
        // The column of the span's start, in characters, for the header.
        let column = if before == 0 {
            f.text[line_start..floor_char(&f.text, start)]
                .chars()
                .count()
        } else {
            0
        };
        let contents = |data: &'a str, offset: usize, line: usize, n_lines: usize| {
            let contents = miette::MietteSpanContents::new_named(
                f.name.clone(),
                data.as_bytes(),
                (offset, data.len()).into(),
                line,
                column,
                n_lines,
            );
            Ok(Box::new(contents) as Box<dyn miette::SpanContents<'a> + 'a>)
        };
        if (first..=last).any(|l| is_long(f, l)) {
            // A long line is shown through a window holding the whole span,
            // alone; a span no window holds (two labels far apart on the
            // line, merged) is refused, and miette draws them apart.
            return match self.windows.iter().find(|w| {
                w.line == first
                    && first == last
                    && w.offset <= start
                    && end <= w.offset + w.shown.len()
            }) {
                Some(w) => contents(&w.shown, w.offset, first, 1),
                None => Err(miette::MietteError::OutOfBounds),
            };
        }
        let n_lines = f.line_starts().len();
        let mut lo = first;
        while lo > 0 && first - lo < before && !is_long(f, lo - 1) {
            lo -= 1;
        }
        // A span ending with a line break counts the line after it as its
        // own (as miette's own reading does), and adds context after that.
        let after = after + usize::from(end > start && f.text.as_bytes()[end - 1] == b'\n');
        let mut hi = last;
        while hi + 1 < n_lines && hi - last < after && !is_long(f, hi + 1) {
            hi += 1;
        }
        let from = f.line_starts()[lo] as usize;
        let to = f
            .line_starts()
            .get(hi + 1)
            .map_or(f.text.len(), |&s| s as usize);
        contents(&f.text[from..to], from, lo, hi - lo + 1)
    }
}

impl fmt::Debug for MietteDiag<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.message)
    }
}

impl fmt::Display for MietteDiag<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for MietteDiag<'_> {}

impl miette::Diagnostic for MietteDiag<'_> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diag::{Span, codes};

    fn one_file(text: &str) -> SourceMap {
        let mut sources = SourceMap::default();
        sources.add("t.cir", "t.cir", text.to_string());
        sources
    }

    fn at(sources: &SourceMap, start: usize, end: usize) -> String {
        let d = Diagnostic::error(codes::UNEXPECTED, "here")
            .with_label(Span::new(FileId(0), start, end), "this");
        render(sources, &d, RenderOptions::default())
    }

    /// Every label position on and around a long line (its ends, its line
    /// break, the end of the file, multi-byte characters) renders, at its
    /// true column, in a few short lines.
    #[test]
    fn any_span_on_a_long_line_renders_small() {
        let long = format!("R1 a{}é b 1k", "µ".repeat(40_000));
        for text in [
            format!("t\n{long}\n.end\n"),
            format!("t\n{long}"),
            format!("t\r\n{long}\r\n"),
        ] {
            let sources = one_file(&text);
            let mut cuts: Vec<usize> = (0..text.len()).step_by(997).collect();
            cuts.extend([0, 2, 3, 4, text.len() - 2, text.len() - 1, text.len()]);
            cuts.extend(text.match_indices('\n').map(|(i, _)| i));
            for &s in &cuts {
                for len in [0, 1, 2, 200, 100_000] {
                    let out = at(&sources, s, s + len);
                    let s = s.min(text.len());
                    let (line, col) = sources.line_col(FileId(0), s as u32);
                    let s = floor_char(&text, s);
                    let (line2, col2) = sources.line_col(FileId(0), s as u32);
                    assert!(
                        out.contains(&format!("t.cir:{line}:{col}]"))
                            || out.contains(&format!("t.cir:{line2}:{col2}]")),
                        "{s}+{len}:\n{out}"
                    );
                    assert!(out.len() < 3_000, "{s}+{len}: {} bytes", out.len());
                    assert!(out.lines().all(|l| l.chars().count() < 200), "{out}");
                }
            }
        }
    }

    /// Past [`MAX_LABELS`], labels are counted in a note instead of drawn.
    #[test]
    fn labels_beyond_the_cap_are_counted() {
        let text: String = (0..1000).map(|i| format!("R{i} a b 1k\n")).collect();
        let sources = one_file(&format!("t\n{text}"));
        let mut d = Diagnostic::error(codes::UNEXPECTED, "many");
        let starts = sources.file(FileId(0)).line_starts().to_vec();
        for &s in &starts[1..1001] {
            d = d.with_label(Span::new(FileId(0), s as usize, s as usize + 2), "here");
        }
        let out = render(&sources, &d, RenderOptions::default());
        assert_eq!(out.matches("── here").count(), MAX_LABELS, "{out}");
        assert!(
            out.contains(&format!("{} more places are not shown", 1000 - MAX_LABELS)),
            "{out}"
        );
    }
}
