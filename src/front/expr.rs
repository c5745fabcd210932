//! Numbers with engineering suffixes and `{…}` parameter expressions (nom).

use nom::IResult;
use nom::Parser;
use nom::branch::alt;
use nom::bytes::complete::{tag, take_while, take_while1};
use nom::character::complete::char;
use nom::combinator::{opt, recognize, value};
use nom::multi::separated_list0;
use nom::number::complete::recognize_float;
use nom::sequence::{delimited, pair, preceded};

use crate::ir::Cmp;

/// A parameter expression, as written (names lower-cased).
#[derive(Clone, Debug, PartialEq)]
pub enum PExpr {
    Num(f64),
    Ident(String),
    Neg(Box<PExpr>),
    Bin(BinOp, Box<PExpr>, Box<PExpr>),
    Call(String, Vec<PExpr>),
    /// `!a`: 1 where `a` is 0, else 0.
    Not(Box<PExpr>),
    /// `c ? a : b`.
    Ternary(Box<PExpr>, Box<PExpr>, Box<PExpr>),
    /// `v(node)`, `v(node, node)` or `i(vsource)` (behavioural sources
    /// only): the names as written.
    Probe {
        current: bool,
        args: Vec<String>,
    },
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BinOp {
    Add,
    Sub,
    Mul,
    Div,
    Pow,
    /// A comparison: 1 where it holds, else 0 (the IR's own operation).
    Cmp(Cmp),
    And,
    Or,
}

impl BinOp {
    fn symbol(self) -> &'static str {
        match self {
            BinOp::Add => "+",
            BinOp::Sub => "-",
            BinOp::Mul => "*",
            BinOp::Div => "/",
            BinOp::Pow => "**",
            BinOp::Cmp(c) => c.symbol(),
            BinOp::And => "&&",
            BinOp::Or => "||",
        }
    }

    /// The operator applied to values (comparisons and logic give 1 or 0).
    pub fn apply(self, a: f64, b: f64) -> f64 {
        let truth = |x: bool| if x { 1.0 } else { 0.0 };
        match self {
            BinOp::Add => a + b,
            BinOp::Sub => a - b,
            BinOp::Mul => a * b,
            BinOp::Div => a / b,
            BinOp::Pow => a.powf(b),
            BinOp::Cmp(c) => c.apply(a, b),
            BinOp::And => truth(a != 0.0 && b != 0.0),
            BinOp::Or => truth(a != 0.0 || b != 0.0),
        }
    }
}

/// The scale of an engineering suffix (`k`, `meg`, `mil`, ...), and how many
/// bytes of the suffix were consumed; trailing unit letters are allowed.
fn suffix_scale(s: &str) -> Option<f64> {
    let lower = s.to_ascii_lowercase();
    if !lower.chars().all(|c| c.is_ascii_alphabetic()) {
        return None;
    }
    let scale = if lower.starts_with("meg") {
        1e6
    } else if lower.starts_with("mil") {
        25.4e-6
    } else {
        match lower.chars().next() {
            None => 1.0,
            Some('f') => 1e-15,
            Some('p') => 1e-12,
            Some('n') => 1e-9,
            Some('u') => 1e-6,
            Some('m') => 1e-3,
            Some('k') => 1e3,
            Some('g') => 1e9,
            Some('t') => 1e12,
            Some(_) => 1.0,
        }
    };
    Some(scale)
}

fn number_with_suffix(input: &str) -> IResult<&str, f64> {
    let (rest, digits) = recognize_float(input)?;
    let (rest, suffix) = take_while(|c: char| c.is_ascii_alphabetic()).parse(rest)?;
    let mantissa: f64 = digits.parse().map_err(|_| {
        nom::Err::Error(nom::error::Error::new(input, nom::error::ErrorKind::Float))
    })?;
    let scale = suffix_scale(suffix).unwrap_or(1.0);
    Ok((rest, mantissa * scale))
}

