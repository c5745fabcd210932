//! Generated source: the schedule as a standalone Rust or C function
//! `rhs(t, y, p, v, dy)` — "the code of the function f(t, y) of the
//! simulation model" — and `jac_mul(t, y, p, v, dv, w, jw)`, the exact J·w:
//! each assignment's tangent `dv` from its operands' (forward-mode automatic
//! differentiation), a loop's tangents by implicit differentiation of its
//! residuals (affine in the tears' tangents: one small dense solve).
//!
//! Every statement is commented with the equation and element it comes from.
//! Values live in one array `v` indexed by variable. Runs of assignments of
//! one shape whose indices step evenly (the repeated sections of a big
//! circuit) are written as loops, and the statements are split into
//! functions of at most [`CHUNK`] statements, so that the source of a
//! 10^4-section ladder compiles in well under a second. Blocks are solved by
//! a small damped Newton in the generated code.

use std::fmt::Write;

use crate::analysis::{Assignment, Schedule, Solved, Step};
use crate::ir::{DiodePart, EquationSystem, Expr, ExprArena, ExprId, Func, VarRole, Waveform};

/// The fixed-size views of `v` and `p` at the top of a generated Rust
/// function (constant indices then need no bounds checks).
const RUST_ARRAY_VIEWS: &str = "    let v: &mut [f64; N_VARS] = v.try_into().expect(\"N_VARS values in v\");\n    let p: &[f64; NP] = p.try_into().expect(\"NP parameters\");\n";

/// Statements per generated function.
pub const CHUNK: usize = 50;

/// Consecutive assignments of one shape whose indices step evenly become a
/// loop from this many on (a big circuit's repeated sections).
pub const MIN_RUN: usize = 16;

/// An explicit assignment with its indices taken out (see [`Gen::shaped`]).
struct Shaped {
    template: String,
    leaves: Vec<i64>,
    var: String,
    comment: String,
}

impl Shaped {
    /// The statement with the holes filled by `index(hole)`.
    fn fill(&self, mut index: impl FnMut(usize) -> String) -> String {
        let mut out = String::with_capacity(self.template.len() + 8 * self.leaves.len());
        for (h, piece) in self.template.split(HOLE).enumerate() {
            if h > 0 {
                out.push_str(&index(h - 1));
            }
            out.push_str(piece);
        }
        out
    }
}

