use super::*;
use crate::io::test_support::TempDir;
use std::f64::consts::PI;
use std::fs;
use std::path::PathBuf;

fn bank(modes: &[(f64, f64, f64, f64)]) -> ModalBank {
    ModalBank {
        frequencies_hz: modes.iter().map(|m| m.0).collect(),
        decay_rates: modes.iter().map(|m| m.1).collect(),
        amplitudes: modes.iter().map(|m| m.2).collect(),
        phases: modes.iter().map(|m| m.3).collect(),
    }
}

#[test]
fn rayleigh_decay_and_damped_frequency_follow_the_formulas() {
    let (alpha, beta, omega) = (4.0, 2e-7, 2.0 * PI * 1000.0);
    let d = rayleigh_decay(omega, alpha, beta);
    assert!((d - (alpha + beta * omega * omega) / 2.0).abs() < 1e-12);
    let zeta = d / omega;
    let wd = damped_frequency(omega, alpha, beta).unwrap();
    assert!((wd - omega * (1.0 - zeta * zeta).sqrt()).abs() < 1e-9);
    assert!(wd < omega);
    // ζ = 1 exactly (α = 2ω, β = 0) and beyond: overdamped.
    assert_eq!(damped_frequency(10.0, 20.0, 0.0), None);
    assert_eq!(damped_frequency(10.0, 0.0, 1.0), None);
    assert_eq!(damped_frequency(0.0, 0.0, 0.0), None);
    assert_eq!(damped_frequency(5.0, 0.0, 0.0), Some(5.0));
}

#[test]
fn bank_from_eigenvalues_drops_overdamped_and_non_positive_modes() {
    let beta = 1e-4; // ζ = βω/2 ≥ 1 once ω ≥ 2e4 rad/s
    let eig = [-1.0, 1e6, 1e8, 1e9]; // ω = –, 1e3, 1e4, 3.16e4
    let b = ModalBank::from_eigenvalues(&eig, &[1.0, 2.0, 3.0, 4.0], 0.0, beta);
    assert_eq!(b.len(), 2);
    assert_eq!(b.amplitudes, [2.0, 3.0]);
    assert_eq!(b.decay_rates[0], rayleigh_decay(1e3, 0.0, beta));
    assert!(
        (b.frequencies_hz[1] - damped_frequency(1e4, 0.0, beta).unwrap() / (2.0 * PI)).abs()
            < 1e-12
    );
    assert_eq!(b.phases, [0.0, 0.0]);
}

#[test]
fn render_matches_direct_evaluation_over_6_s_at_48_khz() {
    let fs = 48_000.0;
    let modes = [
        (123.456, 0.5, 0.8, 0.3),
        (1234.5, 3.0, 0.5, -1.2),
        (7777.7, 10.0, 0.25, 2.0),
        (19_999.9, 1.0, 0.1, 0.0),
        (23_999.0, 0.0, 0.05, 1.0),
    ];
    let b = bank(&modes);
    let s = render(&b, fs, 6.0);
    assert_eq!(s.len(), 288_000);
    let total_amplitude: f64 = modes.iter().map(|m| m.2).sum();
    let mut max_err: f64 = 0.0;
    for (n, &v) in s.iter().enumerate() {
        let t = n as f64 / fs;
        let direct: f64 = modes
            .iter()
            .map(|&(f, d, a, p)| a * (-d * t).exp() * (2.0 * PI * f * t + p).sin())
            .sum();
        max_err = max_err.max((v - direct).abs());
    }
    eprintln!("render vs direct, 6 s @ 48 kHz: max abs error {max_err:.2e} (sum of amplitudes {total_amplitude})");
    assert!(max_err < 1e-9 * total_amplitude, "max error {max_err}");
}

#[test]
fn render_does_not_drift_over_ten_minutes() {
    // f/fs = 1234.5/48000 = 2469/96_000 exactly, so the reference phase is computable in
    // integers: no floating-point phase error in the reference at all.
    let fs = 48_000.0;
    let (f, d, a, phi) = (1234.5, 0.005, 1.0, 0.7);
    let s = render(&bank(&[(f, d, a, phi)]), fs, 600.0);
    assert_eq!(s.len(), 28_800_000);
    let mut max_rel: f64 = 0.0;
    for n in (0..s.len()).step_by(97).chain(s.len() - 2000..s.len()) {
        let cycles = ((n as u64 * 2469) % 96_000) as f64 / 96_000.0;
        let envelope = a * (-d * n as f64 / fs).exp();
        let reference = envelope * (2.0 * PI * cycles + phi).sin();
        max_rel = max_rel.max((s[n] - reference).abs() / envelope);
    }
    eprintln!("render drift over 600 s: max error relative to envelope {max_rel:.2e}");
    assert!(max_rel < 1e-11, "drift {max_rel}");
}