/// Parse a whole token as a SPICE number: `10`, `1.5e-3`, `10uF`, `1kOhm`, `3meg`.
pub fn parse_number(s: &str) -> Option<f64> {
    if !s.starts_with(|c: char| c.is_ascii_digit() || matches!(c, '.' | '-' | '+')) {
        return None;
    }
    match number_with_suffix(s) {
        Ok(("", v)) if v.is_finite() => Some(v),
        _ => None,
    }
}

/// A resistor's value in ngspice's RKM notation (`4k7` is 4.7k, `4R7` 4.7,
/// `1meg5` 1.5 meg): the digits after the scale letter are the fraction, as
/// ngspice's `INPevaluateRKM_R` reads them (the letters T, G, K, U, R, N, P,
/// M or MEG, L; `R` only followed by digits to the end; what follows the
/// digits is ignored, as a unit is), which it does only in its LTspice
/// compatibility mode; kausal reads it only to say so in the error. `None`
/// where the token is not of that form.
pub fn parse_rkm(s: &str) -> Option<f64> {
    let (rest, head) = recognize_float::<_, nom::error::Error<&str>>(s).ok()?;
    let lower = rest.to_ascii_lowercase();
    let (scale, letters) = if lower.starts_with("meg") {
        (1e6, 3)
    } else {
        match lower.as_bytes().first()? {
            b'r' => (1.0, 1),
            b'l' => (1e-3, 1),
            b't' | b'g' | b'k' | b'u' | b'n' | b'p' | b'm' => (suffix_scale(&lower[..1])?, 1),
            _ => return None,
        }
    };
    let tail = &rest[letters..];
    let n = tail.bytes().take_while(u8::is_ascii_digit).count();
    if n == 0 || (letters == 1 && scale == 1.0 && n != tail.len()) {
        return None;
    }
    let head: f64 = head.parse().ok()?;
    let fraction = tail[..n].parse::<f64>().ok()? * 10f64.powi(-(n as i32));
    let value = (head + fraction.copysign(head)) * scale;
    value.is_finite().then_some(value)
}

/// White space, also where the expression goes on over a `+` continuation
/// line (the lexer hands over such an expression as written, with the line
/// breaks, the `+` and any comment lines between).
fn space(input: &str) -> IResult<&str, &str> {
    let mut rest = input;
    loop {
        let t = rest.trim_start_matches(|c: char| c.is_whitespace() && c != '\n');
        let Some(after) = t.strip_prefix('\n') else {
            rest = t;
            break;
        };
        let line = after.trim_start_matches([' ', '\t', '\r']);
        rest = match line.strip_prefix('+') {
            Some(r) => r,
            None if line.starts_with('*') => &line[line.find('\n').unwrap_or(line.len())..],
            None => line,
        };
    }
    Ok((rest, &input[..input.len() - rest.len()]))
}

fn ws<'a, O>(
    p: impl Parser<&'a str, Output = O, Error = nom::error::Error<&'a str>>,
) -> impl Parser<&'a str, Output = O, Error = nom::error::Error<&'a str>> {
    delimited(space, p, space)
}

fn ident(input: &str) -> IResult<&str, &str> {
    recognize(pair(
        take_while1(|c: char| c.is_ascii_alphabetic() || c == '_'),
        take_while(|c: char| c.is_ascii_alphanumeric() || c == '_' || c == '.'),
    ))
    .parse(input)
}

/// `v(a)`, `v(a, b)`, `i(v1)`: node and element names are not
/// expressions (`v(1)` names node 1), so they are read as raw words.
fn probe(input: &str) -> IResult<&str, PExpr> {
    let (i, letter) = alt((char('v'), char('V'), char('i'), char('I'))).parse(input)?;
    let name = |i| take_while1(|c: char| !(c.is_whitespace() || matches!(c, ',' | '(' | ')')))(i);
    let (i, args) = delimited(
        ws(char('(')),
        separated_list0(ws(char(',')), name),
        ws(char(')')),
    )
    .parse(i)?;
    let current = letter.eq_ignore_ascii_case(&'i');
    if args.is_empty() || args.len() > 2 || (current && args.len() != 1) {
        return Err(nom::Err::Error(nom::error::Error::new(
            input,
            nom::error::ErrorKind::Verify,
        )));
    }
    Ok((
        i,
        PExpr::Probe {
            current,
            args: args.into_iter().map(str::to_string).collect(),
        },
    ))
}

