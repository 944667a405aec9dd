//! Linear least squares for the complex amplitudes once the poles are fixed (parent module docs,
//! "Amplitudes"): the full-rate real fit shared by all channels, with its Gram matrix in closed
//! form, and the small complex fit of one decimated band.

use nalgebra::{Cholesky, DMatrix, SymmetricEigen, SVD};

use super::filter::C64;

/// Samples between direct evaluations of zⁿ in the recursions below; the recursion's relative
/// rounding error after this many steps is ~1e-13.
const REANCHOR: usize = 1024;

/// Calls `visit(n, zⁿ)` for n = 0 … n_samples − 1 with z = e^{log_z}, advancing
/// by one complex multiply per sample and re-evaluating zⁿ = e^{n Re log z} e^{i (n Im log z mod 2π)}
/// every [`REANCHOR`] samples so rounding does not accumulate.
fn for_each_power(log_z: C64, n_samples: usize, mut visit: impl FnMut(usize, C64)) {
    let z = log_z.exp();
    let turns_per_sample = log_z.im / (2.0 * std::f64::consts::PI);
    let mut start = 0;
    while start < n_samples {
        let end = (start + REANCHOR).min(n_samples);
        let n = start as f64;
        let angle = 2.0 * std::f64::consts::PI * (turns_per_sample * n).fract();
        let mut p = C64::from_polar((log_z.re * n).exp(), angle);
        for k in start..end {
            visit(k, p);
            p *= z;
        }
        start = end;
    }
}

/// e^w − 1 without cancellation for small |w|.
fn expm1(w: C64) -> C64 {
    let (s, c) = w.im.sin_cos();
    let half = (0.5 * w.im).sin();
    C64::new(w.re.exp_m1() * c - 2.0 * half * half, w.re.exp() * s)
}

/// Σ_{n=0}^{N−1} e^{λn} = (e^{Nλ} − 1)/(e^λ − 1), with Im λ first reduced to (−π, π] (the sum
/// only depends on e^λ) so both expm1 are accurate; N when λ = 0.
fn geometric_sum(lambda: C64, n: usize) -> C64 {
    let two_pi = 2.0 * std::f64::consts::PI;
    let im = lambda.im - two_pi * (lambda.im / two_pi).round();
    let lambda = C64::new(lambda.re, im);
    if lambda.re == 0.0 && lambda.im == 0.0 {
        return C64::new(n as f64, 0.0);
    }
    expm1(lambda * n as f64) / expm1(lambda)
}

/// Σ_{n=0}^{N−1} e^{−2 d n / f_s} for a mode with per-sample log-pole `log_z`: the energy of
/// e^{−d t} over the record, in samples (the energy of a e^{−dt} sin(…) is ≈ a²/2 times this).
pub(crate) fn envelope_energy(log_z: C64, n: usize) -> f64 {
    geometric_sum(C64::new(2.0 * log_z.re, 0.0), n).re
}

/// The full-rate fit: per mode k and channel c the complex amplitude c_{kc} = a e^{iφ} that
/// minimises Σ_n (s_c[n] − Σ_k Im(c_{kc} z_kⁿ))², for per-sample log-poles
/// `log_z[k] = (−d_k + i 2π f_k)/f_s`. Returns `[k][c]`, or `None` if the Gram matrix is
/// singular to working precision (duplicate poles).
pub(crate) fn fit_full_rate(signals: &[&[f64]], log_z: &[C64]) -> Option<Vec<Vec<C64>>> {
    let k_modes = log_z.len();
    let channels = signals.len();
    if k_modes == 0 {
        return Some(vec![]);
    }
    let (gram, rhs) = normal_equations(signals, log_z);
    let x = solve_spd(gram, rhs)?;
    Some(
        (0..k_modes)
            .map(|k| {
                (0..channels)
                    .map(|c| C64::new(x[(2 * k, c)], x[(2 * k + 1, c)]))
                    .collect()
            })
            .collect(),
    )
}