/// Statements for a sequence of shaped assignments: runs of at least
/// [`MIN_RUN`] with one shape and evenly stepping indices as loops, in the
/// same order as the assignments.
fn reroll(run: &[Shaped], lang: Lang, out: &mut Vec<String>) {
    let mut i = 0;
    while i < run.len() {
        let first = &run[i];
        if let Some(second) = run.get(i + 1)
            && second.template == first.template
        {
            let stride: Vec<i64> = second
                .leaves
                .iter()
                .zip(&first.leaves)
                .map(|(b, a)| b - a)
                .collect();
            let mut len = 2;
            while let Some(next) = run.get(i + len)
                && next.template == first.template
                && next
                    .leaves
                    .iter()
                    .zip(&run[i + len - 1].leaves)
                    .zip(&stride)
                    .all(|((b, a), d)| b - a == *d)
            {
                len += 1;
            }
            if len >= MIN_RUN {
                let last = &run[i + len - 1];
                let body = first.fill(|h| match stride[h] {
                    0 => first.leaves[h].to_string(),
                    1 => format!("{} + k", first.leaves[h]),
                    d if d > 0 => format!("{} + {d} * k", first.leaves[h]),
                    d => format!("{} - {} * k", first.leaves[h], -d),
                });
                let head = match lang {
                    Lang::Rust => format!("for k in 0..{len}"),
                    Lang::C => format!("for (size_t k = 0; k < {len}; k++)"),
                };
                out.push(format!(
                    "    {head} {{ {body} }} // {len} assignments, {} .. {}: as {}",
                    first.var, last.var, first.comment
                ));
                i += len;
                continue;
            }
        }
        out.push(format!(
            "    {} // {} := ... from {}",
            first.fill(|h| first.leaves[h].to_string()),
            first.var,
            first.comment
        ));
        i += 1;
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Lang {
    Rust,
    C,
}

fn num(x: f64) -> String {
    if x.is_finite() {
        format!("{x:e}")
    } else if x.is_nan() {
        "(0.0/0.0)".into()
    } else if x > 0.0 {
        "(1.0/0.0)".into()
    } else {
        "(-1.0/0.0)".into()
    }
}

struct Gen<'a> {
    sys: &'a EquationSystem,
    x: &'a ExprArena,
    lang: Lang,
}

/// An indexed operand of a generated expression.
#[derive(Clone, Copy)]
enum Leaf {
    Var(u32),
    Param(u32),
    /// A variable's tangent `dv[k]`.
    Tan(u32),
}

impl Leaf {
    /// The array and index of the operand.
    fn parts(self) -> (&'static str, u32) {
        match self {
            Leaf::Var(v) => ("v", v),
            Leaf::Param(p) => ("p", p),
            Leaf::Tan(v) => ("dv", v),
        }
    }
}

/// Placeholder for an index in an expression shape.
const HOLE: char = '#';

impl Gen<'_> {
    fn expr(&self, e: ExprId) -> String {
        self.expr_with(e, &mut |leaf| {
            let (a, k) = leaf.parts();
            format!("{a}[{k}]")
        })
    }

    /// The tangent of `e` with plain indices (see [`Gen::tangent_with`]).
    fn tangent(&self, e: ExprId) -> String {
        self.tangent_with(e, &mut |leaf| {
            let (a, k) = leaf.parts();
            format!("{a}[{k}]")
        })
        .unwrap_or_else(|| "0.0".into())
    }

    /// Whether `e` reads an unknown (else its tangent is zero).
    fn varies(&self, e: ExprId) -> bool {
        match self.x.get(e) {
            Expr::Var(_) => true,
            Expr::Const(_) | Expr::Param(_) | Expr::Time | Expr::Source(..) => false,
            Expr::Neg(a) | Expr::Call(_, a) | Expr::Device(_, a) => self.varies(a),
            Expr::Add(a, b)
            | Expr::Sub(a, b)
            | Expr::Mul(a, b)
            | Expr::Div(a, b)
            | Expr::Pow(a, b) => self.varies(a) || self.varies(b),
        }
    }

    /// `f(arg)` for a function of the C library, as Rust writes it.
    fn call(&self, f: &str, arg: String) -> String {
        match self.lang {
            Lang::Rust => format!("{arg}.{}()", if f == "log" { "ln" } else { f }),
            Lang::C => format!("{f}({arg})"),
        }
    }

    /// The tangent of `e`, `Σ ∂e/∂x · dx` over the unknowns `x` read (the
    /// forward mode of automatic differentiation), its operands written by
    /// `leaf` in the order they appear; `None` when `e` reads no unknown.
    fn tangent_with(&self, e: ExprId, leaf: &mut dyn FnMut(Leaf) -> String) -> Option<String> {
        if !self.varies(e) {
            return None;
        }
        let rust = self.lang == Lang::Rust;
        let (pow, ln) = (
            |_: &Self, a: String, b: String| {
                if rust {
                    format!("{a}.powf({b})")
                } else {
                    format!("pow({a}, {b})")
                }
            },
            |g: &Self, a: String| g.call("log", a),
        );
        let d = match self.x.get(e) {
            Expr::Var(v) => leaf(Leaf::Tan(v.0)),
            Expr::Neg(a) => format!("(-{})", self.tangent_with(a, leaf)?),
            Expr::Add(a, b) | Expr::Sub(a, b) => {
                let minus = matches!(self.x.get(e), Expr::Sub(..));
                match (self.varies(a), self.varies(b)) {
                    (true, true) => {
                        let da = self.tangent_with(a, leaf)?;
                        let db = self.tangent_with(b, leaf)?;
                        format!("({da} {} {db})", if minus { '-' } else { '+' })
                    }
                    (true, false) => self.tangent_with(a, leaf)?,
                    _ => {
                        let db = self.tangent_with(b, leaf)?;
                        if minus { format!("(-{db})") } else { db }
                    }
                }
            }
            Expr::Mul(a, b) => match (self.varies(a), self.varies(b)) {
                (true, true) => {
                    let da = self.tangent_with(a, leaf)?;
                    let eb = self.expr_with(b, leaf);
                    let ea = self.expr_with(a, leaf);
                    let db = self.tangent_with(b, leaf)?;
                    format!("({da} * {eb} + {ea} * {db})")
                }
                (true, false) => {
                    let da = self.tangent_with(a, leaf)?;
                    format!("({da} * {})", self.expr_with(b, leaf))
                }
                _ => {
                    let ea = self.expr_with(a, leaf);
                    format!("({ea} * {})", self.tangent_with(b, leaf)?)
                }
            },
            Expr::Div(a, b) => match (self.varies(a), self.varies(b)) {
                (true, false) => {
                    let da = self.tangent_with(a, leaf)?;
                    format!("({da} / {})", self.expr_with(b, leaf))
                }
                (false, _) => {
                    let ea = self.expr_with(a, leaf);
                    let db = self.tangent_with(b, leaf)?;
                    let eb = self.expr_with(b, leaf);
                    format!("(-{ea} * {db} / ({eb} * {}))", self.expr_with(b, leaf))
                }
                (true, true) => {
                    let da = self.tangent_with(a, leaf)?;
                    let ea = self.expr_with(a, leaf);
                    let eb = self.expr_with(b, leaf);
                    let db = self.tangent_with(b, leaf)?;
                    format!(
                        "(({da} - {ea} / {eb} * {db}) / {})",
                        self.expr_with(b, leaf)
                    )
                }
            },
            // d(a^b) = b a^(b-1) da + a^b ln(a) db.
            Expr::Pow(a, b) => match (self.varies(a), self.varies(b)) {
                (true, false) => {
                    let eb = self.expr_with(b, leaf);
                    let ea = self.expr_with(a, leaf);
                    let p = pow(self, ea, format!("{} - 1.0", self.expr_with(b, leaf)));
                    format!("({eb} * {p} * {})", self.tangent_with(a, leaf)?)
                }
                (false, _) => {
                    let p = pow(self, self.expr_with(a, leaf), self.expr_with(b, leaf));
                    let l = ln(self, self.expr_with(a, leaf));
                    format!("({p} * {l} * {})", self.tangent_with(b, leaf)?)
                }
                (true, true) => {
                    let p = pow(self, self.expr_with(a, leaf), self.expr_with(b, leaf));
                    let db = self.tangent_with(b, leaf)?;
                    let l = ln(self, self.expr_with(a, leaf));
                    let eb = self.expr_with(b, leaf);
                    let da = self.tangent_with(a, leaf)?;
                    format!(
                        "({p} * ({db} * {l} + {eb} * {da} / {}))",
                        self.expr_with(a, leaf)
                    )
                }
            },
            Expr::Call(f, a) => {
                let x = |g: &Self, leaf: &mut dyn FnMut(Leaf) -> String| g.expr_with(a, leaf);
                let slope = match f {
                    Func::Exp => self.call("exp", x(self, leaf)),
                    Func::Ln => format!("(1.0 / {})", x(self, leaf)),
                    Func::Sqrt => format!("(0.5 / {})", self.call("sqrt", x(self, leaf))),
                    Func::Sin => self.call("cos", x(self, leaf)),
                    Func::Cos => format!("(-{})", self.call("sin", x(self, leaf))),
                    Func::Tan => {
                        let c1 = self.call("cos", x(self, leaf));
                        format!("(1.0 / ({c1} * {}))", self.call("cos", x(self, leaf)))
                    }
                    Func::Atan => {
                        let x1 = x(self, leaf);
                        format!("(1.0 / (1.0 + {x1} * {}))", x(self, leaf))
                    }
                    Func::Sinh => self.call("cosh", x(self, leaf)),
                    Func::Cosh => self.call("sinh", x(self, leaf)),
                    Func::Tanh => {
                        let t1 = self.call("tanh", x(self, leaf));
                        format!("(1.0 - {t1} * {})", self.call("tanh", x(self, leaf)))
                    }
                    // Rust's signum: ±1 by the sign bit, as copysign.
                    Func::Abs => {
                        if rust {
                            format!("{}.signum()", x(self, leaf))
                        } else {
                            format!("copysign(1.0, {})", x(self, leaf))
                        }
                    }
                };
                format!("({slope} * {})", self.tangent_with(a, leaf)?)
            }
            Expr::Device(f, a) => {
                let part = match f.part {
                    DiodePart::Current => 0,
                    DiodePart::Charge => 1,
                };
                if f.order >= 2 {
                    // The model gives two derivatives (as the evaluator: NaN).
                    "(0.0 / 0.0)".to_string()
                } else {
                    let x = self.expr_with(a, leaf);
                    format!(
                        "(diode_{}({part}, {}, {x}) * {})",
                        f.diode,
                        f.order + 1,
                        self.tangent_with(a, leaf)?
                    )
                }
            }
            Expr::Const(_) | Expr::Param(_) | Expr::Time | Expr::Source(..) => return None,
        };
        Some(d)
    }

    /// The expression with its indexed operands written by `leaf`.
    fn expr_with(&self, e: ExprId, leaf: &mut dyn FnMut(Leaf) -> String) -> String {
        let rust = self.lang == Lang::Rust;
        let mut sub = |e| self.expr_with(e, leaf);
        match self.x.get(e) {
            Expr::Const(b) => {
                let s = num(f64::from_bits(b));
                if rust {
                    format!("({s}f64)")
                } else {
                    format!("({s})")
                }
            }
            Expr::Var(v) => leaf(Leaf::Var(v.0)),
            Expr::Param(p) => leaf(Leaf::Param(p.0)),
            Expr::Time => "t".into(),
            Expr::Source(s, order) => format!("src_{}(t, {order})", s.0),
            Expr::Neg(a) => format!("(-{})", sub(a)),
            Expr::Add(a, b) => format!("({} + {})", sub(a), sub(b)),
            Expr::Sub(a, b) => format!("({} - {})", sub(a), sub(b)),
            Expr::Mul(a, b) => format!("({} * {})", sub(a), sub(b)),
            Expr::Div(a, b) => format!("({} / {})", sub(a), sub(b)),
            Expr::Pow(a, b) => {
                if rust {
                    format!("{}.powf({})", sub(a), sub(b))
                } else {
                    format!("pow({}, {})", sub(a), sub(b))
                }
            }
            Expr::Call(f, a) => {
                let name = match f {
                    Func::Ln => "ln",
                    other => other.name(),
                };
                if rust {
                    format!("{}.{name}()", sub(a))
                } else {
                    let c = match f {
                        Func::Ln => "log",
                        Func::Abs => "fabs",
                        other => other.name(),
                    };
                    format!("{c}({})", sub(a))
                }
            }
            Expr::Device(f, a) => {
                let part = match f.part {
                    DiodePart::Current => 0,
                    DiodePart::Charge => 1,
                };
                format!("diode_{}({part}, {}, {})", f.diode, f.order, sub(a))
            }
        }
    }

    fn comment(&self, a: &Assignment) -> String {
        let eq = &self.sys.eqs[a.eq];
        let text = crate::ir::print::equation(self.sys, a.eq).replace("*/", "* /");
        format!("{} ({}): {}", a.eq, eq.origin.describe(), text)
    }

    /// An explicit assignment as a shape, `v[#] = ...;` with a [`HOLE`] for
    /// each index, and the indices that fill the holes.
    fn shaped(&self, a: &Assignment, e: ExprId) -> Shaped {
        let mut leaves = vec![i64::from(a.var.0)];
        let rhs = self.expr_with(e, &mut |leaf| {
            let (arr, k) = leaf.parts();
            leaves.push(i64::from(k));
            format!("{arr}[{HOLE}]")
        });
        Shaped {
            template: format!("v[{HOLE}] = {rhs};"),
            leaves,
            var: self.sys.vars[a.var].name.clone(),
            comment: self.comment(a),
        }
    }

    /// The tangent of an explicit assignment as a shape, `dv[#] = ...;`.
    fn tangent_shaped(&self, a: &Assignment, e: ExprId) -> Shaped {
        let mut leaves = vec![i64::from(a.var.0)];
        let rhs = self
            .tangent_with(e, &mut |leaf| {
                let (arr, k) = leaf.parts();
                leaves.push(i64::from(k));
                format!("{arr}[{HOLE}]")
            })
            .unwrap_or_else(|| "0.0".into());
        Shaped {
            template: format!("dv[{HOLE}] = {rhs};"),
            leaves,
            var: format!("d {}", self.sys.vars[a.var].name),
            comment: self.comment(a),
        }
    }

    /// Statements of one step (blocks become a Newton call).
    fn step(&self, step: &Step, k: usize, out: &mut Vec<String>) {
        match step {
            Step::Assign(a) => match a.solved {
                Solved::Explicit(e) => reroll(&[self.shaped(a, e)], self.lang, out),
                Solved::Implicit(_) => out.push(format!(
                    "    block_{k}(t, y, p, v); // {} solved numerically from {}",
                    self.sys.vars[a.var].name,
                    self.comment(a)
                )),
            },
            Step::Block(b) => {
                let tears: Vec<&str> = b
                    .tears
                    .iter()
                    .map(|&v| self.sys.vars[v].name.as_str())
                    .collect();
                out.push(format!(
                    "    block_{k}(t, y, p, v); // algebraic loop through {} (tearing {})",
                    super::listing::shortened(&b.elements, super::listing::ELEMENTS_SHOWN),
                    super::listing::shortened(&tears, super::listing::ELEMENTS_SHOWN)
                ));
            }
        }
    }

    /// A block's Newton unknowns, its assignments, and its residual
    /// equations (`lhs - rhs`). Implicit equations inside a loop join the
    /// Newton solve.
    #[allow(clippy::type_complexity)]
    fn block_parts<'s>(
        &self,
        step: &'s Step,
    ) -> (Vec<u32>, Vec<&'s Assignment>, Vec<(ExprId, ExprId)>) {
        let (mut tears, inner, mut residuals): (Vec<u32>, Vec<&Assignment>, Vec<(ExprId, ExprId)>) =
            match step {
                Step::Assign(a) => {
                    let eq = &self.sys.eqs[a.eq];
                    (vec![a.var.0], vec![], vec![(eq.lhs, eq.rhs)])
                }
                Step::Block(b) => (
                    b.tears.iter().map(|v| v.0).collect(),
                    b.inner.iter().collect(),
                    b.residuals
                        .iter()
                        .map(|a| (self.sys.eqs[a.eq].lhs, self.sys.eqs[a.eq].rhs))
                        .collect(),
                ),
            };
        for a in &inner {
            if matches!(a.solved, Solved::Implicit(_)) {
                let eq = &self.sys.eqs[a.eq];
                tears.push(a.var.0);
                residuals.push((eq.lhs, eq.rhs));
            }
        }
        (tears, inner, residuals)
    }

    /// The residual function and Newton driver of a block.
    fn block_fns(&self, step: &Step, k: usize, out: &mut String) {
        let rust = self.lang == Lang::Rust;
        let (tears, inner, residuals) = self.block_parts(step);
        let n = tears.len();
        if rust {
            let _ = writeln!(
                out,
                "fn resid_{k}(t: f64, y: &[f64], p: &[f64], v: &mut [f64], r: &mut [f64]) {{"
            );
            let _ = writeln!(out, "    let _ = (t, y, p);");
            out.push_str(RUST_ARRAY_VIEWS);
        } else {
            let _ = writeln!(
                out,
                "static void resid_{k}(double t, const double *y, const double *p, double *v, double *r) {{"
            );
            let _ = writeln!(out, "    (void)t; (void)y; (void)p;");
        }
        for a in inner {
            match a.solved {
                Solved::Explicit(e) => {
                    let _ = writeln!(
                        out,
                        "    v[{}] = {}; // {}",
                        a.var.0,
                        self.expr(e),
                        self.comment(a)
                    );
                }
                Solved::Implicit(_) => {
                    let _ = writeln!(
                        out,
                        "    // {} is a Newton unknown of this loop: {}",
                        self.sys.vars[a.var].name,
                        self.comment(a)
                    );
                }
            }
        }
        for (i, (l, r)) in residuals.iter().enumerate() {
            let _ = writeln!(out, "    r[{i}] = {} - {};", self.expr(*l), self.expr(*r));
        }
        let _ = writeln!(out, "}}\n");
        if rust {
            self.block_driver(
                out,
                &format!("fn block_{k}(t: f64, y: &[f64], p: &[f64; NP], v: &mut [f64; N_VARS])"),
                &tears,
                &format!("newton(&TEARS, v, &mut |v: &mut [f64], r: &mut [f64]| resid_{k}(t, y, p, v, r));"),
            );
        } else {
            self.block_driver(
                out,
                &format!(
                    "static void block_{k}(double t, const double *y, const double *p, double *v)"
                ),
                &tears,
                &format!("newton({n}, tears, t, y, p, v, resid_{k});"),
            );
        }
    }

    /// A block's driver function: `head`, its tears as a constant table
    /// (`TEARS` in Rust, `tears` in C), then `call`.
    fn block_driver(&self, out: &mut String, head: &str, tears: &[u32], call: &str) {
        let n = tears.len();
        let list = tears
            .iter()
            .map(|t| t.to_string())
            .collect::<Vec<_>>()
            .join(", ");
        let table = match self.lang {
            Lang::Rust => format!("const TEARS: [usize; {n}] = [{list}];"),
            Lang::C => format!("static const int tears[{n}] = {{{list}}};"),
        };
        let _ = writeln!(out, "{head} {{\n    {table}\n    {call}\n}}\n");
    }

    /// The tangent of a block: the tangents of its assignments and
    /// residuals (`resid_k_tan`), and their solve (`block_k_tan`).
    fn block_tan_fns(&self, step: &Step, k: usize, out: &mut String) {
        let rust = self.lang == Lang::Rust;
        let (tears, inner, residuals) = self.block_parts(step);
        if rust {
            let _ = writeln!(
                out,
                "fn resid_{k}_tan(t: f64, y: &[f64], p: &[f64], v: &[f64], dv: &mut [f64], dr: &mut [f64]) {{"
            );
            let _ = writeln!(out, "    let _ = (t, y, p, v);");
        } else {
            let _ = writeln!(
                out,
                "static void resid_{k}_tan(double t, const double *y, const double *p, const double *v, double *dv, double *dr) {{"
            );
            let _ = writeln!(out, "    (void)t; (void)y; (void)p; (void)v;");
        }
        for a in inner {
            if let Solved::Explicit(e) = a.solved {
                let _ = writeln!(
                    out,
                    "    dv[{}] = {}; // d {}",
                    a.var.0,
                    self.tangent(e),
                    self.sys.vars[a.var].name
                );
            }
        }
        for (i, (l, r)) in residuals.iter().enumerate() {
            let _ = writeln!(
                out,
                "    dr[{i}] = {} - {};",
                self.tangent(*l),
                self.tangent(*r)
            );
        }
        let _ = writeln!(out, "}}\n");
        let n = tears.len();
        if rust {
            self.block_driver(
                out,
                &format!("fn block_{k}_tan(t: f64, y: &[f64], p: &[f64; NP], v: &[f64; N_VARS], dv: &mut [f64; N_VARS])"),
                &tears,
                &format!("tangent_solve(&TEARS, dv, &mut |dv: &mut [f64], dr: &mut [f64]| resid_{k}_tan(t, y, p, v, dv, dr));"),
            );
        } else {
            self.block_driver(
                out,
                &format!("static void block_{k}_tan(double t, const double *y, const double *p, const double *v, double *dv)"),
                &tears,
                &format!("tangent_solve({n}, tears, t, y, p, v, dv, resid_{k}_tan);"),
            );
        }
    }
}

