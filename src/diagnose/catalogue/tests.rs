//! Tests of the catalogue: kernels against analytic answers, matching, and synthetic evidence
//! generated from the baseline with effects injected — where natural in a different
//! functional form than the detector's (power-law damping detected by the 3-knot curve, a
//! Hertzian sin^1.5 contact detected by the half-sine, directivity patterns detected by the
//! rank-one factor model, glide from the true energies detected on the observed ones).

use std::f64::consts::PI;

use super::model::{split_sigma, CARRIED_MASS_SPLIT_FLOOR, SPLIT_MODEL_FLOOR};
use super::*;
use crate::testing::Rng;

/// Standard normal (Box–Muller).
fn normal(rng: &mut Rng) -> f64 {
    let u1 = 1.0 - rng.next();
    let u2 = rng.next();
    (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()
}

const FIT_CHANNELS: usize = 4;
const HELD_CHANNELS: usize = 3;
const CLUSTERS: usize = 20;
/// Clusters that are degenerate pairs in the simulation.
const DEGENERATE: [usize; 3] = [3, 8, 13];

/// Measurement noise: σ_f = 0.02 Hz + 2·10⁻⁶ f, σ_lnd, σ_lna, and early/late σ = 2 σ_f.
const SIGMA_LN_D: f64 = 0.04;
const SIGMA_LN_A: f64 = 0.05;
fn sigma_f(f: f64) -> f64 {
    0.02 + 2e-6 * f
}

/// A synthetic object: clusters of simulated modes and two true directivities per cluster
/// and microphone (fit channels first, then held-out): lobes |cos m(φ − θ_k)| of random order
/// and orientation per mode (what the transfer carries, times ρ_air ω² as
/// [`crate::audio::radiation`]'s pressure per unit displacement does), and monopole + dipole along the
/// strike axis |1 + β_k cos(φ − θ_s)| with a per-mode dipole strength β_k.
struct Object {
    sim: Vec<SimulatedMode>,
    members: Vec<Vec<usize>>,
    lobes: Vec<Vec<f64>>,
    axis: Vec<Vec<f64>>,
}

/// Which directivity the recording has.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Pattern {
    Lobes,
    Axis,
}

fn object(rng: &mut Rng) -> Object {
    let mut sim = Vec::new();
    let mut members = Vec::new();
    let mut lobes = Vec::new();
    let mut axis = Vec::new();
    let strike_axis = rng.uniform(0.0, 2.0 * PI);
    let n_mics = FIT_CHANNELS + HELD_CHANNELS;
    let azimuth: Vec<f64> = (0..n_mics)
        .map(|c| 2.0 * PI * c as f64 / n_mics as f64 + rng.uniform(-0.2, 0.2))
        .collect();
    for i in 0..CLUSTERS {
        let f = 450.0
            * (7000.0f64 / 450.0).powf(i as f64 / (CLUSTERS - 1) as f64)
            * rng.uniform(0.98, 1.02);
        let support_weight = rng.next().powi(3);
        let mass_weight = rng.next().powi(2);
        let mut list = vec![sim.len()];
        sim.push(SimulatedMode {
            frequency_hz: f,
            drive: rng.uniform(0.3, 1.0),
            support_weight,
            mass_weight,
            cluster: i,
            transfer: None,
            match_frequency_hz: None,
            ln_f_per_poisson: None,
        });
        if DEGENERATE.contains(&i) {
            list.push(sim.len());
            sim.push(SimulatedMode {
                frequency_hz: f * (1.0 + 2e-5),
                drive: rng.uniform(0.3, 1.0),
                support_weight,
                mass_weight,
                cluster: i,
                transfer: None,
                match_frequency_hz: None,
                ln_f_per_poisson: None,
            });
        }
        let order = (rng.next() * 4.0).floor();
        let orientation = rng.uniform(0.0, PI);
        let d: Vec<f64> = azimuth
            .iter()
            .map(|&phi| 0.35 + (order * (phi - orientation)).cos().abs())
            .collect();
        // The transfer is pressure per unit modal displacement: ρ_air ω² times the lobes.
        for &j in &list {
            let omega = 2.0 * PI * sim[j].frequency_hz;
            sim[j].transfer = Some(d.iter().map(|x| 1.225 * omega * omega * x).collect());
        }
        members.push(list);
        lobes.push(d);
        let dipole = rng.uniform(-0.8, 0.8);
        axis.push(
            azimuth
                .iter()
                .map(|&phi| (1.0 + dipole * (phi - strike_axis).cos()).abs())
                .collect(),
        );
    }
    Object {
        sim,
        members,
        lobes,
        axis,
    }
}

/// What the synthetic recording contains.
#[derive(Clone, Debug)]
struct Truth {
    ln_s: f64,
    alpha: f64,
    beta: f64,
    /// d = d_1k (f / 1 kHz)^p instead of Rayleigh.
    power_law: Option<(f64, f64)>,
    /// A knee on top of `power_law`: above f_k, d × (f / f_k)^q (f_k Hz, q).
    knee: Option<(f64, f64)>,
    /// (cluster, relative split δ).
    splits: Vec<(usize, f64)>,
    /// (γ 1/s, κ).
    support: Option<(f64, f64)>,
    /// A spring at the support: Δ ln f = κ_s w (f₁/f)² with f₁ the lowest simulated frequency
    /// (support_contact's module docs).
    spring: Option<f64>,
    /// Hertzian contact of this duration, s.
    hertz: Option<f64>,
    radiation: Option<Pattern>,
    transfer_in_evidence: bool,
    added_mass: Option<f64>,
    fluid: Option<f64>,
    glide: Option<f64>,
    reverb_t60: Option<f64>,
    /// Model-error scatter (ln f, ln d, ln a), shared by fit and held-out data.
    scatter: Option<(f64, f64, f64)>,
    held_out: bool,
    /// Nuisance amplitude tilt: every channel's amplitudes × (f / 1 kHz)^η with η = `tilt`
    /// (the response quantity and a radiation-efficiency trend, common to all microphones)
    /// plus a per-channel part uniform in ±`mic_tilt_spread` (each microphone's response).
    tilt: f64,
    mic_tilt_spread: f64,
    /// A colouration of the levels common to every microphone (a room's, a microphone
    /// type's): ln a += κ (ln(f / 3 kHz))² with κ = `colouration`.
    colouration: f64,
}

impl Default for Truth {
    fn default() -> Self {
        Truth {
            ln_s: 0.03,
            alpha: 4.0,
            beta: 3e-8,
            power_law: None,
            knee: None,
            splits: vec![],
            support: None,
            spring: None,
            hertz: None,
            radiation: None,
            transfer_in_evidence: false,
            added_mass: None,
            fluid: None,
            glide: None,
            reverb_t60: None,
            scatter: None,
            held_out: true,
            tilt: 0.0,
            mic_tilt_spread: 0.0,
            colouration: 0.0,
        }
    }
}

/// |F(ω)|/F(0) of a Hertzian pulse F(t) ∝ sin^1.5(πt/T) on [0, T], by the midpoint rule.
fn hertz_spectrum(omega: f64, t: f64) -> f64 {
    let n = 800;
    let (mut re, mut im, mut area) = (0.0, 0.0, 0.0);
    for i in 0..n {
        let tau = t * (i as f64 + 0.5) / n as f64;
        let f = (PI * tau / t).sin().powf(1.5);
        re += f * (omega * tau).cos();
        im -= f * (omega * tau).sin();
        area += f;
    }
    (re * re + im * im).sqrt() / area
}

/// One unit of the truth: a mode as the recording has it.
struct TrueMode {
    ln_f0: f64,
    decay: f64,
    /// ln of the channel-independent amplitude.
    ln_amp: f64,
    cluster: usize,
    glide: f64,
}

fn true_modes(obj: &Object, truth: &Truth, rng: &mut Rng) -> Vec<TrueMode> {
    let ln_f1 = obj
        .sim
        .iter()
        .map(|m| m.frequency_hz.ln())
        .fold(f64::INFINITY, f64::min);
    let mut out = Vec::new();
    for (i, list) in obj.members.iter().enumerate() {
        let w2: f64 = list.iter().map(|&j| obj.sim[j].drive.powi(2)).sum();
        let ln_f_sim = list
            .iter()
            .map(|&j| obj.sim[j].drive.powi(2) * obj.sim[j].frequency_hz.ln())
            .sum::<f64>()
            / w2;
        let m = &obj.sim[list[0]];
        let (ef, ed, ea) = match truth.scatter {
            Some((sf, sd, sa)) => (sf * normal(rng), sd * normal(rng), sa * normal(rng)),
            None => (0.0, 0.0, 0.0),
        };
        let mut ln_f = truth.ln_s + ln_f_sim + ef;
        if let Some((_, kappa)) = truth.support {
            ln_f += kappa * m.support_weight;
        }
        if let Some(kappa) = truth.spring {
            ln_f += kappa * m.support_weight * (2.0 * (ln_f1 - ln_f_sim)).exp();
        }
        if let Some(mu) = truth.added_mass {
            ln_f -= 0.5 * (mu * m.mass_weight).ln_1p();
        }
        if let Some(mu) = truth.fluid {
            ln_f -= 0.5 * (mu * (ln_f1 - ln_f_sim).exp()).ln_1p();
        }
        let split = truth.splits.iter().find(|s| s.0 == i).map(|s| s.1);
        let halves: Vec<(f64, f64)> = match split {
            None => vec![(ln_f, w2.sqrt())],
            Some(delta) => vec![
                (ln_f - 0.5 * delta, (0.5 * w2).sqrt()),
                (ln_f + 0.5 * delta, (0.5 * w2).sqrt()),
            ],
        };
        for (ln_f0, drive) in halves {
            let omega = 2.0 * PI * ln_f0.exp();
            let mut decay = match truth.power_law {
                Some((d1k, p)) => d1k * (ln_f0.exp() / 1000.0).powf(p),
                None => 0.5 * (truth.alpha + truth.beta * omega * omega),
            };
            if let Some((f_k, q)) = truth.knee {
                decay *= (ln_f0.exp() / f_k).max(1.0).powf(q);
            }
            if let Some((gamma, _)) = truth.support {
                decay += gamma * m.support_weight;
            }
            decay *= ed.exp();
            let mut ln_amp = drive.ln() + omega.ln() + ea;
            if let Some(t) = truth.hertz {
                ln_amp += hertz_spectrum(omega, t).ln();
            }
            out.push(TrueMode {
                ln_f0,
                decay,
                ln_amp,
                cluster: i,
                glide: 0.0,
            });
        }
    }
    if let Some(g) = truth.glide {
        let energy: Vec<f64> = out
            .iter()
            .map(|m| (2.0 * m.ln_amp).exp() / (2.0 * PI * m.ln_f0.exp()).powi(2))
            .collect();
        let max = energy.iter().cloned().fold(0.0, f64::max);
        for (m, e) in out.iter_mut().zip(energy) {
            m.glide = g * e / max;
        }
    }
    out
}

/// Noisy observations of the true modes on `channels` (indices into the gains/directivity).
fn observe(
    obj: &Object,
    truth: &Truth,
    modes: &[TrueMode],
    gains: &[f64],
    tilts: &[f64],
    channels: std::ops::Range<usize>,
    rng: &mut Rng,
) -> Vec<ObservedMode> {
    modes
        .iter()
        .map(|m| {
            let f0 = m.ln_f0.exp();
            let fd = (f0 * f0 - (m.decay / (2.0 * PI)).powi(2)).sqrt();
            let sf = sigma_f(fd);
            let d = m.decay * (SIGMA_LN_D * normal(rng)).exp();
            let amplitudes: Vec<f64> = channels
                .clone()
                .map(|c| {
                    let mut ln_a = gains[c]
                        + m.ln_amp
                        + tilts[c] * (f0 / 1000.0).ln()
                        + truth.colouration * (f0 / 3000.0).ln().powi(2);
                    match truth.radiation {
                        Some(Pattern::Lobes) => ln_a += obj.lobes[m.cluster][c].ln(),
                        Some(Pattern::Axis) => ln_a += obj.axis[m.cluster][c].ln(),
                        None => {}
                    }
                    (ln_a + SIGMA_LN_A * normal(rng)).exp()
                })
                .collect();
            let sigma_amplitudes = amplitudes.iter().map(|a| SIGMA_LN_A * a).collect();
            ObservedMode {
                frequency_hz: fd + sf * normal(rng),
                sigma_frequency_hz: sf,
                decay_rate: d,
                sigma_decay_rate: SIGMA_LN_D * d,
                amplitudes,
                sigma_amplitudes,
                early_frequency_hz: Some((
                    fd * (1.0 + 0.5 * m.glide) + 2.0 * sf * normal(rng),
                    2.0 * sf,
                )),
                late_frequency_hz: Some((
                    fd * (1.0 - 0.5 * m.glide) + 2.0 * sf * normal(rng),
                    2.0 * sf,
                )),
                glide: None,
            }
        })
        .collect()
}

/// Residual envelopes: 6 bands × 120 frames of 10 ms; energy = (N_b + reverb) · χ²₃₀/30.
fn envelopes(truth: &Truth, rng: &mut Rng) -> ResidualEnvelopes {
    let edges = vec![0.0, 500.0, 1000.0, 2000.0, 4000.0, 8000.0, 16000.0];
    let times: Vec<f64> = (0..120).map(|j| 0.01 * j as f64).collect();
    let mut energy = Vec::new();
    let mut floor = Vec::new();
    for _ in 0..6 {
        let n = 10f64.powf(rng.uniform(-7.0, -5.0));
        let rho = 10f64.powf(rng.uniform(0.5, 1.2));
        let row = times
            .iter()
            .map(|&t| {
                let mean = n + truth
                    .reverb_t60
                    .map_or(0.0, |t60| rho * n * (-13.815510557964274 * t / t60).exp());
                let chi2: f64 = (0..30).map(|_| normal(rng).powi(2)).sum::<f64>() / 30.0;
                mean * chi2
            })
            .collect();
        energy.push(row);
        floor.push(n * (0.1 * normal(rng)).exp());
    }
    ResidualEnvelopes {
        times_s: times,
        band_edges_hz: edges,
        energy,
        noise_floor_estimate: floor,
        // Independent χ² frames.
        frames_per_window: 1.0,
    }
}

fn evidence(truth: &Truth, seed: u64) -> (Evidence, Object) {
    let mut rng = Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1);
    let mut obj = object(&mut rng);
    if !truth.transfer_in_evidence {
        for m in &mut obj.sim {
            m.transfer = None;
        }
    }
    let gains: Vec<f64> = (0..FIT_CHANNELS + HELD_CHANNELS)
        .map(|_| rng.uniform(-1.0, 1.0) - 3.0)
        .collect();
    // Drawn only when asked for, so that the other tests' random streams stay as they were.
    let tilts: Vec<f64> = (0..FIT_CHANNELS + HELD_CHANNELS)
        .map(|_| {
            truth.tilt
                + if truth.mic_tilt_spread > 0.0 {
                    rng.uniform(-truth.mic_tilt_spread, truth.mic_tilt_spread)
                } else {
                    0.0
                }
        })
        .collect();
    let modes = true_modes(&obj, truth, &mut rng);
    let fit = observe(
        &obj,
        truth,
        &modes,
        &gains,
        &tilts,
        0..FIT_CHANNELS,
        &mut rng,
    );
    let held_out = truth.held_out.then(|| {
        observe(
            &obj,
            truth,
            &modes,
            &gains,
            &tilts,
            FIT_CHANNELS..FIT_CHANNELS + HELD_CHANNELS,
            &mut rng,
        )
    });
    let residual_envelopes = Some(envelopes(truth, &mut rng));
    (
        Evidence {
            fit,
            held_out,
            simulated: obj.sim.clone(),
            residual_envelopes,
            split_sites: None,
        },
        obj,
    )
}

fn run(truth: &Truth, seed: u64) -> CatalogueReport {
    let (ev, _) = evidence(truth, seed);
    diagnose(&ev, &CatalogueSettings::default()).expect("synthetic evidence is valid")
}

fn accepted<'a>(report: &'a CatalogueReport, name: &str) -> Option<&'a AcceptedEffect> {
    report.accepted.iter().find(|a| a.name == name)
}

/// The rejected effect `name`, or a panic with what was accepted instead.
fn rejected<'a>(report: &'a CatalogueReport, name: &str) -> &'a RejectedEffect {
    report
        .rejected
        .iter()
        .find(|r| r.name == name)
        .unwrap_or_else(|| panic!("{name} not rejected: {:#?}", report.accepted))
}

fn param<'a>(effect: &'a AcceptedEffect, prefix: &str) -> &'a FittedParam {
    effect
        .params
        .iter()
        .find(|p| p.name.starts_with(prefix))
        .unwrap_or_else(|| panic!("no parameter {prefix} in {effect:?}"))
}

fn within_3_sigma(p: &FittedParam, truth: f64) -> bool {
    (p.value - truth).abs() <= 3.0 * p.sigma.unwrap_or(f64::INFINITY)
}

/// The accepted effect `name`, its held-out error fallen, or a panic with the report.
fn expect_accepted<'a>(report: &'a CatalogueReport, name: &str) -> &'a AcceptedEffect {
    let a = accepted(report, name).unwrap_or_else(|| {
        panic!(
            "{name} not accepted: {:#?}",
            report.rejected.iter().find(|r| r.name == name)
        )
    });
    let (b, f) = (
        a.held_out_before.expect("held-out data given"),
        a.held_out_after.expect("held-out data given"),
    );
    assert!(f < b, "{name}: held-out error {b} → {f} did not fall");
    a
}

// ---------------------------------------------------------------------------------------
// Kernels.

#[test]
fn profile_floor_matches_a_brute_force_search() {
    let mut rng = Rng(3);
    for case in 0..20 {
        let n = 5 + case;
        let v: Vec<f64> = (0..n).map(|_| 10f64.powf(rng.uniform(-4.0, 0.0))).collect();
        let true_tau2 = if case % 4 == 0 {
            0.0
        } else {
            10f64.powf(rng.uniform(-3.0, 0.0))
        };
        let r: Vec<f64> = v
            .iter()
            .map(|&v| (v + true_tau2).sqrt() * normal(&mut rng))
            .collect();
        let t = lm::profile_floor(&r, &v);
        let h = |t: f64| {
            r.iter()
                .zip(&v)
                .map(|(r, v)| (v + t).ln() + r * r / (v + t))
                .sum::<f64>()
        };
        // Brute force on a fine log grid plus t = 0.
        let mut best = h(0.0);
        for i in 0..20000 {
            best = best.min(h(1e-8 * 1e10f64.powf(i as f64 / 19999.0)));
        }
        assert!(
            h(t) <= best + 1e-6,
            "case {case}: h({t}) = {} > brute force {best}",
            h(t)
        );
        // Stationarity in the interior.
        if t > 0.0 {
            let dh: f64 = r
                .iter()
                .zip(&v)
                .map(|(r, v)| 1.0 / (v + t) - r * r / (v + t).powi(2))
                .sum();
            let scale: f64 = v.iter().map(|v| 1.0 / (v + t)).sum();
            assert!(dh.abs() < 1e-6 * scale, "case {case}: h'({t}) = {dh}");
        }
    }
    assert_eq!(lm::profile_floor(&[], &[]), 0.0);
    // Residuals smaller than their σ: no floor.
    assert_eq!(lm::profile_floor(&[0.1, -0.1, 0.05], &[1.0, 1.0, 1.0]), 0.0);
}

#[test]
fn levenberg_marquardt_solves_a_bounded_exponential_fit() {
    // y = A e^(−k t) with A = 2, k = 3 exactly: the minimum is the truth with zero cost.
    let t: Vec<f64> = (0..30).map(|i| 0.05 * i as f64).collect();
    let y: Vec<f64> = t.iter().map(|&t| 2.0 * (-3.0 * t).exp()).collect();
    let f = |x: &[f64], out: &mut [f64]| {
        for ((o, &t), &y) in out.iter_mut().zip(&t).zip(&y) {
            *o = y - x[0] * (-x[1] * t).exp();
        }
    };
    let m = lm::minimise(
        f,
        t.len(),
        &[0.5, 0.5],
        &[true, true],
        &[0.0, 0.0],
        &[10.0, 10.0],
        &[1.0, 1.0],
        200,
    );
    assert!(
        (m.x[0] - 2.0).abs() < 1e-8 && (m.x[1] - 3.0).abs() < 1e-8,
        "{m:?}"
    );
    // With k bounded above by 2.5 the answer sits on the bound and A is the best for it.
    let m = lm::minimise(
        f,
        t.len(),
        &[0.5, 0.5],
        &[true, true],
        &[0.0, 0.0],
        &[10.0, 2.5],
        &[1.0, 1.0],
        200,
    );
    assert_eq!(m.x[1], 2.5);
    let best_a = {
        let e: Vec<f64> = t.iter().map(|&t| (-2.5 * t).exp()).collect();
        e.iter().zip(&y).map(|(e, y)| e * y).sum::<f64>() / e.iter().map(|e| e * e).sum::<f64>()
    };
    assert!((m.x[0] - best_a).abs() < 1e-7, "A = {} vs {best_a}", m.x[0]);
    // Standard errors of a linear model equal the analytic (XᵀX)⁻¹ diagonal.
    let jac = nalgebra::DMatrix::from_fn(10, 2, |i, j| if j == 0 { 1.0 } else { i as f64 });
    let se = lm::standard_errors(&jac);
    let (n, sx, sxx): (f64, f64, f64) = (10.0, 45.0, 285.0);
    let det = n * sxx - sx * sx;
    assert!(
        (se[0] - (sxx / det).sqrt()).abs() < 1e-12 && (se[1] - (n / det).sqrt()).abs() < 1e-12,
        "{se:?}"
    );
}