#[test]
fn modes_outside_zero_to_nyquist_are_skipped() {
    let s = render(
        &bank(&[
            (24_000.0, 0.0, 1.0, 0.5),
            (30_000.0, 0.0, 1.0, 0.5),
            (-5.0, 0.0, 1.0, 0.5),
            (f64::NAN, 0.0, 1.0, 0.5),
        ]),
        48_000.0,
        0.1,
    );
    assert_eq!(s.len(), 4800);
    assert!(s.iter().all(|&v| v == 0.0));
    assert!(render(&ModalBank::default(), 48_000.0, -1.0).is_empty());
}

#[test]
#[should_panic(expected = "differ in length")]
fn render_rejects_ragged_banks() {
    let mut b = bank(&[(100.0, 1.0, 1.0, 0.0)]);
    b.phases.clear();
    render(&b, 8000.0, 0.01);
}

#[test]
fn single_mode_spectrum_peaks_at_its_frequency() {
    let (fs, f) = (8000.0, 443.0);
    let s = render(&bank(&[(f, 2.0, 1.0, 0.4)]), fs, 0.5);
    let n = s.len();
    // Plain DFT magnitude over the non-negative bins; bin spacing fs/n = 2 Hz.
    let magnitude = |k: usize| {
        let (mut re, mut im) = (0.0, 0.0);
        for (j, &v) in s.iter().enumerate() {
            let w = -2.0 * PI * (k * j % n) as f64 / n as f64;
            re += v * w.cos();
            im += v * w.sin();
        }
        re.hypot(im)
    };
    let peak = (0..=n / 2)
        .max_by(|&a, &b| magnitude(a).total_cmp(&magnitude(b)))
        .unwrap();
    let peak_hz = peak as f64 * fs / n as f64;
    assert!(
        (peak_hz - f).abs() <= fs / n as f64,
        "peak at {peak_hz} Hz, expected {f} Hz"
    );
}

#[test]
fn wav_round_trip_for_each_format() {
    let dir = TempDir::new("roundtrip");
    let fs = 48_000;
    let signal = render(
        &bank(&[(440.0, 3.0, 0.6, 0.0), (1320.0, 8.0, 0.3, 1.0)]),
        fs as f64,
        0.25,
    );
    for (format, name, tol) in [
        (WavFormat::Pcm16, "a16.wav", 0.5 / 32768.0 + 1e-12),
        (WavFormat::Float32, "af.wav", 1e-7),
    ] {
        let path = dir.path(name);
        write_wav(&path, &signal, fs, format, None).unwrap();
        let (channels, rate) = read_wav(&path).unwrap();
        assert_eq!((channels.len(), rate), (1, fs));
        assert_eq!(channels[0].len(), signal.len());
        let err = signal
            .iter()
            .zip(&channels[0])
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(err <= tol, "{format:?}: round-trip error {err}");
    }
    // Normalisation puts the peak where asked.
    let path = dir.path("norm.wav");
    write_wav(&path, &signal, fs, WavFormat::Float32, Some(0.5)).unwrap();
    let peak = read_wav(&path).unwrap().0[0]
        .iter()
        .fold(0.0_f64, |m, v| m.max(v.abs()));
    assert!((peak - 0.5).abs() < 1e-7, "peak {peak}");
    // PCM saturates instead of wrapping around.
    let path = dir.path("clip.wav");
    write_wav(&path, &[2.0, -2.0, 1.0], fs, WavFormat::Pcm16, None).unwrap();
    assert_eq!(
        read_wav(&path).unwrap().0[0],
        [32767.0 / 32768.0, -1.0, 32767.0 / 32768.0]
    );
    assert_eq!(
        dir.entries(),
        ["a16.wav", "af.wav", "clip.wav", "norm.wav"],
        "no temporaries left"
    );
}

#[test]
fn read_wav_handles_24_and_32_bit_int_and_multichannel() {
    let dir = TempDir::new("formats");
    for bits in [8u16, 24, 32] {
        let path = dir.path(&format!("s{bits}.wav"));
        let spec = hound::WavSpec {
            channels: 2,
            sample_rate: 44_100,
            bits_per_sample: bits,
            sample_format: hound::SampleFormat::Int,
        };
        let full = 1i64 << (bits - 1);
        let mut w = hound::WavWriter::create(&path, spec).unwrap();
        for (l, r) in [(0i64, -full), (full / 2, full - 1), (-full / 4, 1)] {
            w.write_sample(l as i32).unwrap();
            w.write_sample(r as i32).unwrap();
        }
        w.finalize().unwrap();
        let (ch, rate) = read_wav(&path).unwrap();
        assert_eq!(rate, 44_100);
        let step = 1.0 / full as f64;
        assert_eq!(ch[0], [0.0, 0.5, -0.25], "{bits}-bit left");
        assert_eq!(ch[1], [-1.0, 1.0 - step, step], "{bits}-bit right");
    }
}

