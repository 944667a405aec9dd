//! Multi-channel ESPRIT on the decimated band signals (parent module docs, "Subspace" and
//! "Model order").

use nalgebra::{DMatrix, SymmetricEigen, SVD};

use super::eig;
use super::filter::C64;

/// Outcome of the subspace step of one band.
#[derive(Clone, Debug)]
pub(super) struct Subspace {
    /// Model order K chosen.
    pub order: usize,
    /// ESPRIT poles w_k per decimated sample (K of them).
    pub poles: Vec<C64>,
}

/// Why a band's subspace step failed.
#[derive(Clone, Debug, PartialEq)]
pub(super) enum SubspaceFailure {
    HermitianEigen,
    RotationEigen,
}

/// R[i][j] = Σ_c Σ_{t=0}^{M−1} y_c[i + t] ȳ_c[j + t], i, j < L, M = N − L + 1: the Gram matrix
/// of the channels' L × M Hankel matrices placed side by side, [H₁ H₂ …] [H₁ H₂ …]ᴴ.
/// Costs O(C (L M + L²)): the first row directly, then down each diagonal by the sliding-window
/// update R[i+1][j+1] = R[i][j] + y[i+M] ȳ[j+M] − y[i] ȳ[j].
pub(super) fn sliding_gram(bands: &[Vec<C64>], rows: usize) -> DMatrix<C64> {
    let mut r = DMatrix::<C64>::zeros(rows, rows);
    for y in bands {
        let m = y.len() + 1 - rows;
        for j in 0..rows {
            let mut first = C64::new(0.0, 0.0);
            for t in 0..m {
                first += y[t] * y[j + t].conj();
            }
            // Walk the diagonal (0, j), (1, j+1), … of the upper triangle.
            let mut value = first;
            for i in 0..rows - j {
                r[(i, i + j)] += value;
                if i + 1 < rows - j {
                    value += y[i + m] * y[i + j + m].conj() - y[i] * y[i + j].conj();
                }
            }
        }
    }
    for i in 0..rows {
        r[(i, i)] = C64::new(r[(i, i)].re, 0.0);
        for j in i + 1..rows {
            r[(j, i)] = r[(i, j)].conj();
        }
    }
    r
}

/// The signal subspace and poles of one band. `max_order` caps K; `threshold` is the factor
/// (linear, power) by which a signal eigenvalue must exceed the noise floor.
pub(super) fn estimate_poles(
    bands: &[Vec<C64>],
    rows: usize,
    max_order: usize,
    threshold: f64,
) -> Result<Subspace, SubspaceFailure> {
    let gram = sliding_gram(bands, rows);
    if gram.iter().any(|v| !(v.re.is_finite() && v.im.is_finite())) {
        return Err(SubspaceFailure::HermitianEigen);
    }
    let eig = SymmetricEigen::try_new(gram, f64::EPSILON, 1000 * rows)
        .ok_or(SubspaceFailure::HermitianEigen)?;
    let mut order: Vec<usize> = (0..rows).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let eigenvalues: Vec<f64> = order.iter().map(|&i| eig.eigenvalues[i]).collect();
    if eigenvalues.iter().any(|v| !v.is_finite()) {
        return Err(SubspaceFailure::HermitianEigen);
    }
    let k = model_order(&eigenvalues, max_order.min(rows - 1), threshold);
    if k == 0 {
        return Ok(Subspace {
            order: 0,
            poles: vec![],
        });
    }
    let u = DMatrix::from_fn(rows, k, |i, j| eig.eigenvectors[(i, order[j])]);
    // Shift invariance U₂ ≈ U₁ Φ, solved in the least-squares sense: Φ = (U₁ᴴU₁)⁻¹ U₁ᴴ U₂.
    // U₁ᴴU₁ = I − u uᴴ (u = last row of U, conjugated) is well conditioned unless ‖u‖ → 1.
    let u1 = u.rows(0, rows - 1);
    let u2 = u.rows(1, rows - 1);
    let a = u1.adjoint() * u1;
    let b = u1.adjoint() * u2;
    let phi = match a.clone().cholesky() {
        Some(ch) => ch.solve(&b),
        None => {
            // Only when the last row of U carries (almost) all of some direction: solve in the
            // minimum-norm sense instead.
            let svd = SVD::try_new(a, true, true, f64::EPSILON, 1000 * k)
                .ok_or(SubspaceFailure::RotationEigen)?;
            svd.solve(&b, 1e-12)
                .map_err(|_| SubspaceFailure::RotationEigen)?
        }
    };
    let poles = eig::eigenvalues(&phi).ok_or(SubspaceFailure::RotationEigen)?;
    Ok(Subspace { order: k, poles })
}

