use super::*;
use rustfft::{num_complex::Complex, FftPlanner};

/// Small deterministic generator for test inputs (independent of the
/// synthesiser's noise stream).
fn random_vec(len: usize, seed: u64) -> Vec<f64> {
    let mut rng = Xoshiro256StarStar::from_seed(seed ^ 0xA5A5_5A5A_DEAD_BEEF);
    (0..len).map(|_| rng.next_symmetric_unit()).collect()
}

/// The same synthesiser (same noise) with each convolution method forced.
fn both_methods(noise: FilteredNoise) -> [FilteredNoise; 2] {
    let fft_len = (noise.hop + noise.filter_len - 1).next_power_of_two();
    let mut direct = noise.clone();
    direct.convolution = Convolution::Direct;
    let mut fft = noise;
    fft.convolution = Convolution::Fft(FftPlans::new(fft_len));
    [direct, fft]
}

fn method_name(noise: &FilteredNoise) -> &'static str {
    match noise.convolution {
        Convolution::Direct => "direct",
        Convolution::Fft(_) => "fft",
    }
}

fn inner(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Straight from the module-doc equations, with no shared helpers: the
/// IDFT by its cosine sum, rotation, window, and the triple overlap-add sum.
fn reference_render(noise: &FilteredNoise, magnitudes: &[f64]) -> Vec<f64> {
    let (b_count, l, hop) = (noise.n_bands, noise.filter_len, noise.hop);
    let mut y = vec![0.0; noise.n_samples];
    for m in 0..noise.n_frames {
        let hm = &magnitudes[m * b_count..(m + 1) * b_count];
        let z: Vec<f64> = (0..l)
            .map(|k| {
                let mut s = hm[0] + hm[b_count - 1] * if k % 2 == 0 { 1.0 } else { -1.0 };
                for (b, &v) in hm.iter().enumerate().take(b_count - 1).skip(1) {
                    s += 2.0 * v * (2.0 * PI * (b * k) as f64 / l as f64).cos();
                }
                s / l as f64
            })
            .collect();
        for j in 0..l {
            let w = 0.5 - 0.5 * (2.0 * PI * j as f64 / l as f64).cos();
            let h = w * z[(j + l / 2) % l];
            for i in 0..hop {
                let n = (m * hop + i + j) as isize - (l / 2) as isize;
                if n >= 0 && (n as usize) < noise.n_samples {
                    y[n as usize] += h * noise.noise[m * hop + i];
                }
            }
        }
    }
    y
}

/// Sizes that exercise: hop < L, hop > L, n_samples not a multiple of hop,
/// n_samples shorter than one filter, a single frame, B = 2.
const CONFIGS: [(usize, usize, usize); 6] = [
    (1000, 9, 64),
    (777, 17, 20),
    (500, 5, 100),
    (7, 9, 3),
    (40, 6, 64),
    (33, 2, 4),
];

#[test]
fn render_matches_the_documented_equations() {
    for (case, &(n_samples, n_bands, hop)) in CONFIGS.iter().enumerate() {
        let noise = FilteredNoise::new(n_samples, 16_000.0, n_bands, hop, 7 + case as u64).unwrap();
        let h = random_vec(noise.n_magnitudes(), 100 + case as u64);
        let slow = reference_render(&noise, &h);
        let scale = slow.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        assert!(scale > 0.0, "case {case}: silent reference");
        for noise in both_methods(noise) {
            let fast = noise.render(&h).unwrap();
            let err = fast
                .iter()
                .zip(&slow)
                .fold(0.0f64, |a, (x, y)| a.max((x - y).abs()));
            let method = method_name(&noise);
            assert!(
                err <= 1e-13 * scale,
                "case {case} {method}: {err:e} vs scale {scale:e}"
            );
        }
    }
}

#[test]
fn backward_matches_central_finite_differences() {
    for (case, &(n_samples, n_bands, hop)) in CONFIGS.iter().enumerate() {
        let base = FilteredNoise::new(n_samples, 44_100.0, n_bands, hop, 3 + case as u64).unwrap();
        let h = random_vec(base.n_magnitudes(), 200 + case as u64);
        let g = random_vec(n_samples, 300 + case as u64);
        for noise in both_methods(base) {
            let method = method_name(&noise);
            let loss = |mags: &[f64]| inner(&noise.render(mags).unwrap(), &g);
            let mut grad = vec![0.0; noise.n_magnitudes()];
            noise.backward(&g, &mut grad).unwrap();
            let step = 1e-3;
            let mut worst = 0.0f64;
            let grad_scale = grad.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            for p in 0..h.len() {
                let mut plus = h.clone();
                let mut minus = h.clone();
                plus[p] += step;
                minus[p] -= step;
                let fd = (loss(&plus) - loss(&minus)) / (2.0 * step);
                worst = worst.max((fd - grad[p]).abs() / grad_scale);
            }
            assert!(grad_scale > 0.0, "case {case} {method}: zero gradient");
            assert!(
                worst < 1e-6,
                "case {case} {method}: relative error {worst:e}"
            );
        }
    }
}

#[test]
fn backward_is_the_exact_adjoint_and_accumulates() {
    // ⟨y(H), g⟩ = ⟨H, Jᵀ g⟩ to rounding, for the 1 s / 48 kHz production size.
    for noise in both_methods(FilteredNoise::new(48_000, 48_000.0, 65, 256, 11).unwrap()) {
        let h = random_vec(noise.n_magnitudes(), 1);
        let g = random_vec(noise.n_samples(), 2);
        let mut grad = vec![0.0; noise.n_magnitudes()];
        noise.backward(&g, &mut grad).unwrap();
        let lhs = inner(&noise.render(&h).unwrap(), &g);
        let rhs = inner(&h, &grad);
        assert!(
            (lhs - rhs).abs() <= 1e-12 * lhs.abs().max(1.0),
            "{lhs} vs {rhs}"
        );
        // A second call adds the same amount again.
        let first = grad.clone();
        noise.backward(&g, &mut grad).unwrap();
        for (a, b) in grad.iter().zip(&first) {
            assert!((a - 2.0 * b).abs() <= 1e-15 * b.abs().max(1.0));
        }
    }
}

#[test]
fn output_is_linear_in_the_magnitudes() {
    for noise in both_methods(FilteredNoise::new(3000, 48_000.0, 33, 128, 5).unwrap()) {
        let a = random_vec(noise.n_magnitudes(), 10);
        let b = random_vec(noise.n_magnitudes(), 11);
        let (alpha, beta) = (1.7, -0.6);
        let combined: Vec<f64> = a
            .iter()
            .zip(&b)
            .map(|(x, y)| alpha * x + beta * y)
            .collect();
        let ya = noise.render(&a).unwrap();
        let yb = noise.render(&b).unwrap();
        let yc = noise.render(&combined).unwrap();
        for n in 0..yc.len() {
            let expected = alpha * ya[n] + beta * yb[n];
            assert!((yc[n] - expected).abs() < 1e-13, "sample {n}");
        }
        // render_add_into adds onto what is already there.
        let mut sum = ya.clone();
        noise.render_add_into(&b, &mut sum).unwrap();
        for n in 0..sum.len() {
            assert!((sum[n] - (ya[n] + yb[n])).abs() < 1e-13);
        }
    }
}

#[test]
fn zero_magnitudes_give_exactly_zero() {
    for noise in both_methods(FilteredNoise::new(2000, 48_000.0, 65, 256, 1).unwrap()) {
        let y = noise.render(&vec![0.0; noise.n_magnitudes()]).unwrap();
        assert!(y.iter().all(|&v| v == 0.0), "{}", method_name(&noise));
        let mut grad = vec![0.0; noise.n_magnitudes()];
        noise.backward(&vec![0.0; 2000], &mut grad).unwrap();
        assert!(grad.iter().all(|&v| v == 0.0), "{}", method_name(&noise));
    }
}

#[test]
fn flat_unit_magnitudes_pass_the_noise_through() {
    // Flat spectrum → IDFT is δ[k]; rotated to L/2 where the periodic Hann
    // is exactly 1, so h = δ[j − L/2] and, with the L/2 advance, y = x.
    // Only rounding in the cosine sums remains: each tap is a sum of B
    // terms of size ≤ 2/L, so |h_j − δ| ≲ B·ε ≈ 1e-14; times |x| < 1 → 1e-12
    // is a safe bound with two orders to spare.
    let noise = FilteredNoise::new(4800, 48_000.0, 65, 256, 9).unwrap();
    let taps = noise.impulse_response(&vec![1.0; 65]).unwrap();
    for (j, &t) in taps.iter().enumerate() {
        let ideal = if j == 64 { 1.0 } else { 0.0 };
        assert!((t - ideal).abs() < 1e-14, "tap {j}: {t}");
    }
    for noise in both_methods(noise) {
        let y = noise.render(&vec![1.0; noise.n_magnitudes()]).unwrap();
        let err = y
            .iter()
            .zip(noise.noise())
            .fold(0.0f64, |a, (y, x)| a.max((y - x).abs()));
        assert!(
            err < 1e-12,
            "{}: max |y − x| = {err:e}",
            method_name(&noise)
        );
    }
}

/// One-sided power spectrum |FFT(signal)|², bins 0 … N/2.
fn power_spectrum(signal: &[f64]) -> Vec<f64> {
    let mut buf: Vec<Complex<f64>> = signal.iter().map(|&v| Complex::new(v, 0.0)).collect();
    FftPlanner::new()
        .plan_fft_forward(buf.len())
        .process(&mut buf);
    buf[..=signal.len() / 2]
        .iter()
        .map(|c| c.norm_sqr())
        .collect()
}

#[test]
fn low_pass_profile_suppresses_the_stop_band() {
    // Pass bands 0 … 15 (0–5625 Hz at 48 kHz, B = 65: 375 Hz per band),
    // stop bands from 16 (6000 Hz) up. The Hann taper smears the edge over
    // ±2 bands, so the stop band is measured from band 20 (7500 Hz) up.
    let (fs, n_bands, hop) = (48_000.0, 65, 256);
    let noise = FilteredNoise::new(96_000, fs, n_bands, hop, 21).unwrap();
    let profile: Vec<f64> = (0..n_bands)
        .map(|b| if b < 16 { 1.0 } else { 0.0 })
        .collect();
    let mags: Vec<f64> = (0..noise.n_frames())
        .flat_map(|_| profile.clone())
        .collect();
    let y = noise.render(&mags).unwrap();
    let spectrum = power_spectrum(&y);
    let bin_hz = fs / y.len() as f64;
    let mean_power = |lo_hz: f64, hi_hz: f64| {
        let bins: Vec<f64> = spectrum
            .iter()
            .enumerate()
            .filter(|(k, _)| (lo_hz..hi_hz).contains(&(*k as f64 * bin_hz)))
            .map(|(_, &p)| p)
            .collect();
        bins.iter().sum::<f64>() / bins.len() as f64
    };
    let pass = mean_power(100.0, 4800.0);
    let stop = mean_power(7500.0, 24_000.0);
    let suppression_db = 10.0 * (pass / stop).log10();
    eprintln!("low-pass: stop band {suppression_db:.1} dB below pass band");
    assert!(suppression_db > 55.0, "only {suppression_db:.1} dB");
}

#[test]
fn energy_stays_in_the_active_frames() {
    let (hop, n_bands) = (128, 33); // L = 64
    for noise in both_methods(FilteredNoise::new(40 * hop, 48_000.0, n_bands, hop, 4).unwrap()) {
        let method = method_name(&noise);
        let mut mags = random_vec(noise.n_magnitudes(), 40);
        for (m, row) in mags.chunks_exact_mut(n_bands).enumerate() {
            if !(10..20).contains(&m) {
                row.fill(0.0);
            }
        }
        let y = noise.render(&mags).unwrap();
        // Support: from 10·hop − L/2 + 1 to 20·hop − 1 + L/2 − 1 (h[0] = 0).
        let half = noise.filter_len() / 2;
        let (first, last) = (10 * hop - half + 1, 20 * hop + half - 2);
        for (n, &v) in y.iter().enumerate() {
            if n < first || n > last {
                assert_eq!(v, 0.0, "{method}: sample {n} outside frames 10..20");
            }
        }
        let inside: f64 = y[10 * hop..20 * hop].iter().map(|v| v * v).sum();
        assert!(inside > 1e-3, "active frames are silent: {inside}");
        // And each active frame does carry energy in its own block.
        for m in 10..20 {
            let e: f64 = y[m * hop..(m + 1) * hop].iter().map(|v| v * v).sum();
            assert!(e > 0.0, "{method}: frame {m} silent");
        }
    }
}

#[test]
fn extreme_scales_keep_full_relative_accuracy() {
    // Packing taps (or ∂ℒ/∂y) with the unit-scale noise in one FFT would
    // bury a tiny signal under the noise's rounding without normalisation.
    let base = FilteredNoise::new(2000, 48_000.0, 65, 256, 8).unwrap();
    let h = random_vec(base.n_magnitudes(), 80);
    let g = random_vec(2000, 81);
    for noise in both_methods(base) {
        let method = method_name(&noise);
        let y = noise.render(&h).unwrap();
        let mut grad = vec![0.0; noise.n_magnitudes()];
        noise.backward(&g, &mut grad).unwrap();
        for factor in [1e-200, 1e-30, 1e40, 1e250] {
            let scaled: Vec<f64> = h.iter().map(|v| v * factor).collect();
            let ys = noise.render(&scaled).unwrap();
            let peak = y.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            let err = ys
                .iter()
                .zip(&y)
                .fold(0.0f64, |a, (p, q)| a.max((p / factor - q).abs()));
            assert!(err < 1e-13 * peak, "{method} render × {factor:e}: {err:e}");

            let g_scaled: Vec<f64> = g.iter().map(|v| v * factor).collect();
            let mut grad_scaled = vec![0.0; noise.n_magnitudes()];
            noise.backward(&g_scaled, &mut grad_scaled).unwrap();
            let peak = grad.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            let err = grad_scaled
                .iter()
                .zip(&grad)
                .fold(0.0f64, |a, (p, q)| a.max((p / factor - q).abs()));
            assert!(
                err < 1e-13 * peak,
                "{method} backward × {factor:e}: {err:e}"
            );
        }
    }
}

#[test]
fn non_finite_inputs_are_not_silently_dropped() {
    for noise in both_methods(FilteredNoise::new(1000, 48_000.0, 9, 100, 2).unwrap()) {
        let mut h = vec![0.5; noise.n_magnitudes()];
        h[3 * 9 + 4] = f64::NAN;
        let y = noise.render(&h).unwrap();
        assert!(y[350].is_nan(), "{}", method_name(&noise));
        assert!(
            y[900].is_finite(),
            "{}: NaN spread beyond its frame",
            method_name(&noise)
        );
        let mut g = vec![0.0; 1000];
        g[350] = f64::INFINITY;
        let mut grad = vec![0.0; noise.n_magnitudes()];
        noise.backward(&g, &mut grad).unwrap();
        assert!(
            grad[3 * 9..4 * 9].iter().any(|v| !v.is_finite()),
            "{}",
            method_name(&noise)
        );
        assert!(grad[8 * 9..].iter().all(|v| v.is_finite()));
    }
}

#[test]
fn the_cheaper_convolution_is_chosen() {
    // The production size (B = 65, hop = 256) measured 0.75 ms by FFT and
    // 1.24 ms direct; short filters with long hops favour direct.
    let pick =
        |n_bands, hop| method_name(&FilteredNoise::new(48_000, 48_000.0, n_bands, hop, 0).unwrap());
    assert_eq!(pick(65, 256), "fft");
    assert_eq!(pick(257, 256), "fft");
    assert_eq!(pick(17, 512), "direct");
    assert_eq!(pick(65, 16), "direct");
    assert_eq!(pick(2, 1), "direct");
}

#[test]
fn seed_fixes_the_noise() {
    let mags = vec![0.5; 8 * 17];
    let make = |seed| FilteredNoise::new(1000, 22_050.0, 17, 125, seed).unwrap();
    let a = make(42).render(&mags).unwrap();
    let b = make(42).render(&mags).unwrap();
    let c = make(43).render(&mags).unwrap();
    assert_eq!(a, b);
    let differing = a.iter().zip(&c).filter(|(x, y)| x != y).count();
    assert!(differing > 990, "only {differing} samples differ");
    // Seed 0 is fine too (splitmix64 seeding), and the noise is uniform on [−1, 1).
    let x = FilteredNoise::new(100_000, 1.0, 2, 1, 0)
        .unwrap()
        .noise()
        .to_vec();
    assert!(x.iter().all(|&v| (-1.0..1.0).contains(&v)));
    let mean = x.iter().sum::<f64>() / x.len() as f64;
    let var = x.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / x.len() as f64;
    assert!(
        mean.abs() < 0.01 && (var - NOISE_VARIANCE).abs() < 0.01,
        "{mean} {var}"
    );
}

#[test]
fn bad_sizes_are_errors() {
    assert_eq!(
        FilteredNoise::new(100, 48_000.0, 1, 10, 0).unwrap_err(),
        NoiseError::TooFewBands { n_bands: 1 }
    );
    assert_eq!(
        FilteredNoise::new(100, 48_000.0, 0, 10, 0).unwrap_err(),
        NoiseError::TooFewBands { n_bands: 0 }
    );
    assert_eq!(
        FilteredNoise::new(100, 48_000.0, 9, 0, 0).unwrap_err(),
        NoiseError::ZeroHop
    );
    assert_eq!(
        FilteredNoise::new(0, 48_000.0, 9, 10, 0).unwrap_err(),
        NoiseError::ZeroSamples
    );
    for rate in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        assert!(matches!(
            FilteredNoise::new(100, rate, 9, 10, 0),
            Err(NoiseError::InvalidSampleRate { .. })
        ));
    }
    assert!(matches!(
        FilteredNoise::new(100, 48_000.0, usize::MAX, 10, 0),
        Err(NoiseError::TooLarge { .. })
    ));

    let noise = FilteredNoise::new(100, 48_000.0, 9, 10, 0).unwrap();
    assert_eq!(noise.n_frames(), 10);
    let good = vec![1.0; 90];
    assert_eq!(
        noise.render(&good[..89]).unwrap_err(),
        NoiseError::LengthMismatch {
            what: "magnitudes",
            expected: 90,
            actual: 89
        }
    );
    let mut short_out = vec![7.0; 99];
    assert!(noise.render_add_into(&good, &mut short_out).is_err());
    assert!(
        short_out.iter().all(|&v| v == 7.0),
        "output touched on error"
    );
    let mut grad = vec![3.0; 90];
    assert!(noise.backward(&[0.0; 101], &mut grad).is_err());
    assert!(noise.backward(&[0.0; 100], &mut grad[..80]).is_err());
    assert!(grad.iter().all(|&v| v == 3.0), "gradient touched on error");
    assert!(noise.impulse_response(&[1.0; 8]).is_err());
    // Envelope grids: empty, unsorted, non-finite, wrong size.
    assert!(noise.magnitudes_from_envelope(&[], &[0.0], &[]).is_err());
    assert!(noise
        .magnitudes_from_envelope(&[1.0, 0.0], &[0.0], &[1.0, 1.0])
        .is_err());
    assert!(noise
        .magnitudes_from_envelope(&[0.0], &[f64::NAN], &[1.0])
        .is_err());
    assert!(noise
        .magnitudes_from_envelope(&[0.0], &[0.0, 1.0], &[1.0])
        .is_err());
}

