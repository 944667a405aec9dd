use super::*;
use crate::mesh::box_mesh;

#[test]
fn hertz_spectrum_matches_the_fft_of_the_sampled_pulse() {
    for tau in [0.05e-3, 0.3e-3, 0.6e-3] {
        let pulse = HertzPulse::new(tau).unwrap();
        // Unit area (F̃(0) = 1) and the closed-form shape area.
        assert!((pulse.laplace(Complex64::new(0.0, 0.0)).re - 1.0).abs() < 1e-12);
        let (nodes, weights) = crate::fem::quadrature::gauss_legendre_01(40);
        let plain: f64 = nodes
            .iter()
            .zip(&weights)
            .map(|(u, w)| w * (PI * u).sin().powf(1.5))
            .sum();
        assert!(
            (plain - HERTZ_SHAPE_AREA).abs() < 2e-5,
            "plain Gauss–Legendre {plain}"
        );
        // The pulse sampled at 4096 points over T and zero-padded to N: X[k]·dt ≈ F̃(iω_k),
        // a Riemann sum accurate to ~5e-10 here (the sampled
        // function vanishes smoothly, like t^(3/2), at both ends).
        let n_pulse = 4096;
        let dt = tau / n_pulse as f64;
        let n = 1 << 18;
        let mut buf: Vec<Complex64> = (0..n)
            .map(|i| {
                Complex64::new(
                    if i <= n_pulse {
                        pulse.force(i as f64 * dt)
                    } else {
                        0.0
                    },
                    0.0,
                )
            })
            .collect();
        rustfft::FftPlanner::<f64>::new()
            .plan_fft_forward(n)
            .process(&mut buf);
        for f in [100.0, 1000.0, 3000.0, 7000.0, 12000.0, 20000.0] {
            let k = (f * n as f64 * dt).round() as usize;
            let omega = 2.0 * PI * k as f64 / (n as f64 * dt);
            let fft = buf[k] * dt;
            let quad = pulse.laplace(Complex64::new(0.0, omega));
            assert!(
                (fft - quad).norm() < 1e-8,
                "T {tau} f {f}: fft {fft} quad {quad}"
            );
        }
        // Damped poles: against a fine midpoint sum of the same integral.
        let s = Complex64::new(-40.0, 2.0 * PI * 5000.0);
        let m = 200_000;
        let mid: Complex64 = (0..m)
            .map(|i| (i as f64 + 0.5) * tau / m as f64)
            .map(|t| (-s * t).exp() * pulse.force(t))
            .sum::<Complex64>()
            * (tau / m as f64);
        assert!(
            (mid - pulse.laplace(s)).norm() < 1e-8,
            "{mid} vs {}",
            pulse.laplace(s)
        );
    }
    // A low pass: longer contacts suppress a high mode more.
    let short = HertzPulse::new(0.05e-3)
        .unwrap()
        .laplace(Complex64::new(0.0, 2.0 * PI * 8000.0))
        .norm();
    let long = HertzPulse::new(0.6e-3)
        .unwrap()
        .laplace(Complex64::new(0.0, 2.0 * PI * 8000.0))
        .norm();
    assert!(short > 0.8 && short < 1.0 && long < 0.05, "{short} {long}");
    assert!(HertzPulse::new(0.0).is_err() && HertzPulse::new(f64::NAN).is_err());
}

#[test]
fn glide_render_matches_a_reference_integration_and_reduces_to_the_synthesiser() {
    let fs = 48_000.0;
    let n = 9600;
    let tracks = vec![
        ModeTrack {
            frequency_hz: 1234.5,
            decay_rate: 6.0,
            amplitudes: vec![Complex64::new(0.3, -0.2), Complex64::new(-0.1, 0.05)],
        },
        ModeTrack {
            frequency_hz: 7010.0,
            decay_rate: 40.0,
            amplitudes: vec![Complex64::new(0.0, 0.5), Complex64::new(0.2, 0.2)],
        },
    ];
    // g = 0 is the synthesiser's bank.
    let plain = render_tracks(&tracks, 2, fs, n, None).unwrap();
    let zero = render_tracks(&tracks, 2, fs, n, Some(0.0)).unwrap();
    for c in 0..2 {
        let err = plain[c]
            .iter()
            .zip(&zero[c])
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(err < 1e-9, "channel {c}: {err}");
    }
    // Small g: the phase from a fine trapezoid integration of 2π f(t) (64 sub-steps per
    // sample), against the closed form.
    let g = 0.002;
    let glided = render_tracks(&tracks, 2, fs, n, Some(g)).unwrap();
    let sub = 64;
    let h = 1.0 / (fs * sub as f64);
    let mut reference = vec![vec![0.0; n]; 2];
    for t in &tracks {
        let freq = |time: f64| t.frequency_hz * (1.0 + g * (-2.0 * t.decay_rate * time).exp());
        let mut theta = 0.0;
        for i in 0..n {
            let time = i as f64 / fs;
            let env = (-t.decay_rate * time).exp();
            for (ch, z) in reference.iter_mut().zip(&t.amplitudes) {
                ch[i] += env * (z * Complex64::new(0.0, theta).exp()).im;
            }
            for j in 0..sub {
                let t0 = time + j as f64 * h;
                theta += PI * h * (freq(t0) + freq(t0 + h));
            }
        }
    }
    for c in 0..2 {
        let err = glided[c]
            .iter()
            .zip(&reference[c])
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        let diff = glided[c]
            .iter()
            .zip(&plain[c])
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(err < 1e-6, "channel {c}: closed form vs integration {err}");
        assert!(
            diff > 1e-3,
            "channel {c}: the glide must change the sound ({diff})"
        );
    }
    // The instantaneous frequency of the phase: f₀(1 + g) at the start, f₀ late.
    let (f0, d) = (1000.0, 5.0);
    let dphi = |t: f64| {
        (glide_phase(f0, d, g, t + 1e-6) - glide_phase(f0, d, g, t - 1e-6)) / (2e-6 * 2.0 * PI)
    };
    assert!((dphi(1e-6) / f0 - 1.0 - g).abs() < 1e-6 && (dphi(2.0) / f0 - 1.0).abs() < 1e-6);
    assert!((glide_phase(f0, 0.0, g, 0.5) - 2.0 * PI * f0 * (1.0 + g) * 0.5).abs() < 1e-9);
    assert!(render_tracks(&tracks, 3, fs, n, Some(g)).is_err());
}

