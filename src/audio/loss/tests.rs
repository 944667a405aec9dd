use super::*;
use crate::audio::synth::{render_backward, render_samples, ModalBank};

/// `n` values uniform in [−1, 1) from a seeded generator.
fn uniform_noise(seed: u64, n: usize) -> Vec<f64> {
    crate::testing::Rng(seed).uniform_vec(n, -1.0, 1.0)
}

fn tone(freq: f64, decay: f64, amplitude: f64) -> ModalBank {
    ModalBank {
        frequencies_hz: vec![freq],
        decay_rates: vec![decay],
        amplitudes: vec![amplitude],
        phases: vec![0.3],
    }
}

fn bank(seed: u64, n: usize) -> ModalBank {
    let r = uniform_noise(seed, 4 * n);
    ModalBank {
        frequencies_hz: (0..n)
            .map(|k| 200.0 + 3000.0 * (0.5 + 0.5 * r[4 * k]))
            .collect(),
        decay_rates: (0..n)
            .map(|k| 5.0 + 10.0 * (0.5 + 0.5 * r[4 * k + 1]))
            .collect(),
        amplitudes: (0..n).map(|k| 0.2 + 0.3 * r[4 * k + 2].abs()).collect(),
        phases: (0..n).map(|k| 3.0 * r[4 * k + 3]).collect(),
    }
}

const FS: f64 = 8000.0;
const LEN: usize = 3000;

/// A loss on a signal: its value and its gradient with respect to the samples.
type LossFn<'a> = dyn Fn(&[f64]) -> (f64, Vec<f64>) + 'a;

/// Mutable access to one parameter field of a bank.
type BankField = fn(&mut ModalBank) -> &mut Vec<f64>;

/// Central differences of a loss through the synthesiser, parameter by parameter.
fn check_bank_gradient(name: &str, loss: &LossFn, b: &ModalBank, tol: f64) {
    let (_, g_signal) = loss(&render_samples(b, FS, LEN));
    let g = render_backward(b, FS, &g_signal);
    let value = |b: &ModalBank| loss(&render_samples(b, FS, LEN)).0;
    let fields: [(&str, BankField, &Vec<f64>, f64); 4] = [
        (
            "frequency",
            |b| &mut b.frequencies_hz,
            &g.frequencies_hz,
            1e-4,
        ),
        ("decay", |b| &mut b.decay_rates, &g.decay_rates, 1e-4),
        ("amplitude", |b| &mut b.amplitudes, &g.amplitudes, 1e-6),
        ("phase", |b| &mut b.phases, &g.phases, 1e-6),
    ];
    for (field, get, exact, h) in fields {
        let scale = exact.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        // Index loop: k indexes the perturbed copies' field and the exact gradient together.
        #[allow(clippy::needless_range_loop)]
        for k in 0..b.len() {
            let (mut p, mut m) = (b.clone(), b.clone());
            get(&mut p)[k] += h;
            get(&mut m)[k] -= h;
            let fd = (value(&p) - value(&m)) / (2.0 * h);
            assert!(
                (fd - exact[k]).abs() <= tol * scale,
                "{name}: d/d{field}_{k}: fd {fd} vs exact {} (scale {scale})",
                exact[k]
            );
        }
    }
}

#[test]
fn spectral_loss_gradient_matches_finite_differences_through_the_synthesiser() {
    let target = render_samples(&bank(1, 4), FS, LEN);
    let config = SpectralLossConfig {
        fft_sizes: vec![512, 128, 64],
        ..Default::default()
    };
    let loss = MultiScaleSpectralLoss::new(&target, config).unwrap();
    check_bank_gradient(
        "spectral",
        &|x| loss.value_and_gradient(x).unwrap(),
        &bank(2, 4),
        2e-4,
    );
}

