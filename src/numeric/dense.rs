//! Dense LU with partial pivoting, row-major, for small blocks: the tape's
//! torn loops, the operating point and kausal's own integrator.
//!
//! The factors live in the caller's buffers ([`lu_factor`], [`lu_solve`]) so
//! that hot loops allocate nothing; [`DenseLu`] owns them where that is
//! simpler.

/// The largest order [`lu_factor`] and [`lu_solve`] compile for one by one:
/// with the order a constant the loops unroll (kausal's circuit integrator
/// factors and solves its few states at every step; on VACASK's mul, 5·10^5
/// steps of 7 states, the general loops were a fifth of the run).
const UNROLLED: usize = 8;

/// Calls `$f::<N, INV>` for `$n` up to [`UNROLLED`], else `$f::<0, INV>`
/// (the order read at run time).
macro_rules! by_order {
    ($n:expr, $f:ident::<$inv:tt>($($arg:expr),*)) => {
        match $n {
            1 => $f::<1, $inv>($n, $($arg),*),
            2 => $f::<2, $inv>($n, $($arg),*),
            3 => $f::<3, $inv>($n, $($arg),*),
            4 => $f::<4, $inv>($n, $($arg),*),
            5 => $f::<5, $inv>($n, $($arg),*),
            6 => $f::<6, $inv>($n, $($arg),*),
            7 => $f::<7, $inv>($n, $($arg),*),
            UNROLLED => $f::<UNROLLED, $inv>($n, $($arg),*),
            _ => $f::<0, $inv>($n, $($arg),*),
        }
    };
}

/// LU-factorize the row-major `n`×`n` matrix `a` in place (partial
/// pivoting, row order into `perm`); false if it is singular or not finite.
pub fn lu_factor(n: usize, a: &mut [f64], perm: &mut [usize]) -> bool {
    by_order!(n, factor::<false>(a, perm))
}

/// [`lu_factor`] with U's diagonal stored as its reciprocals, for
/// [`lu_solve_inv`]: the multipliers and the back substitution multiply
/// where [`lu_factor`] and [`lu_solve`] divide. The circuit integrator
/// factors and solves at every step, and the divisions in the
/// substitution's dependency chain were most of its solves' time (mul:
/// 5·10^5 steps of 7 states). Its own matrices only: the tape's blocks and
/// the operating point keep the exact quotients, whose rounding the corpus
/// results were validated with (a level-1 inverter loop's Newton, marginal
/// at an edge, fails under the other rounding).
pub fn lu_factor_inv(n: usize, a: &mut [f64], perm: &mut [usize]) -> bool {
    by_order!(n, factor::<true>(a, perm))
}

/// [`lu_factor`] (`INV`: [`lu_factor_inv`]) of order `N`, or of order `n`
/// where `N` is 0.
#[inline(always)]
fn factor<const N: usize, const INV: bool>(n: usize, a: &mut [f64], perm: &mut [usize]) -> bool {
    let n = if N == 0 { n } else { N };
    let perm = &mut perm[..n];
    for (k, p) in perm.iter_mut().enumerate() {
        *p = k;
    }
    let a = &mut a[..n * n];
    for k in 0..n {
        let p = (k..n)
            .max_by(|&i, &j| a[i * n + k].abs().total_cmp(&a[j * n + k].abs()))
            .unwrap_or(k);
        if a[p * n + k] == 0.0 || !a[p * n + k].is_finite() {
            return false;
        }
        if p != k {
            let (upper, lower) = a.split_at_mut(p * n);
            upper[k * n..(k + 1) * n].swap_with_slice(&mut lower[..n]);
            perm.swap(k, p);
        }
        // Row slices, as in `lu_solve`: the circuit integrator factors at
        // every stage, and bounds checks per entry showed in its profile.
        let (upper, lower) = a.split_at_mut((k + 1) * n);
        let pivot = upper[k * n + k];
        let inv = if INV {
            let inv = 1.0 / pivot;
            if !inv.is_finite() {
                // A subnormal pivot, the largest of its column: singular.
                return false;
            }
            upper[k * n + k] = inv;
            inv
        } else {
            f64::NAN
        };
        let pivot_row = &upper[k * n..];
        for row in lower.chunks_exact_mut(n) {
            let f = if INV { row[k] * inv } else { row[k] / pivot };
            row[k] = f;
            if f != 0.0 {
                for (x, &u) in row[k + 1..].iter_mut().zip(&pivot_row[k + 1..]) {
                    *x -= f * u;
                }
            }
        }
    }
    true
}