#[test]
fn room_response_has_the_requested_decay_and_direct_to_reverberant_ratio() {
    let fs = 48_000.0;
    for (i, &(t60, drr)) in [(0.2, 0.0), (0.5, 7.0), (1.0, 15.0)].iter().enumerate() {
        let room = RoomResponse {
            t60_s: t60,
            direct_to_reverberant_db: drr,
            predelay_s: 0.004,
        };
        let h = room
            .impulse_response(fs, 10 * fs as usize, &mut SplitMix64::new(40 + i as u64))
            .unwrap();
        let start = (0.004 * fs) as usize;
        assert_eq!(h[1..start].iter().filter(|v| **v != 0.0).count(), 0);
        let tail: f64 = h[start..].iter().map(|v| v * v).sum();
        assert!((10.0 * (1.0 / tail).log10() - drr).abs() < 1e-9);
        let measured = schroeder_t60(&h, fs, start, -5.0, -35.0).unwrap();
        assert!(
            (measured / t60 - 1.0).abs() < 0.05,
            "T60 {t60}: measured {measured}"
        );
    }
    // Convolution: a delayed impulse shifts, the tail is cut at the signal's length.
    let x: Vec<f64> = (0..100).map(|i| (i as f64 * 0.1).sin()).collect();
    let y = convolve_truncated(&x, &[0.0, 0.0, 2.0]);
    assert_eq!(y.len(), 100);
    assert!(y
        .iter()
        .enumerate()
        .all(|(i, v)| (v - if i >= 2 { 2.0 * x[i - 2] } else { 0.0 }).abs() < 1e-12));
    assert!(RoomResponse {
        t60_s: 0.0,
        direct_to_reverberant_db: 3.0,
        predelay_s: 0.0
    }
    .impulse_response(fs, 1000, &mut SplitMix64::new(1))
    .is_err());
}

#[test]
fn zener_damping_is_a_loss_factor_with_a_relaxation_peak_that_rayleigh_cannot_follow() {
    let law = ZenerDamping::matched(3000.0, 8.0, 3.0, 2000.0).unwrap();
    assert!((law.decay(3000.0) - 8.0).abs() < 1e-12);
    assert!((law.relaxation_strength / law.loss_factor - 3.0).abs() < 1e-12);
    // Loss factor η(f) = 2d/ω: η + Δ/2 at the corner; η far below and far above it.
    let eta = |f: f64| law.decay(f) / (PI * f);
    assert!((eta(2000.0) - law.loss_factor - 0.5 * law.relaxation_strength).abs() < 1e-15);
    assert!(
        (eta(2.0) - law.loss_factor) / law.loss_factor < 0.01
            && (eta(2e6) - law.loss_factor) / law.loss_factor < 0.01
    );
    // The other form of the module docs: π η f + A f²/(1 + (f/f_c)²), A = πΔ/f_c.
    let a = PI * law.relaxation_strength / law.corner_hz;
    let f = 4321.0;
    assert!(
        (law.decay(f)
            - (PI * law.loss_factor * f + a * f * f / (1.0 + (f / law.corner_hz).powi(2))))
        .abs()
            < 1e-12
    );
    // A Rayleigh law is fitted exactly, the Zener law is not.
    let freqs: Vec<f64> = (0..20).map(|i| 800.0 * 1.15f64.powi(i)).collect();
    let rayleigh: Vec<f64> = freqs
        .iter()
        .map(|f| 0.5 * (5.0 + 3e-8 * (2.0 * PI * f).powi(2)))
        .collect();
    let (alpha, beta, misfit) = rayleigh_fit(&freqs, &rayleigh).unwrap();
    assert!((alpha - 5.0).abs() < 1e-9 && (beta / 3e-8 - 1.0).abs() < 1e-9 && misfit < 1e-9);
    let zener: Vec<f64> = freqs.iter().map(|&f| law.decay(f)).collect();
    let (_, _, misfit) = rayleigh_fit(&freqs, &zener).unwrap();
    assert!(
        misfit > 0.1,
        "Rayleigh should miss the Zener law by > 10 %: {misfit}"
    );
    assert!(
        ZenerDamping::matched(0.0, 1.0, 1.0, 1.0).is_err() && rayleigh_fit(&[1.0], &[]).is_err()
    );
}

