//! Expressions and their tangents as source text, in the syntax of the
//! target language. Each indexed operand (`v[k]`, `p[k]`, `dv[k]`) is written
//! by a callback in the order it appears in the text, so that a caller can
//! take the indices out of a statement (see `Gen::shaped`).

use super::{Gen, num};
use crate::ir::{DeviceFn, DiodePart, Expr, ExprId, Func, Slope};

/// An indexed operand of a generated expression.
#[derive(Clone, Copy)]
pub(super) enum Leaf {
    Var(u32),
    Param(u32),
    /// A variable's tangent `dv[k]`.
    Tan(u32),
}

impl Leaf {
    /// The array and index of the operand.
    pub(super) fn parts(self) -> (&'static str, u32) {
        match self {
            Leaf::Var(v) => ("v", v),
            Leaf::Param(p) => ("p", p),
            Leaf::Tan(v) => ("dv", v),
        }
    }
}

/// The writer of indexed operands: the operand, how it is written.
type LeafFn<'l> = dyn FnMut(Leaf) -> String + 'l;

/// An operand with its plain index, `v[3]`.
fn plain(leaf: Leaf) -> String {
    let (a, k) = leaf.parts();
    format!("{a}[{k}]")
}

/// The `part` argument of a device function: 0 the current, 1 the charge.
fn part_index(f: DeviceFn) -> u8 {
    match f.part {
        DiodePart::Current => 0,
        DiodePart::Charge => 1,
    }
}

