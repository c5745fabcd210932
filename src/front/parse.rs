//! Statements from logical lines: blocks, subcircuits, includes, library
//! sections; directive lines are read in `directive.rs`, element lines in
//! `element.rs`.

use super::ast::*;
use super::error::ParseError;
use super::expr::{parse_expr, parse_number, too_complex};
use super::lex::{LogicalLine, TokKind, Token, lex_file};
use crate::diag::{FileId, SourceMap, Span};

mod directive;
mod element;

pub(super) struct Parser<'a> {
    pub sources: &'a SourceMap,
    pub errors: Vec<ParseError>,
    include_stack: Vec<FileId>,
    /// The library sections being read (file, lower-case name): a section
    /// may use another of its own file, but not itself.
    lib_stack: Vec<(FileId, String)>,
    /// Subcircuit definitions, includes and library sections being read.
    depth: usize,
}

/// Subcircuit definitions, includes and library sections nested deeper than
/// this are refused (reading them recurses: unbounded, 10^4 nested
/// `.subckt`s overflow the stack).
pub const MAX_NESTING: usize = 64;

/// Why a block of lines ended.
enum BlockEnd {
    Eof,
    End,
    Ends(Span),
}

impl<'a> Parser<'a> {
    pub fn new(sources: &'a SourceMap) -> Parser<'a> {
        Parser {
            sources,
            errors: Vec::new(),
            include_stack: Vec::new(),
            lib_stack: Vec::new(),
            depth: 0,
        }
    }

    pub fn parse_root(&mut self, root: FileId) -> Netlist<'a> {
        let lexed = lex_file(self.sources, root, true, &mut self.errors);
        let Some((title, title_span)) = lexed.title else {
            let len = self.sources.file(root).text.len();
            self.errors.push(ParseError::Empty {
                span: Span::new(root, 0, len.min(1)),
            });
            return Netlist::default();
        };
        self.include_stack.push(root);
        let mut idx = 0;
        let (stmts, end) = self.block(&lexed.lines(), &mut idx, false);
        if let BlockEnd::Ends(span) = end {
            self.errors.push(ParseError::StrayEnds { span });
        }
        Netlist {
            title,
            title_span,
            stmts,
        }
    }

    /// Parse lines from `*idx` until EOF, `.end`, or (inside a subcircuit)
    /// `.ends`, one nesting level deeper.
    fn block(
        &mut self,
        lines: &[LogicalLine<'_, 'a>],
        idx: &mut usize,
        in_subckt: bool,
    ) -> (Vec<Stmt<'a>>, BlockEnd) {
        self.depth += 1;
        let r = self.block_lines(lines, idx, in_subckt);
        self.depth -= 1;
        r
    }

    /// Whether a block opened at `span` would nest too deeply (then said).
    fn too_deep(&mut self, span: Span, what: &'static str) -> bool {
        let deep = self.depth > MAX_NESTING;
        if deep {
            self.errors.push(ParseError::TooDeep {
                span,
                what,
                limit: MAX_NESTING,
            });
        }
        deep
    }

    /// Skip a subcircuit's body up to its matching `.ends`, without reading it.
    fn skip_subckt(lines: &[LogicalLine<'_, 'a>], idx: &mut usize) {
        let mut open = 1usize;
        while *idx < lines.len() {
            let first = &lines[*idx].tokens[0];
            *idx += 1;
            if first.is_word(".subckt") {
                open += 1;
            } else if first.is_word(".ends") {
                open -= 1;
                if open == 0 {
                    return;
                }
            } else if first.is_word(".end") {
                return;
            }
        }
    }