#[test]
fn noise_has_the_requested_level_and_colour() {
    let fs = 48_000.0;
    let mut rng = SplitMix64::new(3);
    let n = 1 << 16;
    let signal: Vec<f64> = (0..n)
        .map(|i| {
            if i >= n / 4 {
                (i as f64 * 0.05).sin()
            } else {
                0.0
            }
        })
        .collect();
    let mut channels = vec![signal.clone(), signal.iter().map(|v| 2.0 * v).collect()];
    // Mean power over the window, averaged over the channels (the second is 4× the first).
    let power = 2.5 * signal[n / 4..].iter().map(|v| v * v).sum::<f64>() / (n - n / 4) as f64;
    let rms = add_noise(
        &mut channels,
        n / 4..n,
        60.0,
        NoiseColour::White,
        fs,
        &mut rng,
    )
    .unwrap();
    assert!((20.0 * (power.sqrt() / rms).log10() - 60.0).abs() < 1e-9);
    let measured = crate::audio::rms(&channels[0][..n / 4]);
    assert!(
        (measured / rms - 1.0).abs() < 0.03,
        "pre-roll noise RMS {measured} vs {rms}"
    );
    // Pink: band powers fall by 10 dB per decade (octave bands from 100 Hz to 12.8 kHz).
    let np = 1 << 18;
    let pink = coloured_noise(np, NoiseColour::Pink, fs, &mut rng);
    assert!((crate::audio::rms(&pink) - 1.0).abs() < 1e-12);
    let mut spec: Vec<Complex64> = pink.iter().map(|&v| Complex64::new(v, 0.0)).collect();
    rustfft::FftPlanner::<f64>::new()
        .plan_fft_forward(np)
        .process(&mut spec);
    let band = |lo: f64| {
        let (a, b) = (
            (lo * np as f64 / fs) as usize,
            (2.0 * lo * np as f64 / fs) as usize,
        );
        spec[a..b].iter().map(|v| v.norm_sqr()).sum::<f64>()
    };
    // Octave bands of 1/f noise hold equal power; per-Hz density falls 3 dB per octave.
    for lo in [100.0, 400.0, 1600.0, 6400.0] {
        let ratio_db = 10.0 * (band(2.0 * lo) / band(lo)).log10();
        assert!(ratio_db.abs() < 1.0, "octave {lo} Hz: {ratio_db} dB");
    }
    let white = coloured_noise(n, NoiseColour::White, fs, &mut rng);
    let mut spec_w: Vec<Complex64> = white.iter().map(|&v| Complex64::new(v, 0.0)).collect();
    rustfft::FftPlanner::<f64>::new()
        .plan_fft_forward(n)
        .process(&mut spec_w);
    let band_w = |lo: f64| {
        spec_w[(lo * n as f64 / fs) as usize..(2.0 * lo * n as f64 / fs) as usize]
            .iter()
            .map(|v| v.norm_sqr())
            .sum::<f64>()
    };
    assert!((10.0 * (band_w(3200.0) / band_w(1600.0)).log10() - 3.01).abs() < 0.5);
    // A reversed signal range is refused.
    let (start, end) = (10, 5);
    assert!(add_noise(
        &mut channels,
        start..end,
        60.0,
        NoiseColour::White,
        fs,
        &mut rng
    )
    .is_err());
}

#[test]
fn streams_start_independently() {
    // First draws of 4000 neighbouring streams: uniform mean ½, mean |u_i − u_(i+1)| = ⅓
    // and no lag-1 correlation, for several seeds (standard errors ≈ 0.005).
    for seed in [0u64, 1, 7, 12345, u64::MAX] {
        let u: Vec<f64> = (0..4000)
            .map(|i| SplitMix64::stream(seed, i).unit())
            .collect();
        let n = u.len() as f64;
        let mean = u.iter().sum::<f64>() / n;
        let step = u.windows(2).map(|w| (w[0] - w[1]).abs()).sum::<f64>() / (n - 1.0);
        let corr = u
            .windows(2)
            .map(|w| (w[0] - mean) * (w[1] - mean))
            .sum::<f64>()
            / u.iter().map(|v| (v - mean).powi(2)).sum::<f64>();
        assert!(
            (mean - 0.5).abs() < 0.025 && (step - 1.0 / 3.0).abs() < 0.02 && corr.abs() < 0.06,
            "seed {seed}: mean {mean} step {step} corr {corr}"
        );
    }
    let mut rng = SplitMix64::new(5);
    let z: Vec<f64> = (0..20000).map(|_| rng.normal()).collect();
    let (m, v) = (
        z.iter().sum::<f64>() / 2e4,
        z.iter().map(|x| x * x).sum::<f64>() / 2e4,
    );
    assert!(
        m.abs() < 0.03 && (v - 1.0).abs() < 0.04,
        "normal: mean {m} variance {v}"
    );
}

