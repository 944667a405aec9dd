use super::*;
use crate::audio::chain::{DampingModel, ModalChain};
use crate::audio::excitation::{ContactForce, Response};
use crate::audio::synth::{render_samples, ModalBank};
use crate::random::SplitMix64;

const TWO_PI: f64 = 2.0 * std::f64::consts::PI;

/// x_c[n] = Σ_k Re{a_kc e^(s_k (t_n − t₀))} for t_n ≥ t₀, `pre` before.
fn synthesise(
    amplitudes: &[Vec<Complex64>],
    poles: &[MeasuredMode],
    fs: f64,
    len: usize,
    start_s: f64,
    pre: f64,
) -> Vec<Vec<f64>> {
    amplitudes
        .iter()
        .map(|row| {
            (0..len)
                .map(|n| {
                    let t = n as f64 / fs - start_s;
                    if t < -1e-12 {
                        return pre;
                    }
                    row.iter()
                        .zip(poles)
                        .map(|(a, p)| {
                            (a * (Complex64::new(-p.decay_rate, TWO_PI * p.frequency_hz) * t).exp())
                                .re
                        })
                        .sum()
                })
                .collect()
        })
        .collect()
}

fn pole(f: f64, d: f64) -> MeasuredMode {
    MeasuredMode::pole(f, d)
}

#[test]
fn noise_free_amplitudes_are_recovered_at_a_start_between_samples() {
    let fs = 16_000.0;
    let poles = [
        pole(300.0, 2.0),
        pole(1234.5, 15.0),
        pole(5000.0, 40.0),
        pole(7900.0, 90.0),
    ];
    let amps = vec![
        vec![
            Complex64::new(0.3, -0.2),
            Complex64::new(-1.0, 0.1),
            Complex64::new(0.05, 0.5),
            Complex64::new(0.2, 0.2),
        ],
        vec![
            Complex64::new(0.0, 1.0),
            Complex64::new(0.4, 0.0),
            Complex64::new(-0.7, -0.3),
            Complex64::new(0.0, -0.01),
        ],
    ];
    let start = 0.012_345_6;
    // Garbage before the start must be ignored.
    let x = synthesise(&amps, &poles, fs, 6000, start, 3.0);
    let fit = fit_amplitudes(&x, fs, start, &poles, &AmplitudeFitOptions::default()).unwrap();
    assert_eq!(fit.first_sample, 198);
    assert_eq!(fit.rank, 8);
    for (got, want) in fit.amplitudes.iter().flatten().zip(amps.iter().flatten()) {
        assert!((got - want).norm() < 1e-9, "{got} vs {want}");
    }
    assert!(
        fit.noise_rms.iter().all(|&s| s < 1e-11),
        "{:?}",
        fit.noise_rms
    );
    assert!(fit.not_separable.is_empty());
    assert!(
        fit.variance_inflation.iter().all(|&v| v < 1.1),
        "{:?}",
        fit.variance_inflation
    );
}

#[test]
fn amplitude_sds_are_calibrated() {
    // Three modes, two of them 2.5/T apart (correlated), two channels, white noise; 300 draws.
    let (fs, len) = (8000.0, 2000);
    let poles = [pole(500.0, 5.0), pole(510.0, 8.0), pole(1700.0, 20.0)];
    let amps = vec![
        vec![
            Complex64::new(0.8, 0.3),
            Complex64::new(-0.4, 0.5),
            Complex64::new(0.2, -0.9),
        ],
        vec![
            Complex64::new(0.1, -0.6),
            Complex64::new(0.7, 0.2),
            Complex64::new(-0.3, 0.3),
        ],
    ];
    let clean = synthesise(&amps, &poles, fs, len, 0.0, 0.0);
    let sigma = 0.05;
    let mut rng = SplitMix64::new(17);
    let (mut z_parts, mut z_abs, mut noise) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..300 {
        let x: Vec<Vec<f64>> = clean
            .iter()
            .map(|c| c.iter().map(|v| v + sigma * rng.normal()).collect())
            .collect();
        let fit = fit_amplitudes(&x, fs, 0.0, &poles, &AmplitudeFitOptions::default()).unwrap();
        // Index loops: (c, k) index the fit's fields and the true amplitudes together.
        #[allow(clippy::needless_range_loop)]
        for c in 0..2 {
            noise.push(fit.noise_rms[c] / sigma);
            for k in 0..3 {
                let cov = fit.covariance(c, k, k);
                let (got, want) = (fit.amplitudes[c][k], amps[c][k]);
                z_parts.push((got.re - want.re) / cov[0][0].sqrt());
                z_parts.push((got.im - want.im) / cov[1][1].sqrt());
                z_abs.push((got.norm() - want.norm()) / fit.amplitude_sds[c][k]);
            }
        }
    }
    let stats = |z: &[f64]| {
        let mean = z.iter().sum::<f64>() / z.len() as f64;
        let sd = (z.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (z.len() - 1) as f64).sqrt();
        (mean, sd)
    };
    let (m, s) = stats(&z_parts);
    let (ma, sa) = stats(&z_abs);
    eprintln!(
        "z(Re a, Im a): mean {m:.3}, sd {s:.3} over {}; z(|a|): mean {ma:.3}, sd {sa:.3} over {}",
        z_parts.len(),
        z_abs.len()
    );
    assert!(
        m.abs() < 0.06 && (s - 1.0).abs() < 0.06,
        "Re/Im z: mean {m}, sd {s}"
    );
    let (m, s) = stats(&z_abs);
    assert!(
        m.abs() < 0.08 && (s - 1.0).abs() < 0.08,
        "|a| z: mean {m}, sd {s}"
    );
    let (m, _) = stats(&noise);
    assert!((m - 1.0).abs() < 0.01, "σ̂/σ mean {m}");
}

