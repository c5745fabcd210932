//! Sparse LU for circuit Jacobians: factored once from triplets
//! ([`TripletLu`]) or refactored per step as a diffsol linear solver
//! ([`CircuitLu`]).
//!
//! Circuit matrices are very sparse, nearly structurally symmetric and
//! refactored thousands of times with one pattern. The method is the one
//! circuit simulators use (Davis & Palamadai Natarajan, "Algorithm 907:
//! KLU", ACM TOMS 37(3), 2010):
//! - a fill-reducing order of the columns from approximate minimum degree on
//!   `A + Aᵀ` (faer's AMD), fixed for the run;
//! - left-looking factorization column by column (Gilbert & Peierls): the
//!   pattern of each column of `L \ A(:,j)` is found by a depth-first search
//!   through `L`, then computed in topological order;
//! - threshold partial pivoting that keeps the diagonal when it is within a
//!   factor [`PIVOT_TOL`] of the column's largest entry, so a circuit's
//!   natural pivots survive;
//! - refactorization with the same pivots and pattern (no search), which
//!   falls back to a full factorization if a pivot has become too small.
//!
//! The solve is two sparse triangular sweeps over compressed columns.
//!
//! The sparse LU keeps its column order and pivots between refactorizations
//! and factors afresh when a kept pivot falls below 1e-6 of its column; a
//! singular matrix makes the solve fail (diffsol cuts the step), never a
//! panic.

use std::cell::RefCell;

use diffsol::{FaerSparseMat, Matrix, MatrixCommon, Vector};
use diffsol_la::LinearOp;
use diffsol_la::LinearSolver as LaLinearSolver;
use diffsol_la::error::{LaError, LinearSolverError};
use faer::dyn_stack::{MemBuffer, MemStack};

/// A pivot is kept on the diagonal while it is at least this fraction of the
/// largest candidate in its column (KLU's default).
const PIVOT_TOL: f64 = 1e-3;

/// A refactorization keeps the old pivot while it is at least this fraction
/// of the largest entry below it; otherwise the matrix is factored afresh.
const REFACTOR_TOL: f64 = 1e-6;

const NONE: usize = usize::MAX;

type Vf = <FaerSparseMat<f64> as MatrixCommon>::V;
type Ctx = <FaerSparseMat<f64> as MatrixCommon>::C;

/// The factors `P A Q = L U`: `L` unit lower triangular, `U` upper
/// triangular, both by columns in pivot order.
#[derive(Clone, Default)]
struct Factors {
    n: usize,
    /// Step `k` eliminates column `q[k]` of `A`.
    q: Vec<usize>,
    /// `pinv[row]`: the step whose pivot row is `row`.
    pinv: Vec<usize>,
    /// Their inverses, for the solve's gathers: `prow[k]`, the pivot row of
    /// step `k`; `qinv[col]`, the step that eliminates column `col`.
    prow: Vec<usize>,
    qinv: Vec<usize>,
    /// Strictly lower part of `L`, rows in step numbering.
    lp: Vec<usize>,
    li: Vec<usize>,
    lx: Vec<f64>,
    /// Strictly upper part of `U` by columns (rows in step numbering, in an
    /// order where each entry's dependencies come first).
    up: Vec<usize>,
    ui: Vec<usize>,
    ux: Vec<f64>,
    /// `1 / U(k,k)`, the only copy of the pivots: the solves multiply (a
    /// division's latency would chain through the whole backward sweep).
    inv_pivot: Vec<f64>,
    valid: bool,
}

/// The matrix of `A` as compressed columns.
struct Csc<'m> {
    col_ptr: &'m [usize],
    row_idx: &'m [usize],
    val: &'m [f64],
}

impl Csc<'_> {
    fn col(&self, j: usize) -> (&[usize], &[f64]) {
        let (a, b) = (self.col_ptr[j], self.col_ptr[j + 1]);
        (&self.row_idx[a..b], &self.val[a..b])
    }
}