#[test]
fn schedule_mixes_clean_single_and_double_cases_and_balances_effects() {
    let mut rng = SplitMix64::new(11);
    let plan = schedule_effects(100, &Effect::ALL, &mut rng);
    let count = |k: usize| plan.iter().filter(|p| p.len() == k).count();
    assert_eq!((count(0), count(1), count(2)), (30, 40, 30));
    assert!(
        plan.iter().all(|p| p.len() < 2 || p[0] != p[1]),
        "two different effects"
    );
    for e in Effect::ALL {
        let n = plan.iter().filter(|p| p.contains(&e)).count();
        assert!((11..=13).contains(&n), "{e}: {n} cases"); // 100 effects over 8
    }
    let small = schedule_effects(3, &[Effect::SupportContact, Effect::AddedMass], &mut rng);
    assert_eq!(small.iter().map(Vec::len).sum::<usize>(), 3);
    assert!(small
        .iter()
        .any(|p| p == &vec![Effect::SupportContact, Effect::AddedMass]));
    assert!(schedule_effects(4, &[Effect::Reverb], &mut rng)
        .iter()
        .all(|p| p.len() <= 1));
    assert_eq!(
        parse_effect_list("reverb, added_mass,reverb").unwrap(),
        vec![Effect::Reverb, Effect::AddedMass]
    );
    assert!(parse_effect_list("reverb,echo").is_err());
    // The strength scales run through their documented ranges.
    let s = Effect::ContactDuration.strength_scale();
    assert!((s.value(0.0) - 0.05e-3).abs() < 1e-15 && (s.value(1.0) - 0.6e-3).abs() < 1e-15);
    assert!((s.strength_of(s.value(0.37)) - 0.37).abs() < 1e-12);
    assert_eq!(Effect::Reverb.strength_scale().value(1.0), 0.0);
    let json = serde_json::to_string(&Effect::NonRayleighDamping).unwrap();
    assert_eq!(json, "\"non_rayleigh_damping\"");
}

#[test]
fn geometry_helpers_pick_a_sector_and_the_support_damping() {
    // The support, strike and neighbourhood helpers are tested in `mesh::locate`.
    let down = [0.0, 0.0, -1.0];
    // On a square plate, the quadrant x > 0.2, y > 0.2 about the vertical axis through the
    // centre holds a quarter of the tets (cell faces lie on the quadrant's edges); the
    // sector [π/2, 3π/2) is the half x < 0.2; a sector through ψ = 0 wraps around.
    let plate = box_mesh([4, 4, 2], [0.4, 0.4, 0.1]);
    let (centre, up) = ([0.2, 0.2, 0.05], [0.0, 0.0, 1.0]);
    let quadrant = sector_mesh(&plate, centre, up, 0.0, 0.5 * PI);
    assert_eq!(quadrant.n_tets() * 4, plate.n_tets());
    assert_eq!(quadrant.n_nodes(), plate.n_nodes());
    assert!((0..quadrant.n_tets()).all(|e| quadrant
        .corner_coords(e)
        .iter()
        .all(|x| x[0] >= 0.2 && x[1] >= 0.2)));
    let left = sector_mesh(&plate, centre, up, 0.5 * PI, PI);
    assert_eq!(left.n_tets() * 2, plate.n_tets());
    assert!((0..left.n_tets()).all(|e| left.corner_coords(e).iter().all(|x| x[0] <= 0.2)));
    let wrap = sector_mesh(&plate, centre, up, 1.5 * PI, PI);
    assert!(
        wrap.n_tets() * 2 == plate.n_tets()
            && (0..wrap.n_tets()).all(|e| wrap.corner_coords(e).iter().all(|x| x[0] >= 0.2))
    );
    // Dashpot damping: ½ c_n for a unit normal motion at one node, ½ c_t for a tangential one.
    assert!((support_damping(&[[0.0, 0.0, 1.0]], 4.0, 1.0, down) - 2.0).abs() < 1e-15);
    assert!(
        (support_damping(&[[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]], 4.0, 1.0, down) - 2.5).abs() < 1e-15
    );
    // Level misfit: exactly rank-1 levels give 0; one deviating entry gives > 0.
    let levels: Vec<Vec<f64>> = (0..5)
        .map(|k| {
            (0..4)
                .map(|c| (k as f64 + 1.0) * (1.0 + c as f64))
                .collect()
        })
        .collect();
    assert!(rank_one_level_misfit_db(&levels, &[1.0; 5]).unwrap() < 1e-9);
    let mut off = levels.clone();
    off[2][1] *= 10.0;
    assert!(rank_one_level_misfit_db(&off, &[1.0; 5]).unwrap() > 1.0);
}