#[test]
fn close_poles_are_reported_and_coincident_ones_unresolved() {
    let (fs, len) = (8000.0, 4000); // T = 0.5 s
    let amps = vec![vec![
        Complex64::new(1.0, 0.0),
        Complex64::new(0.0, 0.5),
        Complex64::new(0.3, 0.3),
    ]];
    let fit_with = |df: f64| {
        let poles = [pole(1000.0, 2.0), pole(1000.0 + df, 2.0), pole(2500.0, 5.0)];
        let x = synthesise(&amps, &poles, fs, len, 0.0, 0.0);
        fit_amplitudes(&x, fs, 0.0, &poles, &AmplitudeFitOptions::default()).unwrap()
    };
    let apart = fit_with(3.0 / 0.5);
    assert!(
        apart.not_separable.is_empty() && apart.variance_inflation[0] < 1.5,
        "{:?}",
        apart.variance_inflation
    );
    let close = fit_with(0.02 / 0.5);
    eprintln!(
        "VIF at 3/T: {:?}; at 0.02/T: {:?}",
        apart.variance_inflation, close.variance_inflation
    );
    assert_eq!(
        close.not_separable,
        vec![0, 1],
        "{:?}",
        close.variance_inflation
    );
    assert!(close.variance_inflation[2] < 1.5);
    // Noise-free, the close pair's amplitudes are still exact: ill-conditioned, not singular.
    assert!(
        (close.amplitudes[0][0] - amps[0][0]).norm() < 1e-5,
        "{}",
        close.amplitudes[0][0]
    );
    let same = fit_with(0.0);
    assert_eq!(same.rank, 4);
    assert!(same.variance_inflation[0].is_infinite() && same.variance_inflation[1].is_infinite());
    assert!(same.amplitude_sds[0][0].is_infinite() && same.amplitude_sds[0][2].is_finite());
    // The combination is what the data hold: minimum norm splits it evenly.
    let sum = amps[0][0] + amps[0][1];
    assert!(
        (same.amplitudes[0][0] - 0.5 * sum).norm() < 1e-8
            && (same.amplitudes[0][1] - 0.5 * sum).norm() < 1e-8
    );
    assert!((same.amplitudes[0][2] - amps[0][2]).norm() < 1e-8);
    let clusters = cluster_amplitudes(&same, &[0, 0, 1]).unwrap();
    assert!(clusters.sd[0][0].is_infinite() && clusters.sd[1][0].is_finite());
}

#[test]
fn invalid_fit_input_is_an_error() {
    let ok = vec![vec![0.0; 100]; 2];
    let poles = [pole(100.0, 1.0)];
    let o = AmplitudeFitOptions::default();
    assert_eq!(
        fit_amplitudes(&[], 1000.0, 0.0, &poles, &o),
        Err(ImpactError::NoChannels)
    );
    assert!(matches!(
        fit_amplitudes(&[vec![0.0; 100], vec![0.0; 99]], 1000.0, 0.0, &poles, &o),
        Err(ImpactError::ChannelLength { channel: 1, .. })
    ));
    let mut nan = ok.clone();
    nan[1][7] = f64::NAN;
    assert!(matches!(
        fit_amplitudes(&nan, 1000.0, 0.0, &poles, &o),
        Err(ImpactError::NonFiniteSample {
            channel: 1,
            index: 7,
            ..
        })
    ));
    assert!(matches!(
        fit_amplitudes(&ok, 0.0, 0.0, &poles, &o),
        Err(ImpactError::BadSampleRate(_))
    ));
    assert_eq!(
        fit_amplitudes(&ok, 1000.0, 0.0, &[], &o),
        Err(ImpactError::NoModes)
    );
    assert!(matches!(
        fit_amplitudes(&ok, 1000.0, 0.0, &[pole(600.0, 1.0)], &o),
        Err(ImpactError::BadPole { index: 0, .. })
    ));
    assert!(matches!(
        fit_amplitudes(&ok, 1000.0, 0.0, &[pole(100.0, f64::NAN)], &o),
        Err(ImpactError::BadPole { .. })
    ));
    assert!(matches!(
        fit_amplitudes(&ok, 1000.0, 0.2, &poles, &o),
        Err(ImpactError::BadStart { .. })
    ));
    assert!(matches!(
        fit_amplitudes(&ok, 1000.0, -1.0, &poles, &o),
        Err(ImpactError::BadStart { .. })
    ));
    assert!(matches!(
        fit_amplitudes(&ok, 1000.0, 0.099, &poles, &o),
        Err(ImpactError::WindowTooShort {
            samples: 1,
            unknowns: 2
        })
    ));
    let short = AmplitudeFitOptions {
        window_s: Some(-1.0),
        ..Default::default()
    };
    assert!(matches!(
        fit_amplitudes(&ok, 1000.0, 0.0, &poles, &short),
        Err(ImpactError::BadOption {
            name: "window_s",
            ..
        })
    ));
    let fit = fit_amplitudes(&ok, 1000.0, 0.0, &poles, &o).unwrap();
    assert!(matches!(
        cluster_amplitudes(&fit, &[0, 1]),
        Err(ImpactError::LengthMismatch { .. })
    ));
}

// ---------------------------------------------------------------------------------------------
// Test geometry and modes
// ---------------------------------------------------------------------------------------------

/// An icosphere of radius `r` [m] (642 vertices at 3 levels; [`crate::testing::icosphere`]).
fn icosphere(levels: usize, r: f64) -> (Vec<[f64; 3]>, Vec<[usize; 3]>) {
    crate::testing::icosphere(r, levels)
}

