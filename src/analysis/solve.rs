//! Solving one equation for its red unknown: symbolic isolation when the
//! equation is linear in it, inversion of a chain of invertible functions when
//! it occurs once, otherwise the equation stays implicit. Also the linearity
//! test used for algebraic blocks. All walks are iterative (children have
//! smaller ids than parents), so deep sums cannot overflow the stack.

use std::collections::HashMap;

use crate::ir::{Expr, ExprArena, ExprId, Func, VarId};

/// The nodes of the DAG below `root`, ascending (children first).
pub fn subtree(x: &ExprArena, root: ExprId) -> Vec<ExprId> {
    x.subtree(root)
}

/// A map from the nodes of a [`subtree`] (sorted ids) to values.
struct NodeMap<'n, T> {
    nodes: &'n [ExprId],
    vals: Vec<T>,
}

impl<T: Copy> NodeMap<'_, T> {
    fn idx(&self, e: ExprId) -> usize {
        self.nodes.binary_search(&e).expect("node of the subtree")
    }
}

impl<T: Copy> std::ops::Index<&ExprId> for NodeMap<'_, T> {
    type Output = T;
    fn index(&self, e: &ExprId) -> &T {
        &self.vals[self.idx(*e)]
    }
}

/// For each node of `nodes` (ascending), whether it depends on a variable
/// for which `is_var` holds.
fn dependence<'n>(
    x: &ExprArena,
    nodes: &'n [ExprId],
    is_var: &dyn Fn(VarId) -> bool,
) -> NodeMap<'n, bool> {
    let mut dep = NodeMap {
        nodes,
        vals: Vec::with_capacity(nodes.len()),
    };
    for &n in nodes {
        let d = match x.get(n) {
            Expr::Var(v) => is_var(v),
            op => op.operands().into_iter().flatten().any(|a| dep[&a]),
        };
        dep.vals.push(d);
    }
    dep
}

/// The variables of `root` that a select on other variables flips in sign,
/// `c ? a : −a` (sorted): as a tear, such a variable holds its value while
/// the others flip the condition, so the residual jumps by `2a` (a
/// MOSFET's current in its own frame, `vds ≥ 0 ? id : −id`, unless `id`
/// is 0). An arm that only one side has, or both alike, is continuous
/// where the condition's own terms make it so (`vds ≥ 0 ? vd − vg : vs − vg`).
pub fn switched_vars(x: &ExprArena, root: ExprId) -> Vec<VarId> {
    let nodes = subtree(x, root);
    let vars_of = |e: ExprId| -> Vec<VarId> {
        let mut v: Vec<VarId> = subtree(x, e)
            .into_iter()
            .filter_map(|n| match x.get(n) {
                Expr::Var(v) => Some(v),
                _ => None,
            })
            .collect();
        v.sort_unstable();
        v.dedup();
        v
    };
    let mut out = Vec::new();
    for &n in &nodes {
        if let Expr::Select(c, a, b) = x.get(n) {
            let negated = x.get(a) == Expr::Neg(b) || x.get(b) == Expr::Neg(a);
            let cond = vars_of(c);
            if !negated || cond.is_empty() {
                continue;
            }
            out.extend(
                vars_of(a)
                    .into_iter()
                    .filter(|v| cond.binary_search(v).is_err()),
            );
        }
    }
    out.sort_unstable();
    out.dedup();
    out
}

/// Whether `root` is affine in the variables selected by `is_var`.
pub fn is_linear_in(x: &ExprArena, root: ExprId, is_var: &dyn Fn(VarId) -> bool) -> bool {
    affine_in(x, root, is_var, false)
}

/// Whether `root` is affine in the selected variables once every other
/// variable is fixed: as [`is_linear_in`], but a select whose condition does
/// not depend on them takes one of two affine branches. A block's solve holds
/// the states fixed, so a junction's diffusion charge under a guarded square
/// root (`x > 0 ? sqrt(x) : 0` of the states) leaves its derivative affine.
pub fn is_piecewise_affine_in(x: &ExprArena, root: ExprId, is_var: &dyn Fn(VarId) -> bool) -> bool {
    affine_in(x, root, is_var, true)
}

fn affine_in(
    x: &ExprArena,
    root: ExprId,
    is_var: &dyn Fn(VarId) -> bool,
    branches_fixed: bool,
) -> bool {
    let nodes = subtree(x, root);
    let dep = dependence(x, &nodes, is_var);
    nodes.iter().all(|&n| match x.get(n) {
        Expr::Mul(a, b) => !(dep[&a] && dep[&b]),
        Expr::Div(_, b) => !dep[&b],
        Expr::Pow(a, b) => !(dep[&a] || dep[&b]),
        Expr::Call(_, a) | Expr::Device(_, a) => !dep[&a],
        Expr::Cmp(_, a, b) => !(dep[&a] || dep[&b]),
        Expr::Select(c, _, _) if branches_fixed => !dep[&c],
        Expr::Select(c, a, b) => !(dep[&c] || dep[&a] || dep[&b]),
        _ => true,
    })
}

