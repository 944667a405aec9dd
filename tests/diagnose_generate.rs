//! Smoke run of the benchmark generator `examples/diagnose_generate.rs` on a small plate
//! (1 rank, 4 cases, effects drawn from support contact and added mass: one clean case, one
//! with each effect alone, one with both): every file is there,
//! the metadata holds no labels, the labels parse for the scorer, and the hidden effects change
//! the sound as their physics says (added mass lowers the frequencies, the support's springs
//! raise them and its dashpots shorten the decays), measured in the written WAV files: the
//! labelled modes are spectral peaks of the recording and explain its start down to the noise,
//! while the same modes without the effects leave a residual many times larger.

mod common;
use common::*;
use diffsound::diagnose::inject::{CaseTruth, Effect};
use rustfft::num_complex::Complex64;
use std::process::Command;
use std::time::Duration;

const FS: f64 = 48_000.0;
const PRE_ROLL: f64 = 0.25;
const DURATION: f64 = 1.0;

/// Magnitude spectrum of `x` (Hann window, zero-padded 8×) and its bin width [Hz].
fn spectrum(x: &[f64]) -> (Vec<f64>, f64) {
    let n = (8 * x.len()).next_power_of_two();
    let mut buf: Vec<Complex64> = (0..n)
        .map(|i| {
            let v = if i < x.len() {
                x[i] * (0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / x.len() as f64).cos())
            } else {
                0.0
            };
            Complex64::new(v, 0.0)
        })
        .collect();
    rustfft::FftPlanner::<f64>::new()
        .plan_fft_forward(n)
        .process(&mut buf);
    (
        buf[..n / 2].iter().map(|v| v.norm()).collect(),
        FS / n as f64,
    )
}

/// The strongest spectral peak in [lo, hi] Hz (parabolic interpolation on ln|X|).
fn peak_in(spec: &(Vec<f64>, f64), lo: f64, hi: f64) -> (f64, f64) {
    let (mag, df) = spec;
    let (a, b) = (
        (lo / df).floor() as usize,
        ((hi / df).ceil() as usize).min(mag.len() - 2),
    );
    let k = (a.max(1)..=b)
        .max_by(|&i, &j| mag[i].total_cmp(&mag[j]))
        .unwrap();
    let (l, c, r) = (mag[k - 1].ln(), mag[k].ln(), mag[k + 1].ln());
    let offset = 0.5 * (l - r) / (l - 2.0 * c + r);
    ((k as f64 + offset) * df, mag[k])
}

/// RMS of the least-squares residual of `x` (sampled from t = 0) against damped sinusoids with
/// the given (frequency [Hz], decay [1/s]) and free amplitudes and phases.
fn modal_residual(x: &[f64], poles: &[(f64, f64)]) -> f64 {
    let a = nalgebra::DMatrix::from_fn(x.len(), 2 * poles.len(), |n, j| {
        let (f, d) = poles[j / 2];
        let t = n as f64 / FS;
        let phase = 2.0 * std::f64::consts::PI * f * t;
        (-d * t).exp() * if j % 2 == 0 { phase.cos() } else { phase.sin() }
    });
    let b = nalgebra::DVector::from_column_slice(x);
    let coef = a
        .clone()
        .svd(true, true)
        .solve(&b, 1e-12)
        .expect("svd solve");
    ((&a * coef - b).norm_squared() / x.len() as f64).sqrt()
}