fn atom(input: &str) -> IResult<&str, PExpr> {
    ws(alt((
        |i| {
            let (i, v) = number_with_suffix(i)?;
            Ok((i, PExpr::Num(v)))
        },
        probe,
        |i| {
            let (i, name) = ident(i)?;
            let (i, args) = opt(delimited(
                ws(char('(')),
                separated_list0(ws(char(',')), ternary),
                ws(char(')')),
            ))
            .parse(i)?;
            let name = name.to_ascii_lowercase();
            Ok((
                i,
                match args {
                    Some(args) => PExpr::Call(name, args),
                    None => PExpr::Ident(name),
                },
            ))
        },
        delimited(ws(char('(')), ternary, ws(char(')'))),
        // Braces nested in an expression group as parentheses do
        // (PSpice's `{a > {b}}`, which ngspice reads so).
        delimited(ws(char('{')), ternary, ws(char('}'))),
    )))
    .parse(input)
}

fn power(input: &str) -> IResult<&str, PExpr> {
    let (i, base) = atom(input)?;
    let (i, exp) = opt(preceded(ws(alt((tag("**"), tag("^")))), unary)).parse(i)?;
    Ok((
        i,
        match exp {
            Some(e) => PExpr::Bin(BinOp::Pow, Box::new(base), Box::new(e)),
            None => base,
        },
    ))
}

fn unary(input: &str) -> IResult<&str, PExpr> {
    alt((
        |i| {
            let (i, e) = preceded(ws(char('-')), unary).parse(i)?;
            Ok((i, PExpr::Neg(Box::new(e))))
        },
        preceded(ws(char('+')), unary),
        |i| {
            // `!` but not `!=`; PSpice's `~` is `!` too (ngspice's PSpice
            // mode reads it so).
            let (i, _) = ws(alt((char('!'), char('~')))).parse(i)?;
            if i.starts_with('=') {
                return Err(nom::Err::Error(nom::error::Error::new(
                    i,
                    nom::error::ErrorKind::Char,
                )));
            }
            let (i, e) = unary(i)?;
            Ok((i, PExpr::Not(Box::new(e))))
        },
        power,
    ))
    .parse(input)
}

fn mul_op(i: &str) -> IResult<&str, BinOp> {
    let (i, _) = char('*')(i)?;
    // `**` is power, handled below `unary`.
    if i.starts_with('*') {
        return Err(nom::Err::Error(nom::error::Error::new(
            i,
            nom::error::ErrorKind::Char,
        )));
    }
    Ok((i, BinOp::Mul))
}

fn product(input: &str) -> IResult<&str, PExpr> {
    let (mut i, mut acc) = unary(input)?;
    loop {
        let op = ws(alt((mul_op, |i| {
            char('/')(i).map(|(i, _)| (i, BinOp::Div))
        })))
        .parse(i);
        match op {
            Ok((r, op)) => {
                let (r, rhs) = unary(r)?;
                acc = PExpr::Bin(op, Box::new(acc), Box::new(rhs));
                i = r;
            }
            Err(_) => return Ok((i, acc)),
        }
    }
}

fn sum(input: &str) -> IResult<&str, PExpr> {
    let (mut i, mut acc) = product(input)?;
    loop {
        let op = ws(alt((
            |i| char('+')(i).map(|(i, _)| (i, BinOp::Add)),
            |i| char('-')(i).map(|(i, _)| (i, BinOp::Sub)),
        )))
        .parse(i);
        match op {
            Ok((r, op)) => {
                let (r, rhs) = product(r)?;
                acc = PExpr::Bin(op, Box::new(acc), Box::new(rhs));
                i = r;
            }
            Err(_) => return Ok((i, acc)),
        }
    }
}

