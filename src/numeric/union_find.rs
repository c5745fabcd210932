//! Union-find over `0..n` with path halving: connected groups of nodes
//! (spanning trees, floating islands, loops of capacitors).

/// Disjoint sets of `0..n`.
#[derive(Clone, Debug)]
pub struct UnionFind {
    parent: Vec<usize>,
}

impl UnionFind {
    /// `n` singleton sets.
    pub fn new(n: usize) -> UnionFind {
        UnionFind {
            parent: (0..n).collect(),
        }
    }

    /// The representative of `x`'s set (halving the path on the way, so a
    /// long chain costs nearly nothing the second time; no recursion).
    pub fn find(&mut self, mut x: usize) -> usize {
        while self.parent[x] != x {
            self.parent[x] = self.parent[self.parent[x]];
            x = self.parent[x];
        }
        x
    }

    /// Join the sets of `a` and `b`; false if they were one set already.
    /// The joined set's representative is `b`'s.
    pub fn union(&mut self, a: usize, b: usize) -> bool {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra == rb {
            return false;
        }
        self.parent[ra] = rb;
        true
    }

    /// The representative of every element.
    pub fn representatives(&mut self) -> Vec<usize> {
        (0..self.parent.len()).map(|x| self.find(x)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unions_join_and_report_loops() {
        let mut uf = UnionFind::new(5);
        assert!(uf.union(0, 1));
        assert!(uf.union(1, 2));
        assert!(
            !uf.union(2, 0),
            "0, 1, 2 are one set: this edge closes a loop"
        );
        assert_ne!(uf.find(3), uf.find(0));
        let reps = uf.representatives();
        assert_eq!(reps[0], reps[2]);
        assert_eq!(reps[3], 3);
        assert_eq!(reps[4], 4);
    }

    #[test]
    fn a_long_chain_needs_no_recursion() {
        let n = 1_000_000;
        let mut uf = UnionFind::new(n);
        for k in 1..n {
            uf.union(k - 1, k);
        }
        assert_eq!(uf.find(0), uf.find(n - 1));
    }
}