/// `b := A⁻¹ b` with the factors of [`lu_factor`]; `tmp` is scratch of
/// length `n`. Row slices, not indexed loops: every Newton iteration of the
/// circuit integrator solves, and bounds checks per entry showed in its
/// profile.
pub fn lu_solve(n: usize, lu: &[f64], perm: &[usize], b: &mut [f64], tmp: &mut [f64]) {
    by_order!(n, solve::<false>(lu, perm, b, tmp))
}

/// [`lu_solve`] with the factors of [`lu_factor_inv`].
pub fn lu_solve_inv(n: usize, lu: &[f64], perm: &[usize], b: &mut [f64], tmp: &mut [f64]) {
    by_order!(n, solve::<true>(lu, perm, b, tmp))
}

/// [`lu_solve`] (`INV`: [`lu_solve_inv`]) of order `N`, or of order `n`
/// where `N` is 0.
#[inline(always)]
fn solve<const N: usize, const INV: bool>(
    n: usize,
    lu: &[f64],
    perm: &[usize],
    b: &mut [f64],
    tmp: &mut [f64],
) {
    let n = if N == 0 { n } else { N };
    let (lu, tmp) = (&lu[..n * n], &mut tmp[..n]);
    for (x, &p) in tmp.iter_mut().zip(&perm[..n]) {
        *x = b[p];
    }
    for (i, row) in lu.chunks_exact(n).enumerate() {
        let (done, rest) = tmp.split_at_mut(i);
        rest[0] -= row[..i]
            .iter()
            .zip(done.iter())
            .map(|(l, x)| l * x)
            .sum::<f64>();
    }
    for (i, row) in lu.chunks_exact(n).enumerate().rev() {
        let (head, rest) = tmp.split_at_mut(i + 1);
        let x = &mut head[i];
        *x -= row[i + 1..]
            .iter()
            .zip(rest.iter())
            .map(|(u, y)| u * y)
            .sum::<f64>();
        if INV {
            *x *= row[i];
        } else {
            *x /= row[i];
        }
    }
    b[..n].copy_from_slice(tmp);
}

/// A factored dense matrix that owns its factors.
#[derive(Clone, Debug, Default)]
pub struct DenseLu {
    /// The row-major factors of [`lu_factor`].
    pub lu: Vec<f64>,
    /// Their row order; its length is the matrix's order.
    pub perm: Vec<usize>,
}

impl DenseLu {
    /// Factor the row-major `n`×`n` matrix `a`; `None` if it is singular.
    pub fn new(n: usize, mut a: Vec<f64>) -> Option<DenseLu> {
        let mut perm = vec![0; n];
        lu_factor(n, &mut a, &mut perm).then_some(DenseLu { lu: a, perm })
    }

    /// The order of the matrix.
    pub fn n(&self) -> usize {
        self.perm.len()
    }

    /// `b := A⁻¹ b`; `tmp` is scratch of length `n`.
    pub fn solve_in_place(&self, b: &mut [f64], tmp: &mut [f64]) {
        lu_solve(self.n(), &self.lu, &self.perm, b, tmp);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `A x` for a row-major `A`.
    fn mul(a: &[f64], x: &[f64]) -> Vec<f64> {
        let n = x.len();
        (0..n)
            .map(|i| (0..n).map(|j| a[i * n + j] * x[j]).sum())
            .collect()
    }

    /// Numbers in [-0.5, 0.5) from a xorshift generator seeded with `seed`.
    fn uniform(mut seed: u64) -> impl FnMut() -> f64 {
        move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        }
    }

    /// `max_k |a_k - b_k|`.
    fn max_difference(a: &[f64], b: &[f64]) -> f64 {
        a.iter()
            .zip(b)
            .map(|(p, q)| (p - q).abs())
            .fold(0.0, f64::max)
    }

