//! Numerical kernels below the tape and the simulator: dense and sparse LU
//! behind one factored-matrix type, damped Newton's step control,
//! union-find, Jacobian column colouring, and the subnormal-flushing mode
//! a simulation runs in.
//!
//! This layer knows no circuit, equation or tape: it works on slices and
//! index lists, so that every user shares one copy of each routine.

pub mod balance;
pub mod colour;
pub mod dense;
pub mod newton;
pub mod sparse_lu;
pub mod subnormal;
pub mod union_find;

pub use dense::DenseLu;
pub use sparse_lu::{SparsePattern, TripletLu};
pub use union_find::UnionFind;

/// A factored square matrix, dense or sparse.
#[derive(Clone)]
pub enum Factored {
    Dense(DenseLu),
    Sparse(TripletLu),
}

impl Factored {
    /// `b := A⁻¹ b`; `tmp` is scratch of the matrix's order.
    pub fn solve_in_place(&self, b: &mut [f64], tmp: &mut [f64]) {
        match self {
            Factored::Dense(lu) => lu.solve_in_place(b, tmp),
            Factored::Sparse(lu) => lu.solve_in_place(b, tmp),
        }
    }

    /// `A⁻¹ b`, or `None` when it is not finite (a singular matrix that
    /// factored only through rounding).
    pub fn solve(&self, b: &[f64]) -> Option<Vec<f64>> {
        let mut x = b.to_vec();
        let mut tmp = vec![0.0; b.len()];
        self.solve_in_place(&mut x, &mut tmp);
        x.iter().all(|v| v.is_finite()).then_some(x)
    }
}

impl std::fmt::Debug for Factored {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Factored::Dense(lu) => write!(f, "Dense({}x{0})", lu.n()),
            Factored::Sparse(_) => f.write_str("Sparse"),
        }
    }
}
