//! The bipartite structure graph (equations × unknowns) in compressed
//! adjacency form, and the petgraph boundary: strongly connected components
//! of dependency graphs. petgraph stays inside this file; callers get typed
//! ids back.

use petgraph::graph::{DiGraph, NodeIndex};

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
pub fn strong_components(n: usize, edges: impl Iterator<Item = (u32, u32)>) -> Vec<Vec<u32>> {
    let mut g: DiGraph<(), ()> = DiGraph::with_capacity(n, 0);
    for _ in 0..n {
        g.add_node(());
    }
    for (a, b) in edges {
        g.add_edge(NodeIndex::new(a as usize), NodeIndex::new(b as usize), ());
    }
    // tarjan_scc returns components in reverse topological order.
    let mut comps: Vec<Vec<u32>> = petgraph::algo::tarjan_scc(&g)
        .into_iter()
        .map(|c| {
            let mut v: Vec<u32> = c.into_iter().map(|i| i.index() as u32).collect();
            v.sort_unstable();
            v
        })
        .collect();
    comps.reverse();
    comps
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn components_come_in_topological_order() {
        // 0 -> 1 <-> 2 -> 3
        let comps = strong_components(4, [(0, 1), (1, 2), (2, 1), (2, 3)].into_iter());
        assert_eq!(comps, vec![vec![0], vec![1, 2], vec![3]]);
    }
}
