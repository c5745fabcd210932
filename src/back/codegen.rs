//! Generated source: the schedule as a standalone Rust or C function
//! `rhs(t, y, p, v, dy)` — "the code of the function f(t, y) of the
//! simulation model" — and `jac_mul(t, y, p, v, w, jw)` (J·w by a central
//! directional difference; the in-process evaluator has the analytic one).
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

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
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
}

/// Placeholder for an index in an expression shape.
const HOLE: char = '#';

impl Gen<'_> {
    fn expr(&self, e: ExprId) -> String {
        self.expr_with(e, &mut |leaf| match leaf {
            Leaf::Var(v) => format!("v[{v}]"),
            Leaf::Param(p) => format!("p[{p}]"),
        })
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
        let rhs = self.expr_with(e, &mut |leaf| match leaf {
            Leaf::Var(v) => {
                leaves.push(i64::from(v));
                format!("v[{HOLE}]")
            }
            Leaf::Param(p) => {
                leaves.push(i64::from(p));
                format!("p[{HOLE}]")
            }
        });
        Shaped {
            template: format!("v[{HOLE}] = {rhs};"),
            leaves,
            var: self.sys.vars[a.var].name.clone(),
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
                    b.elements.join(", "),
                    tears.join(", ")
                ));
            }
        }
    }

    /// The residual function and Newton driver of a block.
    fn block_fns(&self, step: &Step, k: usize, out: &mut String) {
        let rust = self.lang == Lang::Rust;
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
        // Implicit equations inside the loop join the Newton solve.
        for a in &inner {
            if matches!(a.solved, Solved::Implicit(_)) {
                let eq = &self.sys.eqs[a.eq];
                tears.push(a.var.0);
                residuals.push((eq.lhs, eq.rhs));
            }
        }
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
        let tear_list = tears
            .iter()
            .map(|t| t.to_string())
            .collect::<Vec<_>>()
            .join(", ");
        if rust {
            let _ = writeln!(
                out,
                "fn block_{k}(t: f64, y: &[f64], p: &[f64; NP], v: &mut [f64; N_VARS]) {{"
            );
            let _ = writeln!(out, "    const TEARS: [usize; {n}] = [{tear_list}];");
            let _ = writeln!(
                out,
                "    newton(&TEARS, v, &mut |v: &mut [f64], r: &mut [f64]| resid_{k}(t, y, p, v, r));"
            );
        } else {
            let _ = writeln!(
                out,
                "static void block_{k}(double t, const double *y, const double *p, double *v) {{"
            );
            let _ = writeln!(out, "    static const int tears[{n}] = {{{tear_list}}};");
            let _ = writeln!(out, "    newton({n}, tears, t, y, p, v, resid_{k});");
        }
        let _ = writeln!(out, "}}\n");
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
        for k in 0..n {
            let piv = (k..n).max_by(|&i, &j| a[i * n + k].abs().total_cmp(&a[j * n + k].abs())).unwrap_or(k);
            for j in 0..n { a.swap(k * n + j, piv * n + j); }
            dx.swap(k, piv);
            for i in k + 1..n { let q = a[i * n + k] / a[k * n + k]; for j in k..n { a[i * n + j] -= q * a[k * n + j]; } dx[i] -= q * dx[k]; }
        }
        for k in (0..n).rev() { let mut s = dx[k]; for j in k + 1..n { s -= a[k * n + j] * dx[j]; } dx[k] = s / a[k * n + k]; }
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
"#;

const C_PRELUDE: &str = r#"
#include <math.h>
#include <string.h>

static double pulse(double t, int o, double v1, double v2, double td, double tr, double tf, double pw, double per) {
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

static double sine(double t, int o, double vo, double va, double freq, double td, double theta, double phase) {
    double ph = phase * M_PI / 180.0;
    if (t < td) return o == 0 ? vo + va * sin(ph) : 0.0;
    double s = t - td, w = 2.0 * M_PI * freq, cr = 1.0, ci = 0.0;
    for (int k = 0; k < o; k++) { double nr = -cr * theta - ci * w, ni = cr * w - ci * theta; cr = nr; ci = ni; }
    double d = va * exp(-theta * s) * (cr * sin(w * s + ph) + ci * cos(w * s + ph));
    return o == 0 ? vo + d : d;
}

static double expo(double t, int o, double v1, double v2, double td1, double tau1, double td2, double tau2) {
    double val = o == 0 ? v1 : 0.0;
    if (t >= td1) { double e = exp(-(t - td1) / tau1); val += o == 0 ? (v2 - v1) * (1.0 - e) : -(v2 - v1) * pow(-1.0 / tau1, o) * e; }
    if (t >= td2) { double e = exp(-(t - td2) / tau2); val += o == 0 ? (v1 - v2) * (1.0 - e) : -(v1 - v2) * pow(-1.0 / tau2, o) * e; }
    return val;
}

static double pwl(double t, int o, const double *ts, const double *ys, int n) {
    if (n == 0) return 0.0;
    if (t < ts[0]) return o == 0 ? ys[0] : 0.0;
    int k = 0;
    while (k < n && ts[k] <= t) k++;
    if (k >= n) return o == 0 ? ys[n - 1] : 0.0;
    double s = ts[k] > ts[k - 1] ? (ys[k] - ys[k - 1]) / (ts[k] - ts[k - 1]) : 0.0;
    return o == 0 ? ys[k - 1] + s * (t - ts[k - 1]) : (o == 1 ? s : 0.0);
}

static double diode(int part, int o, double v, double is, double vte, double bv, double g, double cjo, double vj, double m, double fc, double tt) {
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

/* Damped Newton on the tearing variables (finite-difference Jacobian). */
static void newton(int n, const int *tears, double t, const double *y, const double *p, double *v, resid_fn f) {
    double r[64], r1[64], a[64 * 64], dx[64], x0[64];
    if (n > 64) return;
    for (int it = 0; it < 100; it++) {
        f(t, y, p, v, r);
        double base = 0.0; for (int i = 0; i < n; i++) base += r[i] * r[i];
        if (base == 0.0) return;
        for (int j = 0; j < n; j++) {
            double xj = v[tears[j]], h = 1e-7 * (1.0 + fabs(xj));
            v[tears[j]] = xj + h; f(t, y, p, v, r1); v[tears[j]] = xj;
            for (int i = 0; i < n; i++) a[i * n + j] = (r1[i] - r[i]) / h;
        }
        memcpy(dx, r, sizeof(double) * n);
        for (int k = 0; k < n; k++) {
            int piv = k; for (int i = k + 1; i < n; i++) if (fabs(a[i * n + k]) > fabs(a[piv * n + k])) piv = i;
            for (int j = 0; j < n; j++) { double s = a[k * n + j]; a[k * n + j] = a[piv * n + j]; a[piv * n + j] = s; }
            double s = dx[k]; dx[k] = dx[piv]; dx[piv] = s;
            for (int i = k + 1; i < n; i++) { double q = a[i * n + k] / a[k * n + k]; for (int j = k; j < n; j++) a[i * n + j] -= q * a[k * n + j]; dx[i] -= q * dx[k]; }
        }
        for (int k = n - 1; k >= 0; k--) { double s = dx[k]; for (int j = k + 1; j < n; j++) s -= a[k * n + j] * dx[j]; dx[k] = s / a[k * n + k]; }
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
        if (small) return;
    }
}
"#;

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
        out.push_str("#![allow(dead_code, unused_parens, clippy::all)]\n");
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
        }
    }
    // Statements, in chunks; repeated sections as loops.
    let mut stmts = Vec::new();
    let mut run = Vec::new();
    for (k, step) in sched.steps.iter().enumerate() {
        if let Step::Assign(a) = step
            && let Solved::Explicit(e) = a.solved
        {
            run.push(g.shaped(a, e));
            continue;
        }
        reroll(&run, lang, &mut stmts);
        run.clear();
        g.step(step, k, &mut stmts);
    }
    reroll(&run, lang, &mut stmts);
    let chunks: Vec<&[String]> = stmts.chunks(CHUNK).collect();
    for (c, chunk) in chunks.iter().enumerate() {
        if rust {
            // Fixed-size arrays: constant indices need no bounds checks.
            let _ = writeln!(
                out,
                "\n#[inline(never)]\nfn part_{c}(t: f64, y: &[f64], p: &[f64; NP], v: &mut [f64; N_VARS]) {{\n    let _ = (t, y, p);"
            );
        } else {
            let _ = writeln!(
                out,
                "\n__attribute__((noinline)) static void part_{c}(double t, const double *y, const double *p, double *v) {{\n    (void)t; (void)y; (void)p;"
            );
        }
        for s in chunk.iter() {
            let _ = writeln!(out, "{s}");
        }
        out.push_str("}\n");
    }
    // rhs: load states, run the chunks, store derivatives.
    let ders: Vec<u32> = states
        .iter()
        .map(|&s| match sys.vars[s].role {
            VarRole::State { der } => der.0,
            _ => unreachable!("states have derivatives"),
        })
        .collect();
    if rust {
        let _ = writeln!(
            out,
            "\n/// dy/dt = f(t, y): `v` is scratch of N_VARS values (it keeps Newton's warm start)."
        );
        let _ = writeln!(
            out,
            "pub fn rhs(t: f64, y: &[f64], p: &[f64], v: &mut [f64], dy: &mut [f64]) {{"
        );
    } else {
        let _ = writeln!(
            out,
            "\n/* dy/dt = f(t, y): v is scratch of N_VARS values (it keeps Newton's warm start). */"
        );
        let _ = writeln!(
            out,
            "void rhs(double t, const double *y, const double *p, double *v, double *dy) {{"
        );
    }
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
        out.push_str(RUST_ARRAY_VIEWS);
        let _ = writeln!(
            out,
            "    const STATE_VAR: [usize; {}] = [{st}];",
            states.len()
        );
        let _ = writeln!(
            out,
            "    const DER_VAR: [usize; {}] = [{dt}];",
            states.len()
        );
        let _ = writeln!(
            out,
            "    for k in 0..N_STATES {{ v[STATE_VAR[k]] = y[k]; }}"
        );
    } else {
        let _ = writeln!(out, "    static const int STATE_VAR[{ns}] = {{{st}}};");
        let _ = writeln!(out, "    static const int DER_VAR[{ns}] = {{{dt}}};");
        let _ = writeln!(
            out,
            "    for (int k = 0; k < N_STATES; k++) v[STATE_VAR[k]] = y[k];"
        );
    }
    for c in 0..chunks.len() {
        let _ = writeln!(out, "    part_{c}(t, y, p, v);");
    }
    if rust {
        let _ = writeln!(out, "    for k in 0..N_STATES {{ dy[k] = v[DER_VAR[k]]; }}");
    } else {
        let _ = writeln!(
            out,
            "    for (int k = 0; k < N_STATES; k++) dy[k] = v[DER_VAR[k]];"
        );
    }
    out.push_str("}\n");
    // jac_mul by a directional difference (exact enough for Newton; the
    // in-process evaluator has the analytic one).
    if rust {
        out.push_str(
            "\n/// J(t, y) w by a central directional difference.\npub fn jac_mul(t: f64, y: &[f64], p: &[f64], v: &mut [f64], w: &[f64], jw: &mut [f64]) {\n    let n = y.len();\n    let norm = w.iter().fold(0.0f64, |m, x| m.max(x.abs()));\n    if norm == 0.0 { jw.iter_mut().for_each(|x| *x = 0.0); return; }\n    let ys = y.iter().fold(1.0f64, |m, x| m.max(x.abs()));\n    let h = 1e-6 * ys / norm;\n    let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);\n    let yp: Vec<f64> = y.iter().zip(w).map(|(y, w)| y + h * w).collect();\n    let ym: Vec<f64> = y.iter().zip(w).map(|(y, w)| y - h * w).collect();\n    rhs(t, &yp, p, v, &mut a);\n    rhs(t, &ym, p, v, &mut b);\n    for k in 0..n { jw[k] = (a[k] - b[k]) / (2.0 * h); }\n}\n",
        );
    } else {
        out.push_str(
            "\n/* J(t, y) w by a central directional difference. */\nvoid jac_mul(double t, const double *y, const double *p, double *v, const double *w, double *jw) {\n    int n = N_STATES; double norm = 0.0, ys = 1.0;\n    for (int k = 0; k < n; k++) { if (fabs(w[k]) > norm) norm = fabs(w[k]); if (fabs(y[k]) > ys) ys = fabs(y[k]); }\n    if (norm == 0.0) { for (int k = 0; k < n; k++) jw[k] = 0.0; return; }\n    double h = 1e-6 * ys / norm, yp[N_STATES + 1], ym[N_STATES + 1], a[N_STATES + 1], b[N_STATES + 1];\n    for (int k = 0; k < n; k++) { yp[k] = y[k] + h * w[k]; ym[k] = y[k] - h * w[k]; }\n    rhs(t, yp, p, v, a); rhs(t, ym, p, v, b);\n    for (int k = 0; k < n; k++) jw[k] = (a[k] - b[k]) / (2.0 * h);\n}\n",
        );
    }
    out
}
