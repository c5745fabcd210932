//! The loop formulation: a normal spanning tree (voltage sources first, then
//! capacitors, resistors, inductors; current sources never), node potentials
//! as sums of tree-branch voltages, and KVL on each link's fundamental loop.

use super::ElemVars;
use crate::elab::{Circuit, ElementKind, GROUND};
use crate::ir::{EquationSystem, ExprId, KvlLoop, Name, Origin, OriginKind, VarKind};
use crate::numeric::UnionFind;

/// Tree preference of an element: lower goes into the tree first.
fn rank(k: &ElementKind) -> u8 {
    match k {
        ElementKind::VSource { .. } => 0,
        ElementKind::Vcvs { .. }
        | ElementKind::Ccvs { .. }
        | ElementKind::Behavioural { current: false, .. } => 1,
        ElementKind::Capacitor { .. }
        | ElementKind::DeviceBranch {
            capacitance: Some(_),
            ..
        } => 2,
        ElementKind::Resistor { .. } | ElementKind::Diode { .. } | ElementKind::Switch { .. } => 3,
        // A transistor's junction (and charge) branches are as diodes; its
        // transport current, a current alone, is never in the tree.
        ElementKind::DeviceBranch { controlled, .. } => {
            if *controlled {
                5
            } else {
                3
            }
        }
        ElementKind::Inductor { .. } => 4,
        ElementKind::ISource { .. }
        | ElementKind::Vccs { .. }
        | ElementKind::Cccs { .. }
        | ElementKind::Behavioural { current: true, .. } => 5,
        ElementKind::Coupling { .. } | ElementKind::Intermediate { .. } => 6,
    }
}

/// Tree membership per element, computed by Kruskal over the ranks.
fn tree_elements(c: &Circuit) -> Vec<bool> {
    let mut order: Vec<usize> = (0..c.elements.len()).collect();
    order.sort_by_key(|&i| rank(&c.elements.as_slice()[i].kind));
    let mut sets = UnionFind::new(c.nodes.len());
    let mut in_tree = vec![false; c.elements.len()];
    for i in order {
        let e = &c.elements.as_slice()[i];
        if rank(&e.kind) >= 5 {
            continue;
        }
        let (a, b) = (e.nodes[0].0 as usize, e.nodes[1].0 as usize);
        if sets.union(a, b) {
            in_tree[i] = true;
        }
    }
    in_tree
}

/// The tree elements at each node.
fn tree_adjacency(c: &Circuit, in_tree: &[bool]) -> Vec<Vec<usize>> {
    let mut adj: Vec<Vec<usize>> = vec![Vec::new(); c.nodes.len()];
    for (i, e) in c.elements.values().enumerate() {
        if in_tree[i] {
            adj[e.nodes[0].0 as usize].push(i);
            adj[e.nodes[1].0 as usize].push(i);
        }
    }
    adj
}

/// Potentials of all nodes as expressions in tree-branch voltages, by a
/// breadth-first walk from ground. A part of the circuit not connected to
/// ground through the tree gets a free potential variable at its first node.
pub fn potentials_from_tree(
    sys: &mut EquationSystem,
    c: &Circuit,
    vars: &[Option<ElemVars>],
) -> Vec<ExprId> {
    let tree = rooted(c, &tree_elements(c));
    let mut pot: Vec<Option<ExprId>> = vec![None; c.nodes.len()];
    for &x in &tree.order {
        let from_parent = tree.up[x].and_then(|(parent, ei, s)| {
            let u = sys.exprs.var(vars[ei]?.u);
            let pa = pot[parent]?;
            // v(x) = v(parent) + s·u
            Some(if s > 0.0 {
                sys.exprs.add(pa, u)
            } else {
                sys.exprs.sub(pa, u)
            })
        });
        pot[x] = Some(match from_parent {
            Some(p) => p,
            None if x == GROUND.0 as usize => sys.exprs.constant(0.0),
            None => {
                let node = &c.nodes.as_slice()[x];
                let v = sys.add_var(
                    format!("v({})", node.name),
                    VarKind::Potential,
                    Origin {
                        kind: OriginKind::Node {
                            name: node.name.clone(),
                        },
                    },
                );
                sys.exprs.var(v)
            }
        });
    }
    pot.into_iter()
        .map(|p| p.expect("every node visited"))
        .collect()
}