/// Smooth random mode shapes on `points` (scale `r`): each component a sum of three plane
/// waves of wavelength ~ r.
fn smooth_shapes(points: &[[f64; 3]], modes: usize, r: f64, rng: &mut SplitMix64) -> Vec<Vec<f64>> {
    (0..modes)
        .map(|_| {
            let waves: Vec<([f64; 3], f64, f64)> = (0..9)
                .map(|_| {
                    let dir = [rng.normal(), rng.normal(), rng.normal()];
                    let k = rng.uniform(1.0, 3.0) / r / norm(dir);
                    (
                        dir.map(|c| c * k),
                        rng.uniform(0.0, TWO_PI),
                        rng.uniform(0.5, 1.5),
                    )
                })
                .collect();
            points
                .iter()
                .flat_map(|x| {
                    let w = &waves;
                    (0..3).map(move |d| {
                        w[3 * d..3 * d + 3]
                            .iter()
                            .map(|(kv, ph, a)| {
                                a * (kv[0] * x[0] + kv[1] * x[1] + kv[2] * x[2] + ph).sin()
                            })
                            .sum::<f64>()
                    })
                })
                .collect()
        })
        .collect()
}

fn inward(points: &[[f64; 3]]) -> Vec<Candidate> {
    points
        .iter()
        .enumerate()
        .map(|(vertex, p)| Candidate {
            vertex,
            direction: p.map(|c| -c),
        })
        .collect()
}

fn random_transfer(modes: usize, mics: usize, rng: &mut SplitMix64) -> Vec<Vec<Complex64>> {
    (0..modes)
        .map(|_| {
            (0..mics)
                .map(|_| Complex64::from_polar(rng.uniform(0.3, 1.0), rng.uniform(0.0, TWO_PI)))
                .collect()
        })
        .collect()
}

/// Eigenvalues of modes at 400 … 400 + 150 k Hz, Rayleigh-like decays.
fn spectrum(modes: usize) -> (Vec<f64>, Vec<f64>) {
    let f: Vec<f64> = (0..modes).map(|k| 400.0 + 150.0 * k as f64).collect();
    (
        f.iter().map(|f| (TWO_PI * f).powi(2)).collect(),
        f.iter().map(|f| 2.0 + 0.004 * f).collect(),
    )
}

const STRIKE: Strike = Strike {
    force: ContactForce::HalfSine { duration_s: 2e-4 },
    response: Response::Displacement,
};

/// Exact measured cluster amplitudes of a strike of strength `s` at candidate `v`, relative sd
/// `rel`.
fn exact_measurement(table: &ForwardTable, v: usize, s: f64, rel: f64) -> ClusterAmplitudes {
    let m = table.microphones;
    let amplitude: Vec<Vec<f64>> = (0..table.clusters.len())
        .map(|c| (0..m).map(|i| s * table.amplitude(v, c, i)).collect())
        .collect();
    ClusterAmplitudes {
        clusters: table.clusters.clone(),
        sd: amplitude
            .iter()
            .map(|r| r.iter().map(|a| rel * a).collect())
            .collect(),
        detection_limit: amplitude
            .iter()
            .map(|r| vec![1e-12 * r.iter().cloned().fold(0.0, f64::max); r.len()])
            .collect(),
        below_limit: amplitude.iter().map(|r| vec![false; r.len()]).collect(),
        amplitude,
    }
}

// ---------------------------------------------------------------------------------------------
// Forward amplitudes
// ---------------------------------------------------------------------------------------------

#[test]
fn forward_amplitudes_match_the_renderer_through_the_transfer() {
    // Render a strike with the chain and synthesiser, each microphone hearing z·conj(T); the
    // amplitude fit must give back a = −i z conj(T) with |a| = J |φ·n| |G| |T|.
    let mut rng = SplitMix64::new(3);
    let (points, _) = icosphere(1, 0.05);
    let (k_modes, mics) = (6, 3);
    let shapes = smooth_shapes(&points, k_modes, 0.05, &mut rng);
    let (eigenvalues, decays) = spectrum(k_modes);
    let transfer = random_transfer(k_modes, mics, &mut rng);
    let candidates = inward(&points);
    let ids: Vec<usize> = (0..k_modes).collect();
    let table = forward_amplitudes(
        &shapes,
        &eigenvalues,
        &decays,
        &STRIKE,
        &candidates,
        &Transfer::Directional(&transfer),
        &ids,
    )
    .unwrap();
    let (v, impulse) = (17, 0.37);
    let projections: Vec<f64> = table.drive[v].iter().map(|d| impulse * d).collect();
    let (bank, _) = ModalChain::new(
        &eigenvalues,
        &projections,
        &DampingModel::PerMode {
            decay_rates: decays.clone(),
        },
        &STRIKE,
    )
    .unwrap();
    let fs = 16_000.0;
    let channels: Vec<Vec<f64>> = (0..mics)
        .map(|m| {
            let z: Vec<Complex64> = (0..k_modes)
                .map(|k| {
                    Complex64::from_polar(bank.amplitudes[k], bank.phases[k])
                        * transfer[k][m].conj()
                })
                .collect();
            let heard = ModalBank {
                frequencies_hz: bank.frequencies_hz.clone(),
                decay_rates: bank.decay_rates.clone(),
                amplitudes: z.iter().map(|z| z.norm()).collect(),
                phases: z.iter().map(|z| z.arg()).collect(),
            };
            render_samples(&heard, fs, 4000)
        })
        .collect();
    let poles: Vec<MeasuredMode> = (0..k_modes)
        .map(|k| pole(bank.frequencies_hz[k], bank.decay_rates[k]))
        .collect();
    let fit = fit_amplitudes(&channels, fs, 0.0, &poles, &AmplitudeFitOptions::default()).unwrap();
    // Index loops: (m, k) index the table, the bank, the transfers and the fit together.
    #[allow(clippy::needless_range_loop)]
    for m in 0..mics {
        for k in 0..k_modes {
            let want = impulse * table.mode_amplitude(v, k, m);
            let z =
                Complex64::from_polar(bank.amplitudes[k], bank.phases[k]) * transfer[k][m].conj();
            let a = fit.amplitudes[m][k];
            assert!(
                (a.norm() - want).abs() < 1e-9 * want,
                "mode {k} mic {m}: {} vs {want}",
                a.norm()
            );
            assert!((a - Complex64::new(0.0, -1.0) * z).norm() < 1e-9 * want);
            // Singleton clusters: the table's cluster amplitude is the mode's.
            assert!(
                (table.amplitude(v, k, m) - table.mode_amplitude(v, k, m)).abs()
                    <= 1e-12 * table.mode_amplitude(v, k, m)
            );
        }
    }
}

