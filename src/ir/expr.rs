//! Symbolic expressions in a hash-consed arena.
//!
//! Identical subterms share one [`ExprId`]. The constructors fold constants and
//! apply the small algebraic simplifications that keep listings readable
//! (`0 + x`, `1*x`, `a - (-b)`, `-(-x)`).

use std::collections::HashMap;

use hashbrown::hash_table::{Entry, HashTable};
use rustc_hash::FxHasher;
use std::hash::{Hash, Hasher};

use super::device::DeviceFn;
use super::system::{ParamId, SourceId, VarId};

crate::entity_id!(
    /// An expression in an [`ExprArena`]. Operands always have smaller ids than
    /// the expression that uses them (children before parents).
    ExprId,
    "e"
);

fn hash_expr(e: &Expr) -> u64 {
    let mut h = FxHasher::default();
    e.hash(&mut h);
    h.finish()
}

/// The bits of an `f64`, so constants can be hashed.
pub fn bits(x: f64) -> u64 {
    // Fold -0.0 into 0.0 so that both intern as one constant.
    if x == 0.0 { 0 } else { x.to_bits() }
}

/// Built-in functions of one argument.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Func {
    Exp,
    Ln,
    Sqrt,
    Sin,
    Cos,
    Tan,
    Atan,
    Sinh,
    Cosh,
    Tanh,
    Abs,
}

impl Func {
    pub fn name(self) -> &'static str {
        match self {
            Func::Exp => "exp",
            Func::Ln => "ln",
            Func::Sqrt => "sqrt",
            Func::Sin => "sin",
            Func::Cos => "cos",
            Func::Tan => "tan",
            Func::Atan => "atan",
            Func::Sinh => "sinh",
            Func::Cosh => "cosh",
            Func::Tanh => "tanh",
            Func::Abs => "abs",
        }
    }

    /// The derivative rule of the function: the one table that symbolic
    /// differentiation, the tape's tangents and generated code all read.
    pub fn slope(self) -> Slope {
        match self {
            Func::Exp => Slope::Value,
            Func::Ln => Slope::Reciprocal,
            Func::Sqrt => Slope::HalfReciprocalValue,
            Func::Sin => Slope::Call(Func::Cos),
            Func::Cos => Slope::NegCall(Func::Sin),
            Func::Tan => Slope::ReciprocalSquareOf(Func::Cos),
            Func::Atan => Slope::ReciprocalOnePlusSquare,
            Func::Sinh => Slope::Call(Func::Cosh),
            Func::Cosh => Slope::Call(Func::Sinh),
            Func::Tanh => Slope::OneMinusValueSquared,
            Func::Abs => Slope::Sign,
        }
    }

    /// `f′(x)`, given `x` and `fx = f(x)`.
    pub fn derivative(self, x: f64, fx: f64) -> f64 {
        match self.slope() {
            Slope::Value => fx,
            Slope::Reciprocal => 1.0 / x,
            Slope::HalfReciprocalValue => 0.5 / fx,
            Slope::Call(g) => g.apply(x),
            Slope::NegCall(g) => -g.apply(x),
            Slope::ReciprocalSquareOf(g) => {
                let v = g.apply(x);
                1.0 / (v * v)
            }
            Slope::ReciprocalOnePlusSquare => 1.0 / (1.0 + x * x),
            Slope::OneMinusValueSquared => 1.0 - fx * fx,
            Slope::Sign => x.signum(),
        }
    }

    pub fn apply(self, x: f64) -> f64 {
        match self {
            Func::Exp => x.exp(),
            Func::Ln => x.ln(),
            Func::Sqrt => x.sqrt(),
            Func::Sin => x.sin(),
            Func::Cos => x.cos(),
            Func::Tan => x.tan(),
            Func::Atan => x.atan(),
            Func::Sinh => x.sinh(),
            Func::Cosh => x.cosh(),
            Func::Tanh => x.tanh(),
            Func::Abs => x.abs(),
        }
    }
}

/// A derivative rule `f′(x)`, written with the argument `x` and the
/// function's own value `f(x)` (see [`Func::slope`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Slope {
    /// `f′ = f` (exp).
    Value,
    /// `f′ = 1/x` (ln).
    Reciprocal,
    /// `f′ = 1/(2f)` (sqrt).
    HalfReciprocalValue,
    /// `f′ = g(x)` (sin, sinh, cosh).
    Call(Func),
    /// `f′ = −g(x)` (cos).
    NegCall(Func),
    /// `f′ = 1/g(x)²` (tan).
    ReciprocalSquareOf(Func),
    /// `f′ = 1/(1 + x²)` (atan).
    ReciprocalOnePlusSquare,
    /// `f′ = 1 − f²` (tanh).
    OneMinusValueSquared,
    /// `f′ = sign(x)` (abs).
    Sign,
}

