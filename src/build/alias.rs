//! Alias elimination: equations `x = y`, `x = -y` (also `0 = x + y`) and
//! `x = known` (a constant, parameter or source function) are removed, and
//! the eliminated variable is replaced everywhere. States and derivatives
//! are never eliminated; an alias between two states is kept (it is a
//! structural singularity for the analysis to report).

use std::collections::HashMap;

use super::Built;
use crate::elab::{Circuit, ElementKind};
use crate::ir::{EqId, Expr, ExprId, IdVec, VarId, VarKind, VarRole, print};

/// How strongly a variable should be kept (higher survives); 8 and up are
/// never eliminated. `passive`: the variable belongs to an R, C, L or D.
fn keep_rank(b: &Built, v: VarId, passive: bool) -> u8 {
    let var = &b.system.vars[v];
    match var.role {
        VarRole::State { .. } => 9,
        VarRole::Derivative { .. } => 8,
        VarRole::Unknown => match var.kind {
            VarKind::Derivative | VarKind::Charge => 8,
            VarKind::Potential => 3,
            // Passive elements' variables read better than sources'.
            VarKind::BranchVoltage | VarKind::BranchCurrent if passive => 5,
            VarKind::BranchVoltage | VarKind::BranchCurrent => 4,
        },
    }
}

#[derive(Clone, Copy)]
struct Link {
    parent: VarId,
    /// `self = sign * parent`
    sign: f64,
}

struct Aliases {
    link: IdVec<VarId, Option<Link>>,
    /// For roots: a known value, `root = value`.
    value: IdVec<VarId, Option<ExprId>>,
}

impl Aliases {
    /// The root of `v` and `v = sign * root`, with the path compressed.
    /// Two passes, no recursion: a chain of 3·10^5 aliases (the currents of
    /// resistors in series) would overflow the stack.
    fn find(&mut self, v: VarId) -> (VarId, f64) {
        let (mut root, mut sign) = (v, 1.0);
        while let Some(l) = self.link[root] {
            sign *= l.sign;
            root = l.parent;
        }
        // Point every variable on the path at the root, with its own sign.
        let (mut x, mut s) = (v, sign);
        while let Some(l) = self.link[x] {
            self.link[x] = Some(Link {
                parent: root,
                sign: s,
            });
            s *= l.sign;
            x = l.parent;
        }
        (root, sign)
    }
}

/// Classify `lhs = rhs` as an alias: `Some((a, sign, b))` for `a = sign*b`.
fn var_alias(b: &Built, lhs: ExprId, rhs: ExprId) -> Option<(VarId, f64, VarId)> {
    let x = &b.system.exprs;
    let as_signed = |e: ExprId| match x.get(e) {
        Expr::Var(v) => Some((v, 1.0)),
        Expr::Neg(a) => match x.get(a) {
            Expr::Var(v) => Some((v, -1.0)),
            _ => None,
        },
        _ => None,
    };
    if let (Some((a, sa)), Some((c, sc))) = (as_signed(lhs), as_signed(rhs)) {
        return Some((a, sa * sc, c));
    }
    // 0 = a + b, 0 = a - b
    let zero = |e: ExprId| x.as_const(e) == Some(0.0);
    let pair = |e: ExprId| match x.get(e) {
        Expr::Add(p, q) => Some((as_signed(p)?, as_signed(q)?, 1.0)),
        Expr::Sub(p, q) => Some((as_signed(p)?, as_signed(q)?, -1.0)),
        _ => None,
    };
    let sum = if zero(lhs) {
        pair(rhs)
    } else if zero(rhs) {
        pair(lhs)
    } else {
        None
    };
    // sp*p + op*sq*q = 0  =>  p = -(op*sq/sp) q
    sum.map(|((p, sp), (q, sq), op)| (p, -op * sq * sp, q))
}

/// `x = known`, where known mentions no variable.
fn value_alias(b: &Built, lhs: ExprId, rhs: ExprId) -> Option<(VarId, ExprId)> {
    let x = &b.system.exprs;
    let mut vars = Vec::new();
    let mut stack = Vec::new();
    x.vars_into(rhs, &mut vars, &mut stack);
    match (x.get(lhs), vars.is_empty()) {
        (Expr::Var(v), true) => Some((v, rhs)),
        _ => None,
    }
}

/// Remove the alias equations of `b` and replace each eliminated variable
/// by its root (or the root's known value) everywhere: in the equations
/// left and in the node potentials.
pub fn eliminate(b: &mut Built, circuit: &Circuit) {
    let passive = passive_vars(b, circuit);
    let ranks: Vec<u8> = b
        .system
        .vars
        .ids()
        .map(|v| keep_rank(b, v, passive[v.0 as usize]))
        .collect();
    let n = b.system.vars.len();
    let mut al = Aliases {
        link: IdVec::filled(n, None),
        value: IdVec::filled(n, None),
    };
    let mut removed: Vec<EqId> = Vec::new();
    let mut notes: Vec<String> = Vec::new();
    for eq in b.system.eqs.ids() {
        if al.join(b, &ranks, eq) {
            removed.push(eq);
            let e = &b.system.eqs[eq];
            notes.push(format!(
                "{}  ({})",
                print::equation(&b.system, eq),
                e.origin.describe()
            ));
        }
    }
    if removed.is_empty() {
        return;
    }
    let repl = al.replacements(b);
    substitute(b, &removed, &repl);
    b.system.eliminated = notes;
}