#[test]
fn half_sine_spectrum_matches_the_excitation_module() {
    use crate::audio::excitation::ContactForce;
    use rustfft::num_complex::Complex64;
    let tau = 4e-4;
    let force = ContactForce::HalfSine { duration_s: tau };
    for i in 0..200 {
        let omega = 1.0 + i as f64 * 3.0 * PI / tau / 200.0;
        let (f, _) = force.laplace(Complex64::new(0.0, omega));
        let want = f.norm();
        let got = half_sine_spectrum(omega * tau);
        assert!(
            (got - want).abs() < 1e-9 * want.max(1e-3),
            "ωτ = {}: {got} vs {want}",
            omega * tau
        );
    }
    assert!((half_sine_spectrum(PI) - PI / 4.0).abs() < 1e-12);
    assert_eq!(half_sine_spectrum(0.0), 1.0);
}

#[test]
fn the_side_lobe_envelope_meets_the_half_sine_and_bounds_its_lobes() {
    // Equal up to u = ωT/π = 2 and continuous there; beyond, above every side lobe and
    // touching their peaks at even u; falling as u⁻².
    for i in 0..=200 {
        let u = 0.01 * i as f64;
        let x = PI * u;
        assert_eq!(half_sine_envelope(x), half_sine_spectrum(x), "u = {u}");
    }
    assert!((half_sine_envelope(PI * (2.0 + 1e-9)) - 1.0 / 3.0).abs() < 1e-8);
    for i in 1..=2000 {
        let u = 2.0 + 0.005 * i as f64;
        let x = PI * u;
        assert!(
            half_sine_envelope(x) >= half_sine_spectrum(x) - 1e-12,
            "u = {u}"
        );
    }
    for u in [4.0, 6.0, 8.0, 10.0] {
        let x = PI * u;
        assert!(
            (half_sine_envelope(x) / half_sine_spectrum(x) - 1.0).abs() < 1e-9,
            "u = {u}"
        );
    }
    let ratio = half_sine_envelope(PI * 200.0) / half_sine_envelope(PI * 100.0);
    assert!((ratio - 0.25).abs() < 1e-3, "{ratio}");
}

#[test]
fn weighted_regression_is_exact_on_a_line() {
    let pts: Vec<(f64, f64, f64)> = (0..10)
        .map(|i| (i as f64, 3.0 - 0.5 * i as f64, 1.0 + i as f64))
        .collect();
    let (slope, _) = weighted_regression(&pts);
    assert!((slope + 0.5).abs() < 1e-12);
    assert_eq!(
        weighted_regression(&[(1.0, 2.0, 1.0), (1.0, 3.0, 1.0)]),
        (0.0, 0.0)
    );
}

// ---------------------------------------------------------------------------------------
// Matching.

fn sim(f: f64, cluster: usize) -> SimulatedMode {
    SimulatedMode {
        frequency_hz: f,
        drive: 1.0,
        support_weight: 0.0,
        mass_weight: 0.0,
        cluster,
        transfer: None,
        match_frequency_hz: None,
        ln_f_per_poisson: None,
    }
}

#[test]
fn matching_finds_the_scale_clusters_and_split_partners() {
    let simulated = vec![
        sim(500.0, 0),
        sim(800.0, 1),
        sim(1200.0, 2),
        sim(1200.1, 2),
        sim(2000.0, 3),
        sim(3100.0, 4),
        sim(5000.0, 5),
    ];
    let s = 1.07;
    // Observed: 500 and 800 matched; cluster 2 unresolved (one mode); 2000 split in two
    // (0.4 %); 3100 missing; 5000 present; a spurious 4100 nothing matches.
    let obs_hz = [
        500.0 * s,
        800.0 * s * 1.01,
        1200.05 * s,
        2000.0 * s * 0.998,
        2000.0 * s * 1.002,
        4100.0,
        5000.0 * s,
    ];
    let ln: Vec<f64> = obs_hz.iter().map(|f: &f64| f.ln()).collect();
    let m = match_modes(&ln, &[], &simulated, None, &CatalogueSettings::default());
    assert!(
        (m.ln_scale - s.ln()).abs() < 0.006,
        "scale {}",
        m.ln_scale.exp()
    );
    assert_eq!(m.unmatched_observed, vec![5]);
    assert_eq!(m.unmatched_simulated, vec![5]);
    let unit = |i: usize| m.units.iter().find(|u| u.observed == i).expect("matched");
    assert_eq!(unit(2).role, Role::Single);
    assert_eq!(unit(2).represents, vec![2, 3]);
    assert_eq!(
        (unit(3).role, unit(4).role),
        (Role::SplitLower, Role::SplitUpper)
    );
    assert_eq!((unit(3).cluster, unit(4).cluster), (3, 3));
    assert!((unit(3).drive_factor - 0.5f64.sqrt()).abs() < 1e-15);
    assert_eq!(unit(6).represents, vec![6]);
    // With a fixed scale the search is skipped.
    let fixed = match_modes(
        &ln,
        &[],
        &simulated,
        Some(0.0),
        &CatalogueSettings::default(),
    );
    assert_eq!(fixed.ln_scale, 0.0);
}

fn observed_at(f: f64) -> ObservedMode {
    ObservedMode {
        frequency_hz: f,
        sigma_frequency_hz: 1e-3,
        decay_rate: 0.0,
        sigma_decay_rate: 0.0,
        amplitudes: vec![1.0, 1.0],
        sigma_amplitudes: vec![0.01, 0.01],
        early_frequency_hz: None,
        late_frequency_hz: None,
        glide: None,
    }
}

#[test]
fn extra_poles_of_a_partial_join_its_cluster_and_far_modes_stay_unmatched() {
    // A real partial recorded as several poles (the bowl's near 1680 Hz: five within 0.5 %):
    // the first split pair takes the cluster, the other poles within the largest pair split
    // join it as extra poles; a mode 4.6 % from everything stays unmatched.
    let simulated = vec![
        sim(1000.0, 0),
        sim(1000.2, 0),
        sim(1700.0, 1),
        sim(2600.0, 2),
        sim(4000.0, 3),
    ];
    let obs_hz = [
        1000.0,
        998.0,
        1001.5,
        1003.0,
        1700.0,
        2600.0 * 0.996,
        2600.0 * 1.004,
        2600.0 * 1.009,
        4000.0,
        3100.0,
    ];
    let ln: Vec<f64> = obs_hz.iter().map(|f: &f64| f.ln()).collect();
    let m = match_modes(
        &ln,
        &[],
        &simulated,
        Some(0.0),
        &CatalogueSettings::default(),
    );
    assert_eq!(m.unmatched_observed, vec![9], "{m:#?}");
    // Which poles of a partial become its split pair is the matching's choice; the others are
    // its extra poles: two beside the partial near 1000 Hz, one beside 2600 Hz.
    let mut extra: Vec<(usize, usize)> = m.extra_poles.iter().map(|&(i, _, c)| (i, c)).collect();
    extra.sort_unstable();
    let per_cluster = |c: usize| extra.iter().filter(|e| e.1 == c).count();
    assert_eq!(
        (per_cluster(0), per_cluster(2), extra.len()),
        (2, 1, 3),
        "{m:#?}"
    );
    // Extra poles carry no rows: every unit is one of the matched modes.
    assert!(m
        .units
        .iter()
        .all(|u| !extra.iter().any(|e| e.0 == u.observed)));
}

#[test]
fn faint_poles_beside_a_partial_are_not_its_split_pair() {
    // A degenerate cluster simulated at 1000 Hz, recorded 1 % higher at 1010 Hz, with two poles
    // 70 dB fainter at 999 and 1001 Hz (a room's response around the partial): by frequency
    // alone the faint two are the closer "split pair"; they are extra poles of the partial.
    let simulated = vec![sim(1000.0, 0), sim(1000.2, 0), sim(2000.0, 1)];
    let obs_hz = [999.0, 1001.0, 1010.0, 2000.0];
    let ln: Vec<f64> = obs_hz.iter().map(|f: &f64| f.ln()).collect();
    let loud = 1.0f64.ln();
    let faint = (10.0f64.powf(-70.0 / 20.0)).ln();
    let levels = [faint, faint, loud, loud];
    let settings = CatalogueSettings::default();
    let m = match_modes(&ln, &levels, &simulated, Some(0.0), &settings);
    assert_eq!(m.faint, vec![true, true, false, false]);
    let unit = |i: usize| m.units.iter().find(|u| u.observed == i);
    assert_eq!(
        unit(2).map(|u| (u.role, u.cluster)),
        Some((Role::Single, 0)),
        "{m:#?}"
    );
    let mut extra: Vec<usize> = m.extra_poles.iter().map(|&(i, _, _)| i).collect();
    extra.sort_unstable();
    assert_eq!(extra, vec![0, 1], "{m:#?}");
    // Nor may a faint pole be swapped in for the partial.
    assert!(m.with_swap(&ln, &simulated, 2, 0, &settings).is_none());
    // By frequency alone (no levels, or the rule off) they take the cluster as a pair.
    for m in [
        match_modes(&ln, &[], &simulated, Some(0.0), &settings),
        match_modes(
            &ln,
            &levels,
            &simulated,
            Some(0.0),
            &CatalogueSettings {
                faint_pole_db: f64::INFINITY,
                ..CatalogueSettings::default()
            },
        ),
    ] {
        assert_eq!(unit_role(&m, 0), Some(Role::SplitLower), "{m:#?}");
        assert_eq!(unit_role(&m, 1), Some(Role::SplitUpper), "{m:#?}");
    }
    // 30 dB is not faint: a beating pair's members are of comparable level.
    let quieter = [
        loud - 30.0 / 20.0 * std::f64::consts::LN_10,
        loud,
        loud,
        loud,
    ];
    assert!(faint_poles(&ln, &quieter, &settings).iter().all(|&f| !f));
}

fn unit_role(m: &Matching, observed: usize) -> Option<Role> {
    m.units
        .iter()
        .find(|u| u.observed == observed)
        .map(|u| u.role)
}

#[test]
fn extra_poles_change_no_decision_on_clean_evidence() {
    // The clean baseline of `clean_evidence_recovers_the_baseline_and_accepts_nothing`, with
    // two faint extra poles beside cluster 5's mode (−0.4 %, +0.6 %): they are matched to it as
    // extra poles, nothing is unmatched and nothing is accepted.
    let (mut ev, _) = evidence(&Truth::default(), 5);
    let k = 5;
    for factor in [0.996, 1.006] {
        let mut extra = ev.fit[k].clone();
        extra.frequency_hz *= factor;
        extra.amplitudes.iter_mut().for_each(|a| *a *= 0.1);
        extra.sigma_amplitudes.iter_mut().for_each(|a| *a *= 0.1);
        ev.fit.push(extra);
    }
    let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    // One of the two may become the partial's split partner instead; both are matched.
    let in_cluster = report
        .matching
        .pairs
        .iter()
        .filter(|p| p.cluster == k)
        .count();
    assert_eq!(
        report.matching.extra_poles.len() + in_cluster,
        3,
        "{:#?}",
        report.matching
    );
    assert!(
        report.matching.unmatched_observed.is_empty(),
        "{:#?}",
        report.matching
    );
    assert!(report.accepted.is_empty(), "{:#?}", report.accepted);
}

#[test]
fn the_pole_readings_cost_on_threads_give_the_same_report() {
    // Extra poles beside three clusters' modes give the pole choice (matching step 6) readings
    // to cost in each round; on one thread or three the report must be the same, to the bit.
    let (mut ev, _) = evidence(&Truth::default(), 5);
    for (k, factor, level) in [
        (3, 1.004, 0.3),
        (5, 0.996, 0.1),
        (5, 1.006, 0.5),
        (7, 0.995, 0.4),
    ] {
        let mut extra = ev.fit[k].clone();
        extra.frequency_hz *= factor;
        extra.amplitudes.iter_mut().for_each(|a| *a *= level);
        extra.sigma_amplitudes.iter_mut().for_each(|a| *a *= level);
        ev.fit.push(extra);
    }
    let one = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    assert!(
        !one.matching.extra_poles.is_empty(),
        "the pole choice had no reading to weigh: {:#?}",
        one.matching
    );
    let three = diagnose(
        &ev,
        &CatalogueSettings {
            threads: Some(3),
            ..CatalogueSettings::default()
        },
    )
    .expect("valid");
    assert_eq!(format!("{one:?}"), format!("{three:?}"));
}

#[test]
fn a_pair_split_as_the_mesh_splits_it_stands_for_its_own_members() {
    // Cluster 1: members at 1000 and 1002 Hz (split 2·10⁻³) with unlike drives and transfers.
    let mut simulated = vec![
        sim(500.0, 0),
        sim(1000.0, 1),
        sim(1002.0, 1),
        sim(2000.0, 2),
    ];
    (simulated[1].drive, simulated[2].drive) = (1.0, 0.2);
    (simulated[1].mass_weight, simulated[2].mass_weight) = (1.0, 0.0);
    for m in simulated.iter_mut() {
        m.transfer = Some(vec![1.0, 1.0]);
    }
    simulated[1].transfer = Some(vec![4.0, 1.0]);
    simulated[2].transfer = Some(vec![1.0, 4.0]);
    let settings = CatalogueSettings::default();
    let table_for = |upper_hz: f64, z: f64| {
        let observed: Vec<ObservedMode> = [500.0, 1000.0, upper_hz, 2000.0]
            .iter()
            .map(|&f| observed_at(f))
            .collect();
        let ln: Vec<f64> = observed.iter().map(|m| m.frequency_hz.ln()).collect();
        let matching = match_modes(&ln, &[], &simulated, Some(0.0), &settings);
        ModeTable::build(&observed, &simulated, &matching, 0, z)
    };
    let pair = |t: &ModeTable| -> (ModeEntry, ModeEntry) {
        let find = |role: Role| {
            t.modes
                .iter()
                .find(|m| m.role == role)
                .expect("split pair matched")
                .clone()
        };
        (find(Role::SplitLower), find(Role::SplitUpper))
    };
    // The observed split equals the simulated one: each observed mode is its own member.
    let (lower, upper) = pair(&table_for(1002.0, DEFAULT_OWN_MEMBER_SPLIT_Z));
    assert_eq!(
        (lower.simulated.clone(), upper.simulated.clone()),
        (vec![1], vec![2])
    );
    assert!(
        (lower.drive - 1.0).abs() < 1e-12 && (upper.drive - 0.2).abs() < 1e-12,
        "{lower:?} {upper:?}"
    );
    assert_eq!((lower.mass_weight, upper.mass_weight), (1.0, 0.0));
    assert_eq!(
        (
            lower.transfer.clone().unwrap(),
            upper.transfer.clone().unwrap()
        ),
        (vec![4.0, 1.0], vec![1.0, 4.0])
    );
    // 10 % wider than the simulated split: within 3κ (κ = 5 %), still the mesh's own split.
    let (lower, upper) = pair(&table_for(1002.2, DEFAULT_OWN_MEMBER_SPLIT_Z));
    assert_eq!(
        (lower.simulated.clone(), upper.simulated.clone()),
        (vec![1], vec![2])
    );
    // Split 3× or 20 % wider than the simulated one (a beating pair): the orientation is
    // unknown, both pooled.
    let pooled_drive = (1.0f64 + 0.04).sqrt() * 0.5f64.sqrt();
    for (t, why) in [
        (
            table_for(1006.0, DEFAULT_OWN_MEMBER_SPLIT_Z),
            "split 3× the simulated",
        ),
        (
            table_for(1002.4, DEFAULT_OWN_MEMBER_SPLIT_Z),
            "split 20 % wider than the simulated",
        ),
        (table_for(1002.0, 0.0), "own_member_split_z = 0"),
    ] {
        let (lower, upper) = pair(&t);
        assert_eq!(
            (lower.simulated.clone(), upper.simulated.clone()),
            (vec![1, 2], vec![1, 2]),
            "{why}"
        );
        assert!(
            (lower.drive - pooled_drive).abs() < 1e-12
                && (upper.drive - pooled_drive).abs() < 1e-12,
            "{why}"
        );
    }
    // The helper on its own: singles never have an own member.
    let observed: Vec<ObservedMode> = [500.0, 1000.0, 1002.0, 2000.0]
        .iter()
        .map(|&f| observed_at(f))
        .collect();
    let ln: Vec<f64> = observed.iter().map(|m| m.frequency_hz.ln()).collect();
    let matching = match_modes(&ln, &[], &simulated, Some(0.0), &settings);
    let own = own_members(&observed, &simulated, &matching, 3.0);
    for (u, o) in matching.units.iter().zip(&own) {
        assert_eq!(o.is_some(), u.role != Role::Single, "{u:?}");
    }
}

/// A simulation carrying a mass: a degenerate pair at 1000 Hz (baseline, the mass taken out)
/// whose loaded members lie at 970 and 1000 Hz, between lone modes at 500 and 2000 Hz; the
/// observed modes at the loaded frequencies. Returns the simulated and observed modes, and the
/// table's split pair (lower, upper).
fn loaded_pair() -> (Vec<SimulatedMode>, Vec<ObservedMode>, ModeEntry, ModeEntry) {
    let mut simulated = vec![
        sim(500.0, 0),
        sim(1000.0, 1),
        sim(1000.0, 1),
        sim(2000.0, 2),
    ];
    let loaded_hz = [500.0, 970.0, 1000.0, 2000.0];
    for (m, &f) in simulated.iter_mut().zip(&loaded_hz) {
        m.match_frequency_hz = Some(f);
    }
    (simulated[1].mass_weight, simulated[2].mass_weight) = (1.0, 0.0);
    let settings = CatalogueSettings::default();
    let observed: Vec<ObservedMode> = loaded_hz.iter().map(|&f| observed_at(f)).collect();
    let ln: Vec<f64> = observed.iter().map(|m| m.frequency_hz.ln()).collect();
    let matching = match_modes(&ln, &[], &simulated, Some(0.0), &settings);
    let table = ModeTable::build(
        &observed,
        &simulated,
        &matching,
        0,
        DEFAULT_OWN_MEMBER_SPLIT_Z,
    );
    let find = |role: Role| {
        table
            .modes
            .iter()
            .find(|m| m.role == role)
            .expect("split pair matched")
            .clone()
    };
    let (lower, upper) = (find(Role::SplitLower), find(Role::SplitUpper));
    (simulated, observed, lower, upper)
}

#[test]
fn a_loaded_simulation_is_matched_by_its_loaded_frequencies() {
    // The observed pair splits by 3 %, twice `max_pair_split`. Matched by the loaded
    // frequencies, each observed mode finds its own member and stands for it (its mass
    // weight), so an added mass reproduces the split; the baseline frequency stays the
    // unloaded one.
    let settings = CatalogueSettings::default();
    let (simulated, observed, lower, upper) = loaded_pair();
    let ln: Vec<f64> = observed.iter().map(|m| m.frequency_hz.ln()).collect();
    assert_eq!(
        (lower.simulated.clone(), upper.simulated.clone()),
        (vec![1], vec![2])
    );
    assert_eq!((lower.mass_weight, upper.mass_weight), (1.0, 0.0));
    assert!(
        (lower.ln_f_sim - 1000f64.ln()).abs() < 1e-12,
        "baseline is the unloaded frequency: {lower:?}"
    );
    // Without the loaded frequencies the same observations overflow max_pair_split: one of the
    // pair is dropped from the cluster.
    let unloaded: Vec<SimulatedMode> = simulated
        .iter()
        .cloned()
        .map(|mut m| {
            m.match_frequency_hz = None;
            m
        })
        .collect();
    let plain = match_modes(&ln, &[], &unloaded, Some(0.0), &settings);
    assert!(
        !plain.units.iter().any(|u| u.role == Role::SplitLower),
        "{plain:?}"
    );
    assert!(
        (lower.ln_f_carried - 970f64.ln()).abs() < 1e-12,
        "the loaded frequency is kept beside it: {lower:?}"
    );
    // A bad match frequency is an input error.
    let (mut ev, _) = evidence(&Truth::default(), 1);
    ev.simulated[0].match_frequency_hz = Some(-1.0);
    assert!(matches!(
        diagnose(&ev, &settings),
        Err(CatalogueError::InvalidSimulated {
            field: "match_frequency_hz",
            ..
        })
    ));
    // So is a sensitivity to ν that is not a number.
    let (mut ev, _) = evidence(&Truth::default(), 1);
    ev.simulated[0].ln_f_per_poisson = Some(f64::NAN);
    assert!(matches!(
        diagnose(&ev, &settings),
        Err(CatalogueError::InvalidSimulated {
            field: "ln_f_per_poisson",
            ..
        })
    ));
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    let (ev, _) = evidence(&Truth::default(), 1);
    let settings = CatalogueSettings::default();
    let mut e = ev.clone();
    e.fit[2].sigma_frequency_hz = 0.0;
    assert!(matches!(
        diagnose(&e, &settings),
        Err(CatalogueError::InvalidObserved {
            index: 2,
            field: "sigma_frequency_hz",
            ..
        })
    ));
    let mut e = ev.clone();
    e.fit[1].amplitudes.pop();
    assert!(matches!(
        diagnose(&e, &settings),
        Err(CatalogueError::ChannelMismatch { index: 1, .. })
    ));
    let mut e = ev.clone();
    e.simulated[0].support_weight = 1.5;
    assert!(matches!(
        diagnose(&e, &settings),
        Err(CatalogueError::InvalidSimulated { index: 0, .. })
    ));
    let mut e = ev.clone();
    e.simulated[0].transfer = Some(vec![1.0; 5]);
    assert!(matches!(
        diagnose(&e, &settings),
        Err(CatalogueError::TransferLength {
            found: 5,
            fit: 4,
            total: 7,
            ..
        })
    ));
    let mut e = ev.clone();
    e.residual_envelopes.as_mut().expect("given").energy[0].pop();
    assert!(matches!(
        diagnose(&e, &settings),
        Err(CatalogueError::InvalidEnvelopes(_))
    ));
    // Two simulated modes cannot carry the baseline.
    let mut e = ev.clone();
    e.simulated.truncate(2);
    assert!(matches!(
        diagnose(&e, &settings),
        Err(CatalogueError::TooFewMatches { matched: 2, .. })
    ));
    let e = Evidence {
        fit: vec![],
        ..ev.clone()
    };
    assert_eq!(
        diagnose(&e, &settings).unwrap_err(),
        CatalogueError::NoObservedModes
    );
    let bad = CatalogueSettings {
        max_pair_split: 0.5,
        ..CatalogueSettings::default()
    };
    assert!(matches!(
        diagnose(&ev, &bad),
        Err(CatalogueError::InvalidSetting {
            name: "max_pair_split",
            ..
        })
    ));
    for z in [-1.0, f64::NAN, f64::INFINITY] {
        let bad = CatalogueSettings {
            own_member_split_z: z,
            ..CatalogueSettings::default()
        };
        let err = diagnose(&ev, &bad).unwrap_err();
        assert!(
            matches!(
                err,
                CatalogueError::InvalidSetting {
                    name: "own_member_split_z",
                    ..
                }
            ),
            "{z}: {err:?}"
        );
        assert!(err.to_string().contains("must be finite and ≥ 0"), "{err}");
    }
    for (bad, name) in [
        (
            CatalogueSettings {
                max_amplitude_tilt: f64::NAN,
                ..CatalogueSettings::default()
            },
            "max_amplitude_tilt",
        ),
        (
            CatalogueSettings {
                max_amplitude_tilt: -1.0,
                ..CatalogueSettings::default()
            },
            "max_amplitude_tilt",
        ),
        (
            CatalogueSettings {
                level_prior_rows: f64::NAN,
                ..CatalogueSettings::default()
            },
            "level_prior_rows",
        ),
        (
            CatalogueSettings {
                level_prior_rows: -4.0,
                ..CatalogueSettings::default()
            },
            "level_prior_rows",
        ),
        (
            CatalogueSettings {
                faint_pole_db: 0.0,
                ..CatalogueSettings::default()
            },
            "faint_pole_db",
        ),
        (
            CatalogueSettings {
                faint_pole_db: f64::NAN,
                ..CatalogueSettings::default()
            },
            "faint_pole_db",
        ),
    ] {
        let err = diagnose(&ev, &bad).unwrap_err();
        assert!(
            matches!(err, CatalogueError::InvalidSetting { name: n, .. } if n == name),
            "{name}: {err:?}"
        );
    }
}