/// The pair (0, 1) rotated by θ in shape space (and in transfer, which is linear in the shape).
fn rotate_pair<
    T: Copy + std::ops::Mul<f64, Output = T> + std::ops::Add<Output = T> + std::ops::Sub<Output = T>,
>(
    a: T,
    b: T,
    theta: f64,
) -> (T, T) {
    let (s, c) = theta.sin_cos();
    (a * c + b * s, b * c - a * s)
}

#[test]
fn degenerate_pair_rotation_leaves_table_and_map_unchanged() {
    let mut rng = SplitMix64::new(5);
    let (points, tris) = icosphere(2, 0.05);
    let graph = SurfaceGraph::new(&points, &tris).unwrap();
    let k_modes = 5;
    let mut shapes = smooth_shapes(&points, k_modes, 0.05, &mut rng);
    let (mut eigenvalues, mut decays) = spectrum(k_modes);
    // Modes 0 and 1: an exactly degenerate pair.
    eigenvalues[1] = eigenvalues[0];
    decays[1] = decays[0];
    let ids = [0, 0, 1, 2, 3];
    let candidates = inward(&points);
    let mut directional = random_transfer(k_modes, 3, &mut rng);
    // Magnitude-only transfers: the same for both members (as for the direction-averaged
    // transfer of a symmetry pair).
    let magnitude: Vec<Vec<f64>> = (0..k_modes)
        .map(|k| {
            (0..3)
                .map(|m| directional[if k == 1 { 0 } else { k }][m].norm())
                .collect()
        })
        .collect();
    let tables = |shapes: &[Vec<f64>], directional: &[Vec<Complex64>]| {
        [
            Transfer::None { microphones: 3 },
            Transfer::Magnitude(&magnitude),
            Transfer::Directional(directional),
        ]
        .iter()
        .map(|t| {
            forward_amplitudes(shapes, &eigenvalues, &decays, &STRIKE, &candidates, t, &ids)
                .unwrap()
        })
        .collect::<Vec<_>>()
    };
    let before = tables(&shapes, &directional);
    let theta = 0.7;
    let (a, b): (Vec<f64>, Vec<f64>) = shapes[0]
        .iter()
        .zip(&shapes[1])
        .map(|(&x, &y)| rotate_pair(x, y, theta))
        .unzip();
    shapes[0] = a;
    shapes[1] = b;
    // Index loop: microphone m is read and written in two rows of `directional` at once.
    #[allow(clippy::needless_range_loop)]
    for m in 0..3 {
        let (x, y) = rotate_pair(directional[0][m], directional[1][m], theta);
        directional[0][m] = x;
        directional[1][m] = y;
    }
    let after = tables(&shapes, &directional);
    // The per-mode drives did change; the cluster amplitudes did not.
    assert!((before[0].drive[40][0] - after[0].drive[40][0]).abs() > 1e-3);
    for (t0, t1) in before.iter().zip(&after) {
        for v in 0..points.len() {
            for (x, y) in t0.amplitudes_of(v).iter().zip(t1.amplitudes_of(v)) {
                assert!((x - y).abs() <= 1e-12 * x.abs().max(1e-30), "{x} vs {y}");
            }
        }
        let measured = exact_measurement(t0, 123, 1.7, 0.05);
        let m0 = likelihood_map(&measured, t0, &graph, &MapOptions::default()).unwrap();
        let m1 = likelihood_map(&measured, t1, &graph, &MapOptions::default()).unwrap();
        for (x, y) in m0.log_likelihood.iter().zip(&m1.log_likelihood) {
            assert!((x - y).abs() < 1e-8 * x.abs().max(1.0), "{x} vs {y}");
        }
        assert_eq!(m0.best, 123);
    }
}

#[test]
fn directional_cluster_prediction_is_the_average_over_cluster_bases() {
    // (‖g‖²‖T‖² + 2|Σ g T|²)/(n + 2) against the mean over rotations (64 equally spaced angles
    // are exact for these degree-4 trigonometric polynomials) and one reflection.
    let g = [0.8, -0.3];
    let t = [Complex64::new(0.2, 0.9), Complex64::new(-0.5, 0.4)];
    let formula = cluster_prediction(
        &[0, 1],
        &g,
        &[1.0, 1.0],
        &Transfer::Directional(&[vec![t[0]], vec![t[1]]]),
        0,
    );
    let steps = 64;
    let mean: f64 = (0..steps)
        .map(|i| {
            let theta = TWO_PI * i as f64 / steps as f64;
            let (g0, g1) = rotate_pair(g[0], g[1], theta);
            let (t0, t1) = rotate_pair(t[0], t[1], theta);
            // Reflections (g1, t1 → −g1, −t1) give the same values: squares only.
            g0 * g0 * t0.norm_sqr() + g1 * g1 * t1.norm_sqr()
        })
        .sum::<f64>()
        / steps as f64;
    assert!((formula - mean).abs() < 1e-14, "{formula} vs {mean}");
    // A single mode: g² |T|².
    let one = cluster_prediction(
        &[0],
        &g,
        &[2.0, 1.0],
        &Transfer::Directional(&[vec![t[0]], vec![t[1]]]),
        0,
    );
    assert!((one - (g[0] * 2.0).powi(2) * t[0].norm_sqr()).abs() < 1e-15);
}