/// Which variables belong to an R, C, L or D (by variable index).
fn passive_vars(b: &Built, circuit: &Circuit) -> Vec<bool> {
    let mut passive = vec![false; b.system.vars.len()];
    for (k, ev) in b.elem_vars.iter().enumerate() {
        if let Some(ev) = ev
            && matches!(
                circuit.elements.as_slice()[k].kind,
                ElementKind::Resistor { .. }
                    | ElementKind::Capacitor { .. }
                    | ElementKind::Inductor { .. }
                    | ElementKind::Diode { .. }
            )
        {
            passive[ev.u.0 as usize] = true;
            passive[ev.i.0 as usize] = true;
        }
    }
    passive
}

impl Aliases {
    /// Record equation `eq` if it is an alias the variables' `ranks` allow
    /// to eliminate; whether it did (the equation is then removed).
    fn join(&mut self, b: &mut Built, ranks: &[u8], eq: EqId) -> bool {
        let is_fixed = |v: VarId| ranks[v.0 as usize] >= 8;
        let (lhs, rhs) = (b.system.eqs[eq].lhs, b.system.eqs[eq].rhs);
        if let Some((a, s, c)) = var_alias(b, lhs, rhs) {
            let (ra, sa) = self.find(a);
            let (rc, sc) = self.find(c);
            if ra == rc || (is_fixed(ra) && is_fixed(rc)) {
                return false;
            }
            if self.value[ra].is_some() && self.value[rc].is_some() {
                return false;
            }
            // sa*ra = s*sc*rc  =>  ra = (sa*s*sc) rc
            let k = sa * s * sc;
            let (child, parent) = if ranks[ra.0 as usize] > ranks[rc.0 as usize] {
                (rc, ra)
            } else {
                (ra, rc)
            };
            // A state never takes a value: `state = known` is a constraint
            // for the analysis to report, not an alias.
            if is_fixed(child) || (is_fixed(parent) && self.value[child].is_some()) {
                return false;
            }
            self.link[child] = Some(Link { parent, sign: k });
            if let Some(v) = self.value[child].take() {
                // child = v and child = k*parent  =>  parent = k*v
                let scaled = if k < 0.0 { b.system.exprs.neg(v) } else { v };
                self.value[parent] = Some(scaled);
            }
            true
        } else if let Some((v, val)) = value_alias(b, lhs, rhs) {
            let (r, s) = self.find(v);
            if is_fixed(r) || self.value[r].is_some() {
                return false;
            }
            let scaled = if s < 0.0 {
                b.system.exprs.neg(val)
            } else {
                val
            };
            self.value[r] = Some(scaled);
            true
        } else {
            false
        }
    }

    /// The replacement of every eliminated variable: its root times its
    /// sign, or the root's known value.
    fn replacements(&mut self, b: &mut Built) -> HashMap<VarId, ExprId> {
        let mut repl: HashMap<VarId, ExprId> = HashMap::new();
        for v in b.system.vars.ids() {
            let (r, s) = self.find(v);
            let target = match self.value[r] {
                Some(val) => val,
                None if r != v => b.system.exprs.var(r),
                None => continue,
            };
            let e = if s < 0.0 {
                b.system.exprs.neg(target)
            } else {
                target
            };
            repl.insert(v, e);
        }
        repl
    }
}

/// Drop the `removed` equations (in id order) and apply `repl` to the
/// others and to the node potentials.
fn substitute(b: &mut Built, removed: &[EqId], repl: &HashMap<VarId, ExprId>) {
    let sys = &mut b.system;
    let mut memo = HashMap::new();
    let old = std::mem::take(&mut sys.eqs);
    let mut removed_iter = removed.iter().peekable();
    for (id, mut e) in old.iter().map(|(i, e)| (i, e.clone())) {
        if removed_iter.peek() == Some(&&id) {
            removed_iter.next();
            continue;
        }
        e.lhs = sys
            .exprs
            .substitute(e.lhs, &mut |v| repl.get(&v).copied(), &mut memo);
        e.rhs = sys
            .exprs
            .substitute(e.rhs, &mut |v| repl.get(&v).copied(), &mut memo);
        sys.eqs.push(e);
    }
    sys.rebuild_incidence();
    for (&v, &e) in repl {
        sys.set_alias(v, e);
    }
    for p in b.node_pot.iter_mut() {
        *p = sys
            .exprs
            .substitute(*p, &mut |v| repl.get(&v).copied(), &mut memo);
    }
}
