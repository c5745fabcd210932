//! Coupled inductors whose inductance matrix is singular (perfect coupling,
//! `K L1 L2 1`): fewer independent fluxes than windings.
//!
//! A group of inductors joined by K elements has the inductance matrix `L`
//! (`L_jj` the self inductances, `L_jk = k·√(L_j·L_k)`) and `u = L·di/dt`.
//! When `L` is singular its currents cannot all be states: `di/dt` has no
//! unique value. This is a numerical singularity, not a structural one, so
//! it is found from the values: a pivoted Cholesky factorization picks the
//! windings whose fluxes are independent (the pivots `P`, largest diagonal
//! first) and stops where what is left is below [`RANK_TOL`] of the largest
//! self inductance. The group is then written with the pivots' fluxes as
//! states, each as a magnetizing current `im_p = φ_p/L_pp`:
//!
//! - `u_p = L_pp·der(im_p)` (Faraday's law on winding p);
//! - `im_p = Σ_j (L_pj/L_pp)·i_j` (the flux of winding p);
//! - `u_q = Σ_p C_qp·u_p` for every other winding q, with `C = L_QP·L_PP⁻¹`
//!   (its flux is a combination of the pivots': an ideal transformer).
//!
//! A group whose matrix is regular keeps one state per inductor; one that
//! is indefinite (coefficients that no magnetic circuit has) too, with a
//! warning that names its K elements (K0331, [`Groups::indefinite`]): its
//! matrix is invertible, which is all the per-inductor form needs.

use std::collections::HashMap;

use crate::elab::{Circuit, ElemId, ElementKind};
use crate::numeric::UnionFind;

/// Below this fraction of the largest self inductance, what is left of the
/// matrix after the pivots is zero: `k = 1 − 1e-10` is perfect coupling.
pub const RANK_TOL: f64 = 1e-9;

/// A group of coupled inductors with a singular inductance matrix, written
/// with its pivots' fluxes as states.
#[derive(Clone, Debug)]
pub struct Reduced {
    /// The inductors, in circuit order.
    pub members: Vec<ElemId>,
    /// The K elements that join them.
    pub couplings: Vec<ElemId>,
    /// Indices into `members` of the windings whose fluxes are the states.
    pub pivots: Vec<usize>,
    /// Per pivot: `im_p = Σ_j flux[p][j]·i_j` over all members.
    pub flux: Vec<Vec<f64>>,
    /// Per other winding (in member order, pivots left out): its voltage as
    /// `Σ_p ratio[q][p]·u_p` over the pivots.
    pub ratio: Vec<(usize, Vec<f64>)>,
    /// The self inductance of each pivot.
    pub l_pivot: Vec<f64>,
}

/// A group of inductors joined by K elements and its inductance matrix.
struct Group {
    members: Vec<ElemId>,
    couplings: Vec<ElemId>,
    /// Row-major, `members.len()` square.
    l: Vec<f64>,
}

/// The coupled groups of `c`, with their inductance matrices.
fn groups(c: &Circuit) -> Vec<Group> {
    let inductance = |e: ElemId| match c.elements[e].kind {
        ElementKind::Inductor { l, .. } => Some(l),
        _ => None,
    };
    let mut sets = UnionFind::new(c.elements.len());
    let mut couplings = Vec::new();
    for (id, e) in c.elements.iter() {
        if let ElementKind::Coupling { l1, l2, .. } = e.kind
            && inductance(l1).is_some()
            && inductance(l2).is_some()
        {
            sets.union(l1.0 as usize, l2.0 as usize);
            couplings.push(id);
        }
    }
    if couplings.is_empty() {
        return Vec::new();
    }
    // Members and couplings of each group, keyed by its representative.
    let mut groups: HashMap<usize, (Vec<ElemId>, Vec<ElemId>)> = HashMap::new();
    for &k in &couplings {
        let ElementKind::Coupling { l1, .. } = c.elements[k].kind else {
            continue;
        };
        groups
            .entry(sets.find(l1.0 as usize))
            .or_default()
            .1
            .push(k);
    }
    for (id, e) in c.elements.iter() {
        if matches!(e.kind, ElementKind::Inductor { .. })
            && let Some(g) = groups.get_mut(&sets.find(id.0 as usize))
        {
            g.0.push(id);
        }
    }
    let mut out: Vec<Group> = groups
        .into_values()
        .filter_map(|(members, couplings)| {
            let n = members.len();
            let index: HashMap<ElemId, usize> =
                members.iter().enumerate().map(|(k, &e)| (e, k)).collect();
            let mut l = vec![0.0; n * n];
            for (k, &e) in members.iter().enumerate() {
                l[k * n + k] = inductance(e)?;
            }
            for &kid in &couplings {
                let ElementKind::Coupling { l1, l2, k } = c.elements[kid].kind else {
                    continue;
                };
                let (a, b) = (index[&l1], index[&l2]);
                let m = k * (l[a * n + a] * l[b * n + b]).sqrt();
                l[a * n + b] += m;
                l[b * n + a] += m;
            }
            Some(Group {
                members,
                couplings,
                l,
            })
        })
        .collect();
    out.sort_by_key(|g| g.members[0]);
    out
}