#[test]
fn invalid_forward_input_is_an_error() {
    let shapes = vec![vec![0.1; 9], vec![0.2; 9]];
    let (eig, dec) = (vec![1e6, 2e6], vec![1.0, 1.0]);
    let cands = [Candidate {
        vertex: 1,
        direction: [0.0, 0.0, 2.0],
    }];
    let none = Transfer::None { microphones: 2 };
    let f = |shapes: &[Vec<f64>], cands: &[Candidate], t: &Transfer, ids: &[usize]| {
        forward_amplitudes(shapes, &eig, &dec, &Strike::default(), cands, t, ids)
    };
    assert!(f(&shapes, &cands, &none, &[0, 1]).is_ok());
    assert_eq!(f(&[], &cands, &none, &[]), Err(ImpactError::NoModes));
    assert_eq!(
        f(&shapes, &[], &none, &[0, 1]),
        Err(ImpactError::NoCandidates)
    );
    assert!(matches!(
        f(&shapes, &cands, &none, &[0]),
        Err(ImpactError::LengthMismatch {
            what: "cluster ids",
            ..
        })
    ));
    assert!(matches!(
        f(&[vec![0.1; 9], vec![0.2; 6]], &cands, &none, &[0, 1]),
        Err(ImpactError::LengthMismatch { .. })
    ));
    assert!(matches!(
        f(&[vec![0.1; 8], vec![0.2; 8]], &cands, &none, &[0, 1]),
        Err(ImpactError::ShapeLength(8))
    ));
    assert!(matches!(
        f(&[vec![f64::NAN; 9], vec![0.2; 9]], &cands, &none, &[0, 1]),
        Err(ImpactError::NonFinite { .. })
    ));
    assert!(matches!(
        f(
            &shapes,
            &[Candidate {
                vertex: 3,
                direction: [1.0, 0.0, 0.0]
            }],
            &none,
            &[0, 1]
        ),
        Err(ImpactError::BadVertex { vertex: 3, .. })
    ));
    assert!(matches!(
        f(
            &shapes,
            &[Candidate {
                vertex: 0,
                direction: [0.0; 3]
            }],
            &none,
            &[0, 1]
        ),
        Err(ImpactError::BadDirection { .. })
    ));
    assert!(matches!(
        f(&shapes, &[cands[0], cands[0]], &none, &[0, 1]),
        Err(ImpactError::DuplicateCandidate {
            index: 1,
            first: 0,
            ..
        })
    ));
    assert!(matches!(
        f(&shapes, &cands, &Transfer::None { microphones: 0 }, &[0, 1]),
        Err(ImpactError::BadOption { .. })
    ));
    let short = vec![vec![1.0, 1.0]];
    assert!(matches!(
        f(&shapes, &cands, &Transfer::Magnitude(&short), &[0, 1]),
        Err(ImpactError::LengthMismatch {
            what: "transfer modes",
            ..
        })
    ));
    let ragged = vec![
        vec![Complex64::new(1.0, 0.0); 2],
        vec![Complex64::new(1.0, 0.0); 1],
    ];
    assert!(matches!(
        f(&shapes, &cands, &Transfer::Directional(&ragged), &[0, 1]),
        Err(ImpactError::LengthMismatch {
            what: "transfer microphones",
            ..
        })
    ));
    let bad_strike = Strike {
        force: ContactForce::HalfSine { duration_s: 0.0 },
        response: Response::Velocity,
    };
    assert!(matches!(
        forward_amplitudes(&shapes, &eig, &dec, &bad_strike, &cands, &none, &[0, 1]),
        Err(ImpactError::BadStrike(_))
    ));
    // Directions are normalised.
    let t = f(&shapes, &cands, &none, &[0, 1]).unwrap();
    assert_eq!(t.candidates[0].direction, [0.0, 0.0, 1.0]);
}

// ---------------------------------------------------------------------------------------------
// The map
// ---------------------------------------------------------------------------------------------

struct Scene {
    points: Vec<[f64; 3]>,
    graph: SurfaceGraph,
    table: ForwardTable,
}

fn scene(seed: u64, modes: usize, mics: usize) -> Scene {
    let mut rng = SplitMix64::new(seed);
    let (points, tris) = icosphere(3, 0.05);
    let graph = SurfaceGraph::new(&points, &tris).unwrap();
    let shapes = smooth_shapes(&points, modes, 0.05, &mut rng);
    let (eigenvalues, decays) = spectrum(modes);
    let transfer = random_transfer(modes, mics, &mut rng);
    let ids: Vec<usize> = (0..modes).collect();
    let table = forward_amplitudes(
        &shapes,
        &eigenvalues,
        &decays,
        &STRIKE,
        &inward(&points),
        &Transfer::Directional(&transfer),
        &ids,
    )
    .unwrap();
    Scene {
        points,
        graph,
        table,
    }
}