/// A comparison, as [`Expr::Cmp`] makes it: 1 where it holds, else 0.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Cmp {
    Lt,
    Le,
    Gt,
    Ge,
    Eq,
    Ne,
}

impl Cmp {
    pub fn symbol(self) -> &'static str {
        match self {
            Cmp::Lt => "<",
            Cmp::Le => "<=",
            Cmp::Gt => ">",
            Cmp::Ge => ">=",
            Cmp::Eq => "==",
            Cmp::Ne => "!=",
        }
    }

    /// 1 where `a op b` holds, else 0 (a NaN operand: 0, but 1 for `!=`).
    pub fn apply(self, a: f64, b: f64) -> f64 {
        let holds = match self {
            Cmp::Lt => a < b,
            Cmp::Le => a <= b,
            Cmp::Gt => a > b,
            Cmp::Ge => a >= b,
            Cmp::Eq => a == b,
            Cmp::Ne => a != b,
        };
        if holds { 1.0 } else { 0.0 }
    }
}

/// `if c != 0 { a } else { b }`: only the chosen operand is used (a NaN in
/// the other one does not leak), as ngspice's B sources choose.
#[inline]
pub fn select(c: f64, a: f64, b: f64) -> f64 {
    if c != 0.0 { a } else { b }
}

/// One node of an expression DAG.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Expr {
    /// A constant, as the bits of an `f64` (see [`bits`]).
    Const(u64),
    Var(VarId),
    Param(ParamId),
    /// Simulation time `t`.
    Time,
    /// d/dt of time: 1 in a transient, 0 at the operating point, where
    /// every source's derivative is 0 (ngspice's first point is its DC
    /// solution). What index reduction makes of `time` in a B source.
    TimeRate,
    /// The `order`-th time derivative of an independent source's waveform.
    Source(SourceId, u8),
    Neg(ExprId),
    Add(ExprId, ExprId),
    Sub(ExprId, ExprId),
    Mul(ExprId, ExprId),
    Div(ExprId, ExprId),
    Pow(ExprId, ExprId),
    Call(Func, ExprId),
    /// A device function (diode current or charge) of one argument.
    Device(DeviceFn, ExprId),
    /// A comparison: 1 where it holds, else 0 (its derivative is 0).
    Cmp(Cmp, ExprId, ExprId),
    /// `Select(c, a, b)`: `a` where `c` is not 0, else `b` (see [`select`]).
    Select(ExprId, ExprId, ExprId),
}

impl Expr {
    /// The operands, left to right (`None` past the arity).
    pub fn operands(self) -> [Option<ExprId>; 3] {
        match self {
            Expr::Neg(a) | Expr::Call(_, a) | Expr::Device(_, a) => [Some(a), None, None],
            Expr::Add(a, b)
            | Expr::Sub(a, b)
            | Expr::Mul(a, b)
            | Expr::Div(a, b)
            | Expr::Pow(a, b)
            | Expr::Cmp(_, a, b) => [Some(a), Some(b), None],
            Expr::Select(c, a, b) => [Some(c), Some(a), Some(b)],
            Expr::Const(_)
            | Expr::Var(_)
            | Expr::Param(_)
            | Expr::Time
            | Expr::TimeRate
            | Expr::Source(..) => [None, None, None],
        }
    }
}

/// The deduplicating arena that owns every expression of a system.
#[derive(Clone, Debug, Default)]
pub struct ExprArena {
    nodes: Vec<Expr>,
    /// Ids of the hashed nodes (all but variables and parameters), keyed by
    /// the node they point to: four bytes a slot keep the table small enough
    /// to stay in cache on systems of a million expressions.
    dedup: HashTable<ExprId>,
    /// The node of each variable and parameter, by index (`u32::MAX`: none).
    var_nodes: Vec<u32>,
    param_nodes: Vec<u32>,
}

/// Terms of a sum written as one left-to-right chain (see [`ExprArena::sum`]).
pub const SUM_CHAIN: usize = 64;

impl ExprArena {
    pub fn new() -> ExprArena {
        ExprArena::default()
    }