fn comparison(input: &str) -> IResult<&str, PExpr> {
    let (i, a) = sum(input)?;
    let op = ws(alt((
        value(Cmp::Le, tag("<=")),
        value(Cmp::Ge, tag(">=")),
        value(Cmp::Eq, tag("==")),
        value(Cmp::Ne, tag("!=")),
        value(Cmp::Ne, tag("<>")),
        value(Cmp::Lt, tag("<")),
        value(Cmp::Gt, tag(">")),
    )))
    .parse(i);
    match op {
        Ok((r, op)) => {
            let (r, b) = sum(r)?;
            Ok((r, PExpr::Bin(BinOp::Cmp(op), Box::new(a), Box::new(b))))
        }
        Err(_) => Ok((i, a)),
    }
}

/// A left-associative chain of `op` over `item`, written `token` or, as
/// PSpice writes it and ngspice's PSpice mode reads it, its first half
/// (`&` for `&&`, `|` for `||`).
fn chain<'a>(
    input: &'a str,
    item: fn(&str) -> IResult<&str, PExpr>,
    token: &'static str,
    op: BinOp,
) -> IResult<&'a str, PExpr> {
    let (mut i, mut acc) = item(input)?;
    while let Ok((r, _)) = ws(alt((tag(token), tag(&token[..1])))).parse(i) {
        let (r, rhs) = item(r)?;
        acc = PExpr::Bin(op, Box::new(acc), Box::new(rhs));
        i = r;
    }
    Ok((i, acc))
}

fn conjunction(input: &str) -> IResult<&str, PExpr> {
    chain(input, comparison, "&&", BinOp::And)
}

fn disjunction(input: &str) -> IResult<&str, PExpr> {
    chain(input, conjunction, "||", BinOp::Or)
}

/// `c ? a : b` (right-associative), the loosest binding.
fn ternary(input: &str) -> IResult<&str, PExpr> {
    let (i, c) = disjunction(input)?;
    match ws(char('?')).parse(i) {
        Ok((r, _)) => {
            let (r, a) = ternary(r)?;
            let (r, _) = ws(char(':')).parse(r)?;
            let (r, b) = ternary(r)?;
            Ok((r, PExpr::Ternary(Box::new(c), Box::new(a), Box::new(b))))
        }
        Err(_) => Ok((i, c)),
    }
}

/// Nested parentheses an expression may have (see [`too_complex`]).
pub const MAX_NESTING: usize = 64;
/// Operators an expression may have (see [`too_complex`]).
pub const MAX_OPERATORS: usize = 1000;

/// Where `s` first has more than [`MAX_NESTING`] nested parentheses or
/// [`MAX_OPERATORS`] operators, and which: parsing, evaluating, printing
/// and dropping an expression recurse over its tree, whose depth these
/// bound (a 10^5-term sum would overflow the stack).
pub fn too_complex(s: &str) -> Option<(usize, String)> {
    let (mut depth, mut ops) = (0usize, 0usize);
    for (k, c) in s.char_indices() {
        match c {
            '(' => {
                depth += 1;
                if depth > MAX_NESTING {
                    return Some((k, format!("more than {MAX_NESTING} nested parentheses")));
                }
            }
            ')' => depth = depth.saturating_sub(1),
            '+' | '-' | '*' | '/' | '^' | ',' | '<' | '>' | '=' | '!' | '&' | '|' | '?' => {
                ops += 1;
                if ops > MAX_OPERATORS {
                    return Some((k, format!("more than {MAX_OPERATORS} operators")));
                }
            }
            _ => {}
        }
    }
    None
}

/// Parse a whole parameter expression; on failure, the byte offset where
/// parsing stopped. The caller checks [`too_complex`] first.
pub fn parse_expr(s: &str) -> Result<PExpr, usize> {
    match ternary(s) {
        Ok((rest, e)) if space(rest).is_ok_and(|(r, _)| r.is_empty()) => Ok(e),
        Ok((rest, _)) => Err(s.len() - rest.len()),
        Err(nom::Err::Error(e) | nom::Err::Failure(e)) => Err(s.len() - e.input.len()),
        Err(nom::Err::Incomplete(_)) => Err(s.len()),
    }
}

