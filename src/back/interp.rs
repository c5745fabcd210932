//! A reference interpreter for schedules: walks expression trees and solves
//! blocks by Newton's method with a finite-difference Jacobian. Slow and
//! simple on purpose: it is the yardstick the fast evaluator and generated
//! code are checked against, and it serves tests on small systems.

use crate::analysis::{Assignment, Schedule, Solved, Step};
use crate::ir::{EqId, EquationSystem, Expr, ExprArena, ExprId, VarId};
use crate::numeric::DenseLu;
use crate::numeric::newton;

/// Why the interpreter failed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum InterpError {
    #[error("Newton did not converge in block {block} (residual {residual:e})")]
    NoConvergence { block: usize, residual: f64 },
    #[error("singular Jacobian in block {block}")]
    Singular { block: usize },
}

/// Evaluate `e` with variable values `vals` (indexed by `VarId`) at time `t`.
pub fn eval(sys: &EquationSystem, x: &ExprArena, e: ExprId, vals: &[f64], t: f64) -> f64 {
    match x.get(e) {
        Expr::Const(b) => f64::from_bits(b),
        Expr::Var(v) => vals[v.0 as usize],
        Expr::Param(p) => sys.params[p].value,
        Expr::Time => t,
        Expr::TimeRate => 1.0,
        Expr::Source(s, order) => sys.sources[s].wave.eval(t, order),
        Expr::Neg(a) => -eval(sys, x, a, vals, t),
        Expr::Add(a, b) => eval(sys, x, a, vals, t) + eval(sys, x, b, vals, t),
        Expr::Sub(a, b) => eval(sys, x, a, vals, t) - eval(sys, x, b, vals, t),
        Expr::Mul(a, b) => eval(sys, x, a, vals, t) * eval(sys, x, b, vals, t),
        Expr::Div(a, b) => eval(sys, x, a, vals, t) / eval(sys, x, b, vals, t),
        Expr::Pow(a, b) => eval(sys, x, a, vals, t).powf(eval(sys, x, b, vals, t)),
        Expr::Call(f, a) => f.apply(eval(sys, x, a, vals, t)),
        Expr::Device(f, a) => {
            sys.diodes[f.diode as usize].eval(f.part, f.order, eval(sys, x, a, vals, t))
        }
        Expr::Cmp(op, a, b) => op.apply(eval(sys, x, a, vals, t), eval(sys, x, b, vals, t)),
        Expr::Select(c, a, b) => {
            if eval(sys, x, c, vals, t) != 0.0 {
                eval(sys, x, a, vals, t)
            } else {
                eval(sys, x, b, vals, t)
            }
        }
    }
}

/// The size of `e`'s terms at `vals`: sums and differences add their
/// operands' sizes, products multiply them, anything else is its value's.
/// A residual is judged against it (a KCL sum of milliamperes cancels to
/// zero).
pub fn magnitude(sys: &EquationSystem, x: &ExprArena, e: ExprId, vals: &[f64], t: f64) -> f64 {
    let m = |a| magnitude(sys, x, a, vals, t);
    match x.get(e) {
        Expr::Neg(a) => m(a),
        Expr::Add(a, b) | Expr::Sub(a, b) => m(a) + m(b),
        Expr::Mul(a, b) => m(a) * m(b),
        Expr::Div(a, b) => m(a) / eval(sys, x, b, vals, t).abs(),
        _ => eval(sys, x, e, vals, t).abs(),
    }
}

fn residual_of(sys: &EquationSystem, a: &Assignment, vals: &[f64], t: f64) -> f64 {
    let eq = &sys.eqs[a.eq];
    eval(sys, &sys.exprs, eq.lhs, vals, t) - eval(sys, &sys.exprs, eq.rhs, vals, t)
}

fn assign(
    sys: &EquationSystem,
    a: &Assignment,
    vals: &mut [f64],
    t: f64,
    block: usize,
) -> Result<(), InterpError> {
    match a.solved {
        Solved::Explicit(e) => {
            vals[a.var.0 as usize] = eval(sys, &sys.exprs, e, vals, t);
            Ok(())
        }
        Solved::Implicit(f) => {
            let v = a.var.0 as usize;
            for _ in 0..100 {
                let r = eval(sys, &sys.exprs, f, vals, t);
                if r.abs() <= 1e-13 * (1.0 + vals[v].abs()) {
                    return Ok(());
                }
                let h = 1e-7 * (1.0 + vals[v].abs());
                let x0 = vals[v];
                vals[v] = x0 + h;
                let r1 = eval(sys, &sys.exprs, f, vals, t);
                vals[v] = x0;
                let d = (r1 - r) / h;
                if d == 0.0 || !d.is_finite() {
                    return Err(InterpError::Singular { block });
                }
                vals[v] = x0 - r / d;
            }
            Err(InterpError::NoConvergence {
                block,
                residual: eval(sys, &sys.exprs, f, vals, t).abs(),
            })
        }
    }
}

