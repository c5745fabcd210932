//! Lines and tokens: comments, `+` continuation, the title line, and the
//! splitting of a logical line into words, `=`, parentheses and `{…}`
//! expressions, each with its byte span.

use super::error::ParseError;
use crate::diag::{FileId, SourceMap, Span};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TokKind {
    Word,
    Eq,
    LParen,
    RParen,
    /// A `{…}` or `'…'` expression; `text` is the part inside the delimiters.
    Expr,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Token<'a> {
    pub kind: TokKind,
    pub text: &'a str,
    pub span: Span,
}

impl Token<'_> {
    pub fn is_word(&self, w: &str) -> bool {
        self.kind == TokKind::Word && self.text.eq_ignore_ascii_case(w)
    }
}

/// One statement: a physical line plus its `+` continuation lines.
#[derive(Clone, Copy, Debug)]
pub struct LogicalLine<'t, 'a> {
    pub tokens: &'t [Token<'a>],
    /// The lexer reported an error on this line; the parser skips it so that
    /// one mistake gives one message.
    pub poisoned: bool,
}

impl LogicalLine<'_, '_> {
    pub fn span(&self) -> Span {
        let first = self.tokens[0].span;
        self.tokens.last().map_or(first, |t| first.to(t.span))
    }
}

/// A lexed file: its title line (root file only) and its logical lines, whose
/// tokens lie end to end in one vector.
pub struct LexedFile<'a> {
    pub title: Option<(&'a str, Span)>,
    tokens: Vec<Token<'a>>,
    /// Each logical line's token range and poisoned flag.
    ranges: Vec<(u32, u32, bool)>,
}

impl<'a> LexedFile<'a> {
    /// The logical lines, in order.
    pub fn lines(&self) -> Vec<LogicalLine<'_, 'a>> {
        self.ranges
            .iter()
            .map(|&(s, e, poisoned)| LogicalLine {
                tokens: &self.tokens[s as usize..e as usize],
                poisoned,
            })
            .collect()
    }
}

/// Split `file` into logical lines. The first line is the title when
/// `has_title` (ngspice: the root file's first line, never an included file's).
pub fn lex_file<'a>(
    sources: &'a SourceMap,
    file: FileId,
    has_title: bool,
    errors: &mut Vec<ParseError>,
) -> LexedFile<'a> {
    let text = sources.file(file).text.as_str();
    // Element lines run about three bytes per token (`R1 n0 n1 1k`).
    let mut tokens: Vec<Token<'a>> = Vec::with_capacity(text.len() / 3);
    let mut ranges: Vec<(u32, u32, bool)> = Vec::with_capacity(text.len() / 24);
    let mut title = None;
    let mut offset = 0usize;
    let mut first = true;
    // Where the last failed search for an expression's close stopped.
    let mut searched_to = 0usize;
    while offset < text.len() {
        let start = offset;
        let raw = &text[start..line_end(text, start)];
        offset += raw.len();
        let line = raw.trim_end_matches(['\n', '\r']);
        if first && has_title {
            first = false;
            let t = line.trim();
            let lead = line.len() - line.trim_start().len();
            title = Some((t, Span::new(file, start + lead, start + lead + t.len())));
            continue;
        }
        first = false;
        let trimmed = line.trim_start();
        if trimmed.is_empty() || trimmed.starts_with('*') {
            continue;
        }
        let lead = line.len() - trimmed.len();
        // A line that starts with `)` closes the previous line's parentheses
        // (a `.model` whose `)` stands alone): ngspice warns and reads on,
        // and so does joining it to that line.
        let (body, body_start, continuation) = match trimmed.strip_prefix('+') {
            Some(rest) => (rest, start + lead + 1, true),
            None if trimmed.starts_with(')') => (trimmed, start + lead, true),
            None => (trimmed, start + lead, false),
        };
        let n_errors = errors.len();
        let before = tokens.len();
        let (mut body, mut body_start) = (body, body_start);
        // An expression left open at the end of the line goes on over the
        // `+` lines after it (ngspice joins them before reading it): its
        // token spans them, and the line ends after the one that closes it.
        while let Some(open_at) = tokenize(body, file, body_start, errors, &mut tokens) {
            let open = text.as_bytes()[open_at];
            let close = closing(open);
            // Past a failed search, an expression opened within the text
            // it covered is not searched again: the logical line is an
            // error already, and searching from every `{` of a long run of
            // `+` lines would be quadratic.
            let found = if open_at < searched_to {
                None
            } else {
                close_across(text, open_at, open, close)
                    .map_err(|end| searched_to = end)
                    .ok()
            };
            let Some(close_at) = found else {
                errors.push(ParseError::Unterminated {
                    span: Span::new(file, open_at, open_at + 1),
                    close: close as char,
                });
                break;
            };
            tokens.push(Token {
                kind: TokKind::Expr,
                text: &text[open_at + 1..close_at],
                span: Span::new(file, open_at, close_at + 1),
            });
            offset = line_end(text, close_at);
            body = text[close_at + 1..offset].trim_end_matches(['\n', '\r']);
            body_start = close_at + 1;
        }
        let poisoned = errors.len() > n_errors;
        if continuation {
            // The previous logical line ends where this one's tokens begin,
            // so extending its range takes them in.
            match ranges.last_mut() {
                Some(prev) => {
                    prev.1 = tokens.len() as u32;
                    prev.2 |= poisoned;
                }
                None => {
                    tokens.truncate(before);
                    errors.push(ParseError::StrayContinuation {
                        span: Span::new(file, start + lead, start + lead + 1),
                    })
                }
            }
        } else if tokens.len() > before {
            ranges.push((before as u32, tokens.len() as u32, poisoned));
        }
    }
    LexedFile {
        title,
        tokens,
        ranges,
    }
}