/// K = #{i < K_max : λ_i > max(ν·τ, 1e-15 λ₀)}, ν = median of the eigenvalues from K_max on
/// (eigenvalues that cannot be signal under the cap, so the median is the noise floor even when
/// every allowed slot holds a mode), τ = `threshold`. In a noise-free signal ν is the rounding
/// level of R; the 1e-15 λ₀ floor only matters when the tail is exactly zero. (Counting down to
/// rounding is deliberate: a noise-free band is then modelled with every component, including
/// the −90 dB leakage of other bands, which made poles ~100 times more accurate than a floor at
/// 1e-11 λ₀ did.)
fn model_order(eigenvalues: &[f64], max_order: usize, threshold: f64) -> usize {
    let top = eigenvalues.first().copied().unwrap_or(0.0);
    if top <= 0.0 {
        return 0;
    }
    let tail = &eigenvalues[max_order.min(eigenvalues.len() - 1)..];
    // Sorted descending, so the median is the middle element.
    let floor = tail[tail.len() / 2].max(0.0);
    let level = (floor * threshold).max(1e-15 * top);
    eigenvalues
        .iter()
        .take(max_order)
        .take_while(|&&l| l > level)
        .count()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sliding_gram_equals_the_explicit_hankel_product() {
        let y: Vec<C64> = (0..40)
            .map(|k| {
                C64::new(
                    (k as f64 * 0.37).sin(),
                    (k as f64 * 1.3).cos() + 0.1 * k as f64,
                )
            })
            .collect();
        let y2: Vec<C64> = y.iter().map(|v| v * C64::new(0.3, -2.0) + 0.5).collect();
        let rows = 11;
        let r = sliding_gram(&[y.clone(), y2.clone()], rows);
        let m = y.len() - rows + 1;
        let h = DMatrix::from_fn(
            rows,
            2 * m,
            |i, t| if t < m { y[i + t] } else { y2[i + t - m] },
        );
        let want = &h * h.adjoint();
        assert!((r - want.clone()).norm() < 1e-12 * want.norm());
    }

    #[test]
    fn poles_of_a_noise_free_two_channel_signal_are_exact() {
        let poles = [
            C64::from_polar(0.999, 0.4),
            C64::from_polar(0.99, 0.41),
            C64::from_polar(0.95, -2.0),
        ];
        let amps = [
            [C64::new(1.0, 0.0), C64::new(0.2, 0.3)],
            [C64::new(0.0, -0.5), C64::new(1.0, 0.0)],
            [C64::new(0.3, 0.0), C64::new(0.0, 0.0)],
        ];
        let bands: Vec<Vec<C64>> = (0..2)
            .map(|c| {
                (0..300)
                    .map(|m| (0..3).map(|k| amps[k][c] * poles[k].powu(m as u32)).sum())
                    .collect()
            })
            .collect();
        let s = estimate_poles(&bands, 60, 20, 2.0).unwrap();
        assert_eq!(s.order, 3);
        for p in poles {
            let best = s
                .poles
                .iter()
                .map(|q| (q - p).norm())
                .fold(f64::INFINITY, f64::min);
            assert!(best < 1e-10, "pole {p} off by {best:e}");
        }
    }

    #[test]
    fn model_order_counts_eigenvalues_above_the_floor() {
        let mut ev = vec![100.0, 50.0, 3.0, 1.2, 1.1, 1.0, 1.0, 0.9, 0.9, 0.8];
        assert_eq!(model_order(&ev, 4, 2.0), 3);
        assert_eq!(model_order(&ev, 2, 2.0), 2);
        ev.iter_mut().for_each(|v| *v = 0.0);
        assert_eq!(model_order(&ev, 4, 2.0), 0);
    }
}
