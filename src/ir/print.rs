//! Text form of expressions and equations, used by listings and snapshots.
//!
//! Constants print in Rust's shortest round-trip form, so output is
//! deterministic across machines.

use std::fmt::Write;

use super::expr::{Expr, ExprId};
use super::system::{EqId, EquationSystem};

/// Format a constant the way listings show it (`1000`, `1e-9`, `0.5`).
pub fn number(x: f64) -> String {
    if x == 0.0 {
        return "0".into();
    }
    let a = x.abs();
    if (1e-3..1e6).contains(&a) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

fn prec(e: Expr) -> u8 {
    match e {
        Expr::Add(..) | Expr::Sub(..) => 1,
        Expr::Mul(..) | Expr::Div(..) => 2,
        Expr::Neg(..) => 3,
        Expr::Pow(..) => 4,
        Expr::Const(b) if f64::from_bits(b) < 0.0 => 3,
        _ => 5,
    }
}

/// Append the text of expression `id` to `out`.
pub fn write_expr(sys: &EquationSystem, id: ExprId, out: &mut String) {
    let e = sys.exprs.get(id);
    let child = |c: ExprId, min: u8, out: &mut String| {
        let paren = prec(sys.exprs.get(c)) < min;
        if paren {
            out.push('(');
        }
        write_expr(sys, c, out);
        if paren {
            out.push(')');
        }
    };
    match e {
        Expr::Const(b) => out.push_str(&number(f64::from_bits(b))),
        Expr::Var(v) => out.push_str(&sys.vars[v].name),
        Expr::Param(p) => out.push_str(&sys.params[p].name),
        Expr::Time => out.push('t'),
        Expr::Source(s, order) => {
            let name = &sys.source_name(s);
            match order {
                0 => {
                    let _ = write!(out, "{name}(t)");
                }
                1 => {
                    let _ = write!(out, "der({name}(t))");
                }
                k => {
                    let _ = write!(out, "der{k}({name}(t))");
                }
            }
        }
        Expr::Neg(a) => {
            out.push('-');
            child(a, 4, out);
        }
        Expr::Add(a, b) => {
            child(a, 1, out);
            out.push_str(" + ");
            child(b, 2, out);
        }
        Expr::Sub(a, b) => {
            child(a, 1, out);
            out.push_str(" - ");
            child(b, 2, out);
        }
        Expr::Mul(a, b) => {
            child(a, 2, out);
            out.push('*');
            child(b, 3, out);
        }
        Expr::Div(a, b) => {
            child(a, 2, out);
            out.push('/');
            child(b, 3, out);
        }
        Expr::Pow(a, b) => {
            child(a, 5, out);
            out.push('^');
            child(b, 5, out);
        }
        Expr::Call(f, a) => {
            out.push_str(f.name());
            out.push('(');
            write_expr(sys, a, out);
            out.push(')');
        }
    }
}

pub fn expr(sys: &EquationSystem, id: ExprId) -> String {
    let mut s = String::new();
    write_expr(sys, id, &mut s);
    s
}

/// `lhs = rhs` of an equation.
pub fn equation(sys: &EquationSystem, eq: EqId) -> String {
    let e = &sys.eqs[eq];
    let mut s = String::new();
    write_expr(sys, e.lhs, &mut s);
    s.push_str(" = ");
    write_expr(sys, e.rhs, &mut s);
    s
}

impl EquationSystem {
    pub fn source_name(&self, s: super::SourceId) -> &str {
        &self.sources[s].name
    }
}