fn is_sep(c: char) -> bool {
    c.is_whitespace() || c == ','
}

fn is_word_end(c: char) -> bool {
    is_sep(c) || matches!(c, '(' | ')' | '=' | '{' | '}' | '\'' | ';')
}

/// The delimiter that closes an expression opened by `open` (`{` or `'`).
fn closing(open: u8) -> u8 {
    if open == b'{' { b'}' } else { b'\'' }
}

/// The end of the physical line that holds byte `at`: past its `\n`, or the
/// end of the text.
fn line_end(text: &str, at: usize) -> usize {
    text[at..].find('\n').map_or(text.len(), |k| at + k + 1)
}

/// Byte index of the delimiter closing the one at `text[open_at]`, over the
/// physical lines after it while each is a `+` continuation (comment and
/// blank lines between them skipped, as ngspice skips them); nesting counts
/// for braces. Where there is none, the offset the search stopped at. The
/// delimiters are ASCII, so bytes suffice.
fn close_across(text: &str, open_at: usize, open: u8, close: u8) -> Result<usize, usize> {
    let b = text.as_bytes();
    let mut depth = 1usize;
    let mut i = open_at + 1;
    while i < b.len() {
        let c = b[i];
        if c == b'\n' {
            let mut j = i + 1;
            loop {
                while j < b.len() && matches!(b[j], b' ' | b'\t' | b'\r') {
                    j += 1;
                }
                match b.get(j) {
                    Some(b'+') => break,
                    Some(b'*') | Some(b'\n') => j = line_end(text, j),
                    _ => return Err(j),
                }
            }
            i = j + 1;
            continue;
        }
        if c == close {
            depth -= 1;
            if depth == 0 {
                return Ok(i);
            }
        } else if c == open && open != close {
            depth += 1;
        }
        i += 1;
    }
    Err(b.len())
}