/// Write `root = a*v + b` with `a`, `b` free of `v`, if `root` is affine in `v`.
pub fn linear_coeffs(x: &mut ExprArena, root: ExprId, v: VarId) -> Option<(ExprId, ExprId)> {
    let nodes = subtree(x, root);
    let dep = dependence(x, &nodes, &|w| w == v);
    let mut lin: HashMap<ExprId, (ExprId, ExprId)> = HashMap::with_capacity(8);
    let zero = x.constant(0.0);
    let one = x.constant(1.0);
    for &n in &nodes {
        if !dep[&n] {
            continue;
        }
        let get = |lin: &HashMap<ExprId, (ExprId, ExprId)>, e: ExprId| -> (ExprId, ExprId) {
            if dep[&e] { lin[&e] } else { (zero, e) }
        };
        let r = match x.get(n) {
            Expr::Var(_) => (one, zero),
            Expr::Neg(a) => {
                let (a1, b1) = get(&lin, a);
                (x.neg(a1), x.neg(b1))
            }
            Expr::Add(a, b) => {
                let ((a1, b1), (a2, b2)) = (get(&lin, a), get(&lin, b));
                (x.add(a1, a2), x.add(b1, b2))
            }
            Expr::Sub(a, b) => {
                let ((a1, b1), (a2, b2)) = (get(&lin, a), get(&lin, b));
                (x.sub(a1, a2), x.sub(b1, b2))
            }
            Expr::Mul(a, b) if !dep[&a] => {
                let (a2, b2) = lin[&b];
                (x.mul(a, a2), x.mul(a, b2))
            }
            Expr::Mul(a, b) if !dep[&b] => {
                let (a1, b1) = lin[&a];
                (x.mul(a1, b), x.mul(b1, b))
            }
            Expr::Div(a, b) if !dep[&b] => {
                let (a1, b1) = lin[&a];
                (x.div(a1, b), x.div(b1, b))
            }
            _ => return None,
        };
        lin.insert(n, r);
    }
    Some(if dep[&root] { lin[&root] } else { (zero, root) })
}

/// Solve `f(v) = target` where `v` occurs exactly once in `f`, by inverting
/// the chain of operations from the root down to `v`.
pub fn invert(x: &mut ExprArena, f: ExprId, v: VarId, target: ExprId) -> Option<ExprId> {
    if x.occurrences(f, v) != 1 {
        return None;
    }
    let nodes = subtree(x, f);
    let dep = dependence(x, &nodes, &|w| w == v);
    let (mut cur, mut t) = (f, target);
    loop {
        match x.get(cur) {
            Expr::Var(w) if w == v => return Some(t),
            Expr::Neg(a) => {
                t = x.neg(t);
                cur = a;
            }
            Expr::Add(a, b) => {
                let (inner, other) = if dep[&a] { (a, b) } else { (b, a) };
                t = x.sub(t, other);
                cur = inner;
            }
            Expr::Sub(a, b) => {
                if dep[&a] {
                    t = x.add(t, b);
                    cur = a;
                } else {
                    t = x.sub(a, t);
                    cur = b;
                }
            }
            Expr::Mul(a, b) => {
                let (inner, other) = if dep[&a] { (a, b) } else { (b, a) };
                t = x.div(t, other);
                cur = inner;
            }
            Expr::Div(a, b) => {
                if dep[&a] {
                    t = x.mul(t, b);
                    cur = a;
                } else {
                    t = x.div(a, t);
                    cur = b;
                }
            }
            Expr::Call(Func::Exp, a) => {
                t = x.call(Func::Ln, t);
                cur = a;
            }
            Expr::Call(Func::Ln, a) => {
                t = x.call(Func::Exp, t);
                cur = a;
            }
            Expr::Call(Func::Sqrt, a) => {
                t = x.mul(t, t);
                cur = a;
            }
            Expr::Call(Func::Tan, a) => {
                t = x.call(Func::Atan, t);
                cur = a;
            }
            Expr::Call(Func::Atan, a) => {
                t = x.call(Func::Tan, t);
                cur = a;
            }
            _ => return None,
        }
    }
}

/// How an equation was solved for its unknown.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Solved {
    /// `v := expr`.
    Explicit(ExprId),
    /// `0 = residual`, solved for `v` numerically.
    Implicit(ExprId),
}