/// Scratch of the factorization, kept between calls.
#[derive(Default)]
struct Work {
    x: Vec<f64>,
    /// Depth-first search: the reach (in topological order), the stack of
    /// rows and of positions within their `L` columns, and marks.
    reach: Vec<usize>,
    stack: Vec<usize>,
    pos: Vec<usize>,
    mark: Vec<u32>,
    epoch: u32,
}

impl Factors {
    /// Factor `a` afresh, choosing pivots. `Err` when it is singular.
    fn factor(&mut self, a: &Csc<'_>, w: &mut Work) -> Result<(), ()> {
        let n = self.n;
        self.valid = false;
        self.pinv.clear();
        self.pinv.resize(n, NONE);
        // During the factorization `L` holds original row numbers (rows not
        // yet pivotal have no step); they are renumbered at the end.
        self.lp.clear();
        self.li.clear();
        self.lx.clear();
        self.up.clear();
        self.ui.clear();
        self.ux.clear();
        self.inv_pivot.clear();
        self.lp.push(0);
        self.up.push(0);
        w.x.clear();
        w.x.resize(n, 0.0);
        w.mark.clear();
        w.mark.resize(n, 0);
        w.epoch = 0;
        for k in 0..n {
            let col = self.q[k];
            let (rows, vals) = a.col(col);
            self.reach(rows, w);
            for &i in &w.reach {
                w.x[i] = 0.0;
            }
            for (&i, &v) in rows.iter().zip(vals) {
                w.x[i] += v;
            }
            // Eliminate with the finished columns, dependencies first.
            for &i in &w.reach {
                let j = self.pinv[i];
                if j == NONE {
                    continue;
                }
                let xi = w.x[i];
                for p in self.lp[j]..self.lp[j + 1] {
                    w.x[self.li[p]] -= self.lx[p] * xi;
                }
            }
            // Pivot: the diagonal unless it is much smaller than the largest.
            let (mut big, mut ipiv) = (0.0f64, NONE);
            for &i in &w.reach {
                if self.pinv[i] == NONE && w.x[i].abs() > big {
                    big = w.x[i].abs();
                    ipiv = i;
                }
            }
            if ipiv == NONE || big == 0.0 || !big.is_finite() {
                return Err(());
            }
            if self.pinv[col] == NONE && w.x[col].abs() >= PIVOT_TOL * big {
                ipiv = col;
            }
            let pivot = w.x[ipiv];
            for &i in &w.reach {
                let j = self.pinv[i];
                if j != NONE {
                    self.ui.push(j);
                    self.ux.push(w.x[i]);
                }
            }
            self.up.push(self.ui.len());
            self.inv_pivot.push(1.0 / pivot);
            self.pinv[ipiv] = k;
            for &i in &w.reach {
                if self.pinv[i] == NONE {
                    self.li.push(i);
                    self.lx.push(w.x[i] / pivot);
                }
            }
            self.lp.push(self.li.len());
        }
        for i in self.li.iter_mut() {
            *i = self.pinv[*i];
        }
        self.prow.clear();
        self.prow.resize(n, 0);
        self.qinv.clear();
        self.qinv.resize(n, 0);
        for (row, &k) in self.pinv.iter().enumerate() {
            self.prow[k] = row;
        }
        for (k, &col) in self.q.iter().enumerate() {
            self.qinv[col] = k;
        }
        self.valid = true;
        Ok(())
    }

    /// The rows reachable from `rows` through the columns of `L` finished so
    /// far, into `w.reach` in topological order (a row before the rows its
    /// `L` column updates).
    fn reach(&self, rows: &[usize], w: &mut Work) {
        w.epoch = w.epoch.wrapping_add(1);
        if w.epoch == 0 {
            w.mark.iter_mut().for_each(|m| *m = 0);
            w.epoch = 1;
        }
        let epoch = w.epoch;
        w.reach.clear();
        for &start in rows {
            if w.mark[start] == epoch {
                continue;
            }
            w.mark[start] = epoch;
            w.stack.clear();
            w.pos.clear();
            w.stack.push(start);
            w.pos.push(self.l_begin(start));
            while let Some(&i) = w.stack.last() {
                let top = w.stack.len() - 1;
                let end = self.l_end(i);
                let mut p = w.pos[top];
                let mut descended = false;
                while p < end {
                    let r = self.li[p];
                    p += 1;
                    if w.mark[r] != epoch {
                        w.mark[r] = epoch;
                        w.pos[top] = p;
                        w.stack.push(r);
                        w.pos.push(self.l_begin(r));
                        descended = true;
                        break;
                    }
                }
                if !descended {
                    w.stack.pop();
                    w.pos.pop();
                    w.reach.push(i);
                }
            }
        }
        // Finished last = needed first.
        w.reach.reverse();
    }