/// The normal equations of the full-rate fit: the real unknowns are (Re c_k, Im c_k) at rows
/// 2k, 2k + 1, with basis functions Im zⁿ and Re zⁿ (Im(c zⁿ) = Re c · Im zⁿ + Im c · Re zⁿ).
/// Returns the 2K × 2K Gram matrix, in closed form from geometric sums (no pass over the
/// samples), and the 2K × C right-hand sides Σ_n s_c[n] (Im zⁿ, Re zⁿ), one pass over zⁿ per
/// mode for all channels.
pub(crate) fn normal_equations(signals: &[&[f64]], log_z: &[C64]) -> (DMatrix<f64>, DMatrix<f64>) {
    let k_modes = log_z.len();
    let n = signals.first().map_or(0, |s| s.len());
    let channels = signals.len();
    let dim = 2 * k_modes;
    let mut gram = DMatrix::<f64>::zeros(dim, dim);
    for j in 0..k_modes {
        for k in j..k_modes {
            // P = Σ (z_j z_k)ⁿ, Q = Σ (z_j z̄_k)ⁿ; Re a Re b = ½Re(ab + ab̄), Im a Im b = ½Re(ab̄ − ab),
            // Im a Re b = ½Im(ab + ab̄), Re a Im b = ½Im(ab − ab̄).
            let p = geometric_sum(log_z[j] + log_z[k], n);
            let q = geometric_sum(log_z[j] + log_z[k].conj(), n);
            let im_im = 0.5 * (q - p).re;
            let im_re = 0.5 * (p + q).im;
            let re_im = 0.5 * (p - q).im;
            let re_re = 0.5 * (p + q).re;
            let (a, b) = (2 * j, 2 * k);
            gram[(a, b)] = im_im;
            gram[(a, b + 1)] = im_re;
            gram[(a + 1, b)] = re_im;
            gram[(a + 1, b + 1)] = re_re;
            gram[(b, a)] = im_im;
            gram[(b + 1, a)] = im_re;
            gram[(b, a + 1)] = re_im;
            gram[(b + 1, a + 1)] = re_re;
        }
    }
    let mut rhs = DMatrix::<f64>::zeros(dim, channels);
    let mut acc = vec![[0.0f64; 2]; channels];
    for (k, &lz) in log_z.iter().enumerate() {
        acc.iter_mut().for_each(|a| *a = [0.0; 2]);
        for_each_power(lz, n, |i, p| {
            for (a, s) in acc.iter_mut().zip(signals) {
                a[0] += s[i] * p.im;
                a[1] += s[i] * p.re;
            }
        });
        for (c, a) in acc.iter().enumerate() {
            rhs[(2 * k, c)] = a[0];
            rhs[(2 * k + 1, c)] = a[1];
        }
    }
    (gram, rhs)
}

/// Solves G X = B for symmetric positive semi-definite G: symmetric (Jacobi) scaling to a unit
/// diagonal, then Cholesky; if that fails, a pseudo-inverse keeping eigenvalues above 1e-12 of the
/// largest. `None` if G has a non-positive or non-finite diagonal.
fn solve_spd(gram: DMatrix<f64>, rhs: DMatrix<f64>) -> Option<DMatrix<f64>> {
    let dim = gram.nrows();
    let scale: Vec<f64> = (0..dim).map(|i| gram[(i, i)]).collect();
    if scale.iter().any(|&g| !(g > 0.0 && g.is_finite())) {
        return None;
    }
    let scale: Vec<f64> = scale.iter().map(|g| 1.0 / g.sqrt()).collect();
    let scaled = DMatrix::from_fn(dim, dim, |i, j| gram[(i, j)] * scale[i] * scale[j]);
    let b = DMatrix::from_fn(dim, rhs.ncols(), |i, c| rhs[(i, c)] * scale[i]);
    let y = match Cholesky::new(scaled.clone()) {
        Some(ch) => ch.solve(&b),
        None => {
            let eig = SymmetricEigen::try_new(scaled, f64::EPSILON, 100 * dim)?;
            let top = eig.eigenvalues.iter().cloned().fold(0.0, f64::max);
            let inv = eig
                .eigenvalues
                .map(|l| if l > 1e-12 * top { 1.0 / l } else { 0.0 });
            let v = &eig.eigenvectors;
            v * DMatrix::from_diagonal(&inv) * v.transpose() * b
        }
    };
    if y.iter().any(|v| !v.is_finite()) {
        return None;
    }
    Some(DMatrix::from_fn(dim, y.ncols(), |i, c| {
        y[(i, c)] * scale[i]
    }))
}

/// s_c[n] − Σ_k Im(c_{kc} z_kⁿ) for every channel (the full-rate residual).
pub(crate) fn residuals(signals: &[&[f64]], log_z: &[C64], coeffs: &[Vec<C64>]) -> Vec<Vec<f64>> {
    let n = signals.first().map_or(0, |s| s.len());
    let mut out: Vec<Vec<f64>> = signals.iter().map(|s| s.to_vec()).collect();
    for (&lz, ck) in log_z.iter().zip(coeffs) {
        for_each_power(lz, n, |i, p| {
            for (r, c) in out.iter_mut().zip(ck) {
                r[i] -= c.re * p.im + c.im * p.re;
            }
        });
    }
    out
}