#[test]
fn corrupt_or_truncated_wav_is_a_clear_error() {
    let dir = TempDir::new("corrupt");
    let good = dir.path("good.wav");
    write_wav(&good, &vec![0.25; 1000], 8000, WavFormat::Pcm16, None).unwrap();
    let bytes = fs::read(&good).unwrap();

    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("empty.wav", Vec::new()),
        ("garbage.wav", b"definitely not a RIFF file at all".to_vec()),
        ("header_only.wav", bytes[..30].to_vec()),
        ("truncated_data.wav", bytes[..bytes.len() / 2].to_vec()),
        ("half_sample.wav", bytes[..bytes.len() - 1].to_vec()),
    ];
    for (name, content) in cases {
        let path = dir.path(name);
        fs::write(&path, content).unwrap();
        let err = read_wav(&path).expect_err(name);
        let msg = err.to_string();
        assert!(msg.contains(name), "error does not name the file: {msg}");
        eprintln!("{msg}");
    }
    let err = read_wav(&dir.path("missing.wav")).unwrap_err();
    assert!(err.to_string().contains("missing.wav"));
}

#[test]
fn a_float_wav_with_nan_or_inf_is_refused_naming_the_first_sample() {
    let dir = TempDir::new("nonfinite");
    let path = dir.path("nan.wav");
    let spec = hound::WavSpec {
        channels: 2,
        sample_rate: 1000,
        bits_per_sample: 32,
        sample_format: hound::SampleFormat::Float,
    };
    let mut w = hound::WavWriter::create(&path, spec).unwrap();
    for k in 0..100 {
        w.write_sample(0.1f32).unwrap();
        // Channel 1 turns NaN at frame 25 and infinite at frame 60.
        let right = match k {
            25 => f32::NAN,
            60 => f32::INFINITY,
            _ => -0.1,
        };
        w.write_sample(right).unwrap();
    }
    w.finalize().unwrap();
    let err = read_wav(&path).unwrap_err();
    let msg = err.to_string();
    assert!(
        matches!(
            err,
            AudioError::NonFinite {
                count: 2,
                frame: 25,
                channel: 1,
                ..
            }
        ),
        "{msg}"
    );
    assert!(
        msg.contains("nan.wav") && msg.contains("(NaN) at sample 25 of channel 1 (0.025000 s)"),
        "{msg}"
    );
}

#[test]
fn write_wav_refuses_bad_input_and_leaves_nothing() {
    let dir = TempDir::new("badwrite");
    let path = dir.path("x.wav");
    for (samples, rate, peak) in [
        (vec![0.0, f64::NAN], 8000, None),
        (vec![0.1], 0, None),
        (vec![0.1], 8000, Some(-1.0)),
    ] {
        let err = write_wav(&path, &samples, rate, WavFormat::Float32, peak).unwrap_err();
        assert!(
            matches!(err, AudioError::InvalidInput { .. }) && err.to_string().contains("x.wav"),
            "{err}"
        );
    }
    // Unwritable destination: the temporary cannot be created either.
    let err = write_wav(
        &dir.path("no/such/dir/y.wav"),
        &[0.0],
        8000,
        WavFormat::Pcm16,
        None,
    )
    .unwrap_err();
    assert!(err.to_string().contains("y.wav"), "{err}");
    assert!(dir.entries().is_empty(), "left: {:?}", dir.entries());
}

#[test]
fn reads_the_real_bowl_recording() {
    let shared = std::env::var_os("DIFFSOUND_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/work/shared"));
    let path = shared.join("data/bowl/mic0.wav");
    if !path.exists() {
        eprintln!("note: {} not present, skipping", path.display());
        return;
    }
    let (channels, rate) = read_wav(&path).unwrap();
    assert_eq!(rate, 48_000);
    assert_eq!(channels.len(), 1);
    assert_eq!(channels[0].len(), 288_000);
    let peak = channels[0].iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    assert!(peak > 0.0 && peak <= 1.0, "peak {peak}");
}

#[test]
fn threaded_synthesis_and_gradient_equal_the_single_threaded_ones() {
    let n = 37; // not a multiple of the lane width
    let b = ModalBank {
        frequencies_hz: (0..n).map(|k| 50.0 + 311.7 * k as f64).collect(),
        decay_rates: (0..n).map(|k| 1.0 + 0.5 * k as f64).collect(),
        amplitudes: (0..n)
            .map(|k| if k == 5 { 0.0 } else { 1.0 / (1.0 + k as f64) })
            .collect(),
        phases: (0..n).map(|k| 0.1 * k as f64).collect(),
    };
    let g: Vec<f64> = (0..5000)
        .map(|i| ((i * 7919) % 101) as f64 / 101.0 - 0.5)
        .collect();
    synth::set_worker_threads(1);
    let one = (
        synth::render_samples(&b, 32000.0, 5000),
        synth::render_backward(&b, 32000.0, &g),
    );
    synth::set_worker_threads(3);
    let three = (
        synth::render_samples(&b, 32000.0, 5000),
        synth::render_backward(&b, 32000.0, &g),
    );
    synth::set_worker_threads(0);
    let worst = one
        .0
        .iter()
        .zip(&three.0)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-13, "signals differ by {worst}");
    assert_eq!(
        one.1, three.1,
        "per-mode gradients do not depend on the thread split"
    );
    assert!(
        one.1.amplitudes[5] != 0.0,
        "a silent mode still has an amplitude gradient"
    );
}