    fn l_begin(&self, row: usize) -> usize {
        match self.pinv[row] {
            NONE => 0,
            j => self.lp[j],
        }
    }

    fn l_end(&self, row: usize) -> usize {
        match self.pinv[row] {
            NONE => 0,
            j => self.lp[j + 1],
        }
    }

    /// Factor `a` again with the pivots and pattern of the last
    /// factorization. `false` when a pivot became too small (or not finite).
    fn refactor(&mut self, a: &Csc<'_>, x: &mut [f64]) -> bool {
        for k in 0..self.n {
            let (rows, vals) = a.col(self.q[k]);
            for (&i, &v) in rows.iter().zip(vals) {
                x[self.pinv[i]] += v;
            }
            for p in self.up[k]..self.up[k + 1] {
                let j = self.ui[p];
                let xj = x[j];
                x[j] = 0.0;
                self.ux[p] = xj;
                for q in self.lp[j]..self.lp[j + 1] {
                    x[self.li[q]] -= self.lx[q] * xj;
                }
            }
            let pivot = x[k];
            x[k] = 0.0;
            let mut big = 0.0f64;
            for p in self.lp[k]..self.lp[k + 1] {
                big = big.max(x[self.li[p]].abs());
            }
            let ok = pivot.is_finite() && pivot != 0.0 && pivot.abs() >= REFACTOR_TOL * big;
            self.inv_pivot[k] = 1.0 / pivot;
            for p in self.lp[k]..self.lp[k + 1] {
                let r = self.li[p];
                self.lx[p] = x[r] / pivot;
                x[r] = 0.0;
            }
            if !ok {
                x.iter_mut().for_each(|v| *v = 0.0);
                return false;
            }
        }
        true
    }

    /// Solve `A x = b` in place; `y` is scratch of length `n`.
    ///
    /// Written for columns of one or two entries (a ladder's): the sweeps
    /// walk one running position through `L` and `U` rather than slicing
    /// each column, and the permutations are gathers.
    fn solve(&self, b: &mut [f64], y: &mut [f64]) {
        let n = self.n;
        let y = &mut y[..n];
        for (yk, &row) in y.iter_mut().zip(&self.prow) {
            *yk = b[row];
        }
        let (li, lx) = (&self.li[..], &self.lx[..]);
        let mut p = 0;
        for (j, &end) in self.lp[1..].iter().enumerate() {
            let yj = y[j];
            while p < end {
                y[li[p]] -= lx[p] * yj;
                p += 1;
            }
        }
        let (ui, ux) = (&self.ui[..], &self.ux[..]);
        let mut p = self.up[n];
        for j in (0..n).rev() {
            let yj = y[j] * self.inv_pivot[j];
            y[j] = yj;
            let start = self.up[j];
            while p > start {
                p -= 1;
                y[ui[p]] -= ux[p] * yj;
            }
        }
        for (bi, &k) in b.iter_mut().zip(&self.qinv) {
            *bi = y[k];
        }
    }

    /// Solve `Aᵀ x = b` in place.
    fn solve_transpose(&self, b: &mut [f64], y: &mut [f64]) {
        for k in 0..self.n {
            y[k] = b[self.q[k]];
        }
        for j in 0..self.n {
            let mut s = y[j];
            for p in self.up[j]..self.up[j + 1] {
                s -= self.ux[p] * y[self.ui[p]];
            }
            y[j] = s * self.inv_pivot[j];
        }
        for j in (0..self.n).rev() {
            let mut s = y[j];
            for p in self.lp[j]..self.lp[j + 1] {
                s -= self.lx[p] * y[self.li[p]];
            }
            y[j] = s;
        }
        for (i, bi) in b.iter_mut().enumerate() {
            *bi = y[self.pinv[i]];
        }
    }
}