/// Why an expression could not be evaluated.
#[derive(Clone, Debug, PartialEq)]
pub enum EvalError {
    Undefined(String),
    UnknownFunction(String),
    Arity(String, usize),
    NotFinite,
    /// A `.func` that calls itself, directly or not.
    Recursive(String),
    /// `.func`s that call each other more deeply than the evaluator allows.
    TooDeep(String),
    /// `.func`s that call each other more than 10^5 times in one expression.
    TooManyCalls,
    /// A node voltage or branch current (`v(a)`), which only a behavioural
    /// source can read.
    Probe(String),
}

/// A user function (`.func`) as the evaluator calls it: `None` when `name`
/// is not one, else its value at `args`.
pub type UserCall<'c> = &'c dyn Fn(&str, &[f64]) -> Option<Result<f64, EvalError>>;

impl PExpr {
    /// Evaluate with `lookup` for parameter names.
    pub fn eval(&self, lookup: &dyn Fn(&str) -> Option<f64>) -> Result<f64, EvalError> {
        self.eval_with(lookup, &|_, _| None)
    }

    /// Evaluate with `lookup` for parameter names and `user` for functions
    /// defined by `.func` (tried before the built-in ones).
    pub fn eval_with(
        &self,
        lookup: &dyn Fn(&str) -> Option<f64>,
        user: UserCall<'_>,
    ) -> Result<f64, EvalError> {
        let v = match self {
            PExpr::Num(x) => *x,
            PExpr::Ident(name) => match lookup(name) {
                Some(v) => v,
                None => match name.as_str() {
                    "pi" => std::f64::consts::PI,
                    "e" => std::f64::consts::E,
                    _ => return Err(EvalError::Undefined(name.clone())),
                },
            },
            PExpr::Neg(a) => -a.eval_with(lookup, user)?,
            PExpr::Bin(op, a, b) => {
                let (a, b) = (a.eval_with(lookup, user)?, b.eval_with(lookup, user)?);
                op.apply(a, b)
            }
            PExpr::Not(a) => {
                if a.eval_with(lookup, user)? == 0.0 {
                    1.0
                } else {
                    0.0
                }
            }
            PExpr::Ternary(c, a, b) => {
                if c.eval_with(lookup, user)? != 0.0 {
                    a.eval_with(lookup, user)?
                } else {
                    b.eval_with(lookup, user)?
                }
            }
            PExpr::Probe { .. } => return Err(EvalError::Probe(self.to_string())),
            PExpr::Call(name, args) if name == "if" && args.len() == 3 => {
                if args[0].eval_with(lookup, user)? != 0.0 {
                    args[1].eval_with(lookup, user)?
                } else {
                    args[2].eval_with(lookup, user)?
                }
            }
            PExpr::Call(name, args) => {
                let vals = args
                    .iter()
                    .map(|a| a.eval_with(lookup, user))
                    .collect::<Result<Vec<_>, _>>()?;
                if let Some(v) = user(name, &vals) {
                    v?
                } else {
                    Self::builtin(name, &vals)?
                }
            }
        };
        if v.is_finite() {
            Ok(v)
        } else {
            Err(EvalError::NotFinite)
        }
    }

    /// A built-in function of `vals`.
    fn builtin(name: &str, vals: &[f64]) -> Result<f64, EvalError> {
        let one = |f: fn(f64) -> f64| -> Result<f64, EvalError> {
            match vals {
                [x] => Ok(f(*x)),
                _ => Err(EvalError::Arity(name.to_string(), 1)),
            }
        };
        let two = |f: fn(f64, f64) -> f64| -> Result<f64, EvalError> {
            match vals {
                [x, y] => Ok(f(*x, *y)),
                _ => Err(EvalError::Arity(name.to_string(), 2)),
            }
        };
        match name {
            "sqrt" => one(f64::sqrt),
            "exp" => one(f64::exp),
            "log" | "ln" => one(f64::ln),
            "log10" => one(f64::log10),
            "sin" => one(f64::sin),
            "cos" => one(f64::cos),
            "tan" => one(f64::tan),
            "atan" => one(f64::atan),
            "asin" => one(f64::asin),
            "acos" => one(f64::acos),
            "sinh" => one(f64::sinh),
            "cosh" => one(f64::cosh),
            "tanh" => one(f64::tanh),
            "abs" => one(f64::abs),
            "floor" => one(f64::floor),
            "ceil" => one(f64::ceil),
            "int" => one(f64::trunc),
            "pow" | "pwr" => two(f64::powf),
            "min" => two(f64::min),
            "max" => two(f64::max),
            "atan2" => two(f64::atan2),
            "u" => one(|x| {
                if x > 0.0 {
                    1.0
                } else if x < 0.0 {
                    0.0
                } else {
                    0.5
                }
            }),
            "uramp" => one(|x| x.max(0.0)),
            "sgn" => one(|x| {
                if x > 0.0 {
                    1.0
                } else if x < 0.0 {
                    -1.0
                } else {
                    0.0
                }
            }),
            _ => Err(EvalError::UnknownFunction(name.to_string())),
        }
    }