/// The complex fit of one band: per channel the β_k minimising Σ_m |y[m] − Σ_k β_k w_kᵐ|² over
/// the decimated samples. Returns (β as `[k][c]`, residual energy per channel), or `None` if the
/// SVD fails. Rank-deficient bases (two equal poles) are solved in the minimum-norm sense.
pub(super) fn fit_band(bands: &[Vec<C64>], w: &[C64]) -> Option<(Vec<Vec<C64>>, Vec<f64>)> {
    let n = bands.first().map_or(0, |b| b.len());
    let k_modes = w.len();
    let channels = bands.len();
    if k_modes == 0 {
        return Some((
            vec![],
            bands
                .iter()
                .map(|b| b.iter().map(|v| v.norm_sqr()).sum())
                .collect(),
        ));
    }
    let mut a = DMatrix::<C64>::zeros(n, k_modes);
    for (k, &wk) in w.iter().enumerate() {
        let mut p = C64::new(1.0, 0.0);
        for m in 0..n {
            a[(m, k)] = p;
            p *= wk;
        }
    }
    let y = DMatrix::from_fn(n, channels, |m, c| bands[c][m]);
    if bands
        .iter()
        .flatten()
        .any(|v| !(v.re.is_finite() && v.im.is_finite()))
    {
        return None;
    }
    let svd = SVD::try_new(a.clone(), true, true, f64::EPSILON, 1000 * k_modes.max(10))?;
    let tol = 1e-12 * svd.singular_values.iter().cloned().fold(0.0, f64::max);
    let beta = svd.solve(&y, tol).ok()?;
    let resid = y - a * &beta;
    let energy = (0..channels)
        .map(|c| resid.column(c).iter().map(|v| v.norm_sqr()).sum())
        .collect();
    Some((
        (0..k_modes)
            .map(|k| (0..channels).map(|c| beta[(k, c)]).collect())
            .collect(),
        energy,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn geometric_sum_matches_direct_summation() {
        for (lambda, n) in [
            (C64::new(-1e-5, 0.3), 5000usize),
            (C64::new(0.0, 1e-9), 48_000),
            (C64::new(-2e-3, 2.0 * std::f64::consts::PI - 1e-4), 3000),
            (C64::new(0.0, 0.0), 17),
            (C64::new(-0.5, 3.1), 40),
        ] {
            let direct: C64 = (0..n).map(|k| (lambda * k as f64).exp()).sum();
            let closed = geometric_sum(lambda, n);
            assert!(
                (closed - direct).norm() <= 1e-10 * direct.norm().max(1.0),
                "{lambda}: {closed} vs {direct}"
            );
        }
    }

    #[test]
    fn full_rate_fit_recovers_amplitudes_exactly_and_leaves_no_residual() {
        let fs = 48_000.0;
        let poles = [
            (440.0, 3.0),
            (442.0, 5.0),
            (12_000.0, 40.0),
            (23_500.0, 1.0),
        ];
        let log_z: Vec<C64> = poles
            .iter()
            .map(|&(f, d)| C64::new(-d, 2.0 * std::f64::consts::PI * f) / fs)
            .collect();
        let coeffs: Vec<Vec<C64>> = vec![
            vec![C64::new(0.3, 0.1), C64::new(-1.0, 0.0)],
            vec![C64::new(0.0, 0.2), C64::new(0.5, 0.5)],
            vec![C64::new(-0.7, 0.05), C64::new(0.0, 0.0)],
            vec![C64::new(0.01, -0.02), C64::new(0.3, 0.0)],
        ];
        let n = 20_000;
        let zero = vec![vec![0.0; n]; 2];
        let zero_refs: Vec<&[f64]> = zero.iter().map(|v| v.as_slice()).collect();
        // residuals(0, −c) = Σ Im(c zⁿ): the signal itself.
        let neg: Vec<Vec<C64>> = coeffs
            .iter()
            .map(|r| r.iter().map(|c| -c).collect())
            .collect();
        let signals = residuals(&zero_refs, &log_z, &neg);
        let refs: Vec<&[f64]> = signals.iter().map(|v| v.as_slice()).collect();
        let got = fit_full_rate(&refs, &log_z).unwrap();
        for (g, w) in got.iter().flatten().zip(coeffs.iter().flatten()) {
            assert!((g - w).norm() < 1e-11, "{g} vs {w}");
        }
        let r = residuals(&refs, &log_z, &got);
        let rms = (r.iter().flatten().map(|v| v * v).sum::<f64>() / (2 * n) as f64).sqrt();
        assert!(rms < 1e-13, "residual RMS {rms:e}");
    }
}