    fn block_lines(
        &mut self,
        lines: &[LogicalLine<'_, 'a>],
        idx: &mut usize,
        in_subckt: bool,
    ) -> (Vec<Stmt<'a>>, BlockEnd) {
        // A file's top level takes most of its lines (never reserve the rest
        // of the file for every subcircuit body).
        let mut out = if in_subckt {
            Vec::new()
        } else {
            Vec::with_capacity(lines.len() - *idx)
        };
        while *idx < lines.len() {
            let line = &lines[*idx];
            *idx += 1;
            if line.poisoned {
                continue;
            }
            let first = line.tokens[0];
            if first.kind != TokKind::Word {
                self.errors.push(ParseError::Unexpected {
                    span: first.span,
                    what: format!("`{}` at the start of a line", first.text),
                });
                continue;
            }
            if let Some(directive) = first.text.strip_prefix('.') {
                let d = directive.to_ascii_lowercase();
                match d.as_str() {
                    "end" => return (out, BlockEnd::End),
                    "ends" => {
                        if in_subckt {
                            return (out, BlockEnd::Ends(first.span));
                        }
                        self.errors.push(ParseError::StrayEnds { span: first.span });
                    }
                    "subckt" => {
                        if let Some(s) = self.subckt(line, lines, idx) {
                            out.push(Stmt::Subckt(Box::new(s)));
                        }
                    }
                    "lib" if line.tokens.len() == 2 => self.skip_lib_definition(line, lines, idx),
                    "endl" => self.errors.push(ParseError::Unexpected {
                        span: first.span,
                        what: "`.endl` without `.lib SECTION`".into(),
                    }),
                    "control" => self.skip_control(first.span, lines, idx),
                    _ => {
                        if let Some(s) = self.directive(&d, line) {
                            out.push(s);
                        }
                    }
                }
            } else if let Some(e) = self.element(line) {
                out.push(Stmt::Element(e));
            }
        }
        (out, BlockEnd::Eof)
    }

    /// Skip a section's definition (`.lib SECTION` up to `.endl`): it is
    /// read only where a `.lib FILE SECTION` asks for it.
    fn skip_lib_definition(
        &mut self,
        line: &LogicalLine<'_, 'a>,
        lines: &[LogicalLine<'_, 'a>],
        idx: &mut usize,
    ) {
        let start = line.span();
        let section = line.tokens[1].text.to_string();
        match lines[*idx..]
            .iter()
            .position(|l| l.tokens[0].is_word(".endl"))
        {
            Some(k) => *idx += k + 1,
            None => {
                *idx = lines.len();
                self.errors.push(ParseError::UnclosedLib {
                    span: start,
                    section,
                });
            }
        }
    }

    /// Skip a `.control` block (opened at `start`) up to its `.endc`, and
    /// report it as skipped.
    fn skip_control(&mut self, start: Span, lines: &[LogicalLine<'_, 'a>], idx: &mut usize) {
        let mut closed = false;
        while *idx < lines.len() {
            let l = &lines[*idx];
            *idx += 1;
            if l.tokens[0].is_word(".endc") {
                closed = true;
                break;
            }
        }
        if closed {
            self.errors.push(ParseError::SkippedControl { span: start });
        } else {
            self.errors
                .push(ParseError::UnclosedControl { span: start });
        }
    }