#[test]
fn a_hop_longer_than_the_signal_is_one_frame() {
    // hop = 18 = n_samples + L/2 and hop = 2^40 (or usize::MAX) store the same
    // 18 noise samples and give the same single-frame output.
    let h = random_vec(9, 5);
    let reference = FilteredNoise::new(10, 8000.0, 9, 18, 6).unwrap();
    let expected = reference.render(&h).unwrap();
    assert!(expected.iter().any(|&v| v != 0.0));
    for hop in [1usize << 40, usize::MAX] {
        let noise = FilteredNoise::new(10, 8000.0, 9, hop, 6).unwrap();
        assert_eq!((noise.n_frames(), noise.noise().len()), (1, 18));
        assert_eq!(noise.render(&h).unwrap(), expected, "hop {hop}");
        let mut grad = vec![0.0; 9];
        noise.backward(&[1.0; 10], &mut grad).unwrap();
        assert!(grad.iter().all(|v| v.is_finite()));
    }
}

#[test]
fn grid_accessors_follow_the_definitions() {
    let noise = FilteredNoise::new(1000, 16_000.0, 5, 300, 0).unwrap();
    assert_eq!(
        (
            noise.n_frames(),
            noise.n_bands(),
            noise.hop(),
            noise.filter_len()
        ),
        (4, 5, 300, 8)
    );
    assert_eq!(
        noise.band_frequencies_hz(),
        vec![0.0, 2000.0, 4000.0, 6000.0, 8000.0]
    );
    let times = noise.frame_times_s();
    assert_eq!(times.len(), 4);
    assert!((times[0] - 149.5 / 16_000.0).abs() < 1e-15);
    assert!((times[3] - 1049.5 / 16_000.0).abs() < 1e-15);
    assert_eq!(noise.noise().len(), 1004); // n_samples + L/2 < n_frames·hop
}

#[test]
fn envelope_interpolation_is_bilinear_and_clamped() {
    let noise = FilteredNoise::new(1000, 16_000.0, 5, 250, 0).unwrap();
    // Envelope a + b·t + c·f on a coarse grid: bilinear reproduces it
    // exactly inside the grid, clamps outside.
    let times = [0.0, 0.02, 0.05];
    let freqs = [1000.0, 4000.0, 7000.0];
    let value = |t: f64, f: f64| 1.0 + 10.0 * t + 1e-4 * f;
    let env: Vec<f64> = times
        .iter()
        .flat_map(|&t| freqs.iter().map(move |&f| value(t, f)))
        .collect();
    let mags = noise
        .magnitudes_from_envelope(&times, &freqs, &env)
        .unwrap();
    let ft = noise.frame_times_s();
    let bf = noise.band_frequencies_hz();
    for (m, &t) in ft.iter().enumerate() {
        for (b, &f) in bf.iter().enumerate() {
            let expected = value(t.clamp(0.0, 0.05), f.clamp(1000.0, 7000.0));
            assert!(
                (mags[m * 5 + b] - expected).abs() < 1e-12,
                "frame {m} band {b}"
            );
        }
    }
}