// ---------------------------------------------------------------------------------------
// Clean evidence.

#[test]
fn clean_evidence_recovers_the_baseline_and_accepts_nothing() {
    let truth = Truth::default();
    let report = run(&truth, 11);
    assert!(report.accepted.is_empty(), "{:#?}", report.accepted);
    let p = &report.baseline.params;
    let get = |name: &str| p.iter().find(|q| q.name == name).expect(name);
    assert!(
        within_3_sigma(get("frequency scale s"), truth.ln_s.exp()),
        "{:?}",
        get("frequency scale s")
    );
    assert!(
        within_3_sigma(get("Rayleigh α"), truth.alpha),
        "{:?}",
        get("Rayleigh α")
    );
    assert!(
        within_3_sigma(get("Rayleigh β"), truth.beta),
        "{:?}",
        get("Rayleigh β")
    );
    assert_eq!(report.matching.pairs.len(), CLUSTERS);
    assert!(
        report.matching.unmatched_observed.is_empty()
            && report.matching.unmatched_simulated.is_empty()
    );
    assert!(report.unexplained.is_empty(), "{:#?}", report.unexplained);
    // The report is plain data.
    let json = serde_json::to_string(&report).expect("serialises");
    let back: CatalogueReport = serde_json::from_str(&json).expect("deserialises");
    assert_eq!(back.accepted.len(), 0);
    assert_eq!(back.residuals.len(), report.residuals.len());
}

// ---------------------------------------------------------------------------------------
// One effect at a time, at a realistic strength: accepted, held-out error down, parameters
// within 3σ of the truth.

/// A power law is named by the `power_law` variant (the law itself, charged nothing beyond
/// Rayleigh's two parameters), with its exponent and its rate at the reference within 3σ.
#[test]
fn non_rayleigh_power_law_is_found_and_its_exponent_recovered() {
    // d ∝ f^0.7 (a near-constant loss factor), 5 1/s at 1 kHz.
    let truth = Truth {
        power_law: Some((5.0, 0.7)),
        ..Truth::default()
    };
    let report = run(&truth, 21);
    let a = expect_accepted(&report, "non_rayleigh_damping");
    assert_eq!(a.variant, "power_law", "{a:?}");
    let exponent = param(a, "damping exponent p");
    assert!(within_3_sigma(exponent, 0.7), "{exponent:?}");
    let rate = a
        .params
        .iter()
        .find(|p| p.name.starts_with("decay rate at "))
        .expect("the rate at the reference");
    let f: f64 = rate
        .name
        .trim_start_matches("decay rate at ")
        .trim_end_matches(" Hz")
        .parse()
        .expect("reference frequency in the name");
    // The name rounds the reference to 1 Hz: allow the law's change over half a hertz.
    let want = 5.0 * (f / 1000.0).powf(0.7);
    assert!(
        (rate.value - want).abs() <= 3.0 * rate.sigma.expect("determined") + 0.7 * 0.5 / f * want,
        "{rate:?} vs {want}"
    );
    assert_eq!(report.accepted.len(), 1, "{:#?}", report.accepted);
}

/// A damping law that bends in log–log (Rayleigh's own shape beyond its reach: flat at the
/// bottom, steep at the top, here a loss with a knee) is named by the three-knot curve, which
/// the power law cannot follow.
#[test]
fn a_bending_damping_law_is_found_by_the_three_knot_curve() {
    // Constant 4 1/s up to 2 kHz, then rising as f^1.8: a knee the power law cannot bend.
    let truth = Truth {
        power_law: Some((4.0, 0.0)),
        knee: Some((2000.0, 1.8)),
        ..Truth::default()
    };
    let report = run(&truth, 23);
    let a = expect_accepted(&report, "non_rayleigh_damping");
    assert_eq!(a.variant, "three_knot_log_log", "{a:?}");
}

#[test]
fn beating_pairs_are_found_and_their_splits_recovered() {
    // Two degenerate pairs split by 0.4 % and 0.2 %.
    let truth = Truth {
        splits: vec![(3, 0.004), (8, 0.002)],
        ..Truth::default()
    };
    let report = run(&truth, 22);
    let a = expect_accepted(&report, "beating_pair");
    assert_eq!(a.params.len(), 2, "{a:?}");
    for (cluster, delta) in [(3, 0.004), (8, 0.002)] {
        let p = param(a, &format!("relative split δf/f of cluster {cluster} "));
        assert!(within_3_sigma(p, delta), "{p:?} vs {delta}");
    }
    assert_eq!(report.accepted.len(), 1, "{:#?}", report.accepted);

    // A lone simulated mode seen as two: not a beating pair (nothing is degenerate there),
    // but the split stays in the data and is reported as unexplained.
    let truth = Truth {
        splits: vec![(5, 0.004)],
        ..Truth::default()
    };
    let report = run(&truth, 22);
    assert!(
        report.accepted.iter().all(|a| a.name != "beating_pair"),
        "{:#?}",
        report.accepted
    );
    assert!(
        report
            .unexplained
            .iter()
            .any(|u| u.quantity == Some(Quantity::Split)),
        "{:#?}",
        report.unexplained
    );
}

/// A carried mass's footprint is what the loaded line match knows least, so a split row of a
/// pair the mass moves is trusted only to [`CARRIED_MASS_SPLIT_FLOOR`] of the mass's shift of
/// the pair's centre (`model.rs`); a pair it leaves in place keeps the σ of its measurements
/// and the mesh's split.
#[test]
fn a_carried_mass_loosens_the_split_rows_of_the_pairs_it_moves() {
    let (_, _, lower, upper) = loaded_pair();
    let measured = lower.sigma_ln_f.powi(2) + upper.sigma_ln_f.powi(2);
    let mesh = (SPLIT_MODEL_FLOOR * (upper.ln_f_sim - lower.ln_f_sim)).powi(2);
    // Loaded centre ½(ln 970 + ln 1000) against the unloaded ln 1000.
    let shift = 0.5 * (1000.0f64 / 970.0).ln();
    let sigma = split_sigma(&lower, &upper);
    let expected = (measured + mesh + (CARRIED_MASS_SPLIT_FLOOR * shift).powi(2)).sqrt();
    assert!(
        (sigma - expected).abs() <= 1e-12 * expected,
        "{sigma} against {expected}"
    );
    assert!(sigma > 0.4 * shift, "{sigma} against a shift of {shift}");
    // The same pair without a carried mass.
    let (mut l0, mut u0) = (lower.clone(), upper.clone());
    l0.ln_f_carried = l0.ln_f_sim;
    u0.ln_f_carried = u0.ln_f_sim;
    let plain = split_sigma(&l0, &u0);
    assert!(
        (plain - (measured + mesh).sqrt()).abs() <= 1e-12 * plain,
        "{plain}"
    );
    assert!(plain < 0.1 * sigma, "{plain} against {sigma}");
}

/// Evidence with clusters 3 and 8 split by 0.4 % and 0.2 %, and the observed (lower, upper)
/// poles of cluster 3 as the catalogue matches them.
fn two_split_pairs() -> (Evidence, usize, usize) {
    let truth = Truth {
        splits: vec![(3, 0.004), (8, 0.002)],
        ..Truth::default()
    };
    let (ev, _) = evidence(&truth, 22);
    let first = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    let pole = |role: Role| {
        first
            .matching
            .pairs
            .iter()
            .find(|p| p.cluster == 3 && p.role == role)
            .expect("cluster 3 is seen split")
            .observed
    };
    let (lower, upper) = (pole(Role::SplitLower), pole(Role::SplitUpper));
    (ev, lower, upper)
}

/// Splits are set last (parent docs, "Selection"): a mass that lowers a pair's two members by
/// different amounts moves the pair's centre, but the split predicted is the one a
/// split-setting term set, whether the mass entered before or after it. With the terms applied
/// in the order of acceptance, the mass after the free splits changed the split (blind seed 109
/// case 001).
#[test]
fn a_split_set_by_a_term_is_the_split_predicted_whatever_entered_after_it() {
    let settings = CatalogueSettings::default();
    let (ev, _, _) = two_split_pairs();
    let (mut table, _, ln_scale) = fit_and_held_tables(&ev, &settings);
    let pair = *table
        .pairs
        .iter()
        .find(|p| p.cluster == 3)
        .expect("cluster 3 is seen split");
    table.modes[pair.lower].mass_weight = 1.0;
    table.modes[pair.upper].mass_weight = 0.2;
    let (delta, mu) = (3e-3, 0.5);
    let splits = || SplitClusters {
        clusters: vec![3],
        centre_hz: vec![1.0],
    };
    let setters: [(Arc<dyn Term>, Vec<f64>); 3] = [
        (Arc::new(PairSplits { splits: splits() }), vec![delta]),
        (
            Arc::new(added_mass::LoweredMembers { splits: splits() }),
            vec![delta],
        ),
        (
            Arc::new(support_contact::RaisedMembers { splits: splits() }),
            vec![0.0, delta],
        ),
    ];
    let mass: Arc<dyn Term> = Arc::new(MassLoading { fluid_ln_f1: None });
    let predict = |terms: Vec<(Arc<dyn Term>, Vec<f64>)>| {
        let model = Model::new(
            terms.iter().map(|(t, _)| t.clone()).collect(),
            ln_scale,
            table.channels,
        );
        let mut x = vec![0.0; model.n_params()];
        x[0] = ln_scale;
        for (i, (_, p)) in terms.iter().enumerate() {
            let off = model.term_offset(i);
            x[off..off + p.len()].copy_from_slice(p);
        }
        let p = model.prediction(&table, &x);
        (p.ln_f[pair.lower], p.ln_f[pair.upper])
    };
    for (setter, p) in &setters {
        let alone = predict(vec![(setter.clone(), p.clone())]);
        let after = predict(vec![(setter.clone(), p.clone()), (mass.clone(), vec![mu])]);
        let before = predict(vec![(mass.clone(), vec![mu]), (setter.clone(), p.clone())]);
        for (l, u) in [alone, after, before] {
            assert!(
                ((u - l) - delta).abs() < 1e-12,
                "{}: split {} where the term set {delta}",
                setter.variant(),
                u - l
            );
        }
        assert_eq!(after, before, "{}", setter.variant());
        // The mass still lowers the pair: at least by the smaller member's drop.
        let smaller = 0.5 * (1.0 + mu * 0.2_f64).ln();
        assert!(
            after.0 < alone.0 - 0.9 * smaller && after.1 < alone.1 - 0.9 * smaller,
            "{}: {alone:?} → {after:?}",
            setter.variant()
        );
    }
}

/// Beating accepted for cluster 8 (its split recovered) but not for cluster 3.
fn assert_only_cluster_8_split(report: &CatalogueReport) {
    let a = expect_accepted(report, "beating_pair");
    assert!(
        a.params.iter().all(|p| !p.name.contains("cluster 3 ")),
        "{a:?}"
    );
    assert!(
        within_3_sigma(param(a, "relative split δf/f of cluster 8 "), 0.002),
        "{a:?}"
    );
}

/// A split that the held-out microphones hear at other frequencies is not the object's (a
/// room puts poles near each partial, different in every microphone): moving the held-out
/// pole of cluster 3's lower member by a quarter of the split leaves only cluster 8 split;
/// removing it altogether (the held-out microphones near that member's node) contradicts
/// nothing, and both splits are found.
#[test]
fn a_pair_the_held_out_recordings_hear_elsewhere_is_not_a_beating_pair() {
    let (ev, lower, upper) = two_split_pairs();
    let (fl, fu) = (ev.fit[lower].frequency_hz, ev.fit[upper].frequency_hz);
    let nearest = |held: &[ObservedMode]| {
        (0..held.len())
            .min_by(|&a, &b| {
                (held[a].frequency_hz - fl)
                    .abs()
                    .total_cmp(&(held[b].frequency_hz - fl).abs())
            })
            .expect("held-out poles")
    };
    let mut moved = ev.clone();
    let held = moved.held_out.as_mut().expect("held-out microphones");
    let i = nearest(held);
    assert!((held[i].frequency_hz - fl).abs() < 0.05 * (fu - fl));
    held[i].frequency_hz = fl - 0.25 * (fu - fl);
    let report = diagnose(&moved, &CatalogueSettings::default()).expect("valid");
    assert_only_cluster_8_split(&report);

    let mut unheard = ev.clone();
    let held = unheard.held_out.as_mut().expect("held-out microphones");
    let i = nearest(held);
    held.remove(i);
    let report = diagnose(&unheard, &CatalogueSettings::default()).expect("valid");
    let a = expect_accepted(&report, "beating_pair");
    assert!(
        within_3_sigma(param(a, "relative split δf/f of cluster 3 "), 0.004),
        "{a:?}"
    );
}

/// The replication screen of a split member: contradicted only when the held-out extraction
/// has a pole within half the split of it and none agrees with it within 3σ (σ with a tenth of
/// its linewidth); no pole near it, or one that agrees, contradicts nothing.
#[test]
fn a_split_member_is_contradicted_only_by_held_out_poles_near_it_that_disagree() {
    use super::beating_pair::member_contradicted;
    // 2000 Hz, d = 20 1/s (linewidth 3.18 Hz, floor 0.32 Hz), split 1 % (half: 10 Hz).
    let (ln_f, sigma, d, split) = (2000f64.ln(), 1e-5, 20.0, 0.01);
    let at = |fs: &[f64]| fs.iter().map(|&f| observed_at(f)).collect::<Vec<_>>();
    assert!(!member_contradicted(ln_f, sigma, d, split, &at(&[])));
    assert!(!member_contradicted(ln_f, sigma, d, split, &at(&[2000.5])));
    assert!(member_contradicted(ln_f, sigma, d, split, &at(&[2001.5])));
    assert!(member_contradicted(
        ln_f,
        sigma,
        d,
        split,
        &at(&[1996.0, 2004.0])
    ));
    assert!(!member_contradicted(
        ln_f,
        sigma,
        d,
        split,
        &at(&[1996.0, 2000.1])
    ));
    assert!(!member_contradicted(ln_f, sigma, d, split, &at(&[2011.0])));
    // A broader member (d = 200 1/s, floor 3.2 Hz) is located less sharply.
    assert!(!member_contradicted(
        ln_f,
        sigma,
        200.0,
        split,
        &at(&[2004.0])
    ));
}

/// A pair whose slower pole decays far more slowly than the damping law there (3 × below it:
/// a reverberant tail at the room's rate) is not the other half of a split degenerate mode.
#[test]
fn a_pair_whose_slower_pole_is_far_below_the_law_is_not_a_beating_pair() {
    let (mut ev, _, upper) = two_split_pairs();
    ev.fit[upper].decay_rate /= 3.0;
    ev.fit[upper].sigma_decay_rate /= 3.0;
    let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    assert_only_cluster_8_split(&report);
}

/// A local loss on a split pair (a support point or a flaw at one member's antinode) damps
/// one member more: the pair, its slower member on the law, is still a split pair.
#[test]
fn a_pair_with_a_local_loss_on_one_member_is_still_a_beating_pair() {
    let (mut ev, _, upper) = two_split_pairs();
    ev.fit[upper].decay_rate *= 1.5;
    let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    let a = expect_accepted(&report, "beating_pair");
    assert!(
        within_3_sigma(param(a, "relative split δf/f of cluster 3 "), 0.004),
        "{a:?}"
    );
    assert!(
        within_3_sigma(param(a, "relative split δf/f of cluster 8 "), 0.002),
        "{a:?}"
    );
}

/// Matching step 6: a broad, weak pole that sits right on the simulated cluster (closer than
/// either pole of the true split pair) takes a slot by frequency alone; the baseline's
/// likelihood gives the slot back to the partial's own pole, and the split is recovered.
#[test]
fn the_partials_own_poles_win_over_a_closer_broad_pole() {
    let (mut ev, lower, upper) = two_split_pairs();
    let scale = diagnose(&ev, &CatalogueSettings::default())
        .expect("valid")
        .matching
        .scale;
    let centre = ev
        .simulated
        .iter()
        .filter(|m| m.cluster == 3)
        .map(|m| m.frequency_hz)
        .sum::<f64>()
        / ev.simulated.iter().filter(|m| m.cluster == 3).count() as f64;
    let mut broad = ev.fit[lower].clone();
    broad.frequency_hz = centre * scale;
    broad.decay_rate *= 8.0;
    broad.sigma_decay_rate *= 8.0;
    for a in broad.amplitudes.iter_mut() {
        *a *= 0.3;
    }
    let broad_index = ev.fit.len();
    ev.fit.push(broad);
    let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    let mut chosen: Vec<usize> = report
        .matching
        .pairs
        .iter()
        .filter(|p| p.cluster == 3)
        .map(|p| p.observed)
        .collect();
    chosen.sort_unstable();
    let mut truth = vec![lower, upper];
    truth.sort_unstable();
    assert_eq!(
        chosen, truth,
        "broad pole {broad_index}: {:#?}",
        report.matching
    );
    let a = expect_accepted(&report, "beating_pair");
    assert!(
        within_3_sigma(param(a, "relative split δf/f of cluster 3 "), 0.004),
        "{a:?}"
    );
}

/// Two poles centred far from their cluster (3 % below it, while every other match sits on
/// its model frequency) are not identified with it: not a beating pair, whatever their split.
#[test]
fn a_pair_centred_far_from_its_cluster_is_not_a_beating_pair() {
    let (mut ev, lower, upper) = two_split_pairs();
    let members = [lower, upper];
    for &i in &members {
        ev.fit[i].frequency_hz *= 0.97;
    }
    let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    assert!(
        report
            .matching
            .pairs
            .iter()
            .filter(|p| p.cluster == 3 && p.role != Role::Single)
            .count()
            == 2,
        "still matched as a pair: {:#?}",
        report.matching.pairs
    );
    assert_only_cluster_8_split(&report);
    assert!(
        report
            .unexplained
            .iter()
            .any(|u| members.contains(&u.observed) && u.quantity == Some(Quantity::LnFrequency)),
        "{:#?}",
        report.unexplained
    );
}

/// A split narrower than the pair's own measured glide lies inside the range the mode sweeps:
/// not a beating pair. The same split with a glide narrower than it still is.
#[test]
fn a_split_inside_its_glide_sweep_is_not_a_beating_pair() {
    let (ev, _, upper) = two_split_pairs();
    let with_glide = |g: f64| {
        let mut ev = ev.clone();
        ev.fit[upper].glide = Some((g, 0.05 * g));
        diagnose(&ev, &CatalogueSettings::default()).expect("valid")
    };
    assert_only_cluster_8_split(&with_glide(0.006));
    let report = with_glide(0.002);
    let a = expect_accepted(&report, "beating_pair");
    assert!(
        within_3_sigma(param(a, "relative split δf/f of cluster 3 "), 0.004),
        "{a:?}"
    );
}

