use super::*;
use crate::testing::Rng;

/// Standard normal (Box–Muller).
fn normal(rng: &mut Rng) -> f64 {
    let u1 = 1.0 - rng.next();
    let u2 = rng.next();
    (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()
}

fn rayleigh(f_hz: f64, alpha: f64, beta: f64) -> f64 {
    0.5 * (alpha + beta * (2.0 * PI * f_hz).powi(2))
}

#[test]
fn rayleigh_recovers_exact_alpha_and_beta() {
    let mut rng = Rng(7);
    let f: Vec<f64> = (0..40)
        .map(|i| 120.0 * 1.12f64.powi(i) * rng.uniform(0.97, 1.03))
        .collect();
    let w = rng.uniform_vec(f.len(), 0.2, 3.0);
    for (alpha, beta) in [(6.0, 1e-7), (0.8, 3e-9), (5.0, 0.0), (0.0, 2e-8)] {
        let d: Vec<f64> = f.iter().map(|&f| rayleigh(f, alpha, beta)).collect();
        let fit = fit_rayleigh(&f, &d, &w).unwrap();
        let close = |got: f64, want: f64| {
            (got - want).abs() <= 1e-9 * want.max(1e-300) || (want == 0.0 && got.abs() < 1e-12)
        };
        assert!(
            close(fit.alpha, alpha) && close(fit.beta, beta),
            "α {alpha} β {beta}: got {fit:?}"
        );
        assert!(fit.rms_log_error < 1e-9, "{fit:?}");
    }
    // Data that want a negative α: the fit stays on the boundary α = 0 with the best β.
    let d: Vec<f64> = f
        .iter()
        .map(|&f| rayleigh(f, 0.0, 1e-8) * (f / 1000.0).powf(0.3))
        .collect();
    let fit = fit_rayleigh(&f, &d, &w).unwrap();
    assert!(fit.alpha >= 0.0 && fit.beta > 0.0, "{fit:?}");
}

#[test]
fn curve_recovers_a_piecewise_power_law_despite_outliers() {
    // d ∝ f^0.3 below 800 Hz and ∝ f^1.5 above (a knot: 100 Hz · 2^(9/3)), 4 per knot interval.
    let truth = |f: f64| {
        if f < 800.0 {
            3.0 * (f / 800.0).powf(0.3)
        } else {
            3.0 * (f / 800.0).powf(1.5)
        }
    };
    let mut rng = Rng(11);
    let mut f: Vec<f64> = (0..=84)
        .map(|i| 100.0 * 2f64.powf(i as f64 / 12.0))
        .collect();
    f.iter_mut()
        .skip(1)
        .take(83)
        .for_each(|v| *v *= rng.uniform(0.99, 1.01));
    let mut d: Vec<f64> = f.iter().map(|&f| truth(f)).collect();
    let w = vec![1.0; f.len()];
    // Exact data: GCV picks the least smoothing, which rounds the kink by 0.6 %.
    let (curve, _, smoothness) = robust_curve(&f, &d, &w, &CurveFitSettings::default()).unwrap();
    assert_eq!(
        smoothness, SMOOTHNESS_GRID.0,
        "the least smoothing of the grid"
    );
    assert_eq!(curve.frequencies_hz.len(), 22, "7 octaves × 3 + 1 knots");
    for &fi in &f {
        let err = (curve.decay(fi) / truth(fi)).ln().abs();
        assert!(err < 1e-2, "f {fi}: {err}");
    }
    // Scatter of 5 % and beating pairs: every 7th mode 40–100 % off. The Huber weights keep the
    // curve near the truth (rms 2.6 %: 5 % over ~4 modes per knot), plain least squares is bent
    // (7 %).
    for (i, v) in d.iter_mut().enumerate() {
        *v *= (0.05 * normal(&mut rng)).exp()
            * if i % 7 != 3 {
                1.0
            } else if i % 2 == 0 {
                2.0
            } else {
                0.6
            };
    }
    let error = |c: &DampingCurve| {
        (f.iter()
            .map(|&fi| (c.decay(fi) / truth(fi)).ln().powi(2))
            .sum::<f64>()
            / f.len() as f64)
            .sqrt()
    };
    let (curve, weights, _) = robust_curve(&f, &d, &w, &CurveFitSettings::default()).unwrap();
    assert!(error(&curve) < 0.035, "rms ln error {}", error(&curve));
    assert!(
        weights[3] < 0.3 && weights[4] == 1.0,
        "outlier weight {} inlier {}",
        weights[3],
        weights[4]
    );
    let plain = CurveFitSettings {
        huber_threshold: 1e9,
        ..CurveFitSettings::default()
    };
    let bent = fit_damping_curve(&f, &d, &w, &plain).unwrap();
    assert!(
        error(&bent) > 2.0 * error(&curve),
        "plain {} robust {}",
        error(&bent),
        error(&curve)
    );
}

#[test]
fn curve_with_few_modes_and_bad_input() {
    let s = CurveFitSettings::default();
    let one = fit_damping_curve(&[440.0], &[3.0], &[1.0], &s).unwrap();
    assert_eq!(one.frequencies_hz, vec![440.0]);
    assert!((one.decay(1000.0) - 3.0).abs() < 1e-12);
    // Three modes over 4 octaves: 2 knots, the power law through the outer two.
    let two = fit_damping_curve(&[100.0, 400.0, 1600.0], &[1.0, 2.0, 4.0], &[1.0; 3], &s).unwrap();
    assert_eq!(two.frequencies_hz.len(), 2);
    assert!(
        (two.decay(400.0) - 2.0).abs() < 1e-9 && (two.decay(3200.0) - 5.656854249).abs() < 1e-6
    );
    for (f, d, w) in [
        (vec![], vec![], vec![]),
        (vec![100.0], vec![1.0, 2.0], vec![1.0]),
        (vec![-100.0], vec![1.0], vec![1.0]),
        (vec![100.0], vec![0.0], vec![1.0]),
        (vec![100.0], vec![f64::NAN], vec![1.0]),
        (vec![100.0], vec![1.0], vec![0.0]),
        (vec![100.0], vec![1.0], vec![-1.0]),
    ] {
        assert!(
            matches!(
                fit_damping_curve(&f, &d, &w, &s),
                Err(DampingError::InvalidData { .. })
            ),
            "{f:?} {d:?} {w:?}"
        );
        assert!(
            matches!(
                fit_rayleigh(&f, &d, &w),
                Err(DampingError::InvalidData { .. })
            ),
            "{f:?} {d:?} {w:?}"
        );
    }
    let bad = CurveFitSettings {
        knots_per_octave: 0.0,
        ..CurveFitSettings::default()
    };
    assert!(matches!(
        fit_damping_curve(&[1.0], &[1.0], &[1.0], &bad),
        Err(DampingError::InvalidSetting { .. })
    ));
}

#[test]
fn energy_decay_of_one_pole_is_exact_and_a_cluster_gets_its_late_slope() {
    let w = 2.0 * PI * 1000.0;
    let one = EnergyDecay::new(
        &[(7.0, w)],
        &[vec![
            Complex64::from_polar(0.3, 1.0),
            Complex64::from_polar(0.1, -2.0),
        ]],
    );
    assert!((one.decay_rate([5.0, 35.0]).unwrap() / 7.0 - 1.0).abs() < 1e-9);
    assert!((one.at(0.1) / one.at(0.0) - (-1.4f64).exp()).abs() < 1e-12);
    // A loud fast pole (d = 100) over a quiet slow one (d = 5, 1/6 of the energy) 2 Hz away:
    // the early part of E is the fast pole, the 5–35 dB range mostly the slow one.
    let amplitudes = vec![
        vec![Complex64::new(1.0, 0.0)],
        vec![Complex64::new(0.0, 0.1)],
    ];
    let pair = EnergyDecay::new(&[(100.0, w), (5.0, w + 2.0 * PI * 2.0)], &amplitudes);
    let (early, late) = (
        pair.decay_rate([0.0, 5.0]).unwrap(),
        pair.decay_rate([5.0, 35.0]).unwrap(),
    );
    assert!(
        early > 50.0 && late > 5.0 && late < 8.0,
        "early {early} late {late}"
    );
    let times: Vec<f64> = (0..50).map(|i| i as f64 * 0.02).collect();
    assert!(
        times.windows(2).all(|t| pair.at(t[1]) < pair.at(t[0])),
        "E decreases"
    );
}

/// A two-channel strike at 16 kHz, 0.5 s: 12 modes with Rayleigh decays, a fast junk pole
/// (d = 500 1/s), a weak one (−80 dB), a 3 ms burst of contact noise and white noise.
struct Strike {
    fs: f64,
    channels: Vec<Vec<f64>>,
    freqs: Vec<f64>,
    decays: Vec<f64>,
    amps: Vec<Vec<f64>>,
    phases: Vec<Vec<f64>>,
}

const ALPHA: f64 = 3.0;
const BETA: f64 = 3e-8;
const FAST_HZ: f64 = 2900.0;
const WEAK_HZ: f64 = 4700.0;

fn strike() -> Strike {
    let fs = 16_000.0;
    let n = 8000;
    let mut rng = Rng(3);
    let mut freqs = vec![
        220.0, 347.0, 511.0, 733.0, 1010.0, 1390.0, 1870.0, 2480.0, 3270.0, 4150.0, 5320.0, 6610.0,
    ];
    // Rayleigh at the undamped frequency; the mode rings at ω_d = √(ω² − d²).
    let mut decays: Vec<f64> = freqs.iter().map(|&f| rayleigh(f, ALPHA, BETA)).collect();
    for (f, d) in freqs.iter_mut().zip(&decays) {
        *f = ((2.0 * PI * *f).powi(2) - d * d).sqrt() / (2.0 * PI);
    }
    let mut amps: Vec<Vec<f64>> = freqs
        .iter()
        .map(|_| rng.uniform_vec(2, 0.05, 0.3))
        .collect();
    freqs.extend([FAST_HZ, WEAK_HZ]);
    decays.extend([500.0, 6.0]);
    amps.extend([vec![0.8, 0.5], vec![2e-5, 1.5e-5]]);
    let phases: Vec<Vec<f64>> = freqs.iter().map(|_| rng.uniform_vec(2, -PI, PI)).collect();
    let channels = (0..2)
        .map(|c| {
            let bank = ModalBank {
                frequencies_hz: freqs.clone(),
                decay_rates: decays.clone(),
                amplitudes: amps.iter().map(|a| a[c]).collect(),
                phases: phases.iter().map(|p| p[c]).collect(),
            };
            let mut x = render_samples(&bank, fs, n);
            for (i, v) in x.iter_mut().enumerate() {
                let t = i as f64 / fs;
                *v += 0.2 * (-t / 0.001).exp() * normal(&mut rng) * f64::from(u8::from(t < 0.003))
                    + 3e-6 * normal(&mut rng);
            }
            x
        })
        .collect();
    Strike {
        fs,
        channels,
        freqs,
        decays,
        amps,
        phases,
    }
}

fn test_settings() -> DampingFitSettings {
    DampingFitSettings {
        estimate: EstimateOptions {
            max_decay_rate: 3000.0,
            ..EstimateOptions::default()
        },
        estimate_skip_s: 0.005,
        steps: 60,
        // 6 ms frames and 4 ms filters, as the defaults give at 48 kHz.
        noise_hop: 96,
        noise_bands: 33,
        ..DampingFitSettings::default()
    }
}

#[test]
fn synthetic_strike_gives_curve_and_rayleigh_and_rejects_junk() {
    let s = strike();
    let mut seen = 0;
    let fit = fit_damping(&s.channels, s.fs, &test_settings(), |_| seen += 1).unwrap();
    assert_eq!(seen, 61);
    assert_eq!(fit.history.len(), 61);
    // The refinement lowers the loss below the estimate alone and below its own start.
    assert!(
        fit.loss_final < fit.loss_initial && fit.loss_final < fit.history[0].loss,
        "{} {} {}",
        fit.loss_initial,
        fit.history[0].loss,
        fit.loss_final
    );
    // Every real mode is found and kept, the junk is rejected for the right reason.
    let nearest = |f: f64| {
        fit.modes
            .iter()
            .min_by(|a, b| {
                (a.frequency_hz - f)
                    .abs()
                    .total_cmp(&(b.frequency_hz - f).abs())
            })
            .unwrap()
    };
    for k in 0..12 {
        let m = nearest(s.freqs[k]);
        assert!(
            (m.frequency_hz - s.freqs[k]).abs() < 0.5,
            "mode {k}: {} Hz vs {}",
            m.frequency_hz,
            s.freqs[k]
        );
        assert!(
            m.kept(),
            "mode {k} at {} Hz rejected: {:?}",
            s.freqs[k],
            m.verdict().reason
        );
        assert!(
            (m.decay_rate / s.decays[k]).ln().abs() < 0.03,
            "mode {k}: d {} vs {}",
            m.decay_rate,
            s.decays[k]
        );
    }
    assert_eq!(
        fit.kept().count(),
        12,
        "{:#?}",
        fit.modes
            .iter()
            .map(|m| (
                m.frequency_hz,
                m.decay_rate,
                m.refined_from.unwrap().decay_rate,
                m.verdict().level_db,
                m.snr(),
                m.verdict().reason
            ))
            .collect::<Vec<_>>()
    );
    let fast = nearest(FAST_HZ);
    assert!(
        (fast.frequency_hz - FAST_HZ).abs() < 5.0
            && fast.verdict().reason == ModeVerdict::DecayTooFast,
        "{fast:?}"
    );
    let weak = nearest(WEAK_HZ);
    assert!(
        (weak.frequency_hz - WEAK_HZ).abs() < 1.0 && weak.verdict().reason == ModeVerdict::Weak,
        "{weak:?}"
    );
    assert!(
        weak.verdict().level_db < -70.0 && weak.snr() > 30.0,
        "{weak:?}"
    );
    // Isolated modes are peaks of their own, with their own decay.
    assert_eq!(fit.kept_peaks().count(), 12);
    for p in fit.kept_peaks() {
        assert_eq!(p.members.len(), 1, "{p:?}");
        let m = &fit.modes[p.members[0]];
        assert!(
            (p.decay_rate / m.decay_rate - 1.0).abs() < 1e-6 && m.verdict().peak.is_some(),
            "{p:?} {m:?}"
        );
    }
    // Curve and Rayleigh.
    for k in 0..12 {
        let f0 = ((2.0 * PI * s.freqs[k]).powi(2) + s.decays[k].powi(2)).sqrt() / (2.0 * PI);
        let err = (fit.curve.decay(f0) / s.decays[k]).ln().abs();
        assert!(err < 0.03, "curve at {f0} Hz off by {err}");
    }
    assert!(
        fit.curve_rms_log_error < 0.02,
        "{}",
        fit.curve_rms_log_error
    );
    let r = fit.rayleigh;
    assert!(
        (r.alpha / ALPHA - 1.0).abs() < 0.1 && (r.beta / BETA - 1.0).abs() < 0.03,
        "{r:?}"
    );
    assert_eq!(fit.noise.magnitudes.len(), 2);
    assert!(fit.noise.magnitudes[0]
        .iter()
        .all(|h| h.is_finite() && *h > 0.0));
}

#[test]
fn refinement_pulls_perturbed_modes_back_to_the_truth() {
    // Start the 12 real modes 25 % off in d, 30 % in a, 0.3 Hz in f, 0.3 rad in φ: the loss
    // gradient must bring d back (the wiring of every parameter's gradient is exercised).
    let s = strike();
    let signals: Vec<&[f64]> = s.channels.iter().map(|c| c.as_slice()).collect();
    let settings = DampingFitSettings {
        steps: 80,
        step_log_decay: 0.03,
        step_log_noise: 0.2,
        ..test_settings()
    };
    let start: Vec<MeasuredMode> = (0..12)
        .map(|k| MeasuredMode {
            amplitudes: s.amps[k].iter().map(|a| a * 1.3).collect(),
            phases: s.phases[k].iter().map(|p| p + 0.3).collect(),
            snr_db: Some(100.0),
            ..MeasuredMode::pole(
                s.freqs[k] + if k % 2 == 0 { 0.3 } else { -0.3 },
                s.decays[k] * if k % 2 == 0 { 1.25 } else { 0.8 },
            )
        })
        .collect();
    let problem = Problem::new(&signals, s.fs, &start, &settings).unwrap();
    let params = problem
        .initial_parameters(&signals, &start, &settings)
        .unwrap();
    let refined = problem
        .refine(&signals, &start, params, &settings, &mut |_| {})
        .unwrap();
    assert!(
        refined.loss < 0.1 * refined.history[0].loss,
        "{} → {}",
        refined.history[0].loss,
        refined.loss
    );
    let modes = problem.modes(&refined.params, &start);
    for k in 0..12 {
        let err = (modes[k].decay_rate / s.decays[k]).ln().abs();
        assert!(
            err < 0.02,
            "mode {k} at {} Hz: d {} vs {} (start {})",
            s.freqs[k],
            modes[k].decay_rate,
            s.decays[k],
            start[k].decay_rate
        );
    }
}

#[test]
fn estimate_after_the_skip_is_shifted_back_to_the_onset() {
    // No refinement: the modes are the estimate's, moved from t₀ = 50 ms to t = 0.
    let s = strike();
    let settings = DampingFitSettings {
        steps: 0,
        estimate_skip_s: 0.05,
        ..test_settings()
    };
    let fit = fit_damping(&s.channels, s.fs, &settings, |_| {}).unwrap();
    assert_eq!(fit.best_step, 0);
    assert_eq!(fit.loss_final, fit.history[0].loss);
    for k in 0..12 {
        let m = fit
            .modes
            .iter()
            .find(|m| (m.frequency_hz - s.freqs[k]).abs() < 0.1)
            .unwrap();
        for c in 0..2 {
            assert!(
                (m.amplitudes[c] / s.amps[k][c] - 1.0).abs() < 0.01,
                "mode {k} ch {c}: a {} vs {}",
                m.amplitudes[c],
                s.amps[k][c]
            );
            let dphi = wrap_phase(m.phases[c] - s.phases[k][c]);
            assert!(dphi.abs() < 0.01, "mode {k} ch {c}: φ off by {dphi}");
        }
    }
}

#[test]
fn bad_input_is_an_error() {
    let s = DampingFitSettings::default();
    let ok = vec![0.1; 4000];
    let none: Vec<Vec<f64>> = vec![];
    assert!(matches!(
        fit_damping(&none, 16e3, &s, |_| {}),
        Err(DampingError::NoChannels)
    ));
    assert!(matches!(
        fit_damping(&[Vec::<f64>::new()], 16e3, &s, |_| {}),
        Err(DampingError::EmptyChannels)
    ));
    assert!(matches!(
        fit_damping(&[ok.clone(), vec![0.1; 3999]], 16e3, &s, |_| {}),
        Err(DampingError::LengthMismatch { channel: 1, .. })
    ));
    let mut nan = ok.clone();
    nan[17] = f64::NAN;
    assert!(matches!(
        fit_damping(&[ok.clone(), nan], 16e3, &s, |_| {}),
        Err(DampingError::NonFiniteSample {
            channel: 1,
            index: 17,
            ..
        })
    ));
    for rate in [0.0, -1.0, f64::INFINITY, f64::NAN] {
        assert!(matches!(
            fit_damping(std::slice::from_ref(&ok), rate, &s, |_| {}),
            Err(DampingError::InvalidSampleRate { .. })
        ));
    }
    let skip_all = DampingFitSettings {
        estimate_skip_s: 1.0,
        ..DampingFitSettings::default()
    };
    assert!(matches!(
        fit_damping(std::slice::from_ref(&ok), 16e3, &skip_all, |_| {}),
        Err(DampingError::SkipTooLong { .. })
    ));
    for bad in [
        DampingFitSettings {
            max_modes: 0,
            ..DampingFitSettings::default()
        },
        DampingFitSettings {
            step_log_decay: f64::NAN,
            ..DampingFitSettings::default()
        },
        DampingFitSettings {
            final_step_fraction: 0.0,
            ..DampingFitSettings::default()
        },
        DampingFitSettings {
            min_decay_rate: -1.0,
            ..DampingFitSettings::default()
        },
        DampingFitSettings {
            max_decay_rate: 0.0,
            ..DampingFitSettings::default()
        },
        DampingFitSettings {
            duration_s: Some(-1.0),
            ..DampingFitSettings::default()
        },
        DampingFitSettings {
            noise_bands: 1,
            ..DampingFitSettings::default()
        },
    ] {
        assert!(
            matches!(
                fit_damping(std::slice::from_ref(&ok), 16e3, &bad, |_| {}),
                Err(DampingError::InvalidSetting { .. })
            ),
            "{bad:?}"
        );
    }
    // Silence has no modes: a clear error, not a panic.
    let silent = vec![vec![0.0; 8000]];
    let err = fit_damping(
        &silent,
        16e3,
        &DampingFitSettings {
            estimate_skip_s: 0.0,
            ..DampingFitSettings::default()
        },
        |_| {},
    );
    assert!(err.is_err(), "{err:?}");
}
