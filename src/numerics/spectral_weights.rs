//! Eigenvalues of a symmetric matrix with the weight of one vector on each eigenvector.
//!
//! For symmetric C (n × n) with C v_k = λ_k v_k (v_k orthonormal) and a vector w, the pairs
//! (λ_k, (w · v_k)²) are what a modal problem needs when only one drive (or one observation)
//! matters: the loaded line match ([`crate::inverse::loaded_match`]) asks for the loaded
//! frequencies and the strike's drive of each, tens of thousands of times on 60 × 60 matrices.
//! Forming every eigenvector costs more than the reduction to tridiagonal form itself; the
//! weights need one vector carried through the same transformations instead (on 60 × 60,
//! 0.31-0.33 ms against nalgebra's 0.43-0.69 ms for the full decomposition, one core).
//!
//! **Method.** Householder reflections H_j = I − 2 u_j u_jᵀ reduce C to tridiagonal T = Qᵀ C Q
//! (Q = H_1 ⋯ H_{n−2}); the same reflections give w′ = Qᵀ w, applied in order. The implicit QL
//! iteration with Wilkinson's shift then diagonalises T by plane rotations, T → Gᵀ T G; the
//! eigenvectors Y of T are the product of the rotations, and since w · v_k = w′ · y_k, the vector
//! Yᵀ w′ is updated by each rotation's two entries (O(1) per rotation rather than O(n)). Cost:
//! about 2n³ flops for the reduction (both triangles updated) and O(n²) for the iteration.
//! Eigenvalues come out ascending, each with its weight; their sum is |w|² (Parseval), kept to
//! rounding.
//!
//! Where eigenvalues coincide the eigenvectors within the eigenspace are arbitrary, and so is the
//! split of the weight among them; only its sum over the eigenspace is defined (any
//! eigensolver's choice is one of many).

use nalgebra::{DMatrix, DVector};

/// Why [`eigen_with_weights`] gave no answer.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SpectralWeightsError {
    #[error("matrix {rows} × {cols} and vector of length {len} do not fit a square problem")]
    Shape {
        rows: usize,
        cols: usize,
        len: usize,
    },
    #[error("the matrix or the vector holds a value that is not finite")]
    NotFinite,
    #[error("the QL iteration did not converge at eigenvalue {index} in {iterations} sweeps")]
    NoConvergence { index: usize, iterations: usize },
}

/// Sweeps of the QL iteration per eigenvalue before giving up (it needs two or three).
const MAX_SWEEPS: usize = 60;

/// The eigenvalues of the symmetric `c` (its lower triangle is used) ascending, each with the
/// weight (w · v_k)² of `w` on its unit eigenvector (module docs).
pub fn eigen_with_weights(
    c: &DMatrix<f64>,
    w: &DVector<f64>,
) -> Result<Vec<(f64, f64)>, SpectralWeightsError> {
    let n = c.nrows();
    if c.ncols() != n || w.len() != n {
        return Err(SpectralWeightsError::Shape {
            rows: c.nrows(),
            cols: c.ncols(),
            len: w.len(),
        });
    }
    if c.iter().chain(w.iter()).any(|x| !x.is_finite()) {
        return Err(SpectralWeightsError::NotFinite);
    }
    if n == 0 {
        return Ok(Vec::new());
    }
    let (mut d, mut e, mut u) = tridiagonalise(c, w);
    ql_implicit(&mut d, &mut e, &mut u)?;
    let mut out: Vec<(f64, f64)> = d.into_iter().zip(u).map(|(l, x)| (l, x * x)).collect();
    out.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok(out)
}