/// The tree as parent links: for each node, its parent node, the tree
/// element joining them and the sign `s` with `v(node) - v(parent) = s·u_e`,
/// and its depth (roots: no parent, depth 0).
struct Rooted {
    up: Vec<Option<(usize, usize, f64)>>,
    depth: Vec<usize>,
    /// Breadth-first order, a tree at a time (ground's first).
    order: Vec<usize>,
}

fn rooted(c: &Circuit, in_tree: &[bool]) -> Rooted {
    let n = c.nodes.len();
    let adj = tree_adjacency(c, in_tree);
    let mut up = vec![None; n];
    let mut depth = vec![0; n];
    let mut seen = vec![false; n];
    let mut order = Vec::with_capacity(n);
    let mut queue = std::collections::VecDeque::new();
    for start in std::iter::once(GROUND.0 as usize).chain(0..n) {
        if seen[start] {
            continue;
        }
        seen[start] = true;
        queue.push_back(start);
        while let Some(a) = queue.pop_front() {
            order.push(a);
            for &ei in &adj[a] {
                let e = &c.elements.as_slice()[ei];
                let (p, q) = (e.nodes[0].0 as usize, e.nodes[1].0 as usize);
                let other = if p == a { q } else { p };
                if seen[other] {
                    continue;
                }
                seen[other] = true;
                // u_e = v(p) - v(q): the child is q (sign -1) or p (+1).
                up[other] = Some((a, ei, if other == p { 1.0 } else { -1.0 }));
                depth[other] = depth[a] + 1;
                queue.push_back(other);
            }
        }
    }
    Rooted { up, depth, order }
}

impl Rooted {
    /// `v(a) - v(b)` as signed tree elements along the tree path between
    /// them, `None` when they are in different trees.
    fn path(&self, mut a: usize, mut b: usize) -> Option<Vec<(usize, f64)>> {
        let (mut from_a, mut from_b) = (Vec::new(), Vec::new());
        while a != b {
            if self.depth[a] >= self.depth[b] {
                let (p, e, s) = self.up[a]?;
                from_a.push((e, s));
                a = p;
            } else {
                let (p, e, s) = self.up[b]?;
                from_b.push((e, -s));
                b = p;
            }
        }
        from_a.extend(from_b.into_iter().rev());
        Some(from_a)
    }
}

/// `u_link = v(a) - v(b)` for every element outside the tree, written on the
/// tree path between its nodes (the common part of their paths to ground
/// cancels, and a sum that only cancelled in value hid the constraint of a
/// loop of capacitors from index reduction), with the path's elements
/// recorded in the origin.
pub fn loop_equations(
    sys: &mut EquationSystem,
    c: &Circuit,
    vars: &[Option<ElemVars>],
    pots: &[ExprId],
) {
    let in_tree = tree_elements(c);
    let tree = rooted(c, &in_tree);
    for (i, e) in c.elements.values().enumerate() {
        if in_tree[i] {
            continue;
        }
        let Some(ev) = vars[i] else { continue };
        let u = sys.exprs.var(ev.u);
        let (a, b) = (e.nodes[0].0 as usize, e.nodes[1].0 as usize);
        let path = tree.path(a, b).and_then(|path| {
            path.into_iter()
                .map(|(el, s)| vars[el].map(|v| (v.u, s)))
                .collect::<Option<Vec<_>>>()
        });
        let rhs = match path {
            Some(path) => {
                let terms: Vec<ExprId> = path
                    .into_iter()
                    .map(|(v, s)| {
                        let x = sys.exprs.var(v);
                        if s < 0.0 { sys.exprs.neg(x) } else { x }
                    })
                    .collect();
                sys.exprs.sum(terms)
            }
            None => sys.exprs.sub(pots[a], pots[b]),
        };
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
                kind: OriginKind::Kvl(Box::new(KvlLoop {
                    link: e.name.clone(),
                    elements,
                })),
            },
        );
    }
}