    fn subckt(
        &mut self,
        line: &LogicalLine<'_, 'a>,
        lines: &[LogicalLine<'_, 'a>],
        idx: &mut usize,
    ) -> Option<Subckt<'a>> {
        let toks = &line.tokens;
        let mut c = Cursor::new(toks);
        c.next();
        let Some(name) = c.word() else {
            self.errors.push(ParseError::Expected {
                span: toks[0].span,
                expected: "a subcircuit name after `.subckt`".into(),
            });
            // Still consume the body so its `.ends` does not look stray.
            let _ = self.block(lines, idx, true);
            return None;
        };
        let mut ports = Vec::new();
        // `.subckt inv (in out vdd vss)`: ports in parentheses, as VACASK's
        // and some vendors' netlists write them.
        let paren = c.peek().is_some_and(|t| t.kind == TokKind::LParen);
        if paren {
            c.next();
        }
        while let Some(t) = c.peek() {
            if paren && t.kind == TokKind::RParen {
                c.next();
                break;
            }
            if t.kind != TokKind::Word || c.peek_at(1).is_some_and(|t| t.kind == TokKind::Eq) {
                break;
            }
            if t.is_word("params:") {
                c.next();
                break;
            }
            ports.push(name_of(t));
            c.next();
        }
        if c.peek().is_some_and(|t| t.is_word("params:")) {
            c.next();
        }
        let params = self.assigns(&mut c);
        self.rest_unexpected(&c);
        if self.too_deep(line.span(), "subcircuit definitions") {
            Self::skip_subckt(lines, idx);
            return None;
        }
        let (body, end) = self.block(lines, idx, true);
        if !matches!(end, BlockEnd::Ends(_)) {
            self.errors.push(ParseError::UnclosedSubckt {
                span: toks[0].span.to(name.span),
                name: name.text.to_string(),
            });
        }
        Some(Subckt {
            name,
            ports,
            params,
            body,
            span: line.span(),
        })
    }

    /// `name=value` pairs until the cursor meets something else.
    fn assigns(&mut self, c: &mut Cursor<'_, 'a>) -> Vec<Assign<'a>> {
        let mut out = Vec::new();
        while let (Some(n), Some(eq)) = (c.peek(), c.peek_at(1)) {
            if n.kind != TokKind::Word || eq.kind != TokKind::Eq {
                break;
            }
            c.next();
            c.next();
            // A BSIM card's `version=4.7.0` names a release, not a number:
            // kept as written (no model kausal has reads it).
            if n.is_word("version")
                && let Some(v) = c.peek().copied()
                && v.text.split('.').count() > 2
                && v.text
                    .split('.')
                    .all(|d| !d.is_empty() && d.bytes().all(|b| b.is_ascii_digit()))
            {
                c.next();
                out.push(Assign {
                    name: name_of(n),
                    value: Value::Ident(name_of(&v)),
                });
                continue;
            }
            match self.value_tok(c, n.text, "value") {
                Some(value) => out.push(Assign {
                    name: name_of(n),
                    value,
                }),
                None => break,
            }
        }
        out
    }

    /// `v(a)`, `v(a,b)`, `i(v1)`, or a bare node name meaning `v(name)`.
    fn out_vec(&mut self, c: &mut Cursor<'_, 'a>) -> Option<OutVec<'a>> {
        let t = *c.peek()?;
        if t.kind != TokKind::Word {
            self.errors.push(ParseError::Expected {
                span: t.span,
                expected: "an output vector such as `v(out)` or `i(v1)`".into(),
            });
            return None;
        }
        c.next();
        let kind = t.text.to_ascii_lowercase();
        if (kind == "v" || kind == "i") && c.eat(TokKind::LParen) {
            let mut args = Vec::new();
            while let Some(a) = c.peek() {
                if a.kind != TokKind::Word {
                    break;
                }
                args.push(name_of(a));
                c.next();
            }
            let close = c.peek().copied();
            if !c.eat(TokKind::RParen) || args.is_empty() || args.len() > 2 {
                self.errors.push(ParseError::Expected {
                    span: close.map_or(t.span, |x| x.span),
                    expected: "`v(node)`, `v(node1,node2)` or `i(source)`".into(),
                });
                return None;
            }
            let end = close.map_or(t.span, |x| x.span);
            return Some(OutVec {
                kind: if kind == "v" { 'v' } else { 'i' },
                args,
                span: t.span.to(end),
            });
        }
        Some(OutVec {
            kind: 'v',
            args: vec![name_of(&t)],
            span: t.span,
        })
    }

    /// The value at the cursor: a number, `{expr}` or parameter name.
    fn value_tok(
        &mut self,
        c: &mut Cursor<'_, 'a>,
        owner: &str,
        what: &'static str,
    ) -> Option<Value<'a>> {
        let Some(t) = c.next() else {
            self.errors.push(ParseError::MissingValue {
                span: c.here(c.toks[0].span),
                name: owner.to_string(),
                what,
            });
            return None;
        };
        match value_of(t) {
            Ok(v) => Some(v),
            Err(e) => {
                self.errors.push(e);
                None
            }
        }
    }

    fn rest_unexpected(&mut self, c: &Cursor<'_, 'a>) {
        if let Some(t) = c.peek() {
            self.errors.push(ParseError::Unexpected {
                span: t.span,
                what: format!("`{}`", t.text),
            });
        }
    }
}