    /// An arena with room for `n` expressions (about half of them variable
    /// leaves, which are not hashed).
    pub fn with_capacity(n: usize) -> ExprArena {
        ExprArena {
            nodes: Vec::with_capacity(n),
            dedup: HashTable::with_capacity(n / 2),
            var_nodes: Vec::with_capacity(n / 2),
            param_nodes: Vec::new(),
        }
    }

    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    #[inline]
    pub fn get(&self, id: ExprId) -> Expr {
        self.nodes[id.0 as usize]
    }

    pub fn nodes(&self) -> &[Expr] {
        &self.nodes
    }

    /// Intern `e` as it is, without simplification.
    pub fn intern(&mut self, e: Expr) -> ExprId {
        match e {
            Expr::Var(v) => self.leaf(e, v.0 as usize, false),
            Expr::Param(p) => self.leaf(e, p.0 as usize, true),
            _ => {
                let nodes = &self.nodes;
                let hash = hash_expr(&e);
                match self.dedup.entry(
                    hash,
                    |&id| nodes[id.0 as usize] == e,
                    |&id| hash_expr(&nodes[id.0 as usize]),
                ) {
                    Entry::Occupied(o) => *o.get(),
                    Entry::Vacant(v) => {
                        let id = ExprId(self.nodes.len() as u32);
                        v.insert(id);
                        self.nodes.push(e);
                        id
                    }
                }
            }
        }
    }

    /// Variables and parameters are looked up by index, not hashed: they
    /// are most of the lookups when building big systems.
    fn leaf(&mut self, e: Expr, k: usize, param: bool) -> ExprId {
        let table = if param {
            &mut self.param_nodes
        } else {
            &mut self.var_nodes
        };
        if let Some(&id) = table.get(k)
            && id != u32::MAX
        {
            return ExprId(id);
        }
        if table.len() <= k {
            table.resize(k + 1, u32::MAX);
        }
        let id = self.nodes.len() as u32;
        table[k] = id;
        self.nodes.push(e);
        ExprId(id)
    }

    pub fn constant(&mut self, x: f64) -> ExprId {
        self.intern(Expr::Const(bits(x)))
    }

    pub fn var(&mut self, v: VarId) -> ExprId {
        self.intern(Expr::Var(v))
    }

    pub fn param(&mut self, p: ParamId) -> ExprId {
        self.intern(Expr::Param(p))
    }

    pub fn time(&mut self) -> ExprId {
        self.intern(Expr::Time)
    }

    pub fn time_rate(&mut self) -> ExprId {
        self.intern(Expr::TimeRate)
    }

    pub fn source(&mut self, s: SourceId, order: u8) -> ExprId {
        self.intern(Expr::Source(s, order))
    }

    /// The value of a constant expression node, if it is one.
    pub fn as_const(&self, id: ExprId) -> Option<f64> {
        match self.get(id) {
            Expr::Const(b) => Some(f64::from_bits(b)),
            _ => None,
        }
    }

    fn is_const(&self, id: ExprId, x: f64) -> bool {
        self.as_const(id) == Some(x)
    }

    pub fn neg(&mut self, a: ExprId) -> ExprId {
        match self.get(a) {
            Expr::Const(b) => self.constant(-f64::from_bits(b)),
            Expr::Neg(x) => x,
            Expr::Sub(x, y) => self.intern(Expr::Sub(y, x)),
            _ => self.intern(Expr::Neg(a)),
        }
    }

    pub fn add(&mut self, a: ExprId, b: ExprId) -> ExprId {
        if let (Some(x), Some(y)) = (self.as_const(a), self.as_const(b)) {
            return self.constant(x + y);
        }
        if self.is_const(a, 0.0) {
            return b;
        }
        if self.is_const(b, 0.0) {
            return a;
        }
        if let Expr::Neg(y) = self.get(b) {
            return self.sub(a, y);
        }
        if let Expr::Neg(x) = self.get(a) {
            return self.sub(b, x);
        }
        self.intern(Expr::Add(a, b))
    }

    pub fn sub(&mut self, a: ExprId, b: ExprId) -> ExprId {
        if let (Some(x), Some(y)) = (self.as_const(a), self.as_const(b)) {
            return self.constant(x - y);
        }
        if a == b {
            return self.constant(0.0);
        }
        if self.is_const(b, 0.0) {
            return a;
        }
        if self.is_const(a, 0.0) {
            return self.neg(b);
        }
        if let Expr::Neg(y) = self.get(b) {
            return self.add(a, y);
        }
        self.intern(Expr::Sub(a, b))
    }