#[test]
fn scorer_counts_hits_false_alarms_and_recall_by_strength() {
    let label = |e: Effect, s: f64| EffectLabel {
        effect: e,
        strength: s,
        parameters: serde_json::Value::Null,
    };
    let truth = vec![
        CaseTruth {
            case: "a".into(),
            effects: vec![],
        },
        CaseTruth {
            case: "b".into(),
            effects: vec![label(Effect::Reverb, 0.9)],
        },
        CaseTruth {
            case: "c".into(),
            effects: vec![label(Effect::Reverb, 0.1), label(Effect::AddedMass, 0.5)],
        },
        CaseTruth {
            case: "d".into(),
            effects: vec![],
        },
    ];
    let detected = vec![
        vec![Effect::PitchGlide],
        vec![Effect::Reverb],
        vec![Effect::AddedMass],
        vec![],
    ];
    let s = score(&truth, &detected, 2).unwrap();
    let reverb = s
        .per_effect
        .iter()
        .find(|e| e.effect == Effect::Reverb)
        .unwrap();
    assert_eq!(
        (
            reverb.true_positives,
            reverb.false_positives,
            reverb.false_negatives
        ),
        (1, 0, 1)
    );
    assert_eq!((reverb.precision, reverb.recall), (Some(1.0), Some(0.5)));
    assert_eq!(
        reverb.recall_by_strength,
        vec![(0.0, 0.5, 0, 1), (0.5, 1.0, 1, 1)]
    );
    let glide = s
        .per_effect
        .iter()
        .find(|e| e.effect == Effect::PitchGlide)
        .unwrap();
    assert_eq!(
        (glide.precision, glide.recall, glide.f1),
        (Some(0.0), None, Some(0.0))
    );
    assert_eq!(s.clean_cases, 2);
    assert_eq!(s.clean_false_positive_rate, Some(0.5));
    // F1: reverb 2/3, added mass 1, pitch glide 0; the others have none.
    assert!((s.macro_f1.unwrap() - (2.0 / 3.0 + 1.0) / 3.0).abs() < 1e-12);
    assert!(score(&truth, &detected[..2], 2).is_err());
}