const RUST_PRELUDE: &str = r#"
fn pulse(t: f64, o: u8, v1: f64, v2: f64, td: f64, tr: f64, tf: f64, pw: f64, per: f64) -> f64 {
    if t < td { return if o == 0 { v1 } else { 0.0 }; }
    let mut tt = t - td;
    if per > 0.0 && tt >= per { tt -= (tt / per).floor() * per; }
    let (val, s) = if tt < tr { ((v1 + (v2 - v1) / tr * tt), (v2 - v1) / tr) }
        else if tt < tr + pw { (v2, 0.0) }
        else if tt < tr + pw + tf { (v2 + (v1 - v2) / tf * (tt - tr - pw), (v1 - v2) / tf) }
        else { (v1, 0.0) };
    match o { 0 => val, 1 => s, _ => 0.0 }
}

fn sine(t: f64, o: u8, vo: f64, va: f64, freq: f64, td: f64, theta: f64, phase: f64) -> f64 {
    let ph = phase * std::f64::consts::PI / 180.0;
    if t < td { return if o == 0 { vo + va * ph.sin() } else { 0.0 }; }
    let s = t - td;
    let w = 2.0 * std::f64::consts::PI * freq;
    let (mut cr, mut ci) = (1.0, 0.0);
    for _ in 0..o { let nr = -cr * theta - ci * w; let ni = cr * w - ci * theta; cr = nr; ci = ni; }
    let d = va * (-theta * s).exp() * (cr * (w * s + ph).sin() + ci * (w * s + ph).cos());
    if o == 0 { vo + d } else { d }
}