    /// The orders compiled one by one compute exactly what the general
    /// loops compute (the same operations in the same order), and solve.
    #[test]
    fn unrolled_orders_agree_with_the_general_loops_bit_for_bit() {
        let mut next = uniform(0x2545_f491_4f6c_dd1d);
        for n in 1..=UNROLLED + 2 {
            let a: Vec<f64> = (0..n * n).map(|_| next()).collect();
            let x: Vec<f64> = (0..n).map(|_| next()).collect();
            let b = mul(&a, &x);
            let (mut fast, mut general) = (a.clone(), a.clone());
            let (mut pf, mut pg) = (vec![0; n], vec![0; n]);
            assert!(lu_factor(n, &mut fast, &mut pf), "order {n}");
            assert!(factor::<0, false>(n, &mut general, &mut pg), "order {n}");
            assert_eq!((&fast, &pf), (&general, &pg), "order {n}");
            let (mut bf, mut bg, mut tmp) = (b.clone(), b.clone(), vec![0.0; n]);
            lu_solve(n, &fast, &pf, &mut bf, &mut tmp);
            solve::<0, false>(n, &general, &pg, &mut bg, &mut tmp);
            assert_eq!(bf, bg, "order {n}");
            let err = max_difference(&bf, &x);
            assert!(err < 1e-9, "order {n}: {err:e}");
        }
    }

    /// The reciprocal factors: U's diagonal inverted, the same solutions
    /// to rounding at every order, and a column whose largest entry is
    /// subnormal (its reciprocal overflows) singular.
    #[test]
    fn reciprocal_factors_solve_as_the_quotients_do() {
        let mut a = vec![4.0, 1.0, 2.0, 3.0];
        let mut perm = vec![0; 2];
        assert!(lu_factor_inv(2, &mut a, &mut perm));
        // U = [[4, 1], [0, 3 - 0.5·1]]
        assert_eq!([a[0], a[3]], [0.25, 1.0 / 2.5]);
        let mut tiny = vec![1e-310, 0.0, 0.0, 1.0];
        assert!(!lu_factor_inv(2, &mut tiny, &mut perm));
        assert!(lu_factor(2, &mut [1e-310, 0.0, 0.0, 1.0], &mut perm));
        let mut next = uniform(0x9e37_79b9_7f4a_7c15);
        for n in 1..=UNROLLED + 2 {
            let a: Vec<f64> = (0..n * n).map(|_| next()).collect();
            let x: Vec<f64> = (0..n).map(|_| next()).collect();
            let b = mul(&a, &x);
            let (mut lu, mut p) = (a.clone(), vec![0; n]);
            assert!(lu_factor_inv(n, &mut lu, &mut p), "order {n}");
            let (mut got, mut tmp) = (b.clone(), vec![0.0; n]);
            lu_solve_inv(n, &lu, &p, &mut got, &mut tmp);
            let err = max_difference(&got, &x);
            assert!(err < 1e-9, "order {n}: {err:e}");
        }
    }

    #[test]
    fn solves_a_system_that_needs_pivoting() {
        // A zero on the first diagonal: without a row exchange the
        // elimination divides by zero.
        let a = vec![0.0, 2.0, 1.0, 1.0, 1.0, 0.0, 3.0, 0.0, 4.0];
        let x = [1.0, -2.0, 0.5];
        let mut b = mul(&a, &x);
        let lu = DenseLu::new(3, a.clone()).expect("regular");
        lu.solve_in_place(&mut b, &mut [0.0; 3]);
        for (got, want) in b.iter().zip(x) {
            assert!((got - want).abs() < 1e-14, "{got} vs {want}");
        }
    }

    #[test]
    fn the_owned_factors_solve_many_right_hand_sides() {
        let n = 6;
        // Diagonally weak and unsymmetric, so both pivoting and both sweeps
        // matter.
        let a: Vec<f64> = (0..n * n)
            .map(|k| ((k * 7 + 3) % 11) as f64 - 5.0 + if k % (n + 1) == 0 { 0.5 } else { 0.0 })
            .collect();
        let lu = DenseLu::new(n, a.clone()).expect("regular");
        let mut tmp = vec![0.0; n];
        for s in 0..3 {
            let x: Vec<f64> = (0..n).map(|i| (i as f64 - s as f64).sin()).collect();
            let mut b = mul(&a, &x);
            lu.solve_in_place(&mut b, &mut tmp);
            for (got, want) in b.iter().zip(&x) {
                assert!((got - want).abs() < 1e-12, "{got} vs {want}");
            }
        }
    }

    #[test]
    fn singular_and_non_finite_matrices_are_refused() {
        let mut perm = [0; 2];
        assert!(!lu_factor(2, &mut [1.0, 2.0, 2.0, 4.0], &mut perm));
        assert!(!lu_factor(2, &mut [f64::NAN, 0.0, 0.0, 1.0], &mut perm));
        assert!(DenseLu::new(2, vec![0.0; 4]).is_none());
    }
}
