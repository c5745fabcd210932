//! Symbolic differentiation of expressions: with respect to time (for index
//! reduction: sources' time functions included) and with respect to a
//! variable (for Jacobians).

use std::collections::HashMap;

use super::expr::{Expr, ExprArena, ExprId, Func, Slope};
use super::system::VarId;

/// d/dt of `e`, where `dvar(x)` gives the expression of dx/dt. Sources
/// differentiate to their next derivative; time to its rate (1, but 0 at
/// the operating point, as every source's derivative).
pub fn time_derivative(
    x: &mut ExprArena,
    e: ExprId,
    dvar: &mut dyn FnMut(VarId, &mut ExprArena) -> ExprId,
    memo: &mut HashMap<ExprId, ExprId>,
) -> ExprId {
    derive(x, e, &mut |v, x| Some(dvar(v, x)), true, memo)
}

/// ∂e/∂v.
pub fn partial(
    x: &mut ExprArena,
    e: ExprId,
    v: VarId,
    memo: &mut HashMap<ExprId, ExprId>,
) -> ExprId {
    derive(
        x,
        e,
        &mut |w, x| {
            Some(if w == v {
                x.constant(1.0)
            } else {
                x.constant(0.0)
            })
        },
        false,
        memo,
    )
}

fn derive(
    x: &mut ExprArena,
    e: ExprId,
    dvar: &mut dyn FnMut(VarId, &mut ExprArena) -> Option<ExprId>,
    time: bool,
    memo: &mut HashMap<ExprId, ExprId>,
) -> ExprId {
    if let Some(&d) = memo.get(&e) {
        return d;
    }
    // Children first, iteratively in id order, so deep sums cannot overflow.
    let nodes = x.subtree(e);
    for n in nodes {
        if memo.contains_key(&n) {
            continue;
        }
        let d = |memo: &HashMap<ExprId, ExprId>, c: ExprId| memo[&c];
        let r = match x.get(n) {
            Expr::Const(_) | Expr::Param(_) => x.constant(0.0),
            Expr::Var(v) => dvar(v, x).unwrap_or_else(|| x.constant(0.0)),
            Expr::Time if time => x.time_rate(),
            Expr::Time | Expr::TimeRate => x.constant(0.0),
            Expr::Source(s, k) => {
                if time {
                    x.source(s, k.saturating_add(1))
                } else {
                    x.constant(0.0)
                }
            }
            Expr::Neg(a) => {
                let da = d(memo, a);
                x.neg(da)
            }
            Expr::Add(a, b) => {
                let (da, db) = (d(memo, a), d(memo, b));
                x.add(da, db)
            }
            Expr::Sub(a, b) => {
                let (da, db) = (d(memo, a), d(memo, b));
                x.sub(da, db)
            }
            Expr::Mul(a, b) => {
                let (da, db) = (d(memo, a), d(memo, b));
                let l = x.mul(da, b);
                let r = x.mul(a, db);
                x.add(l, r)
            }
            Expr::Div(a, b) => {
                // (da*b - a*db) / b^2, written as da/b - a*db/b^2
                let (da, db) = (d(memo, a), d(memo, b));
                let first = x.div(da, b);
                let num = x.mul(a, db);
                let bb = x.mul(b, b);
                let second = x.div(num, bb);
                x.sub(first, second)
            }
            Expr::Pow(a, b) => {
                let (da, db) = (d(memo, a), d(memo, b));
                if x.as_const(db) == Some(0.0) {
                    // b * a^(b-1) * da
                    let one = x.constant(1.0);
                    let bm1 = x.sub(b, one);
                    let p = x.pow(a, bm1);
                    let t = x.mul(b, p);
                    x.mul(t, da)
                } else {
                    // a^b * (db*ln(a) + b*da/a)
                    let p = x.pow(a, b);
                    let la = x.call(Func::Ln, a);
                    let t1 = x.mul(db, la);
                    let q = x.div(da, a);
                    let t2 = x.mul(b, q);
                    let s = x.add(t1, t2);
                    x.mul(p, s)
                }
            }
            // A comparison is piecewise constant; a selection's derivative
            // is that of the operand it chooses.
            Expr::Cmp(..) => x.constant(0.0),
            Expr::Select(c, a, b) => {
                let (da, db) = (d(memo, a), d(memo, b));
                x.select(c, da, db)
            }
            Expr::Device(f, a) => {
                let da = d(memo, a);
                let next = crate::ir::DeviceFn {
                    order: f.order + 1,
                    ..f
                };
                let inner = x.intern(Expr::Device(next, a));
                x.mul(inner, da)
            }
            Expr::Call(f, a) => {
                let da = d(memo, a);
                let inner = match f.slope() {
                    Slope::Value => x.call(f, a),
                    Slope::Reciprocal => {
                        let one = x.constant(1.0);
                        x.div(one, a)
                    }
                    Slope::HalfReciprocalValue => {
                        let two = x.constant(2.0);
                        let s = x.call(f, a);
                        let den = x.mul(two, s);
                        let one = x.constant(1.0);
                        x.div(one, den)
                    }
                    Slope::Call(g) => x.call(g, a),
                    Slope::NegCall(g) => {
                        let s = x.call(g, a);
                        x.neg(s)
                    }
                    Slope::ReciprocalSquareOf(g) => {
                        let c = x.call(g, a);
                        let cc = x.mul(c, c);
                        let one = x.constant(1.0);
                        x.div(one, cc)
                    }
                    Slope::ReciprocalOnePlusSquare => {
                        let aa = x.mul(a, a);
                        let one = x.constant(1.0);
                        let den = x.add(one, aa);
                        x.div(one, den)
                    }
                    Slope::OneMinusValueSquared => {
                        let t = x.call(f, a);
                        let tt = x.mul(t, t);
                        let one = x.constant(1.0);
                        x.sub(one, tt)
                    }
                    Slope::Sign => {
                        let m = x.call(f, a);
                        x.div(a, m)
                    }
                };
                x.mul(inner, da)
            }
        };
        memo.insert(n, r);
    }
    memo[&e]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ir::{EquationSystem, Origin, OriginKind, VarKind, print};

    #[test]
    fn product_and_chain_rules() {
        let mut s = EquationSystem::default();
        let o = Origin {
            kind: OriginKind::Element { name: "D1".into() },
        };
        let u = s.add_var("u", VarKind::BranchVoltage, o.clone());
        let du = s.add_var("du", VarKind::Derivative, o);
        let p = s.add_param("k".into(), 2.0);
        let x = &mut s.exprs;
        let (ue, pe) = (x.var(u), x.param(p));
        let arg = x.div(ue, pe);
        let e = x.call(Func::Exp, arg);
        let mut memo = HashMap::new();
        let d = time_derivative(
            x,
            e,
            &mut |v, x| if v == u { x.var(du) } else { x.constant(0.0) },
            &mut memo,
        );
        assert_eq!(print::expr(&s, d), "exp(u/k)*(du/k)");
        let x = &mut s.exprs;
        let sq = x.mul(ue, ue);
        let mut memo = HashMap::new();
        let d = partial(x, sq, u, &mut memo);
        assert_eq!(print::expr(&s, d), "u + u");
    }
}
