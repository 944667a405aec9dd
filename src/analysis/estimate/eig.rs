//! Eigenvalues of a small general complex matrix (the ESPRIT rotation Φ), by nalgebra's complex
//! Schur decomposition with a cap on its iterations.
//!
//! The cap matters: the QR iteration can fail to converge (a hand-written single-shift QR
//! served here until nalgebra's `Schur::try_new` took an iteration limit; without one the
//! iteration could loop forever, nalgebra issue #611). With it, a rotation that does not
//! converge is an error the caller reports instead of a hung job.

use nalgebra::DMatrix;

use super::filter::C64;

/// Iterations allowed per eigenvalue before giving up (LAPACK allows 30 per eigenvalue with a
/// double shift; nalgebra's complex Schur uses single shifts, which need somewhat more).
const MAX_ITER_PER_EIGENVALUE: usize = 60;

/// All eigenvalues of the square matrix `a` (in no particular order), or `None` if the QR
/// iteration did not converge or `a` holds non-finite entries.
pub(super) fn eigenvalues(a: &DMatrix<C64>) -> Option<Vec<C64>> {
    let n = a.nrows();
    assert_eq!(n, a.ncols(), "eigenvalues of a non-square matrix");
    if a.iter().any(|v| !(v.re.is_finite() && v.im.is_finite())) {
        return None;
    }
    if a.iter().all(|v| v.re == 0.0 && v.im == 0.0) {
        // nalgebra's Schur divides by the matrix's norm; the zero matrix's spectrum is zero.
        return Some(vec![C64::new(0.0, 0.0); n]);
    }
    let schur = nalgebra::Schur::try_new(a.clone(), f64::EPSILON, MAX_ITER_PER_EIGENVALUE * n)?;
    // Over the complex field the Schur form is upper triangular: its diagonal is the spectrum.
    let (_, t) = schur.unpack();
    let eig: Vec<C64> = (0..n).map(|i| t[(i, i)]).collect();
    eig.iter()
        .all(|v| v.re.is_finite() && v.im.is_finite())
        .then_some(eig)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Matches every wanted eigenvalue to a distinct computed one within `tol` (relative to the
    /// largest magnitude).
    fn assert_same_spectrum(got: &[C64], want: &[C64], tol: f64) {
        assert_eq!(got.len(), want.len());
        let scale = want.iter().map(|z| z.norm()).fold(1e-300, f64::max);
        let mut used = vec![false; got.len()];
        for w in want {
            let (best, dist) = got
                .iter()
                .enumerate()
                .filter(|(i, _)| !used[*i])
                .map(|(i, g)| (i, (g - w).norm()))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap();
            assert!(
                dist <= tol * scale,
                "eigenvalue {w} found only as {} (off by {dist:e})",
                got[best]
            );
            used[best] = true;
        }
    }

    fn lcg(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }

    #[test]
    fn similarity_transform_of_a_diagonal_matrix() {
        // A = V Λ V⁻¹ with a random complex V and eigenvalues on and inside the unit circle, as
        // ESPRIT produces.
        let mut seed = 7u64;
        for n in [1usize, 2, 3, 8, 25, 60] {
            let lambda: Vec<C64> = (0..n)
                .map(|k| {
                    C64::from_polar(
                        0.9 + 0.1 * (k as f64 / n as f64),
                        6.0 * k as f64 / n as f64 - 3.0,
                    )
                })
                .collect();
            let v = DMatrix::from_fn(n, n, |_, _| C64::new(lcg(&mut seed), lcg(&mut seed)));
            let v_inv = v.clone().try_inverse().unwrap();
            let a =
                &v * DMatrix::from_diagonal(&nalgebra::DVector::from_vec(lambda.clone())) * v_inv;
            let got = eigenvalues(&a).expect("converges");
            assert_same_spectrum(&got, &lambda, 1e-9);
        }
    }

    #[test]
    fn companion_matrices_with_close_and_repeated_roots() {
        // Roots of z⁵ − 1 (nalgebra's Schur loops on a companion matrix like this), and a
        // cluster of nearly equal roots as two close modes give.
        let cases: Vec<Vec<C64>> = vec![
            (0..5)
                .map(|k| C64::from_polar(1.0, 2.0 * std::f64::consts::PI * k as f64 / 5.0))
                .collect(),
            vec![
                C64::from_polar(0.999, 0.3),
                C64::from_polar(0.999, 0.3 + 1e-4),
                C64::from_polar(0.98, -1.0),
                C64::new(0.5, 0.0),
            ],
        ];
        for roots in cases {
            let n = roots.len();
            // Coefficients of Π (z − r) by repeated multiplication; companion matrix in the
            // usual form (ones on the sub-diagonal, −coefficients in the last column).
            let mut coef = vec![C64::new(1.0, 0.0)];
            for r in &roots {
                let mut next = vec![C64::new(0.0, 0.0); coef.len() + 1];
                for (i, c) in coef.iter().enumerate() {
                    next[i + 1] += c;
                    next[i] -= c * r;
                }
                coef = next;
            }
            let a = DMatrix::from_fn(n, n, |i, j| {
                if j == n - 1 {
                    -coef[i]
                } else if i == j + 1 {
                    C64::new(1.0, 0.0)
                } else {
                    C64::new(0.0, 0.0)
                }
            });
            let got = eigenvalues(&a).expect("converges");
            // A cluster of width δ is only determined to ~√(ε) relative accuracy.
            assert_same_spectrum(&got, &roots, 1e-7);
        }
    }

    #[test]
    fn non_finite_input_is_refused() {
        let mut a = DMatrix::from_element(3, 3, C64::new(1.0, 0.0));
        a[(1, 2)] = C64::new(f64::NAN, 0.0);
        assert!(eigenvalues(&a).is_none());
        assert_eq!(eigenvalues(&DMatrix::<C64>::zeros(0, 0)), Some(vec![]));
        assert_eq!(
            eigenvalues(&DMatrix::<C64>::zeros(4, 4)),
            Some(vec![C64::new(0.0, 0.0); 4])
        );
    }
}