/// Solve `lhs = rhs` for `v`.
pub fn solve_for(x: &mut ExprArena, lhs: ExprId, rhs: ExprId, v: VarId) -> Solved {
    // The common case first: `v = expr` or `expr = v`.
    if x.get(lhs) == Expr::Var(v) && x.occurrences(rhs, v) == 0 {
        return Solved::Explicit(rhs);
    }
    if x.get(rhs) == Expr::Var(v) && x.occurrences(lhs, v) == 0 {
        return Solved::Explicit(lhs);
    }
    let in_l = x.occurrences(lhs, v) > 0;
    let in_r = x.occurrences(rhs, v) > 0;
    let (side, other) = match (in_l, in_r) {
        (true, false) => (lhs, rhs),
        (false, true) => (rhs, lhs),
        _ => {
            let f = x.sub(lhs, rhs);
            if let Some((a, b)) = linear_coeffs(x, f, v)
                && x.as_const(a) != Some(0.0)
            {
                let nb = x.neg(b);
                return Solved::Explicit(x.div(nb, a));
            }
            return Solved::Implicit(f);
        }
    };
    // One operation away from `v` (Ohm's law, a KCL of two terms): solved
    // without the general linear walk, which builds maps per equation.
    let direct = |x: &mut ExprArena, a: ExprId, w: ExprId| {
        x.get(w) == Expr::Var(v) && x.occurrences(a, v) == 0
    };
    match x.get(side) {
        Expr::Mul(a, w) | Expr::Mul(w, a) if direct(x, a, w) && x.as_const(a) != Some(0.0) => {
            return Solved::Explicit(x.div(other, a));
        }
        Expr::Add(a, w) | Expr::Add(w, a) if direct(x, a, w) => {
            return Solved::Explicit(x.sub(other, a));
        }
        _ => {}
    }
    if let Some((a, b)) = linear_coeffs(x, side, v)
        && x.as_const(a) != Some(0.0)
    {
        let num = x.sub(other, b);
        return Solved::Explicit(x.div(num, a));
    }
    if let Some(e) = invert(x, side, v, other) {
        return Solved::Explicit(e);
    }
    Solved::Implicit(x.sub(lhs, rhs))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ir::{EquationSystem, Origin, OriginKind, VarKind, print};

    fn sys() -> (EquationSystem, VarId, VarId) {
        let mut s = EquationSystem::default();
        let o = Origin {
            kind: OriginKind::Element { name: "R1".into() },
        };
        let u = s.add_var("u", VarKind::BranchVoltage, o.clone());
        let i = s.add_var("i", VarKind::BranchCurrent, o);
        (s, u, i)
    }

    /// A frame current (`vds ≥ 0 ? id : −id`) is switched by its select; a
    /// node potential in one arm of a frame's gate voltage, or in both
    /// alike, is not.
    #[test]
    fn only_a_sign_flip_switches_an_unknown() {
        use crate::ir::Cmp;
        let (mut s, vds, id) = sys();
        let o = Origin {
            kind: OriginKind::Element { name: "M1".into() },
        };
        let vd = s.add_var("vd", VarKind::Potential, o.clone());
        let vg = s.add_var("vg", VarKind::Potential, o);
        let x = &mut s.exprs;
        let (e_vds, e_id, e_vd, e_vg) = (x.var(vds), x.var(id), x.var(vd), x.var(vg));
        let zero = x.constant(0.0);
        let c = x.cmp(Cmp::Ge, e_vds, zero);
        let minus_id = x.neg(e_id);
        let current = x.select(c, e_id, minus_id);
        assert_eq!(switched_vars(x, current), vec![id]);
        let a = x.sub(e_vd, e_vg);
        let b = x.neg(e_vg);
        let gate = x.select(c, a, b);
        assert!(switched_vars(x, gate).is_empty());
        // A condition on the unknown itself is its own switch: continuous.
        let c_id = x.cmp(Cmp::Ge, e_id, zero);
        let own = x.select(c_id, e_id, minus_id);
        assert!(switched_vars(x, own).is_empty());
    }

    #[test]
    fn ohm_both_ways() {
        let (mut s, u, i) = sys();
        let p = s.add_param("R1".into(), 1e3);
        let (pe, ue, ie) = (s.exprs.param(p), s.exprs.var(u), s.exprs.var(i));
        let rhs = s.exprs.mul(pe, ie);
        let Solved::Explicit(e) = solve_for(&mut s.exprs, ue, rhs, i) else {
            panic!()
        };
        assert_eq!(print::expr(&s, e), "u/R1");
        let Solved::Explicit(e) = solve_for(&mut s.exprs, ue, rhs, u) else {
            panic!()
        };
        assert_eq!(print::expr(&s, e), "R1*i");
    }

    #[test]
    fn diode_inverts_through_ln() {
        let (mut s, u, i) = sys();
        let is = s.add_param("is".into(), 1e-14);
        let nvt = s.add_param("nvt".into(), 0.025);
        let x = &mut s.exprs;
        let (ise, nvte, ue, ie) = (x.param(is), x.param(nvt), x.var(u), x.var(i));
        let arg = x.div(ue, nvte);
        let ex = x.call(Func::Exp, arg);
        let one = x.constant(1.0);
        let em1 = x.sub(ex, one);
        let rhs = x.mul(ise, em1);
        let Solved::Explicit(e) = solve_for(x, ie, rhs, u) else {
            panic!()
        };
        assert_eq!(print::expr(&s, e), "ln(i/is + 1)*nvt");
    }

    #[test]
    fn kcl_isolates_with_signs() {
        let (mut s, u, i) = sys();
        let x = &mut s.exprs;
        let (ue, ie) = (x.var(u), x.var(i));
        let zero = x.constant(0.0);
        let sum = x.add(ue, ie);
        let Solved::Explicit(e) = solve_for(x, zero, sum, u) else {
            panic!()
        };
        assert_eq!(print::expr(&s, e), "-i");
    }
}