/// The two poles of a pair split by less than its glide, gliding opposite ways, are one
/// partial followed by the extraction, not two glide measurements: the table keeps one glide
/// row, the louder pole's (`model::shadow_glide_fragments`; generator 2's seed 191 case 004,
/// +5.8·10⁻³ on the louder pole and −1.2·10⁻² on one 5 × weaker 1 Hz above). Both are kept
/// when they glide the same way (two modes that both glide: generator 2's set m5003 case 010)
/// or when the split is wider than either glide.
#[test]
fn the_weaker_pole_of_a_pair_inside_its_glide_has_no_glide_row() {
    let settings = CatalogueSettings::default();
    let (ev, lower, upper) = two_split_pairs();
    // Cluster 3 is split by 0.4 %; the upper pole is made 5 × weaker.
    let glide_rows = |g_lower: f64, g_upper: f64| {
        let mut ev = ev.clone();
        for a in &mut ev.fit[upper].amplitudes {
            *a *= 0.2;
        }
        ev.fit[lower].glide = Some((g_lower, 1e-4));
        ev.fit[upper].glide = Some((g_upper, 1e-4));
        let (table, _, _) = fit_and_held_tables(&ev, &settings);
        let pair = *table
            .pairs
            .iter()
            .find(|p| p.cluster == 3)
            .expect("cluster 3 is seen split");
        let has_row = |k: usize| table.rows.iter().any(|r| r.kind == RowKind::Glide(k));
        (has_row(pair.lower), has_row(pair.upper))
    };
    // Inside the sweep (|g| 1 % > the split), opposite signs: only the louder pole's row.
    assert_eq!(glide_rows(0.006, -0.01), (true, false));
    assert_eq!(glide_rows(-0.01, 0.006), (true, false));
    // The same sign: both.
    assert_eq!(glide_rows(0.006, 0.01), (true, true));
    // Opposite signs, but the split (0.4 %) wider than either glide: both.
    assert_eq!(glide_rows(0.002, -0.003), (true, true));
}

/// A split pair with a third pole of its partial within one split of it is one choice among a
/// comb (a room's fine structure), not two modes beating: a pole half a split above cluster
/// 3's upper member at half the weaker member's level leaves only cluster 8 split. The same
/// pole at 5 % of that level (under `COMB_LEVEL`), or two splits away, leaves both.
#[test]
fn a_pair_among_more_poles_of_its_partial_is_not_a_beating_pair() {
    let (ev, lower, upper) = two_split_pairs();
    let with_pole = |offset_splits: f64, level: f64| {
        let mut ev = ev.clone();
        let (l, u) = (&ev.fit[lower], &ev.fit[upper]);
        let mut third = u.clone();
        third.frequency_hz = u.frequency_hz + offset_splits * (u.frequency_hz - l.frequency_hz);
        for (a, (al, au)) in third
            .amplitudes
            .iter_mut()
            .zip(l.amplitudes.iter().zip(&u.amplitudes))
        {
            *a = level * al.min(*au);
        }
        for (s, a) in third.sigma_amplitudes.iter_mut().zip(&third.amplitudes) {
            *s = 0.01 * a;
        }
        third.glide = None;
        ev.fit.push(third);
        diagnose(&ev, &CatalogueSettings::default()).expect("valid")
    };
    assert_only_cluster_8_split(&with_pole(0.5, 0.5));
    for (offset, level) in [(0.5, 0.05), (2.0, 0.5)] {
        let report = with_pole(offset, level);
        let a = expect_accepted(&report, "beating_pair");
        assert!(
            within_3_sigma(param(a, "relative split δf/f of cluster 3 "), 0.004),
            "pole {offset} splits above at {level}: {a:?}"
        );
    }
}

#[test]
fn support_contact_damping_and_stiffening_are_recovered() {
    let truth = Truth {
        support: Some((6.0, 0.008)),
        ..Truth::default()
    };
    let report = run(&truth, 23);
    let a = expect_accepted(&report, "support_contact");
    assert_eq!(a.variant, "damping_and_frequency");
    assert!(within_3_sigma(param(a, "support damping γ"), 6.0), "{a:?}");
    assert!(
        within_3_sigma(param(a, "support frequency shift κ"), 0.008),
        "{a:?}"
    );
    assert_eq!(report.accepted.len(), 1, "{:#?}", report.accepted);
}

/// A damping support whose spring shifts the frequencies by κ_s w (f₁/f)² (1 % at the lowest
/// mode for w = 1, falling as 1/f²) is found as a spring, the law its frequencies follow, and
/// nothing else is named.
#[test]
fn support_contact_spring_is_recovered_as_a_spring() {
    for seed in [23, 24, 25] {
        let truth = Truth {
            support: Some((6.0, 0.0)),
            spring: Some(0.01),
            ..Truth::default()
        };
        let report = run(&truth, seed);
        let a = expect_accepted(&report, "support_contact");
        assert_eq!(a.variant, "damping_and_spring", "seed {seed}: {a:?}");
        assert!(within_3_sigma(param(a, "support damping γ"), 6.0), "{a:?}");
        assert_eq!(
            report.accepted.len(),
            1,
            "seed {seed}: {:#?}",
            report.accepted
        );
    }
}

#[test]
fn a_support_that_does_not_damp_is_not_named() {
    // No damping, with (1) a stiffening of 10⁻⁴ at w = 1, far below what a finite-element
    // model is trusted to though the synthetic frequencies resolve it, and (2) the recovery
    // test's κ = 0.008, well resolved: a pattern of frequency shifts that follows the support
    // weights, but no energy lost at the contact, which every passive support takes (module
    // docs of support_contact; the rule before set 3 named case 2).
    for kappa in [1e-4, 0.008] {
        let truth = Truth {
            support: Some((0.0, kappa)),
            ..Truth::default()
        };
        let report = run(&truth, 23);
        assert!(
            accepted(&report, "support_contact").is_none(),
            "κ = {kappa}: {:#?}",
            report.accepted
        );
        let r = rejected(&report, "support_contact");
        assert_eq!(r.reason, Rejection::SignatureMissing, "κ = {kappa}: {r:?}");
    }
    // (3) A lossless spring: a shift that falls as 1/f², as a support's spring makes, and no
    // damping.
    let truth = Truth {
        spring: Some(0.01),
        ..Truth::default()
    };
    let report = run(&truth, 23);
    assert!(
        accepted(&report, "support_contact").is_none(),
        "spring: {:#?}",
        report.accepted
    );
}

/// Evidence of an object whose damping law the baseline cannot follow (a power law with a
/// 15 % misfit per cluster, common to both modes of a pair) and whose support damps by
/// Δd = γ w: six split pairs resolved in the simulation (members 0.2 % apart) and six lone
/// modes, support weights ≤ 0.005 with the lowest pair's members at 0.003 and 0.0045. Decay
/// rates measured to 0.3 %, as the extraction measures a clean recording's.
fn support_pair_evidence(gamma: f64, seed: u64) -> Evidence {
    let mut rng = Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1);
    let gains: Vec<f64> = (0..FIT_CHANNELS + HELD_CHANNELS)
        .map(|_| rng.uniform(-1.0, 1.0) - 3.0)
        .collect();
    let mut simulated = Vec::new();
    // (simulated index, true decay, ln amplitude without the channel gain)
    let mut truth = Vec::new();
    for cluster in 0..12 {
        let f = 800.0 * 1.35f64.powi(cluster);
        let misfit = (0.15 * normal(&mut rng)).exp();
        let members: Vec<f64> = if cluster % 2 == 0 {
            vec![f, f * 1.002]
        } else {
            vec![f]
        };
        for (slot, &fm) in members.iter().enumerate() {
            let w = match (cluster, slot) {
                (0, 0) => 0.003,
                (0, _) => 0.0045,
                _ => 0.005 * rng.next().powi(3),
            };
            let drive: f64 = rng.uniform(0.3, 1.0);
            let d = 2.5 * (fm / 1000.0).powf(0.7) * misfit + gamma * w;
            truth.push((simulated.len(), d, drive.ln() + (2.0 * PI * fm).ln()));
            simulated.push(SimulatedMode {
                frequency_hz: fm,
                drive,
                support_weight: w,
                mass_weight: 0.0,
                cluster: cluster as usize,
                transfer: None,
                match_frequency_hz: None,
                ln_f_per_poisson: None,
            });
        }
    }
    let truth: Vec<(f64, f64, f64)> = truth
        .iter()
        .map(|&(j, d, ln_amp)| (simulated[j].frequency_hz * 1.01, d, ln_amp))
        .collect();
    observed_evidence(&truth, &gains, 0.003, simulated, &mut rng)
}

#[test]
fn a_support_that_damps_one_mode_of_a_pair_more_is_found_under_a_damping_law_misfit() {
    // γ = 50 1/s: the lowest pair's modes (d ≈ 2.2 1/s) gain 0.150 and 0.225 1/s, a decay
    // split of 3 %, which the 15 % law misfit hides mode by mode but not within the pair.
    for seed in [1, 2, 3] {
        let report = diagnose(
            &support_pair_evidence(50.0, seed),
            &CatalogueSettings::default(),
        )
        .expect("valid evidence");
        let a = expect_accepted(&report, "support_contact");
        assert!(
            within_3_sigma(param(a, "support damping γ"), 50.0),
            "seed {seed}: {a:?}"
        );
        let clean = diagnose(
            &support_pair_evidence(0.0, seed),
            &CatalogueSettings::default(),
        )
        .expect("valid evidence");
        assert!(
            accepted(&clean, "support_contact").is_none(),
            "seed {seed}: {:#?}",
            clean.accepted
        );
    }
}

/// The same pairs, each split by less than its own measured glide (0.4 %, the members 0.2 %
/// apart): two poles of one gliding mode, not the two members as the model has them, so the
/// difference of their decay rates is not a support's to claim (`ModeTable::
/// resolve_split_weights` pools their weights; generator 2's seed 31 case 022).
#[test]
fn a_pair_inside_its_glide_is_not_a_supports_split() {
    for seed in [1, 2, 3] {
        let mut ev = support_pair_evidence(50.0, seed);
        for m in ev.fit.iter_mut().chain(ev.held_out.iter_mut().flatten()) {
            m.glide = Some((0.004, 1e-4));
        }
        let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid evidence");
        assert!(
            accepted(&report, "support_contact").is_none(),
            "seed {seed}: {:#?}",
            report.accepted
        );
    }
}

/// Pairs that a support strip splits beyond any law the model has: in each of six degenerate
/// pairs the member pressing into the support (support weight 0.6–1, the other ≈ 0) is raised
/// by its own 0.2–0.6 % and damped by γ w_k, the other member stays on the model. A spring law
/// δ ∝ w (f_ref/f)² would not fit these rises (they are drawn independently), so only free
/// per-pair rises can; the pressing member's extra decay says whose they are (generator 2's
/// seed 65 case 011, a tube on a strip, was named a beating pair).
fn support_raise_evidence(gamma: f64, seed: u64) -> Evidence {
    let mut rng = Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1);
    let gains: Vec<f64> = (0..FIT_CHANNELS + HELD_CHANNELS)
        .map(|_| rng.uniform(-1.0, 1.0) - 3.0)
        .collect();
    let mut simulated = Vec::new();
    let mut truth = Vec::new();
    for cluster in 0..12 {
        let f = 800.0 * 1.35f64.powi(cluster);
        let members: Vec<f64> = if cluster % 2 == 0 {
            vec![f, f * 1.0003]
        } else {
            vec![f]
        };
        let rise = rng.uniform(0.002, 0.006);
        for (slot, &fm) in members.iter().enumerate() {
            let (w, up) = match (members.len(), slot) {
                (2, 0) => (0.02 * rng.next(), 0.0),
                (2, _) => (rng.uniform(0.6, 1.0), rise),
                _ => (0.3 * rng.next(), 0.0),
            };
            let drive: f64 = rng.uniform(0.3, 1.0);
            let d = 2.5 * (fm / 1000.0).powf(1.2) + gamma * w;
            truth.push((fm * 1.01 * (1.0 + up), d, drive.ln() + (2.0 * PI * fm).ln()));
            simulated.push(SimulatedMode {
                frequency_hz: fm,
                drive,
                support_weight: w,
                mass_weight: 0.0,
                cluster: cluster as usize,
                transfer: None,
                match_frequency_hz: None,
                ln_f_per_poisson: None,
            });
        }
    }
    observed_evidence(&truth, &gains, 0.01, simulated, &mut rng)
}

#[test]
fn a_support_that_raises_and_damps_the_pressing_members_is_a_support_not_a_beating_pair() {
    for seed in [1, 2, 3] {
        let report = diagnose(
            &support_raise_evidence(1.5, seed),
            &CatalogueSettings::default(),
        )
        .expect("valid evidence");
        let a = expect_accepted(&report, "support_contact");
        assert_eq!(a.variant, "raised_members", "seed {seed}: {a:?}");
        assert!(
            within_3_sigma(param(a, "support damping γ"), 1.5),
            "seed {seed}: {a:?}"
        );
        assert!(
            accepted(&report, "beating_pair").is_none(),
            "seed {seed}: {:#?}",
            report.accepted
        );
        // The same rises without the damping: nothing says they are a support's.
        let undamped = diagnose(
            &support_raise_evidence(0.0, seed),
            &CatalogueSettings::default(),
        )
        .expect("valid evidence");
        assert!(
            accepted(&undamped, "support_contact").is_none(),
            "seed {seed}: {:#?}",
            undamped.accepted
        );
    }
}

/// One mode alone moving at the support (the others' weights 0), its decay rate 0.4 1/s
/// (15 %) above the damping law: a free decay for one mode, the law's own misfit there, not a
/// support (generator 2's seed 71 case 016, a uniform-shift cup whose lowest mode alone moved
/// at the foot ring).
#[test]
fn one_mode_alone_at_the_support_is_not_a_support() {
    let evidence = |seed: u64| {
        let mut ev = support_pair_evidence(0.0, seed);
        for m in ev.simulated.iter_mut() {
            m.support_weight = 0.0;
        }
        ev.simulated[2].support_weight = 1.0;
        let f = ev.simulated[2].frequency_hz * 1.01;
        for m in ev.fit.iter_mut().chain(ev.held_out.iter_mut().flatten()) {
            if (m.frequency_hz / f - 1.0).abs() < 1e-3 {
                m.decay_rate += 0.4;
            }
        }
        ev
    };
    for seed in [1, 2, 3] {
        let report = diagnose(&evidence(seed), &CatalogueSettings::default()).expect("valid");
        assert!(
            accepted(&report, "support_contact").is_none(),
            "seed {seed}: {:#?}",
            report.accepted
        );
        let r = rejected(&report, "support_contact");
        assert!(
            r.detail.contains("move at the support"),
            "seed {seed}: {r:?}"
        );
    }
}

/// The half-sine duration whose spectrum best matches a Hertzian pulse of duration `t_h` on
/// the modes' frequencies (up to a constant, which the gains absorb): the pseudo-true value
/// the misspecified fit converges to.
fn pseudo_true_half_sine(t_h: f64, omegas: &[f64]) -> f64 {
    let cost = |t: f64| {
        let d: Vec<f64> = omegas
            .iter()
            .map(|&w| hertz_spectrum(w, t_h).ln() - half_sine_spectrum(w * t).ln())
            .collect();
        let mean = d.iter().sum::<f64>() / d.len() as f64;
        d.iter().map(|x| (x - mean).powi(2)).sum::<f64>()
    };
    let (mut a, mut b) = (0.2 * t_h, 1.5 * t_h);
    for _ in 0..100 {
        let (c, d) = (a + 0.382 * (b - a), a + 0.618 * (b - a));
        if cost(c) < cost(d) {
            b = d;
        } else {
            a = c;
        }
    }
    0.5 * (a + b)
}

#[test]
fn hertzian_contact_is_found_by_the_half_sine_model() {
    // A hard mallet: the Hertzian pulse puts the top mode (7 kHz) ~10 dB down.
    let t_h = 1.6e-4;
    let truth = Truth {
        hertz: Some(t_h),
        ..Truth::default()
    };
    let (ev, _) = evidence(&truth, 24);
    let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    let a = expect_accepted(&report, "contact_duration");
    let omegas: Vec<f64> = report
        .matching
        .pairs
        .iter()
        .map(|p| 2.0 * PI * p.observed_hz)
        .collect();
    let t_star = pseudo_true_half_sine(t_h, &omegas);
    let p = param(a, "contact duration T");
    assert!(
        within_3_sigma(p, t_star),
        "{p:?} vs pseudo-true {t_star} (Hertz {t_h})"
    );
    assert_eq!(report.accepted.len(), 1, "{:#?}", report.accepted);
}

#[test]
fn a_soft_contact_beyond_its_first_null_is_not_taken_by_the_tilt() {
    // A 0.5 ms Hertzian contact (first null near 3 kHz, inside the 450 Hz–7 kHz band) on a
    // velocity response (tilt −1): past the null the levels fall about as f⁻² more, which
    // tilts of −3 beyond the acceleration law would take whole. The contact is named by its
    // knee, which no tilt takes: the screen profiles a slope with each duration, and the fit
    // starts with the envelope's own slope taken off the tilts, so it is found whether the
    // tilts are held to their physical bound (±3) or let go to ±6 (as in a room). Before
    // either (stop 51) it was found in 3 of 6 bounded and 0 of 6 loose.
    let truth = Truth {
        hertz: Some(5e-4),
        tilt: -1.0,
        ..Truth::default()
    };
    let mut found = Vec::new();
    for seed in 40..46 {
        let (ev, _) = evidence(&truth, seed);
        let bounded = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
        let loose = diagnose(
            &ev,
            &CatalogueSettings {
                max_amplitude_tilt: 6.0,
                ..CatalogueSettings::default()
            },
        )
        .expect("valid");
        found.push((
            accepted(&bounded, "contact_duration").is_some(),
            accepted(&loose, "contact_duration").is_some(),
        ));
    }
    // Measured: bounded 6 of 6, loose 6 of 6.
    let bounded = found.iter().filter(|f| f.0).count();
    let loose = found.iter().filter(|f| f.1).count();
    assert!(bounded >= 5 && loose >= 5, "{found:?}");
}

/// A 0.4 ms Hertzian (sin^1.5) contact: its first null at u = 3.5, 4.4 kHz, inside the
/// 450 Hz–7 kHz band. The contact is named, a pulse with its null in the band (`sine_power`,
/// or `hertz_pulse`, the same pulse with Hertz's p = 1.5) takes it in at least 2 of 4 draws,
/// and the null it places ((p + 2)/(2T): T and p alone are confounded) is within 10 % of the
/// truth's.
#[test]
fn a_contact_whose_first_null_is_inside_the_band_is_named_with_its_null() {
    let t_h = 4e-4;
    let null_hz = 3.5 / (2.0 * t_h);
    let mut named = 0;
    let mut nulls = Vec::new();
    let mut variants = Vec::new();
    for seed in 60..64 {
        let (ev, _) = evidence(
            &Truth {
                hertz: Some(t_h),
                ..Truth::default()
            },
            seed,
        );
        let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
        let Some(a) = accepted(&report, "contact_duration") else {
            continue;
        };
        named += 1;
        if a.variant == "sine_power" || a.variant == "hertz_pulse" {
            nulls.push(param(a, super::FIRST_NULL_PARAM).value);
        }
        variants.push(a.variant.clone());
    }
    println!("variants {variants:?}, nulls {nulls:?} against {null_hz} Hz");
    assert!(named >= 3, "named in {named} of 4");
    assert!(
        nulls.len() >= 2 && nulls.iter().all(|f| (f / null_hz - 1.0).abs() < 0.1),
        "nulls {nulls:?} against {null_hz} Hz"
    );
}

#[test]
fn room_reverberation_is_found_in_the_residual_envelopes() {
    let truth = Truth {
        reverb_t60: Some(0.4),
        ..Truth::default()
    };
    let report = run(&truth, 25);
    let a = expect_accepted(&report, "reverb_noise");
    assert!(
        within_3_sigma(param(a, "reverberation time T60"), 0.4),
        "{a:?}"
    );
    let noise = report.noise.as_ref().expect("envelopes given");
    // The floor fitted under the reverberant model is the true floor, which the pre-roll
    // estimates within its 10 % scatter.
    assert!(noise.excess_db.iter().all(|e| e.abs() < 1.5), "{noise:?}");
    assert_eq!(report.accepted.len(), 1, "{:#?}", report.accepted);
}

#[test]
fn a_bands_frames_count_by_the_independent_values_they_hold() {
    // The room of the test above, its envelopes declared as frames that overlap ever more:
    // the same energies then hold fewer independent values, and at 10⁴ frames per window no
    // band's own likelihood ratio is significant, so the room is no longer named.
    let truth = Truth {
        reverb_t60: Some(0.4),
        ..Truth::default()
    };
    let (mut ev, _) = evidence(&truth, 25);
    ev.residual_envelopes
        .as_mut()
        .expect("envelopes")
        .frames_per_window = 2.0;
    let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    expect_accepted(&report, "reverb_noise");
    ev.residual_envelopes
        .as_mut()
        .expect("envelopes")
        .frames_per_window = 1e4;
    let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    let r = rejected(&report, "reverb_noise");
    assert_eq!(r.reason, Rejection::SignatureMissing, "{r:?}");
    // Fewer than one frame per window is not an STFT.
    ev.residual_envelopes
        .as_mut()
        .expect("envelopes")
        .frames_per_window = 0.5;
    assert!(matches!(
        diagnose(&ev, &CatalogueSettings::default()),
        Err(CatalogueError::InvalidEnvelopes(_))
    ));
}

#[test]
fn an_excess_in_one_band_is_a_local_misfit_not_a_room() {
    // The same strike, its residual clean in every band but the top one, which carries a
    // reverberant-looking excess: one band is not a room.
    let (mut ev, _) = evidence(&Truth::default(), 25);
    let env = ev.residual_envelopes.as_mut().expect("envelopes");
    let top = env.energy.len() - 1;
    let times = env.times_s.clone();
    for (e, t) in env.energy[top].iter_mut().zip(times) {
        *e *= 1.0 + 30.0 * (-13.815510557964274 * t / 0.4).exp();
    }
    let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    let r = rejected(&report, "reverb_noise");
    assert_eq!(r.reason, Rejection::SignatureMissing, "{r:?}");
    assert!(
        r.delta_bic.expect("fitted") > 2.0,
        "the likelihood alone would have taken it: {r:?}"
    );
}

