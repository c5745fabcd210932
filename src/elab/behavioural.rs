//! B sources: the `V=`/`I=` expression lowered to a [`BExpr`]. Parameters
//! become numbers, `.func` calls are inlined, `v(a)` names a node and
//! `i(v1)` a controlling V source (resolved once every element exists); the
//! functions ngspice's B sources know become the IR's operations
//! (comparisons and choices for `if`, `u`, `min`, `limit`, `pwl`).

use super::{Arith, BExpr, BNode, Elab, ElabError, ElementKind, GROUND, Scope};
use crate::diag::Span;
use crate::front::ast::{self, Value};
use crate::front::expr::{BinOp, PExpr};
use crate::ir::{Cmp, Func};

/// Expression nodes a B source may expand to (`.func`s inlined): a bound on
/// the memory a few lines of nested functions can ask for.
const MAX_NODES: usize = 100_000;
/// `.func` calls nested deeper than this are refused.
const MAX_DEPTH: usize = 64;

/// The lowering of one expression into `out`'s arena.
struct Lower<'e, 's, 'a> {
    elab: &'e mut Elab,
    scope: &'e Scope<'s, 'a>,
    /// The expression as written, and where (errors point at it).
    text: &'e str,
    span: Span,
    out: BExpr,
    /// Controlling V sources by hierarchical key, in order of first use.
    controls: Vec<String>,
    depth: usize,
}

/// A node of the arena being built.
type N = u32;
type Lowered = Result<N, ElabError>;
/// `.func` arguments bound to their lowered values.
type Env = [(String, N)];

impl Elab {
    /// A B source's kind; its controlling sources' keys are left in
    /// `self.b_controls` for the caller to resolve.
    pub(super) fn behavioural(
        &mut self,
        current: bool,
        expr: &PExpr,
        text: &str,
        span: Span,
        scope: &Scope<'_, '_>,
    ) -> Option<ElementKind> {
        let mut l = Lower {
            elab: self,
            scope,
            text,
            span,
            out: BExpr::default(),
            controls: Vec::new(),
            depth: 0,
        };
        match l.lower(expr, &[]) {
            Ok(_) => {
                let (out, controls) = (std::mem::take(&mut l.out), std::mem::take(&mut l.controls));
                let n = controls.len();
                self.b_controls = controls;
                Some(ElementKind::Behavioural {
                    current,
                    expr: Box::new(out),
                    controls: vec![super::ElemId(u32::MAX); n],
                })
            }
            Err(e) => {
                self.errors.push(e);
                None
            }
        }
    }
}