fn expo(t: f64, o: u8, v1: f64, v2: f64, td1: f64, tau1: f64, td2: f64, tau2: f64) -> f64 {
    let mut val = if o == 0 { v1 } else { 0.0 };
    let term = |t0: f64, tau: f64, amp: f64| { let e = (-(t - t0) / tau).exp();
        if o == 0 { amp * (1.0 - e) } else { -amp * (-1.0 / tau).powi(o as i32) * e } };
    if t >= td1 { val += term(td1, tau1, v2 - v1); }
    if t >= td2 { val += term(td2, tau2, v1 - v2); }
    val
}

fn pwl(t: f64, o: u8, pts: &[(f64, f64)]) -> f64 {
    if pts.is_empty() { return 0.0; }
    if t < pts[0].0 { return if o == 0 { pts[0].1 } else { 0.0 }; }
    let k = pts.partition_point(|q| q.0 <= t);
    if k >= pts.len() { return if o == 0 { pts[pts.len() - 1].1 } else { 0.0 }; }
    let ((ta, ya), (tb, yb)) = (pts[k - 1], pts[k]);
    let s = if tb > ta { (yb - ya) / (tb - ta) } else { 0.0 };
    match o { 0 => ya + s * (t - ta), 1 => s, _ => 0.0 }
}