/// Execute the schedule: on entry `vals` holds the states (and warm-start
/// guesses for tearing variables); on exit every unknown is computed.
///
/// Returns, for each equation that closes a torn loop, the residual that
/// rounding its loop's tears to `f64` can leave (`Σ_j |∂r/∂x_j| · 4 ulp(x_j)`):
/// a badly conditioned loop (a tiny transconductance solved for its control
/// voltage) cannot be satisfied more closely than that.
pub fn run(
    sys: &EquationSystem,
    s: &Schedule,
    vals: &mut [f64],
    t: f64,
) -> Result<Vec<(EqId, f64)>, InterpError> {
    let mut floors = Vec::new();
    for step in &s.steps {
        match step {
            Step::Assign(a) => assign(sys, a, vals, t, 0)?,
            Step::Block(b) => {
                let n = b.tears.len();
                let tears: Vec<VarId> = b.tears.clone();
                let resid = |vals: &mut [f64]| -> Result<Vec<f64>, InterpError> {
                    for a in &b.inner {
                        assign(sys, a, vals, t, b.index)?;
                    }
                    Ok(b.residuals
                        .iter()
                        .map(|a| residual_of(sys, a, vals, t))
                        .collect())
                };
                let mut converged = false;
                let mut last = f64::INFINITY;
                // Each residual relative to the size of its own terms (the
                // loop mixes amperes with volts per second).
                let norm = |r: &[f64], vals: &[f64]| {
                    r.iter()
                        .zip(&b.residuals)
                        .map(|(x, a)| {
                            let eq = &sys.eqs[a.eq];
                            let size = magnitude(sys, &sys.exprs, eq.lhs, vals, t)
                                + magnitude(sys, &sys.exprs, eq.rhs, vals, t);
                            if *x == 0.0 { 0.0 } else { x.abs() / size }
                        })
                        .fold(0.0, f64::max)
                };
                let mut r = resid(vals)?;
                let mut jac = vec![0.0; n * n];
                for _ in 0..200 {
                    last = norm(&r, vals);
                    if last <= 1e-14 {
                        converged = true;
                        break;
                    }
                    // A tear far from its solution (a capacitor's der(u) of
                    // 1e11 V/s from a guess of 0) moves residuals of that size
                    // by less than their rounding at a relative step of 1e-7:
                    // the difference is zero and the matrix looks singular.
                    // Longer steps are tried then (exact on a linear block).
                    let mut lu = None;
                    for widen in [1.0, 1e4, 1e8, 1e12] {
                        for (j, &v) in tears.iter().enumerate() {
                            let x0 = vals[v.0 as usize];
                            let h = widen * 1e-7 * (1.0 + x0.abs());
                            vals[v.0 as usize] = x0 + h;
                            let r1 = resid(vals)?;
                            vals[v.0 as usize] = x0;
                            for i in 0..n {
                                jac[i * n + j] = (r1[i] - r[i]) / h;
                            }
                        }
                        lu = DenseLu::new(n, jac.clone());
                        if lu.is_some() {
                            break;
                        }
                    }
                    let lu = lu.ok_or(InterpError::Singular { block: b.index })?;
                    let mut scratch = vec![0.0; n];
                    let mut dx = r.clone();
                    lu.solve_in_place(&mut dx, &mut scratch);
                    // Damped by the natural monotonicity test; where no damped
                    // step passes, the shortest one tried is taken.
                    let x0: Vec<f64> = tears.iter().map(|v| vals[v.0 as usize]).collect();
                    let scale = |j: usize| 1.0 + x0[j].abs();
                    let full = newton::scaled_norm(&dx, scale);
                    let mut lambda = 1.0;
                    newton::damp(full, |l| {
                        lambda = l;
                        for (j, &v) in tears.iter().enumerate() {
                            vals[v.0 as usize] = x0[j] - l * dx[j];
                        }
                        let mut bar = resid(vals)?;
                        lu.solve_in_place(&mut bar, &mut scratch);
                        Ok(newton::scaled_norm(&bar, scale))
                    })?;
                    r = resid(vals)?;
                    let small = dx
                        .iter()
                        .zip(&x0)
                        .all(|(d, x)| (lambda * d).abs() <= 1e-15 * x.abs());
                    if small && norm(&r, vals).is_finite() {
                        converged = true;
                        break;
                    }
                }
                if !converged {
                    return Err(InterpError::NoConvergence {
                        block: b.index,
                        residual: last,
                    });
                }
                // Leave the inner unknowns consistent with the final guess.
                resid(vals)?;
                for (i, a) in b.residuals.iter().enumerate() {
                    let floor = tears
                        .iter()
                        .enumerate()
                        .map(|(j, v)| {
                            jac[i * n + j].abs() * 4.0 * f64::EPSILON * vals[v.0 as usize].abs()
                        })
                        .sum();
                    floors.push((a.eq, floor));
                }
            }
        }
    }
    Ok(floors)
}