impl Lower<'_, '_, '_> {
    fn bad(&self, reason: String) -> ElabError {
        ElabError::BadValue {
            span: self.span,
            text: self.text.to_string(),
            reason,
        }
    }

    fn push(&mut self, n: BNode) -> Lowered {
        if self.out.nodes.len() >= MAX_NODES {
            return Err(self.bad(format!("it expands to more than {MAX_NODES} operations")));
        }
        self.out.nodes.push(n);
        Ok((self.out.nodes.len() - 1) as N)
    }

    fn num(&mut self, x: f64) -> Lowered {
        self.push(BNode::Num(x))
    }

    fn cmp(&mut self, op: Cmp, a: N, b: N) -> Lowered {
        self.push(BNode::Cmp(op, a, b))
    }

    fn cmp0(&mut self, op: Cmp, a: N) -> Lowered {
        let z = self.num(0.0)?;
        self.cmp(op, a, z)
    }

    /// A comparison whose value jumps where it flips: a state event.
    fn event(&mut self, c: Lowered) -> Lowered {
        let c = c?;
        self.out.events.push(c);
        Ok(c)
    }

    fn select(&mut self, c: N, a: N, b: N) -> Lowered {
        self.push(BNode::Select(c, a, b))
    }

    fn arith(&mut self, op: Arith, a: N, b: N) -> Lowered {
        self.push(BNode::Arith(op, a, b))
    }

    fn lower(&mut self, e: &PExpr, env: &Env) -> Lowered {
        match e {
            PExpr::Num(x) => self.num(*x),
            PExpr::Ident(name) => self.ident(name, env),
            PExpr::Neg(a) => {
                let a = self.lower(a, env)?;
                self.push(BNode::Neg(a))
            }
            PExpr::Not(a) => {
                let a = self.lower(a, env)?;
                let c = self.cmp0(Cmp::Eq, a);
                self.event(c)
            }
            PExpr::Ternary(c, x, y) => {
                let c = self.lower(c, env)?;
                let (x, y) = (self.lower(x, env)?, self.lower(y, env)?);
                self.select(c, x, y)
            }
            PExpr::Bin(op, x, y) => {
                let (x, y) = (self.lower(x, env)?, self.lower(y, env)?);
                self.binary(*op, x, y)
            }
            PExpr::Probe { current, args } => self.probe(*current, args),
            PExpr::Call(name, args) => self.call(name, args, env),
        }
    }

    fn binary(&mut self, op: BinOp, x: N, y: N) -> Lowered {
        match op {
            BinOp::Add => self.arith(Arith::Add, x, y),
            BinOp::Sub => self.arith(Arith::Sub, x, y),
            BinOp::Mul => self.arith(Arith::Mul, x, y),
            BinOp::Div => self.arith(Arith::Div, x, y),
            BinOp::Pow => self.arith(Arith::Pow, x, y),
            BinOp::Cmp(op) => {
                let c = self.cmp(op, x, y);
                self.event(c)
            }
            BinOp::And => {
                let ty = self.cmp0(Cmp::Ne, y);
                let (ty, z) = (self.event(ty)?, self.num(0.0)?);
                self.select(x, ty, z)
            }
            BinOp::Or => {
                let one = self.num(1.0)?;
                let ty = self.cmp0(Cmp::Ne, y);
                let ty = self.event(ty)?;
                self.select(x, one, ty)
            }
        }
    }

    fn ident(&mut self, name: &str, env: &Env) -> Lowered {
        if let Some(&(_, v)) = env.iter().rev().find(|(n, _)| n == name) {
            return Ok(v);
        }
        if name == "time" {
            return self.push(BNode::Time);
        }
        if let Some(v) = self.scope.param(name) {
            return self.num(v);
        }
        match name {
            "pi" => self.num(std::f64::consts::PI),
            "e" => self.num(std::f64::consts::E),
            "temper" => {
                let t = self.elab.circuit.options.temp.unwrap_or(27.0);
                self.num(t)
            }
            _ => Err(ElabError::UndefinedParam {
                span: self.span,
                name: name.to_string(),
            }),
        }
    }

    /// `v(a)`, `v(a, b)`, `i(v1)`.
    fn probe(&mut self, current: bool, args: &[String]) -> Lowered {
        if current {
            let key = format!("{}{}", self.scope.prefix, args[0]).to_ascii_lowercase();
            let k = match self.controls.iter().position(|c| *c == key) {
                Some(k) => k,
                None => {
                    self.controls.push(key);
                    self.controls.len() - 1
                }
            };
            return self.push(BNode::Current(k as u32));
        }
        let mut pots = Vec::with_capacity(2);
        for name in args {
            let n = ast::Name {
                text: name,
                span: self.span,
            };
            let id = self.elab.node(&n, self.scope);
            pots.push(if id == GROUND {
                self.num(0.0)?
            } else {
                self.push(BNode::Pot(id))?
            });
        }
        match pots[..] {
            [a] => Ok(a),
            [a, b] => self.arith(Arith::Sub, a, b),
            _ => unreachable!("the parser reads one or two nodes"),
        }
    }

    fn call(&mut self, name: &str, args: &[PExpr], env: &Env) -> Lowered {
        if let Some(f) = self.scope.func(name) {
            return self.user(f, name, args, env);
        }
        let func = match name {
            "exp" => Some(Func::Exp),
            "ln" | "log" => Some(Func::Ln),
            "sqrt" => Some(Func::Sqrt),
            "sin" => Some(Func::Sin),
            "cos" => Some(Func::Cos),
            "tan" => Some(Func::Tan),
            "atan" | "arctan" => Some(Func::Atan),
            "sinh" => Some(Func::Sinh),
            "cosh" => Some(Func::Cosh),
            "tanh" => Some(Func::Tanh),
            "abs" => Some(Func::Abs),
            _ => None,
        };
        let arity = match (func, name) {
            (Some(_), _) | (None, "log10" | "u" | "step" | "uramp" | "sgn" | "sign" | "ddt") => {
                Some(1)
            }
            (None, "pow" | "pwr" | "min" | "max") => Some(2),
            (None, "if" | "limit") => Some(3),
            (None, "pwl") => None,
            _ => return Err(self.bad(format!("unknown function `{name}`"))),
        };
        if let Some(n) = arity
            && args.len() != n
        {
            return Err(self.bad(format!("`{name}` takes {n} argument(s)")));
        }
        let mut a = Vec::with_capacity(args.len());
        for x in args {
            a.push(self.lower(x, env)?);
        }
        if let Some(f) = func {
            return self.push(BNode::Call(f, a[0]));
        }
        match name {
            "log10" => {
                let ln = self.push(BNode::Call(Func::Ln, a[0]))?;
                let k = self.num(std::f64::consts::LOG10_E)?;
                self.arith(Arith::Mul, ln, k)
            }
            "pow" => self.arith(Arith::Pow, a[0], a[1]),
            "ddt" => self.push(BNode::Ddt(a[0])),
            // ngspice: sign(x)·|x|^y.
            "pwr" => {
                let abs = self.push(BNode::Call(Func::Abs, a[0]))?;
                let mag = self.arith(Arith::Pow, abs, a[1])?;
                let neg = self.push(BNode::Neg(mag))?;
                let below = self.cmp0(Cmp::Lt, a[0])?;
                self.select(below, neg, mag)
            }
            "min" | "max" => {
                let op = if name == "min" { Cmp::Lt } else { Cmp::Gt };
                let c = self.cmp(op, a[0], a[1])?;
                self.select(c, a[0], a[1])
            }
            // ngspice: 0 below zero, 1 above, 0.5 at zero.
            "u" | "step" => {
                let (pos, negc) = (self.cmp0(Cmp::Gt, a[0]), self.cmp0(Cmp::Lt, a[0]));
                let (pos, negc) = (self.event(pos)?, self.event(negc)?);
                let (one, zero, half) = (self.num(1.0)?, self.num(0.0)?, self.num(0.5)?);
                let low = self.select(negc, zero, half)?;
                self.select(pos, one, low)
            }
            "uramp" => {
                let (c, z) = (self.cmp0(Cmp::Gt, a[0])?, self.num(0.0)?);
                self.select(c, a[0], z)
            }
            "sgn" | "sign" => {
                let (pos, negc) = (self.cmp0(Cmp::Gt, a[0]), self.cmp0(Cmp::Lt, a[0]));
                let (pos, negc) = (self.event(pos)?, self.event(negc)?);
                let (one, minus, zero) = (self.num(1.0)?, self.num(-1.0)?, self.num(0.0)?);
                let neg = self.select(negc, minus, zero)?;
                self.select(pos, one, neg)
            }
            "if" => self.select(a[0], a[1], a[2]),
            "limit" => {
                // A clamp between the two bounds in either order, as
                // ngspice's PSpice mode defines it (TI's TLC555 writes
                // `LIMIT(x, upper, 0)`); Xyce's agrees where lo ≤ hi.
                let (x, a1, a2) = (a[0], a[1], a[2]);
                let swap = self.cmp(Cmp::Gt, a1, a2)?;
                let lo = self.select(swap, a2, a1)?;
                let hi = self.select(swap, a1, a2)?;
                let c_hi = self.cmp(Cmp::Gt, x, hi)?;
                let above = self.select(c_hi, hi, x)?;
                let c_lo = self.cmp(Cmp::Lt, x, lo)?;
                self.select(c_lo, lo, above)
            }
            _ => self.pwl(&a),
        }
    }

    /// `pwl(x, x1, y1, x2, y2, ...)`: linear between the points and, as
    /// ngspice extends it, along the end segments outside them.
    fn pwl(&mut self, a: &[N]) -> Lowered {
        if a.len() < 5 || a.len().is_multiple_of(2) {
            return Err(
                self.bad("`pwl` takes its input and then at least two points `x, y`".into())
            );
        }
        let value = |k: N| match self.out.nodes[k as usize] {
            BNode::Num(v) => Some(v),
            BNode::Neg(m) => match self.out.nodes[m as usize] {
                BNode::Num(v) => Some(-v),
                _ => None,
            },
            _ => None,
        };
        let pts: Option<Vec<(f64, f64)>> = a[1..]
            .chunks(2)
            .map(|p| Some((value(p[0])?, value(p[1])?)))
            .collect();
        let Some(pts) = pts else {
            return Err(self.bad("`pwl`'s points must be numbers".into()));
        };
        if pts.windows(2).any(|w| w[1].0 < w[0].0) {
            return Err(self.bad("`pwl`'s points must be in increasing x".into()));
        }
        let x = a[0];
        // Segment k joins points k and k+1; x below point k+1 takes the
        // first such segment, and the end segments extend past the ends.
        let n = pts.len();
        let mut acc = self.segment(x, pts[n - 2], pts[n - 1])?;
        for k in (0..n - 2).rev() {
            let seg = self.segment(x, pts[k], pts[k + 1])?;
            let nx1 = self.num(pts[k + 1].0)?;
            let below = self.cmp(Cmp::Lt, x, nx1)?;
            acc = self.select(below, seg, acc)?;
        }
        Ok(acc)
    }

    /// The line through two points at `x` (a vertical one: its upper value).
    fn segment(&mut self, x: N, (x0, y0): (f64, f64), (x1, y1): (f64, f64)) -> Lowered {
        if x1 <= x0 {
            return self.num(y1);
        }
        let (nx0, ny0) = (self.num(x0)?, self.num(y0)?);
        let slope = self.num((y1 - y0) / (x1 - x0))?;
        let dx = self.arith(Arith::Sub, x, nx0)?;
        let rise = self.arith(Arith::Mul, slope, dx)?;
        self.arith(Arith::Add, ny0, rise)
    }

    /// A `.func` inlined with its arguments bound.
    fn user(&mut self, f: &ast::FuncDef<'_>, name: &str, args: &[PExpr], env: &Env) -> Lowered {
        if args.len() != f.params.len() {
            return Err(self.bad(format!("`{name}` takes {} argument(s)", f.params.len())));
        }
        if self.depth >= MAX_DEPTH {
            return Err(self.bad(format!(
                "`.func` calls are nested more than {MAX_DEPTH} deep (at `{name}`)"
            )));
        }
        let mut inner = Vec::with_capacity(args.len());
        for (p, a) in f.params.iter().zip(args) {
            let v = self.lower(a, env)?;
            inner.push((p.key(), v));
        }
        self.depth += 1;
        let r = match &f.body {
            Value::Num { value, .. } => self.num(*value),
            // An unbraced body (`.func sq(x) = x*x`) is one word.
            Value::Ident(n) => match crate::front::expr::parse_expr(n.text) {
                Ok(e) => self.lower(&e, &inner),
                Err(_) => Err(self.bad(format!("cannot read the body of `{name}`"))),
            },
            Value::Expr { expr, .. } => self.lower(expr, &inner),
        };
        self.depth -= 1;
        r
    }
}