    pub fn mul(&mut self, a: ExprId, b: ExprId) -> ExprId {
        if let (Some(x), Some(y)) = (self.as_const(a), self.as_const(b)) {
            return self.constant(x * y);
        }
        if self.is_const(a, 0.0) || self.is_const(b, 0.0) {
            return self.constant(0.0);
        }
        if self.is_const(a, 1.0) {
            return b;
        }
        if self.is_const(b, 1.0) {
            return a;
        }
        if self.is_const(a, -1.0) {
            return self.neg(b);
        }
        if self.is_const(b, -1.0) {
            return self.neg(a);
        }
        match (self.get(a), self.get(b)) {
            (Expr::Neg(x), Expr::Neg(y)) => self.mul(x, y),
            (Expr::Neg(x), _) => {
                let m = self.mul(x, b);
                self.neg(m)
            }
            (_, Expr::Neg(y)) => {
                let m = self.mul(a, y);
                self.neg(m)
            }
            _ => self.intern(Expr::Mul(a, b)),
        }
    }

    pub fn div(&mut self, a: ExprId, b: ExprId) -> ExprId {
        if let (Some(x), Some(y)) = (self.as_const(a), self.as_const(b))
            && y != 0.0
        {
            return self.constant(x / y);
        }
        if self.is_const(b, 1.0) {
            return a;
        }
        if self.is_const(a, 0.0) {
            return a;
        }
        if self.is_const(b, -1.0) {
            return self.neg(a);
        }
        match (self.get(a), self.get(b)) {
            (Expr::Neg(x), Expr::Neg(y)) => self.div(x, y),
            (Expr::Neg(x), _) => {
                let d = self.div(x, b);
                self.neg(d)
            }
            (_, Expr::Neg(y)) => {
                let d = self.div(a, y);
                self.neg(d)
            }
            _ => self.intern(Expr::Div(a, b)),
        }
    }

    pub fn pow(&mut self, a: ExprId, b: ExprId) -> ExprId {
        if let (Some(x), Some(y)) = (self.as_const(a), self.as_const(b)) {
            return self.constant(x.powf(y));
        }
        if self.is_const(b, 1.0) {
            return a;
        }
        if self.is_const(b, 0.0) {
            return self.constant(1.0);
        }
        self.intern(Expr::Pow(a, b))
    }

    pub fn call(&mut self, f: Func, a: ExprId) -> ExprId {
        if let Some(x) = self.as_const(a) {
            return self.constant(f.apply(x));
        }
        match (f, self.get(a)) {
            (Func::Exp, Expr::Call(Func::Ln, x)) | (Func::Ln, Expr::Call(Func::Exp, x)) => x,
            _ => self.intern(Expr::Call(f, a)),
        }
    }

    pub fn cmp(&mut self, op: Cmp, a: ExprId, b: ExprId) -> ExprId {
        if let (Some(x), Some(y)) = (self.as_const(a), self.as_const(b)) {
            return self.constant(op.apply(x, y));
        }
        self.intern(Expr::Cmp(op, a, b))
    }

    /// `a` where `c` is not 0, else `b`.
    pub fn select(&mut self, c: ExprId, a: ExprId, b: ExprId) -> ExprId {
        if let Some(x) = self.as_const(c) {
            return if x != 0.0 { a } else { b };
        }
        if a == b {
            return a;
        }
        self.intern(Expr::Select(c, a, b))
    }

    /// Sum of many terms (an empty sum is 0).
    ///
    /// Up to [`SUM_CHAIN`] terms make a left-to-right chain, `((a + b) + c)`,
    /// which prints as written; longer sums (a node with 10^5 elements) are
    /// chains of that length added pairwise, so that no expression is deeper
    /// than `SUM_CHAIN + log2(terms)` for the recursive passes over it.
    pub fn sum(&mut self, terms: impl IntoIterator<Item = ExprId>) -> ExprId {
        let terms: Vec<ExprId> = terms.into_iter().collect();
        let mut level: Vec<ExprId> = terms
            .chunks(SUM_CHAIN)
            .map(|chunk| {
                let mut acc = chunk[0];
                for &t in &chunk[1..] {
                    acc = self.add(acc, t);
                }
                acc
            })
            .collect();
        while level.len() > 1 {
            level = level
                .chunks(2)
                .map(|p| {
                    if p.len() == 2 {
                        self.add(p[0], p[1])
                    } else {
                        p[0]
                    }
                })
                .collect();
        }
        level.pop().unwrap_or_else(|| self.constant(0.0))
    }