fn is_value_token(t: &Token<'_>) -> bool {
    t.kind == TokKind::Expr || (t.kind == TokKind::Word && parse_number(t.text).is_some())
}

fn include_path<'a>(t: &Token<'a>) -> &'a str {
    t.text.trim_matches('"')
}

pub(super) fn name_of<'a>(t: &Token<'a>) -> Name<'a> {
    Name {
        text: t.text,
        span: t.span,
    }
}

/// Interpret one token as a value.
pub(super) fn value_of<'a>(t: &Token<'a>) -> Result<Value<'a>, ParseError> {
    match t.kind {
        TokKind::Expr if let Some((at, why)) = too_complex(t.text) => {
            let start = t.span.start as usize + 1 + at;
            let end = (start + 1).min(t.span.end as usize);
            Err(ParseError::ComplexExpression {
                span: Span::new(t.span.file, start.min(end), end),
                why,
            })
        }
        TokKind::Expr => match parse_expr(t.text) {
            Ok(expr) => Ok(Value::Expr {
                expr: Box::new(expr),
                text: t.text,
                span: t.span,
            }),
            Err(at) => {
                // Point at the offending character inside the braces.
                let start = t.span.start as usize + 1 + at;
                let end = (start + 1).min(t.span.end as usize);
                Err(ParseError::BadExpression {
                    span: Span::new(t.span.file, start.min(end), end),
                    text: t.text.to_string(),
                })
            }
        },
        TokKind::Word => {
            if let Some(value) = parse_number(t.text) {
                Ok(Value::Num {
                    value,
                    text: t.text,
                    span: t.span,
                })
            } else if t
                .text
                .starts_with(|c: char| c.is_ascii_alphabetic() || c == '_')
            {
                Ok(Value::Ident(name_of(t)))
            } else {
                Err(ParseError::BadNumber {
                    span: t.span,
                    text: t.text.to_string(),
                })
            }
        }
        _ => Err(ParseError::Expected {
            span: t.span,
            expected: "a value".into(),
        }),
    }
}

/// A read position in a token list.
pub(super) struct Cursor<'t, 'a> {
    toks: &'t [Token<'a>],
    pos: usize,
}

impl<'t, 'a> Cursor<'t, 'a> {
    fn new(toks: &'t [Token<'a>]) -> Self {
        Cursor { toks, pos: 0 }
    }

    fn peek(&self) -> Option<&'t Token<'a>> {
        self.toks.get(self.pos)
    }

    fn peek_at(&self, k: usize) -> Option<&'t Token<'a>> {
        self.toks.get(self.pos + k)
    }

    fn next(&mut self) -> Option<&'t Token<'a>> {
        let t = self.toks.get(self.pos);
        if t.is_some() {
            self.pos += 1;
        }
        t
    }

    fn done(&self) -> bool {
        self.pos >= self.toks.len()
    }

    fn eat(&mut self, kind: TokKind) -> bool {
        if self.peek().is_some_and(|t| t.kind == kind) {
            self.pos += 1;
            true
        } else {
            false
        }
    }

    fn word(&mut self) -> Option<Name<'a>> {
        match self.peek() {
            Some(t) if t.kind == TokKind::Word => {
                self.pos += 1;
                Some(name_of(t))
            }
            _ => None,
        }
    }

    /// Span of the current token, or just past the line's end.
    fn here(&self, fallback: Span) -> Span {
        match self.peek() {
            Some(t) => t.span,
            None => match self.toks.last() {
                Some(t) => Span {
                    start: t.span.end,
                    end: t.span.end + 1,
                    ..t.span
                },
                None => fallback,
            },
        }
    }
}