/// Householder reduction of the symmetric `c` (lower triangle) to tridiagonal form: its
/// diagonal, its subdiagonal (e_i = T_{i+1,i}, the last entry 0) and Qᵀ w.
fn tridiagonalise(c: &DMatrix<f64>, w: &DVector<f64>) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let n = c.nrows();
    // A symmetric copy filled from the lower triangle, column-major: column j is
    // a[j n .. (j + 1) n], so every inner loop below runs along a contiguous column.
    let mut a = vec![0.0; n * n];
    for j in 0..n {
        for i in j..n {
            let x = c[(i, j)];
            a[j * n + i] = x;
            a[i * n + j] = x;
        }
    }
    let mut wq: Vec<f64> = w.iter().copied().collect();
    let mut v = vec![0.0; n];
    let mut p = vec![0.0; n];
    let dot = |x: &[f64], y: &[f64]| x.iter().zip(y).map(|(a, b)| a * b).sum::<f64>();
    for k in 0..n.saturating_sub(2) {
        let start = k + 1;
        let column = &a[k * n + start..(k + 1) * n];
        let norm = dot(column, column).sqrt();
        if norm == 0.0 {
            continue;
        }
        // Reflect x = a[start.., k] onto ∓|x| e_1, the sign chosen against cancellation.
        let alpha = if column[0] > 0.0 { -norm } else { norm };
        v[start..n].copy_from_slice(column);
        v[start] -= alpha;
        let vnorm = dot(&v[start..n], &v[start..n]).sqrt();
        if vnorm == 0.0 {
            continue;
        }
        v[start..n].iter_mut().for_each(|x| *x /= vnorm);
        // H A H on the trailing block: p = A v (A symmetric: p_i = column i · v), K = vᵀp,
        // q = p − K v, A −= 2(v qᵀ + q vᵀ).
        // As axpys over the columns (p += A_{·j} v_j, j ascending), which vectorise across
        // i; each p_i sums the same terms in the same order as column i · v would (A is kept
        // exactly symmetric), from −0.0 as `Iterator::sum` does, so the result is the same.
        p[start..n].iter_mut().for_each(|x| *x = -0.0);
        for j in start..n {
            let vj = v[j];
            let col = &a[j * n + start..(j + 1) * n];
            for (pi, aij) in p[start..n].iter_mut().zip(col) {
                *pi += aij * vj;
            }
        }
        let kk = dot(&v[start..n], &p[start..n]);
        for i in start..n {
            p[i] -= kk * v[i];
        }
        for j in start..n {
            let (vj, pj) = (2.0 * v[j], 2.0 * p[j]);
            let col = &mut a[j * n + start..(j + 1) * n];
            for ((x, vi), pi) in col.iter_mut().zip(&v[start..n]).zip(&p[start..n]) {
                *x -= vi * pj + pi * vj;
            }
        }
        a[k * n + start] = alpha;
        a[start * n + k] = alpha;
        for i in start + 1..n {
            a[k * n + i] = 0.0;
            a[i * n + k] = 0.0;
        }
        // w′ ← H w′.
        let vw = dot(&v[start..n], &wq[start..n]);
        for i in start..n {
            wq[i] -= 2.0 * vw * v[i];
        }
    }
    let d = (0..n).map(|i| a[i * n + i]).collect();
    let e = (0..n)
        .map(|i| if i + 1 < n { a[i * n + i + 1] } else { 0.0 })
        .collect();
    (d, e, wq)
}

