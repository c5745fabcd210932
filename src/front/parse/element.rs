//! Element lines: the name's letter ([`ElementLetter`]) decides how many
//! nodes follow and what comes after them; one function per element kind.
//! Elements kausal does not read are refused here, by letter.

use super::{Cursor, Parser, is_value_token, name_of};
use crate::diag::Span;
use crate::front::ast::*;
use crate::front::error::ParseError;
use crate::front::lex::{LogicalLine, TokKind, Token};

impl<'a> Parser<'a> {
    pub(super) fn element(&mut self, line: &LogicalLine<'_, 'a>) -> Option<Element<'a>> {
        let toks = &line.tokens;
        let name = name_of(&toks[0]);
        let span = line.span();
        let letter = self.letter(name)?;
        let mut c = Cursor::new(toks);
        c.next();
        let Some(mut n_nodes) = letter.n_nodes() else {
            return self.instance(&mut c, name, span);
        };
        // `E1 out 0 VALUE={…}`, `G1 out 0 cur={…}`, `F1 out 0 POLY(1) V1 0 2`:
        // a B source by another name, with two nodes.
        let controlled = matches!(
            letter,
            ElementLetter::E | ElementLetter::F | ElementLetter::G | ElementLetter::H
        );
        let expression = controlled
            && toks
                .get(3)
                .is_some_and(|t| t.is_word("value") || t.is_word("vol") || t.is_word("cur"))
            && toks.get(4).is_some_and(|t| t.kind == TokKind::Eq);
        let poly = controlled
            && toks.get(3).is_some_and(|t| t.is_word("poly"))
            && toks.get(4).is_some_and(|t| t.kind == TokKind::LParen);
        if expression || poly {
            n_nodes = 2;
        }
        // Read as a B source's nodes: these forms are not refused.
        let node_letter = if expression || poly {
            ElementLetter::B
        } else {
            letter
        };
        let nodes = self.nodes(&mut c, name, node_letter, n_nodes)?;
        if expression || poly {
            let current = matches!(letter, ElementLetter::G | ElementLetter::F);
            let body = if poly {
                self.poly(&mut c, name, letter, current, span)?
            } else {
                c.next();
                self.expression_body(&mut c, name, current)?
            };
            return Some(Element {
                name,
                letter,
                nodes,
                body,
                span,
            });
        }
        use ElementLetter::*;
        let body = match letter {
            R | C | L => self.passive(&mut c, name, letter, span)?,
            K => self.coupling(&mut c, name, span)?,
            V | I => self.source(&mut c, name, span)?,
            E | G => self.voltage_controlled(&mut c, name, span)?,
            F | H => self.current_controlled(&mut c, name, span)?,
            D => self.diode(&mut c, name, span)?,
            Q | J | M => self.device(&mut c),
            S | W => self.switch(&mut c),
            B => self.behavioural_source(&mut c, name, span)?,
            X => unreachable!("instances are read by Parser::instance"),
        };
        Some(Element {
            name,
            letter,
            nodes,
            body,
            span,
        })
    }

    /// The element's letter; an error for a letter kausal does not read.
    fn letter(&mut self, name: Name<'a>) -> Option<ElementLetter> {
        let first = name.text.chars().next().unwrap_or('?');
        if let Some(letter) = ElementLetter::from_char(first) {
            return Some(letter);
        }
        let upper = first.to_ascii_uppercase();
        self.errors.push(match unsupported_kind(upper) {
            Some(kind) => ParseError::UnsupportedElement {
                span: name.span,
                letter: upper,
                kind,
            },
            None => ParseError::UnknownElement {
                span: name.span,
                letter: first,
            },
        });
        None
    }

    /// `X1 n1 n2 sub a=1`: words up to the first `name=` or `params:`; the
    /// last is the subcircuit.
    fn instance(
        &mut self,
        c: &mut Cursor<'_, 'a>,
        name: Name<'a>,
        span: Span,
    ) -> Option<Element<'a>> {
        let mut nodes = Vec::new();
        while let Some(t) = c.peek() {
            if t.kind != TokKind::Word
                || t.is_word("params:")
                || c.peek_at(1).is_some_and(|n| n.kind == TokKind::Eq)
            {
                break;
            }
            nodes.push(name_of(t));
            c.next();
        }
        if c.peek().is_some_and(|t| t.is_word("params:")) {
            c.next();
        }
        let Some(subckt) = nodes.pop() else {
            self.errors.push(ParseError::Expected {
                span,
                expected: "nodes and a subcircuit name after the instance name".into(),
            });
            return None;
        };
        let params = self.assigns(c);
        self.rest_unexpected(c);
        Some(Element {
            name,
            letter: ElementLetter::X,
            nodes,
            body: ElementBody::Instance { subckt, params },
            span,
        })
    }

    /// The `n_nodes` nodes after the name. A behavioural form where a node
    /// or what follows the nodes should stand is refused.
    fn nodes(
        &mut self,
        c: &mut Cursor<'_, 'a>,
        name: Name<'a>,
        letter: ElementLetter,
        n_nodes: usize,
    ) -> Option<Vec<Name<'a>>> {
        let mut nodes = Vec::with_capacity(n_nodes);
        for k in 0..=n_nodes {
            if let Some(e) = behavioural(c, name, letter) {
                self.errors.push(e);
                return None;
            }
            if k == n_nodes {
                break;
            }
            match c.peek() {
                Some(t)
                    if t.kind == TokKind::Word
                        && !c.peek_at(1).is_some_and(|n| n.kind == TokKind::Eq) =>
                {
                    nodes.push(name_of(t));
                    c.next();
                }
                _ => {
                    let at = c.peek().map_or_else(
                        || {
                            let last = c.toks[c.toks.len() - 1].span;
                            Span {
                                start: last.end,
                                end: last.end + 1,
                                ..last
                            }
                        },
                        |t| t.span,
                    );
                    self.errors.push(ParseError::MissingNode {
                        span: at,
                        name: name.text.to_string(),
                        expected: n_nodes,
                        found: nodes.len(),
                    });
                    return None;
                }
            }
        }
        Some(nodes)
    }

    /// R, C, L: a value, positional or as `r=`/`c=`/`l=`, and `name=value`
    /// extras.
    fn passive(
        &mut self,
        c: &mut Cursor<'_, 'a>,
        name: Name<'a>,
        letter: ElementLetter,
        span: Span,
    ) -> Option<ElementBody<'a>> {
        let key = match letter {
            ElementLetter::R => "r",
            ElementLetter::C => "c",
            _ => "l",
        };
        let mut value = None;
        if c.peek().is_some_and(|t| t.kind != TokKind::Eq)
            && !c.peek_at(1).is_some_and(|t| t.kind == TokKind::Eq)
        {
            value = Some(self.value_tok(c, name.text, "value")?);
        }
        // A model after the value (`R1 a b 1k RMOD`), or before it
        // (`L1 a b LMOD 10m`: ngspice takes a value that is no number for a
        // model name, and a number after it for the value).
        let mut model = None;
        let not_assign = |c: &Cursor<'_, 'a>| !c.peek_at(1).is_some_and(|n| n.kind == TokKind::Eq);
        if let Some(v) = &value {
            if let Value::Ident(m) = v
                && c.peek().is_some_and(is_value_token)
                && not_assign(c)
            {
                model = Some(*m);
                value = Some(self.value_tok(c, name.text, "value")?);
            } else if let Some(&t) = c.peek()
                && t.kind == TokKind::Word
                && t.text
                    .starts_with(|ch: char| ch.is_ascii_alphabetic() || ch == '_')
                && not_assign(c)
            {
                c.next();
                model = Some(name_of(&t));
            }
        }
        let mut params = self.assigns(c);
        // A resistor's `tc=tc1 tc2`, which ngspice reads as `tc1=tc1 tc2=tc2`.
        while letter == ElementLetter::R
            && params.last().is_some_and(|a| a.name.is("tc"))
            && let Some(&t) = c.peek()
            && t.kind == TokKind::Word
            && !c.peek_at(1).is_some_and(|n| n.kind == TokKind::Eq)
        {
            let tc2 = self.value_tok(c, name.text, "tc2")?;
            params.push(Assign {
                name: Name {
                    text: "tc2",
                    span: t.span,
                },
                value: tc2,
            });
            params.extend(self.assigns(c));
        }
        self.rest_unexpected(c);
        if value.is_none()
            && let Some(i) = params.iter().position(|a| a.name.is(key))
        {
            value = Some(params.remove(i).value);
        }
        let Some(value) = value else {
            self.errors.push(ParseError::MissingValue {
                span: c.here(span),
                name: name.text.to_string(),
                what: "value",
            });
            return None;
        };
        Some(ElementBody::Passive {
            value,
            model,
            params,
        })
    }

    /// K: two inductor names and the coupling, positional or as `k=`.
    fn coupling(
        &mut self,
        c: &mut Cursor<'_, 'a>,
        name: Name<'a>,
        span: Span,
    ) -> Option<ElementBody<'a>> {
        let (Some(l1), Some(l2)) = (c.word(), c.word()) else {
            self.errors.push(ParseError::Expected {
                span: c.here(span),
                expected: "two inductor names, e.g. `K1 L1 L2 0.99`".into(),
            });
            return None;
        };
        let k = if c.peek().is_some_and(|t| t.is_word("k"))
            && c.peek_at(1).is_some_and(|t| t.kind == TokKind::Eq)
        {
            c.next();
            c.next();
            self.value_tok(c, name.text, "coupling")?
        } else {
            self.required_value(c, name, span, "coupling", "coupling coefficient")?
        };
        self.rest_unexpected(c);
        Some(ElementBody::Coupling { l1, l2, k })
    }

    /// E, G: a gain (the behavioural forms are refused).
    fn voltage_controlled(
        &mut self,
        c: &mut Cursor<'_, 'a>,
        name: Name<'a>,
        span: Span,
    ) -> Option<ElementBody<'a>> {
        if let Some(t) = c.peek()
            && (t.is_word("poly") || t.is_word("value") || t.is_word("table"))
        {
            self.errors.push(ParseError::UnsupportedSource {
                span: t.span,
                name: t.text.to_string(),
            });
            return None;
        }
        let gain = self.required_value(c, name, span, "gain", "gain")?;
        self.rest_unexpected(c);
        Some(ElementBody::VoltageControlled { gain })
    }

    /// F, H: the controlling V source and a gain.
    fn current_controlled(
        &mut self,
        c: &mut Cursor<'_, 'a>,
        name: Name<'a>,
        span: Span,
    ) -> Option<ElementBody<'a>> {
        let Some(vsrc) = c.word() else {
            self.errors.push(ParseError::Expected {
                span: c.here(span),
                expected: "the name of the controlling V source".into(),
            });
            return None;
        };
        let gain = self.required_value(c, name, span, "gain", "gain")?;
        self.rest_unexpected(c);
        Some(ElementBody::CurrentControlled { vsrc, gain })
    }

    /// D: a model name, an optional area, an optional `off`, and
    /// `name=value` extras.
    fn diode(
        &mut self,
        c: &mut Cursor<'_, 'a>,
        name: Name<'a>,
        span: Span,
    ) -> Option<ElementBody<'a>> {
        let Some(model) = c.word() else {
            self.errors.push(ParseError::MissingValue {
                span: c.here(span),
                name: name.text.to_string(),
                what: "model name",
            });
            return None;
        };
        let mut area = None;
        if let Some(t) = c.peek()
            && !c.peek_at(1).is_some_and(|n| n.kind == TokKind::Eq)
            && !t.is_word("off")
        {
            area = Some(self.value_tok(c, name.text, "area")?);
        }
        if c.peek().is_some_and(|t| t.is_word("off")) {
            c.next();
        }
        let params = self.assigns(c);
        self.rest_unexpected(c);
        Some(ElementBody::Diode {
            model,
            area,
            params,
        })
    }

    /// Q, J and M: the bare words after the terminals (up to `off` or the
    /// first `name=value`), then the `name=value`s (and `off` among them). Which word is the model is
    /// decided where models are known.
    fn device(&mut self, c: &mut Cursor<'_, 'a>) -> ElementBody<'a> {
        let words = self.bare_words(c, true);
        if c.peek().is_some_and(|t| t.is_word("off")) {
            c.next();
        }
        // `IC=VBE, VCE` (the comma is a separator): the values after the
        // first are read past, as the initial condition itself is (kausal's
        // operating point does not take it).
        let mut params = Vec::new();
        loop {
            params.extend(self.assigns(c));
            // `off` may also follow the parameters (`M1 d g s b n W=1u off`).
            if c.peek().is_some_and(|t| t.is_word("off")) {
                c.next();
                continue;
            }
            let after_ic = params.last().is_some_and(|p: &Assign<'_>| p.name.is("ic"));
            if !(after_ic && c.peek().is_some_and(is_value_token)) {
                break;
            }
            while c.peek().is_some_and(is_value_token)
                && !c.peek_at(1).is_some_and(|n| n.kind == TokKind::Eq)
            {
                c.next();
            }
        }
        self.rest_unexpected(c);
        ElementBody::Device { words, params }
    }

    /// S and W: the words after the terminals (W's controlling source, the
    /// model, `on` or `off`), then any `name=value`s.
    fn switch(&mut self, c: &mut Cursor<'_, 'a>) -> ElementBody<'a> {
        let words = self.bare_words(c, false);
        let params = self.assigns(c);
        self.rest_unexpected(c);
        ElementBody::Device { words, params }
    }

    /// The bare words up to the first `name=value` (or up to `off` when
    /// `stop_at_off`): values, or names for words that are not numbers (a
    /// model or node name that starts with a digit, `2n3904`).
    fn bare_words(&mut self, c: &mut Cursor<'_, 'a>, stop_at_off: bool) -> Vec<Value<'a>> {
        let mut words = Vec::new();
        while let Some(t) = c.peek() {
            if (stop_at_off && t.is_word("off"))
                || c.peek_at(1).is_some_and(|n| n.kind == TokKind::Eq)
            {
                break;
            }
            c.next();
            match super::value_of(t) {
                Ok(v) => words.push(v),
                Err(_) if t.kind == TokKind::Word => words.push(Value::Ident(name_of(t))),
                Err(e) => self.errors.push(e),
            }
        }
        words
    }

    /// B: `V=expr` or `I=expr`, the expression running to the end of the
    /// line, braced or not.
    fn behavioural_source(
        &mut self,
        c: &mut Cursor<'_, 'a>,
        name: Name<'a>,
        span: Span,
    ) -> Option<ElementBody<'a>> {
        let kind = c.peek().filter(|t| t.is_word("v") || t.is_word("i"));
        let (Some(kind), Some(_)) = (kind, c.peek_at(1).filter(|t| t.kind == TokKind::Eq)) else {
            self.errors.push(ParseError::Expected {
                span: c.here(span),
                expected: format!(
                    "`V=expression` or `I=expression` after the nodes of {}",
                    name.text
                ),
            });
            return None;
        };
        let current = kind.is_word("i");
        c.next();
        self.expression_body(c, name, current)
    }

    /// `POLY(n)`, the `n` controls (node pairs for E and G, V sources for F
    /// and H) and the coefficients, as SPICE orders them: the constant, the
    /// linear terms, then each higher degree's products `x_i·x_j·…` with
    /// `i ≤ j ≤ …` in lexicographic order. A single coefficient is the
    /// constant, as ngspice reads it (SPICE2 took it as the gain).
    fn poly(
        &mut self,
        c: &mut Cursor<'_, 'a>,
        name: Name<'a>,
        letter: ElementLetter,
        current: bool,
        span: Span,
    ) -> Option<ElementBody<'a>> {
        use crate::front::expr::{BinOp, PExpr};
        let head = *c.next()?;
        c.next();
        let dims = c.word().and_then(|w| w.text.parse::<usize>().ok());
        let close = c.eat(TokKind::RParen);
        let Some(dims) = dims.filter(|&n| close && (1..=8).contains(&n)) else {
            self.errors.push(ParseError::Expected {
                span: head.span,
                expected: "`POLY(n)` with n from 1 to 8 controls".into(),
            });
            return None;
        };
        let by_nodes = matches!(letter, ElementLetter::E | ElementLetter::G);
        let mut xs = Vec::with_capacity(dims);
        for _ in 0..dims {
            // `(3,0)`: a pair may be parenthesized.
            c.eat(TokKind::LParen);
            let pair = if by_nodes {
                c.word().zip(c.word())
            } else {
                c.word().map(|a| (a, a))
            };
            let Some((a, b)) = pair else {
                self.errors.push(ParseError::Expected {
                    span: c.here(span),
                    expected: format!(
                        "the {dims} {} of `POLY({dims})`",
                        if by_nodes {
                            "controlling node pairs"
                        } else {
                            "controlling V sources"
                        }
                    ),
                });
                return None;
            };
            c.eat(TokKind::RParen);
            xs.push(PExpr::Probe {
                current: !by_nodes,
                args: if by_nodes {
                    vec![a.text.to_string(), b.text.to_string()]
                } else {
                    vec![a.text.to_string()]
                },
            });
        }
        let mut coeffs = Vec::new();
        while let Some(t) = c.peek() {
            if matches!(t.kind, TokKind::LParen | TokKind::RParen) {
                c.next();
                continue;
            }
            if t.kind == TokKind::Word && c.peek_at(1).is_some_and(|n| n.kind == TokKind::Eq) {
                break;
            }
            coeffs.push(match self.value_tok(c, name.text, "coefficient")? {
                Value::Num { value, .. } => PExpr::Num(value),
                Value::Expr { expr, .. } => *expr,
                Value::Ident(n) => PExpr::Ident(n.key()),
            });
        }
        self.rest_unexpected(c);
        if coeffs.is_empty() {
            self.errors.push(ParseError::MissingValue {
                span: c.here(span),
                name: name.text.to_string(),
                what: "polynomial coefficients",
            });
            return None;
        }
        // The monomials in SPICE's order, as lists of control indices.
        let mut monomials: Vec<Vec<usize>> = vec![Vec::new()];
        let mut degree: Vec<Vec<usize>> = vec![Vec::new()];
        while monomials.len() < coeffs.len() {
            let mut next = Vec::new();
            for m in &degree {
                for i in m.last().copied().unwrap_or(0)..dims {
                    let mut n = m.clone();
                    n.push(i);
                    next.push(n);
                }
            }
            monomials.extend(next.iter().cloned());
            degree = next;
        }
        let bin = |op, a, b| PExpr::Bin(op, Box::new(a), Box::new(b));
        let mut sum: Option<PExpr> = None;
        for (k, m) in monomials.iter().zip(coeffs) {
            if m == PExpr::Num(0.0) {
                continue;
            }
            let term = k
                .iter()
                .fold(m, |acc, &i| bin(BinOp::Mul, acc, xs[i].clone()));
            sum = Some(match sum {
                None => term,
                Some(s) => bin(BinOp::Add, s, term),
            });
        }
        let expr = sum.unwrap_or(PExpr::Num(0.0));
        Some(ElementBody::Behavioural {
            current,
            text: expr.to_string(),
            expr: Box::new(expr),
            span: head.span.to(c.toks[c.toks.len() - 1].span),
        })
    }

    /// After `V`, `I` or `VALUE` (at the `=`): the expression to the end of
    /// the line, braced or not.
    fn expression_body(
        &mut self,
        c: &mut Cursor<'_, 'a>,
        name: Name<'a>,
        current: bool,
    ) -> Option<ElementBody<'a>> {
        let eq = *c.next()?;
        let toks = &c.toks[c.pos..];
        c.pos = c.toks.len();
        if toks.is_empty() {
            self.errors.push(ParseError::MissingValue {
                span: Span {
                    start: eq.span.end,
                    end: eq.span.end + 1,
                    ..eq.span
                },
                name: name.text.to_string(),
                what: "expression",
            });
            return None;
        }
        // The expression's text, and where each piece of it starts in the
        // file (for carets).
        let file_text = self.sources.file(eq.span.file).text.as_str();
        let mut text = String::new();
        let mut pieces: Vec<(usize, usize)> = Vec::with_capacity(toks.len());
        for (k, t) in toks.iter().enumerate() {
            if k > 0 {
                let gap = &file_text[toks[k - 1].span.end as usize..t.span.start as usize];
                if gap.contains('\n') {
                    text.push(' ');
                } else {
                    text.push_str(gap);
                }
            }
            if t.kind == TokKind::Expr && toks.len() == 1 {
                // `V={…}`: the braces' content as it is.
                pieces.push((text.len(), t.span.start as usize + 1));
                text.push_str(t.text);
            } else if t.kind == TokKind::Expr {
                pieces.push((text.len(), t.span.start as usize));
                text.push('(');
                text.push_str(t.text);
                text.push(')');
            } else {
                pieces.push((text.len(), t.span.start as usize));
                text.push_str(t.text);
            }
        }
        let whole = toks[0].span.to(toks[toks.len() - 1].span);
        let at_offset = |k: usize| {
            let (from, pos) = pieces
                .iter()
                .rev()
                .find(|p| p.0 <= k)
                .copied()
                .unwrap_or((0, whole.start as usize));
            let start = (pos + (k - from)).min(whole.end as usize - 1);
            Span::new(whole.file, start, start + 1)
        };
        if let Some((k, why)) = crate::front::expr::too_complex(&text) {
            self.errors.push(ParseError::ComplexExpression {
                span: at_offset(k),
                why,
            });
            return None;
        }
        match crate::front::expr::parse_expr(&text) {
            Ok(expr) => Some(ElementBody::Behavioural {
                current,
                expr: Box::new(expr),
                text,
                span: whole,
            }),
            Err(k) => {
                self.errors.push(ParseError::BadExpression {
                    span: at_offset(k.min(text.len().saturating_sub(1))),
                    text,
                });
                None
            }
        }
    }

    /// The value at the cursor (`what` in a malformed value's error), or a
    /// missing-value error naming `missing` at the end of the line.
    fn required_value(
        &mut self,
        c: &mut Cursor<'_, 'a>,
        name: Name<'a>,
        span: Span,
        what: &'static str,
        missing: &'static str,
    ) -> Option<Value<'a>> {
        if c.peek().is_none() {
            self.errors.push(ParseError::MissingValue {
                span: c.here(span),
                name: name.text.to_string(),
                what: missing,
            });
            return None;
        }
        self.value_tok(c, name.text, what)
    }
}