#[test]
fn a_smooth_misfit_band_does_not_capture_the_rooms_decay() {
    // A room (T60 = 0.4 s) plus one band holding a mode the extraction left in, at a constant,
    // slowly rising level 60 dB over the floor: with its tiny profiled σ that band alone would
    // set the shared T60 (module docs); floored at the median band's σ it does not.
    let (mut ev, _) = evidence(
        &Truth {
            reverb_t60: Some(0.4),
            ..Truth::default()
        },
        25,
    );
    let env = ev.residual_envelopes.as_mut().expect("envelopes");
    let top = env.energy.len() - 1;
    let floor = env.noise_floor_estimate[top];
    env.energy[top] = env
        .times_s
        .iter()
        .map(|&t| 1e6 * floor * (1.0 + 0.3 * t))
        .collect();
    let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    let a = expect_accepted(&report, "reverb_noise");
    assert!(
        within_3_sigma(param(a, "reverberation time T60"), 0.4),
        "{a:?}"
    );
}

/// What a room does to the modes that decay faster than it (parent docs, "A room holds up the
/// fast modes"): the pole read at such a mode's frequency is the room's tail as much as the
/// mode's, decaying at d_room (d_k/d_room)^¼ rather than d_k, and its level is lowered by
/// d_room/d_k. The observed decay rates and levels of `modes` are changed so.
fn held_up_by_the_room(modes: &mut [ObservedMode], t60: f64) {
    let d_room = 6.907755278982137 / t60;
    for m in modes {
        let ratio = m.decay_rate / d_room;
        if ratio > 1.0 {
            m.decay_rate = d_room * ratio.powf(0.25);
            m.sigma_decay_rate = SIGMA_LN_D * m.decay_rate;
            for (a, s) in m.amplitudes.iter_mut().zip(&mut m.sigma_amplitudes) {
                *a /= ratio;
                *s /= ratio;
            }
        }
    }
}

/// A room slower than every mode (T60 = 3 s, 2.3 1/s) holds all of them: only frequencies
/// are left, and the diagnosis still runs (the gains and tilts then rest on no rows).
#[test]
fn a_room_that_holds_every_mode_leaves_a_diagnosis_of_the_frequencies() {
    let truth = Truth {
        reverb_t60: Some(3.0),
        ..Truth::default()
    };
    let (mut ev, _) = evidence(&truth, 11);
    held_up_by_the_room(&mut ev.fit, 3.0);
    held_up_by_the_room(ev.held_out.as_mut().expect("held out"), 3.0);
    let report = diagnose(&ev, &CatalogueSettings::default()).expect("a report, not an error");
    let held = report
        .matching
        .room_held
        .as_ref()
        .expect("the room is established");
    assert_eq!(held.frequencies_hz.len(), report.matching.pairs.len());
    assert!(
        report.accepted.iter().all(|a| a.name == "reverb_noise"),
        "{:?}",
        report.accepted
    );
}

#[test]
fn modes_held_by_the_room_keep_their_frequency_rows_and_lose_their_decay_and_level_rows() {
    // Two split pairs (clusters 3 and 8), so that a pair with one member held falls back to
    // the other member's own ln d row.
    let truth = Truth {
        splits: vec![(3, 0.004), (8, 0.004)],
        ..Truth::default()
    };
    let (ev, _) = evidence(&truth, 7);
    let (mut table, _, _) = fit_and_held_tables(&ev, &CatalogueSettings::default());
    let before = table.clone();
    let decay = |m: &model::ModeEntry| m.ln_d.map(|(v, _)| v.exp());
    // Between two observed decay rates: some modes above, some below.
    let mut rates: Vec<f64> = table.modes.iter().filter_map(decay).collect();
    rates.sort_by(f64::total_cmp);
    let d_room = 0.5 * (rates[rates.len() / 2] + rates[rates.len() / 2 + 1]);
    let held = table.set_aside_room_held(d_room);
    let expected: Vec<usize> = (0..before.modes.len())
        .filter(|&k| decay(&before.modes[k]).is_some_and(|d| d >= d_room))
        .collect();
    assert_eq!(held, expected);
    assert!(!held.is_empty() && held.len() < before.modes.len());
    let count =
        |t: &ModeTable, q: Quantity| t.rows.iter().filter(|r| r.kind.quantity() == q).count();
    for q in [Quantity::LnFrequency, Quantity::Split, Quantity::Glide] {
        assert_eq!(count(&table, q), count(&before, q), "{q:?}");
    }
    let touches = |kind: model::RowKind, k: usize| {
        let (a, b) = kind.modes();
        a == k || b == Some(k)
    };
    for &k in &held {
        assert!(table.modes[k].ln_d.is_none());
        assert!(table.modes[k].ln_a.iter().all(Option::is_none));
        for r in &table.rows {
            let q = r.kind.quantity();
            if touches(r.kind, k) {
                assert!(
                    !matches!(
                        q,
                        Quantity::LnDecay | Quantity::DecaySplit | Quantity::LnAmplitude
                    ),
                    "row {:?} of held mode {k} stays",
                    r.kind
                );
            }
        }
        assert!(table.amplitude_groups.iter().all(|(m, _)| *m != k));
    }
    // Every mode not held keeps a decay row: its own, or its pair's mean.
    for k in (0..table.modes.len()).filter(|k| !held.contains(k)) {
        if table.modes[k].ln_d.is_some() {
            assert!(
                table
                    .rows
                    .iter()
                    .any(|r| touches(r.kind, k) && r.kind.quantity() == Quantity::LnDecay),
                "mode {k} lost its decay row"
            );
        }
    }
    // The other rows are indexed afresh.
    assert_eq!(
        table.other_rows.len()
            + table
                .amplitude_groups
                .iter()
                .map(|g| g.1.len())
                .sum::<usize>(),
        table.rows.len()
    );
}

#[test]
fn a_room_holds_up_the_fast_modes_and_no_damping_law_or_contact_is_made_of_it() {
    // A clean object under Rayleigh damping (2 + 1.5·10⁻⁸ ω² 1/s: 7 to 31 1/s over 3 to 7
    // kHz) in a room of T60 = 0.4 s (17.3 1/s): the modes above about 5 kHz decay faster than
    // the room, so their poles decay near the room's rate and their levels fall with their
    // own decay rate, which a flatter damping law and a contact's low-pass both imitate.
    let truth = Truth {
        reverb_t60: Some(0.4),
        ..Truth::default()
    };
    let off = CatalogueSettings {
        room_held_rows: false,
        ..CatalogueSettings::default()
    };
    let (mut claimed_with, mut claimed_without) = (0, 0);
    for seed in 0..6 {
        let (mut ev, _) = evidence(&truth, 2000 + seed);
        held_up_by_the_room(&mut ev.fit, 0.4);
        held_up_by_the_room(ev.held_out.as_mut().expect("held out"), 0.4);
        let modal = |r: &CatalogueReport| r.accepted.iter().any(|a| a.name != "reverb_noise");
        let with = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
        expect_accepted(&with, "reverb_noise");
        let held = with
            .matching
            .room_held
            .as_ref()
            .expect("the room is established");
        assert!((12.0..20.0).contains(&held.room_decay_rate), "{held:?}");
        assert!(!held.frequencies_hz.is_empty(), "{held:?}");
        claimed_with += usize::from(modal(&with));
        let without = diagnose(&ev, &off).expect("valid");
        assert!(without.matching.room_held.is_none());
        claimed_without += usize::from(modal(&without));
        eprintln!(
            "seed {seed}: with {:?}, without {:?}",
            with.accepted.iter().map(|a| &a.name).collect::<Vec<_>>(),
            without.accepted.iter().map(|a| &a.name).collect::<Vec<_>>()
        );
    }
    assert_eq!(claimed_with, 0, "a modal effect claimed in a room");
    assert!(
        claimed_without >= 3,
        "the room's hold was claimed in {claimed_without} of 6 without the rule"
    );
}

#[test]
fn radiation_with_known_transfer_recovers_unit_exponent() {
    let truth = Truth {
        radiation: Some(Pattern::Lobes),
        transfer_in_evidence: true,
        ..Truth::default()
    };
    let report = run(&truth, 26);
    let a = expect_accepted(&report, "radiation");
    assert_eq!(a.variant, "transfer");
    assert!(
        within_3_sigma(param(a, "transfer exponent η"), 1.0),
        "{a:?}"
    );
    assert_eq!(report.accepted.len(), 1, "{:#?}", report.accepted);
}

#[test]
fn radiation_without_positions_is_a_microphone_dependent_finding() {
    // Monopole + dipole along the strike axis, ln|1 + β_k cos(φ − θ)|: not rank one in ln a
    // (the factor model's form), but dominated by one pattern across the microphones.
    let truth = Truth {
        radiation: Some(Pattern::Axis),
        ..Truth::default()
    };
    let report = run(&truth, 27);
    let a = expect_accepted(&report, "radiation");
    assert_eq!(a.variant, "factor");
    assert!(a.params.len() >= CLUSTERS, "{a:?}");
}

#[test]
fn added_mass_and_fluid_loading_are_told_apart() {
    let truth = Truth {
        added_mass: Some(0.06),
        ..Truth::default()
    };
    let report = run(&truth, 28);
    let a = expect_accepted(&report, "added_mass");
    assert_eq!(a.variant, "added_mass");
    assert!(
        within_3_sigma(param(a, "added-mass ratio μ"), 0.06),
        "{a:?}"
    );
    assert_eq!(report.accepted.len(), 1, "{:#?}", report.accepted);

    let truth = Truth {
        fluid: Some(0.08),
        ..Truth::default()
    };
    let report = run(&truth, 29);
    let a = expect_accepted(&report, "added_mass");
    assert_eq!(a.variant, "fluid_loading");
    assert!(
        within_3_sigma(param(a, "fluid added-mass ratio μ_f"), 0.08),
        "{a:?}"
    );
    assert_eq!(report.accepted.len(), 1, "{:#?}", report.accepted);
}

#[test]
fn pitch_glide_is_found_and_its_coefficient_recovered() {
    // 0.1 % downward glide of the most energetic mode, from the true (noise-free) energies.
    let truth = Truth {
        glide: Some(1e-3),
        ..Truth::default()
    };
    let report = run(&truth, 30);
    let a = expect_accepted(&report, "pitch_glide");
    assert_eq!(a.variant, "energy_power_law", "{a:?}");
    // The truth's energies carry each mode's level error (±40 %), which the model's energy
    // (drive² alone) cannot know: g refers to the matched mode of the largest drive rather than
    // to the most energetic true mode, so it is compared to 25 %, not to its σ (measured:
    // 0.88·10⁻³).
    let g = param(a, "relative glide g").value;
    assert!((g / 1e-3 - 1.0).abs() < 0.25, "{a:?}");
    // The truth's law is the energy itself: no power of f on top.
    let p = param(a, "exponent p");
    assert!(within_3_sigma(p, 0.0) && p.value.abs() < 0.2, "{a:?}");
    assert_eq!(report.accepted.len(), 1, "{:#?}", report.accepted);
}

/// One simulated mode the recording does not hold, far above the band, with a drive 2000
/// times any other (generator 2's seed 139 case 014: a plate mode at the strike vertex): the
/// glide is still found with its coefficient, because g is the glide of the fit's most
/// energetic *matched* mode. With Q² relative to that one mode (before stop 72) every matched
/// covariate was 2.5·10⁻⁷ of it, g would have had to be 4·10³, and the fit was held to ±0.2.
#[test]
fn one_unheard_mode_with_a_huge_drive_does_not_hide_a_glide() {
    let truth = Truth {
        glide: Some(1e-3),
        ..Truth::default()
    };
    let (mut ev, _) = evidence(&truth, 30);
    let loudest = ev.simulated.iter().map(|m| m.drive).fold(0.0, f64::max);
    let top = ev
        .simulated
        .iter()
        .max_by(|a, b| a.frequency_hz.total_cmp(&b.frequency_hz))
        .expect("modes")
        .clone();
    let cluster = ev.simulated.iter().map(|m| m.cluster).max().unwrap_or(0) + 1;
    ev.simulated.push(SimulatedMode {
        frequency_hz: 3.0 * top.frequency_hz,
        drive: 2000.0 * loudest,
        cluster,
        match_frequency_hz: None,
        ..top
    });
    let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    let a = expect_accepted(&report, "pitch_glide");
    let g = param(a, "relative glide g").value;
    assert!((g / 1e-3 - 1.0).abs() < 0.25, "{a:?}");
}

#[test]
fn a_glide_below_the_physical_minimum_is_not_named() {
    // Every mode measured gliding by g ± σ_g (the chirp fit's observable), the same in fit and
    // held-out data.
    let with_glide = |g: f64| {
        let (mut ev, _) = evidence(&Truth::default(), 30);
        for m in ev.fit.iter_mut().chain(ev.held_out.iter_mut().flatten()) {
            m.glide = Some((g, 0.1 * g));
        }
        diagnose(&ev, &CatalogueSettings::default()).expect("valid")
    };
    // 5·10⁻⁵ at 10 σ per mode: significant, but below MIN_GLIDE.
    let report = with_glide(0.5 * pitch_glide::MIN_GLIDE);
    let r = rejected(&report, "pitch_glide");
    assert_eq!(r.reason, Rejection::DetectorFoundNothing, "{r:?}");
    let report = with_glide(5.0 * pitch_glide::MIN_GLIDE);
    let a = expect_accepted(&report, "pitch_glide");
    assert!(
        within_3_sigma(param(a, "relative glide g"), 5.0 * pitch_glide::MIN_GLIDE),
        "{a:?}"
    );
}

/// The blind benchmark's seed 202 case 021: every well-resolved mode measured the injected
/// uniform glide to 10⁻⁴ of itself, but a few fast-decaying high modes came out with glides of
/// either sign, far beyond their stated σ. Under a Gaussian likelihood those rows set the glide
/// floor with or without the effect and the glide gained ΔBIC 0.08; the Student-t rows
/// (parent docs, "Likelihood") let the many agreeing modes speak.
#[test]
fn a_glide_is_found_past_a_few_wild_glide_measurements() {
    let g = 3.3e-3;
    let (mut ev, _) = evidence(&Truth::default(), 33);
    for set in std::iter::once(&mut ev.fit).chain(ev.held_out.iter_mut()) {
        let n = set.len();
        for (i, m) in set.iter_mut().enumerate() {
            // The top fifth of the modes by frequency: wild glides of alternating sign.
            let wild = i >= n - n / 5;
            m.glide = Some(if wild {
                (if i % 2 == 0 { -2.0 } else { 2.5 } * g, 0.1 * g)
            } else {
                (g, 1e-3 * g)
            });
        }
    }
    let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    let a = expect_accepted(&report, "pitch_glide");
    assert!(
        (param(a, "relative glide g").value / g - 1.0).abs() < 1e-2,
        "{a:?}"
    );
}

#[test]
fn two_effects_together_are_both_found() {
    let truth = Truth {
        power_law: Some((5.0, 0.7)),
        added_mass: Some(0.06),
        ..Truth::default()
    };
    let report = run(&truth, 31);
    expect_accepted(&report, "non_rayleigh_damping");
    let a = expect_accepted(&report, "added_mass");
    assert!(
        within_3_sigma(param(a, "added-mass ratio μ"), 0.06),
        "{a:?}"
    );
    let truth = Truth {
        hertz: Some(1.6e-4),
        splits: vec![(13, 0.003)],
        ..Truth::default()
    };
    let report = run(&truth, 32);
    expect_accepted(&report, "contact_duration");
    expect_accepted(&report, "beating_pair");
    assert!(
        report.final_model.held_out_error < report.baseline.held_out_error,
        "{:?} vs {:?}",
        report.final_model,
        report.baseline
    );
}

#[test]
fn a_lone_off_mode_is_unexplained_and_a_spurious_mode_unmatched() {
    let (mut ev, _) = evidence(&Truth::default(), 33);
    // Mode 9 off by 1.5 % in frequency: no catalogue effect makes one mode alone move.
    ev.fit[9].frequency_hz *= 1.015;
    if let Some(h) = ev.held_out.as_mut() {
        h[9].frequency_hz *= 1.015;
    }
    // A mode at a frequency the simulation does not have (between clusters 15 and 16).
    let mut spurious = ev.fit[15].clone();
    spurious.frequency_hz *= 1.075;
    ev.fit.push(spurious);
    let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    assert!(
        report
            .unexplained
            .iter()
            .any(|u| u.observed == 9 && u.quantity == Some(Quantity::LnFrequency)),
        "{:#?}",
        report.unexplained
    );
    let last = ev.fit.len() - 1;
    assert!(
        report
            .unexplained
            .iter()
            .any(|u| u.observed == last && u.quantity.is_none()),
        "{:#?}",
        report.unexplained
    );
    assert!(report.matching.unmatched_observed.contains(&last));
}

#[test]
fn without_held_out_data_effects_are_not_confirmed() {
    let truth = Truth {
        added_mass: Some(0.06),
        held_out: false,
        ..Truth::default()
    };
    let (ev, _) = evidence(&truth, 34);
    let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    let r = rejected(&report, "added_mass");
    assert_eq!(r.reason, Rejection::NoHeldOutData);
    assert!(r.delta_bic.expect("fitted") > DEFAULT_DELTA_BIC_THRESHOLD);
    let relaxed = CatalogueSettings {
        require_held_out: false,
        ..CatalogueSettings::default()
    };
    let report = diagnose(&ev, &relaxed).expect("valid");
    assert!(
        accepted(&report, "added_mass").is_some(),
        "{:#?}",
        report.rejected
    );
}

// ---------------------------------------------------------------------------------------
// Calibration and false alarms.

const EFFECTS: [&str; 8] = [
    "non_rayleigh_damping",
    "beating_pair",
    "support_contact",
    "contact_duration",
    "reverb_noise",
    "radiation",
    "added_mass",
    "pitch_glide",
];

/// Per draw and effect: its ΔBIC (None if the detector did not send it to a fit) and whether
/// it was accepted.
fn clean_draws(truth: &Truth, seeds: std::ops::Range<u64>) -> Vec<[(Option<f64>, bool); 8]> {
    seeds
        .map(|seed| {
            let report = run(truth, seed);
            let mut out = [(None, false); 8];
            for (i, name) in EFFECTS.iter().enumerate() {
                if let Some(a) = accepted(&report, name) {
                    out[i] = (Some(a.delta_bic), true);
                } else if let Some(r) = report.rejected.iter().find(|r| r.name == *name) {
                    out[i] = (r.delta_bic, false);
                }
            }
            out
        })
        .collect()
}

#[test]
fn calibration_false_alarms_at_most_two_percent() {
    // Clean evidence from the baseline with the stated σ's, 240 draws. For each candidate
    // threshold c the false-alarm rate of an effect is the fraction of draws with ΔBIC > c
    // (a draw the detector did not send to a fit counts as no alarm). The calibrated
    // threshold is the smallest c in {0, 1, …, 10} with a rate ≤ 2 % for every effect; the
    // shipped default must not be below it. Acceptances (which also need the held-out error to
    // fall) must stay ≤ 5 % per effect.
    let draws = clean_draws(&Truth::default(), 1000..1240);
    let n = draws.len() as f64;
    let rate = |i: usize, c: f64| {
        draws
            .iter()
            .filter(|d| d[i].0.is_some_and(|x| x > c))
            .count() as f64
            / n
    };
    let calibrated = (0..=10)
        .map(f64::from)
        .find(|&c| (0..EFFECTS.len()).all(|i| rate(i, c) <= 0.02));
    for (i, name) in EFFECTS.iter().enumerate() {
        let fitted = draws.iter().filter(|d| d[i].0.is_some()).count();
        let max = draws
            .iter()
            .filter_map(|d| d[i].0)
            .fold(f64::NEG_INFINITY, f64::max);
        let accepted = draws.iter().filter(|d| d[i].1).count();
        println!(
            "{name:22} fitted {fitted:3}/{n} max ΔBIC {max:8.2} rate at ΔBIC > 0: {:.3}, > 2: {:.3}, > {DEFAULT_DELTA_BIC_THRESHOLD}: {:.3}; accepted {accepted}",
            rate(i, 0.0),
            rate(i, 2.0),
            rate(i, DEFAULT_DELTA_BIC_THRESHOLD)
        );
        assert!(
            rate(i, DEFAULT_DELTA_BIC_THRESHOLD) <= 0.02,
            "{name}: false-alarm rate {} above 2 %",
            rate(i, DEFAULT_DELTA_BIC_THRESHOLD)
        );
        assert!(
            accepted as f64 <= 0.05 * n,
            "{name}: accepted on {accepted} of {n} clean draws"
        );
    }
    println!("calibrated threshold {calibrated:?}, shipped {DEFAULT_DELTA_BIC_THRESHOLD}");
    let calibrated = calibrated.expect("some threshold up to 10 keeps every effect at ≤ 2 %");
    assert!(DEFAULT_DELTA_BIC_THRESHOLD >= calibrated);
}

#[test]
fn false_alarms_with_model_error_scatter_at_most_five_percent() {
    // Clean physics but a finite-element model off by 0.4 % in frequency, 10 % in decay and
    // 15 % in level from mode to mode (shared by fit and held-out data): the floors must take
    // it, not an effect.
    let truth = Truth {
        scatter: Some((0.004, 0.1, 0.15)),
        ..Truth::default()
    };
    let draws = clean_draws(&truth, 2000..2100);
    let n = draws.len() as f64;
    for (i, name) in EFFECTS.iter().enumerate() {
        let accepted = draws.iter().filter(|d| d[i].1).count();
        println!("{name:22} accepted {accepted} of {n}");
        assert!(
            accepted as f64 <= 0.05 * n,
            "{name}: accepted on {accepted} of {n} draws with model-error scatter"
        );
    }
}

