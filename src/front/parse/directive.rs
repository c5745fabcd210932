//! Directive lines (`.model`, `.param`, `.tran`, `.include`, …): the name
//! decides which function reads the rest of the line; one function per
//! directive. Directives kausal does not read are reported here by name.
//! `.subckt`, `.ends`, `.end`, `.control` and section definitions span
//! several lines and are read by the block in `parse.rs`.

use super::{BlockEnd, Cursor, Parser, include_path, name_of};
use crate::diag::{FileId, Span};
use crate::front::ast::*;
use crate::front::error::ParseError;
use crate::front::expr::parse_number;
use crate::front::lex::{LogicalLine, TokKind, Token, lex_file};
use crate::front::resolve_include;

impl<'a> Parser<'a> {
    /// The statement of directive `d` (lower case, without its dot).
    pub(super) fn directive(&mut self, d: &str, line: &LogicalLine<'_, 'a>) -> Option<Stmt<'a>> {
        let toks = &line.tokens;
        let span = line.span();
        let mut c = Cursor::new(toks);
        c.next();
        match d {
            "model" => self.model(&mut c, span),
            "param" => self.param(&mut c, span),
            "func" => self.func(&mut c, span),
            "global" => self.global(&mut c, span),
            "ic" => self
                .node_values(&mut c, ".ic", span)
                .map(|v| Stmt::Ic(v, span)),
            "nodeset" => self
                .node_values(&mut c, ".nodeset", span)
                .map(|v| Stmt::Nodeset(v, span)),
            "tran" => self.tran(&mut c, span),
            "options" | "option" | "opt" | "opts" => self.options(&mut c, span),
            "print" | "save" | "probe" | "plot" => self.output(&mut c, span),
            "include" | "inc" => self.include(&mut c, span),
            "lib" => self.lib_section(toks, span),
            "ac" | "op" | "dc" | "noise" | "tf" | "four" | "disto" | "pz" | "sens" | "sp"
            | "meas" | "measure" | "fft" => self.refuse(ParseError::SkippedAnalysis {
                span: toks[0].span,
                name: toks[0].text.to_string(),
            }),
            "temp" | "width" | "csparam" | "title" | "save_all" => {
                self.refuse(ParseError::IgnoredDirective {
                    span: toks[0].span,
                    name: d.to_string(),
                })
            }
            "if" | "else" | "endif" | "model_lib" => {
                self.refuse(ParseError::UnsupportedDirective {
                    span: toks[0].span,
                    name: toks[0].text.to_string(),
                })
            }
            "endc" => self.refuse(ParseError::Unexpected {
                span: toks[0].span,
                what: "`.endc` without `.control`".into(),
            }),
            _ => self.refuse(ParseError::UnknownDirective {
                span: toks[0].span,
                name: toks[0].text.to_string(),
            }),
        }
    }

    /// A directive that yields no statement, for the reason `e` gives.
    fn refuse(&mut self, e: ParseError) -> Option<Stmt<'a>> {
        self.errors.push(e);
        None
    }

    /// `.model NAME TYPE(PARAM=VALUE ...)`; the parentheses are optional.
    fn model(&mut self, c: &mut Cursor<'_, 'a>, span: Span) -> Option<Stmt<'a>> {
        let missing = |p: &mut Self| {
            p.errors.push(ParseError::Expected {
                span,
                expected: "`.model NAME TYPE(PARAM=VALUE ...)`".into(),
            });
        };
        let (Some(name), Some(mut kind)) = (c.word(), c.word()) else {
            missing(self);
            return None;
        };
        // `AKO:ORIG TYPE(...)` (or `AKO: ORIG`): the model ORIG is named first.
        let mut ako = None;
        if kind
            .text
            .get(..4)
            .is_some_and(|p| p.eq_ignore_ascii_case("ako:"))
        {
            let orig = if kind.text.len() > 4 {
                Name {
                    text: &kind.text[4..],
                    span: Span {
                        start: kind.span.start + 4,
                        ..kind.span
                    },
                }
            } else if let Some(w) = c.word() {
                w
            } else {
                missing(self);
                return None;
            };
            let Some(k) = c.word() else {
                missing(self);
                return None;
            };
            ako = Some(orig);
            kind = k;
        }
        let paren = c.eat(TokKind::LParen);
        let mut closed = false;
        let mut params = Vec::new();
        loop {
            params.extend(self.assigns(c));
            let Some(t) = c.peek() else { break };
            match t.kind {
                // A `+` left mid-line between parameters (a continuation mark
                // pasted into one line), or commas between them: ngspice
                // reads past them.
                TokKind::Word if t.is_word("+") || t.is_word(",") => {}
                // More parameters after the closing parenthesis (a
                // continuation line after `…)`), as ngspice reads them.
                TokKind::RParen if paren && !closed => closed = true,
                // `(… NE=2)` then `+ CJE=… TR=159N)`: the continuation's own
                // closing parenthesis.
                TokKind::RParen if closed => {}
                // A value with no name before it (a decimal comma, `M=0,2`):
                // ngspice warns and reads on.
                _ if super::is_value_token(t)
                    && t.kind == TokKind::Word
                    && super::parse_number(t.text).is_some() =>
                {
                    self.errors.push(ParseError::StrayModelValue {
                        span: t.span,
                        text: t.text.to_string(),
                        model: name.text.to_string(),
                    });
                }
                // SPICE2's `BF 20 RB 100`: a name, then its value.
                TokKind::Word if c.peek_at(1).is_some_and(super::is_value_token) => {
                    c.next();
                    match self.value_tok(c, t.text, "value") {
                        Some(value) => params.push(Assign {
                            name: name_of(t),
                            value,
                        }),
                        None => break,
                    }
                    continue;
                }
                _ => break,
            }
            c.next();
        }
        if paren && !closed {
            self.errors.push(ParseError::Expected {
                span: c.here(span),
                expected: "`)` closing the model parameters".into(),
            });
            return None;
        }
        self.rest_unexpected(c);
        Some(Stmt::Model(Model {
            name,
            kind,
            params,
            ako,
            span,
        }))
    }

    /// `.param NAME=VALUE ...`: at least one.
    fn param(&mut self, c: &mut Cursor<'_, 'a>, span: Span) -> Option<Stmt<'a>> {
        let params = self.assigns(c);
        self.rest_unexpected(c);
        if params.is_empty() {
            self.errors.push(ParseError::Expected {
                span,
                expected: "`NAME=VALUE` after `.param`".into(),
            });
            return None;
        }
        Some(Stmt::Param(params, span))
    }

    /// `.func NAME(ARG ...) {EXPRESSION}`.
    fn func(&mut self, c: &mut Cursor<'_, 'a>, span: Span) -> Option<Stmt<'a>> {
        let def = self.func_def(c, span)?;
        self.rest_unexpected(c);
        Some(Stmt::Func(Box::new(def)))
    }

    /// `.global NODE ...`: at least one.
    fn global(&mut self, c: &mut Cursor<'_, 'a>, span: Span) -> Option<Stmt<'a>> {
        let mut names = Vec::new();
        while let Some(t) = c.peek() {
            if t.kind != TokKind::Word {
                break;
            }
            names.push(name_of(t));
            c.next();
        }
        self.rest_unexpected(c);
        if names.is_empty() {
            self.errors.push(ParseError::Expected {
                span,
                expected: "node names after `.global`".into(),
            });
            return None;
        }
        Some(Stmt::Global(names, span))
    }

    /// `v(node)=VALUE ...` of an `.ic` or `.nodeset` (named `directive`).
    fn node_values(
        &mut self,
        c: &mut Cursor<'_, 'a>,
        directive: &str,
        span: Span,
    ) -> Option<Vec<(OutVec<'a>, Value<'a>)>> {
        let mut ics = Vec::new();
        while !c.done() {
            let Some(v) = self.out_vec(c) else {
                break;
            };
            if !c.eat(TokKind::Eq) {
                self.errors.push(ParseError::Expected {
                    span: c.here(span),
                    expected: format!("`=` after `v(node)` in `{directive}`"),
                });
                return None;
            }
            let val = self.value_tok(c, directive, "value")?;
            ics.push((v, val));
        }
        self.rest_unexpected(c);
        Some(ics)
    }

    /// `.tran TSTEP TSTOP [TSTART [TMAX]] [UIC]`.
    fn tran(&mut self, c: &mut Cursor<'_, 'a>, span: Span) -> Option<Stmt<'a>> {
        let mut vals = Vec::new();
        let mut uic = false;
        while let Some(t) = c.peek() {
            if t.is_word("uic") {
                uic = true;
                c.next();
                continue;
            }
            vals.push(self.value_tok(c, ".tran", "time")?);
        }
        if vals.len() < 2 {
            self.errors.push(ParseError::MissingValue {
                span,
                name: ".tran".into(),
                what: "TSTEP and TSTOP",
            });
            return None;
        }
        if vals.len() > 4 {
            self.errors.push(ParseError::Unexpected {
                span: vals[4].span(),
                what: "fifth value in `.tran`".into(),
            });
        }
        let mut it = vals.into_iter();
        Some(Stmt::Tran(Box::new(Tran {
            tstep: it.next()?,
            tstop: it.next()?,
            tstart: it.next(),
            tmax: it.next(),
            uic,
            span,
        })))
    }

    /// `.options NAME[=VALUE] ...`; a token that is not a name is reported
    /// and skipped.
    fn options(&mut self, c: &mut Cursor<'_, 'a>, span: Span) -> Option<Stmt<'a>> {
        let mut opts = Vec::new();
        while let Some(t) = c.peek() {
            if t.kind != TokKind::Word {
                self.errors.push(ParseError::Unexpected {
                    span: t.span,
                    what: format!("`{}` in `.options`", t.text),
                });
                c.next();
                continue;
            }
            let name = name_of(t);
            c.next();
            let value = if c.eat(TokKind::Eq) {
                self.option_value(c, name)?
            } else {
                OptValue::Flag
            };
            opts.push(OptionDef { name, value });
        }
        Some(Stmt::Options(opts, span))
    }

    /// What follows `NAME=` in `.options`: a word such as `gear`, else a value.
    fn option_value(&mut self, c: &mut Cursor<'_, 'a>, name: Name<'a>) -> Option<OptValue<'a>> {
        match c.peek() {
            Some(v)
                if v.kind == TokKind::Word
                    && parse_number(v.text).is_none()
                    && v.text.starts_with(|ch: char| ch.is_ascii_alphabetic()) =>
            {
                c.next();
                Some(OptValue::Word(name_of(v)))
            }
            _ => Some(OptValue::Value(self.value_tok(c, name.text, "value")?)),
        }
    }

    /// `.print`, `.save`, `.probe`, `.plot`: an optional analysis name, then
    /// output vectors and the keyword `all`.
    fn output(&mut self, c: &mut Cursor<'_, 'a>, span: Span) -> Option<Stmt<'a>> {
        let directive = name_of(&c.toks[0]);
        let mut analysis = None;
        if let Some(t) = c.peek()
            && [
                "tran", "ac", "dc", "op", "noise", "homotopy", "sens", "pz", "disto", "tf", "sp",
                "pss",
            ]
            .iter()
            .any(|a| t.is_word(a))
        {
            analysis = Some(name_of(t));
            c.next();
        }
        let mut vectors = Vec::new();
        let mut all = false;
        while let Some(t) = c.peek() {
            if t.is_word("all") {
                all = true;
                c.next();
                continue;
            }
            // `v(…)`, `i(…)` and node names are vectors; any other item
            // (`vdb(2)`, `@r1[i]`, `par('…')`) is left out with a warning,
            // as ngspice leaves out what it cannot print.
            let plain = t.kind == TokKind::Word
                && !t.text.starts_with('@')
                && (t.is_word("v")
                    || t.is_word("i")
                    || c.peek_at(1)
                        .is_none_or(|n| n.kind != TokKind::LParen || n.span.start != t.span.end));
            let start = c.pos;
            let errors = self.errors.len();
            if plain
                && let Some(v) = self.out_vec(c)
                && item_end(c.toks, start) <= c.pos
            {
                vectors.push(v);
                continue;
            }
            self.errors.truncate(errors);
            c.pos = item_end(c.toks, start);
            let (first, last) = (c.toks[start].span, c.toks[c.pos - 1].span);
            let span = first.to(last);
            self.errors.push(ParseError::IgnoredOutput {
                span,
                directive: directive.text.trim_start_matches('.').to_ascii_lowercase(),
                item: self.sources.text(span).to_string(),
            });
        }
        Some(Stmt::Output {
            directive,
            analysis,
            vectors,
            all,
            span,
        })
    }

    /// `.include FILE`: the file's statements (loaded beforehand), parsed in
    /// place.
    fn include(&mut self, c: &mut Cursor<'_, 'a>, span: Span) -> Option<Stmt<'a>> {
        let Some(t) = c.next() else {
            self.errors.push(ParseError::Expected {
                span,
                expected: "a file name after `.include`".into(),
            });
            return None;
        };
        if self.too_deep(t.span, "includes") {
            return None;
        }
        // The loader reported why it could not read a missing file.
        let (path, file) = self.loaded(t)?;
        if self.include_stack.contains(&file) {
            // Reported by the loader as a cycle.
            return None;
        }
        self.include_stack.push(file);
        let lexed = lex_file(self.sources, file, false, &mut self.errors);
        let mut i = 0;
        let (body, end) = self.block(&lexed.lines(), &mut i, false);
        if let BlockEnd::Ends(span) = end {
            self.errors.push(ParseError::StrayEnds { span });
        }
        self.include_stack.pop();
        Some(Stmt::Include {
            path,
            section: None,
            span: t.span,
            body,
        })
    }

    /// The path a `.include` or `.lib` token names, and its file as loaded.
    fn loaded(&self, t: &Token<'a>) -> Option<(&'a str, FileId)> {
        let path = include_path(t);
        let from = self.sources.file(t.span.file);
        let resolved = resolve_include(&from.path, path);
        Some((path, self.sources.find_path(&resolved)?))
    }

    /// `.lib FILE SECTION`: the statements between `.lib SECTION` and `.endl`
    /// in FILE (loaded beside the includes), parsed in place.
    fn lib_section(&mut self, toks: &[Token<'a>], span: Span) -> Option<Stmt<'a>> {
        let (Some(t), Some(sect)) = (toks.get(1), toks.get(2)) else {
            self.errors.push(ParseError::Expected {
                span,
                expected: "a file and a section name after `.lib`".into(),
            });
            return None;
        };
        // The loader reported why it could not read a missing file.
        let (path, file) = self.loaded(t)?;
        let key = (file, sect.text.to_ascii_lowercase());
        if self.lib_stack.contains(&key) {
            self.errors.push(ParseError::IncludeCycle {
                span: sect.span,
                path: format!("{path} {}", sect.text),
            });
            return None;
        }
        // Lex errors count inside the section only: the rest of a library
        // is not read.
        let mut lex_errors = Vec::new();
        let lexed = lex_file(self.sources, file, false, &mut lex_errors);
        let lines = lexed.lines();
        let Some(open) = lines.iter().position(|l| {
            l.tokens.len() == 2
                && l.tokens[0].is_word(".lib")
                && l.tokens[1].text.eq_ignore_ascii_case(sect.text)
        }) else {
            self.errors.push(ParseError::LibSectionNotFound {
                span: sect.span,
                path: path.to_string(),
                section: sect.text.to_string(),
            });
            return None;
        };
        let close = lines[open + 1..]
            .iter()
            .position(|l| l.tokens[0].is_word(".endl"))
            .map(|k| open + 1 + k);
        let Some(close) = close else {
            self.errors.push(ParseError::UnclosedLib {
                span: lines[open].span(),
                section: sect.text.to_string(),
            });
            return None;
        };
        let (lo, hi) = (lines[open].span().start, lines[close].span().start);
        self.errors.extend(lex_errors.into_iter().filter(|e| {
            let s = e.span();
            s.file == file && s.start > lo && s.start < hi
        }));
        if self.too_deep(t.span, "library sections") {
            return None;
        }
        self.lib_stack.push(key);
        let mut i = 0;
        let (body, end) = self.block(&lines[open + 1..close], &mut i, false);
        if let BlockEnd::Ends(span) = end {
            self.errors.push(ParseError::StrayEnds { span });
        }
        self.lib_stack.pop();
        Some(Stmt::Include {
            path,
            section: Some(sect.text),
            span: t.span,
            body,
        })
    }

    /// `name(arg ...) [=] {expression}` of a `.func`.
    fn func_def(&mut self, c: &mut Cursor<'_, 'a>, span: Span) -> Option<FuncDef<'a>> {
        let expected = |this: &mut Self, c: &Cursor<'_, 'a>, what: &str| {
            this.errors.push(ParseError::Expected {
                span: c.here(span),
                expected: what.into(),
            });
        };
        let Some(name) = c.peek().filter(|t| t.kind == TokKind::Word).map(name_of) else {
            expected(self, c, "a function name after `.func`");
            return None;
        };
        c.next();
        if !c.eat(TokKind::LParen) {
            expected(self, c, "`(` and the argument names");
            return None;
        }
        let mut params = Vec::new();
        while let Some(t) = c.peek().filter(|t| t.kind == TokKind::Word) {
            params.push(name_of(t));
            c.next();
        }
        if !c.eat(TokKind::RParen) {
            expected(self, c, "`)` closing the argument names");
            return None;
        }
        // The lexer takes commas as separators: look between the names.
        let text = &self.sources.file(span.file).text;
        if let Some(w) = params.windows(2).find(|w| {
            let (a, b) = (w[0].span.end as usize, w[1].span.start as usize);
            text.get(a..b).is_some_and(|between| !between.contains(','))
        }) {
            self.errors.push(ParseError::FuncArgsWithoutComma {
                span: w[1].span,
                name: name.text.to_string(),
            });
        }
        c.eat(TokKind::Eq);
        if c.done() {
            expected(self, c, "the function's `{expression}`");
            return None;
        }
        let body = self.value_tok(c, name.text, "function body")?;
        Some(FuncDef {
            name,
            params,
            body,
            span,
        })
    }
}

/// Where the output item that starts at token `start` ends: tokens written
/// without a space between them, and everything inside parentheses or
/// brackets, are one item.
fn item_end(toks: &[Token<'_>], start: usize) -> usize {
    let mut depth = 0usize;
    let mut k = start;
    while k < toks.len() {
        match toks[k].kind {
            TokKind::LParen => depth += 1,
            TokKind::RParen => depth = depth.saturating_sub(1),
            _ => {}
        }
        k += 1;
        let joined = toks
            .get(k)
            .is_some_and(|n| n.span.start == toks[k - 1].span.end);
        if depth == 0 && !joined {
            break;
        }
    }
    k
}