impl Gen<'_> {
    /// The expression with plain indices.
    pub(super) fn expr(&self, e: ExprId) -> String {
        self.expr_with(e, &mut plain)
    }

    /// The tangent of `e` with plain indices (see [`Gen::tangent_with`]).
    pub(super) fn tangent(&self, e: ExprId) -> String {
        self.tangent_with(e, &mut plain)
            .unwrap_or_else(|| "0.0".into())
    }

    /// Whether `e` reads an unknown (else its tangent is zero).
    fn varies(&self, e: ExprId) -> bool {
        match self.x.get(e) {
            Expr::Var(_) => true,
            // A comparison's tangent is zero wherever it is defined.
            Expr::Const(_)
            | Expr::Param(_)
            | Expr::Time
            | Expr::TimeRate
            | Expr::Source(..)
            | Expr::Cmp(..) => false,
            Expr::Select(_, a, b) => self.varies(a) || self.varies(b),
            Expr::Neg(a) | Expr::Call(_, a) | Expr::Device(_, a) => self.varies(a),
            Expr::Add(a, b)
            | Expr::Sub(a, b)
            | Expr::Mul(a, b)
            | Expr::Div(a, b)
            | Expr::Pow(a, b) => self.varies(a) || self.varies(b),
        }
    }

    /// The expression with its indexed operands written by `leaf`.
    pub(super) fn expr_with(&self, e: ExprId, leaf: &mut LeafFn) -> String {
        let syn = self.syn;
        let mut sub = |e| self.expr_with(e, leaf);
        match self.x.get(e) {
            Expr::Const(b) => syn.float(&num(f64::from_bits(b))),
            Expr::Var(v) => leaf(Leaf::Var(v.0)),
            Expr::Param(p) => leaf(Leaf::Param(p.0)),
            Expr::Time => "t".into(),
            // The generated f is the transient's.
            Expr::TimeRate => syn.float("1.0"),
            Expr::Source(s, order) => format!("src_{}(t, {order})", s.0),
            Expr::Neg(a) => format!("(-{})", sub(a)),
            Expr::Add(a, b) => format!("({} + {})", sub(a), sub(b)),
            Expr::Sub(a, b) => format!("({} - {})", sub(a), sub(b)),
            Expr::Mul(a, b) => format!("({} * {})", sub(a), sub(b)),
            Expr::Div(a, b) => format!("({} / {})", sub(a), sub(b)),
            Expr::Pow(a, b) => {
                let base = sub(a);
                syn.pow(base, sub(b))
            }
            Expr::Call(f, a) => syn.call(f, sub(a)),
            Expr::Cmp(op, a, b) => {
                let ea = sub(a);
                syn.cmp(op, ea, sub(b))
            }
            Expr::Select(c, a, b) => {
                let (ec, ea) = (sub(c), sub(a));
                syn.select(ec, ea, sub(b))
            }
            Expr::Device(f, a) => {
                format!(
                    "diode_{}({}, {}, {})",
                    f.diode,
                    part_index(f),
                    f.order,
                    sub(a)
                )
            }
        }
    }

    /// The tangent of `e`, `Σ ∂e/∂x · dx` over the unknowns `x` read (the
    /// forward mode of automatic differentiation), its operands written by
    /// `leaf` in the order they appear; `None` when `e` reads no unknown.
    ///
    /// Every arm writes its pieces in the order they appear in its text:
    /// the indices `leaf` sees must follow the text.
    pub(super) fn tangent_with(&self, e: ExprId, leaf: &mut LeafFn) -> Option<String> {
        if !self.varies(e) {
            return None;
        }
        let d = match self.x.get(e) {
            Expr::Var(v) => leaf(Leaf::Tan(v.0)),
            Expr::Neg(a) => format!("(-{})", self.tangent_with(a, leaf)?),
            Expr::Add(a, b) => self.tangent_sum(a, b, '+', leaf)?,
            Expr::Sub(a, b) => self.tangent_sum(a, b, '-', leaf)?,
            Expr::Mul(a, b) => self.tangent_mul(a, b, leaf)?,
            Expr::Div(a, b) => self.tangent_div(a, b, leaf)?,
            Expr::Pow(a, b) => self.tangent_pow(a, b, leaf)?,
            Expr::Call(f, a) => {
                let slope = self.slope(f, a, leaf);
                format!("({slope} * {})", self.tangent_with(a, leaf)?)
            }
            Expr::Device(f, a) => self.tangent_device(f, a, leaf)?,
            Expr::Select(c, a, b) => {
                let ec = self.expr_with(c, leaf);
                let da = self
                    .tangent_with(a, leaf)
                    .unwrap_or_else(|| self.syn.float("0.0"));
                let db = self
                    .tangent_with(b, leaf)
                    .unwrap_or_else(|| self.syn.float("0.0"));
                self.syn.select(ec, da, db)
            }
            Expr::Const(_)
            | Expr::Param(_)
            | Expr::Time
            | Expr::TimeRate
            | Expr::Source(..)
            | Expr::Cmp(..) => {
                return None;
            }
        };
        Some(d)
    }

    /// The tangent of `a + b` or `a - b` (`op`).
    fn tangent_sum(&self, a: ExprId, b: ExprId, op: char, leaf: &mut LeafFn) -> Option<String> {
        Some(match (self.varies(a), self.varies(b)) {
            (true, true) => {
                let da = self.tangent_with(a, leaf)?;
                let db = self.tangent_with(b, leaf)?;
                format!("({da} {op} {db})")
            }
            (true, false) => self.tangent_with(a, leaf)?,
            _ => {
                let db = self.tangent_with(b, leaf)?;
                if op == '-' { format!("(-{db})") } else { db }
            }
        })
    }

    /// The tangent of `a * b`.
    fn tangent_mul(&self, a: ExprId, b: ExprId, leaf: &mut LeafFn) -> Option<String> {
        Some(match (self.varies(a), self.varies(b)) {
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
        })
    }

    /// The tangent of `a / b`.
    fn tangent_div(&self, a: ExprId, b: ExprId, leaf: &mut LeafFn) -> Option<String> {
        Some(match (self.varies(a), self.varies(b)) {
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
        })
    }

    /// The tangent of `a ^ b`: d(a^b) = b a^(b-1) da + a^b ln(a) db.
    fn tangent_pow(&self, a: ExprId, b: ExprId, leaf: &mut LeafFn) -> Option<String> {
        let syn = self.syn;
        Some(match (self.varies(a), self.varies(b)) {
            (true, false) => {
                let eb = self.expr_with(b, leaf);
                let ea = self.expr_with(a, leaf);
                let p = syn.pow(ea, format!("{} - 1.0", self.expr_with(b, leaf)));
                format!("({eb} * {p} * {})", self.tangent_with(a, leaf)?)
            }
            (false, _) => {
                let ea = self.expr_with(a, leaf);
                let p = syn.pow(ea, self.expr_with(b, leaf));
                let l = syn.call(Func::Ln, self.expr_with(a, leaf));
                format!("({p} * {l} * {})", self.tangent_with(b, leaf)?)
            }
            (true, true) => {
                let ea = self.expr_with(a, leaf);
                let p = syn.pow(ea, self.expr_with(b, leaf));
                let db = self.tangent_with(b, leaf)?;
                let l = syn.call(Func::Ln, self.expr_with(a, leaf));
                let eb = self.expr_with(b, leaf);
                let da = self.tangent_with(a, leaf)?;
                format!(
                    "({p} * ({db} * {l} + {eb} * {da} / {}))",
                    self.expr_with(a, leaf)
                )
            }
        })
    }

    /// The derivative of `f` at `a`, `f'(a)`.
    fn slope(&self, f: Func, a: ExprId, leaf: &mut LeafFn) -> String {
        let syn = self.syn;
        let mut x = || self.expr_with(a, leaf);
        match f.slope() {
            Slope::Value => syn.call(f, x()),
            Slope::Reciprocal => format!("(1.0 / {})", x()),
            Slope::HalfReciprocalValue => format!("(0.5 / {})", syn.call(f, x())),
            Slope::Call(g) => syn.call(g, x()),
            Slope::NegCall(g) => format!("(-{})", syn.call(g, x())),
            Slope::ReciprocalSquareOf(g) => {
                let c1 = syn.call(g, x());
                format!("(1.0 / ({c1} * {}))", syn.call(g, x()))
            }
            Slope::ReciprocalOnePlusSquare => {
                let x1 = x();
                format!("(1.0 / (1.0 + {x1} * {}))", x())
            }
            Slope::OneMinusValueSquared => {
                let t1 = syn.call(f, x());
                format!("(1.0 - {t1} * {})", syn.call(f, x()))
            }
            Slope::Sign => syn.sign(x()),
        }
    }

    /// The tangent of a device function: its next derivative times the
    /// argument's tangent.
    fn tangent_device(&self, f: DeviceFn, a: ExprId, leaf: &mut LeafFn) -> Option<String> {
        if f.order >= 2 {
            // The model gives two derivatives (as the evaluator: NaN).
            return Some("(0.0 / 0.0)".to_string());
        }
        let x = self.expr_with(a, leaf);
        Some(format!(
            "(diode_{}({}, {}, {x}) * {})",
            f.diode,
            part_index(f),
            f.order + 1,
            self.tangent_with(a, leaf)?
        ))
    }
}