/// The circuit sparse LU as a diffsol linear solver for [`FaerSparseMat`].
#[derive(Default)]
pub struct CircuitLu {
    a: Option<FaerSparseMat<f64>>,
    f: Factors,
    work: Work,
    /// Dense scratch of the solves.
    y: RefCell<Vec<f64>>,
}

impl CircuitLu {
    fn csc(a: &FaerSparseMat<f64>) -> Csc<'_> {
        let m = &a.inner()[0];
        let sym = m.symbolic();
        // diffsol builds its matrices compact: no per-column lengths.
        debug_assert!(sym.col_nnz().is_none());
        Csc {
            col_ptr: sym.col_ptr(),
            row_idx: sym.row_idx(),
            val: m.val(),
        }
    }

    /// Factor the matrix now in `a`.
    fn factor_current(&mut self) {
        let Some(a) = self.a.as_ref() else { return };
        let csc = Self::csc(a);
        if self.f.valid {
            self.work.x.resize(self.f.n, 0.0);
            if self.f.refactor(&csc, &mut self.work.x) {
                return;
            }
        }
        // A singular matrix leaves the factors invalid; the solve reports it.
        let _ = self.f.factor(&csc, &mut self.work);
        self.work.x.iter_mut().for_each(|v| *v = 0.0);
    }

    fn solve_with(&self, b: &mut Vf, transpose: bool) -> Result<(), LaError> {
        if !self.f.valid {
            return Err(LaError::from(LinearSolverError::LuSolveFailed));
        }
        let mut y = self.y.borrow_mut();
        y.resize(self.f.n, 0.0);
        let b = b.inner_mut().col_as_slice_mut(0);
        if transpose {
            self.f.solve_transpose(b, &mut y);
        } else {
            self.f.solve(b, &mut y);
        }
        Ok(())
    }
}

/// A matrix given by `(row, column, value)` entries, factored once
/// (pivoting, AMD order) for several right-hand sides.
#[derive(Clone)]
pub struct TripletLu {
    /// Boxed: `Factored` holds either this or a small dense LU.
    f: Box<Factors>,
}

impl TripletLu {
    /// Factor the `n`×`n` matrix of `entries` (repeated positions add up);
    /// `None` when it is singular.
    pub fn new(n: usize, mut entries: Vec<(usize, usize, f64)>) -> Option<TripletLu> {
        entries.sort_unstable_by_key(|&(i, j, _)| (j, i));
        let (mut col_ptr, mut row_idx, mut val) = (vec![0usize; n + 1], Vec::new(), Vec::new());
        let mut last = None;
        for (i, j, v) in entries {
            if last == Some((i, j)) {
                *val.last_mut().expect("an entry") += v;
                continue;
            }
            last = Some((i, j));
            row_idx.push(i);
            val.push(v);
            col_ptr[j + 1] += 1;
        }
        for j in 0..n {
            col_ptr[j + 1] += col_ptr[j];
        }
        let sym =
            faer::sparse::SymbolicSparseColMatRef::new_checked(n, n, &col_ptr, None, &row_idx);
        let mut f = Factors {
            n,
            q: amd_order_of(n, sym),
            ..Factors::default()
        };
        let csc = Csc {
            col_ptr: &col_ptr,
            row_idx: &row_idx,
            val: &val,
        };
        f.factor(&csc, &mut Work::default()).ok()?;
        Some(TripletLu { f: Box::new(f) })
    }

    /// `b := A⁻¹ b`; `tmp` is scratch of length `n`.
    pub fn solve_in_place(&self, b: &mut [f64], tmp: &mut [f64]) {
        self.f.solve(&mut b[..self.f.n], &mut tmp[..self.f.n]);
    }

    /// `A⁻¹ b`.
    pub fn solve(&self, b: &[f64]) -> Vec<f64> {
        let mut x = b.to_vec();
        self.f.solve(&mut x, &mut vec![0.0; self.f.n]);
        x
    }
}