    /// The parameter names this expression reads.
    pub fn idents<'s>(&'s self, out: &mut Vec<&'s str>) {
        match self {
            PExpr::Num(_) | PExpr::Probe { .. } => {}
            PExpr::Ident(n) => out.push(n),
            PExpr::Neg(a) | PExpr::Not(a) => a.idents(out),
            PExpr::Bin(_, a, b) => {
                a.idents(out);
                b.idents(out);
            }
            PExpr::Ternary(c, a, b) => {
                c.idents(out);
                a.idents(out);
                b.idents(out);
            }
            PExpr::Call(_, args) => args.iter().for_each(|a| a.idents(out)),
        }
    }
}

impl std::fmt::Display for PExpr {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PExpr::Num(x) => write!(f, "{x:e}"),
            PExpr::Ident(n) => f.write_str(n),
            PExpr::Neg(a) => write!(f, "-({a})"),
            PExpr::Not(a) => write!(f, "!({a})"),
            PExpr::Bin(op, a, b) => write!(f, "({a}){}({b})", op.symbol()),
            PExpr::Ternary(c, a, b) => write!(f, "({c}) ? ({a}) : ({b})"),
            PExpr::Probe { current, args } => {
                write!(
                    f,
                    "{}({})",
                    if *current { 'i' } else { 'v' },
                    args.join(", ")
                )
            }
            PExpr::Call(n, args) => {
                write!(f, "{n}(")?;
                for (i, a) in args.iter().enumerate() {
                    if i > 0 {
                        f.write_str(", ")?;
                    }
                    write!(f, "{a}")?;
                }
                f.write_str(")")
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// RKM values as ngspice reads a resistor's in its LTspice mode (its
    /// RKM-R-1 example), and what is not one.
    #[test]
    fn rkm_values_read_as_ngspice_reads_them() {
        let close = |a: Option<f64>, b: f64| a.is_some_and(|a| (a - b).abs() <= 1e-12 * b.abs());
        for (text, value) in [
            ("4K7", 4.7e3),
            ("4R7", 4.7),
            ("47K3", 47.3e3),
            ("4Meg7", 4.7e6),
            ("4L7", 4.7e-3),
            ("4M7", 4.7e-3),
            ("-2k2", -2.2e3),
            ("4u76", 4.76e-6),
            ("1k5Ohm", 1.5e3),
        ] {
            assert!(
                close(parse_rkm(text), value),
                "{text}: {:?}",
                parse_rkm(text)
            );
        }
        for text in ["470R", "R47", "4k", "10uF", "4F7", "1mil5", "k7", "4x7"] {
            assert_eq!(parse_rkm(text), None, "{text}");
        }
    }

    /// PSpice's spellings, as ngspice's PSpice mode reads them: `&`, `|`
    /// and `~` for `&&`, `||` and `!`, braces nested as parentheses, and
    /// the line breaks of an expression continued over `+` lines (a
    /// comment line between) as white space.
    #[test]
    fn pspice_spellings_read_as_ngspice_reads_them() {
        let value = |s: &str| parse_expr(s).ok().and_then(|e| e.eval(&|_| None).ok());
        assert_eq!(value("(1 > 0) & (2 > 3)"), Some(0.0));
        assert_eq!(value("(1 > 0) | (2 > 3)"), Some(1.0));
        assert_eq!(value("~(1) || 0"), Some(0.0));
        assert_eq!(value("2 * {1 + {3}}"), Some(8.0));
        assert_eq!(value("1 +\n+ 2 *\n* note\n+ 3 \n+ "), Some(7.0));
        assert_eq!(value("1 2"), None);
        assert_eq!(value("1\n 2"), None);
    }

    /// The most deeply recursive expressions within the bounds parse,
    /// evaluate, print and drop on a test thread's 2 MiB stack; one more
    /// operator or parenthesis is refused.
    #[test]
    fn expressions_at_the_bounds_fit_the_stack() {
        let n = MAX_OPERATORS;
        let parens = MAX_NESTING;
        let cases = [
            format!("{}1", "-".repeat(n)),
            format!("{}1", "2^".repeat(n)),
            std::iter::repeat_n("1", n + 1)
                .collect::<Vec<_>>()
                .join("+"),
            format!("{}1{}", "(".repeat(parens), ")".repeat(parens)),
            format!(
                "{}{}1{}",
                "(-".repeat(parens),
                "-".repeat(n - parens),
                ")".repeat(parens)
            ),
        ];
        for s in &cases {
            assert_eq!(too_complex(s), None, "{}", &s[..20]);
            let e = parse_expr(s).unwrap_or_else(|at| panic!("{} at {at}", &s[..20]));
            let _ = e.eval(&|_| None);
            assert!(!format!("{e:?}").is_empty());
            drop(e.clone());
        }
        assert!(too_complex(&format!("{}1", "-".repeat(n + 1))).is_some());
        assert!(too_complex(&format!("{}1", "(".repeat(parens + 1))).is_some());
    }

    #[test]
    fn engineering_suffixes() {
        let cases = [
            ("10", 10.0),
            ("1k", 1e3),
            ("1K", 1e3),
            ("1kOhm", 1e3),
            ("10uF", 10e-6),
            ("2.2n", 2.2e-9),
            ("3meg", 3e6),
            ("3MEG", 3e6),
            ("1m", 1e-3),
            ("1M", 1e-3),
            ("1mil", 25.4e-6),
            ("1e-3", 1e-3),
            ("1.5E3", 1500.0),
            ("-2p", -2e-12),
            ("1f", 1e-15),
            ("5V", 5.0),
            ("1g", 1e9),
            ("2t", 2e12),
            (".5", 0.5),
        ];
        for (s, v) in cases {
            let got = parse_number(s).unwrap_or_else(|| panic!("{s} did not parse"));
            assert!((got - v).abs() <= 1e-12 * v.abs(), "{s}: {got} != {v}");
        }
        for bad in ["abc", "1k5", "--1", "", "1.2.3"] {
            assert_eq!(parse_number(bad), None, "{bad}");
        }
    }

    #[test]
    fn expressions() {
        let env = |n: &str| match n {
            "r" => Some(2e3),
            "c" => Some(1e-6),
            _ => None,
        };
        let cases = [
            ("1+2*3", 7.0),
            ("(1+2)*3", 9.0),
            ("-r/2", -1e3),
            ("2**3**2", 512.0),
            ("2^3", 8.0),
            ("sqrt(16) + max(1, 2)", 6.0),
            ("1/(2*pi*r*c)", 1.0 / (2.0 * std::f64::consts::PI * 2e-3)),
            ("2k*3", 6e3),
            ("1e-3*2", 2e-3),
            ("- -1", 1.0),
        ];
        for (s, v) in cases {
            let e = parse_expr(s).unwrap_or_else(|at| panic!("{s} failed at {at}"));
            let got = e.eval(&env).unwrap();
            assert!((got - v).abs() <= 1e-12 * v.abs(), "{s}: {got} != {v}");
        }
        assert!(parse_expr("1 +").is_err());
        assert!(parse_expr("(1").is_err());
        assert_eq!(
            parse_expr("x*2").unwrap().eval(&env),
            Err(EvalError::Undefined("x".into()))
        );
    }
}