    /// The distinct variables of an expression, in first-occurrence order
    /// (after those already in `out`).
    pub fn vars_into(&self, root: ExprId, out: &mut Vec<VarId>, stack: &mut Vec<ExprId>) {
        stack.clear();
        stack.push(root);
        // Repeats are found by scanning while `out` is short, then by a set
        // (a KCL sum can read 10^5 currents).
        let mut seen: Option<std::collections::HashSet<VarId>> = None;
        while let Some(e) = stack.pop() {
            match self.get(e) {
                Expr::Var(v) => {
                    let new = if out.len() < 32 {
                        !out.contains(&v)
                    } else {
                        seen.get_or_insert_with(|| out.iter().copied().collect())
                            .insert(v)
                    };
                    if new {
                        out.push(v);
                    }
                }
                // Right operand pushed first: variables are listed left to right.
                op => stack.extend(op.operands().into_iter().rev().flatten()),
            }
        }
    }

    /// The nodes of the DAG below `root`, ascending (children first).
    pub fn subtree(&self, root: ExprId) -> Vec<ExprId> {
        let mut stack = vec![root];
        let mut out: Vec<ExprId> = Vec::new();
        // Small trees (the usual equation) check repeats by scanning; large DAGs
        // switch to a hash set so shared subterms are visited once.
        let mut seen: Option<std::collections::HashSet<ExprId>> = None;
        while let Some(e) = stack.pop() {
            let repeat = match &mut seen {
                Some(set) => !set.insert(e),
                None => {
                    if out.len() >= 64 {
                        seen = Some(out.iter().copied().chain([e]).collect());
                        false
                    } else {
                        out.contains(&e)
                    }
                }
            };
            if repeat {
                continue;
            }
            out.push(e);
            stack.extend(self.get(e).operands().into_iter().flatten());
        }
        out.sort_unstable();
        out.dedup();
        out
    }

    /// How many times `v` occurs in the tree of `root` (shared subterms counted
    /// once per use).
    pub fn occurrences(&self, root: ExprId, v: VarId) -> usize {
        // Recursion while the tree is shallow (the usual equation); a deep
        // one (a tree-path sum 10^4 deep) is counted bottom-up with an
        // explicit stack, each shared node once.
        fn shallow(x: &ExprArena, e: ExprId, v: VarId, depth: usize) -> Option<usize> {
            if depth > 128 {
                return None;
            }
            match x.get(e) {
                Expr::Var(y) => Some(usize::from(y == v)),
                op => op
                    .operands()
                    .into_iter()
                    .flatten()
                    .try_fold(0, |n, a| Some(n + shallow(x, a, v, depth + 1)?)),
            }
        }
        if let Some(n) = shallow(self, root, v, 0) {
            return n;
        }
        let mut count: HashMap<ExprId, usize> = HashMap::new();
        let mut stack = vec![(root, false)];
        while let Some((e, expanded)) = stack.pop() {
            if count.contains_key(&e) {
                continue;
            }
            let ops = self.get(e).operands();
            if let Expr::Var(y) = self.get(e) {
                count.insert(e, usize::from(y == v));
            } else if expanded {
                let n = ops.into_iter().flatten().map(|a| count[&a]).sum();
                count.insert(e, n);
            } else {
                stack.push((e, true));
                stack.extend(ops.into_iter().flatten().map(|a| (a, false)));
            }
        }
        count[&root]
    }

    /// Replace variables by expressions (`map` returns `None` to keep one).
    pub fn substitute(
        &mut self,
        root: ExprId,
        map: &mut dyn FnMut(VarId) -> Option<ExprId>,
        memo: &mut HashMap<ExprId, ExprId>,
    ) -> ExprId {
        self.substitute_at(root, map, memo, 0)
    }