/// The coupled groups of `c` by the shape of their inductance matrix.
#[derive(Debug, Default)]
pub struct Groups {
    /// Those whose matrix is singular (and positive semidefinite), reduced.
    pub singular: Vec<Reduced>,
    /// The K elements of each whose matrix is indefinite: coefficients no
    /// magnetic circuit has (`k12 = 1` beside `k13 = 0.99` with `k23 = 0`),
    /// a direction of negative magnetic energy along which the currents
    /// grow without bound. ngspice simulates them as written; so does
    /// kausal, with a warning.
    pub indefinite: Vec<Vec<ElemId>>,
}

/// Each coupled group of `c`, factored once.
pub fn classify(c: &Circuit) -> Groups {
    let mut out = Groups::default();
    for g in groups(c) {
        let n = g.members.len();
        match factor(&g.l, n) {
            Shape::Singular { pivots, left } => {
                if let Some((pivots, flux, ratio)) = reduce(&g.l, n, pivots, left) {
                    out.singular.push(Reduced {
                        l_pivot: pivots.iter().map(|&p| g.l[p * n + p]).collect(),
                        members: g.members,
                        couplings: g.couplings,
                        pivots,
                        flux,
                        ratio,
                    });
                }
            }
            Shape::Indefinite => out.indefinite.push(g.couplings),
            Shape::Regular | Shape::Degenerate => {}
        }
    }
    out
}

/// The coupled groups of `c` whose inductance matrix is singular.
pub fn singular_groups(c: &Circuit) -> Vec<Reduced> {
    classify(c).singular
}

/// What a pivoted Cholesky factorization finds of an inductance matrix.
enum Shape {
    /// Positive definite: every winding a pivot.
    Regular,
    /// Positive semidefinite of rank `pivots.len()`; `left` the rest.
    Singular {
        pivots: Vec<usize>,
        left: Vec<usize>,
    },
    /// A remainder that is not zero after the positive pivots: a negative
    /// diagonal, or a coupling left between windings.
    Indefinite,
    /// No finite, nonzero self inductance to scale by.
    Degenerate,
}

/// Pivoted Cholesky of the row-major `n`×`n` matrix `l`, largest diagonal
/// first, stopping below [`RANK_TOL`] of the largest self inductance.
fn factor(l: &[f64], n: usize) -> Shape {
    let scale = (0..n).map(|k| l[k * n + k].abs()).fold(0.0, f64::max);
    if !(scale > 0.0 && scale.is_finite()) {
        return Shape::Degenerate;
    }
    let tol = RANK_TOL * scale;
    // On a copy: after each pivot, `a` holds the Schur complement of the
    // pivots so far.
    let mut a = l.to_vec();
    let mut pivots = Vec::new();
    let mut left: Vec<usize> = (0..n).collect();
    // The largest diagonal, the first winding among equals.
    while let Some((pos, &p)) = left.iter().enumerate().max_by(|x, y| {
        a[x.1 * n + x.1]
            .total_cmp(&a[y.1 * n + y.1])
            .then(y.1.cmp(x.1))
    }) {
        let d = a[p * n + p];
        if d <= tol {
            break;
        }
        left.swap_remove(pos);
        pivots.push(p);
        for &i in &left {
            let f = a[i * n + p] / d;
            for &j in &left {
                a[i * n + j] -= f * a[p * n + j];
            }
        }
    }
    if left.is_empty() {
        Shape::Regular
    } else if left
        .iter()
        .any(|&i| left.iter().any(|&j| a[i * n + j].abs() > tol))
    {
        Shape::Indefinite
    } else {
        Shape::Singular { pivots, left }
    }
}

