//! Seed 003's step 8, the simplification of the junction structure:
//!
//! - 8a: the reference node's 0-junction goes (its effort is zero), and with
//!   it the bonds that reach it;
//! - 8b: a junction with one bond in and one out goes, its two bonds
//!   becoming one;
//! - 8c: two junctions of the same kind joined by a bond become one;
//! - 8d (equal differences are one) is applied as the graph is built.
//!
//! 8b and 8c repeat until neither applies. Every bond variable a rule
//! removes is recorded in terms of bonds still there (`BondGraph::forward`),
//! so that a signal (a node potential a controlled source reads) can still be
//! found after the junction that held it is gone.

use super::{
    Atom, BondGraph, BondId, Lin, Note, Origin, Rule, Simplification, Var, VertexId, VertexKind,
};

pub(super) fn simplify(g: &mut BondGraph) {
    rule_a(g);
    // A node no element's current reaches has a 0-junction without bonds
    // (its note says so): nothing to simplify, nothing to draw.
    for v in g.vertices.ids() {
        let x = &g.vertices[v];
        if x.kind.is_junction() && x.bonds.is_empty() && !x.removed {
            g.vertices[v].removed = true;
        }
    }
    // The junctions of differences go first, so that a node's 0-junction
    // absorbs a difference's (keeping the node's name, `v(b)`) rather than
    // going itself.
    let mut order: Vec<VertexId> = g
        .vertices
        .iter()
        .filter(|(_, x)| x.kind.is_junction())
        .map(|(v, _)| v)
        .collect();
    order.sort_by_key(|&v| (rank(&g.vertices[v].origin) == 0, v));
    loop {
        let mut changed = false;
        for &v in &order {
            if g.vertices[v].removed {
                continue;
            }
            changed |= rule_b(g, v) || rule_c(g, v);
        }
        if !changed {
            break;
        }
    }
}

fn effort(bond: BondId) -> Atom {
    Atom {
        bond,
        var: Var::Effort,
    }
}

fn flow(bond: BondId) -> Atom {
    Atom {
        bond,
        var: Var::Flow,
    }
}

/// 8a: drop the reference node's 0-junction. A bond to it has effort zero
/// and the flow of the 1-junction at its other end.
fn rule_a(g: &mut BondGraph) {
    let Some(ground) = g
        .vertices
        .iter()
        .find(|(_, v)| v.origin == Origin::Node(crate::elab::GROUND))
        .map(|(id, _)| id)
    else {
        return;
    };
    let dropped = std::mem::take(&mut g.vertices[ground].bonds);
    for &b in &dropped {
        let x = g.bonds[b].other(ground);
        g.vertices[x].bonds.retain(|&c| c != b);
        g.bonds[b].removed = true;
        g.forward.insert(effort(b), Vec::new());
        let same_flow = (g.vertices[x].kind == VertexKind::One)
            .then(|| g.vertices[x].bonds.first().copied())
            .flatten();
        g.forward.insert(
            flow(b),
            same_flow.map(|c| vec![(1, flow(c))]).unwrap_or_default(),
        );
    }
    g.vertices[ground].removed = true;
    g.simplified.push(Simplification {
        rule: Rule::A,
        vertex: ground,
        bond: None,
        into: None,
        elem: None,
        dropped,
        joins: None,
    });
}

/// 8b: `X → J → Y` becomes `X → Y` (both variables of the two bonds are
/// equal at a junction of two bonds, whichever its kind).
fn rule_b(g: &mut BondGraph, j: VertexId) -> bool {
    let bonds = &g.vertices[j].bonds;
    if bonds.len() != 2 {
        return false;
    }
    let (b1, b2) = (bonds[0], bonds[1]);
    let (bi, bo) = match (g.bonds[b1].head == j, g.bonds[b2].head == j) {
        (true, false) => (b1, b2),
        (false, true) => (b2, b1),
        _ => return false,
    };
    let (x, y) = (g.bonds[bi].tail, g.bonds[bo].head);
    if x == j || y == j || x == y {
        return false;
    }
    g.bonds[bi].head = y;
    for c in g.vertices[y].bonds.iter_mut() {
        if *c == bo {
            *c = bi;
        }
    }
    g.bonds[bo].removed = true;
    g.forward.insert(effort(bo), vec![(1, effort(bi))]);
    g.forward.insert(flow(bo), vec![(1, flow(bi))]);
    g.vertices[j].bonds.clear();
    g.vertices[j].removed = true;
    g.simplified.push(Simplification {
        rule: Rule::B,
        vertex: j,
        bond: Some(bi),
        into: None,
        elem: None,
        dropped: Vec::new(),
        joins: Some((x, y)),
    });
    true
}