    /// [`ExprArena::substitute`] at recursion depth `depth`. Past 128 levels
    /// (the loop formulation's tree-path sums are as deep as the tree: 10^4
    /// and more) the operands are substituted bottom-up with an explicit
    /// stack, each then found memoized.
    fn substitute_at(
        &mut self,
        root: ExprId,
        map: &mut dyn FnMut(VarId) -> Option<ExprId>,
        memo: &mut HashMap<ExprId, ExprId>,
        depth: usize,
    ) -> ExprId {
        if let Some(&r) = memo.get(&root) {
            return r;
        }
        if depth > 128 {
            let mut stack = vec![(root, false)];
            while let Some((e, expanded)) = stack.pop() {
                if memo.contains_key(&e) {
                    continue;
                }
                if expanded {
                    self.substitute_at(e, map, memo, 0);
                } else {
                    stack.push((e, true));
                    let ops = self.get(e).operands();
                    stack.extend(ops.into_iter().rev().flatten().map(|a| (a, false)));
                }
            }
            return memo[&root];
        }
        let d = depth + 1;
        let r = match self.get(root) {
            Expr::Var(v) => map(v).unwrap_or(root),
            Expr::Const(_) | Expr::Param(_) | Expr::Time | Expr::TimeRate | Expr::Source(..) => {
                root
            }
            Expr::Neg(a) => {
                let a = self.substitute_at(a, map, memo, d);
                self.neg(a)
            }
            Expr::Call(f, a) => {
                let a = self.substitute_at(a, map, memo, d);
                self.call(f, a)
            }
            Expr::Device(f, a) => {
                let a = self.substitute_at(a, map, memo, d);
                self.intern(Expr::Device(f, a))
            }
            Expr::Add(a, b) => {
                let (a, b) = (
                    self.substitute_at(a, map, memo, d),
                    self.substitute_at(b, map, memo, d),
                );
                self.add(a, b)
            }
            Expr::Sub(a, b) => {
                let (a, b) = (
                    self.substitute_at(a, map, memo, d),
                    self.substitute_at(b, map, memo, d),
                );
                self.sub(a, b)
            }
            Expr::Mul(a, b) => {
                let (a, b) = (
                    self.substitute_at(a, map, memo, d),
                    self.substitute_at(b, map, memo, d),
                );
                self.mul(a, b)
            }
            Expr::Div(a, b) => {
                let (a, b) = (
                    self.substitute_at(a, map, memo, d),
                    self.substitute_at(b, map, memo, d),
                );
                self.div(a, b)
            }
            Expr::Pow(a, b) => {
                let (a, b) = (
                    self.substitute_at(a, map, memo, d),
                    self.substitute_at(b, map, memo, d),
                );
                self.pow(a, b)
            }
            Expr::Cmp(op, a, b) => {
                let (a, b) = (
                    self.substitute_at(a, map, memo, d),
                    self.substitute_at(b, map, memo, d),
                );
                self.cmp(op, a, b)
            }
            Expr::Select(c, a, b) => {
                let (c, a, b) = (
                    self.substitute_at(c, map, memo, d),
                    self.substitute_at(a, map, memo, d),
                    self.substitute_at(b, map, memo, d),
                );
                self.select(c, a, b)
            }
        };
        memo.insert(root, r);
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn derivative_rules_match_finite_differences() {
        use Func::*;
        for f in [Exp, Ln, Sqrt, Sin, Cos, Tan, Atan, Sinh, Cosh, Tanh, Abs] {
            for x in [0.3, 0.7, 1.9] {
                let h = 1e-6;
                let fd = (f.apply(x + h) - f.apply(x - h)) / (2.0 * h);
                let d = f.derivative(x, f.apply(x));
                assert!(
                    (d - fd).abs() <= 1e-7 * (1.0 + d.abs()),
                    "{f:?} at {x}: {d} vs {fd}"
                );
            }
        }
        assert_eq!(Abs.derivative(-2.0, 2.0), -1.0);
    }
    use crate::ir::EntityId;

    #[test]
    fn constructors_simplify_and_share() {
        let mut a = ExprArena::new();
        let x = a.var(VarId::new(0));
        let y = a.var(VarId::new(1));
        let one = a.constant(1.0);
        let zero = a.constant(0.0);
        assert_eq!(a.mul(one, x), x);
        assert_eq!(a.add(zero, x), x);
        let ny = a.neg(y);
        let s1 = a.sub(x, ny);
        let s2 = a.add(x, y);
        assert_eq!(s1, s2);
        let nn = a.neg(ny);
        assert_eq!(nn, y);
        let two = a.constant(2.0);
        let three = a.constant(3.0);
        let six = a.mul(two, three);
        assert_eq!(a.as_const(six), Some(6.0));
    }

    #[test]
    fn operands_come_first() {
        let mut a = ExprArena::new();
        let x = a.var(VarId::new(0));
        let c = a.constant(2.0);
        let m = a.mul(c, x);
        assert!(m > x && m > c);
    }
}