/// ngspice's level-1 diode: [id, id', id''] or [q, q', q''].
#[allow(clippy::too_many_arguments)]
fn diode(part: u8, o: u8, v: f64, is: f64, vte: f64, bv: f64, g: f64, cjo: f64, vj: f64, m: f64, fc: f64, tt: f64) -> f64 {
    let vlin = 50.0 * vte;
    let id = if v > vlin { let e = (vlin / vte).exp(); [is * (e * (1.0 + (v - vlin) / vte) - 1.0) + g * v, is * e / vte + g, 0.0] }
        else if v >= -3.0 * vte { let e = (v / vte).exp(); [is * (e - 1.0) + g * v, is * e / vte + g, is * e / (vte * vte)] }
        else if v >= -bv { let a = 3.0 * vte / (v * std::f64::consts::E); let arg = a * a * a;
            [-is * (1.0 + arg) + g * v, 3.0 * is * arg / v + g, -12.0 * is * arg / (v * v)] }
        else { let e = (-(bv + v) / vte).exp(); [-is * e + g * v, is * e / vte + g, -is * e / (vte * vte)] };
    if part == 0 { return id[o as usize]; }
    let mut q = [tt * id[0], tt * id[1], tt * id[2]];
    if cjo != 0.0 {
        let d = fc * vj;
        if v < d { let arg = 1.0 - v / vj; let sarg = (-m * arg.ln()).exp();
            q[0] += vj * cjo * (1.0 - arg * sarg) / (1.0 - m); q[1] += cjo * sarg; q[2] += cjo * m / vj * sarg / arg; }
        else { let f1 = vj * (1.0 - (1.0 - fc).powf(1.0 - m)) / (1.0 - m); let f2 = (1.0 - fc).powf(1.0 + m);
            let f3 = 1.0 - fc * (1.0 + m); let c = cjo / f2;
            q[0] += cjo * f1 + c * (f3 * (v - d) + m / (2.0 * vj) * (v * v - d * d)); q[1] += c * (f3 + m * v / vj); q[2] += c * m / vj; }
    }
    q[o as usize]
}

/// Solve a x = b in place (`b` becomes x): Gaussian elimination with partial pivoting.
fn lin_solve(n: usize, a: &mut [f64], b: &mut [f64]) {
    for k in 0..n {
        let piv = (k..n).max_by(|&i, &j| a[i * n + k].abs().total_cmp(&a[j * n + k].abs())).unwrap_or(k);
        for j in 0..n { a.swap(k * n + j, piv * n + j); }
        b.swap(k, piv);
        for i in k + 1..n { let q = a[i * n + k] / a[k * n + k]; for j in k..n { a[i * n + j] -= q * a[k * n + j]; } b[i] -= q * b[k]; }
    }
    for k in (0..n).rev() { let mut s = b[k]; for j in k + 1..n { s -= a[k * n + j] * b[j]; } b[k] = s / a[k * n + k]; }
}

/// Damped Newton on `tears` (finite-difference Jacobian, dense solve).
fn newton(tears: &[usize], v: &mut [f64], f: &mut dyn FnMut(&mut [f64], &mut [f64])) {
    let n = tears.len();
    let (mut r, mut r1) = (vec![0.0; n], vec![0.0; n]);
    let norm = |r: &[f64]| r.iter().map(|x| x * x).sum::<f64>();
    for _ in 0..100 {
        f(v, &mut r);
        let base = norm(&r);
        if base == 0.0 { return; }
        let mut a = vec![0.0; n * n];
        for j in 0..n {
            let x0 = v[tears[j]];
            let h = 1e-7 * (1.0 + x0.abs());
            v[tears[j]] = x0 + h;
            f(v, &mut r1);
            v[tears[j]] = x0;
            for i in 0..n { a[i * n + j] = (r1[i] - r[i]) / h; }
        }
        let mut dx = r.clone();
        lin_solve(n, &mut a, &mut dx);
        let x0: Vec<f64> = tears.iter().map(|&t| v[t]).collect();
        let mut lambda = 1.0;
        loop {
            for j in 0..n { v[tears[j]] = x0[j] - lambda * dx[j]; }
            f(v, &mut r1);
            if norm(&r1) < base || lambda < 1e-8 { break; }
            lambda *= 0.5;
        }
        if dx.iter().zip(&x0).all(|(d, x)| (lambda * d).abs() <= 1e-14 * (1.0 + x.abs())) { return; }
    }
}

/// The tangents of a loop's unknowns `tears` by implicit differentiation:
/// `f(dv, dr)` writes the tangents inside the loop and of its residuals,
/// which are affine in the tears' tangents; they are solved for dr = 0.
fn tangent_solve(tears: &[usize], dv: &mut [f64], f: &mut dyn FnMut(&mut [f64], &mut [f64])) {
    let n = tears.len();
    let (mut b, mut c, mut a) = (vec![0.0; n], vec![0.0; n], vec![0.0; n * n]);
    for &k in tears { dv[k] = 0.0; }
    f(dv, &mut b);
    for j in 0..n {
        dv[tears[j]] = 1.0;
        f(dv, &mut c);
        dv[tears[j]] = 0.0;
        for i in 0..n { a[i * n + j] = c[i] - b[i]; }
    }
    lin_solve(n, &mut a, &mut b);
    for j in 0..n { dv[tears[j]] = -b[j]; }
    f(dv, &mut c);
}
"#;

const C_PRELUDE: &str = r#"
#include <math.h>
#include <stdlib.h>
#include <string.h>

/* ISO C has no M_PI or M_E (POSIX does). */
#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif
#ifndef M_E
#define M_E 2.71828182845904523536
#endif

static inline double pulse(double t, int o, double v1, double v2, double td, double tr, double tf, double pw, double per) {
    if (t < td) return o == 0 ? v1 : 0.0;
    double tt = t - td;
    if (per > 0.0 && tt >= per) tt -= floor(tt / per) * per;
    double val, s;
    if (tt < tr) { s = (v2 - v1) / tr; val = v1 + s * tt; }
    else if (tt < tr + pw) { s = 0.0; val = v2; }
    else if (tt < tr + pw + tf) { s = (v1 - v2) / tf; val = v2 + s * (tt - tr - pw); }
    else { s = 0.0; val = v1; }
    return o == 0 ? val : (o == 1 ? s : 0.0);
}

static inline double sine(double t, int o, double vo, double va, double freq, double td, double theta, double phase) {
    double ph = phase * M_PI / 180.0;
    if (t < td) return o == 0 ? vo + va * sin(ph) : 0.0;
    double s = t - td, w = 2.0 * M_PI * freq, cr = 1.0, ci = 0.0;
    for (int k = 0; k < o; k++) { double nr = -cr * theta - ci * w, ni = cr * w - ci * theta; cr = nr; ci = ni; }
    double d = va * exp(-theta * s) * (cr * sin(w * s + ph) + ci * cos(w * s + ph));
    return o == 0 ? vo + d : d;
}

static inline double expo(double t, int o, double v1, double v2, double td1, double tau1, double td2, double tau2) {
    double val = o == 0 ? v1 : 0.0;
    if (t >= td1) { double e = exp(-(t - td1) / tau1); val += o == 0 ? (v2 - v1) * (1.0 - e) : -(v2 - v1) * pow(-1.0 / tau1, o) * e; }
    if (t >= td2) { double e = exp(-(t - td2) / tau2); val += o == 0 ? (v1 - v2) * (1.0 - e) : -(v1 - v2) * pow(-1.0 / tau2, o) * e; }
    return val;
}