/// Which of two merged junctions keeps its name: a node's over a
/// difference's over an element's inner one, then the older.
fn rank(origin: &Origin) -> u8 {
    match origin {
        Origin::Node(_) => 0,
        Origin::Difference(..) => 1,
        _ => 2,
    }
}

/// 8c: a junction and a neighbour of its kind become one.
fn rule_c(g: &mut BondGraph, j: VertexId) -> bool {
    let kind = g.vertices[j].kind;
    let Some((b, k)) = g.vertices[j].bonds.iter().find_map(|&b| {
        let k = g.bonds[b].other(j);
        (k != j && g.vertices[k].kind == kind && !g.vertices[k].removed).then_some((b, k))
    }) else {
        return false;
    };
    let (s, o) = if (rank(&g.vertices[k].origin), k) < (rank(&g.vertices[j].origin), j) {
        (k, j)
    } else {
        (j, k)
    };
    // The bond's shared variable is any other bond's; the other one follows
    // from the balance at the junction that goes.
    let (shared, balanced) = match kind {
        VertexKind::Zero => (Var::Effort, Var::Flow),
        _ => (Var::Flow, Var::Effort),
    };
    let other = g.vertices[s]
        .bonds
        .iter()
        .chain(&g.vertices[o].bonds)
        .copied()
        .find(|&c| c != b);
    g.forward.insert(
        Atom {
            bond: b,
            var: shared,
        },
        other
            .map(|c| {
                vec![(
                    1,
                    Atom {
                        bond: c,
                        var: shared,
                    },
                )]
            })
            .unwrap_or_default(),
    );
    let b_in = g.bonds[b].head == o;
    let balance: Lin = g.vertices[o]
        .bonds
        .iter()
        .filter(|&&c| c != b)
        .map(|&c| {
            let c_in = g.bonds[c].head == o;
            (
                if c_in == b_in { -1 } else { 1 },
                Atom {
                    bond: c,
                    var: balanced,
                },
            )
        })
        .collect();
    g.forward.insert(
        Atom {
            bond: b,
            var: balanced,
        },
        balance,
    );
    let moved: Vec<BondId> = std::mem::take(&mut g.vertices[o].bonds)
        .into_iter()
        .filter(|&c| c != b)
        .collect();
    g.vertices[s].bonds.retain(|&c| c != b);
    g.bonds[b].removed = true;
    g.vertices[o].removed = true;
    for c in moved {
        let bond = &mut g.bonds[c];
        if bond.tail == o {
            bond.tail = s;
        }
        if bond.head == o {
            bond.head = s;
        }
        if bond.tail == s && bond.head == s {
            // A second bond between the two: now a bond from the junction
            // to itself, whose balanced variable circulates undetermined.
            g.vertices[s].bonds.retain(|&x| x != c);
            g.bonds[c].removed = true;
            let other = g.vertices[s].bonds.first().copied();
            g.forward.insert(
                Atom {
                    bond: c,
                    var: shared,
                },
                other
                    .map(|x| {
                        vec![(
                            1,
                            Atom {
                                bond: x,
                                var: shared,
                            },
                        )]
                    })
                    .unwrap_or_default(),
            );
            g.forward.insert(
                Atom {
                    bond: c,
                    var: balanced,
                },
                Vec::new(),
            );
            let name = g.vertex_name(s);
            g.notes.push(Note {
                elem: None,
                text: format!(
                    "bond {c} joined {name} to itself after a merge: dropped (it carries nothing)"
                ),
            });
            continue;
        }
        g.vertices[s].bonds.push(c);
    }
    g.simplified.push(Simplification {
        rule: Rule::C,
        vertex: o,
        bond: Some(b),
        into: Some(s),
        elem: None,
        dropped: Vec::new(),
        joins: None,
    });
    true
}