/// The compressed-column structure of matrices factored many times with
/// one pattern (a torn block's Jacobian at every Newton iteration), with
/// its fill-reducing order computed once.
#[derive(Clone, Debug)]
pub struct SparsePattern {
    n: usize,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    order: Vec<usize>,
}

impl SparsePattern {
    /// The `n`×`n` pattern of the `(row, column)` positions (repeats are one).
    pub fn new(n: usize, mut positions: Vec<(usize, usize)>) -> SparsePattern {
        positions.sort_unstable_by_key(|&(i, j)| (j, i));
        positions.dedup();
        let mut col_ptr = vec![0usize; n + 1];
        let mut row_idx = Vec::with_capacity(positions.len());
        for &(i, j) in &positions {
            row_idx.push(i);
            col_ptr[j + 1] += 1;
        }
        for j in 0..n {
            col_ptr[j + 1] += col_ptr[j];
        }
        let sym =
            faer::sparse::SymbolicSparseColMatRef::new_checked(n, n, &col_ptr, None, &row_idx);
        let order = amd_order_of(n, sym);
        SparsePattern {
            n,
            col_ptr,
            row_idx,
            order,
        }
    }

    /// How many positions; a matrix of this pattern is that many values.
    pub fn nnz(&self) -> usize {
        self.row_idx.len()
    }

    /// Where the value at `(row, column)` goes (`None`: not in the pattern).
    pub fn slot(&self, row: usize, col: usize) -> Option<usize> {
        let (a, b) = (self.col_ptr[col], self.col_ptr[col + 1]);
        self.row_idx[a..b].binary_search(&row).ok().map(|k| a + k)
    }

    /// Factor the matrix whose values are `val` (in [`Self::slot`] order)
    /// in the kept order; `None` when it is singular. Every factorization
    /// searches its pivots: between a block's Newton iterations far from
    /// the solution the matrix changes too much for the last pivots to be
    /// trusted, and on a near-singular block they steer Newton's path.
    pub fn factor(&self, val: &[f64]) -> Option<TripletLu> {
        let csc = Csc {
            col_ptr: &self.col_ptr,
            row_idx: &self.row_idx,
            val,
        };
        let mut f = Factors {
            n: self.n,
            q: self.order.clone(),
            ..Factors::default()
        };
        f.factor(&csc, &mut Work::default()).ok()?;
        Some(TripletLu { f: Box::new(f) })
    }
}

/// An AMD order with its pattern's size, nonzero count and hash.
struct KnownOrder {
    n: usize,
    nnz: usize,
    hash: u64,
    order: Vec<usize>,
}

thread_local! {
    /// The order [`remembered_amd_order`] found last on this thread.
    static LAST_ORDER: RefCell<Option<KnownOrder>> = const { RefCell::new(None) };
}

/// The AMD order of the pattern `sym` ([`amd_order_of`]), remembered for the
/// last pattern: a BDF restart (at every source corner) makes a new solver
/// of the same matrix pattern, and AMD was a third of a restart's cost on a
/// 10^5-state ladder. The pattern is known by its size and a hash of its
/// structure; a collision would cost fill, not correctness, since the
/// factorization is right in any column order.
fn remembered_amd_order(
    n: usize,
    sym: faer::sparse::SymbolicSparseColMatRef<'_, usize>,
) -> Vec<usize> {
    let nnz = sym.compute_nnz();
    // FNV-1a over the column pointers and row indices.
    let mut hash = 0xcbf2_9ce4_8422_2325_u64;
    for &x in sym.col_ptr().iter().chain(sym.row_idx()) {
        hash = (hash ^ x as u64).wrapping_mul(0x0100_0000_01b3);
    }
    LAST_ORDER.with(|last| {
        let mut last = last.borrow_mut();
        if let Some(k) = last.as_ref()
            && (k.n, k.nnz, k.hash) == (n, nnz, hash)
        {
            return k.order.clone();
        }
        let order = amd_order_of(n, sym);
        *last = Some(KnownOrder {
            n,
            nnz,
            hash,
            order: order.clone(),
        });
        order
    })
}