#[test]
fn contact_shapes_match_the_closed_forms_of_sine_power_pulses() {
    // σ² = ψ′(1 + ν/2)/(2π²): 1/4 − 2/π² for ν = 1, (π² − 8G − 16/9)/(2π²) for ν = 3/2.
    let catalan = 0.915_965_594_177_219;
    assert!((sine_power_pulse_variance(1.0) - (0.25 - 2.0 / (PI * PI))).abs() < 1e-12);
    let hertz = (PI * PI - 8.0 * catalan - 16.0 / 9.0) / (2.0 * PI * PI);
    assert!(
        (sine_power_pulse_variance(1.5) - hertz).abs() < 1e-10,
        "{} vs {hertz}",
        sine_power_pulse_variance(1.5)
    );
    let r = contact_shape_ratios();
    // First zeros at (ν + 2)π.
    assert!(
        (r.hertz_first_zero_x - 3.5 * PI).abs() < 1e-9,
        "{}",
        r.hertz_first_zero_x
    );
    assert!((r.ratio_first_zero - 6.0 / 7.0).abs() < 1e-9);
    // The −3 dB points are −3 dB points, and the half-sine's lies where its closed form says.
    let half = crate::diagnose::catalogue::half_sine_spectrum(r.half_sine_minus_3db_x);
    assert!((half - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-12);
    assert!((hertz_amplitude(r.hertz_minus_3db_x) - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-9);
    let t = 1e-3;
    let magnitude = HertzPulse::new(t)
        .unwrap()
        .laplace(Complex64::new(0.0, r.hertz_minus_3db_x / t))
        .norm();
    assert!((magnitude - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-9);
    assert!((r.ratio_low_frequency - (hertz / (0.25 - 2.0 / (PI * PI))).sqrt()).abs() < 1e-9);
    assert!(
        (r.ratio_minus_3db - 0.9008).abs() < 1e-4 && (r.ratio_low_frequency - 0.9041).abs() < 1e-4,
        "{r:?}"
    );
}

#[test]
fn equivalent_half_sine_recovers_a_half_sine_and_follows_the_detectors_bound() {
    use crate::diagnose::catalogue::half_sine_spectrum;
    let freqs: Vec<f64> = (0..12).map(|i| 1500.0 * 1.2f64.powi(i)).collect();
    // A half-sine low-pass with a gain offset of 3 dB: its own T back.
    for t0 in [0.02e-3, 0.08e-3] {
        let att: Vec<f64> = freqs
            .iter()
            .map(|f| 3.0 + 20.0 * half_sine_spectrum(2.0 * PI * f * t0).log10())
            .collect();
        let t = equivalent_half_sine_duration(&freqs, &att).unwrap();
        assert!((t / t0 - 1.0).abs() < 1e-6, "T {t0}: {t}");
    }
    // A short Hertz pulse (modes in its main lobe): the low-frequency ratio.
    let ratios = contact_shape_ratios();
    let hertz_att = |t_h: f64| -> Vec<f64> {
        let pulse = HertzPulse::new(t_h).unwrap();
        freqs
            .iter()
            .map(|f| {
                20.0 * pulse
                    .laplace(Complex64::new(-5.0, 2.0 * PI * f))
                    .norm()
                    .log10()
            })
            .collect()
    };
    let t = equivalent_half_sine_duration(&freqs, &hertz_att(0.03e-3)).unwrap();
    assert!(
        (t / 0.03e-3 / ratios.ratio_low_frequency - 1.0).abs() < 0.005,
        "ratio {}",
        t / 0.03e-3
    );
    // A long one (the high modes beyond its first zero): the detector's bound 2.9π/ω_max.
    let t = equivalent_half_sine_duration(&freqs, &hertz_att(0.6e-3)).unwrap();
    let bound = 2.9 * PI / (2.0 * PI * freqs[11]);
    assert!((t / bound - 1.0).abs() < 1e-3, "{t} vs bound {bound}");
    assert!(equivalent_half_sine_duration(&freqs, &[0.0; 3]).is_err());
    assert!(equivalent_half_sine_duration(&[1000.0], &[0.0]).is_err());
}

#[test]
fn glide_contrast_matches_a_discrete_phase_regression() {
    // Early and late frequencies as amplitude²-weighted regressions of the exact glide phase
    // on the samples of each half of 1 s at 48 kHz (trapezoid weights: the plain sum is off
    // by ~d/fs at the fast-decaying start).
    let (fs, f0, g, span) = (48_000.0, 1000.0, 0.003, 1.0);
    let slope = |d: f64, from: usize, to: usize| {
        let end = |n: usize| if n == from || n == to { 0.5 } else { 1.0 };
        let pts: Vec<(f64, f64, f64)> = (from..=to)
            .map(|n| (n as f64 / fs, end(n)))
            .map(|(t, e)| (t, glide_phase(f0, d, g, t), e * (-2.0 * d * t).exp()))
            .collect();
        let sw: f64 = pts.iter().map(|p| p.2).sum();
        let mt = pts.iter().map(|p| p.2 * p.0).sum::<f64>() / sw;
        let my = pts.iter().map(|p| p.2 * p.1).sum::<f64>() / sw;
        let sxy: f64 = pts.iter().map(|p| p.2 * (p.0 - mt) * (p.1 - my)).sum();
        let sxx: f64 = pts.iter().map(|p| p.2 * (p.0 - mt).powi(2)).sum();
        sxy / sxx / (2.0 * PI * f0)
    };
    let n = (span * fs) as usize;
    for d in [0.5, 5.0, 30.0] {
        let discrete = (slope(d, 0, n / 2) - slope(d, n / 2, n)) / g;
        let contrast = glide_half_contrast(d, span).unwrap();
        assert!(
            (discrete - contrast).abs() < 1e-5 * contrast,
            "d {d}: discrete {discrete} vs {contrast}"
        );
    }
    // Limits: no decay, no contrast; fast decay, ¼ (module docs).
    assert_eq!(glide_half_contrast(0.0, 1.0).unwrap(), 0.0);
    for d in [0.5, 3.0, 20.0] {
        let halves = glide_half_contrast(d, 1.0).unwrap();
        assert!(
            (glide_window_contrast(d, 0.5, 1.0).unwrap() - halves).abs() < 1e-9 * halves.max(1e-12),
            "{d}"
        );
    }
    assert!(glide_window_contrast(3.0, 0.2, 0.2).is_err());
    assert!((glide_half_contrast(500.0, 1.0).unwrap() - 0.25).abs() < 1e-9);
    assert!(glide_half_contrast(1.0, 0.0).is_err() && glide_half_contrast(-1.0, 1.0).is_err());
}

#[test]
fn scorer_helpers_read_names_pair_clusters_and_summarise() {
    assert_eq!(frequency_in_name("decay rate at 1234 Hz"), Some(1234.0));
    assert_eq!(
        frequency_in_name("relative split δf/f of cluster 3 (1662.5 Hz)"),
        Some(1662.5)
    );
    assert_eq!(
        frequency_in_name("reverberant excess ρ = R/N at t = 0, band 250–500 Hz"),
        Some(500.0)
    );
    assert_eq!(frequency_in_name("contact duration T"), None);
    assert_eq!(frequency_in_name("at Hz"), None);
    // Nearest first, one to one, beyond the tolerance unpaired.
    let pairs = pair_by_frequency(&[1000.0, 1003.0, 5000.0], &[1002.5, 1000.5, 7000.0], 0.002);
    assert_eq!(pairs, vec![(1, 0), (0, 1)]);
    let e = ErrorSummary::of(&[0.1, -0.3, 0.2, f64::NAN]).unwrap();
    assert_eq!((e.n, e.max_abs), (3, 0.3));
    assert!((e.median_abs - 0.2).abs() < 1e-15 && (e.median - 0.1).abs() < 1e-15);
    assert!(ErrorSummary::of(&[f64::NAN]).is_none());
    let h = HeldOutSummary::of(&[
        (2.0, 1.0),
        (1.0, 1.5),
        (1.0, 1.0),
        (f64::NAN, 1.0),
        (4.0, 3.0),
    ]);
    assert_eq!((h.cases, h.dropped, h.not_dropped, h.invalid), (5, 2, 2, 1));
    // Drops 0.5, −0.5, 0, 0.25: median 0.125.
    assert!((h.median_relative_drop.unwrap() - 0.125).abs() < 1e-15);
    assert!((modal_mass_loading(1000.0, 950.0) - (1000.0f64 / 950.0).powi(2) + 1.0).abs() < 1e-15);
    let law = ZenerDamping {
        loss_factor: 1e-3,
        relaxation_strength: 2e-3,
        corner_hz: 3000.0,
    };
    assert!(
        zener_knot_rms_error(
            &law,
            &[(1000.0, law.decay(1000.0)), (5000.0, law.decay(5000.0))]
        )
        .unwrap()
            < 1e-15
    );
    let off = zener_knot_rms_error(
        &law,
        &[
            (1000.0, 1.1 * law.decay(1000.0)),
            (5000.0, 0.7 * law.decay(5000.0)),
        ],
    )
    .unwrap();
    assert!((off - (0.5f64 * (0.01 + 0.09)).sqrt()).abs() < 1e-12);
    assert!(zener_knot_rms_error(&law, &[]).is_err());
    assert_eq!(
        Effect::from_catalogue_name("reverb_noise").unwrap(),
        Effect::Reverb
    );
    assert_eq!(
        Effect::from_catalogue_name("added_mass").unwrap(),
        Effect::AddedMass
    );
    assert!(Effect::from_catalogue_name("echo").is_err());
}

/// A catalogue acceptance with the given parameters (name, value).
fn accepted(name: &str, variant: &str, params: &[(&str, f64)]) -> AcceptedEffect {
    AcceptedEffect {
        name: name.into(),
        signature: String::new(),
        variant: variant.into(),
        detector: String::new(),
        step: 0,
        n_params: params.len(),
        delta_bic: 10.0,
        held_out_before: Some(2.0),
        held_out_after: Some(1.5),
        held_out_gain: Some(20.0),
        params: params
            .iter()
            .map(|(n, v)| FittedParam::new(*n, "", *v, 0.0))
            .collect(),
    }
}

#[test]
fn compare_parameters_maps_each_effect_onto_the_detectors_quantity() {
    use crate::diagnose::catalogue::half_sine_spectrum;
    let law = ZenerDamping {
        loss_factor: 1e-3,
        relaxation_strength: 2e-3,
        corner_hz: 3000.0,
    };
    let t_contact = 0.05e-3;
    let modes = [
        (0, 950.0, 3.0),
        (1, 1001.0, 4.0),
        (2, 1003.0, 4.0),
        (3, 1990.0, 8.0),
    ];
    let att: Vec<f64> = modes
        .iter()
        .map(|m| 20.0 * half_sine_spectrum(2.0 * PI * m.1 * t_contact).log10())
        .collect();
    let labels = |effects: serde_json::Value| {
        serde_json::json!({
            "case": "x", "effects": effects, "base_undamped_hz": [1000.0, 1001.0, 1003.0, 2000.0],
            "modes": modes.iter().map(|&(i, f, d)| serde_json::json!({"index": i, "undamped_hz": f, "frequency_hz": f, "decay_rate": d,
                "amplitudes": if i == 0 { [1.0, 1.0] } else { [0.1, 0.1] }})).collect::<Vec<_>>(),
        })
    };
    let all = labels(serde_json::json!([
        {"effect": "reverb", "strength": 0.5, "parameters": {"t60_s": 0.5}},
        {"effect": "added_mass", "strength": 0.5, "parameters": {"mass_fraction": 0.03}},
        {"effect": "pitch_glide", "strength": 0.5, "parameters": {"glide": 0.002}},
        {"effect": "non_rayleigh_damping", "strength": 0.5, "parameters": {"loss_factor": 1e-3, "relaxation_strength": 2e-3, "corner_hz": 3000.0}},
        {"effect": "beating_pair", "strength": 0.5, "parameters": {"clusters": [{"modes": [1, 2], "split_hz": 2.0}]}},
        {"effect": "contact_duration", "strength": 0.5, "parameters": {"duration_s": t_contact, "mode_attenuation_db": att}},
        {"effect": "support_contact", "strength": 0.5, "parameters": {"added_decay_per_mode": [0.5, 0.1, 0.2, 0.0]}},
        {"effect": "radiation", "strength": 0.5, "parameters": {}},
    ]));
    let ctx = ScoringContext {
        glide_span_s: Some(1.0),
        glide_windows_s: None,
        glide_offset_at_onset: false,
        matched_hz: vec![],
    };
    let only_error = |c: &ParameterComparison| {
        assert_eq!(c.errors.len(), 1, "{c:?}");
        c.errors[0]
    };
    let c = compare_parameters(
        &all,
        &accepted(
            "reverb_noise",
            "shared_t60",
            &[
                ("reverberation time T60", 0.55),
                ("reverberant excess ρ", 3.0),
            ],
        ),
        &ctx,
    )
    .unwrap();
    assert_eq!(c.effect, Effect::Reverb);
    assert!((only_error(&c) - 0.1).abs() < 1e-12);
    // Largest loading: mode 0, (1000/950)² − 1; the fluid variant takes the lowest mode (the same here).
    let mu = (1000.0f64 / 950.0).powi(2) - 1.0;
    let mass_only = labels(
        serde_json::json!([{"effect": "added_mass", "strength": 0.5, "parameters": {"mass_fraction": 0.03}}]),
    );
    for variant in ["added_mass", "fluid_loading"] {
        let c = compare_parameters(
            &mass_only,
            &accepted("added_mass", variant, &[("added-mass ratio μ", 1.2 * mu)]),
            &ctx,
        )
        .unwrap();
        assert!((only_error(&c) - 0.2).abs() < 1e-12 && c.not_comparable.is_none());
    }
    // Glide: the most energetic mode is mode 0 (d = 3).
    let expected = 0.002 * glide_half_contrast(3.0, 1.0).unwrap();
    let c = compare_parameters(
        &all,
        &accepted(
            "pitch_glide",
            "energy_squared",
            &[(
                "relative glide g of the most energetic mode",
                2.0 * expected,
            )],
        ),
        &ctx,
    )
    .unwrap();
    assert!((only_error(&c) - 1.0).abs() < 1e-12);
    // … and mode 1 (equal amplitudes: the lowest of the rest, d = 4) when the detector
    // matched only modes 1–3.
    let matched = ScoringContext {
        glide_span_s: Some(1.0),
        glide_windows_s: None,
        glide_offset_at_onset: false,
        matched_hz: vec![1001.0, 1003.0, 1995.0],
    };
    let expected1 = 0.002 * glide_half_contrast(4.0, 1.0).unwrap();
    let c = compare_parameters(
        &all,
        &accepted(
            "pitch_glide",
            "energy_squared",
            &[("relative glide g of the most energetic mode", expected1)],
        ),
        &matched,
    )
    .unwrap();
    assert!(only_error(&c).abs() < 1e-12, "{c:?}");
    let c = compare_parameters(
        &all,
        &accepted(
            "pitch_glide",
            "energy_squared",
            &[("relative glide g", 1e-3)],
        ),
        &ScoringContext::default(),
    )
    .unwrap();
    assert!(c.errors.is_empty() && c.not_comparable.is_some());
    // A chirp-fit report detects the labels' g itself, whatever the windows or the span.
    let onset = ScoringContext {
        glide_offset_at_onset: true,
        ..ctx.clone()
    };
    let c = compare_parameters(
        &all,
        &accepted(
            "pitch_glide",
            "uniform",
            &[(
                "relative glide g (offset at the onset) of every mode",
                0.0022,
            )],
        ),
        &onset,
    )
    .unwrap();
    assert!(
        (only_error(&c) - 0.1).abs() < 1e-9 && c.not_comparable.is_none(),
        "{c:?}"
    );
    // Damping knots 10 % high at 1000 Hz, exact at 2000 Hz: RMS √(0.01/2).
    let knots = [
        ("decay rate at 1000 Hz", 1.1 * law.decay(1000.0)),
        ("decay rate at 2000 Hz", law.decay(2000.0)),
    ];
    let c = compare_parameters(
        &all,
        &accepted("non_rayleigh_damping", "three_knot_log_log", &knots),
        &ctx,
    )
    .unwrap();
    assert!((only_error(&c) - 0.005f64.sqrt()).abs() < 1e-12);
    // Split of 2 Hz at 1002 Hz seen 10 % small; a second detected split pairs with nothing.
    let c = compare_parameters(
        &all,
        &accepted(
            "beating_pair",
            "split_per_cluster",
            &[
                (
                    "relative split δf/f of cluster 4 (1002.1 Hz)",
                    0.9 * 2.0 / 1002.0,
                ),
                ("relative split δf/f of cluster 9 (3000.0 Hz)", 1e-3),
            ],
        ),
        &ctx,
    )
    .unwrap();
    assert!(
        (only_error(&c) + 0.1).abs() < 1e-12
            && c.not_comparable.as_deref().unwrap().contains("3000.0 Hz")
    );
    // Contact: attenuations of a half-sine give back its duration.
    let c = compare_parameters(
        &all,
        &accepted(
            "contact_duration",
            "half_sine",
            &[("contact duration T", t_contact)],
        ),
        &ctx,
    )
    .unwrap();
    assert!(only_error(&c).abs() < 1e-6, "{c:?}");
    // Not comparable: support (the weights are the CLI's), radiation's factor variant.
    let c = compare_parameters(
        &all,
        &accepted(
            "support_contact",
            "damping_only",
            &[("support damping γ", 2.0)],
        ),
        &ctx,
    )
    .unwrap();
    assert!(c.errors.is_empty() && c.not_comparable.is_some() && c.values[1].truth == Some(0.5));
    let c = compare_parameters(
        &all,
        &accepted("radiation", "transfer", &[("transfer exponent η", 0.98)]),
        &ctx,
    )
    .unwrap();
    assert!((only_error(&c) + 0.02).abs() < 1e-12, "{c:?}");
    let c = compare_parameters(
        &all,
        &accepted(
            "radiation",
            "factor",
            &[("directivity u of cluster 0 slot 0", 1.0)],
        ),
        &ctx,
    )
    .unwrap();
    assert!(c.errors.is_empty() && c.not_comparable.is_some());
    // Added mass next to another FEM effect: the frequency drops are not the mass's alone.
    let mixed = labels(serde_json::json!([
        {"effect": "added_mass", "strength": 0.5, "parameters": {"mass_fraction": 0.03}},
        {"effect": "beating_pair", "strength": 0.5, "parameters": {"clusters": []}},
    ]));
    let c = compare_parameters(
        &mixed,
        &accepted("added_mass", "added_mass", &[("added-mass ratio μ", 0.1)]),
        &ctx,
    )
    .unwrap();
    assert!(c.errors.is_empty() && c.not_comparable.unwrap().contains("beating_pair"));
    // Errors: an effect the case does not hold, a parameter the report lacks, bad labels.
    assert!(matches!(
        compare_parameters(
            &mixed,
            &accepted(
                "reverb_noise",
                "shared_t60",
                &[("reverberation time T60", 0.5)]
            ),
            &ctx
        ),
        Err(InjectError::Label(_))
    ));
    assert!(matches!(
        compare_parameters(
            &all,
            &accepted("reverb_noise", "shared_t60", &[("T60", 0.5)]),
            &ctx
        ),
        Err(InjectError::Report(_))
    ));
    assert!(compare_parameters(
        &serde_json::json!({"effects": 3}),
        &accepted("reverb_noise", "", &[]),
        &ctx
    )
    .is_err());
}
