//! Diagonal balancing of a dense matrix before an eigenvalue solve (Parlett
//! and Reinsch's iteration, as LAPACK's `gebal` does it without
//! permutations).
//!
//! A circuit's Jacobian mixes units: a junction charge in coulombs beside a
//! node voltage in volts makes entries of 1e25 next to entries of 1e-3. The
//! eigenvalues of such a matrix, computed as it stands, carry errors of the
//! order of `ε·‖J‖`, which can exceed the true eigenvalues and turn a
//! decaying real mode into a fast complex pair with a positive real part.
//! `D⁻¹ J D`, with `D` chosen so that each row and column have comparable
//! norms, has the same eigenvalues and a norm near the smallest any diagonal
//! similarity gives. The scale factors are powers of two, so the similarity
//! itself rounds nothing.

/// Scale factors change by a factor of this, whose square is the step of a
/// row's and column's norm ratio: a power of two, exact in floating point.
const RADIX: f64 = 2.0;

/// Passes over the matrix at most: each pass moves every row's and
/// column's norms together by factors of `RADIX`, so a few dozen settle any
/// finite matrix; the cap only ends a pathological input.
const MAX_PASSES: usize = 200;

/// A scale factor no larger than this (nor smaller than its reciprocal):
/// products of finite entries with it stay finite.
const MAX_SCALE: f64 = 1e150;

/// Balance the row-major `n`×`n` matrix `a` in place into `D⁻¹ A D` and
/// return `D`'s diagonal. An eigenvector `x` of the balanced matrix is
/// `D⁻¹ v` for the eigenvector `v` of `A`, and a left eigenvector `y` is
/// `D w`, so `|y_k x_k|` (a participation factor) is the same for both.
/// Rows and columns with no off-diagonal entries are left alone.
pub fn balance(n: usize, a: &mut [f64]) -> Vec<f64> {
    let a = &mut a[..n * n];
    let mut d = vec![1.0; n];
    for _ in 0..MAX_PASSES {
        let mut converged = true;
        for i in 0..n {
            let (mut c, mut r) = (0.0, 0.0);
            for j in (0..n).filter(|&j| j != i) {
                c += a[j * n + i].abs();
                r += a[i * n + j].abs();
            }
            if c == 0.0 || r == 0.0 || !(c.is_finite() && r.is_finite()) {
                continue;
            }
            let s = c + r;
            let mut f = 1.0;
            let (lo, hi) = (r / RADIX, r * RADIX);
            while c < lo && d[i] * f < MAX_SCALE {
                f *= RADIX;
                c *= RADIX * RADIX;
            }
            while c > hi && d[i] / f > 1.0 / MAX_SCALE {
                f /= RADIX;
                c /= RADIX * RADIX;
            }
            // `c` is now the column's norm times `f²`, so `(c + r)/f` is
            // the scaled row's and column's sum. Take the factor only where
            // it cuts that sum by a real margin (LAPACK's 0.95), so the
            // passes end.
            if (c + r) / f < 0.95 * s {
                converged = false;
                d[i] *= f;
                for j in 0..n {
                    a[i * n + j] /= f;
                    a[j * n + i] *= f;
                }
            }
        }
        if converged {
            break;
        }
    }
    d
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;

    /// The eigenvalues of `m` by nalgebra, sorted by real part.
    fn eigs(n: usize, m: &[f64]) -> Vec<(f64, f64)> {
        let mut e: Vec<(f64, f64)> = DMatrix::from_row_slice(n, n, m)
            .complex_eigenvalues()
            .iter()
            .map(|l| (l.re, l.im))
            .collect();
        e.sort_by(|x, y| x.0.total_cmp(&y.0));
        e
    }

    /// A tridiagonal RC chain's Jacobian (real, negative eigenvalues),
    /// rescaled as if every other state were a charge on 1e-13 F: the
    /// balanced matrix gives the eigenvalues of the original, the
    /// unbalanced one does not.
    #[test]
    fn badly_scaled_chain_recovers_its_real_spectrum() {
        let n = 12;
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            a[i * n + i] = -2e9 * (1.0 + 0.1 * i as f64);
            if i > 0 {
                a[i * n + i - 1] = 1e9;
            }
            if i + 1 < n {
                a[i * n + i + 1] = 0.9e9;
            }
        }
        let exact = eigs(n, &a);
        assert!(exact.iter().all(|&(re, im)| re < 0.0 && im == 0.0));
        // S⁻¹ A S with S = diag(1, 1e-13, 1, 1e-13, ...) and some
        // arbitrary spread on top, so the similarity spans 1e-20..1e7.
        let s: Vec<f64> = (0..n)
            .map(|i| if i % 2 == 1 { 1e-13 } else { 1.0 } * 10f64.powi(i as i32 % 5 - 2) * 1e-5f64.powi((i % 3) as i32))
            .collect();
        let mut b = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..n {
                b[i * n + j] = a[i * n + j] * s[j] / s[i];
            }
        }
        let raw = eigs(n, &b);
        let worst = |e: &[(f64, f64)]| {
            e.iter()
                .zip(&exact)
                .map(|(x, y)| ((x.0 - y.0).abs() + x.1.abs()) / y.0.abs())
                .fold(0.0, f64::max)
        };
        let d = balance(n, &mut b);
        assert!(d.iter().all(|v| v.is_finite() && *v > 0.0));
        let balanced = eigs(n, &b);
        assert!(
            worst(&balanced) < 1e-6,
            "balanced: {balanced:?} against {exact:?}"
        );
        // The unbalanced solve is what the mode diagnosis saw: positive
        // real parts or spurious imaginary ones, far off.
        assert!(
            worst(&raw) > 1e-3,
            "the test matrix is not badly scaled enough: {raw:?}"
        );
    }

    #[test]
    fn balanced_matrix_is_a_similarity() {
        // D⁻¹ A D entry by entry, with D powers of two (exact).
        let n = 3;
        let a0 = [1.0, 1e12, 0.0, 1e-12, 2.0, 5.0, 3.0, 0.0, -1.0];
        let mut a = a0;
        let d = balance(n, &mut a);
        for i in 0..n {
            assert_eq!(d[i].log2().fract(), 0.0);
            for j in 0..n {
                assert_eq!(a[i * n + j], a0[i * n + j] * d[j] / d[i]);
            }
        }
        assert!(a.iter().all(|v| v.abs() < 1e7));
    }

    #[test]
    fn empty_rows_and_infinite_entries_end() {
        let mut a = [0.0, 0.0, 0.0, 1.0];
        assert_eq!(balance(2, &mut a), vec![1.0, 1.0]);
        let mut b = [f64::INFINITY, 1.0, 1e300, f64::NAN];
        let d = balance(2, &mut b);
        assert!(d.iter().all(|v| v.is_finite()));
    }
}