/// Split one line body (after any `+`) into tokens appended to `toks`;
/// `base` is its file offset. An expression that the body does not close
/// ends the tokens: its opening delimiter's file offset is returned, for
/// the caller to look for its close on the continuation lines.
pub fn tokenize<'a>(
    body: &'a str,
    file: FileId,
    base: usize,
    errors: &mut Vec<ParseError>,
    toks: &mut Vec<Token<'a>>,
) -> Option<usize> {
    let mut rest = body;
    let at = |rest: &str| base + (body.len() - rest.len());
    loop {
        rest = rest.trim_start_matches(is_sep);
        let Some(c) = rest.chars().next() else { break };
        // End-of-line comments: `;` anywhere, `$` and `//` after white space.
        let after_space = rest.len() == body.len()
            || body[..body.len() - rest.len()]
                .chars()
                .next_back()
                .is_some_and(is_sep);
        if c == ';' || (after_space && (c == '$' || rest.starts_with("//"))) {
            break;
        }
        if c == '{' || c == '\'' {
            let close = closing(c as u8);
            let start = at(rest);
            // Within the line (it holds no line break): the search over
            // continuation lines is the caller's.
            match close_across(rest, 0, c as u8, close).ok() {
                Some(end) => {
                    let inner = &rest[1..end];
                    toks.push(Token {
                        kind: TokKind::Expr,
                        text: inner,
                        span: Span::new(file, start, start + end + 1),
                    });
                    rest = &rest[end + 1..];
                }
                None => return Some(start),
            }
            continue;
        }
        if c == '}' {
            let start = at(rest);
            errors.push(ParseError::Unexpected {
                span: Span::new(file, start, start + 1),
                what: "`}` without a matching `{`".into(),
            });
            rest = &rest[1..];
            continue;
        }
        // One character for `=`, `(` and `)`, else a word up to its end.
        let (kind, len) = match c {
            '=' => (TokKind::Eq, 1),
            '(' => (TokKind::LParen, 1),
            ')' => (TokKind::RParen, 1),
            _ => (TokKind::Word, rest.find(is_word_end).unwrap_or(rest.len())),
        };
        if len == 0 {
            break;
        }
        let start = at(rest);
        let (text, r) = rest.split_at(len);
        toks.push(Token {
            kind,
            text,
            span: Span::new(file, start, start + len),
        });
        rest = r;
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kinds(s: &str) -> Vec<(TokKind, &str)> {
        let mut errs = Vec::new();
        let mut toks = Vec::new();
        tokenize(s, FileId(0), 0, &mut errs, &mut toks);
        assert!(errs.is_empty(), "{errs:?}");
        toks.into_iter().map(|t| (t.kind, t.text)).collect()
    }

    #[test]
    fn tokens_and_comments() {
        use TokKind::*;
        assert_eq!(
            kinds("V1 a 0 PULSE(0 1, 1n) ; comment"),
            vec![
                (Word, "V1"),
                (Word, "a"),
                (Word, "0"),
                (Word, "PULSE"),
                (LParen, "("),
                (Word, "0"),
                (Word, "1"),
                (Word, "1n"),
                (RParen, ")")
            ]
        );
        assert_eq!(
            kinds("R1 a b {2*rval} $ x"),
            vec![(Word, "R1"), (Word, "a"), (Word, "b"), (Expr, "2*rval")]
        );
        assert_eq!(
            kinds(".ic v(a)=1"),
            vec![
                (Word, ".ic"),
                (Word, "v"),
                (LParen, "("),
                (Word, "a"),
                (RParen, ")"),
                (Eq, "="),
                (Word, "1")
            ]
        );
    }

    /// An expression left open at a line's end goes on over the `+` lines
    /// after it (a comment line between is skipped), and the logical line
    /// takes in what follows its close; where no `+` line follows, it is
    /// unterminated.
    #[test]
    fn an_expression_goes_on_over_continuation_lines() {
        let lex = |text: &str| {
            let mut sources = SourceMap::default();
            let file = sources.add("t.cir", "t.cir", text.to_string());
            let mut errors = Vec::new();
            let lexed = lex_file(&sources, file, true, &mut errors);
            let lines: Vec<Vec<(TokKind, String)>> = lexed
                .lines()
                .iter()
                .map(|l| {
                    l.tokens
                        .iter()
                        .map(|t| (t.kind, t.text.to_string()))
                        .collect()
                })
                .collect();
            (lines, errors.len())
        };
        use TokKind::*;
        let (lines, errors) = lex("t\nB1 a 0 V={ f(1,\n* note\n+ 2) } k=1\n+ m=2\nR1 a 0 1\n");
        assert_eq!(errors, 0);
        assert_eq!(lines.len(), 2);
        assert_eq!(lines[0][5], (Expr, " f(1,\n* note\n+ 2) ".to_string()));
        let words: Vec<&str> = lines[0][6..].iter().map(|(_, w)| w.as_str()).collect();
        assert_eq!(words, ["k", "=", "1", "m", "=", "2"]);
        assert_eq!(lines[1][0].1, "R1");
        let (lines, errors) = lex("t\nB1 a 0 V={ f(1,\nR1 a 0 1\n");
        assert_eq!(errors, 1, "unterminated");
        assert_eq!(lines.last().unwrap()[0].1, "R1");
    }
}