#[test]
fn noise_free_map_peaks_at_the_truth_with_the_exact_strength() {
    let sc = scene(11, 12, 3);
    for (v, s) in [(0, 2.5), (345, 0.01), (641, 7.0)] {
        let measured = exact_measurement(&sc.table, v, s, 1e-4);
        // A negligible prediction floor: at the truth every residual is then exactly zero.
        let options = MapOptions {
            prediction_floor: 1e-12,
            ..Default::default()
        };
        let map = likelihood_map(&measured, &sc.table, &sc.graph, &options).unwrap();
        assert_eq!(map.best, v);
        assert_eq!(map.top[0].vertex, v);
        assert!(
            (map.strength - s).abs() < 1e-9 * s,
            "{} vs {s}",
            map.strength
        );
        assert!((map.cosine[v] - 1.0).abs() < 1e-12);
        assert!(map.cosine.iter().all(|&c| (0.0..=1.0 + 1e-12).contains(&c)));
        assert!((map.posterior.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        let top_p = map.posterior.iter().cloned().fold(0.0, f64::max);
        assert_eq!(map.posterior[v], top_p);
        // The truth is the best vertex: its rank is its own area share.
        assert!(
            (map.area_rank(v) - map.area_share[v] / map.area_share.iter().sum::<f64>()).abs()
                < 1e-15
        );
        assert_eq!(map.terms, 36);
        // No model error: σ_model goes to the bottom of its range.
        assert!(map.sigma_model[v] < 1.01e-3, "{}", map.sigma_model[v]);
    }
}

#[test]
fn free_microphone_gains_absorb_uncalibrated_microphones() {
    // Microphone gains 10^(±6 dB/20) unknown to the map: with one shared strength the
    // mismatch between microphones reads as model error and blurs the map; with a gain per
    // microphone the truth is exact again (σ_model at the bottom of its range).
    let sc = scene(13, 12, 4);
    let v = 345;
    let mut measured = exact_measurement(&sc.table, v, 1.0, 1e-4);
    let gains = [2.0, 0.5, 1.3, 0.7];
    for row in measured.amplitude.iter_mut() {
        for (a, g) in row.iter_mut().zip(gains) {
            *a *= g;
        }
    }
    for row in measured.sd.iter_mut() {
        for (a, g) in row.iter_mut().zip(gains) {
            *a *= g;
        }
    }
    let free = MapOptions {
        prediction_floor: 1e-12,
        free_microphone_gains: true,
        ..Default::default()
    };
    let map = likelihood_map(&measured, &sc.table, &sc.graph, &free).unwrap();
    assert_eq!(map.best, v);
    assert!(map.sigma_model[v] < 1.01e-3, "{}", map.sigma_model[v]);
    let shared = likelihood_map(
        &measured,
        &sc.table,
        &sc.graph,
        &MapOptions {
            prediction_floor: 1e-12,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(
        shared.sigma_model[v] > 0.3,
        "the gains show up as model error: {}",
        shared.sigma_model[v]
    );
    assert!(shared.log_likelihood[v] < map.log_likelihood[v]);
}

#[test]
fn model_error_is_profiled_by_maximum_likelihood() {
    // Amplitudes scattered by e^(0.1 ε), ε standard normal, measured to 0.1 %: σ_model ≈ 0.1.
    let sc = scene(12, 40, 4);
    let mut rng = SplitMix64::new(99);
    let v = 200;
    let mut measured = exact_measurement(&sc.table, v, 1.0, 1e-3);
    for row in measured.amplitude.iter_mut() {
        for a in row.iter_mut() {
            *a *= (0.1 * rng.normal()).exp();
        }
    }
    let map = likelihood_map(&measured, &sc.table, &sc.graph, &MapOptions::default()).unwrap();
    let s = map.sigma_model[v];
    assert!((s - 0.1).abs() < 0.015, "σ_model at the truth {s}");
    assert!(map.area_rank(v) < 0.01, "rank {}", map.area_rank(v));
    // Fixed σ_model: the same ℓ as the profile at that value.
    let fixed = likelihood_map(
        &measured,
        &sc.table,
        &sc.graph,
        &MapOptions {
            sigma_model: SigmaModel::Fixed { value: s },
            ..Default::default()
        },
    )
    .unwrap();
    assert!((fixed.log_likelihood[v] - map.log_likelihood[v]).abs() < 1e-6);
    assert!(
        fixed
            .log_likelihood
            .iter()
            .zip(&map.log_likelihood)
            .all(|(f, p)| *f <= *p + 1e-6),
        "the profile is the maximum over σ"
    );
}

#[test]
fn top_candidates_are_separated_local_maxima() {
    let sc = scene(13, 8, 2);
    let measured = exact_measurement(&sc.table, 77, 1.0, 0.3);
    let options = MapOptions {
        top_k: 6,
        min_separation_m: Some(0.03),
        neighbourhood_m: Some(0.01),
        ..Default::default()
    };
    let map = likelihood_map(&measured, &sc.table, &sc.graph, &options).unwrap();
    assert_eq!(map.top.len(), 6);
    assert_eq!(map.top[0].candidate, map.best);
    for (i, a) in map.top.iter().enumerate() {
        assert!(a.neighbourhood_mass > 0.0 && a.neighbourhood_mass <= 1.0 + 1e-12);
        assert_eq!(a.position, sc.points[a.vertex]);
        for b in &map.top[i + 1..] {
            assert!(a.log_likelihood >= b.log_likelihood);
            assert!(sc.graph.distance(a.vertex, b.vertex).unwrap() > 0.03);
        }
        // A local maximum: no edge neighbour scores higher (candidates are the vertices here).
        for u in sc.graph.neighbours(a.vertex).unwrap() {
            assert!(map.log_likelihood[u] <= a.log_likelihood);
        }
    }
    // The neighbourhood mass of the best candidate includes its own posterior.
    assert!(map.top[0].neighbourhood_mass >= map.posterior[map.best]);
}

#[test]
fn noisy_strike_is_found_end_to_end() {
    // Render a strike through the transfer at 40 dB below the peak, fit the amplitudes with the
    // poles known, map: the truth is among the best 1 % and the strength within 5 %.
    let mut rng = SplitMix64::new(21);
    let (points, tris) = icosphere(3, 0.05);
    let graph = SurfaceGraph::new(&points, &tris).unwrap();
    let (k_modes, mics) = (16, 3);
    let shapes = smooth_shapes(&points, k_modes, 0.05, &mut rng);
    let (eigenvalues, decays) = spectrum(k_modes);
    let transfer = random_transfer(k_modes, mics, &mut rng);
    let ids: Vec<usize> = (0..k_modes).collect();
    let table = forward_amplitudes(
        &shapes,
        &eigenvalues,
        &decays,
        &STRIKE,
        &inward(&points),
        &Transfer::Directional(&transfer),
        &ids,
    )
    .unwrap();
    let (v, impulse) = (400, 0.02);
    let projections: Vec<f64> = table.drive[v].iter().map(|d| impulse * d).collect();
    let (bank, _) = ModalChain::new(
        &eigenvalues,
        &projections,
        &DampingModel::PerMode {
            decay_rates: decays.clone(),
        },
        &STRIKE,
    )
    .unwrap();
    let fs = 16_000.0;
    let channels: Vec<Vec<f64>> = (0..mics)
        .map(|m| {
            let z: Vec<Complex64> = (0..k_modes)
                .map(|k| {
                    Complex64::from_polar(bank.amplitudes[k], bank.phases[k])
                        * transfer[k][m].conj()
                })
                .collect();
            let heard = ModalBank {
                frequencies_hz: bank.frequencies_hz.clone(),
                decay_rates: bank.decay_rates.clone(),
                amplitudes: z.iter().map(|z| z.norm()).collect(),
                phases: z.iter().map(|z| z.arg()).collect(),
            };
            let clean = render_samples(&heard, fs, 8000);
            let peak = clean.iter().fold(0.0_f64, |p, x| p.max(x.abs()));
            clean
                .iter()
                .map(|x| x + 0.01 * peak * rng.normal())
                .collect()
        })
        .collect();
    let poles: Vec<MeasuredMode> = (0..k_modes)
        .map(|k| pole(bank.frequencies_hz[k], bank.decay_rates[k]))
        .collect();
    let fit = fit_amplitudes(&channels, fs, 0.0, &poles, &AmplitudeFitOptions::default()).unwrap();
    let measured = cluster_amplitudes(&fit, &ids).unwrap();
    let map = likelihood_map(&measured, &table, &graph, &MapOptions::default()).unwrap();
    let rank = map.area_rank(v);
    let dist = graph
        .distance(v, table.candidates[map.best].vertex)
        .unwrap();
    eprintln!("end to end: rank {rank:.4}, best {} at {dist:.4} m, strength {:.5} ± {:.5} (true {impulse}), σ_model {:.3}, {} terms", map.best, map.strength, map.strength_sd, map.sigma_model[map.best], map.terms);
    assert!(rank <= 0.01, "rank {rank}, best {} at {dist} m", map.best);
    assert!(
        (map.strength / impulse - 1.0).abs() < 0.05,
        "strength {} vs {impulse}",
        map.strength
    );
    assert!(map.strength_sd > 0.0 && map.strength_sd.is_finite());
}

#[test]
fn invalid_map_input_is_an_error() {
    let sc = scene(14, 4, 2);
    let good = exact_measurement(&sc.table, 3, 1.0, 0.1);
    let o = MapOptions::default();
    assert!(likelihood_map(&good, &sc.table, &sc.graph, &o).is_ok());
    let mut other = good.clone();
    other.clusters = vec![vec![0, 1], vec![2], vec![3]];
    assert!(matches!(
        likelihood_map(&other, &sc.table, &sc.graph, &o),
        Err(ImpactError::ClusterMismatch { .. })
    ));
    let mut mics = good.clone();
    for r in [&mut mics.amplitude, &mut mics.sd, &mut mics.detection_limit] {
        r.iter_mut().for_each(|row| row.truncate(1));
    }
    assert!(matches!(
        likelihood_map(&mics, &sc.table, &sc.graph, &o),
        Err(ImpactError::MicrophoneMismatch {
            measured: 1,
            table: 2
        })
    ));
    let mut unresolved = good.clone();
    unresolved
        .sd
        .iter_mut()
        .flatten()
        .for_each(|s| *s = f64::INFINITY);
    assert_eq!(
        likelihood_map(&unresolved, &sc.table, &sc.graph, &o),
        Err(ImpactError::NothingToCompare)
    );
    // A graph that lacks the candidates.
    let (p, t) = icosphere(0, 0.05);
    let small = SurfaceGraph::new(&p, &t).unwrap();
    assert!(matches!(
        likelihood_map(&good, &sc.table, &small, &o),
        Err(ImpactError::NotOnSurface {
            index: 12,
            vertex: 12
        })
    ));
    for bad in [
        MapOptions {
            prediction_floor: 0.0,
            ..Default::default()
        },
        MapOptions {
            sigma_model: SigmaModel::Profiled { min: 0.5, max: 0.1 },
            ..Default::default()
        },
        MapOptions {
            sigma_model: SigmaModel::Fixed { value: f64::NAN },
            ..Default::default()
        },
        MapOptions {
            min_separation_m: Some(-1.0),
            ..Default::default()
        },
    ] {
        assert!(matches!(
            likelihood_map(&good, &sc.table, &sc.graph, &bad),
            Err(ImpactError::BadOption { .. })
        ));
    }
}

// ---------------------------------------------------------------------------------------------
// Evaluation helpers
// ---------------------------------------------------------------------------------------------

#[test]
fn dijkstra_overestimates_sphere_geodesics_by_a_few_percent() {
    let r = 0.05;
    let (points, tris) = icosphere(3, r);
    let graph = SurfaceGraph::new(&points, &tris).unwrap();
    assert_eq!(graph.len(), 642);
    assert!((graph.area() - 4.0 * std::f64::consts::PI * r * r).abs() < 0.01 * graph.area());
    let edge = 0.1 * r; // about: 642 vertices
    let mut ratios = Vec::new();
    for source in (0..642).step_by(7) {
        let d = graph.distances_from(source, f64::INFINITY).unwrap();
        for (slot, &dist) in d.iter().enumerate() {
            let (a, b) = (points[source], points[graph.vertices()[slot]]);
            let cos = ((a[0] * b[0] + a[1] * b[1] + a[2] * b[2]) / (r * r)).clamp(-1.0, 1.0);
            let arc = r * cos.acos();
            if arc > 3.0 * edge {
                ratios.push(dist / arc);
            }
        }
    }
    ratios.sort_by(f64::total_cmp);
    let mean = ratios.iter().sum::<f64>() / ratios.len() as f64;
    let p95 = ratios[(0.95 * ratios.len() as f64) as usize];
    let (min, max) = (ratios[0], ratios[ratios.len() - 1]);
    eprintln!("icosphere 642: Dijkstra / great circle over {} pairs: mean {mean:.4}, p95 {p95:.4}, min {min:.4}, max {max:.4}", ratios.len());
    // Edges are chords, a little shorter than arcs, so a path along a great circle of edges
    // comes out just below it.
    assert!(
        min >= 0.998 && mean > 1.03 && mean < 1.10 && p95 < 1.15 && max < 1.3,
        "mean {mean}, p95 {p95}, min {min}, max {max}"
    );
    assert_eq!(graph.distance(5, 5).unwrap(), 0.0);
    assert!(matches!(
        graph.distance(5, 9999),
        Err(ImpactError::UnknownVertex(9999))
    ));
    assert!(graph
        .distances_from(3, 0.01)
        .unwrap()
        .iter()
        .all(|&d| d <= 0.01 || d.is_infinite()));
}

#[test]
fn graph_of_a_tet_mesh_and_its_candidates() {
    let mesh = crate::mesh::box_mesh([2, 2, 2], [0.2, 0.1, 0.1]);
    let graph = SurfaceGraph::from_mesh(&mesh).unwrap();
    let area = 2.0 * (0.2 * 0.1 + 0.2 * 0.1 + 0.1 * 0.1);
    assert!((graph.area() - area).abs() < 1e-12);
    let cands = surface_candidates(&mesh);
    assert_eq!(cands.len(), 26); // 27 nodes, the centre is inside
    assert_eq!(graph.len(), 26);
    let shares: f64 = cands
        .iter()
        .map(|c| graph.area_share(c.vertex).unwrap())
        .sum();
    assert!((shares - 1.0).abs() < 1e-12);
    // Corner (0,0,0) is struck into the box.
    let corner = cands.iter().find(|c| c.vertex == 0).unwrap();
    assert!(corner.direction.iter().all(|&c| c > 0.0));
    // Along the bottom edge: two straight edges of 0.1 m.
    assert!((graph.distance(0, 2).unwrap() - 0.2).abs() < 1e-12);
    assert!(matches!(
        SurfaceGraph::new(&[[0.0; 3]], &[[0, 1, 2]]),
        Err(ImpactError::BadTriangle { point: 1, .. })
    ));
    assert_eq!(
        SurfaceGraph::new(&[[0.0; 3]], &[]),
        Err(ImpactError::NoSurface)
    );
}

/// A ring of `n` points in the plane z = 0 and modes whose radial motion is `f_k(θ)`.
fn ring_table(n: usize, radial: &[fn(f64) -> f64], ids: &[usize]) -> ForwardTable {
    let points: Vec<[f64; 3]> = (0..n)
        .map(|j| TWO_PI * j as f64 / n as f64)
        .map(|t| [t.cos(), t.sin(), 0.0])
        .collect();
    let shapes: Vec<Vec<f64>> = radial
        .iter()
        .map(|f| {
            points
                .iter()
                .flat_map(|p| {
                    let a = f(p[1].atan2(p[0]));
                    [a * p[0], a * p[1], 0.0]
                })
                .collect()
        })
        .collect();
    let k = radial.len();
    let (eig, dec) = spectrum(k);
    forward_amplitudes(
        &shapes,
        &eig,
        &dec,
        &Strike::default(),
        &inward(&points),
        &Transfer::None { microphones: 1 },
        ids,
    )
    .unwrap()
}

#[test]
fn symmetry_orbits_on_a_ring() {
    let n = 36;
    // Axisymmetric: a breathing mode and two cos/sin pairs (each pair one cluster).
    let axi = ring_table(
        n,
        &[
            |_| 1.0,
            |t| (2.0 * t).cos(),
            |t| (2.0 * t).sin(),
            |t| (3.0 * t).cos(),
            |t| (3.0 * t).sin(),
        ],
        &[0, 1, 1, 2, 2],
    );
    let sig = drive_signatures(&axi);
    assert_eq!(
        symmetry_orbit(&sig, 5, 1e-9).unwrap(),
        (0..n).collect::<Vec<_>>()
    );
    // The same modes as five singletons: the pair bases tell the points apart again, up to the
    // symmetry the chosen basis keeps (θ → −θ and θ → θ + π for these five).
    let split = ring_table(
        n,
        &[
            |_| 1.0,
            |t| (2.0 * t).cos(),
            |t| (2.0 * t).sin(),
            |t| (3.0 * t).cos(),
            |t| (3.0 * t).sin(),
        ],
        &[0, 1, 2, 3, 4],
    );
    let orbit = symmetry_orbit(&drive_signatures(&split), 5, 1e-9).unwrap();
    assert!(orbit.len() < n && orbit.contains(&5), "{orbit:?}");
    // Mirror-symmetric only (even in θ, and |cos θ + 0.5| is not symmetric under θ → θ + π):
    // θ and −θ (vertex 5 and 31).
    let mirror = ring_table(n, &[|t| t.cos() + 0.5, |t| (2.0 * t).cos() + 0.3], &[0, 1]);
    assert_eq!(
        symmetry_orbit(&drive_signatures(&mirror), 5, 1e-9).unwrap(),
        vec![5, 31]
    );
    // Asymmetric: no other point.
    let asym = ring_table(
        n,
        &[
            |t| t.cos() + 0.4 * (2.0 * t).sin(),
            |t| (t + 0.3).sin().powi(2) + 0.5 * t.cos(),
        ],
        &[0, 1],
    );
    assert_eq!(
        symmetry_orbit(&drive_signatures(&asym), 5, 1e-3).unwrap(),
        vec![5]
    );
    // Errors.
    assert!(symmetry_orbit(&sig, n, 0.1).is_err());
    assert!(symmetry_orbit(&sig, 0, f64::NAN).is_err());
}