/// A damping law is a function of each mode's own frequency (parent docs, "A damping law at
/// the measured frequency"): a model whose frequencies are off by 3 % from mode to mode
/// (shared by fit and held-out data) on exact Rayleigh decays leaves the decay rows as the
/// extraction measured them, with no decay floor and no damping law named.
#[test]
fn a_frequency_misfit_does_not_come_back_in_the_decay_rows() {
    let mut floors = Vec::new();
    for seed in 0..6 {
        let truth = Truth {
            // Mostly β: at 1–8 kHz the β part is 55–99 % of the decay, so a frequency error
            // e comes back as about 2e in ln d, beside the extraction's 4 %.
            alpha: 2.0,
            beta: 6e-8,
            scatter: Some((0.03, 0.0, 0.0)),
            ..Truth::default()
        };
        let report = run(&truth, 4400 + seed);
        assert!(
            accepted(&report, "non_rayleigh_damping").is_none(),
            "seed {seed}: {:#?}",
            report.accepted
        );
        floors.push(report.baseline.floors.ln_decay);
    }
    println!("baseline ln d floors: {floors:?}");
    // Measured: 0 in every draw; with the law at the model's frequencies 0.02–0.04 in 4 of 6.
    assert!(floors.iter().all(|&t| t < 0.01), "{floors:?}");
}

#[test]
fn amplitude_tilts_from_f_minus_2_to_f_plus_2_are_nuisances_not_effects() {
    // What a user cannot know — the response quantity (displacement … pressure: f^-2 … f^0
    // relative to acceleration, more with a radiation-efficiency trend), each microphone's
    // response (±0.5 in the power per channel) and per-mode radiation levels (±40 %, the
    // level scatter) — tilts the amplitudes with frequency. The baseline profiles a power law
    // per channel, so on clean recordings no effect may claim the tilt (contact duration's
    // low-pass was the one that did: its slope absorbed it).
    let mut worst = 0usize;
    for tilt in [-2.0, -1.0, 1.0, 2.0] {
        let truth = Truth {
            tilt,
            mic_tilt_spread: 0.5,
            scatter: Some((0.0, 0.0, 0.4)),
            ..Truth::default()
        };
        let draws = clean_draws(&truth, 3000..3030);
        for (i, name) in EFFECTS.iter().enumerate() {
            let accepted = draws.iter().filter(|d| d[i].1).count();
            println!(
                "tilt f^{tilt:+}: {name:22} accepted {accepted} of {}",
                draws.len()
            );
            worst = worst.max(accepted);
            assert!(
                accepted * 20 <= draws.len(),
                "tilt {tilt}: {name} accepted on {accepted} of {} clean draws",
                draws.len()
            );
        }
        let contact = draws.iter().filter(|d| d[3].1).count();
        assert_eq!(contact, 0, "tilt {tilt}: contact duration claimed a tilt");
    }
    println!("worst acceptances per effect and tilt: {worst} of 30");
}

#[test]
fn a_contact_duration_is_found_past_an_amplitude_tilt() {
    // The half-sine's knee, not its slope, is the contact's signature: a hard mallet's
    // low-pass is still found when the recording is also tilted (velocity response, f^-1,
    // and microphones that differ by ±0.5).
    let t_h = 1.6e-4;
    for tilt in [-1.0, 1.0] {
        let truth = Truth {
            hertz: Some(t_h),
            tilt,
            mic_tilt_spread: 0.5,
            ..Truth::default()
        };
        let (ev, _) = evidence(&truth, 24);
        let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
        expect_accepted(&report, "contact_duration");
    }
}

/// A fall steeper than any nuisance: a displacement response (f⁻² on the acceleration law)
/// with a soft contact whose knee lies below the band (its side lobes another f⁻² on
/// average), here the levels × (f / 1 kHz)^−4.2 with microphones differing by ±0.3 and
/// ±40 % level scatter. The tilts stop at their bound (−3) and the rest of the fall is the
/// contact's: the screen may take a slope only as far as the tilts can still go. With a free
/// slope (before stop 72) the screen took the rest as a slope and found nothing (generator
/// 2's tubes and cups recorded as displacements, seed 97 case 005 and seed 113 case 017).
#[test]
fn a_fall_steeper_than_the_tilts_bound_is_named_a_contact() {
    let truth = Truth {
        tilt: -4.2,
        mic_tilt_spread: 0.3,
        scatter: Some((0.0, 0.0, 0.4)),
        ..Truth::default()
    };
    let named: Vec<bool> = (70..74)
        .map(|seed| {
            let report = run(&truth, seed);
            accepted(&report, "contact_duration").is_some()
        })
        .collect();
    // Measured: 4 of 4 (0 of 4 with the free slope).
    assert!(
        named.iter().filter(|&&n| n).count() >= 3,
        "named in {named:?}"
    );
}

/// Three groups of modes (the split pairs of clusters 3, 8 and 13 alone, as a cup or a tube
/// with few partials gives) under a level curvature no contact made (a microphone's or the
/// radiation's, ln a += −0.6 (ln(f / 3 kHz))²): the gains and tilts with any contact variant
/// have as many parameters as there are group levels, so the contact cannot be tested and is
/// not named; the report lists it as untested (module docs of contact_duration, "Testable
/// shapes"; set 1's seed 101 case 028).
#[test]
fn a_contact_is_not_named_on_three_groups_of_modes() {
    let truth = Truth {
        splits: vec![(3, 0.004), (8, 0.003), (13, 0.003)],
        colouration: -0.6,
        ..Truth::default()
    };
    let mut named = Vec::new();
    for seed in 80..84 {
        let (mut ev, obj) = evidence(&truth, seed);
        let centres: Vec<f64> = DEGENERATE
            .iter()
            .map(|&c| obj.sim[obj.members[c][0]].frequency_hz * truth.ln_s.exp())
            .collect();
        let near = |m: &ObservedMode| {
            centres
                .iter()
                .any(|&f| (m.frequency_hz / f).ln().abs() < 0.02)
        };
        ev.fit.retain(near);
        if let Some(held) = ev.held_out.as_mut() {
            held.retain(near);
        }
        assert!(ev.fit.len() >= 5, "{} modes kept", ev.fit.len());
        let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
        let untested = report
            .untested()
            .iter()
            .any(|r| r.name == "contact_duration");
        named.push((accepted(&report, "contact_duration").is_some(), untested));
    }
    println!("(named, untested) per draw: {named:?}");
    // Measured: never named, untested in 4 of 4 (named in 4 of 4 without the rule).
    assert!(named.iter().all(|n| !n.0), "{named:?}");
    assert!(named.iter().filter(|n| n.1).count() >= 2, "{named:?}");
}

#[test]
fn level_groups_merge_modes_within_two_per_cent() {
    let ln = |f: &[f64]| {
        f.iter()
            .map(|x: &f64| x.ln())
            .collect::<Vec<_>>()
            .into_iter()
    };
    assert_eq!(super::contact_duration::level_groups(ln(&[])), 0);
    assert_eq!(super::contact_duration::level_groups(ln(&[1000.0])), 1);
    // 1 % apart: one group; 3 % apart: two; any order.
    assert_eq!(
        super::contact_duration::level_groups(ln(&[1010.0, 1000.0, 3000.0, 3090.0])),
        3
    );
}

#[test]
fn missing_observations_are_skipped_not_fatal() {
    // Zero amplitudes on some channels, a mode that does not decay, modes without early/late
    // frequencies: those rows are left out and an injected effect is still found.
    let truth = Truth {
        added_mass: Some(0.06),
        ..Truth::default()
    };
    let (mut ev, _) = evidence(&truth, 35);
    ev.fit[2].amplitudes[1] = 0.0;
    ev.fit[7].amplitudes = vec![0.0; FIT_CHANNELS];
    ev.fit[4].decay_rate = 0.0;
    for m in ev.fit.iter_mut().step_by(3) {
        m.early_frequency_hz = None;
    }
    let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    expect_accepted(&report, "added_mass");
    let row = report
        .residuals
        .iter()
        .find(|r| r.observed == 4)
        .expect("matched");
    assert!(row.before.ln_decay.is_none() && row.after.ln_decay.is_none());
    let row = report
        .residuals
        .iter()
        .find(|r| r.observed == 2)
        .expect("matched");
    assert!(row.before.ln_amplitude[1].is_none() && row.before.ln_amplitude[0].is_some());

    // No amplitudes at all (zero channels): amplitude effects have no data, the rest works.
    for m in ev.fit.iter_mut() {
        m.amplitudes.clear();
        m.sigma_amplitudes.clear();
    }
    ev.held_out = ev.held_out.map(|h| {
        h.into_iter()
            .map(|mut m| {
                m.amplitudes.clear();
                m.sigma_amplitudes.clear();
                m
            })
            .collect()
    });
    let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    expect_accepted(&report, "added_mass");
    for name in ["radiation", "contact_duration"] {
        let r = rejected(&report, name);
        assert_eq!(r.reason, Rejection::NotEnoughData, "{r:?}");
    }
    // Neither glide law needs the amplitudes (the energy is the model's, from the drive):
    // both are screened, and find nothing.
    let r = rejected(&report, "pitch_glide");
    assert_eq!(r.reason, Rejection::DetectorFoundNothing, "{r:?}");
    assert!(
        r.detail.contains("relative energy") && r.detail.contains("uniform"),
        "{r:?}"
    );
}

/// Detection rate over 20 draws per effect at the strengths of the tests above, with the
/// model-error scatter of the false-alarm test (the realistic case): ≥ 18 of 20 detected with
/// the right variant (where the scatter lets the variants be told apart), and at most 5 % of
/// the 200 draws with some other effect accepted as well. About 5 s in release mode, ignored
/// by default to keep the suite short (`cargo test --release --lib catalogue -- --ignored`).
#[test]
#[ignore]
fn detection_power_at_realistic_strengths() {
    let scatter = Some((0.004, 0.1, 0.15));
    let cases: Vec<(&str, &str, Truth)> = vec![
        (
            "non_rayleigh_damping",
            "three_knot_log_log",
            Truth {
                power_law: Some((5.0, 0.7)),
                ..Truth::default()
            },
        ),
        (
            "beating_pair",
            "split_per_cluster",
            Truth {
                splits: vec![(3, 0.004), (8, 0.002)],
                ..Truth::default()
            },
        ),
        // κ = 0.008 at w = 1 is within the 0.4 % frequency scatter: either variant counts.
        (
            "support_contact",
            "",
            Truth {
                support: Some((6.0, 0.008)),
                ..Truth::default()
            },
        ),
        (
            "contact_duration",
            "half_sine",
            Truth {
                hertz: Some(1.6e-4),
                ..Truth::default()
            },
        ),
        (
            "reverb_noise",
            "shared_t60",
            Truth {
                reverb_t60: Some(0.4),
                ..Truth::default()
            },
        ),
        (
            "radiation",
            "transfer",
            Truth {
                radiation: Some(Pattern::Lobes),
                transfer_in_evidence: true,
                ..Truth::default()
            },
        ),
        (
            "radiation",
            "factor",
            Truth {
                radiation: Some(Pattern::Axis),
                ..Truth::default()
            },
        ),
        (
            "added_mass",
            "added_mass",
            Truth {
                added_mass: Some(0.06),
                ..Truth::default()
            },
        ),
        (
            "added_mass",
            "fluid_loading",
            Truth {
                fluid: Some(0.08),
                ..Truth::default()
            },
        ),
        (
            "pitch_glide",
            "energy_power_law",
            Truth {
                glide: Some(1e-3),
                ..Truth::default()
            },
        ),
    ];
    let mut others = 0;
    for (case, (name, variant, truth)) in cases.iter().enumerate() {
        let truth = Truth {
            scatter,
            ..truth.clone()
        };
        let mut hit = 0;
        for seed in 0..20 {
            let r = run(&truth, 5000 + 100 * case as u64 + seed);
            if accepted(&r, name).is_some_and(|a| variant.is_empty() || a.variant == *variant) {
                hit += 1;
            }
            let spurious: Vec<String> = r
                .accepted
                .iter()
                .filter(|a| a.name != *name)
                .map(|a| format!("{} (ΔBIC {:.1})", a.name, a.delta_bic))
                .collect();
            if !spurious.is_empty() {
                println!("  {name} injected, also accepted: {}", spurious.join(", "));
                others += 1;
            }
        }
        println!("{name:22} {variant:22} detected {hit}/20");
        assert!(
            hit >= 18,
            "{name} ({variant}): detected in {hit} of 20 draws"
        );
    }
    println!("draws with an effect accepted that was not injected: {others} of 200");
    assert!(
        others <= 10,
        "{others} of 200 draws accepted an effect not injected"
    );
}

/// The fit and held-out tables of `ev` as matched without the pole choice (the held-out set
/// at the fit's frequency scale), and the fit's ln scale.
fn fit_and_held_tables(ev: &Evidence, settings: &CatalogueSettings) -> (ModeTable, ModeTable, f64) {
    let ln: Vec<f64> = ev.fit.iter().map(|m| m.frequency_hz.ln()).collect();
    let matching = match_modes(&ln, &[], &ev.simulated, None, settings);
    let table = ModeTable::build(&ev.fit, &ev.simulated, &matching, 0, 3.0);
    let held_obs = ev.held_out.clone().expect("held-out data");
    let ln_h: Vec<f64> = held_obs.iter().map(|m| m.frequency_hz.ln()).collect();
    let mh = match_modes(&ln_h, &[], &ev.simulated, Some(matching.ln_scale), settings);
    let held = ModeTable::build(&held_obs, &ev.simulated, &mh, table.channels, 3.0);
    (table, held, matching.ln_scale)
}

/// σ of mode `k`'s ln d row in `t`.
fn decay_sigma(t: &ModeTable, k: usize) -> f64 {
    t.rows
        .iter()
        .find(|r| r.kind == RowKind::LnD(k))
        .map(|r| r.sigma)
        .expect("a decay row")
}

/// An unresolved cluster's decay (parent docs): the ln d row of a pole that stands for a
/// degenerate pair is widened by how far the held-out extraction's poles of that cluster
/// disagree with it, in both tables, σ² + Δ²; a lone simulated mode's row and rows the
/// microphones agree on stay as they were.
#[test]
fn an_unresolved_pairs_decay_counts_as_far_as_the_microphones_agree() {
    let settings = CatalogueSettings::default();
    let (ev, _) = evidence(&Truth::default(), 22);
    let tables = |ev: &Evidence| {
        let (table, held, _) = fit_and_held_tables(ev, &settings);
        (table, held)
    };
    let (table, held) = tables(&ev);
    let pooled = table
        .modes
        .iter()
        .position(|m| m.role == Role::Single && m.simulated.len() >= 2)
        .expect("an unresolved degenerate pair");
    let lone = table
        .modes
        .iter()
        .position(|m| m.role == Role::Single && m.simulated.len() == 1)
        .expect("a lone mode");
    let cluster = table.modes[pooled].key.cluster;
    let held_k = held
        .modes
        .iter()
        .position(|m| m.key.cluster == cluster)
        .expect("the pair in the held-out table");

    // Agreeing microphones (the synthetic truth): every row within 2 % of its σ as built
    // (the extraction noise of the two sets differs by a few σ at most).
    let (mut agree, mut agree_held) = (table.clone(), held.clone());
    agree.widen_unreplicated_decays(&mut agree_held);
    for k in [pooled, lone] {
        let (before, after) = (decay_sigma(&table, k), decay_sigma(&agree, k));
        let delta = (after * after - before * before).max(0.0).sqrt();
        assert!(delta < 0.05, "mode {k}: σ {before} → {after}");
    }

    // The fit microphones hear the pair decay 30 % faster than the held-out ones.
    let mut off = ev.clone();
    let pole = table.modes[pooled].observed;
    off.fit[pole].decay_rate *= 1.3;
    off.fit[pole].sigma_decay_rate *= 1.3;
    let (mut t, mut h) = tables(&off);
    let expected_delta = t.modes[pooled].ln_d.unwrap().0 - h.modes[held_k].ln_d.unwrap().0;
    assert!(expected_delta > 0.2, "{expected_delta}");
    let (s_fit, s_held, s_lone) = (
        decay_sigma(&t, pooled),
        decay_sigma(&h, held_k),
        decay_sigma(&t, lone),
    );
    assert!(t.widen_unreplicated_decays(&mut h) >= 1);
    let widened = |s: f64| (s * s + expected_delta * expected_delta).sqrt();
    assert!((decay_sigma(&t, pooled) - widened(s_fit)).abs() < 1e-12);
    assert!((decay_sigma(&h, held_k) - widened(s_held)).abs() < 1e-12);
    assert_eq!(decay_sigma(&t, lone), s_lone);
}

/// The mirror (parent docs, "An unresolved cluster's decay"): the fit resolves a split pair
/// into its two members and the held-out extraction hears one pole for both, decaying 20 %
/// slower (the beat of the two at that microphone). The held-out pole's row is widened by how
/// far it disagrees with the members' mean, σ² + Δ²; the pair's own rows stay, and where the
/// held-out pole agrees nothing changes. Generator 2's blind seed 181 case 006: a cup whose
/// pair at 2717 Hz decayed at 8.13 and 8.00 1/s on the fit microphones and at 7.20 ± 0.03 1/s
/// as one pole on the held-out one; its true power law raised the held-out error 3.72 → 6.90.
#[test]
fn a_held_out_pole_for_a_resolved_pair_counts_as_far_as_it_agrees_with_the_members() {
    let settings = CatalogueSettings::default();
    let truth = Truth {
        splits: vec![(DEGENERATE[1], 4e-3)],
        ..Truth::default()
    };
    let (ev, _) = evidence(&truth, 22);
    // The held-out extraction keeps the pair's lower pole only, as one pole for both.
    let one_pole = |scale: f64| {
        let mut ev = ev.clone();
        let held = ev.held_out.as_mut().expect("held-out data");
        let f_pair = |m: &ObservedMode| {
            let f = m.frequency_hz;
            ev.simulated
                .iter()
                .filter(|s| s.cluster == DEGENERATE[1])
                .any(|s| (f / (s.frequency_hz * truth.ln_s.exp()) - 1.0).abs() < 0.02)
        };
        let members: Vec<usize> = (0..held.len()).filter(|&i| f_pair(&held[i])).collect();
        assert_eq!(members.len(), 2, "the split pair in the held-out set");
        held[members[0]].decay_rate *= scale;
        held[members[0]].sigma_decay_rate *= scale;
        held.remove(members[1]);
        fit_and_held_tables(&ev, &settings)
    };
    for (scale, widens) in [(0.8, true), (1.0, false)] {
        let (mut table, mut held, _) = one_pole(scale);
        let (fit_before, held_before) = (table.clone(), held.clone());
        let members: Vec<usize> = (0..table.modes.len())
            .filter(|&k| table.modes[k].key.cluster == DEGENERATE[1])
            .collect();
        assert_eq!(members.len(), 2, "the fit resolves the pair");
        assert!(members.iter().all(|&k| table.modes[k].role != Role::Single));
        let pole = held
            .modes
            .iter()
            .position(|m| m.key.cluster == DEGENERATE[1])
            .expect("the pair's pole in the held-out table");
        assert!(held.modes[pole].role == Role::Single && held.modes[pole].simulated.len() >= 2);
        let mean = members
            .iter()
            .map(|&k| table.modes[k].ln_d.unwrap().0)
            .sum::<f64>()
            / 2.0;
        let delta = held.modes[pole].ln_d.unwrap().0 - mean;
        table.widen_unreplicated_decays(&mut held);
        let s = decay_sigma(&held_before, pole);
        let expected = (s * s + delta * delta).sqrt();
        assert!((decay_sigma(&held, pole) - expected).abs() < 1e-12);
        if widens {
            assert!(delta < -0.15, "Δ = {delta}");
            assert!(decay_sigma(&held, pole) > 3.0 * s);
        } else {
            // Agreeing microphones: Δ is the two extractions' noise, a few σ_ln d.
            assert!(delta.abs() < 0.15, "Δ = {delta}");
        }
        // The members' own decay rows (the pair's mean ln d) stay.
        let pair_rows = |t: &ModeTable| -> Vec<f64> {
            t.rows
                .iter()
                .filter(|r| match r.kind {
                    RowKind::PairMeanLnD(l, u) => members.contains(&l) || members.contains(&u),
                    RowKind::LnD(k) => members.contains(&k),
                    _ => false,
                })
                .map(|r| r.sigma)
                .collect()
        };
        assert!(!pair_rows(&table).is_empty(), "the pair's decay rows");
        assert_eq!(pair_rows(&table), pair_rows(&fit_before));
    }
}