/// `E1 out 0 VALUE={...}`, `F1 out 0 POLY(2) ...`: ngspice's behavioural
/// forms of E, F, G and H, where a linear source has its nodes or gain.
fn behavioural<'a>(
    c: &Cursor<'_, 'a>,
    name: Name<'a>,
    letter: ElementLetter,
) -> Option<ParseError> {
    use ElementLetter::*;
    let t = c.peek().filter(|_| matches!(letter, E | F | G | H))?;
    let form = ["value", "poly", "table", "laplace", "vol", "cur"]
        .iter()
        .any(|w| t.is_word(w))
        && c.peek_at(1)
            .is_some_and(|n| matches!(n.kind, TokKind::Eq | TokKind::LParen | TokKind::Expr));
    form.then(|| ParseError::BehavioralSource {
        span: t.span,
        name: name.text.to_string(),
        form: t.text.to_ascii_uppercase(),
    })
}

/// The transient function a word names (`PULSE`, `SIN`, `EXP`, `PWL`,
/// `SFFM`).
fn tran_kind(t: &Token<'_>) -> Option<TranFnKind> {
    if t.is_word("pulse") {
        Some(TranFnKind::Pulse)
    } else if t.is_word("sin") || t.is_word("sine") {
        Some(TranFnKind::Sin)
    } else if t.is_word("exp") {
        Some(TranFnKind::Exp)
    } else if t.is_word("pwl") {
        Some(TranFnKind::Pwl)
    } else if t.is_word("sffm") {
        Some(TranFnKind::Sffm)
    } else {
        None
    }
}

