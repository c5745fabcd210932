//! The bipartite structure graph (equations × unknowns) in compressed
//! adjacency form, and strongly connected components of dependency graphs
//! (an iterative Tarjan: petgraph's `tarjan_scc` recurses once per node and
//! overflows the stack on a 10^5-element loop; its `kosaraju_scc` takes two
//! passes and orders independent components differently).

use crate::ir::{EqId, EquationSystem, VarId};

/// Index of an edge (an occurrence of an unknown in an equation).
pub type EdgeIdx = u32;

/// Equation ↔ unknown incidence. States and eliminated aliases are known and
/// have no edges. Rows list edges by equation, columns by variable.
#[derive(Clone, Debug, Default)]
pub struct StructureGraph {
    /// `eq_start[e]..eq_start[e+1]` are the edges of equation `e`.
    pub eq_start: Vec<u32>,
    /// The unknown of each edge, in row order.
    pub edge_var: Vec<VarId>,
    /// The equation of each edge.
    pub edge_eq: Vec<EqId>,
    /// `var_start[v]..var_start[v+1]` index `var_edges`.
    pub var_start: Vec<u32>,
    /// Edge ids by variable.
    pub var_edges: Vec<EdgeIdx>,
    /// Whether a variable is an unknown (has a column).
    pub is_unknown: Vec<bool>,
}

impl StructureGraph {
    /// Build from the system's equations. O(total expression size).
    pub fn build(sys: &EquationSystem) -> StructureGraph {
        let n_eqs = sys.eqs.len();
        let n_vars = sys.vars.len();
        let is_unknown: Vec<bool> = sys.unknown_flags().to_vec();
        let mut eq_start = Vec::with_capacity(n_eqs + 1);
        let mut edge_var = Vec::with_capacity(n_eqs * 3);
        let mut edge_eq = Vec::with_capacity(n_eqs * 3);
        eq_start.push(0);
        for eq in sys.eqs.ids() {
            for &v in sys.incidence(eq) {
                if is_unknown[v.0 as usize] {
                    edge_var.push(v);
                    edge_eq.push(eq);
                }
            }
            eq_start.push(edge_var.len() as u32);
        }
        // Columns by counting sort.
        let mut var_start = vec![0u32; n_vars + 1];
        for v in &edge_var {
            var_start[v.0 as usize + 1] += 1;
        }
        for k in 0..n_vars {
            var_start[k + 1] += var_start[k];
        }
        let mut fill = var_start.clone();
        let mut var_edges = vec![0; edge_var.len()];
        for (e, v) in edge_var.iter().enumerate() {
            let slot = &mut fill[v.0 as usize];
            var_edges[*slot as usize] = e as EdgeIdx;
            *slot += 1;
        }
        StructureGraph {
            eq_start,
            edge_var,
            edge_eq,
            var_start,
            var_edges,
            is_unknown,
        }
    }

    pub fn n_eqs(&self) -> usize {
        self.eq_start.len() - 1
    }

    pub fn n_vars(&self) -> usize {
        self.var_start.len() - 1
    }

    pub fn n_edges(&self) -> usize {
        self.edge_var.len()
    }

    #[inline]
    pub fn eq_edges(&self, e: EqId) -> std::ops::Range<u32> {
        self.eq_start[e.0 as usize]..self.eq_start[e.0 as usize + 1]
    }

    #[inline]
    pub fn var_edge_ids(&self, v: VarId) -> &[EdgeIdx] {
        let (a, b) = (
            self.var_start[v.0 as usize] as usize,
            self.var_start[v.0 as usize + 1] as usize,
        );
        &self.var_edges[a..b]
    }

    /// The unknowns of an equation.
    pub fn eq_vars(&self, e: EqId) -> impl Iterator<Item = VarId> + '_ {
        self.eq_edges(e).map(|k| self.edge_var[k as usize])
    }

    /// The equations an unknown occurs in.
    pub fn var_eqs(&self, v: VarId) -> impl Iterator<Item = EqId> + '_ {
        self.var_edge_ids(v)
            .iter()
            .map(|&k| self.edge_eq[k as usize])
    }
}