/// The backward pass's last-in test (selection module): an effect that carries its data
/// passes it, one that carries nothing fails it, and the model without it is the model
/// before it.
#[test]
fn last_in_test_keeps_a_real_effect_and_drops_an_empty_one() {
    let settings = CatalogueSettings::default();
    let with_mass = |truth: &Truth, seed: u64| {
        let (ev, _) = evidence(truth, seed);
        let (table, held, ln_scale) = fit_and_held_tables(&ev, &settings);
        let ln_f_ref = ln_scale
            + table.modes.iter().map(|m| m.ln_f_sim).sum::<f64>() / table.modes.len() as f64;
        let base_model = Model::new(vec![], ln_f_ref, table.channels);
        let x0 = model::baseline_start(&table, &base_model, ln_scale);
        let baseline = fit(&table, base_model, x0);
        let term: Arc<dyn Term> = Arc::new(MassLoading { fluid_ln_f1: None });
        let mut x = baseline.x.clone();
        x.push(0.01);
        let full = fit(&table, baseline.model.with_term(term), x);
        let last = selection::last_in(&full, 0, &table, Some(&held), &settings);
        (baseline, last)
    };
    let (baseline, real) = with_mass(
        &Truth {
            added_mass: Some(0.06),
            ..Truth::default()
        },
        31,
    );
    assert!(
        real.rejection.is_none() && real.delta_bic > 20.0,
        "a 6 % mass must pay its way: ΔBIC {}, {:?}",
        real.delta_bic,
        real.rejection
    );
    assert!(
        (real.without.minus_two_log_likelihood - baseline.minus_two_log_likelihood).abs() < 1e-3,
        "without the term the fit is the baseline: {} vs {}",
        real.without.minus_two_log_likelihood,
        baseline.minus_two_log_likelihood
    );
    let (_, empty) = with_mass(&Truth::default(), 31);
    assert!(
        empty.rejection.is_some() && empty.delta_bic < settings.delta_bic_threshold,
        "a mass on clean data must not pay its way: ΔBIC {}",
        empty.delta_bic
    );
}

#[test]
fn a_rooms_colouration_of_the_levels_is_a_nuisance_not_a_contact() {
    // A room (T60 = 0.4 s) whose colouration bends the levels down at both ends (κ = −2, as
    // the second generator's rooms measured −1.1 to −2.6): a tilt plus the half-sine's knee can
    // mimic that on a few modes, and the held-out microphones see the same colouration. With
    // the room established on the envelopes, the baseline carries the colouration, so the
    // contact duration has nothing left to explain; without the nuisance it is claimed.
    let truth = Truth {
        reverb_t60: Some(0.4),
        colouration: -2.0,
        tilt: 1.0,
        ..Truth::default()
    };
    let (ev, _) = evidence(&truth, 24);
    let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    expect_accepted(&report, "reverb_noise");
    assert!(
        report
            .baseline
            .effects
            .iter()
            .any(|e| e.contains("level_colouration")),
        "{:?}",
        report.baseline.effects
    );
    assert!(
        !report.accepted.iter().any(|a| a.name == "contact_duration"),
        "{:#?}",
        report.accepted
    );
    let kappa = report
        .baseline
        .params
        .iter()
        .find(|p| p.name.starts_with("level colouration"))
        .expect("fitted");
    assert!(within_3_sigma(kappa, -2.0), "{kappa:?}");

    let without = CatalogueSettings {
        level_colouration: ColourationWhen::Never,
        ..CatalogueSettings::default()
    };
    let report = diagnose(&ev, &without).expect("valid");
    expect_accepted(&report, "contact_duration");
}

#[test]
fn without_a_room_the_baseline_has_no_colouration_and_a_contact_is_found() {
    let truth = Truth {
        hertz: Some(1.6e-4),
        ..Truth::default()
    };
    let (ev, _) = evidence(&truth, 24);
    let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    assert!(
        report.baseline.effects.is_empty(),
        "{:?}",
        report.baseline.effects
    );
    expect_accepted(&report, "contact_duration");
}

/// Gives every simulated mode its ∂ln f/∂ν from `s(j, mode)`, and moves the simulation to a
/// Poisson ratio `dnu` below the recording's: f_j ← f_j e^(−S_j Δν).
fn with_poisson_error(ev: &mut Evidence, dnu: f64, s: impl Fn(usize, &SimulatedMode) -> f64) {
    for j in 0..ev.simulated.len() {
        let sj = s(j, &ev.simulated[j]);
        let m = &mut ev.simulated[j];
        m.ln_f_per_poisson = Some(sj);
        m.frequency_hz *= (-sj * dnu).exp();
    }
}

#[test]
fn a_poisson_ratio_error_is_a_nuisance_not_an_added_mass() {
    // A clean strike simulated at a ν 0.03 off, with sensitivities shaped like a mass's
    // pattern (S_j = 0.4 − 0.8 w_j: the modes a mass at the candidate region would lower are
    // the ones ν moves least). The baseline profiles Δν and claims nothing; without the
    // nuisance the same residuals are reported as an added mass.
    let (mut ev, _) = evidence(&Truth::default(), 35);
    with_poisson_error(&mut ev, 0.03, |_, m| 0.4 - 0.8 * m.mass_weight);
    let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    assert!(report.accepted.is_empty(), "{:#?}", report.accepted);
    let dnu = report
        .baseline
        .params
        .iter()
        .find(|p| p.name.starts_with("Poisson ratio error"))
        .expect("the nuisance is in the baseline");
    assert!(within_3_sigma(dnu, 0.03), "{dnu:?}");

    let without = CatalogueSettings {
        poisson_nuisance: false,
        ..CatalogueSettings::default()
    };
    let report = diagnose(&ev, &without).expect("valid");
    expect_accepted(&report, "added_mass");
}

#[test]
fn an_added_mass_is_still_found_beside_the_poisson_nuisance() {
    // A true 6 % mass, the simulation at a ν 0.02 off with sensitivities unrelated to the
    // mass's site: the nuisance takes the ν pattern, the mass its own.
    let truth = Truth {
        added_mass: Some(0.06),
        ..Truth::default()
    };
    let (mut ev, _) = evidence(&truth, 35);
    with_poisson_error(&mut ev, 0.02, |j, _| {
        0.05 + 0.3 * ((j as f64) * 2.3).sin().abs()
    });
    let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
    expect_accepted(&report, "added_mass");
    assert!(
        report
            .baseline
            .effects
            .iter()
            .any(|e| e.starts_with("poisson_ratio")),
        "{:?}",
        report.baseline.effects
    );
}

/// Evidence of an object with six degenerate pairs (members 2·10⁻⁵ apart, so the matching
/// pools each observed pair) and six lone modes, the weights of a small region resolved within
/// each pair as [`crate::diagnose::evidence::cluster_region_energies`] resolves them: the
/// region sits near one member's antinode and the other's node, so one member takes a weight
/// u ∈ [0.3, 1] and the other 0.05 u; the lower member for the mass weights, the upper for
/// the support's (a mass lowers the member it loads, a spring raises it). The recording has an
/// added mass μ (each member moved by −½ ln(1 + μ w) on its own weight), a support (γ, κ)
/// (each member's decay rate raised by γ w and its ln f by κ w) and, on the listed pairs, an
/// asymmetry that splits them by δ more. Rayleigh damping, noise as in the synthetic world.
fn local_split_evidence(
    mu: f64,
    support: (f64, f64),
    asymmetry: &[(usize, f64)],
    seed: u64,
) -> Evidence {
    local_split_evidence_with(mu, support, asymmetry, 1.0, seed)
}

/// [`local_split_evidence`] with the lone modes' weights scaled by `lone_weight` (a region near
/// the nodal lines of the lone modes: 0 leaves them unmoved).
fn local_split_evidence_with(
    mu: f64,
    support: (f64, f64),
    asymmetry: &[(usize, f64)],
    lone_weight: f64,
    seed: u64,
) -> Evidence {
    local_split_evidence_misweighted(mu, support, asymmetry, lone_weight, 0.0, seed)
}

/// [`local_split_evidence_with`] whose simulation knows each pair's mass weights only to a
/// relative error `mass_weight_error` (+ on clusters 0, 4, 8, − on 2, 6, 10): a mass whose
/// site or spread the model has only roughly, as a loaded match's or a localisation's is.
fn local_split_evidence_misweighted(
    mu: f64,
    support: (f64, f64),
    asymmetry: &[(usize, f64)],
    lone_weight: f64,
    mass_weight_error: f64,
    seed: u64,
) -> Evidence {
    let mut rng = Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1);
    let gains: Vec<f64> = (0..FIT_CHANNELS + HELD_CHANNELS)
        .map(|_| rng.uniform(-1.0, 1.0) - 3.0)
        .collect();
    let (gamma, kappa) = support;
    let mut simulated = Vec::new();
    // (true ln f₀, true decay, ln amplitude without the channel gain)
    let mut truth = Vec::new();
    for cluster in 0..12 {
        let f = 700.0 * 1.3f64.powi(cluster as i32) * rng.uniform(0.99, 1.01);
        let (u, v) = (rng.uniform(0.3, 1.0), rng.uniform(0.3, 1.0));
        // (frequency, mass weight, support weight) per member.
        let members: Vec<(f64, f64, f64)> = if cluster % 2 == 0 {
            vec![(f, u, 0.05 * v), (f * (1.0 + 2e-5), 0.05 * u, v)]
        } else {
            vec![(f, lone_weight * u * u, lone_weight * v * v)]
        };
        let drive: f64 = rng.uniform(0.3, 1.0);
        let delta = asymmetry
            .iter()
            .find(|a| a.0 == cluster)
            .map_or(0.0, |a| a.1);
        let n = members.len();
        for (slot, &(fm, w_mass, w_support)) in members.iter().enumerate() {
            let side = if n == 2 { slot as f64 - 0.5 } else { 0.0 };
            let ln_f0 =
                0.02 + fm.ln() - 0.5 * (mu * w_mass).ln_1p() + kappa * w_support + side * delta;
            let omega = 2.0 * PI * ln_f0.exp();
            let d = 0.5 * (4.0 + 3e-8 * omega * omega) + gamma * w_support;
            let member_drive = drive / (n as f64).sqrt();
            truth.push((ln_f0, d, member_drive.ln() + omega.ln()));
            let misweight = match cluster % 4 {
                0 => 1.0 + mass_weight_error,
                2 => 1.0 - mass_weight_error,
                _ => 1.0,
            };
            simulated.push(SimulatedMode {
                frequency_hz: fm,
                drive,
                support_weight: w_support,
                mass_weight: (w_mass * misweight).min(1.0),
                cluster,
                transfer: None,
                match_frequency_hz: None,
                ln_f_per_poisson: None,
            });
        }
    }
    let truth: Vec<(f64, f64, f64)> = truth
        .iter()
        .map(|&(ln_f0, d, ln_amp)| (ln_f0.exp(), d, ln_amp))
        .collect();
    observed_evidence(&truth, &gains, SIGMA_LN_D, simulated, &mut rng)
}

/// The fit and held-out recordings' modes of `truth` (undamped frequency f₀ \[Hz\], decay rate
/// d \[1/s\], ln amplitude without the channel gain) seen through the channel `gains` (ln),
/// with the synthetic world's frequency and amplitude noise and a relative decay noise
/// `sigma_ln_d`.
fn observed_evidence(
    truth: &[(f64, f64, f64)],
    gains: &[f64],
    sigma_ln_d: f64,
    simulated: Vec<SimulatedMode>,
    rng: &mut Rng,
) -> Evidence {
    let observe = |channels: std::ops::Range<usize>, rng: &mut Rng| -> Vec<ObservedMode> {
        truth
            .iter()
            .map(|&(f0, d, ln_amp)| {
                let fd = (f0 * f0 - (d / (2.0 * PI)).powi(2)).sqrt();
                let sf = sigma_f(fd);
                let amplitudes: Vec<f64> = channels
                    .clone()
                    .map(|c| (gains[c] + ln_amp + SIGMA_LN_A * normal(rng)).exp())
                    .collect();
                ObservedMode {
                    frequency_hz: fd + sf * normal(rng),
                    sigma_frequency_hz: sf,
                    decay_rate: d * (sigma_ln_d * normal(rng)).exp(),
                    sigma_decay_rate: sigma_ln_d * d,
                    sigma_amplitudes: amplitudes.iter().map(|a| SIGMA_LN_A * a).collect(),
                    amplitudes,
                    early_frequency_hz: None,
                    late_frequency_hz: None,
                    glide: None,
                }
            })
            .collect()
    };
    let fit = observe(0..FIT_CHANNELS, rng);
    let held_out = Some(observe(FIT_CHANNELS..FIT_CHANNELS + HELD_CHANNELS, rng));
    Evidence {
        fit,
        held_out,
        simulated,
        residual_envelopes: None,
        split_sites: None,
    }
}

fn diagnose_default(evidence: &Evidence) -> CatalogueReport {
    diagnose(evidence, &CatalogueSettings::default()).expect("valid evidence")
}

/// A mass or a support splits a degenerate pair by moving the member that moves where it
/// sits: with each pooled pair's modes given their own member's resolved weights, the mass or
/// the support explains the splits it made and no beating pair is named beside it (generator
/// 2's seed 31: a mass on a tube, case 004, claimed as a beating pair beside the mass; its
/// support case 008 still is, since that support hardly damps and a support must). An
/// asymmetry's split, which no weight follows, is still a beating pair and neither a mass nor
/// a support.
#[test]
fn a_pair_split_by_a_mass_or_a_support_is_not_a_beating_pair() {
    for seed in [1, 2, 3] {
        let report = diagnose_default(&local_split_evidence(0.02, (0.0, 0.0), &[], seed));
        let a = expect_accepted(&report, "added_mass");
        assert_eq!(a.variant, "added_mass", "seed {seed}: {a:?}");
        assert!(
            within_3_sigma(param(a, "added-mass ratio μ"), 0.02),
            "seed {seed}: {a:?}"
        );
        assert!(
            accepted(&report, "beating_pair").is_none(),
            "seed {seed}: {:#?}",
            report.accepted
        );

        let report = diagnose_default(&local_split_evidence(0.0, (5.0, 0.006), &[], seed));
        let a = expect_accepted(&report, "support_contact");
        assert!(
            within_3_sigma(param(a, "support damping γ"), 5.0),
            "seed {seed}: {a:?}"
        );
        assert!(
            accepted(&report, "beating_pair").is_none(),
            "seed {seed}: {:#?}",
            report.accepted
        );

        let report = diagnose_default(&local_split_evidence(
            0.0,
            (0.0, 0.0),
            &[(2, 0.004), (6, 0.003)],
            seed,
        ));
        expect_accepted(&report, "beating_pair");
        for name in ["added_mass", "support_contact"] {
            assert!(
                accepted(&report, name).is_none(),
                "seed {seed}: {:#?}",
                report.accepted
            );
        }
    }
}

/// A mass that the model has only roughly (each pair's mass weights 30 % off, up or down) still
/// makes most of every split it causes: what is left of the splits is the mass's imprecision,
/// not a second asymmetry, and no beating pair is named beside the mass (beating_pair module
/// docs, "An asymmetry already modelled"; generator 2's seed 47 case 017, a mass on a tube
/// whose pairs lay 6.9σ and 4.0σ off the mass's model split). A true asymmetry on a pair the
/// mass does not split (a lone mode's cluster has no pair) is not at stake here; one on top of
/// the mass's split pairs, larger than the mass's split, stays a beating pair.
#[test]
fn the_rest_of_a_split_a_mass_makes_is_not_a_beating_pair() {
    for seed in [1, 2, 3] {
        let evidence = local_split_evidence_misweighted(0.02, (0.0, 0.0), &[], 1.0, 0.3, seed);
        let report = diagnose_default(&evidence);
        expect_accepted(&report, "added_mass");
        assert!(
            accepted(&report, "beating_pair").is_none(),
            "seed {seed}: {:#?}",
            report.accepted
        );
        // An asymmetry three times the mass's split on two pairs: the model makes under half
        // of those, so they are still a beating pair.
        let evidence = local_split_evidence_misweighted(
            0.02,
            (0.0, 0.0),
            &[(2, 0.02), (6, 0.02)],
            1.0,
            0.3,
            seed,
        );
        let report = diagnose_default(&evidence);
        expect_accepted(&report, "beating_pair");
    }
}

/// The effect terms' share of a split decides whether it is theirs: at least half, on the
/// same side.
#[test]
fn a_split_is_modelled_when_the_terms_make_half_of_it() {
    use crate::diagnose::catalogue::beating_pair::modelled_split;
    assert!(modelled_split(1e-3, 0.5e-3));
    assert!(modelled_split(1e-3, 1.4e-3));
    assert!(!modelled_split(1e-3, 0.49e-3));
    assert!(!modelled_split(1e-3, -1e-3));
    assert!(!modelled_split(0.0, 0.0));
}

/// A mass whose site no candidate region knows (every mass weight 0, so the region's variant
/// cannot be tried) still shows in the pairs it splits: each pair's lower member drops and the
/// upper stays where the model puts it, which the free splits of an asymmetry (centred on the
/// model) fit less well. Named `added_mass` (`lowered_members`), with no beating pair beside
/// it, when the mass sits where it moves the pairs alone (near the lone modes' nodal lines, as
/// on a cup whose band holds pairs only); where it moves the lone modes too, their unmodelled
/// drops widen the ln f floor, the pair means tell little, and the free splits (the default
/// reading) stay. An asymmetry's splits about the pair's centre stay a beating pair, with no
/// mass. (Generator 2's spent seeds 41, 43 and 47: masses on cups claimed as beating pairs,
/// cases 017, 020 and 013, the localisation map below its offer threshold.)
///
/// The second signature (module docs of `added_mass.rs`, *One site*): the pairs' drops must
/// fit one candidate site. The candidates here are 40 sites with random split patterns and,
/// where `with_true_site`, the mass's own (the pairs' mass-weight differences). Without the
/// true site the mass's drops fit none of them, and the reading is not offered: the splits
/// stay a beating pair.
#[test]
fn a_mass_at_an_unknown_site_is_read_from_the_members_it_lowers() {
    // Unsited evidence (every mass weight 0, so the region's variant cannot be tried) with
    // candidate sites.
    let unsited = |mut ev: Evidence, with_true_site: bool, seed: u64| {
        let mut rng = Rng(seed.wrapping_mul(0x2545_F491_4F6C_DD1D) | 1);
        let mut pairs: Vec<SitePair> = Vec::new();
        for c in 0..12 {
            let members: Vec<&SimulatedMode> =
                ev.simulated.iter().filter(|m| m.cluster == c).collect();
            if members.len() != 2 {
                continue;
            }
            let mut split_per_kg: Vec<f64> = (0..40).map(|_| rng.uniform(0.0, 1.0)).collect();
            if with_true_site {
                split_per_kg.push(members[0].mass_weight - members[1].mass_weight);
            }
            pairs.push(SitePair {
                cluster: c,
                split_per_kg,
            });
        }
        let n_sites = pairs[0].split_per_kg.len();
        ev.split_sites = Some(SplitSites {
            vertices: (100..100 + n_sites).collect(),
            pairs,
        });
        ev.simulated.iter_mut().for_each(|m| m.mass_weight = 0.0);
        ev
    };
    for seed in [1, 2, 3] {
        let mass = || local_split_evidence_with(0.02, (0.0, 0.0), &[], 0.0, seed);
        let report = diagnose_default(&unsited(mass(), true, seed));
        let a = expect_accepted(&report, "added_mass");
        assert_eq!(a.variant, "lowered_members", "seed {seed}: {a:?}");
        // The true site is the last candidate.
        assert!(a.detector.contains("vertex 140"), "seed {seed}: {a:?}");
        assert!(
            accepted(&report, "beating_pair").is_none(),
            "seed {seed}: {:#?}",
            report.accepted
        );

        let report = diagnose_default(&unsited(mass(), false, seed));
        assert!(
            accepted(&report, "added_mass").is_none(),
            "seed {seed}: {:#?}",
            report.accepted
        );
        expect_accepted(&report, "beating_pair");

        let report = diagnose_default(&unsited(
            local_split_evidence_with(
                0.0,
                (0.0, 0.0),
                &[(2, 0.004), (6, 0.003), (10, 0.002)],
                0.0,
                seed,
            ),
            true,
            seed,
        ));
        expect_accepted(&report, "beating_pair");
        assert!(
            accepted(&report, "added_mass").is_none(),
            "seed {seed}: {:#?}",
            report.accepted
        );
    }
}

/// The site fit of the `lowered_members` screen: drops made by one site's pattern are traced
/// to it with their mass, drops that no site's pattern follows have a large misfit, and a
/// cluster without a row gives no fit.
#[test]
fn split_sites_find_the_site_whose_pattern_the_drops_follow() {
    let sites = SplitSites {
        vertices: vec![7, 8, 9],
        pairs: vec![
            SitePair {
                cluster: 0,
                split_per_kg: vec![1.0, 0.2, 0.5],
            },
            SitePair {
                cluster: 3,
                split_per_kg: vec![0.5, 1.0, 0.5],
            },
            SitePair {
                cluster: 5,
                split_per_kg: vec![0.1, 0.3, 0.5],
            },
        ],
    };
    // ½ m x with m = 0.004 kg at vertex 8.
    let drops = [(0, 0.0004), (3, 0.002), (5, 0.0006)];
    let fit = sites.fit(&drops).expect("rows").expect("a fit");
    assert_eq!(fit.vertex, 8);
    assert!((fit.mass_kg - 0.004).abs() < 1e-12, "{fit:?}");
    assert!(fit.misfit < 1e-9, "{fit:?}");
    let fit = sites
        .fit(&[(0, 0.001), (3, 0.0), (5, 0.001)])
        .expect("rows")
        .expect("a fit");
    assert!(fit.misfit > 0.3, "{fit:?}");
    // A cluster without a row is named.
    assert_eq!(sites.fit(&[(0, 0.001), (4, 0.001)]), Err(4));
    // Rows of the wrong length are refused by the evidence check.
    let mut bad = sites.clone();
    bad.pairs[1].split_per_kg.pop();
    assert!(matches!(
        bad.validate(),
        Err(CatalogueError::InvalidSplitSites(_))
    ));
}