/// Approximate minimum degree order of `A + Aᵀ` (identity if it fails).
fn amd_order_of(n: usize, sym: faer::sparse::SymbolicSparseColMatRef<'_, usize>) -> Vec<usize> {
    let nnz = sym.compute_nnz();
    let mut perm = vec![0usize; n];
    let mut perm_inv = vec![0usize; n];
    let mut mem = MemBuffer::new(faer::sparse::linalg::amd::order_maybe_unsorted_scratch::<
        usize,
    >(n, nnz));
    let ok = faer::sparse::linalg::amd::order_maybe_unsorted(
        &mut perm,
        &mut perm_inv,
        sym,
        Default::default(),
        MemStack::new(&mut mem),
    );
    if ok.is_err() {
        return (0..n).collect();
    }
    perm
}

impl LaLinearSolver<FaerSparseMat<f64>> for CircuitLu {
    fn set_linearisation<C: LinearOp<V = Vf, T = f64, M = FaerSparseMat<f64>, C = Ctx>>(
        &mut self,
        op: &C,
    ) {
        let Some(a) = self.a.as_mut() else { return };
        op.matrix_inplace(a);
        self.factor_current();
    }

    fn set_sparsity<C: LinearOp<V = Vf, T = f64, M = FaerSparseMat<f64>, C = Ctx>>(
        &mut self,
        op: &C,
    ) {
        let n = op.nrows();
        let a = FaerSparseMat::new_from_sparsity(n, op.ncols(), op.sparsity(), *op.context());
        self.f = Factors {
            n,
            q: remembered_amd_order(n, a.inner()[0].symbolic()),
            ..Factors::default()
        };
        self.work = Work::default();
        self.a = Some(a);
    }

    fn solve_in_place(&self, b: &mut Vf) -> Result<(), LaError> {
        self.solve_with(b, false)
    }