impl<'a> Parser<'a> {
    /// V, I: `DC value` or a bare value, `AC mag [phase]`, and at most one
    /// transient function.
    fn source(
        &mut self,
        c: &mut Cursor<'_, 'a>,
        name: Name<'a>,
        span: Span,
    ) -> Option<ElementBody<'a>> {
        let mut dc = None;
        let mut tran: Option<TranFn<'a>> = None;
        let mut ac = Vec::new();
        while let Some(t) = c.peek() {
            if t.is_word("dc") {
                c.next();
                // `DC value` or ngspice's `dc=value`.
                c.eat(TokKind::Eq);
                if c.peek().is_some_and(|t| t.kind != TokKind::Eq) {
                    dc = Some(self.value_tok(c, name.text, "DC value")?);
                }
                continue;
            }
            // `(PULSE 0 1 …)`: ngspice reads parentheses on a source line
            // as separators, so a function may stand inside them.
            if t.kind == TokKind::LParen && c.peek_at(1).is_some_and(|f| tran_kind(f).is_some()) {
                c.next();
                let f = c.peek().expect("the function word");
                let (kind, start) = (tran_kind(f).expect("a function"), f.span);
                c.next();
                let (args, _) = self.tran_args(c, name, span, kind, start)?;
                let Some(close) = c.peek().filter(|t| t.kind == TokKind::RParen) else {
                    self.errors.push(ParseError::Expected {
                        span: c.here(span),
                        expected: format!("`)` closing `({}`", kind.name()),
                    });
                    return None;
                };
                c.next();
                self.second_tran(&tran, start);
                tran = Some(TranFn {
                    kind,
                    args,
                    repeat: None,
                    delay: None,
                    span: start.to(close.span),
                });
                continue;
            }
            if t.is_word("ac") {
                c.next();
                for _ in 0..2 {
                    match c.peek() {
                        Some(v) if is_value_token(v) => {
                            ac.push(self.value_tok(c, name.text, "AC value")?)
                        }
                        _ => break,
                    }
                }
                continue;
            }
            if let Some(kind) = tran_kind(t) {
                let start = t.span;
                c.next();
                let (args, end) = self.tran_args(c, name, span, kind, start)?;
                self.second_tran(&tran, start);
                let (repeat, delay, end) = self.pwl_options(c, name, kind, end)?;
                tran = Some(TranFn {
                    kind,
                    args,
                    repeat,
                    delay,
                    span: start.to(end),
                });
                continue;
            }
            if ["am", "trnoise", "trrandom", "pat", "distof1", "distof2"]
                .iter()
                .any(|w| t.is_word(w))
            {
                self.errors.push(ParseError::UnsupportedSource {
                    span: t.span,
                    name: t.text.to_string(),
                });
                return None;
            }
            if is_value_token(t) && dc.is_none() {
                dc = Some(self.value_tok(c, name.text, "value")?);
                continue;
            }
            self.errors.push(ParseError::Unexpected {
                span: t.span,
                what: format!("`{}` in a source", t.text),
            });
            return None;
        }
        Some(ElementBody::Source { dc, tran, ac })
    }

    /// An error at the keyword `at` of a transient function where the
    /// source has one already.
    fn second_tran(&mut self, tran: &Option<TranFn<'a>>, at: Span) {
        if tran.is_some() {
            self.errors.push(ParseError::Unexpected {
                span: at,
                what: "second transient function".into(),
            });
        }
    }

    /// The arguments of a transient function whose keyword (at `start`) was
    /// read, in parentheses or bare; and where they end.
    fn tran_args(
        &mut self,
        c: &mut Cursor<'_, 'a>,
        name: Name<'a>,
        span: Span,
        kind: TranFnKind,
        start: Span,
    ) -> Option<(Vec<Value<'a>>, Span)> {
        let paren = c.eat(TokKind::LParen);
        let mut args = Vec::new();
        while let Some(a) = c.peek() {
            if a.kind == TokKind::RParen || (!paren && !is_value_token(a)) {
                break;
            }
            args.push(self.value_tok(c, name.text, "source argument")?);
        }
        let mut end = args.last().map_or(start, |a| a.span());
        if paren {
            match c.peek() {
                Some(t) if t.kind == TokKind::RParen => {
                    end = t.span;
                    c.next();
                }
                _ => {
                    self.errors.push(ParseError::Expected {
                        span: c.here(span),
                        expected: format!("`)` closing `{}(`", kind.name()),
                    });
                    return None;
                }
            }
        }
        Some((args, end))
    }

    /// PWL's `r=value` and `td=value`, in either order, after its
    /// arguments (ending at `end`): repeat, delay, and where they end.
    fn pwl_options(
        &mut self,
        c: &mut Cursor<'_, 'a>,
        name: Name<'a>,
        kind: TranFnKind,
        mut end: Span,
    ) -> Option<(Option<Value<'a>>, Option<Value<'a>>, Span)> {
        let (mut repeat, mut delay) = (None, None);
        while kind == TranFnKind::Pwl
            && let (Some(n), Some(eq)) = (c.peek(), c.peek_at(1))
            && eq.kind == TokKind::Eq
            && (n.is_word("r") || n.is_word("td"))
        {
            let n = *n;
            c.next();
            c.next();
            let v = self.value_tok(c, name.text, "PWL option")?;
            end = v.span();
            if n.is_word("r") {
                repeat = Some(v);
            } else {
                delay = Some(v);
            }
        }
        Some((repeat, delay, end))
    }
}