/// Strongly connected components of a digraph on `n` nodes given by
/// `succ(i)`, in topological order (sources first), each sorted ascending.
///
/// Tarjan's algorithm with an explicit stack (a recursive search overflows
/// the thread's stack on a 10^5-element algebraic loop). Roots are taken in
/// node order and each node's successors in reverse insertion order, the
/// order of petgraph's adjacency lists: it fixes the order of independent
/// components, which the schedule follows.
pub fn strong_components(n: usize, edges: impl Iterator<Item = (u32, u32)>) -> Vec<Vec<u32>> {
    let edges: Vec<(u32, u32)> = edges.collect();
    // Successor lists (CSR), each filled from its end: reverse insertion order.
    let mut start = vec![0usize; n + 1];
    for &(a, _) in &edges {
        start[a as usize + 1] += 1;
    }
    for k in 0..n {
        start[k + 1] += start[k];
    }
    let mut fill: Vec<usize> = start[1..].to_vec();
    let mut succ = vec![0u32; edges.len()];
    for &(a, b) in &edges {
        fill[a as usize] -= 1;
        succ[fill[a as usize]] = b;
    }
    const UNSEEN: u32 = u32::MAX;
    let mut index = vec![UNSEEN; n];
    let mut low = vec![0u32; n];
    let mut on_stack = vec![false; n];
    let mut stack: Vec<u32> = Vec::new();
    // The search path: a node and the position of its next successor.
    let mut path: Vec<(u32, usize)> = Vec::new();
    let mut counter = 0u32;
    let mut comps: Vec<Vec<u32>> = Vec::new();
    for root in 0..n as u32 {
        if index[root as usize] != UNSEEN {
            continue;
        }
        macro_rules! enter {
            ($v:expr) => {{
                let v: u32 = $v;
                index[v as usize] = counter;
                low[v as usize] = counter;
                counter += 1;
                stack.push(v);
                on_stack[v as usize] = true;
                path.push((v, start[v as usize]));
            }};
        }
        enter!(root);
        while let Some(&mut (v, ref mut next)) = path.last_mut() {
            let vi = v as usize;
            if *next < start[vi + 1] {
                let w = succ[*next];
                *next += 1;
                if index[w as usize] == UNSEEN {
                    enter!(w);
                } else if on_stack[w as usize] {
                    low[vi] = low[vi].min(index[w as usize]);
                }
                continue;
            }
            path.pop();
            if let Some(&(u, _)) = path.last() {
                low[u as usize] = low[u as usize].min(low[vi]);
            }
            if low[vi] == index[vi] {
                let mut comp = Vec::new();
                while let Some(w) = stack.pop() {
                    on_stack[w as usize] = false;
                    comp.push(w);
                    if w == v {
                        break;
                    }
                }
                comp.sort_unstable();
                comps.push(comp);
            }
        }
    }
    comps.reverse();
    comps
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 10^6-node cycle and chain on a test thread's 2 MiB stack (a
    /// recursive search overflows at ~10^4 here).
    #[test]
    fn deep_graphs_need_no_stack() {
        let n = 1_000_000u32;
        let cycle = strong_components(n as usize, (0..n).map(|k| (k, (k + 1) % n)));
        assert_eq!(cycle.len(), 1);
        assert_eq!(cycle[0].len(), n as usize);
        let chain = strong_components(n as usize, (1..n).map(|k| (k - 1, k)));
        assert_eq!(chain.len(), n as usize);
        assert!(chain.iter().enumerate().all(|(k, c)| c == &[k as u32]));
    }

    /// Independent components keep the order of the recursive search:
    /// roots in node order, successors in reverse insertion order.
    #[test]
    fn independent_components_keep_their_order() {
        let comps = strong_components(5, [(0, 3), (0, 1), (2, 4)].into_iter());
        assert_eq!(comps, vec![vec![2], vec![4], vec![0], vec![3], vec![1]]);
    }

    #[test]
    fn components_come_in_topological_order() {
        // 0 -> 1 <-> 2 -> 3
        let comps = strong_components(4, [(0, 1), (1, 2), (2, 1), (2, 3)].into_iter());
        assert_eq!(comps, vec![vec![0], vec![1, 2], vec![3]]);
    }
}