    fn solve_transpose_in_place(&self, b: &mut Vf) -> Result<(), LaError> {
        self.solve_with(b, true)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dense matrix as compressed columns (every entry stored, zeros too).
    fn csc_of(a: &[Vec<f64>]) -> (Vec<usize>, Vec<usize>, Vec<f64>) {
        let n = a.len();
        let (mut cp, mut ri, mut v) = (vec![0], vec![], vec![]);
        for j in 0..n {
            for (i, row) in a.iter().enumerate() {
                if row[j] != 0.0 || i == j {
                    ri.push(i);
                    v.push(row[j]);
                }
            }
            cp.push(ri.len());
        }
        (cp, ri, v)
    }

    /// The remembered order is the pattern's own: two patterns in turn
    /// (an arrow, whose dense node AMD puts last, and a path) each get
    /// theirs, not the last one found.
    #[test]
    fn a_remembered_order_is_its_own_patterns() {
        let n = 5;
        let pattern = |cols: &[Vec<usize>]| {
            let mut cp = vec![0];
            let mut ri = Vec::new();
            for c in cols {
                ri.extend_from_slice(c);
                cp.push(ri.len());
            }
            (cp, ri)
        };
        let arrow = pattern(&[
            vec![0, 1, 2, 3, 4],
            vec![0, 1],
            vec![0, 2],
            vec![0, 3],
            vec![0, 4],
        ]);
        let path = pattern(&[
            vec![0, 1],
            vec![0, 1, 2],
            vec![1, 2, 3],
            vec![2, 3, 4],
            vec![3, 4],
        ]);
        let sym = |p: &(Vec<usize>, Vec<usize>)| {
            faer::sparse::SymbolicSparseColMatRef::new_checked(n, n, &p.0, None, &p.1).to_owned()
        };
        let (arrow, path) = (sym(&arrow).unwrap(), sym(&path).unwrap());
        let (q_arrow, q_path) = (
            amd_order_of(n, arrow.as_ref()),
            amd_order_of(n, path.as_ref()),
        );
        assert_eq!(q_arrow.last(), Some(&0), "AMD puts the dense node last");
        assert_ne!(q_arrow, q_path);
        for _ in 0..2 {
            assert_eq!(remembered_amd_order(n, arrow.as_ref()), q_arrow);
            assert_eq!(remembered_amd_order(n, path.as_ref()), q_path);
        }
    }

    fn check(a: &[Vec<f64>], q: Vec<usize>) {
        let n = a.len();
        let (cp, ri, v) = csc_of(a);
        let csc = Csc {
            col_ptr: &cp,
            row_idx: &ri,
            val: &v,
        };
        let mut f = Factors {
            n,
            q,
            ..Factors::default()
        };
        let mut w = Work::default();
        f.factor(&csc, &mut w).expect("nonsingular");
        let x0: Vec<f64> = (0..n).map(|i| 1.0 + i as f64 * 0.5).collect();
        let b: Vec<f64> = a
            .iter()
            .map(|row| row.iter().zip(&x0).map(|(a, x)| a * x).sum())
            .collect();
        let mut y = vec![0.0; n];
        let mut x = b.clone();
        f.solve(&mut x, &mut y);
        for (u, v) in x.iter().zip(&x0) {
            assert!((u - v).abs() < 1e-10, "{x:?} vs {x0:?}");
        }
        // Aᵀ x = c
        let c: Vec<f64> = (0..n)
            .map(|j| (0..n).map(|i| a[i][j] * x0[i]).sum())
            .collect();
        let mut xt = c.clone();
        f.solve_transpose(&mut xt, &mut y);
        for (u, v) in xt.iter().zip(&x0) {
            assert!((u - v).abs() < 1e-10, "transpose: {xt:?} vs {x0:?}");
        }
        // The same pattern, other values: refactor gives the same solution.
        let a2: Vec<Vec<f64>> = a
            .iter()
            .enumerate()
            .map(|(i, r)| {
                r.iter()
                    .map(|&v| {
                        if v != 0.0 {
                            v * (1.0 + 0.1 * i as f64)
                        } else {
                            0.0
                        }
                    })
                    .collect()
            })
            .collect();
        let (_, _, v2) = csc_of(&a2);
        let csc2 = Csc {
            col_ptr: &cp,
            row_idx: &ri,
            val: &v2,
        };
        let mut xs = vec![0.0; n];
        assert!(f.refactor(&csc2, &mut xs));
        assert!(xs.iter().all(|&v| v == 0.0));
        let b2: Vec<f64> = a2
            .iter()
            .map(|row| row.iter().zip(&x0).map(|(a, x)| a * x).sum())
            .collect();
        let mut x2 = b2.clone();
        f.solve(&mut x2, &mut y);
        for (u, v) in x2.iter().zip(&x0) {
            assert!((u - v).abs() < 1e-10, "refactor: {x2:?} vs {x0:?}");
        }
    }

    #[test]
    fn solves_with_and_without_pivoting() {
        // Diagonally dominant tridiagonal: natural pivots.
        let n = 6;
        let mut a = vec![vec![0.0; n]; n];
        for i in 0..n {
            a[i][i] = 4.0;
            if i > 0 {
                a[i][i - 1] = -1.0;
                a[i - 1][i] = -2.0;
            }
        }
        check(&a, (0..n).collect());
        check(&a, vec![3, 1, 5, 0, 2, 4]);
        // A zero diagonal forces an off-diagonal pivot (an MNA-like source row).
        let b = vec![
            vec![0.0, 1.0, 0.0, 2.0],
            vec![1.0, 3.0, -1.0, 0.0],
            vec![0.0, -1.0, 2.0, 0.0],
            vec![5.0, 0.0, 0.0, 0.0],
        ];
        check(&b, (0..4).collect());
        check(&b, vec![2, 0, 3, 1]);
    }

    #[test]
    fn refactor_refuses_a_vanished_pivot() {
        let a1 = vec![vec![1.0, 1.0], vec![1.0, 2.0]];
        let a2 = vec![vec![1e-12, 1.0], vec![1.0, 2.0]];
        let (cp, ri, v1) = csc_of(&a1);
        let (_, _, v2) = csc_of(&a2);
        let csc = |v| Csc {
            col_ptr: &cp,
            row_idx: &ri,
            val: v,
        };
        let mut f = Factors {
            n: 2,
            q: vec![0, 1],
            ..Factors::default()
        };
        let mut w = Work::default();
        f.factor(&csc(&v1), &mut w).unwrap();
        let mut x = vec![0.0; 2];
        assert!(!f.refactor(&csc(&v2), &mut x), "the kept pivot is 1e-12");
        assert!(x.iter().all(|&v| v == 0.0));
        f.factor(&csc(&v2), &mut w).unwrap();
        // x = (1, 1): b = (1 + 1e-12, 3).
        let mut b = vec![1.0 + 1e-12, 3.0];
        f.solve(&mut b, &mut x);
        assert!(
            (b[0] - 1.0).abs() < 1e-12 && (b[1] - 1.0).abs() < 1e-12,
            "{b:?}"
        );
    }

    /// A pattern factors matrices of other values in its one order: the
    /// solutions are exact each time, a vanished diagonal takes another
    /// pivot row, and a singular matrix is `None`.
    #[test]
    fn a_pattern_factors_each_matrix_of_its_positions() {
        // An arrow matrix (a hub node and its spokes).
        let n = 7;
        let positions: Vec<(usize, usize)> =
            (0..n).flat_map(|i| [(i, i), (i, 0), (0, i)]).collect();
        let pattern = SparsePattern::new(n, positions);
        assert_eq!(pattern.nnz(), 3 * n - 2);
        assert_eq!(pattern.slot(2, 3), None);
        let matrix = |k: f64, spoke3: f64| -> Vec<Vec<f64>> {
            (0..n)
                .map(|i| {
                    (0..n)
                        .map(|j| match (i, j) {
                            (0, 0) => 10.0 + k,
                            (3, 3) => spoke3,
                            (i, j) if i == j => 2.0 + k * i as f64,
                            (0, _) | (_, 0) => -1.0 + 0.1 * k * (i + j) as f64,
                            _ => 0.0,
                        })
                        .collect()
                })
                .collect()
        };
        let values = |a: &[Vec<f64>]| -> Vec<f64> {
            let mut v = vec![0.0; pattern.nnz()];
            for (i, row) in a.iter().enumerate() {
                for (j, &x) in row.iter().enumerate() {
                    if let Some(s) = pattern.slot(i, j) {
                        v[s] = x;
                    } else {
                        assert_eq!(x, 0.0, "({i}, {j}) is outside the pattern");
                    }
                }
            }
            v
        };
        let solves = |lu: &TripletLu, a: &[Vec<f64>]| {
            let x0: Vec<f64> = (0..n).map(|i| 1.0 - 0.3 * i as f64).collect();
            let b: Vec<f64> = a
                .iter()
                .map(|row| row.iter().zip(&x0).map(|(a, x)| a * x).sum())
                .collect();
            let x = lu.solve(&b);
            for (u, v) in x.iter().zip(&x0) {
                assert!((u - v).abs() < 1e-12, "{x:?} against {x0:?}");
            }
        };
        let a1 = matrix(0.0, 2.0);
        let lu = pattern.factor(&values(&a1)).expect("regular");
        solves(&lu, &a1);
        let rows = lu.f.pinv.clone();
        let a2 = matrix(1.0, 5.0);
        let lu = pattern.factor(&values(&a2)).expect("regular");
        solves(&lu, &a2);
        // A spoke's diagonal vanishes: its column takes another pivot row.
        let a3 = matrix(1.0, 0.0);
        let lu = pattern.factor(&values(&a3)).expect("regular");
        assert_ne!(rows, lu.f.pinv, "another pivot row");
        solves(&lu, &a3);
        // A zero column is singular.
        let mut a4 = matrix(1.0, 5.0);
        for row in &mut a4 {
            row[3] = 0.0;
        }
        assert!(pattern.factor(&values(&a4)).is_none());
    }

    #[test]
    fn singular_matrix_is_an_error() {
        let a = vec![vec![1.0, 2.0], vec![2.0, 4.0]];
        let (cp, ri, v) = csc_of(&a);
        let csc = Csc {
            col_ptr: &cp,
            row_idx: &ri,
            val: &v,
        };
        let mut f = Factors {
            n: 2,
            q: vec![0, 1],
            ..Factors::default()
        };
        assert!(f.factor(&csc, &mut Work::default()).is_err());
        assert!(!f.valid);
    }
}