#[test]
fn transport_loss_gradient_matches_finite_differences_through_the_synthesiser() {
    let target = render_samples(&bank(3, 3), FS, LEN);
    let loss = TransportLoss::new(
        &target,
        FS,
        TransportLossConfig {
            fft_size: 256,
            ..Default::default()
        },
    )
    .unwrap();
    check_bank_gradient(
        "transport",
        &|x| loss.value_and_gradient(x).unwrap(),
        &bank(4, 3),
        2e-4,
    );
}

#[test]
fn loss_gradients_with_respect_to_the_signal_match_finite_differences() {
    let target: Vec<f64> = render_samples(&bank(5, 3), FS, 700)
        .iter()
        .zip(uniform_noise(6, 700))
        .map(|(s, n)| s + 0.01 * n)
        .collect();
    let x: Vec<f64> = render_samples(&bank(7, 3), FS, 700)
        .iter()
        .zip(uniform_noise(8, 700))
        .map(|(s, n)| s + 0.01 * n)
        .collect();
    let spectral = MultiScaleSpectralLoss::new(
        &target,
        SpectralLossConfig {
            fft_sizes: vec![256, 64],
            ..Default::default()
        },
    )
    .unwrap();
    let transport = TransportLoss::new(
        &target,
        FS,
        TransportLossConfig {
            fft_size: 128,
            ..Default::default()
        },
    )
    .unwrap();
    let losses: [(&str, Box<LossFn>); 2] = [
        (
            "spectral",
            Box::new(|x| spectral.value_and_gradient(x).unwrap()),
        ),
        (
            "transport",
            Box::new(|x| transport.value_and_gradient(x).unwrap()),
        ),
    ];
    for (name, loss) in &losses {
        let (v, g) = loss(&x);
        assert!(v > 0.0);
        let scale = g.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        let h = 1e-8;
        for i in (0..x.len()).step_by(37) {
            let (mut p, mut m) = (x.clone(), x.clone());
            p[i] += h;
            m[i] -= h;
            let fd = (loss(&p).0 - loss(&m).0) / (2.0 * h);
            assert!(
                (fd - g[i]).abs() < 1e-5 * scale,
                "{name} sample {i}: fd {fd} vs {}",
                g[i]
            );
        }
    }
}

#[test]
fn identical_signals_score_zero_and_length_mismatch_is_an_error() {
    let y = render_samples(&bank(9, 3), FS, LEN);
    let s = MultiScaleSpectralLoss::new(&y, SpectralLossConfig::default()).unwrap();
    let t = TransportLoss::new(&y, FS, TransportLossConfig::default()).unwrap();
    assert_eq!(s.value(&y).unwrap(), 0.0);
    assert!(t.value(&y).unwrap().abs() < 1e-12);
    assert_eq!(
        s.value(&y[1..]).unwrap_err(),
        LossError::Length {
            got: LEN - 1,
            expected: LEN
        }
    );
    assert!(matches!(t.value(&[]), Err(LossError::Length { .. })));
    assert_eq!(
        MultiScaleSpectralLoss::new(&[], SpectralLossConfig::default()).unwrap_err(),
        LossError::EmptyTarget
    );
    assert_eq!(
        MultiScaleSpectralLoss::new(&[0.0, f64::NAN], SpectralLossConfig::default()).unwrap_err(),
        LossError::NonFinite(1)
    );
    assert!(
        TransportLoss::new(&vec![0.0; 100], FS, TransportLossConfig::default()).is_err(),
        "silent target"
    );
    assert!(MultiScaleSpectralLoss::new(
        &y,
        SpectralLossConfig {
            fft_sizes: vec![100, 63],
            ..Default::default()
        }
    )
    .is_err());
    assert!(MultiScaleSpectralLoss::new(
        &y,
        SpectralLossConfig {
            hop_fraction: 0.0,
            ..Default::default()
        }
    )
    .is_err());
}

