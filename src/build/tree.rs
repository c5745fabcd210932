//! The loop formulation: a normal spanning tree (voltage sources first, then
//! capacitors, resistors, inductors; current sources never), node potentials
//! as sums of tree-branch voltages, and KVL on each link's fundamental loop.

use super::ElemVars;
use crate::elab::{Circuit, ElementKind, GROUND};
use crate::ir::{EquationSystem, ExprId, Name, Origin, OriginKind, VarKind};

/// Tree preference of an element: lower goes into the tree first.
fn rank(k: &ElementKind) -> u8 {
    match k {
        ElementKind::VSource { .. } => 0,
        ElementKind::Vcvs { .. } | ElementKind::Ccvs { .. } => 1,
        ElementKind::Capacitor { .. } => 2,
        ElementKind::Resistor { .. } | ElementKind::Diode { .. } => 3,
        ElementKind::Inductor { .. } => 4,
        ElementKind::ISource { .. } | ElementKind::Vccs { .. } | ElementKind::Cccs { .. } => 5,
        ElementKind::Coupling { .. } => 6,
    }
}

fn find(parent: &mut [usize], mut x: usize) -> usize {
    while parent[x] != x {
        parent[x] = parent[parent[x]];
        x = parent[x];
    }
    x
}

/// Tree membership per element, computed by Kruskal over the ranks.
fn tree_elements(c: &Circuit) -> Vec<bool> {
    let mut order: Vec<usize> = (0..c.elements.len()).collect();
    order.sort_by_key(|&i| rank(&c.elements.as_slice()[i].kind));
    let mut parent: Vec<usize> = (0..c.nodes.len()).collect();
    let mut in_tree = vec![false; c.elements.len()];
    for i in order {
        let e = &c.elements.as_slice()[i];
        if rank(&e.kind) >= 5 {
            continue;
        }
        let (a, b) = (e.nodes[0].0 as usize, e.nodes[1].0 as usize);
        let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
        if ra != rb {
            parent[ra] = rb;
            in_tree[i] = true;
        }
    }
    in_tree
}

/// Potentials of all nodes as expressions in tree-branch voltages, by a
/// breadth-first walk from ground. A part of the circuit not connected to
/// ground through the tree gets a free potential variable at its first node.
pub fn potentials_from_tree(
    sys: &mut EquationSystem,
    c: &Circuit,
    vars: &[Option<ElemVars>],
) -> Vec<ExprId> {
    let in_tree = tree_elements(c);
    let n = c.nodes.len();
    let mut adj: Vec<Vec<usize>> = vec![Vec::new(); n];
    for (i, e) in c.elements.values().enumerate() {
        if in_tree[i] {
            adj[e.nodes[0].0 as usize].push(i);
            adj[e.nodes[1].0 as usize].push(i);
        }
    }
    let mut pot: Vec<Option<ExprId>> = vec![None; n];
    let mut queue = std::collections::VecDeque::new();
    for start in 0..n {
        if pot[start].is_some() {
            continue;
        }
        let root = if start == GROUND.0 as usize {
            sys.exprs.constant(0.0)
        } else {
            let node = &c.nodes.as_slice()[start];
            let v = sys.add_var(
                format!("v({})", node.name),
                VarKind::Potential,
                Origin {
                    kind: OriginKind::Node {
                        name: Name::from(node.name.as_str()),
                    },
                    span: Some(node.span),
                },
            );
            sys.exprs.var(v)
        };
        pot[start] = Some(root);
        queue.push_back(start);
        while let Some(a) = queue.pop_front() {
            for &ei in &adj[a] {
                let e = &c.elements.as_slice()[ei];
                let (p, q) = (e.nodes[0].0 as usize, e.nodes[1].0 as usize);
                let other = if p == a { q } else { p };
                if pot[other].is_some() {
                    continue;
                }
                let Some(ev) = vars[ei] else { continue };
                let u = sys.exprs.var(ev.u);
                let pa = pot[a].expect("visited");
                // u = v(p) - v(q)
                pot[other] = Some(if other == q {
                    sys.exprs.sub(pa, u)
                } else {
                    sys.exprs.add(pa, u)
                });
                queue.push_back(other);
            }
        }
    }
    pot.into_iter()
        .map(|p| p.expect("every node visited"))
        .collect()
}

/// `u_link = v(a) - v(b)` for every element outside the tree, with the tree
/// path's elements recorded in the origin.
pub fn loop_equations(
    sys: &mut EquationSystem,
    c: &Circuit,
    vars: &[Option<ElemVars>],
    pots: &[ExprId],
) {
    let in_tree = tree_elements(c);
    for (i, e) in c.elements.values().enumerate() {
        if in_tree[i] {
            continue;
        }
        let Some(ev) = vars[i] else { continue };
        let u = sys.exprs.var(ev.u);
        let rhs = sys
            .exprs
            .sub(pots[e.nodes[0].0 as usize], pots[e.nodes[1].0 as usize]);
        let mut elements: Vec<Name> = vec![Name::from(e.name.as_str())];
        let mut seen = Vec::new();
        let mut stack = Vec::new();
        sys.exprs.vars_into(rhs, &mut seen, &mut stack);
        elements.extend(seen.iter().map(|&v| match &sys.vars[v].origin.kind {
            OriginKind::Element { name } => name.clone(),
            other => Name::from(format!("{other:?}").as_str()),
        }));
        sys.add_eq(
            u,
            rhs,
            Origin {
                kind: OriginKind::Kvl {
                    link: Name::from(e.name.as_str()),
                    elements,
                },
                span: Some(e.span),
            },
        );
    }
}
