//! Eigenvalues of a small general complex matrix (the ESPRIT rotation Φ): Householder
//! reduction to upper Hessenberg form, then the single-shift QR algorithm with Wilkinson shifts
//! and Givens rotations, deflating from the bottom.
//!
//! Written here rather than taken from nalgebra's `Schur` because the latter can loop forever on
//! some inputs (nalgebra issue #611); this one gives up after 60 n iterations and says so, so the
//! caller can report an error instead of hanging.

use nalgebra::DMatrix;

use super::filter::C64;

/// Iterations allowed per eigenvalue before giving up (LAPACK allows 30 per eigenvalue with a
/// double shift; single shifts need somewhat more).
const MAX_ITER_PER_EIGENVALUE: usize = 60;

/// All eigenvalues of the square matrix `a` (in no particular order), or `None` if the QR
/// iteration did not converge or `a` holds non-finite entries.
pub(super) fn eigenvalues(a: &DMatrix<C64>) -> Option<Vec<C64>> {
    let n = a.nrows();
    assert_eq!(n, a.ncols(), "eigenvalues of a non-square matrix");
    if a.iter().any(|v| !(v.re.is_finite() && v.im.is_finite())) {
        return None;
    }
    let mut h = a.clone();
    hessenberg(&mut h);
    let scale = h.iter().map(|v| v.norm()).fold(0.0_f64, f64::max);
    let mut eig = vec![C64::new(0.0, 0.0); n];
    // The unreduced block being iterated is rows/columns lo..hi; everything from hi on has
    // converged.
    let mut hi = n;
    let mut total = 0usize;
    let mut since_deflation = 0usize;
    while hi > 0 {
        // Find lo: the start of the unreduced block ending at hi − 1.
        let mut lo = hi - 1;
        while lo > 0 {
            let mut s = h[(lo - 1, lo - 1)].norm() + h[(lo, lo)].norm();
            if s == 0.0 {
                s = scale;
            }
            if h[(lo, lo - 1)].norm() <= f64::EPSILON * s {
                h[(lo, lo - 1)] = C64::new(0.0, 0.0);
                break;
            }
            lo -= 1;
        }
        if lo == hi - 1 {
            eig[hi - 1] = h[(hi - 1, hi - 1)];
            hi -= 1;
            since_deflation = 0;
            continue;
        }
        total += 1;
        since_deflation += 1;
        if total > MAX_ITER_PER_EIGENVALUE * n {
            return None;
        }
        let mu = if since_deflation % 11 == 10 {
            // Exceptional shift: breaks the rare cycles a Wilkinson shift can fall into.
            h[(hi - 1, hi - 1)] + C64::new(0.75 * h[(hi - 1, hi - 2)].norm(), 0.0)
        } else {
            wilkinson_shift(&h, hi)
        };
        qr_step(&mut h, lo, hi, mu);
    }
    Some(eig)
}

/// The eigenvalue of the trailing 2 × 2 block of rows/columns hi − 2, hi − 1 closest to its
/// last diagonal entry.
fn wilkinson_shift(h: &DMatrix<C64>, hi: usize) -> C64 {
    let a = h[(hi - 2, hi - 2)];
    let b = h[(hi - 2, hi - 1)];
    let c = h[(hi - 1, hi - 2)];
    let d = h[(hi - 1, hi - 1)];
    let half_diff = (a - d) * 0.5;
    let disc = (half_diff * half_diff + b * c).sqrt();
    let mean = (a + d) * 0.5;
    let (m1, m2) = (mean + disc, mean - disc);
    if (m1 - d).norm() <= (m2 - d).norm() {
        m1
    } else {
        m2
    }
}

/// One explicitly shifted QR step H − μI = QR, H ← RQ + μI on the block lo..hi, with the
/// Givens rotations G_k = [[c, s], [−s̄, c]] (c real) that zero the sub-diagonal. Rows above lo
/// and columns from hi on are not updated: they do not affect the block's eigenvalues.
fn qr_step(h: &mut DMatrix<C64>, lo: usize, hi: usize, mu: C64) {
    for i in lo..hi {
        h[(i, i)] -= mu;
    }
    let mut rotations = Vec::with_capacity(hi - lo);
    for k in lo..hi - 1 {
        let (c, s) = givens(h[(k, k)], h[(k + 1, k)]);
        for j in k..hi {
            let x = h[(k, j)];
            let y = h[(k + 1, j)];
            h[(k, j)] = x * c + s * y;
            h[(k + 1, j)] = -s.conj() * x + y * c;
        }
        rotations.push((c, s));
    }
    for (k, &(c, s)) in (lo..hi - 1).zip(&rotations) {
        // Right multiplication by G_kᴴ = [[c, −s], [s̄, c]] on columns k, k + 1.
        for i in lo..=(k + 1).min(hi - 1) {
            let x = h[(i, k)];
            let y = h[(i, k + 1)];
            h[(i, k)] = x * c + s.conj() * y;
            h[(i, k + 1)] = -s * x + y * c;
        }
    }
    for i in lo..hi {
        h[(i, i)] += mu;
    }
}

/// (c, s) with c real, |c|² + |s|² = 1 and [[c, s], [−s̄, c]] (a, b)ᵀ = (r, 0)ᵀ.
fn givens(a: C64, b: C64) -> (f64, C64) {
    let (na, nb) = (a.norm(), b.norm());
    if nb == 0.0 {
        (1.0, C64::new(0.0, 0.0))
    } else if na == 0.0 {
        (0.0, b.conj() / nb)
    } else {
        let norm = na.hypot(nb);
        (na / norm, (a / na) * b.conj() / norm)
    }
}

/// In-place reduction to upper Hessenberg form by Householder reflections P = I − 2vvᴴ
/// (similarity transforms, so the eigenvalues are unchanged).
fn hessenberg(a: &mut DMatrix<C64>) {
    let n = a.nrows();
    for k in 0..n.saturating_sub(2) {
        let norm_x = (k + 1..n).map(|i| a[(i, k)].norm_sqr()).sum::<f64>().sqrt();
        if norm_x == 0.0 {
            continue;
        }
        let x0 = a[(k + 1, k)];
        // α = −e^{i arg x0} ‖x‖, so v = x − α e₁ involves no cancellation.
        let phase = if x0.norm() > 0.0 {
            x0 / x0.norm()
        } else {
            C64::new(1.0, 0.0)
        };
        let alpha = -phase * norm_x;
        let mut v: Vec<C64> = (k + 1..n).map(|i| a[(i, k)]).collect();
        v[0] -= alpha;
        let norm_v = v.iter().map(|z| z.norm_sqr()).sum::<f64>().sqrt();
        if norm_v == 0.0 {
            continue;
        }
        for z in &mut v {
            *z /= norm_v;
        }
        // A ← P A on rows k+1.., then A ← A P on columns k+1...
        for j in k..n {
            let dot: C64 = v
                .iter()
                .enumerate()
                .map(|(t, vi)| vi.conj() * a[(k + 1 + t, j)])
                .sum();
            for (t, vi) in v.iter().enumerate() {
                a[(k + 1 + t, j)] -= vi * dot * 2.0;
            }
        }
        for i in 0..n {
            let dot: C64 = v
                .iter()
                .enumerate()
                .map(|(t, vi)| a[(i, k + 1 + t)] * vi)
                .sum();
            for (t, vi) in v.iter().enumerate() {
                a[(i, k + 1 + t)] -= dot * vi.conj() * 2.0;
            }
        }
        for i in k + 2..n {
            a[(i, k)] = C64::new(0.0, 0.0);
        }
    }
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