static inline double pwl(double t, int o, const double *ts, const double *ys, int n) {
    if (n == 0) return 0.0;
    if (t < ts[0]) return o == 0 ? ys[0] : 0.0;
    int k = 0;
    while (k < n && ts[k] <= t) k++;
    if (k >= n) return o == 0 ? ys[n - 1] : 0.0;
    double s = ts[k] > ts[k - 1] ? (ys[k] - ys[k - 1]) / (ts[k] - ts[k - 1]) : 0.0;
    return o == 0 ? ys[k - 1] + s * (t - ts[k - 1]) : (o == 1 ? s : 0.0);
}

static inline double diode(int part, int o, double v, double is, double vte, double bv, double g, double cjo, double vj, double m, double fc, double tt) {
    double id[3], vlin = 50.0 * vte;
    if (v > vlin) { double e = exp(vlin / vte); id[0] = is * (e * (1.0 + (v - vlin) / vte) - 1.0) + g * v; id[1] = is * e / vte + g; id[2] = 0.0; }
    else if (v >= -3.0 * vte) { double e = exp(v / vte); id[0] = is * (e - 1.0) + g * v; id[1] = is * e / vte + g; id[2] = is * e / (vte * vte); }
    else if (v >= -bv) { double a = 3.0 * vte / (v * M_E), arg = a * a * a; id[0] = -is * (1.0 + arg) + g * v; id[1] = 3.0 * is * arg / v + g; id[2] = -12.0 * is * arg / (v * v); }
    else { double e = exp(-(bv + v) / vte); id[0] = -is * e + g * v; id[1] = is * e / vte + g; id[2] = -is * e / (vte * vte); }
    if (part == 0) return id[o];
    double q[3] = {tt * id[0], tt * id[1], tt * id[2]};
    if (cjo != 0.0) {
        double d = fc * vj;
        if (v < d) { double arg = 1.0 - v / vj, sarg = exp(-m * log(arg)); q[0] += vj * cjo * (1.0 - arg * sarg) / (1.0 - m); q[1] += cjo * sarg; q[2] += cjo * m / vj * sarg / arg; }
        else { double f1 = vj * (1.0 - pow(1.0 - fc, 1.0 - m)) / (1.0 - m), f2 = pow(1.0 - fc, 1.0 + m), f3 = 1.0 - fc * (1.0 + m), c = cjo / f2;
            q[0] += cjo * f1 + c * (f3 * (v - d) + m / (2.0 * vj) * (v * v - d * d)); q[1] += c * (f3 + m * v / vj); q[2] += c * m / vj; }
    }
    return q[o];
}

typedef void (*resid_fn)(double, const double *, const double *, double *, double *);

/* Solve a x = b in place (b becomes x): Gaussian elimination with partial pivoting. */
static inline void lin_solve(int n, double *a, double *b) {
    for (int k = 0; k < n; k++) {
        int piv = k; for (int i = k + 1; i < n; i++) if (fabs(a[i * n + k]) > fabs(a[piv * n + k])) piv = i;
        for (int j = 0; j < n; j++) { double s = a[k * n + j]; a[k * n + j] = a[piv * n + j]; a[piv * n + j] = s; }
        double s = b[k]; b[k] = b[piv]; b[piv] = s;
        for (int i = k + 1; i < n; i++) { double q = a[i * n + k] / a[k * n + k]; for (int j = k; j < n; j++) a[i * n + j] -= q * a[k * n + j]; b[i] -= q * b[k]; }
    }
    for (int k = n - 1; k >= 0; k--) { double s = b[k]; for (int j = k + 1; j < n; j++) s -= a[k * n + j] * b[j]; b[k] = s / a[k * n + k]; }
}

/* Damped Newton on the tearing variables (finite-difference Jacobian). */
static inline void newton(int n, const int *tears, double t, const double *y, const double *p, double *v, resid_fn f) {
    double *r = malloc(sizeof(double) * (size_t)(4 * n + n * n));
    if (!r) { for (int j = 0; j < n; j++) v[tears[j]] = NAN; return; }
    double *r1 = r + n, *dx = r + 2 * n, *x0 = r + 3 * n, *a = r + 4 * n;
    for (int it = 0; it < 100; it++) {
        f(t, y, p, v, r);
        double base = 0.0; for (int i = 0; i < n; i++) base += r[i] * r[i];
        if (base == 0.0) break;
        for (int j = 0; j < n; j++) {
            double xj = v[tears[j]], h = 1e-7 * (1.0 + fabs(xj));
            v[tears[j]] = xj + h; f(t, y, p, v, r1); v[tears[j]] = xj;
            for (int i = 0; i < n; i++) a[i * n + j] = (r1[i] - r[i]) / h;
        }
        memcpy(dx, r, sizeof(double) * (size_t)n);
        lin_solve(n, a, dx);
        for (int j = 0; j < n; j++) x0[j] = v[tears[j]];
        double lambda = 1.0;
        for (;;) {
            for (int j = 0; j < n; j++) v[tears[j]] = x0[j] - lambda * dx[j];
            f(t, y, p, v, r1);
            double nn = 0.0; for (int i = 0; i < n; i++) nn += r1[i] * r1[i];
            if (nn < base || lambda < 1e-8) break;
            lambda *= 0.5;
        }
        int small = 1; for (int j = 0; j < n; j++) if (fabs(lambda * dx[j]) > 1e-14 * (1.0 + fabs(x0[j]))) small = 0;
        if (small) break;
    }
    free(r);
}

typedef void (*tan_fn)(double, const double *, const double *, const double *, double *, double *);

/* The tangents of a loop's unknowns by implicit differentiation: f writes the
   tangents inside the loop and of its residuals, which are affine in the
   tears' tangents; they are solved for dr = 0. */
static inline void tangent_solve(int n, const int *tears, double t, const double *y, const double *p, const double *v, double *dv, tan_fn f) {
    double *b = malloc(sizeof(double) * (size_t)(2 * n + n * n));
    if (!b) { for (int j = 0; j < n; j++) dv[tears[j]] = NAN; return; }
    double *c = b + n, *a = b + 2 * n;
    for (int j = 0; j < n; j++) dv[tears[j]] = 0.0;
    f(t, y, p, v, dv, b);
    for (int j = 0; j < n; j++) {
        dv[tears[j]] = 1.0; f(t, y, p, v, dv, c); dv[tears[j]] = 0.0;
        for (int i = 0; i < n; i++) a[i * n + j] = c[i] - b[i];
    }
    lin_solve(n, a, b);
    for (int j = 0; j < n; j++) dv[tears[j]] = -b[j];
    f(t, y, p, v, dv, c);
    free(b);
}
"#;