/// The implicit QL iteration with Wilkinson's shift on the tridiagonal (d, e) (e_i the entry
/// below d_i, e_{n−1} = 0): d becomes the eigenvalues (unordered), and each rotation is applied
/// to `u` as to the rows of the eigenvector matrix's transpose, so that `u` ends as Yᵀu.
fn ql_implicit(d: &mut [f64], e: &mut [f64], u: &mut [f64]) -> Result<(), SpectralWeightsError> {
    let n = d.len();
    for l in 0..n {
        let mut sweeps = 0;
        loop {
            // The first negligible subdiagonal entry at or after l splits the problem.
            let mut m = l;
            while m + 1 < n {
                let scale = d[m].abs() + d[m + 1].abs();
                if e[m].abs() <= f64::EPSILON * scale {
                    break;
                }
                m += 1;
            }
            if m == l {
                break;
            }
            sweeps += 1;
            if sweeps > MAX_SWEEPS {
                return Err(SpectralWeightsError::NoConvergence {
                    index: l,
                    iterations: sweeps - 1,
                });
            }
            // Wilkinson's shift from the leading 2 × 2 block, folded into the first rotation.
            let mut g = (d[l + 1] - d[l]) / (2.0 * e[l]);
            let r = (g * g + 1.0).sqrt();
            g = d[m] - d[l] + e[l] / (g + r.copysign(g));
            let (mut s, mut c, mut p) = (1.0_f64, 1.0_f64, 0.0_f64);
            let mut deflated = false;
            for i in (l..m).rev() {
                let f = s * e[i];
                let b = c * e[i];
                // √(f² + g²) without hypot's care for overflow: the entries are eigenvalue
                // scales far inside the range, and hypot was half the iteration's time.
                let r = (f * f + g * g).sqrt();
                e[i + 1] = r;
                if r == 0.0 {
                    // An exact zero below d_{i+1}: finish with what is done and sweep again.
                    d[i + 1] -= p;
                    e[m] = 0.0;
                    deflated = true;
                    break;
                }
                s = f / r;
                c = g / r;
                g = d[i + 1] - p;
                let t = (d[i] - g) * s + 2.0 * c * b;
                p = s * t;
                d[i + 1] = g + p;
                g = c * t - b;
                let (ui, uj) = (u[i], u[i + 1]);
                u[i + 1] = s * ui + c * uj;
                u[i] = c * ui - s * uj;
            }
            if deflated {
                continue;
            }
            d[l] -= p;
            e[l] = g;
            e[m] = 0.0;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::SplitMix64;
    use nalgebra::SymmetricEigen;

    /// A reproducible symmetric matrix with eigenvalues `values` (a random orthogonal basis
    /// from the QR of a pseudo-random matrix), and a pseudo-random vector.
    fn with_spectrum(values: &[f64], seed: u64) -> (DMatrix<f64>, DVector<f64>) {
        let n = values.len();
        let mut rng = SplitMix64::new(seed);
        let mut next = || rng.uniform(-0.5, 0.5);
        let raw = DMatrix::from_fn(n, n, |_, _| next());
        let q = raw.qr().q();
        let c = &q * DMatrix::from_diagonal(&DVector::from_column_slice(values)) * q.transpose();
        let w = DVector::from_fn(n, |_, _| next());
        (c, w)
    }

    /// Against nalgebra's full eigendecomposition on separated spectra of sizes 1 to 60: the
    /// same eigenvalues and the same weights, and the weights sum to |w|².
    #[test]
    fn eigenvalues_and_weights_match_a_full_decomposition() {
        for (n, seed) in [(1, 1), (2, 2), (3, 3), (7, 4), (25, 5), (60, 6)] {
            let values: Vec<f64> = (0..n)
                .map(|k| 1.0 + k as f64 * (1.0 + 0.1 * k as f64))
                .collect();
            let (c, w) = with_spectrum(&values, seed);
            let got = eigen_with_weights(&c, &w).unwrap();
            let full = SymmetricEigen::new(c.clone());
            let mut want: Vec<(f64, f64)> = (0..n)
                .map(|k| {
                    let x = w.dot(&full.eigenvectors.column(k));
                    (full.eigenvalues[k], x * x)
                })
                .collect();
            want.sort_by(|a, b| a.0.total_cmp(&b.0));
            let top = values.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
            let w2 = w.norm_squared();
            for (k, (g, e)) in got.iter().zip(&want).enumerate() {
                assert!(
                    (g.0 - e.0).abs() <= 1e-12 * top,
                    "n {n} value {k}: {g:?} vs {e:?}"
                );
                assert!(
                    (g.1 - e.1).abs() <= 1e-10 * w2,
                    "n {n} weight {k}: {g:?} vs {e:?}"
                );
            }
            let sum: f64 = got.iter().map(|x| x.1).sum();
            assert!(
                (sum - w2).abs() <= 1e-12 * w2,
                "n {n}: Σ weights {sum} vs |w|² {w2}"
            );
        }
    }

    /// Exactly and nearly coincident eigenvalues (the split pairs of a symmetric body): every
    /// eigenvalue found, and each cluster's summed weight equals a full decomposition's.
    #[test]
    fn clusters_keep_their_summed_weight() {
        let values = [
            -3.0,
            0.5,
            2.0,
            2.0,
            2.0 + 1e-9,
            5.0,
            5.0 + 1e-6,
            7.0,
            7.0,
            1e3,
            1e3 * (1.0 + 1e-12),
        ];
        let (c, w) = with_spectrum(&values, 11);
        let got = eigen_with_weights(&c, &w).unwrap();
        let full = SymmetricEigen::new(c.clone());
        let weight_near = |pairs: &[(f64, f64)], centre: f64| -> f64 {
            pairs
                .iter()
                .filter(|p| (p.0 - centre).abs() <= 1e-5 * centre.abs().max(1.0))
                .map(|p| p.1)
                .sum()
        };
        let want: Vec<(f64, f64)> = (0..values.len())
            .map(|k| {
                let x = w.dot(&full.eigenvectors.column(k));
                (full.eigenvalues[k], x * x)
            })
            .collect();
        for (g, v) in got.iter().zip(&values) {
            assert!((g.0 - v).abs() <= 1e-11 * 1e3, "{g:?} vs {v}");
        }
        for centre in [-3.0, 0.5, 2.0, 5.0, 7.0, 1e3] {
            let (a, b) = (weight_near(&got, centre), weight_near(&want, centre));
            assert!(
                (a - b).abs() <= 1e-10 * w.norm_squared(),
                "cluster at {centre}: {a} vs {b}"
            );
        }
    }

    /// Already diagonal or tridiagonal input, a zero vector, and bad input.
    #[test]
    fn edge_cases_and_bad_input() {
        let d = DMatrix::from_diagonal(&DVector::from_vec(vec![3.0, 1.0, 2.0]));
        let got = eigen_with_weights(&d, &DVector::from_vec(vec![1.0, 2.0, 0.0])).unwrap();
        assert_eq!(got, vec![(1.0, 4.0), (2.0, 0.0), (3.0, 1.0)]);
        let zero = eigen_with_weights(&d, &DVector::zeros(3)).unwrap();
        assert!(zero.iter().all(|p| p.1 == 0.0));
        assert!(
            eigen_with_weights(&DMatrix::zeros(0, 0), &DVector::zeros(0))
                .unwrap()
                .is_empty()
        );
        assert!(matches!(
            eigen_with_weights(&d, &DVector::zeros(2)),
            Err(SpectralWeightsError::Shape { .. })
        ));
        let mut bad = d.clone();
        bad[(1, 0)] = f64::NAN;
        assert_eq!(
            eigen_with_weights(&bad, &DVector::zeros(3)),
            Err(SpectralWeightsError::NotFinite)
        );
    }
}