#[test]
fn transport_loss_measures_the_frequency_gap_in_hz() {
    // Two steady tones, bin-centred: W1 ≈ |f1 − f2| when all mass has to move.
    let n_fft = 512;
    let bin = FS / n_fft as f64;
    let target = render_samples(&tone(100.0 * bin, 0.0, 1.0), FS, 8000);
    let loss = TransportLoss::new(
        &target,
        FS,
        TransportLossConfig {
            fft_size: n_fft,
            ..Default::default()
        },
    )
    .unwrap();
    for gap_bins in [5.0, 40.0, 120.0] {
        let x = render_samples(&tone((100.0 + gap_bins) * bin, 0.0, 1.0), FS, 8000);
        let w = loss.value(&x).unwrap();
        let gap = gap_bins * bin;
        assert!((w - gap).abs() < 0.01 * gap, "gap {gap} Hz: W1 = {w}");
    }
}

/// Adam on one frequency, the way the fits move parameters.
fn descend(loss: &LossFn, start_hz: f64, steps: usize, rate_hz: f64) -> f64 {
    let (mut f, mut m, mut v) = (start_hz, 0.0, 0.0);
    let (b1, b2) = (0.9, 0.999);
    for t in 1..=steps {
        let b = tone(f, 4.0, 1.0);
        let (_, g_signal) = loss(&render_samples(&b, FS, LEN));
        let g = render_backward(&b, FS, &g_signal).frequencies_hz[0];
        m = b1 * m + (1.0 - b1) * g;
        v = b2 * v + (1.0 - b2) * g * g;
        let m_hat = m / (1.0 - b1.powi(t as i32));
        let v_hat = v / (1.0 - b2.powi(t as i32));
        f -= rate_hz * m_hat / (v_hat.sqrt() + 1e-30);
    }
    f
}

#[test]
fn transport_pulls_a_distant_mode_to_its_target_where_the_spectral_loss_does_not() {
    let target_hz = 2000.0;
    let target = render_samples(&tone(target_hz, 4.0, 1.0), FS, LEN);
    let spectral = MultiScaleSpectralLoss::new(&target, SpectralLossConfig::default()).unwrap();
    let transport = TransportLoss::new(
        &target,
        FS,
        TransportLossConfig {
            fft_size: 512,
            ..Default::default()
        },
    )
    .unwrap();
    let start = 1000.0;
    let by_transport = descend(
        &|x| transport.value_and_gradient(x).unwrap(),
        start,
        300,
        10.0,
    );
    let by_spectral = descend(
        &|x| spectral.value_and_gradient(x).unwrap(),
        start,
        300,
        10.0,
    );
    eprintln!("from {start} Hz to {target_hz} Hz: transport ends at {by_transport:.2} Hz, spectral at {by_spectral:.2} Hz");
    assert!(
        (by_transport - target_hz).abs() < 5.0,
        "transport ended at {by_transport} Hz"
    );
    assert!(
        (by_spectral - target_hz).abs() > 500.0,
        "spectral ended at {by_spectral} Hz"
    );
}

#[test]
fn hybrid_schedule_switches_once_after_a_plateau() {
    let mut s = HybridSchedule::new(3, 0.01);
    assert_eq!(s.phase(), LossPhase::Transport);
    for loss in [10.0, 8.0, 6.0, 5.0] {
        assert_eq!(s.observe(loss), LossPhase::Transport);
    }
    // Less than 1 % better three times in a row: switch.
    assert_eq!(s.observe(4.99), LossPhase::Transport);
    assert_eq!(s.observe(4.98), LossPhase::Transport);
    assert_eq!(s.observe(4.985), LossPhase::Spectral);
    assert_eq!(s.switched_at(), Some(7));
    // For good: later transport-like values do not switch back.
    assert_eq!(s.observe(100.0), LossPhase::Spectral);
    let mut fixed = HybridSchedule::fixed(LossPhase::Spectral);
    assert_eq!(fixed.observe(1.0), LossPhase::Spectral);
}
