//! Maximum matching (Hopcroft–Karp) and the block lower-triangular (BLT)
//! decomposition of what the colouring left: the minimal blocks of
//! equations that must be solved together.

use super::colour::{Colouring, EdgeColour};
use super::graph::strong_components;
use crate::ir::{EqId, VarId};

/// One block of the BLT form: equations and the unknowns they compute.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct BltBlock {
    pub eqs: Vec<EqId>,
    pub vars: Vec<VarId>,
}

/// The BLT form of the unassigned part of a colouring.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Blt {
    /// Blocks in the order they can be solved.
    pub blocks: Vec<BltBlock>,
    /// Equations no unknown is left for (over-determined part).
    pub unmatched_eqs: Vec<EqId>,
    /// Unknowns no equation is left for (under-determined part).
    pub unmatched_vars: Vec<VarId>,
    /// The maximum matching found: equation and the unknown it computes.
    pub pairs: Vec<(EqId, VarId)>,
}

const FREE: u32 = u32::MAX;

/// Hopcroft–Karp on a bipartite graph given as adjacency of the left side.
/// Returns the right partner of every left node (`u32::MAX` when unmatched).
pub fn hopcroft_karp(n_left: usize, n_right: usize, adj: &[Vec<u32>]) -> Vec<u32> {
    let mut match_l = vec![FREE; n_left];
    let mut match_r = vec![FREE; n_right];
    // Greedy start.
    for l in 0..n_left {
        if let Some(&r) = adj[l].iter().find(|&&r| match_r[r as usize] == FREE) {
            match_l[l] = r;
            match_r[r as usize] = l as u32;
        }
    }
    let mut dist = vec![0u32; n_left];
    let mut queue = Vec::with_capacity(n_left);
    loop {
        // BFS layers from free left nodes.
        queue.clear();
        let inf = u32::MAX;
        for l in 0..n_left {
            if match_l[l] == FREE {
                dist[l] = 0;
                queue.push(l as u32);
            } else {
                dist[l] = inf;
            }
        }
        let mut found = false;
        let mut head = 0;
        while head < queue.len() {
            let l = queue[head] as usize;
            head += 1;
            for &r in &adj[l] {
                let m = match_r[r as usize];
                if m == FREE {
                    found = true;
                } else if dist[m as usize] == inf {
                    dist[m as usize] = dist[l] + 1;
                    queue.push(m);
                }
            }
        }
        if !found {
            return match_l;
        }
        // DFS along layers, iteratively, from each free left node.
        let mut it = vec![0usize; n_left];
        for start in 0..n_left {
            if match_l[start] != FREE {
                continue;
            }
            let mut stack: Vec<usize> = vec![start];
            while let Some(&l) = stack.last() {
                if it[l] >= adj[l].len() {
                    dist[l] = inf;
                    stack.pop();
                    continue;
                }
                let r = adj[l][it[l]];
                it[l] += 1;
                let m = match_r[r as usize];
                if m == FREE {
                    // Augment along the stack.
                    let mut r = r;
                    for &ll in stack.iter().rev() {
                        let prev = match_l[ll];
                        match_l[ll] = r;
                        match_r[r as usize] = ll as u32;
                        r = prev;
                    }
                    break;
                } else if dist[m as usize] == dist[l] + 1 {
                    stack.push(m as usize);
                }
            }
        }
    }
}

/// BLT decomposition of the equations `c` has not assigned, on black edges.
pub fn blt(c: &Colouring<'_>) -> Blt {
    let g = c.g;
    let eqs: Vec<EqId> = c.remaining().collect();
    let mut var_index = std::collections::HashMap::new();
    let mut vars: Vec<VarId> = Vec::new();
    let mut adj: Vec<Vec<u32>> = Vec::with_capacity(eqs.len());
    for &e in &eqs {
        let mut row = Vec::new();
        for k in g.eq_edges(e) {
            if c.colour[k as usize] != EdgeColour::Black {
                continue;
            }
            let v = g.edge_var[k as usize];
            let idx = *var_index.entry(v).or_insert_with(|| {
                vars.push(v);
                (vars.len() - 1) as u32
            });
            row.push(idx);
        }
        adj.push(row);
    }
    let m = hopcroft_karp(eqs.len(), vars.len(), &adj);
    let mut owner = vec![FREE; vars.len()];
    for (l, &r) in m.iter().enumerate() {
        if r != FREE {
            owner[r as usize] = l as u32;
        }
    }
    let unmatched_eqs: Vec<EqId> = (0..eqs.len())
        .filter(|&l| m[l] == FREE)
        .map(|l| eqs[l])
        .collect();
    let unmatched_vars: Vec<VarId> = (0..vars.len())
        .filter(|&r| owner[r] == FREE)
        .map(|r| vars[r])
        .collect();
    // e_a -> e_b when e_b uses the unknown matched to e_a.
    let edges = adj.iter().enumerate().flat_map(|(l, row)| {
        let owner = &owner;
        let m = &m;
        row.iter().filter_map(move |&r| {
            let o = owner[r as usize];
            (o != FREE && o as usize != l && m[l] != FREE).then_some((o, l as u32))
        })
    });
    let comps = strong_components(eqs.len(), edges);
    let blocks = comps
        .into_iter()
        .filter(|comp| comp.iter().all(|&l| m[l as usize] != FREE))
        .map(|comp| {
            let mut bvars: Vec<VarId> =
                comp.iter().map(|&l| vars[m[l as usize] as usize]).collect();
            bvars.sort();
            BltBlock {
                eqs: comp.iter().map(|&l| eqs[l as usize]).collect(),
                vars: bvars,
            }
        })
        .collect();
    let pairs = m
        .iter()
        .enumerate()
        .filter(|(_, r)| **r != FREE)
        .map(|(l, &r)| (eqs[l], vars[r as usize]))
        .collect();
    Blt {
        blocks,
        unmatched_eqs,
        unmatched_vars,
        pairs,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hopcroft_karp_finds_a_perfect_matching() {
        // l0:{r0,r1} l1:{r0} l2:{r1,r2}
        let adj = vec![vec![0, 1], vec![0], vec![1, 2]];
        let m = hopcroft_karp(3, 3, &adj);
        assert_eq!(m, vec![1, 0, 2]);
        // A deficient one: two left nodes want the same single right node.
        let m = hopcroft_karp(2, 1, &[vec![0], vec![0]]);
        assert_eq!(m.iter().filter(|&&r| r != FREE).count(), 1);
    }
}