/// A function that sweeps the chunk functions: `sig` with `doc`, then
/// `prologue`, the states' values (`src`) into their variables of `regs`,
/// the calls `name_k(args)`, and the derivatives' values out into `dst`;
/// `arrays` is `(regs, src, dst)`.
fn sweep_fn(
    out: &mut String,
    lang: Lang,
    doc: &str,
    sig: &str,
    prologue: &str,
    arrays: (&str, &str, &str),
    calls: (&str, usize, &str),
) {
    let (regs, src, dst) = arrays;
    let (name, n, args) = calls;
    match lang {
        Lang::Rust => {
            out.push('\n');
            for line in doc.lines() {
                let _ = writeln!(out, "/// {line}");
            }
        }
        Lang::C => {
            let doc = doc.replace('`', "").replace('\n', "\n   ");
            let _ = writeln!(out, "\n/* {doc} */");
        }
    }
    let _ = writeln!(out, "{sig} {{");
    out.push_str(prologue);
    let (load, store) = match lang {
        Lang::Rust => (
            format!("    for k in 0..N_STATES {{ {regs}[STATE_VAR[k]] = {src}[k]; }}"),
            format!("    for k in 0..N_STATES {{ {dst}[k] = {regs}[DER_VAR[k]]; }}"),
        ),
        Lang::C => (
            format!("    for (int k = 0; k < N_STATES; k++) {regs}[STATE_VAR[k]] = {src}[k];"),
            format!("    for (int k = 0; k < N_STATES; k++) {dst}[k] = {regs}[DER_VAR[k]];"),
        ),
    };
    let _ = writeln!(out, "{load}");
    for c in 0..n {
        let _ = writeln!(out, "    {name}_{c}({args});");
    }
    let _ = writeln!(out, "{store}\n}}");
}

/// The statements as functions of at most [`CHUNK`] each, opened by
/// `head(k)`; how many.
fn chunk_fns(out: &mut String, stmts: &[String], head: impl Fn(usize) -> String) -> usize {
    let mut n = 0;
    for (c, chunk) in stmts.chunks(CHUNK).enumerate() {
        let _ = writeln!(out, "\n{}", head(c));
        for s in chunk {
            let _ = writeln!(out, "{s}");
        }
        out.push_str("}\n");
        n += 1;
    }
    n
}