#[test]
fn generator_writes_sealed_cases_whose_hidden_effects_change_the_sound() {
    let dir = scratch("diagnose_generate");
    let mesh_path = dir.join("plate.msh");
    // A free 300 × 200 × 20 mm plate, 6 × 4 × 1 cells (lifted to P2 by the generator).
    diffsound::mesh::write_msh22_ascii(
        &diffsound::mesh::box_mesh([6, 4, 1], [0.3, 0.2, 0.02]),
        &mesh_path,
    )
    .unwrap();
    let out = dir.join("bench");
    let mut cmd = Command::new("mpirun");
    cmd.args(["-np", "1"])
        .arg(generator())
        .args([
            "--cases",
            "4",
            "--seed",
            "5",
            "--mics",
            "3",
            "--effects",
            "support_contact,added_mass",
            "--mesh",
        ])
        .arg(&mesh_path)
        .arg("--out")
        .arg(&out);
    let t0 = std::time::Instant::now();
    let run = run_with_limit(cmd, Duration::from_secs(300));
    assert!(run.success(), "{}", run.describe());
    eprintln!(
        "{}generator: {:.1} s",
        run.stderr,
        t0.elapsed().as_secs_f64()
    );

    let listing = read_json(&out.join("cases.json"));
    let cases = listing["cases"].as_array().expect("cases");
    assert_eq!(cases.len(), 4);
    let mut seen = Vec::new();
    for (i, case) in cases.iter().enumerate() {
        let name = format!("case_{i:03}");
        assert_eq!(case["case"], name.as_str());
        assert!(
            case.get("effects").is_none(),
            "cases.json must not hold labels"
        );
        // Metadata: what a user knows, and nothing of the labels.
        let meta_text = std::fs::read_to_string(out.join(&name).join("metadata.toml")).unwrap();
        let meta: toml::Value = toml::from_str(&meta_text).expect("metadata.toml parses");
        for key in [
            "onset_time_s",
            "density_kg_m3",
            "sample_rate_hz",
            "microphone_positions_m",
            "support_direction",
            "strike",
            "mesh",
        ] {
            assert!(meta.get(key).is_some(), "{name}: metadata lacks {key}");
        }
        for secret in [
            "effect",
            "youngs",
            "poisson",
            "alpha",
            "beta",
            "gain",
            "snr",
            "support_contact",
            "added_mass",
        ] {
            assert!(
                !meta_text.to_lowercase().contains(secret),
                "{name}: metadata mentions {secret:?}"
            );
        }
        assert_eq!(meta["onset_time_s"].as_float(), Some(PRE_ROLL));
        assert_eq!(meta["microphone_positions_m"].as_array().unwrap().len(), 3);
        // Labels parse for the scorer and hold the truth.
        let labels = read_json(&out.join("labels").join(format!("{name}.json")));
        let truth: CaseTruth =
            serde_json::from_value(labels.clone()).expect("labels parse as CaseTruth");
        seen.push(truth.effects.iter().map(|e| e.effect).collect::<Vec<_>>());
        let modes = labels["modes"].as_array().unwrap();
        let base = f64s(&labels, "base_undamped_hz");
        assert!(modes.len() >= 3, "{name}: {} modes", modes.len());
        // WAVs: three 32-bit float channels of pre-roll + duration; the pre-roll is noise only.
        let mut channels = Vec::new();
        for c in 0..3 {
            let (ch, rate) =
                diffsound::audio::read_wav(&out.join(&name).join(format!("mic{c}.wav"))).unwrap();
            assert_eq!(rate, FS as u32);
            assert_eq!(ch[0].len(), ((PRE_ROLL + DURATION) * FS) as usize);
            channels.push(ch[0].clone());
        }
        let onset = (PRE_ROLL * FS) as usize;
        let pre = diffsound::audio::rms(&channels[0][..onset]);
        let strike = diffsound::audio::rms(&channels[0][onset..onset + 4800]);
        let noise_rms = labels["noise"]["rms"].as_f64().unwrap();
        assert!(
            (pre / noise_rms - 1.0).abs() < 0.1 && strike > 100.0 * pre,
            "{name}: pre-roll RMS {pre:e} (noise {noise_rms:e}), strike {strike:e}"
        );

        // The sound follows the labels: each of the three strongest modes (at mic 0) is a
        // spectral peak at its labelled frequency (within 0.05 % plus 15 % of its half-power
        // bandwidth d/π, since a heavily damped mode's peak is pulled by its neighbours;
        // searched over ±0.2 %). Where an
        // effect moved the mode by more than 0.6 %, the old frequency lies outside that window,
        // so the peak is the moved mode. (The k-th sorted eigenvalue only falls when mass is
        // added and only rises when springs are, by the min–max principle, so comparing sorted
        // lists index by index is sound.)
        let effects: Vec<Effect> = truth.effects.iter().map(|e| e.effect).collect();
        let spec = spectrum(&channels[0][onset..]);
        let mut order: Vec<usize> = (0..modes.len()).collect();
        let amp = |k: usize| modes[k]["amplitudes"][0].as_f64().unwrap();
        order.sort_by(|&a, &b| amp(b).total_cmp(&amp(a)));
        // (A mode the added mass pulled into the band from above has no counterpart before.)
        let index = |m: &serde_json::Value| m["index"].as_u64().unwrap() as usize;
        for &k in order
            .iter()
            .filter(|&&k| index(&modes[k]) < base.len())
            .take(3)
        {
            let m = &modes[k];
            let (f, fu, d) = (
                m["frequency_hz"].as_f64().unwrap(),
                m["undamped_hz"].as_f64().unwrap(),
                m["decay_rate"].as_f64().unwrap(),
            );
            let f_base = base[index(m)] * f / fu;
            let shift = f / f_base - 1.0;
            let (peak, _) = peak_in(&spec, f * 0.998, f * 1.002);
            eprintln!("{name} {effects:?}: mode {k} labelled {f:.2} Hz (before the FEM effects {f_base:.2} Hz, {:+.3} %), audio peak {peak:.2} Hz", 100.0 * shift);
            assert!(
                (peak - f).abs() < 0.0005 * f + 0.15 * d / std::f64::consts::PI,
                "{name}: mode {k} at {f} Hz (decay {d} 1/s), audio peak {peak}"
            );
            if shift.abs() > 0.006 {
                assert!((f_base - f).abs() > 0.002 * f);
            }
        }
        let shifts: Vec<f64> = modes
            .iter()
            .filter(|m| index(m) < base.len())
            .map(|m| m["undamped_hz"].as_f64().unwrap() / base[index(m)] - 1.0)
            .collect();
        let decays: Vec<f64> = modes
            .iter()
            .map(|m| m["decay_rate"].as_f64().unwrap())
            .collect();
        let (alpha, beta) = (
            labels["rayleigh_alpha"].as_f64().unwrap(),
            labels["rayleigh_beta"].as_f64().unwrap(),
        );
        let rayleigh = |m: &serde_json::Value| {
            0.5 * (alpha
                + beta * (2.0 * std::f64::consts::PI * m["undamped_hz"].as_f64().unwrap()).powi(2))
        };
        match effects.as_slice() {
            [] => assert!(
                shifts.iter().all(|s| *s == 0.0)
                    && modes
                        .iter()
                        .zip(&decays)
                        .all(|(m, d)| (d - rayleigh(m)).abs() < 1e-9 * d)
            ),
            [Effect::AddedMass] => {
                let worst = shifts.iter().fold(0.0f64, |a, s| a.min(*s));
                eprintln!(
                    "{name}: added mass lowers every mode, by up to {:.2} %",
                    -100.0 * worst
                );
                assert!(
                    shifts.iter().all(|s| *s < 0.0) && worst < -0.003,
                    "{shifts:?}"
                );
            }
            [Effect::SupportContact] => {
                let p = &truth.effects[0].parameters;
                assert_eq!(
                    p["support_modes_hz"].as_array().unwrap().len(),
                    6,
                    "six support modes dropped"
                );
                let extra: Vec<f64> = modes
                    .iter()
                    .zip(&decays)
                    .map(|(m, d)| d - rayleigh(m))
                    .collect();
                eprintln!("{name}: support raises the modes by {:.3}–{:.3} % and adds {:.1}–{:.1} 1/s of decay", 100.0 * shifts.iter().cloned().fold(f64::INFINITY, f64::min), 100.0 * shifts.iter().cloned().fold(0.0, f64::max), extra.iter().cloned().fold(f64::INFINITY, f64::min), extra.iter().cloned().fold(0.0, f64::max));
                assert!(shifts.iter().all(|s| *s >= 0.0) && extra.iter().all(|e| *e > 0.0));
            }
            [Effect::SupportContact, Effect::AddedMass] => {
                assert!(shifts.iter().any(|s| s.abs() > 0.003), "{shifts:?}")
            }
            other => panic!("{name}: unexpected effects {other:?}"),
        }
        // The labelled modes explain the first 0.2 s of the sound down to the noise; the same
        // modes without the effects (Rayleigh decays, frequencies before the FEM effects) do not.
        let window = &channels[0][onset..onset + (0.2 * FS) as usize];
        let labelled: Vec<(f64, f64)> = modes
            .iter()
            .map(|m| {
                (
                    m["frequency_hz"].as_f64().unwrap(),
                    m["decay_rate"].as_f64().unwrap(),
                )
            })
            .collect();
        let fit = modal_residual(window, &labelled);
        eprintln!("{name}: residual of the labelled modes {fit:.3e}, noise RMS {noise_rms:.3e}, signal RMS {:.3e}", diffsound::audio::rms(window));
        assert!(
            fit < 1.5 * noise_rms,
            "{name}: the labelled modes leave {fit:e} (noise {noise_rms:e})"
        );
        if !effects.is_empty() {
            let without: Vec<(f64, f64)> = modes
                .iter()
                .filter(|m| index(m) < base.len())
                .map(|m| {
                    let (omega, d) = (2.0 * std::f64::consts::PI * base[index(m)], rayleigh(m));
                    (
                        (omega * omega - d * d).sqrt() / (2.0 * std::f64::consts::PI),
                        d,
                    )
                })
                .collect();
            let unexplained = modal_residual(window, &without);
            eprintln!(
                "{name}: residual without the effects {unexplained:.3e} ({:.0}× the labelled)",
                unexplained / fit
            );
            assert!(
                unexplained > 10.0 * fit,
                "{name}: the effects barely change the sound ({unexplained:e} vs {fit:e})"
            );
        }
    }
    seen.sort();
    assert_eq!(
        seen,
        vec![
            vec![],
            vec![Effect::SupportContact],
            vec![Effect::SupportContact, Effect::AddedMass],
            vec![Effect::AddedMass]
        ],
        "the case mix"
    );
}