/// Flux rows and voltage ratios of the row-major `n`×`n` inductance matrix
/// `l`, singular and positive semidefinite with `pivots` and the windings
/// `left` (as [`factor`] found them), pivots sorted; `None` when the pivots'
/// block cannot be factored.
#[allow(clippy::type_complexity)]
fn reduce(
    l: &[f64],
    n: usize,
    mut pivots: Vec<usize>,
    mut left: Vec<usize>,
) -> Option<(Vec<usize>, Vec<Vec<f64>>, Vec<(usize, Vec<f64>)>)> {
    pivots.sort_unstable();
    left.sort_unstable();
    let r = pivots.len();
    // C = L_QP · L_PP⁻¹: solve L_PP · Cᵀ = L_PQ, one column per other winding.
    let mut lpp: Vec<f64> = pivots
        .iter()
        .flat_map(|&i| pivots.iter().map(move |&j| l[i * n + j]))
        .collect();
    let mut perm = vec![0; r];
    if !crate::numeric::dense::lu_factor(r, &mut lpp, &mut perm) {
        return None;
    }
    let mut tmp = vec![0.0; r];
    let ratio = left
        .iter()
        .map(|&q| {
            let mut col: Vec<f64> = pivots.iter().map(|&p| l[p * n + q]).collect();
            crate::numeric::dense::lu_solve(r, &lpp, &perm, &mut col, &mut tmp);
            (q, col)
        })
        .collect();
    let flux = pivots
        .iter()
        .map(|&p| (0..n).map(|j| l[p * n + j] / l[p * n + p]).collect())
        .collect();
    Some((pivots, flux, ratio))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`reduce`] of `l` where [`factor`] finds it singular.
    #[allow(clippy::type_complexity)]
    fn reduced(l: &[f64], n: usize) -> Option<(Vec<usize>, Vec<Vec<f64>>, Vec<(usize, Vec<f64>)>)> {
        match factor(l, n) {
            Shape::Singular { pivots, left } => reduce(l, n, pivots, left),
            _ => None,
        }
    }

    /// k12 = 1 beside k13 = 0.9957 with k23 = 0 (a fuzzed netlist's) is
    /// indefinite; k13 = k23 = 0.5 with k12 = 1 is singular, k12 = 0.9
    /// regular.
    #[test]
    fn couplings_no_magnetic_circuit_has_are_indefinite() {
        let m = |k12: f64, k13: f64, k23: f64| vec![1.0, k12, k13, k12, 1.0, k23, k13, k23, 1.0];
        assert!(matches!(factor(&m(1.0, 0.9957, 0.0), 3), Shape::Indefinite));
        assert!(matches!(
            factor(&m(1.0, 0.5, 0.5), 3),
            Shape::Singular { .. }
        ));
        assert!(matches!(factor(&m(0.9, 0.1, 0.0), 3), Shape::Regular));
    }

    #[test]
    fn perfect_coupling_of_two_windings_is_an_ideal_transformer() {
        // L1 = 4, L2 = 1, k = 1: M = 2; pivot L1, im = i1 + i2/2, u2 = u1/2.
        let (pivots, flux, ratio) = reduced(&[4.0, 2.0, 2.0, 1.0], 2).expect("singular");
        assert_eq!(pivots, [0]);
        assert_eq!(flux, [vec![1.0, 0.5]]);
        assert_eq!(ratio.len(), 1);
        assert_eq!(ratio[0].0, 1);
        assert!((ratio[0].1[0] - 0.5).abs() < 1e-15);
    }

    #[test]
    fn three_windings_coupled_pairwise_at_one_have_one_flux() {
        let ls: [f64; 3] = [1.0, 4.0, 9.0];
        let l: Vec<f64> = (0..9).map(|k| (ls[k / 3] * ls[k % 3]).sqrt()).collect();
        let (pivots, _, ratio) = reduced(&l, 3).expect("singular");
        assert_eq!(pivots, [2]);
        // u_q = √(L_q/L_p)·u_p: turns ratios 1:2:3.
        let r: Vec<f64> = ratio.iter().map(|(_, c)| c[0]).collect();
        assert!((r[0] - 1.0 / 3.0).abs() < 1e-12 && (r[1] - 2.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn regular_and_indefinite_matrices_keep_one_state_per_inductor() {
        // k = 0.99: regular.
        assert!(reduced(&[1.0, 0.99, 0.99, 1.0], 2).is_none());
        // k12 = 1 and k13 = 0.9957 on one winding: indefinite, invertible.
        let k13 = 0.9957;
        let l = [1.0, 1.0, k13, 1.0, 1.0, 0.0, k13, 0.0, 1.0];
        assert!(reduced(&l, 3).is_none());
    }
}