/// The `lowered_members` reading with its site untested stands on the pair centres, which
/// need more rows than the frequency nuisances that fit any centres (module docs of
/// `added_mass.rs`, *Centres need a scale*): two centres and no lone mode against the scale
/// and Δν place nothing (generator 2's seed 71 case 015); one lone mode more does.
#[test]
fn pair_centres_need_more_rows_than_the_frequency_nuisances() {
    use crate::diagnose::catalogue::added_mass::pair_centres_placeable;
    assert!(!pair_centres_placeable(2, 0, 2));
    assert!(pair_centres_placeable(2, 1, 2));
    assert!(pair_centres_placeable(2, 0, 1));
    assert!(!pair_centres_placeable(1, 0, 1));
    assert!(pair_centres_placeable(1, 1, 1));
}

/// Matching step 7: two modes 0.1 % apart whose shapes the mesh has the other way round (an
/// avoided crossing). The recording's loud, gliding mode is the lower one; the mesh gives the
/// lower one a drive of 0.05 and the upper one the loud mode's drive. Matched by frequency,
/// the glide's energy covariate is swapped; the exchange of shapes puts it right, the glide is
/// found, and with the mesh's shapes the right way round nothing is exchanged.
#[test]
fn near_crossing_modes_exchange_the_shapes_they_carry() {
    let build = |crossed: bool| {
        let truth = Truth {
            glide: Some(2e-3),
            ..Truth::default()
        };
        let (mut ev, _) = evidence(&truth, 30);
        // The loudest single-member cluster and its recorded mode in each set.
        let sizes = |c: usize| ev.simulated.iter().filter(|m| m.cluster == c).count();
        let k = (0..ev.simulated.len())
            .filter(|&j| sizes(ev.simulated[j].cluster) == 1)
            .max_by(|&a, &b| ev.simulated[a].drive.total_cmp(&ev.simulated[b].drive))
            .unwrap();
        let loud = ev.simulated[k].clone();
        let quiet_drive = 0.05;
        let mut partner = loud.clone();
        partner.frequency_hz *= 1.001;
        partner.drive = quiet_drive;
        partner.cluster = ev.simulated.iter().map(|m| m.cluster).max().unwrap() + 1;
        if crossed {
            // The mesh's lower mode carries the quiet shape, its upper one the loud shape.
            std::mem::swap(&mut ev.simulated[k].drive, &mut partner.drive);
        }
        ev.simulated.push(partner);
        let mut loud_observed = 0;
        for (n, set) in std::iter::once(&mut ev.fit)
            .chain(ev.held_out.iter_mut())
            .enumerate()
        {
            let i = (0..set.len())
                .min_by(|&a, &b| {
                    let d = |m: &ObservedMode| (m.frequency_hz / loud.frequency_hz).ln().abs();
                    d(&set[a]).total_cmp(&d(&set[b]))
                })
                .unwrap();
            let mut quiet = set[i].clone();
            quiet.frequency_hz *= 1.001;
            let ratio = quiet_drive / loud.drive;
            quiet.amplitudes.iter_mut().for_each(|a| *a *= ratio);
            quiet.sigma_amplitudes.iter_mut().for_each(|s| *s *= ratio);
            quiet.glide = quiet.glide.map(|(_, s)| (0.0, s / ratio));
            set.push(quiet);
            if n == 0 {
                loud_observed = i;
            }
        }
        (ev, k, loud_observed)
    };
    for crossed in [true, false] {
        let (ev, k, i) = build(crossed);
        let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
        let pair = report
            .matching
            .pairs
            .iter()
            .find(|p| p.observed == i)
            .expect("the loud mode is matched");
        let loud_shape = if crossed { ev.simulated.len() - 1 } else { k };
        assert_eq!(
            pair.simulated,
            vec![loud_shape],
            "crossed {crossed}: {pair:?}"
        );
        expect_accepted(&report, "pitch_glide");
    }
}

/// Each microphone of `modes` cut to its first, whose levels take an independent radiation
/// error of `sigma` in ln a per mode (as generator 2 draws one per mode and microphone).
fn one_microphone(modes: &mut [ObservedMode], sigma: f64, rng: &mut Rng) {
    for m in modes {
        m.amplitudes.truncate(1);
        m.sigma_amplitudes.truncate(1);
        m.amplitudes[0] *= (sigma * normal(rng)).exp();
    }
}

/// Keeps every `n`-th mode (the `n`-th, the `2n`-th, ...): few modes, as a small object gives.
fn every_nth(modes: &mut Vec<ObservedMode>, n: usize) {
    let mut i = 0;
    modes.retain(|_| {
        i += 1;
        i % n == 0
    });
}

/// The fewest microphones a user can give: one fit and one held out, each mode's level off by
/// its own ±30 % at each, and every other mode only (few modes, as a small plate gives).
/// A hard mallet's knee (a 0.16 ms Hertzian pulse) is fitted on the one microphone, where it
/// and the per-mode scatter share the amplitude floor, so the floor before the contact has
/// swallowed part of the shape; the held-out microphone is judged on the smaller floor
/// (parent docs, "Selection", *A level shape is judged on the smaller amplitude floors*;
/// generator 2's seed 5001 case 006). Without a contact the same setting names none.
#[test]
fn a_contact_heard_by_one_fit_microphone_is_confirmed_by_the_other() {
    let draws = |truth: &Truth| -> usize {
        (90..102)
            .filter(|&seed| {
                let (mut ev, _) = evidence(truth, seed);
                let mut rng = Rng(seed.wrapping_mul(7919) | 1);
                every_nth(&mut ev.fit, 2);
                one_microphone(&mut ev.fit, 0.3, &mut rng);
                if let Some(held) = ev.held_out.as_mut() {
                    every_nth(held, 2);
                    one_microphone(held, 0.3, &mut rng);
                }
                let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
                accepted(&report, "contact_duration").is_some()
            })
            .count()
    };
    let contact = draws(&Truth {
        hertz: Some(1.6e-4),
        ..Truth::default()
    });
    let clean = draws(&Truth::default());
    println!("named in {contact} of 12 draws with a contact, {clean} of 12 without");
    // Measured: 5 of 12 (2 of 12 judged on the floors before the contact); 0 of 12 without a
    // contact either way.
    assert!(contact >= 4, "named in {contact} of 12");
    assert_eq!(clean, 0, "named in {clean} of 12 draws without a contact");
}

/// A damping law heard by one fit microphone and checked on the other: every third mode, each
/// level off by its own ±30 % at each microphone, and each decay rate by its own ±10 % beyond
/// its stated error (an unresolved pair beats differently at each microphone, so each
/// extraction biases its decay its own way: generator 2's seed 167 case 008, a cup's pair at
/// 2474 Hz measured at 3.1 and 3.2 1/s on the fit microphone and 2.96 and 2.80 on the held-out
/// one). Before the law enters, the decay floor is profiled about Rayleigh's misfit of it, and
/// the held-out decays are judged on that inflated scale; judged on the smaller floor (parent
/// docs, "Selection", *A decay law is judged on the smaller decay floor*), more true laws are
/// confirmed, and a Rayleigh object in the same setting is not named more often.
#[test]
fn a_damping_law_heard_by_one_fit_microphone_is_confirmed_by_the_other() {
    let draws = |truth: &Truth| -> usize {
        (90..138)
            .filter(|&seed| {
                let (mut ev, _) = evidence(truth, seed);
                let mut rng = Rng(seed.wrapping_mul(7919) | 1);
                let sparse = |modes: &mut Vec<ObservedMode>, rng: &mut Rng| {
                    every_nth(modes, 3);
                    one_microphone(modes, 0.3, rng);
                    for m in modes.iter_mut() {
                        m.decay_rate *= (0.1 * normal(rng)).exp();
                    }
                };
                sparse(&mut ev.fit, &mut rng);
                if let Some(held) = ev.held_out.as_mut() {
                    sparse(held, &mut rng);
                }
                let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
                accepted(&report, "non_rayleigh_damping").is_some()
            })
            .count()
    };
    let law = draws(&Truth {
        power_law: Some((3.0, 0.4)),
        ..Truth::default()
    });
    let rayleigh = draws(&Truth::default());
    println!("named in {law} of 48 draws with d ∝ f^0.4, {rayleigh} of 48 with Rayleigh's law");
    // Measured: 37 of 48 (31 judged on the decay floor before the law); 1 of 48 with
    // Rayleigh's law either way.
    assert!(law >= 35, "named in {law} of 48");
    assert!(
        rayleigh <= 2,
        "named in {rayleigh} of 48 draws with Rayleigh's law"
    );
}

/// A support that damps weakly (γ = 0.4 1/s at weight 1, against the fit's σ_γ of 0.13–0.27)
/// is named on its damping at 2σ when it also pays for itself and lowers the held-out error,
/// and no support is named where there is none (module docs of `support_contact`, *Back to
/// 2σ*). Measured over 48 draws: 18 named with the 2σ rule, 16 with the 3σ rule before it;
/// none without a support either way. 16 with the 2σ rule since an unresolved cluster's pole
/// carries its members' beat in its ln d σ (`unresolved` module docs): this world's three
/// degenerate clusters (split 2·10⁻⁵, δ/d ≈ 0.02) widen by 0.01–0.02 against σ_ln d = 0.04,
/// and their poles here decay exactly as their members, which a recording's do not.
#[test]
fn a_weak_support_is_named_on_its_damping_at_two_sigma() {
    let named = |gamma: f64| {
        (1..=48u64)
            .filter(|&seed| {
                let truth = Truth {
                    support: Some((gamma, 0.0)),
                    ..Truth::default()
                };
                let report = run(&truth, seed);
                assert!(
                    report.accepted.iter().all(|a| a.name == "support_contact"),
                    "γ = {gamma}, seed {seed}: {:#?}",
                    report.accepted
                );
                accepted(&report, "support_contact").is_some()
            })
            .count()
    };
    let weak = named(0.4);
    assert!(weak >= 16, "a weak support named in {weak} of 48 draws");
    assert_eq!(named(0.0), 0, "a support named where there is none");
}

/// Each microphone of `modes` cut to its first two, whose levels take an independent radiation
/// error of `sigma` in ln a per mode and microphone (generator 2's draw).
fn two_microphones(modes: &mut [ObservedMode], sigma: f64, rng: &mut Rng) {
    for m in modes {
        m.amplitudes.truncate(2);
        m.sigma_amplitudes.truncate(2);
        for a in &mut m.amplitudes {
            *a *= (sigma * normal(rng)).exp();
        }
    }
}

/// Two fit microphones cannot test a directivity without positions (radiation module docs,
/// *Two microphones cannot test the factor*): the factor's u_k per mode fit every mode's mix
/// between them exactly. On clean recordings whose levels scatter per mode and microphone by
/// ±40 % (generator 2's radiation), the report must say the factor could not be tested, never
/// fit it. Measured before the rule (its channel minimum set to 2), over these 12 draws: the
/// factor was fitted in every one, passed the ΔBIC threshold of 3 in 8 (up to 20.3) and was
/// stopped only by the held-out check.
#[test]
fn two_fit_microphones_cannot_test_a_directivity_without_positions() {
    for seed in 140..152 {
        let (mut ev, _) = evidence(&Truth::default(), seed);
        let mut rng = Rng(seed.wrapping_mul(7919) | 1);
        two_microphones(&mut ev.fit, 0.4, &mut rng);
        if let Some(held) = ev.held_out.as_mut() {
            two_microphones(held, 0.4, &mut rng);
        }
        let report = diagnose(&ev, &CatalogueSettings::default()).expect("valid");
        assert!(
            accepted(&report, "radiation").is_none(),
            "seed {seed}: radiation accepted on two fit microphones"
        );
        let r = rejected(&report, "radiation");
        assert_eq!(r.reason, Rejection::NotEnoughData, "seed {seed}: {r:#?}");
        assert!(r.detail.contains("at least 3"), "seed {seed}: {}", r.detail);
    }
}

/// The held-out microphones hear a pair's partial beside both members (beating_pair module
/// docs, *Heard beside the members*): members at 2000 and 2010 Hz (d = 20 1/s: tolerance about
/// 1 Hz), so a held-out pole between 5 + 1 and 10 Hz outside the pair contradicts it, unless
/// another lies at a member or at the pair's centre.
#[test]
fn a_pair_heard_only_beside_its_members_is_not_replicated() {
    use super::beating_pair::pair_heard_beside_its_members;
    let (lo, hi) = ((2000f64.ln(), 1e-5, 20.0), (2010f64.ln(), 1e-5, 20.0));
    let at = |fs: &[f64]| fs.iter().map(|&f| observed_at(f)).collect::<Vec<_>>();
    assert!(!pair_heard_beside_its_members(lo, hi, &at(&[])));
    assert!(pair_heard_beside_its_members(lo, hi, &at(&[2017.0])));
    assert!(pair_heard_beside_its_members(lo, hi, &at(&[1992.0])));
    assert!(pair_heard_beside_its_members(hi, lo, &at(&[2017.0])));
    // At a member, at the centre (the pair unresolved there), or too far to be this partial.
    assert!(!pair_heard_beside_its_members(
        lo,
        hi,
        &at(&[2017.0, 2010.2])
    ));
    assert!(!pair_heard_beside_its_members(
        lo,
        hi,
        &at(&[2017.0, 2005.0])
    ));
    assert!(!pair_heard_beside_its_members(lo, hi, &at(&[2012.0])));
    assert!(!pair_heard_beside_its_members(lo, hi, &at(&[2025.0])));
}

/// A split pair one of whose poles (or both) an established room holds is not a candidate of
/// the split screen (beating_pair module docs, *Held by the room*); held by no room, the same
/// pairs are.
#[test]
fn a_pair_with_a_pole_the_room_holds_is_not_the_objects_split() {
    let settings = CatalogueSettings::default();
    let truth = Truth {
        splits: vec![(3, 0.004), (8, 0.004)],
        ..Truth::default()
    };
    let (ev, _) = evidence(&truth, 7);
    let screen = |room_rate: Option<f64>| {
        let (mut table, _, ln_scale) = fit_and_held_tables(&ev, &settings);
        if let Some(rate) = room_rate {
            table.set_aside_room_held(rate);
        }
        let ln_f_ref = ln_scale
            + table.modes.iter().map(|m| m.ln_f_sim).sum::<f64>() / table.modes.len() as f64;
        let base_model = Model::new(vec![], ln_f_ref, table.channels);
        let x0 = model::baseline_start(&table, &base_model, ln_scale);
        let baseline = fit(&table, base_model, x0);
        beating_pair::split_candidates(&table, ev.held_out.as_deref(), &baseline)
    };
    let free = screen(None).expect("two candidates without a room");
    assert_eq!(free.splits.clusters.len(), 2, "{:?}", free.splits.clusters);
    // A room slower than every mode holds every pole.
    match screen(Some(1e-3)) {
        Ok(c) => panic!(
            "candidates {:?} from poles the room holds",
            c.splits.clusters
        ),
        Err(Detection::Nothing { detail, .. }) => {
            assert!(detail.contains("2 with a pole the room holds"), "{detail}")
        }
        Err(other) => panic!("{other:?}"),
    }
    // A room whose rate lies between the two members' decay rates of the lower pair holds one
    // pole of it (and both of the upper pair's, which decay faster): one held pole is enough.
    let (table, _, _) = fit_and_held_tables(&ev, &settings);
    let lower_pair = table
        .pairs
        .iter()
        .min_by(|a, b| {
            table.modes[a.lower]
                .ln_f
                .total_cmp(&table.modes[b.lower].ln_f)
        })
        .expect("a pair");
    let (Some((dl, _)), Some((du, _))) = (
        table.modes[lower_pair.lower].ln_d,
        table.modes[lower_pair.upper].ln_d,
    ) else {
        panic!("the lower pair's decay rates")
    };
    assert!((dl - du).abs() > 0.0, "members decaying alike");
    match screen(Some((0.5 * (dl + du)).exp())) {
        Ok(c) => panic!(
            "candidates {:?} with a pole the room holds",
            c.splits.clusters
        ),
        Err(Detection::Nothing { detail, .. }) => {
            assert!(detail.contains("2 with a pole the room holds"), "{detail}")
        }
        Err(other) => panic!("{other:?}"),
    }
}

/// The room's T60 is measured band by band (reverb_noise module docs, "The room's T60"): a room
/// of T60 = 0.4 s in all six bands, and in two of them the slower misfit of modes that ring
/// longer than the room (T60 2 s, a tenth of the room's excess at t = 0). The shared fit takes
/// some of the misfit; the lower quartile of the bands' own T60s is the room's.
#[test]
fn the_rooms_t60_is_the_lower_quartile_of_the_bands_own() {
    let mut rng = Rng(97);
    let times: Vec<f64> = (0..120).map(|j| 0.01 * j as f64).collect();
    let (mut energy, mut floor) = (Vec::new(), Vec::new());
    for b in 0..6 {
        let n = 10f64.powf(rng.uniform(-7.0, -5.0));
        let rho = 10f64.powf(rng.uniform(1.5, 2.0));
        let misfit = if b == 1 || b == 2 { 0.1 * rho } else { 0.0 };
        let row = times
            .iter()
            .map(|&t| {
                let mean = n
                    * (1.0
                        + rho * (-13.815510557964274 * t / 0.4).exp()
                        + misfit * (-13.815510557964274 * t / 2.0).exp());
                let chi2: f64 = (0..30).map(|_| normal(&mut rng).powi(2)).sum::<f64>() / 30.0;
                mean * chi2
            })
            .collect();
        energy.push(row);
        floor.push(n);
    }
    let evidence = Evidence {
        fit: Vec::new(),
        held_out: None,
        simulated: Vec::new(),
        residual_envelopes: Some(ResidualEnvelopes {
            times_s: times,
            band_edges_hz: vec![0.0, 500.0, 1000.0, 2000.0, 4000.0, 8000.0, 16000.0],
            energy,
            noise_floor_estimate: floor,
            frames_per_window: 1.0,
        }),
        split_sites: None,
    };
    let eval = ReverbNoise
        .evaluate_own(&evidence, &CatalogueSettings::default())
        .expect("an evaluation");
    let OwnOutcome::Fitted { params, .. } = eval.outcome else {
        panic!("no fit: {:?}", eval.outcome);
    };
    let room = &params[0];
    let shared = params.last().expect("the shared fit's T60");
    assert_eq!(room.name, "reverberation time T60");
    assert!(shared.name.starts_with("T60 of the shared fit"));
    println!("room {room:?}, shared {shared:?}");
    assert!((room.value / 0.4 - 1.0).abs() < 0.1, "{room:?}");
    assert!(
        shared.value > 1.15 * room.value,
        "{shared:?} against {room:?}"
    );
}

#[test]
fn profiled_slope_test_is_not_capped_by_the_number_of_points() {
    use super::profiled_slope_through_origin;
    // Two split pairs whose upper members both decay faster by about b x, to their precision.
    let agree = [(0.6, 4.0, 0.01), (0.6, 4.4, 0.01)];
    let (b, z) = profiled_slope_through_origin(&agree).unwrap();
    assert!((b - 7.0).abs() < 0.1, "slope {b}");
    assert!(z > 3.0, "z {z}");
    // The Wald z with the floor the null profiles (τ² = mean square less s²) stays near √2.
    let tau2 = (16.0 + 19.36) / 2.0 - 0.01;
    let sxx: f64 = agree.iter().map(|p| p.0 * p.0 / (p.2 + tau2)).sum();
    let sxy: f64 = agree.iter().map(|p| p.0 * p.1 / (p.2 + tau2)).sum();
    assert!(sxy / sxx.sqrt() < 1.5);
    // Opposite signs: no slope to speak of.
    let (_, z) = profiled_slope_through_origin(&[(0.6, 4.0, 0.01), (0.6, -4.0, 0.01)]).unwrap();
    assert!(z.abs() < 0.5, "z {z}");
    // Points that scatter about a slope by far more than their σ: the floor profiled under the
    // alternative keeps z modest.
    let scattered = [
        (0.6, 4.0, 0.01),
        (0.5, 0.3, 0.01),
        (0.7, 1.5, 0.01),
        (0.6, -1.0, 0.01),
    ];
    let (_, z) = profiled_slope_through_origin(&scattered).unwrap();
    assert!(z > 0.0 && z < 2.5, "z {z}");
    // Without x: none.
    assert!(profiled_slope_through_origin(&[(0.0, 1.0, 0.1)]).is_none());
    assert!(profiled_slope_through_origin(&[]).is_none());
}

#[test]
fn a_supports_wide_split_of_the_lowest_pair_is_matched_as_a_pair() {
    // A tube on a rail (generator 2's spent seed 307 case 021): the rail's spring raised the
    // pressing member of the lowest bending pair 2.1 % above the other, the pairs above by
    // 0.3 %. Both members must be matched to their cluster, so that their decay rates can
    // show the support (catalogue docs, *How far a pair may split*).
    let simulated = vec![
        sim(2359.1, 0),
        sim(2359.7, 0),
        sim(5849.4, 1),
        sim(5853.5, 1),
        sim(6187.2, 2),
        sim(7900.9, 3),
    ];
    let obs_hz = [2369.7, 2419.5, 5831.4, 5848.2, 6190.0, 7910.5];
    let ln: Vec<f64> = obs_hz.iter().map(|f: &f64| f.ln()).collect();
    let m = match_modes(&ln, &[], &simulated, None, &CatalogueSettings::default());
    assert!(
        m.unmatched_observed.is_empty(),
        "{:?}",
        m.unmatched_observed
    );
    let unit = |i: usize| m.units.iter().find(|u| u.observed == i).expect("matched");
    assert_eq!(
        (unit(0).role, unit(1).role),
        (Role::SplitLower, Role::SplitUpper)
    );
    assert_eq!((unit(0).cluster, unit(1).cluster), (0, 0));
    // At the old 1.5 % the raised member was left unmatched.
    let narrow = CatalogueSettings {
        max_pair_split: 0.015,
        ..CatalogueSettings::default()
    };
    let m = match_modes(&ln, &[], &simulated, None, &narrow);
    assert_eq!(m.unmatched_observed, vec![1]);
}