/// The generated source.
pub fn emit(sys: &EquationSystem, sched: &Schedule, lang: Lang) -> String {
    let g = Gen {
        sys,
        x: &sched.exprs,
        lang,
    };
    let rust = lang == Lang::Rust;
    let states: Vec<_> = sys.states().collect();
    let mut out = String::new();
    let cm = "//";
    let _ = writeln!(
        out,
        "{cm} Generated by kausal from \"{}\". Do not edit.",
        sys.title.replace('\n', " ")
    );
    let _ = writeln!(
        out,
        "{cm} f(t, y) of the sorted equations: {} states, {} equations.",
        states.len(),
        sys.eqs.len()
    );
    if rust {
        out.push_str("#![allow(dead_code, unused_parens, unused_variables, clippy::all)]\n");
        out.push_str(RUST_PRELUDE);
    } else {
        out.push_str(C_PRELUDE);
    }
    // Parameters.
    let _ = writeln!(out, "\n{cm} Parameters p[k], in order:");
    for (id, p) in sys.params.iter() {
        let _ = writeln!(out, "{cm}   p[{}] = {} = {}", id.0, p.name, num(p.value));
    }
    let vals: Vec<String> = sys.params.values().map(|p| num(p.value)).collect();
    let np = vals.len().max(1);
    let list = if vals.is_empty() {
        "0.0".to_string()
    } else {
        vals.join(", ")
    };
    if rust {
        let _ = writeln!(
            out,
            "pub const NP: usize = {np};\npub const P: [f64; NP] = [{list}];"
        );
        let _ = writeln!(out, "pub const N_STATES: usize = {};", states.len());
        let _ = writeln!(out, "pub const N_VARS: usize = {};", sys.vars.len().max(1));
    } else {
        let _ = writeln!(out, "const double P[{np}] = {{{list}}};");
        let _ = writeln!(
            out,
            "#define N_STATES {}\n#define N_VARS {}",
            states.len(),
            sys.vars.len().max(1)
        );
    }
    let _ = writeln!(out, "{cm} States y[k]:");
    for (k, &s) in states.iter().enumerate() {
        let _ = writeln!(out, "{cm}   y[{k}] = {} (v[{}])", sys.vars[s].name, s.0);
    }
    // Sources.
    for (id, s) in sys.sources.iter() {
        let body = match &s.wave {
            Waveform::Dc { value } => num(*value),
            Waveform::Pulse {
                v1,
                v2,
                td,
                tr,
                tf,
                pw,
                per,
            } => format!(
                "pulse(t, o, {}, {}, {}, {}, {}, {}, {})",
                num(*v1),
                num(*v2),
                num(*td),
                num(*tr),
                num(*tf),
                num(*pw),
                num(*per)
            ),
            Waveform::Sin {
                vo,
                va,
                freq,
                td,
                theta,
                phase,
            } => format!(
                "sine(t, o, {}, {}, {}, {}, {}, {})",
                num(*vo),
                num(*va),
                num(*freq),
                num(*td),
                num(*theta),
                num(*phase)
            ),
            Waveform::Exp {
                v1,
                v2,
                td1,
                tau1,
                td2,
                tau2,
            } => format!(
                "expo(t, o, {}, {}, {}, {}, {}, {})",
                num(*v1),
                num(*v2),
                num(*td1),
                num(*tau1),
                num(*td2),
                num(*tau2)
            ),
            Waveform::Pwl {
                points,
                repeat,
                delay,
            } => {
                // The time within the sequence (`ir::pwl_time`): delayed,
                // and folded back past the last point when it repeats (the
                // remainder is of a positive number: `%` and fmod agree).
                let local = if *delay == 0.0 {
                    "t".to_string()
                } else {
                    format!("(t - {})", num(*delay))
                };
                let tau = match (repeat, points.last()) {
                    (Some(r), Some(&(last, _))) => {
                        let (r, last, period) = (num(*r), num(last), num(last - r));
                        if rust {
                            format!(
                                "if {local} >= {last} {{ {r} + ({local} - {r}) % {period} }} else {{ {local} }}"
                            )
                        } else {
                            format!(
                                "({local} >= {last} ? {r} + fmod({local} - {r}, {period}) : {local})"
                            )
                        }
                    }
                    _ => local,
                };
                if rust {
                    let pts: Vec<String> = points
                        .iter()
                        .map(|(a, b)| format!("({}, {})", num(*a), num(*b)))
                        .collect();
                    format!("pwl({tau}, o, &[{}])", pts.join(", "))
                } else {
                    let ts: Vec<String> = points.iter().map(|p| num(p.0)).collect();
                    let ys: Vec<String> = points.iter().map(|p| num(p.1)).collect();
                    format!(
                        "pwl({tau}, o, (const double[]){{{}}}, (const double[]){{{}}}, {})",
                        ts.join(", "),
                        ys.join(", "),
                        points.len()
                    )
                }
            }
        };
        if rust {
            let _ = writeln!(
                out,
                "/// {} (t)\nfn src_{}(t: f64, o: u8) -> f64 {{ let _ = (t, o); {body} }}",
                s.name, id.0
            );
        } else {
            let _ = writeln!(
                out,
                "/* {} (t) */\nstatic double src_{}(double t, int o) {{ (void)t; (void)o; return {body}; }}",
                s.name, id.0
            );
        }
    }
    for (k, d) in sys.diodes.iter().enumerate() {
        let args = format!(
            "{}, {}, {}, {}, {}, {}, {}, {}, {}",
            num(d.is),
            num(d.vte),
            num(d.bv.unwrap_or(f64::INFINITY)),
            num(d.gmin),
            num(d.cjo),
            num(d.vj),
            num(d.m),
            num(d.fc),
            num(d.tt)
        );
        if rust {
            let _ = writeln!(
                out,
                "/// Diode {}.\nfn diode_{k}(part: u8, o: u8, x: f64) -> f64 {{ diode(part, o, x, {args}) }}",
                d.name
            );
        } else {
            let _ = writeln!(
                out,
                "/* Diode {} */\nstatic double diode_{k}(int part, int o, double x) {{ return diode(part, o, x, {args}); }}",
                d.name
            );
        }
    }
    // Blocks.
    for (k, step) in sched.steps.iter().enumerate() {
        let is_block = matches!(step, Step::Block(_))
            || matches!(step, Step::Assign(a) if matches!(a.solved, Solved::Implicit(_)));
        if is_block {
            out.push('\n');
            g.block_fns(step, k, &mut out);
            g.block_tan_fns(step, k, &mut out);
        }
    }
    // Statements, in chunks; repeated sections as loops. Beside them their
    // tangents, in the same order: dv of every assignment from the tangents
    // of its operands; a block's by its tangent solve.
    let (mut stmts, mut tstmts) = (Vec::new(), Vec::new());
    let (mut run, mut trun) = (Vec::new(), Vec::new());
    for (k, step) in sched.steps.iter().enumerate() {
        if let Step::Assign(a) = step
            && let Solved::Explicit(e) = a.solved
        {
            run.push(g.shaped(a, e));
            trun.push(g.tangent_shaped(a, e));
            continue;
        }
        reroll(&run, lang, &mut stmts);
        reroll(&trun, lang, &mut tstmts);
        run.clear();
        trun.clear();
        g.step(step, k, &mut stmts);
        tstmts.push(format!("    block_{k}_tan(t, y, p, v, dv);"));
    }
    reroll(&run, lang, &mut stmts);
    reroll(&trun, lang, &mut tstmts);
    // Fixed-size arrays: constant indices need no bounds checks.
    let tchunks = chunk_fns(&mut out, &tstmts, |c| match lang {
        Lang::Rust => format!(
            "#[inline(never)]\nfn tan_{c}(t: f64, y: &[f64], p: &[f64; NP], v: &[f64; N_VARS], dv: &mut [f64; N_VARS]) {{\n    let _ = (t, y, p, v);"
        ),
        Lang::C => format!(
            "__attribute__((noinline)) static void tan_{c}(double t, const double *y, const double *p, const double *v, double *dv) {{\n    (void)t; (void)y; (void)p; (void)v;"
        ),
    });
    let chunks = chunk_fns(&mut out, &stmts, |c| match lang {
        Lang::Rust => format!(
            "#[inline(never)]\nfn part_{c}(t: f64, y: &[f64], p: &[f64; NP], v: &mut [f64; N_VARS]) {{\n    let _ = (t, y, p);"
        ),
        Lang::C => format!(
            "__attribute__((noinline)) static void part_{c}(double t, const double *y, const double *p, double *v) {{\n    (void)t; (void)y; (void)p;"
        ),
    });
    // rhs: load states, run the chunks, store derivatives.
    let ders: Vec<u32> = states
        .iter()
        .map(|&s| match sys.vars[s].role {
            VarRole::State { der } => der.0,
            _ => unreachable!("states have derivatives"),
        })
        .collect();
    // States in and derivatives out through index tables (loops, not one
    // statement each: a big circuit's rhs stays small).
    let table = |ids: Vec<u32>| {
        ids.iter()
            .map(|i| i.to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let st = table(states.iter().map(|s| s.0).collect());
    let dt = table(ders.clone());
    let ns = states.len().max(1);
    if rust {
        let _ = writeln!(
            out,
            "\n/// The variable of each state, and of its derivative.\nconst STATE_VAR: [usize; {}] = [{st}];\nconst DER_VAR: [usize; {}] = [{dt}];",
            states.len(),
            states.len()
        );
    } else {
        // ISO C has no empty arrays or initializers: a stateless circuit's
        // tables hold one unused 0.
        let (st, dt) = if states.is_empty() {
            ("0".to_string(), "0".to_string())
        } else {
            (st, dt)
        };
        let _ = writeln!(
            out,
            "\n/* The variable of each state, and of its derivative. */\nstatic const int STATE_VAR[{ns}] = {{{st}}};\nstatic const int DER_VAR[{ns}] = {{{dt}}};"
        );
    }
    let (rhs_sig, rhs_prologue, jac_sig, jac_prologue) = match lang {
        Lang::Rust => (
            "pub fn rhs(t: f64, y: &[f64], p: &[f64], v: &mut [f64], dy: &mut [f64])",
            RUST_ARRAY_VIEWS,
            "pub fn jac_mul(t: f64, y: &[f64], p: &[f64], v: &mut [f64], dv: &mut [f64], w: &[f64], jw: &mut [f64])",
            "    rhs(t, y, p, v, jw);\n    let v: &[f64; N_VARS] = (&*v).try_into().expect(\"N_VARS values in v\");\n    let dv: &mut [f64; N_VARS] = dv.try_into().expect(\"N_VARS values in dv\");\n    let p: &[f64; NP] = p.try_into().expect(\"NP parameters\");\n",
        ),
        Lang::C => (
            "void rhs(double t, const double *y, const double *p, double *v, double *dy)",
            "",
            "void jac_mul(double t, const double *y, const double *p, double *v, double *dv, const double *w, double *jw)",
            "    rhs(t, y, p, v, jw);\n",
        ),
    };
    sweep_fn(
        &mut out,
        lang,
        "dy/dt = f(t, y): `v` is scratch of N_VARS values (it keeps Newton's warm start).",
        rhs_sig,
        rhs_prologue,
        ("v", "y", "dy"),
        ("part", chunks, "t, y, p, v"),
    );
    // jac_mul: the values at (t, y) by rhs, then the tangent sweep.
    sweep_fn(
        &mut out,
        lang,
        "J(t, y) w, exact: the tangents of the sorted assignments (forward mode),\nloops by implicit differentiation. `v` and `dv` are scratch of N_VARS values.",
        jac_sig,
        jac_prologue,
        ("dv", "w", "jw"),
        ("tan", tchunks, "t, y, p, v, dv"),
    );
    out
}
