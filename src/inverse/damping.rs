//! Stage 1 of the material fit: the damping of a struck object, d(f), from a recording.
//!
//! An additive synthesiser with many free modes plus filtered noise is fitted to the recording;
//! the modes that are real (judged by decay, SNR and level, thresholds below) are grouped into
//! spectral peaks, each peak gets one decay rate, and the peaks give a continuous
//! [`DampingCurve`] d(f) and, as the two-parameter special case beside it, Rayleigh damping
//! (α, β).
//!
//! # Model
//!
//! Channels s_c[n], c = 0 … C − 1, n = 0 … N − 1 at f_s (Hz), starting at the strike onset (the
//! caller trims), t = n / f_s:
//!
//! ŝ_c[n] = Σ_k a_{kc} e^(−d_k t) sin(2π f_k t + φ_{kc}) + y_c[n]
//!
//! with frequency f_k (Hz) and decay rate d_k (1/s) shared by all channels, amplitude a_{kc}
//! (units of the signal) and phase φ_{kc} (rad) per channel ([`crate::audio::synth`]), and
//! y_c the filtered noise of [`crate::audio::noise`] with magnitudes H_c[m][b] (dimensionless
//! gains per frame m and band b; a flat gain h gives white noise of variance h²/3). The noise
//! takes what the modes cannot: the contact transient, scrape, room and microphone noise.
//! Without it the fit would widen or lift modes to fill noise in the log-spectral loss.
//!
//! # Steps of [`fit_damping`]
//!
//! 1. Crop to [`DampingFitSettings::duration_s`] if given.
//! 2. Estimate modes with sub-band ESPRIT ([`crate::analysis::estimate`]) on the record after
//!    skipping t₀ = [`DampingFitSettings::estimate_skip_s`] (n₀ = round(t₀ f_s) samples; default
//!    20 ms): the contact transient gives fast spurious poles. A mode estimated as
//!    a′ e^(−d t′) sin(2π f t′ + φ′) with t′ = t − t₀ is, from the onset, a = a′ e^(d t₀),
//!    φ = φ′ − 2π f t₀ (exact, since t₀ = n₀/f_s). The [`DampingFitSettings::max_modes`] modes of
//!    highest SNR are kept.
//! 3. Refine all parameters by Adam ([`super::optim`]) on L = Σ_c L_spec(ŝ_c, s_c), the
//!    multi-scale spectral loss ([`crate::audio::loss`]), with exact gradients from
//!    [`crate::audio::synth::render_backward`] and [`FilteredNoise::backward`]. Parameters:
//!    f_k (Hz), ln d_k, ln a_{kc}, φ_{kc}, ln H_c[m][b]; logs keep d, a, H positive and make one
//!    step size per group mean a relative change. f_k stays within
//!    ±[`DampingFitSettings::max_frequency_shift_hz`] of the estimate, so a mode cannot wander
//!    onto a neighbour (ESPRIT's frequencies are already accurate to ~0.02 Hz, far finer than
//!    the spectral loss resolves). Step sizes decay geometrically to
//!    [`DampingFitSettings::final_step_fraction`] of their start over the run. The parameters
//!    of the step with the lowest loss are returned (Adam on an L1 loss does not descend
//!    monotonically; step 0 — the estimate with the initial noise — is a candidate too).
//!
//!    The noise starts from the residual r_c = s_c − (estimated modes), frame by frame: the
//!    Hann periodogram P_k of the S = max(hop, L) samples centred on frame m's noise block,
//!    averaged over the bins within one band spacing of each band, gives the gain
//!    h = √(3 P / Σ w²) of white noise of that power (white noise of variance σ² has
//!    E P_k = σ² Σ w²), scaled by [`DampingFitSettings::noise_init_db`] (default −6 dB: the
//!    residual also holds the estimate's errors, which the refinement fixes on the mode side).
//!    On the bowl this start alone lowers L from 38.9 (modes only) to 25.4. A first version
//!    averaged 3 × 3 periodogram cells of twice the length; it smeared a 3 ms transient over
//!    three frames and started the fit above the modes-only loss. The noise needs a larger
//!    step (default 0.2 per step in ln H) than the modes: with 0.05 it could not fall far
//!    enough in a short run where the start was too loud.
//! 4. Give every mode a verdict ([`ModeVerdict`]; thresholds below).
//! 5. Group the modes that passed into spectral peaks and give each peak one decay rate (below).
//! 6. Fit the damping curve ([`fit_damping_curve`]) to the peaks at their undamped frequency
//!    f₀ = √(f² + (d / 2π)²) (the convention of [`crate::audio::chain`]: the curve and Rayleigh
//!    are functions of ω = 2π f₀, and a mode rings at ω_d = √(ω² − d²)), with weights
//!    w = 1 / (4 · 10^(−SNR/10) + σ_m²). 4/SNR is the Cramér–Rao variance of ln d for one
//!    damped sinusoid in white noise with unknown amplitude (Fisher information of (ln a, d):
//!    I = SNR [[1, −1/(2d)], [−1/(2d), 1/(2d²)]], so var d = 4 d² / SNR), and
//!    σ_m = [`DampingFitSettings::decay_scatter`] (default 0.1) the peak-to-peak scatter of ln d
//!    about any smooth curve. Without σ_m a loud peak would outweigh a quiet one by its SNR
//!    ratio (10⁵ for 50 dB), although both measure the curve only to the scatter. The peak
//!    furthest off the curve, if d / d(f₀) lies outside [1/r, r] (r =
//!    [`DampingFitSettings::max_curve_ratio`], default 3: |ln ratio| > 1.1, ≥ 3.7 σ for the
//!    scatter of 0.3 seen on the bowl), is rejected ([`ModeVerdict::OffCurve`]) and the curve
//!    refitted, until no peak is that far off (one or two peaks always fit, so some are kept).
//! 7. Fit Rayleigh ([`fit_rayleigh`]) to the same peaks and weights.
//!
//! # Mode thresholds (which modes are real)
//!
//! In this order (the first that fails is the [`ModeVerdict`]):
//!
//! * decay: [`DampingFitSettings::min_decay_rate`] < d ≤ [`DampingFitSettings::max_decay_rate`],
//!   default (0, 300] 1/s. d ≤ 0 does not decay (noise or hum). At d = 300 1/s a mode falls
//!   60 dB in 23 ms, half the longest frame of the loss (2048 samples = 43 ms at 48 kHz): faster
//!   poles are not resolved in time by the loss and are the contact transient. It is also the
//!   default cap of the estimate, so nothing faster is initialised unless asked.
//! * SNR (of the estimate, over the residual noise in its band; [`crate::analysis::estimate`]) ≥
//!   [`DampingFitSettings::min_snr_db`], default 30 dB: by the Cramér–Rao bound above, the
//!   relative error of d is at least 2/√SNR, 6 % at 30 dB (20 % at the estimate's own 20 dB,
//!   which only separates modes from noise poles). Note that this SNR is measured against the
//!   band's residual after fitting up to 40 poles; in a nearly noise-free test record, poles
//!   fitted to the −110 dB noise scored 32–55 dB, so the level test below is what removes them.
//! * level: ℓ_k = 10 log10(Σ_c a_{kc}² / max_j Σ_c a_{jc}²) ≥ [`DampingFitSettings::min_level_db`],
//!   default −60 dB, the maximum taken over the modes that passed the decay test (a
//!   back-extrapolated transient pole must not set the reference). The spectral loss ignores
//!   magnitudes below ε = 10⁻⁴ of the target's peak (−80 dB): a mode 60 dB below the strongest
//!   is seen for at least 20 dB of its decay, whereas a weaker one barely moves the loss and its
//!   refined parameters are not determined by the data (in the tests such modes drift by 50 %
//!   in d during the refinement while real ones stay within 0.1 %).
//!
//! # Peaks
//!
//! On the bowl every audible partial is fitted by a cluster of 2–9 poles within ~50–150 Hz
//! whose individual decays scatter from 8 to 240 1/s (e.g. 4145.6/71.7, 4162.6/46.2,
//! 4168.5/19.5, 4170.5/7.6 Hz/(1/s)), while the band energy of the recording falls along one
//! slope (≈ 9–13 1/s at 4.16 kHz). A partial that is not one exponential (beating of a split
//! pair, a slight glide, a fast early part) is expanded in several stationary poles; their
//! individual decays mean nothing alone, and fitting a curve to them put d(4.2 kHz) at 50 1/s.
//! So the modes that passed are sorted by frequency and neighbours j, k are linked into one
//! peak when |f_j − f_k| ≤ [`DampingFitSettings::peak_width`] · (d_j + d_k)/(2π) (their lines,
//! of half-width d/(2π) Hz, overlap) or ≤ 2/T (closer than the record can resolve). The
//! default width 3 joins the satellites seen on the bowl 2–3 half-widths off a partial
//! (4184.3/34.4 next to 4170.5/7.6) and keeps partials 4 half-widths apart (7023/142 and
//! 7258/240) separate.
//!
//! A peak's decay rate is that of its energy-decay curve (Schroeder), in closed form for the
//! fitted poles with complex amplitudes C_{kc} = a_{kc} e^(iφ_{kc}), s_k = −d_k + i 2π f_k:
//!
//! E(t) = Σ_c ∫_t^∞ |Σ_k C_{kc} e^(s_k τ)|² dτ = Re Σ_{jk} G_{jk} e^((s_j + s̄_k) t) / −(s_j + s̄_k),
//! G_{jk} = Σ_c C_{jc} C̄_{kc},
//!
//! monotone, and E ∝ e^(−2dt) exactly for a single pole, so a lone mode keeps its own d. d is
//! the least-squares slope of ln E = const − 2 d t over 33 points between the times where E is
//! 5 and 35 dB below E(0) ([`DampingFitSettings::decay_range_db`], the T30 range of room
//! acoustics, which leaves out the fast early part of a partial). On the bowl the 5–25, 5–35
//! and 10–40 dB ranges gave 10.7, 9.5, 8.7 1/s at 4.16 kHz and 50, 42, 36 1/s at 7.29 kHz.
//! The peak's frequency is the members' mean weighted by their energies Σ_c a²/(4d), its SNR
//! 10 log10 Σ 10^(SNR_k/10), its level the energy E(0) relative to the most energetic peak.
//!
//! # Damping curve ([`fit_damping_curve`])
//!
//! θ_j = ln d at K knots x_j = ln f_j, evenly spaced in ln f from the lowest to the highest
//! point, K = min(⌈octaves · [`CurveFitSettings::knots_per_octave`]⌉ + 1, max(2, ⌊n /
//! [`CurveFitSettings::modes_per_knot`]⌋)) (K = 1, a constant, if all points share one
//! frequency). ln d is linear in ln f between knots (the [`DampingCurve`] of
//! [`crate::audio::chain`], a power law beyond the ends). θ minimises
//!
//! Σ_i w_i u_i (ln d_i − Σ_j B_ij θ_j)² + λ Σ_j (θ_{j−1} − 2θ_j + θ_{j+1})²,
//! λ = s · Σ_i w_i u_i / K
//!
//! with B the hat functions of the knots: the second-difference penalty vanishes on power laws
//! and makes knots without nearby points follow their neighbours, so dense knots stay well
//! posed. u_i are Huber weights, iterated (IRLS): u_i = min(1, k σ / |r_i|) with k =
//! [`CurveFitSettings::huber_threshold`] (1.345, 95 % efficiency for Gaussian scatter), the
//! residuals r_i and the robust scale σ = max(median |r_i| / 0.6745,
//! [`CurveFitSettings::scale_floor`]): a point off the trend (a beating pair, a mode damped by
//! its mount) pulls with a bounded force instead of bending the curve (test: 5 % scatter plus
//! every 7th point 40–100 % off gives an rms error of 2.6 % robust, 7 % plain).
//!
//! The smoothness s is [`CurveFitSettings::smoothness`] if given, else chosen at every IRLS
//! pass by generalised cross-validation, GCV(s) = n Σ w u r² / (n − tr H)² with
//! tr H = tr((BᵀWUB + λDᵀD)⁻¹ BᵀWUB), over s = 10⁻², 10^(−1.5), …, 10² (the smallest wins
//! ties, so exact data are fitted as closely as the grid allows). The grid starts at 10⁻²
//! because on the bowl (18 peaks, 9 knots, two peaks a factor 3 apart in d within one knot
//! interval) GCV down to 10⁻⁴ chose near-interpolation and the curve swung to 12 000 1/s
//! between peaks; from 10⁻² it chose s = 1 and a monotone curve.
//!
//! # Rayleigh ([`fit_rayleigh`])
//!
//! α, β ≥ 0 minimising Σ_i w_i (ln d_i − ln((α + β ω_i²)/2))², ω_i = 2π f_i. With
//! q_i = ω_i²/ω_r² (ω_r² the weighted mean of ω²) and b = β ω_r² the two unknowns have similar
//! scales. Candidates: the two boundary optima in closed form (β = 0: ln α = mean of ln 2d;
//! α = 0: ln b = mean of ln(2d/q)), and an interior Levenberg–Marquardt solve in (ln α, ln b)
//! started from the linear least-squares fit of the relative errors (α + b q_i)/(2 d_i) − 1
//! (exact on exact Rayleigh data). The best candidate wins.
//!
//! # Cost and the bowl (measured, release build, 2 shared cores)
//!
//! Per refinement step and channel: render and backward of the modes (one complex multiply-add
//! per mode and sample each), the loss and its gradient (6 FFT sizes, the largest share), the
//! noise forward and backward. `examples/damping_probe.rs` on the bowl (8 channels × 1 s at
//! 48 kHz, onset-trimmed, default settings):
//!
//! * estimate: 93 modes in 0.5 s; refinement: 150 steps in 18–31 s, 0.12–0.21 s per step
//!   depending on the machine's load; the unit tests take ~1 s.
//! * loss: 38.9 (estimated modes alone) → 25.4 (with the initial noise) → 17.1 after 150 steps
//!   (17.7 with a noise step of 0.05).
//! * verdicts: 3 modes too fast, 5 below 30 dB SNR, the other 84 in 18 peaks, 17 peaks kept
//!   (7023 Hz with d = 142 1/s is off the curve).
//! * curve: 3.1 1/s at 1.68 kHz, 13 at 4.2 kHz, 31 at 7.3 kHz, 47 at 10.6 kHz, 61 at 15 kHz,
//!   66 at 22 kHz (rms ln error 0.15); the peaks' decays agree with the slopes of the band
//!   energy of the recording (≈ 3.1, 13, 32, 40–50 1/s at 1.68, 4.16, 7.36, 11.15 kHz).
//! * Rayleigh: α = 10.1 1/s, β = 1.04·10⁻⁸ s, rms ln error 0.40: d grows much more slowly than
//!   ω² above ~7 kHz, so the best Rayleigh fit is 1.8× too high at 1.7 kHz, 2× too low at
//!   7.4 kHz and 1.6× too high at 22 kHz. The curve, not Rayleigh, is the bowl's damping.

#[cfg(test)]
mod tests;

use std::f64::consts::PI;
use std::time::Instant;

use nalgebra::{DMatrix, DVector};
use rustfft::num_complex::Complex64;

use super::optim::Adam;
use crate::analysis::estimate::{estimate_modes, EstimateError, EstimateOptions};
pub use crate::analysis::mode::ModeVerdict;
use crate::analysis::mode::{MeasuredMode, RefinedFrom, Verdict};
use crate::audio::chain::DampingCurve;
use crate::audio::loss::{LossError, MultiScaleSpectralLoss, SpectralLossConfig};
use crate::audio::noise::{FilteredNoise, NoiseError};
use crate::audio::synth::{render_backward, render_samples, ModalBank};
use crate::numerics::lm;

/// The generalised cross-validation choice of the curve's smoothness: s from 10⁻² to 10² in 8
/// steps of half a decade, from a loose fit to a nearly pure power law (module docs: why not
/// lower).
const SMOOTHNESS_GRID: (f64, f64, usize) = (1e-2, 1e2, 8);

/// Smallest decay rate a mode starts the refinement with, 1/s (ln d must be finite).
const MIN_START_DECAY: f64 = 1e-3;

/// Bounds of ln d during the refinement, 1/s: far outside any threshold, so a bound never
/// decides a verdict, but a runaway step cannot overflow.
const DECAY_BOUNDS: (f64, f64) = (1e-4, 1e4);

/// Bounds of the noise gains relative to √3 × the channel's peak |s| (the gain of white noise
/// as loud as the peak): −160 dB … +20 dB.
const NOISE_BOUNDS: (f64, f64) = (1e-8, 10.0);

/// Settings of [`fit_damping_curve`]; see the module docs.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CurveFitSettings {
    /// Knots per octave of the kept modes' range (default 3).
    pub knots_per_octave: f64,
    /// At most one knot per this many modes, but at least 2 knots (default 2).
    pub modes_per_knot: f64,
    /// s: λ = s Σ w u / K, the weight of the second-difference penalty relative to the data
    /// per knot; `None` (default) chooses s by generalised cross-validation.
    pub smoothness: Option<f64>,
    /// Huber threshold k in robust standard deviations (default 1.345).
    pub huber_threshold: f64,
    /// Floor of the robust scale σ, in ln d (default 0.01: residuals under 1.3 % always count
    /// fully, so exact data do not make every mode an outlier).
    pub scale_floor: f64,
    /// Most reweighting passes (default 50).
    pub max_iterations: usize,
}

impl Default for CurveFitSettings {
    fn default() -> Self {
        CurveFitSettings {
            knots_per_octave: 3.0,
            modes_per_knot: 2.0,
            smoothness: None,
            huber_threshold: 1.345,
            scale_floor: 0.01,
            max_iterations: 50,
        }
    }
}

/// Settings of [`fit_damping`]; see the module docs for how each is used.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DampingFitSettings {
    /// Options of the initial estimate.
    pub estimate: EstimateOptions,
    /// t₀: the estimate ignores the first t₀ seconds (default 0.02 s).
    pub estimate_skip_s: f64,
    /// Fit only the first this many seconds (default: all).
    pub duration_s: Option<f64>,
    /// Most modes refined, those of highest SNR (default 256).
    pub max_modes: usize,
    /// Adam steps (default 150; 0 = the estimate with the initial noise).
    pub steps: usize,
    /// Initial step sizes: f in Hz (default 0.05), ln d (0.02), ln a (0.02), φ in rad (0.02),
    /// ln H (0.2).
    pub step_frequency_hz: f64,
    pub step_log_decay: f64,
    pub step_log_amplitude: f64,
    pub step_phase: f64,
    pub step_log_noise: f64,
    /// Step sizes at the last step relative to the first (default 0.1).
    pub final_step_fraction: f64,
    /// f_k stays within this of its estimate, Hz (default 2).
    pub max_frequency_shift_hz: f64,
    /// The loss, per channel.
    pub loss: SpectralLossConfig,
    /// Noise bands B from 0 Hz to Nyquist (default 65: 375 Hz apart at 48 kHz).
    pub noise_bands: usize,
    /// Samples per noise frame (default 256: 5.3 ms at 48 kHz, short enough for the transient).
    pub noise_hop: usize,
    /// Initial noise relative to the residual's envelope, dB (default −6).
    pub noise_init_db: f64,
    /// Seed of the noise of channel c is `noise_seed + c`.
    pub noise_seed: u64,
    /// Thresholds (module docs): d in (min_decay_rate, max_decay_rate] 1/s (default (0, 300]),
    /// SNR ≥ min_snr_db (default 30 dB), level ≥ min_level_db (default −60 dB).
    pub min_decay_rate: f64,
    pub max_decay_rate: f64,
    pub min_snr_db: f64,
    pub min_level_db: f64,
    /// Peaks with d / d(f) outside [1/r, r] are rejected and the curve refitted (default
    /// r = 3).
    pub max_curve_ratio: f64,
    /// Neighbouring modes j, k are one peak if |f_j − f_k| ≤ peak_width · (d_j + d_k)/(2π)
    /// or ≤ 2/T (T the record length): default 3.
    pub peak_width: f64,
    /// The peak's decay rate is fitted to its energy-decay curve between these levels, dB
    /// below its start (default 5 and 35, the T30 range of room acoustics).
    pub decay_range_db: [f64; 2],
    /// σ_m, the scatter of ln d between modes used in the curve weights (default 0.1).
    pub decay_scatter: f64,
    pub curve: CurveFitSettings,
}

impl Default for DampingFitSettings {
    fn default() -> Self {
        DampingFitSettings {
            estimate: EstimateOptions::default(),
            estimate_skip_s: 0.02,
            duration_s: None,
            max_modes: 256,
            steps: 150,
            step_frequency_hz: 0.05,
            step_log_decay: 0.02,
            step_log_amplitude: 0.02,
            step_phase: 0.02,
            step_log_noise: 0.2,
            final_step_fraction: 0.1,
            max_frequency_shift_hz: 2.0,
            loss: SpectralLossConfig::default(),
            noise_bands: 65,
            noise_hop: 256,
            noise_init_db: -6.0,
            noise_seed: 1,
            min_decay_rate: 0.0,
            max_decay_rate: 300.0,
            min_snr_db: 30.0,
            min_level_db: -60.0,
            max_curve_ratio: 3.0,
            peak_width: 3.0,
            decay_range_db: [5.0, 35.0],
            decay_scatter: 0.1,
            curve: CurveFitSettings::default(),
        }
    }
}

/// One spectral peak: modes whose lines overlap (module docs), with one decay rate.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FittedPeak {
    /// Energy-weighted mean frequency of the members, Hz.
    pub frequency_hz: f64,
    /// √(f² + (d/2π)²) with d the peak's decay rate, Hz.
    pub undamped_frequency_hz: f64,
    /// The decay rate of the members' summed energy-decay curve (module docs), 1/s.
    pub decay_rate: f64,
    /// Energy of the peak (all channels) relative to the most energetic peak, dB.
    pub level_db: f64,
    /// 10 log10 Σ 10^(SNR/10) over the members, dB.
    pub snr_db: f64,
    /// Indices into [`DampingFit::modes`].
    pub members: Vec<usize>,
    pub kept: bool,
    /// Kept or OffCurve.
    pub reason: ModeVerdict,
    /// Weight in the final curve fit, w·u (0 if not kept).
    pub curve_weight: f64,
}

/// Rayleigh damping d = (α + β ω²)/2 fitted to decay rates.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RayleighFit {
    /// α, 1/s.
    pub alpha: f64,
    /// β, s.
    pub beta: f64,
    /// √(Σ w r² / Σ w) with r = ln d − ln((α + β ω²)/2).
    pub rms_log_error: f64,
}

/// One step of the refinement.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DampingStep {
    pub step: usize,
    /// L = Σ_c L_spec at the parameters before this step's update.
    pub loss: f64,
    /// Seconds since the refinement started.
    pub elapsed_s: f64,
}

/// The fitted noise, per channel.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NoiseFit {
    pub n_bands: usize,
    pub hop: usize,
    pub seed: u64,
    /// Band centres, Hz.
    pub band_frequencies_hz: Vec<f64>,
    /// Frame centres, s from the onset.
    pub frame_times_s: Vec<f64>,
    /// H_c, row-major frames × bands, per channel.
    pub magnitudes: Vec<Vec<f64>>,
}

/// The result of [`fit_damping`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DampingFit {
    pub sample_rate: f64,
    /// Samples per channel used (after the crop).
    pub n_samples: usize,
    pub n_channels: usize,
    /// Modes found by the estimate (before `max_modes`).
    pub n_estimated: usize,
    /// Every refined mode, by frequency.
    pub modes: Vec<MeasuredMode>,
    /// The spectral peaks formed by the modes that passed the mode thresholds, by frequency.
    pub peaks: Vec<FittedPeak>,
    /// d(f₀) through the kept peaks.
    pub curve: DampingCurve,
    /// The smoothness s of the curve fit (chosen by GCV unless given).
    pub curve_smoothness: f64,
    /// √(Σ w r² / Σ w) of ln d about the curve over the kept peaks (weights w without the
    /// robust factor).
    pub curve_rms_log_error: f64,
    pub rayleigh: RayleighFit,
    /// L of the estimated modes alone (no noise) and L at the returned parameters.
    pub loss_initial: f64,
    pub loss_final: f64,
    /// The step whose parameters are returned.
    pub best_step: usize,
    pub history: Vec<DampingStep>,
    pub noise: NoiseFit,
    /// Wall-clock seconds of the estimate and the refinement, and per refinement step.
    pub estimate_seconds: f64,
    pub refine_seconds: f64,
    pub seconds_per_step: f64,
}

impl DampingFit {
    /// The kept modes.
    pub fn kept(&self) -> impl Iterator<Item = &MeasuredMode> {
        self.modes.iter().filter(|m| m.kept())
    }

    /// The kept peaks.
    pub fn kept_peaks(&self) -> impl Iterator<Item = &FittedPeak> {
        self.peaks.iter().filter(|p| p.kept)
    }

    /// Channel `c` of the fitted modes as a bank for [`crate::audio::synth::render`].
    ///
    /// # Panics
    /// If `c` is not a channel of the fit.
    pub fn bank(&self, c: usize) -> ModalBank {
        ModalBank {
            frequencies_hz: self.modes.iter().map(|m| m.frequency_hz).collect(),
            decay_rates: self.modes.iter().map(|m| m.decay_rate).collect(),
            amplitudes: self.modes.iter().map(|m| m.amplitudes[c]).collect(),
            phases: self.modes.iter().map(|m| m.phases[c]).collect(),
        }
    }
}

/// Why a damping fit failed.
#[derive(thiserror::Error, Debug, Clone, PartialEq)]
pub enum DampingError {
    #[error("no channels given")]
    NoChannels,
    #[error("channel 0 is empty")]
    EmptyChannels,
    #[error("sample rate {sample_rate} Hz is not a positive finite number")]
    InvalidSampleRate { sample_rate: f64 },
    #[error("channel {channel} has {len} samples, channel 0 has {expected}: channels must be one strike recorded in parallel")]
    LengthMismatch {
        channel: usize,
        len: usize,
        expected: usize,
    },
    #[error("channel {channel}, sample {index} is {value}; the fit needs finite samples")]
    NonFiniteSample {
        channel: usize,
        index: usize,
        value: f64,
    },
    #[error("damping setting {name} = {value} is invalid: {reason}")]
    InvalidSetting {
        name: &'static str,
        value: f64,
        reason: &'static str,
    },
    #[error(
        "skipping {skip} of {samples} samples for the estimate leaves nothing to estimate from"
    )]
    SkipTooLong { skip: usize, samples: usize },
    #[error("mode estimate: {0}")]
    Estimate(#[from] EstimateError),
    #[error("spectral loss: {0}")]
    Loss(#[from] LossError),
    #[error("filtered noise: {0}")]
    Noise(#[from] NoiseError),
    #[error("the estimate found no modes in the recording")]
    NoModes,
    #[error("none of the {refined} refined modes passed the thresholds (decay, SNR, level): no damping curve")]
    NoKeptModes { refined: usize },
    #[error("the loss is not finite at step {step}")]
    NonFiniteLoss { step: usize },
    #[error("{what}: {reason}")]
    InvalidData { what: &'static str, reason: String },
    #[error("the damping-curve least-squares system is singular")]
    SingularCurve,
}

/// Fits modes and noise to a strike recorded on `channels` (equal lengths, starting at the
/// onset) at `sample_rate` Hz, and from the real modes the damping curve and Rayleigh damping;
/// see the module docs. `on_step` sees every refinement step (progress display).
pub fn fit_damping<S: AsRef<[f64]>>(
    channels: &[S],
    sample_rate: f64,
    settings: &DampingFitSettings,
    mut on_step: impl FnMut(&DampingStep),
) -> Result<DampingFit, DampingError> {
    let signals: Vec<&[f64]> = channels.iter().map(|c| c.as_ref()).collect();
    let full_len = check_channels(&signals, sample_rate)?;
    check_settings(settings)?;
    let n = match settings.duration_s {
        Some(d) => ((d * sample_rate).round() as usize).clamp(1, full_len),
        None => full_len,
    };
    let signals: Vec<&[f64]> = signals.iter().map(|s| &s[..n]).collect();
    let n_channels = signals.len();

    // 2. Estimate after the skip, shifted back to the onset.
    let started = Instant::now();
    let skip = (settings.estimate_skip_s * sample_rate).round() as usize;
    if skip >= n {
        return Err(DampingError::SkipTooLong { skip, samples: n });
    }
    let tails: Vec<&[f64]> = signals.iter().map(|s| &s[skip..]).collect();
    let estimate = estimate_modes(&tails, sample_rate, &settings.estimate)?;
    let n_estimated = estimate.modes.len();
    let mut chosen = estimate.strongest(settings.max_modes);
    if chosen.is_empty() {
        return Err(DampingError::NoModes);
    }
    chosen.sort_by(|a, b| a.frequency_hz.total_cmp(&b.frequency_hz));
    let t0 = skip as f64 / sample_rate;
    let start: Vec<MeasuredMode> = chosen
        .iter()
        .map(|m| {
            // f·n₀/f_s modulo one cycle, so the phase shift is exact for long skips too.
            let cycles = m.frequency_hz * skip as f64 / sample_rate;
            let shift = 2.0 * PI * (cycles - cycles.round());
            let growth = (m.decay_rate * t0).exp();
            MeasuredMode {
                amplitudes: m.amplitudes.iter().map(|a| a * growth).collect(),
                phases: m.phases.iter().map(|p| wrap_phase(p - shift)).collect(),
                snr_db: m.snr_db,
                ..MeasuredMode::pole(m.frequency_hz, m.decay_rate)
            }
        })
        .collect();
    let estimate_seconds = started.elapsed().as_secs_f64();

    // 3. Refinement.
    let problem = Problem::new(&signals, sample_rate, &start, settings)?;
    let params = problem.initial_parameters(&signals, &start, settings)?;
    let loss_initial = problem.modes_only_loss(&params)?;
    let refined = problem.refine(&signals, &start, params, settings, &mut on_step)?;
    let (loss_final, best_step, params) = (refined.loss, refined.best_step, refined.params);

    // 4. Verdicts.
    let mut modes = problem.modes(&params, &start);
    classify(&mut modes, settings);

    // 5. Spectral peaks: the modes that passed, grouped where their lines overlap.
    let mut peaks = group_peaks(&mut modes, settings, n as f64 / sample_rate)?;

    // 6. Curve through the peaks; peaks far off it are rejected and the curve refitted.
    let sigma2 = settings.decay_scatter * settings.decay_scatter;
    let (curve, curve_smoothness, f0, d, w) = loop {
        let kept: Vec<usize> = (0..peaks.len()).filter(|&p| peaks[p].kept).collect();
        if kept.is_empty() {
            return Err(DampingError::NoKeptModes {
                refined: modes.len(),
            });
        }
        let f0: Vec<f64> = kept
            .iter()
            .map(|&p| peaks[p].undamped_frequency_hz)
            .collect();
        let d: Vec<f64> = kept.iter().map(|&p| peaks[p].decay_rate).collect();
        let w: Vec<f64> = kept
            .iter()
            .map(|&p| 1.0 / (4.0 * 10f64.powf(-peaks[p].snr_db / 10.0) + sigma2))
            .collect();
        let (curve, robust, smoothness) = robust_curve(&f0, &d, &w, &settings.curve)?;
        // The worst peak beyond the limit goes, one per pass: each refit may bring others back.
        let worst = (0..kept.len())
            .map(|i| (i, (d[i] / curve.decay(f0[i])).ln().abs()))
            .filter(|&(_, r)| r > settings.max_curve_ratio.ln())
            .max_by(|a, b| a.1.total_cmp(&b.1));
        match worst {
            Some((i, _)) => {
                let p = kept[i];
                peaks[p].kept = false;
                peaks[p].reason = ModeVerdict::OffCurve;
            }
            None => {
                for (i, &p) in kept.iter().enumerate() {
                    peaks[p].curve_weight = robust[i];
                }
                break (curve, smoothness, f0, d, w);
            }
        }
    };
    for m in modes.iter_mut() {
        let v = m.verdict_mut();
        if let Some(p) = v.peak {
            v.kept = peaks[p].kept;
            v.reason = peaks[p].reason;
        }
    }
    let curve_rms_log_error = weighted_rms(
        &f0.iter()
            .zip(&d)
            .map(|(&f, &d)| d.ln() - curve.decay(f).ln())
            .collect::<Vec<_>>(),
        &w,
    );
    let rayleigh = fit_rayleigh(&f0, &d, &w)?;

    Ok(DampingFit {
        sample_rate,
        n_samples: n,
        n_channels,
        n_estimated,
        modes,
        peaks,
        curve,
        curve_smoothness,
        curve_rms_log_error,
        rayleigh,
        loss_initial,
        loss_final,
        best_step,
        seconds_per_step: refined.seconds / refined.history.len() as f64,
        history: refined.history,
        noise: problem.noise_fit(&params, settings),
        estimate_seconds,
        refine_seconds: refined.seconds,
    })
}

/// What [`Problem::refine`] returns.
struct Refined {
    loss: f64,
    best_step: usize,
    params: Vec<f64>,
    history: Vec<DampingStep>,
    seconds: f64,
}

/// The refinement: losses, noise synthesisers and the parameter layout
/// [f_k | ln d_k | ln a_{kc} (c-major) | φ_{kc} (c-major) | ln H_c (c-major)].
struct Problem {
    sample_rate: f64,
    n_samples: usize,
    n_modes: usize,
    losses: Vec<MultiScaleSpectralLoss>,
    noises: Vec<FilteredNoise>,
}

impl Problem {
    fn new(
        signals: &[&[f64]],
        sample_rate: f64,
        start: &[MeasuredMode],
        settings: &DampingFitSettings,
    ) -> Result<Problem, DampingError> {
        let n_samples = signals[0].len();
        let losses = signals
            .iter()
            .map(|s| MultiScaleSpectralLoss::new(s, settings.loss.clone()))
            .collect::<Result<_, _>>()?;
        let noises = (0..signals.len())
            .map(|c| {
                FilteredNoise::new(
                    n_samples,
                    sample_rate,
                    settings.noise_bands,
                    settings.noise_hop,
                    settings.noise_seed.wrapping_add(c as u64),
                )
            })
            .collect::<Result<_, _>>()?;
        Ok(Problem {
            sample_rate,
            n_samples,
            n_modes: start.len(),
            losses,
            noises,
        })
    }

    fn n_channels(&self) -> usize {
        self.losses.len()
    }

    fn amplitude_offset(&self, c: usize) -> usize {
        2 * self.n_modes + c * self.n_modes
    }

    fn phase_offset(&self, c: usize) -> usize {
        2 * self.n_modes + (self.n_channels() + c) * self.n_modes
    }

    fn noise_offset(&self, c: usize) -> usize {
        2 * self.n_modes * (1 + self.n_channels()) + c * self.noises[0].n_magnitudes()
    }

    fn n_parameters(&self) -> usize {
        self.noise_offset(self.n_channels())
    }

    fn bank(&self, params: &[f64], c: usize) -> ModalBank {
        let k = self.n_modes;
        let (a, p) = (self.amplitude_offset(c), self.phase_offset(c));
        ModalBank {
            frequencies_hz: params[..k].to_vec(),
            decay_rates: params[k..2 * k].iter().map(|v| v.exp()).collect(),
            amplitudes: params[a..a + k].iter().map(|v| v.exp()).collect(),
            phases: params[p..p + k].to_vec(),
        }
    }

    fn noise_magnitudes(&self, params: &[f64], c: usize) -> Vec<f64> {
        let o = self.noise_offset(c);
        params[o..o + self.noises[c].n_magnitudes()]
            .iter()
            .map(|v| v.exp())
            .collect()
    }

    /// The estimate's modes, and noise from the residual's envelope.
    fn initial_parameters(
        &self,
        signals: &[&[f64]],
        start: &[MeasuredMode],
        settings: &DampingFitSettings,
    ) -> Result<Vec<f64>, DampingError> {
        let mut params = vec![0.0; self.n_parameters()];
        let k = self.n_modes;
        for (i, m) in start.iter().enumerate() {
            params[i] = m.frequency_hz;
            params[k + i] = m.decay_rate.max(MIN_START_DECAY).ln();
            for c in 0..self.n_channels() {
                // A zero amplitude has no logarithm; 10⁻³⁰⁰ is silent for any signal.
                params[self.amplitude_offset(c) + i] = m.amplitudes[c].max(1e-300).ln();
                params[self.phase_offset(c) + i] = m.phases[c];
            }
        }
        let gain = 10f64.powf(settings.noise_init_db / 20.0);
        for (c, signal) in signals.iter().enumerate() {
            let model = render_samples(&self.bank(&params, c), self.sample_rate, self.n_samples);
            let residual: Vec<f64> = signal.iter().zip(&model).map(|(s, m)| s - m).collect();
            let envelope = residual_envelope(&self.noises[c], &residual, gain);
            let (lo, hi) = noise_bounds(signal);
            let o = self.noise_offset(c);
            for (p, h) in params[o..o + envelope.len()].iter_mut().zip(&envelope) {
                *p = h.max(lo).min(hi).ln();
            }
        }
        Ok(params)
    }

    fn step_sizes(&self, s: &DampingFitSettings) -> Vec<f64> {
        let k = self.n_modes;
        let c = self.n_channels();
        let mut steps = Vec::with_capacity(self.n_parameters());
        steps.extend(std::iter::repeat_n(s.step_frequency_hz, k));
        steps.extend(std::iter::repeat_n(s.step_log_decay, k));
        steps.extend(std::iter::repeat_n(s.step_log_amplitude, k * c));
        steps.extend(std::iter::repeat_n(s.step_phase, k * c));
        steps.extend(std::iter::repeat_n(
            s.step_log_noise,
            self.n_parameters() - steps.len(),
        ));
        steps
    }

    fn bounds(
        &self,
        start: &[MeasuredMode],
        signals: &[&[f64]],
        s: &DampingFitSettings,
    ) -> (Vec<f64>, Vec<f64>) {
        let n = self.n_parameters();
        let k = self.n_modes;
        let mut lower = vec![f64::NEG_INFINITY; n];
        let mut upper = vec![f64::INFINITY; n];
        // Strictly inside (0, Nyquist), where the synthesiser renders a mode.
        let nyquist = 0.5 * self.sample_rate;
        let margin = 1e-6 * nyquist;
        for (i, m) in start.iter().enumerate() {
            lower[i] = (m.frequency_hz - s.max_frequency_shift_hz)
                .max(margin)
                .min(m.frequency_hz);
            upper[i] = (m.frequency_hz + s.max_frequency_shift_hz)
                .min(nyquist - margin)
                .max(m.frequency_hz);
            lower[k + i] = DECAY_BOUNDS.0.ln();
            upper[k + i] = DECAY_BOUNDS.1.ln();
        }
        for (c, signal) in signals.iter().enumerate() {
            let (lo, hi) = noise_bounds(signal);
            let o = self.noise_offset(c);
            for i in o..o + self.noises[c].n_magnitudes() {
                lower[i] = lo.ln();
                upper[i] = hi.ln();
            }
        }
        (lower, upper)
    }

    /// L of the modes without noise.
    fn modes_only_loss(&self, params: &[f64]) -> Result<f64, DampingError> {
        let mut total = 0.0;
        for c in 0..self.n_channels() {
            let x = render_samples(&self.bank(params, c), self.sample_rate, self.n_samples);
            total += self.losses[c].value(&x)?;
        }
        Ok(total)
    }

    /// Adam from `params` for `settings.steps` steps; keeps the parameters of the lowest loss.
    fn refine(
        &self,
        signals: &[&[f64]],
        start: &[MeasuredMode],
        mut params: Vec<f64>,
        settings: &DampingFitSettings,
        on_step: &mut impl FnMut(&DampingStep),
    ) -> Result<Refined, DampingError> {
        let (lower, upper) = self.bounds(start, signals, settings);
        let mut adam = Adam::new(self.step_sizes(settings)).with_bounds(lower, upper);
        let decay_per_step = if settings.steps > 0 {
            settings
                .final_step_fraction
                .powf(1.0 / settings.steps as f64)
        } else {
            1.0
        };
        let started = Instant::now();
        let mut grad = vec![0.0; params.len()];
        let mut best = (f64::INFINITY, 0, params.clone());
        let mut history = Vec::with_capacity(settings.steps + 1);
        for step in 0..=settings.steps {
            // The last pass only evaluates the final parameters.
            let loss = self.loss_and_gradient(&params, &mut grad)?;
            if !loss.is_finite() {
                return Err(DampingError::NonFiniteLoss { step });
            }
            if loss < best.0 {
                best = (loss, step, params.clone());
            }
            let record = DampingStep {
                step,
                loss,
                elapsed_s: started.elapsed().as_secs_f64(),
            };
            on_step(&record);
            history.push(record);
            if step < settings.steps {
                adam.step(&mut params, &grad);
                adam.scale_steps(decay_per_step);
            }
        }
        let (loss, best_step, params) = best;
        Ok(Refined {
            loss,
            best_step,
            params,
            history,
            seconds: started.elapsed().as_secs_f64(),
        })
    }

    /// L and dL/d(params) (written into `grad`).
    fn loss_and_gradient(&self, params: &[f64], grad: &mut [f64]) -> Result<f64, DampingError> {
        grad.iter_mut().for_each(|g| *g = 0.0);
        let k = self.n_modes;
        let mut total = 0.0;
        for c in 0..self.n_channels() {
            let bank = self.bank(params, c);
            let magnitudes = self.noise_magnitudes(params, c);
            let mut x = render_samples(&bank, self.sample_rate, self.n_samples);
            self.noises[c].render_add_into(&magnitudes, &mut x)?;
            let (value, g) = self.losses[c].value_and_gradient(&x)?;
            total += value;
            let gb = render_backward(&bank, self.sample_rate, &g);
            let (a_off, p_off) = (self.amplitude_offset(c), self.phase_offset(c));
            for i in 0..k {
                grad[i] += gb.frequencies_hz[i];
                // d/d ln v = v d/dv.
                grad[k + i] += gb.decay_rates[i] * bank.decay_rates[i];
                grad[a_off + i] = gb.amplitudes[i] * bank.amplitudes[i];
                grad[p_off + i] = gb.phases[i];
            }
            let o = self.noise_offset(c);
            let g_noise = &mut grad[o..o + magnitudes.len()];
            self.noises[c].backward(&g, g_noise)?;
            g_noise
                .iter_mut()
                .zip(&magnitudes)
                .for_each(|(g, h)| *g *= h);
        }
        Ok(total)
    }

    /// The modes at `params`, verdicts not yet given.
    fn modes(&self, params: &[f64], start: &[MeasuredMode]) -> Vec<MeasuredMode> {
        let k = self.n_modes;
        let banks: Vec<ModalBank> = (0..self.n_channels())
            .map(|c| self.bank(params, c))
            .collect();
        (0..k)
            .map(|i| {
                let f = params[i];
                let d = params[k + i].exp();
                MeasuredMode {
                    amplitudes: banks.iter().map(|b| b.amplitudes[i]).collect(),
                    phases: banks.iter().map(|b| wrap_phase(b.phases[i])).collect(),
                    snr_db: start[i].snr_db,
                    refined_from: Some(RefinedFrom {
                        frequency_hz: start[i].frequency_hz,
                        decay_rate: start[i].decay_rate,
                    }),
                    verdict: Some(Verdict {
                        level_db: f64::NEG_INFINITY,
                        kept: false,
                        reason: ModeVerdict::Weak,
                        peak: None,
                    }),
                    ..MeasuredMode::pole(f, d)
                }
            })
            .collect()
    }

    fn noise_fit(&self, params: &[f64], s: &DampingFitSettings) -> NoiseFit {
        NoiseFit {
            n_bands: s.noise_bands,
            hop: s.noise_hop,
            seed: s.noise_seed,
            band_frequencies_hz: self.noises[0].band_frequencies_hz(),
            frame_times_s: self.noises[0].frame_times_s(),
            magnitudes: (0..self.n_channels())
                .map(|c| self.noise_magnitudes(params, c))
                .collect(),
        }
    }
}

/// Bounds of the noise gains of one channel (see [`NOISE_BOUNDS`]).
fn noise_bounds(signal: &[f64]) -> (f64, f64) {
    let peak = signal.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    // A silent channel still needs a positive range for ln H.
    let scale = 3f64.sqrt() * if peak > 0.0 { peak } else { 1.0 };
    (NOISE_BOUNDS.0 * scale, NOISE_BOUNDS.1 * scale)
}

/// Noise gains from the residual, frame by frame (module docs): the Hann periodogram of the
/// S = max(hop, L) samples centred on frame m's block (zero outside the record, the window's
/// energy counted over the samples inside), averaged over the bins within one band spacing of
/// each band. White noise of variance σ² gives E|X_k|² = σ² Σ w², and a flat gain h gives
/// σ² = h²/3.
fn residual_envelope(noise: &FilteredNoise, residual: &[f64], gain: f64) -> Vec<f64> {
    let (hop, bands) = (noise.hop(), noise.n_bands());
    let span = hop.max(noise.filter_len());
    let n_fft = span.next_power_of_two().max(4);
    let fft = rustfft::FftPlanner::new().plan_fft_forward(n_fft);
    let window: Vec<f64> = (0..span)
        .map(|j| (PI * (j as f64 + 0.5) / span as f64).sin().powi(2))
        .collect();
    let fs = noise.sample_rate();
    let band_spacing = fs / noise.filter_len() as f64;
    let bin_hz = fs / n_fft as f64;
    // Bins averaged for each band: within one band spacing of its centre.
    let ranges: Vec<(usize, usize)> = noise
        .band_frequencies_hz()
        .iter()
        .map(|&f| {
            let lo = ((f - band_spacing) / bin_hz).ceil().max(0.0) as usize;
            let hi = (((f + band_spacing) / bin_hz).floor() as usize).min(n_fft / 2);
            (lo.min(hi), hi)
        })
        .collect();
    let mut buffer = vec![rustfft::num_complex::Complex64::new(0.0, 0.0); n_fft];
    let mut envelope = Vec::with_capacity(noise.n_magnitudes());
    for m in 0..noise.n_frames() {
        // First sample of the span: the block's centre minus half the span (may be < 0).
        let first = (m * hop) as isize + (hop / 2) as isize - (span / 2) as isize;
        let mut energy = 0.0;
        buffer.iter_mut().for_each(|b| *b = 0.0.into());
        for (j, w) in window.iter().enumerate() {
            let i = first + j as isize;
            if i >= 0 && (i as usize) < residual.len() {
                buffer[j].re = w * residual[i as usize];
                energy += w * w;
            }
        }
        fft.process(&mut buffer);
        for &(lo, hi) in ranges.iter().take(bands) {
            let power = if energy > 0.0 {
                (lo..=hi).map(|k| buffer[k].norm_sqr()).sum::<f64>()
                    / ((hi - lo + 1) as f64 * energy)
            } else {
                0.0
            };
            envelope.push(gain * (3.0 * power).sqrt());
        }
    }
    envelope
}

/// Groups the modes that passed the mode thresholds into peaks (sorted by frequency; single
/// linkage of neighbours, module docs) and gives each peak its frequency, decay and level.
/// `duration_s` is the record length T.
fn group_peaks(
    modes: &mut [MeasuredMode],
    s: &DampingFitSettings,
    duration_s: f64,
) -> Result<Vec<FittedPeak>, DampingError> {
    let passed: Vec<usize> = (0..modes.len()).filter(|&k| modes[k].kept()).collect();
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for &k in &passed {
        let joins = groups.last().and_then(|g| g.last()).is_some_and(|&j| {
            let (a, b) = (&modes[j], &modes[k]);
            let gap = (b.frequency_hz - a.frequency_hz).abs();
            gap <= s.peak_width * (a.decay_rate + b.decay_rate) / (2.0 * PI)
                || gap <= 2.0 / duration_s
        });
        match groups.last_mut() {
            Some(g) if joins => g.push(k),
            _ => groups.push(vec![k]),
        }
    }
    let mut peaks = Vec::with_capacity(groups.len());
    for (index, members) in groups.into_iter().enumerate() {
        let poles: Vec<(f64, f64)> = members
            .iter()
            .map(|&k| (modes[k].decay_rate, 2.0 * PI * modes[k].frequency_hz))
            .collect();
        let amplitudes: Vec<Vec<Complex64>> = members
            .iter()
            .map(|&k| {
                modes[k]
                    .amplitudes
                    .iter()
                    .zip(&modes[k].phases)
                    .map(|(&a, &p)| Complex64::from_polar(a, p))
                    .collect()
            })
            .collect();
        let edc = EnergyDecay::new(&poles, &amplitudes);
        let decay_rate = edc
            .decay_rate(s.decay_range_db)
            .ok_or(DampingError::InvalidData {
                what: "peak energy-decay curve",
                reason: format!(
                    "no decay found for the peak near {:.1} Hz",
                    modes[members[0]].frequency_hz
                ),
            })?;
        // Energy of each member alone, Σ_c a²/(2·2d) (the complex envelope's), for the mean f.
        let energy: Vec<f64> = members
            .iter()
            .map(|&k| {
                modes[k].amplitudes.iter().map(|a| a * a).sum::<f64>() / (2.0 * modes[k].decay_rate)
            })
            .collect();
        let total: f64 = energy.iter().sum();
        let frequency_hz = members
            .iter()
            .zip(&energy)
            .map(|(&k, e)| modes[k].frequency_hz * e)
            .sum::<f64>()
            / total;
        let snr = members
            .iter()
            .map(|&k| 10f64.powf(modes[k].snr() / 10.0))
            .sum::<f64>();
        for &k in &members {
            modes[k].verdict_mut().peak = Some(index);
        }
        peaks.push(FittedPeak {
            frequency_hz,
            undamped_frequency_hz: frequency_hz.hypot(decay_rate / (2.0 * PI)),
            decay_rate,
            level_db: edc.at(0.0),
            snr_db: 10.0 * snr.log10(),
            members,
            kept: true,
            reason: ModeVerdict::Kept,
            curve_weight: 0.0,
        });
    }
    let loudest = peaks.iter().map(|p| p.level_db).fold(0.0_f64, f64::max);
    for p in peaks.iter_mut() {
        p.level_db = 10.0 * (p.level_db / loudest).log10();
    }
    Ok(peaks)
}

/// The energy-decay curve of a sum of damped complex exponentials over channels,
/// E(t) = Σ_c ∫_t^∞ |Σ_k C_kc e^(s_k τ)|² dτ = Re Σ_jk G_jk e^((s_j + s̄_k) t) / −(s_j + s̄_k),
/// with s_k = −d_k + iω_k and G_jk = Σ_c C_jc C̄_kc. For one mode E ∝ e^(−2dt) exactly.
struct EnergyDecay {
    /// (G_jk / −(s_j + s̄_k), s_j + s̄_k) for every pair.
    terms: Vec<(Complex64, Complex64)>,
    slowest: f64,
}

impl EnergyDecay {
    /// `poles` (d_k, ω_k), `amplitudes[k][c]` = C_kc.
    fn new(poles: &[(f64, f64)], amplitudes: &[Vec<Complex64>]) -> EnergyDecay {
        let mut terms = Vec::with_capacity(poles.len() * poles.len());
        for (j, &(dj, wj)) in poles.iter().enumerate() {
            for (k, &(dk, wk)) in poles.iter().enumerate() {
                let g: Complex64 = amplitudes[j]
                    .iter()
                    .zip(&amplitudes[k])
                    .map(|(a, b)| a * b.conj())
                    .sum();
                let rate = Complex64::new(-(dj + dk), wj - wk);
                terms.push((-g / rate, rate));
            }
        }
        let slowest = poles.iter().map(|p| p.0).fold(f64::INFINITY, f64::min);
        EnergyDecay { terms, slowest }
    }

    /// E(t).
    fn at(&self, t: f64) -> f64 {
        self.terms
            .iter()
            .map(|(c, r)| (c * (r * t).exp()).re)
            .sum::<f64>()
            .max(0.0)
    }

    /// The t at which E has fallen `db` below E(0) (E decreases monotonically: its derivative
    /// is minus a squared magnitude).
    fn time_at(&self, db: f64) -> Option<f64> {
        let target = self.at(0.0) * 10f64.powf(-db / 10.0);
        if !(target > 0.0) {
            return None;
        }
        // The slowest mode sets how long the curve can last: 10 dB per 1.15/d.
        let mut hi = 1.0 / self.slowest;
        while self.at(hi) > target {
            hi *= 2.0;
            if !hi.is_finite() || hi > 1e6 {
                return None;
            }
        }
        let mut lo = 0.0;
        for _ in 0..100 {
            let mid = 0.5 * (lo + hi);
            if self.at(mid) > target {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        Some(0.5 * (lo + hi))
    }

    /// d from the least-squares slope of ln E(t) = const − 2 d t between the times where E is
    /// range[0] and range[1] dB below its start.
    fn decay_rate(&self, range_db: [f64; 2]) -> Option<f64> {
        let (t0, t1) = (self.time_at(range_db[0])?, self.time_at(range_db[1])?);
        if !(t1 > t0) {
            return None;
        }
        const POINTS: usize = 33;
        let samples: Vec<(f64, f64)> = (0..POINTS)
            .map(|i| {
                let t = t0 + (t1 - t0) * i as f64 / (POINTS - 1) as f64;
                (t, self.at(t).ln())
            })
            .collect();
        let mean_t = samples.iter().map(|p| p.0).sum::<f64>() / POINTS as f64;
        let mean_y = samples.iter().map(|p| p.1).sum::<f64>() / POINTS as f64;
        let sxy: f64 = samples
            .iter()
            .map(|(t, y)| (t - mean_t) * (y - mean_y))
            .sum();
        let sxx: f64 = samples.iter().map(|(t, _)| (t - mean_t).powi(2)).sum();
        let d = -0.5 * sxy / sxx;
        (d > 0.0 && d.is_finite()).then_some(d)
    }
}

/// Gives every mode its level and verdict (module docs).
fn classify(modes: &mut [MeasuredMode], s: &DampingFitSettings) {
    let power = |m: &MeasuredMode| m.amplitudes.iter().map(|a| a * a).sum::<f64>();
    let decay_ok =
        |m: &MeasuredMode| m.decay_rate > s.min_decay_rate && m.decay_rate <= s.max_decay_rate;
    let reference = modes
        .iter()
        .filter(|m| decay_ok(m))
        .map(power)
        .fold(0.0_f64, f64::max);
    for m in modes.iter_mut() {
        let level_db = if reference > 0.0 {
            10.0 * (power(m) / reference).log10()
        } else {
            f64::NEG_INFINITY
        };
        let reason = if m.decay_rate <= s.min_decay_rate {
            ModeVerdict::DecayTooSlow
        } else if m.decay_rate > s.max_decay_rate {
            ModeVerdict::DecayTooFast
        } else if !(m.snr() >= s.min_snr_db) {
            ModeVerdict::LowSnr
        } else if !(level_db >= s.min_level_db) {
            ModeVerdict::Weak
        } else {
            ModeVerdict::Kept
        };
        let v = m.verdict_mut();
        v.level_db = level_db;
        v.reason = reason;
        v.kept = reason == ModeVerdict::Kept;
    }
}

fn wrap_phase(p: f64) -> f64 {
    let w = p - 2.0 * PI * (p / (2.0 * PI)).round();
    // round() sends exactly −π to −π; the convention is (−π, π].
    if w <= -PI {
        w + 2.0 * PI
    } else {
        w
    }
}

fn weighted_rms(residuals: &[f64], weights: &[f64]) -> f64 {
    let total: f64 = weights.iter().sum();
    (residuals
        .iter()
        .zip(weights)
        .map(|(r, w)| w * r * r)
        .sum::<f64>()
        / total)
        .sqrt()
}

fn check_channels(signals: &[&[f64]], sample_rate: f64) -> Result<usize, DampingError> {
    if !(sample_rate > 0.0 && sample_rate.is_finite()) {
        return Err(DampingError::InvalidSampleRate { sample_rate });
    }
    // An empty channel 0 is reported as such before a longer channel 1 is called a mismatch.
    if signals.first().is_some_and(|s| s.is_empty()) {
        return Err(DampingError::EmptyChannels);
    }
    Ok(crate::audio::check_parallel_channels(signals)?)
}

impl From<crate::audio::ChannelFault> for DampingError {
    fn from(fault: crate::audio::ChannelFault) -> Self {
        use crate::audio::ChannelFault as F;
        match fault {
            F::NoChannels => DampingError::NoChannels,
            F::LengthMismatch {
                channel,
                len,
                expected,
            } => DampingError::LengthMismatch {
                channel,
                len,
                expected,
            },
            F::NonFiniteSample {
                channel,
                index,
                value,
            } => DampingError::NonFiniteSample {
                channel,
                index,
                value,
            },
        }
    }
}

fn check_settings(s: &DampingFitSettings) -> Result<(), DampingError> {
    let invalid = |name, value: f64, reason| {
        Err(DampingError::InvalidSetting {
            name,
            value,
            reason,
        })
    };
    let non_negative = |v: f64| v >= 0.0 && v.is_finite();
    let positive = |v: f64| v > 0.0 && v.is_finite();
    if !non_negative(s.estimate_skip_s) {
        return invalid(
            "estimate_skip_s",
            s.estimate_skip_s,
            "must be a finite number ≥ 0",
        );
    }
    if let Some(d) = s.duration_s {
        if !positive(d) {
            return invalid("duration_s", d, "must be a positive finite number");
        }
    }
    if s.max_modes == 0 {
        return invalid("max_modes", 0.0, "must be at least 1");
    }
    for (name, v) in [
        ("step_frequency_hz", s.step_frequency_hz),
        ("step_log_decay", s.step_log_decay),
        ("step_log_amplitude", s.step_log_amplitude),
        ("step_phase", s.step_phase),
        ("step_log_noise", s.step_log_noise),
        ("max_frequency_shift_hz", s.max_frequency_shift_hz),
    ] {
        if !non_negative(v) {
            return invalid(name, v, "must be a finite number ≥ 0");
        }
    }
    if !(s.final_step_fraction > 0.0 && s.final_step_fraction <= 1.0) {
        return invalid(
            "final_step_fraction",
            s.final_step_fraction,
            "must lie in (0, 1]",
        );
    }
    if s.noise_bands < 2 {
        return invalid("noise_bands", s.noise_bands as f64, "must be at least 2");
    }
    if s.noise_hop == 0 {
        return invalid("noise_hop", 0.0, "must be at least 1");
    }
    if !s.noise_init_db.is_finite() {
        return invalid("noise_init_db", s.noise_init_db, "must be finite");
    }
    if !(s.min_decay_rate >= 0.0 && s.min_decay_rate.is_finite()) {
        return invalid(
            "min_decay_rate",
            s.min_decay_rate,
            "must be a finite number ≥ 0 (ln d of kept modes)",
        );
    }
    if !(s.max_decay_rate > s.min_decay_rate) {
        return invalid(
            "max_decay_rate",
            s.max_decay_rate,
            "must exceed min_decay_rate",
        );
    }
    if s.min_snr_db.is_nan() {
        return invalid("min_snr_db", s.min_snr_db, "must be a number");
    }
    if s.min_level_db.is_nan() {
        return invalid("min_level_db", s.min_level_db, "must be a number");
    }
    if !(s.max_curve_ratio > 1.0) {
        return invalid(
            "max_curve_ratio",
            s.max_curve_ratio,
            "must exceed 1 (infinity: no test)",
        );
    }
    if !(s.peak_width >= 0.0 && s.peak_width.is_finite()) {
        return invalid("peak_width", s.peak_width, "must be a finite number ≥ 0");
    }
    let [early, late] = s.decay_range_db;
    if !(early >= 0.0 && late > early && late.is_finite()) {
        return invalid(
            "decay_range_db",
            late,
            "needs 0 ≤ start < end, finite (dB below the start)",
        );
    }
    if !positive(s.decay_scatter) {
        return invalid(
            "decay_scatter",
            s.decay_scatter,
            "must be a positive finite number",
        );
    }
    check_curve_settings(&s.curve)
}

fn check_curve_settings(s: &CurveFitSettings) -> Result<(), DampingError> {
    let invalid = |name, value: f64, reason| {
        Err(DampingError::InvalidSetting {
            name,
            value,
            reason,
        })
    };
    let positive = |v: f64| v > 0.0 && v.is_finite();
    if !positive(s.knots_per_octave) {
        return invalid(
            "curve.knots_per_octave",
            s.knots_per_octave,
            "must be a positive finite number",
        );
    }
    if !positive(s.modes_per_knot) {
        return invalid(
            "curve.modes_per_knot",
            s.modes_per_knot,
            "must be a positive finite number",
        );
    }
    if let Some(v) = s.smoothness {
        if !(v >= 0.0 && v.is_finite()) {
            return invalid("curve.smoothness", v, "must be a finite number ≥ 0");
        }
    }
    if !positive(s.huber_threshold) {
        return invalid(
            "curve.huber_threshold",
            s.huber_threshold,
            "must be a positive finite number",
        );
    }
    if !positive(s.scale_floor) {
        return invalid(
            "curve.scale_floor",
            s.scale_floor,
            "must be a positive finite number",
        );
    }
    if s.max_iterations == 0 {
        return invalid("curve.max_iterations", 0.0, "must be at least 1");
    }
    Ok(())
}

/// Checks (f, d, w) triples for the curve and Rayleigh fits.
fn check_decay_data(
    what: &'static str,
    f: &[f64],
    d: &[f64],
    w: &[f64],
) -> Result<(), DampingError> {
    let bad = |reason: String| Err(DampingError::InvalidData { what, reason });
    if f.len() != d.len() || f.len() != w.len() {
        return bad(format!(
            "{} frequencies, {} decay rates and {} weights differ in number",
            f.len(),
            d.len(),
            w.len()
        ));
    }
    if f.is_empty() {
        return bad("no modes given".into());
    }
    for i in 0..f.len() {
        if !(f[i] > 0.0 && f[i].is_finite()) {
            return bad(format!(
                "mode {i}: frequency {} Hz must be positive and finite",
                f[i]
            ));
        }
        if !(d[i] > 0.0 && d[i].is_finite()) {
            return bad(format!(
                "mode {i}: decay rate {} 1/s must be positive and finite",
                d[i]
            ));
        }
        if !(w[i] >= 0.0 && w[i].is_finite()) {
            return bad(format!("mode {i}: weight {} must be finite and ≥ 0", w[i]));
        }
    }
    if !(w.iter().sum::<f64>() > 0.0) {
        return bad("all weights are zero".into());
    }
    Ok(())
}

/// The damping curve d(f) through modes at `frequencies_hz` with `decay_rates` (1/s) and
/// non-negative `weights` (relative inverse variances of ln d): knots log-spaced over the modes'
/// range, weighted and Huber-robust least squares of ln d with a second-difference penalty; see
/// the module docs.
pub fn fit_damping_curve(
    frequencies_hz: &[f64],
    decay_rates: &[f64],
    weights: &[f64],
    settings: &CurveFitSettings,
) -> Result<DampingCurve, DampingError> {
    robust_curve(frequencies_hz, decay_rates, weights, settings).map(|(curve, _, _)| curve)
}

/// [`fit_damping_curve`], also returning each mode's final weight w_i u_i and the smoothness
/// used.
fn robust_curve(
    f: &[f64],
    d: &[f64],
    w: &[f64],
    settings: &CurveFitSettings,
) -> Result<(DampingCurve, Vec<f64>, f64), DampingError> {
    check_decay_data("damping curve", f, d, w)?;
    check_curve_settings(settings)?;
    let used: Vec<usize> = (0..f.len()).filter(|&i| w[i] > 0.0).collect();
    let x_lo = used
        .iter()
        .map(|&i| f[i].ln())
        .fold(f64::INFINITY, f64::min);
    let x_hi = used
        .iter()
        .map(|&i| f[i].ln())
        .fold(f64::NEG_INFINITY, f64::max);
    let mut distinct: Vec<f64> = used.iter().map(|&i| f[i].ln()).collect();
    distinct.sort_by(f64::total_cmp);
    distinct.dedup_by(|a, b| (*a - *b).abs() <= 1e-9);
    let n_knots = if distinct.len() < 2 {
        1
    } else {
        let octaves = (x_hi - x_lo) / std::f64::consts::LN_2;
        let by_range = (octaves * settings.knots_per_octave - 1e-9).ceil().max(1.0) as usize + 1;
        let by_count = ((distinct.len() as f64 / settings.modes_per_knot).floor() as usize).max(2);
        by_range.min(by_count)
    };
    let spacing = if n_knots > 1 {
        (x_hi - x_lo) / (n_knots - 1) as f64
    } else {
        0.0
    };
    // Each mode's two hat-function values (knot index, weight).
    let basis: Vec<[(usize, f64); 2]> = f
        .iter()
        .map(|&fi| {
            if n_knots == 1 {
                return [(0, 1.0), (0, 0.0)];
            }
            let s = ((fi.ln() - x_lo) / spacing).clamp(0.0, (n_knots - 1) as f64);
            let j = (s.floor() as usize).min(n_knots - 2);
            let t = s - j as f64;
            [(j, 1.0 - t), (j + 1, t)]
        })
        .collect();
    let y: Vec<f64> = d.iter().map(|v| v.ln()).collect();
    // AᵀWUA and AᵀWUy for robust weights u, and the penalty DᵀD.
    let data_system = |u: &[f64]| -> (DMatrix<f64>, DVector<f64>) {
        let mut normal = DMatrix::<f64>::zeros(n_knots, n_knots);
        let mut rhs = DVector::<f64>::zeros(n_knots);
        for i in 0..f.len() {
            let wi = w[i] * u[i];
            for &(a, ba) in &basis[i] {
                rhs[a] += wi * ba * y[i];
                for &(b, bb) in &basis[i] {
                    normal[(a, b)] += wi * ba * bb;
                }
            }
        }
        (normal, rhs)
    };
    let mut penalty = DMatrix::<f64>::zeros(n_knots, n_knots);
    for j in 1..n_knots.saturating_sub(1) {
        let row = [(j - 1, 1.0), (j, -2.0), (j + 1, 1.0)];
        for &(a, ca) in &row {
            for &(b, cb) in &row {
                penalty[(a, b)] += ca * cb;
            }
        }
    }
    let residuals = |theta: &[f64]| -> Vec<f64> {
        (0..f.len())
            .map(|i| y[i] - basis[i].iter().map(|&(j, b)| b * theta[j]).sum::<f64>())
            .collect()
    };
    // θ for weights u and relative smoothness s (λ = s Σ w u / K), with its GCV score
    // n·RSS/(n − tr H)², tr H = tr((AᵀWUA + λDᵀD)⁻¹ AᵀWUA).
    let solve = |u: &[f64], smoothness: f64| -> Result<(Vec<f64>, f64), DampingError> {
        let (data, rhs) = data_system(u);
        let lambda = smoothness * used.iter().map(|&i| w[i] * u[i]).sum::<f64>() / n_knots as f64;
        let factor = (&data + &penalty * lambda)
            .cholesky()
            .ok_or(DampingError::SingularCurve)?;
        let theta: Vec<f64> = factor.solve(&rhs).iter().copied().collect();
        if !theta.iter().all(|v| v.is_finite()) {
            return Err(DampingError::SingularCurve);
        }
        let trace = factor.solve(&data).trace();
        let r = residuals(&theta);
        let rss: f64 = used.iter().map(|&i| w[i] * u[i] * r[i] * r[i]).sum();
        let n = used.len() as f64;
        let gcv = if n - trace > 1e-9 {
            n * rss / (n - trace).powi(2)
        } else {
            f64::INFINITY
        };
        Ok((theta, gcv))
    };
    // The given smoothness, or the grid value of least GCV (the smallest wins ties, so exact
    // data are fitted exactly). Without second differences (K ≤ 2) there is nothing to choose.
    let choose = |u: &[f64]| -> Result<(Vec<f64>, f64), DampingError> {
        if n_knots <= 2 {
            return Ok((solve(u, 0.0)?.0, 0.0));
        }
        if let Some(s) = settings.smoothness {
            return Ok((solve(u, s)?.0, s));
        }
        let mut best: Option<(Vec<f64>, f64, f64)> = None;
        for e in 0..=SMOOTHNESS_GRID.2 {
            let s = SMOOTHNESS_GRID.0
                * (SMOOTHNESS_GRID.1 / SMOOTHNESS_GRID.0).powf(e as f64 / SMOOTHNESS_GRID.2 as f64);
            let (theta, gcv) = solve(u, s)?;
            if best.as_ref().is_none_or(|b| gcv < b.2) {
                best = Some((theta, s, gcv));
            }
        }
        let (theta, s, _) = best.expect("the grid is not empty");
        Ok((theta, s))
    };
    let mut u = vec![1.0; f.len()];
    let (mut theta, mut smoothness) = choose(&u)?;
    for _ in 0..settings.max_iterations {
        let r = residuals(&theta);
        let mut abs: Vec<f64> = used.iter().map(|&i| r[i].abs()).collect();
        abs.sort_by(f64::total_cmp);
        let median = if abs.len() % 2 == 1 {
            abs[abs.len() / 2]
        } else {
            0.5 * (abs[abs.len() / 2 - 1] + abs[abs.len() / 2])
        };
        let scale = (median / 0.6745).max(settings.scale_floor);
        let cut = settings.huber_threshold * scale;
        let next: Vec<f64> = r
            .iter()
            .map(|ri| if ri.abs() <= cut { 1.0 } else { cut / ri.abs() })
            .collect();
        let change = next
            .iter()
            .zip(&u)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        u = next;
        (theta, smoothness) = choose(&u)?;
        if change < 1e-6 {
            break;
        }
    }
    // The end knots are the extreme modes' frequencies exactly (exp ∘ ln may round).
    let f_lo = used.iter().map(|&i| f[i]).fold(f64::INFINITY, f64::min);
    let f_hi = used.iter().map(|&i| f[i]).fold(f64::NEG_INFINITY, f64::max);
    let knots: Vec<f64> = (0..n_knots)
        .map(|j| match j {
            0 => f_lo,
            j if j + 1 == n_knots => f_hi,
            j => (x_lo + j as f64 * spacing).exp(),
        })
        .collect();
    let curve = DampingCurve {
        frequencies_hz: knots,
        log_decay: theta,
    };
    curve
        .validate()
        .map_err(|reason| DampingError::InvalidData {
            what: "damping curve",
            reason: reason.to_string(),
        })?;
    Ok((
        curve,
        w.iter().zip(&u).map(|(w, u)| w * u).collect(),
        smoothness,
    ))
}

/// Rayleigh damping d = (α + β ω²)/2, ω = 2π f, fitted to decay rates (1/s) at (undamped)
/// frequencies (Hz) with non-negative weights; α, β ≥ 0 minimise the weighted squared error of
/// ln d (module docs).
pub fn fit_rayleigh(
    frequencies_hz: &[f64],
    decay_rates: &[f64],
    weights: &[f64],
) -> Result<RayleighFit, DampingError> {
    check_decay_data("Rayleigh fit", frequencies_hz, decay_rates, weights)?;
    let w = weights;
    let w_sum: f64 = w.iter().sum();
    let omega2: Vec<f64> = frequencies_hz
        .iter()
        .map(|f| (2.0 * PI * f).powi(2))
        .collect();
    let ref2 = omega2.iter().zip(w).map(|(o, w)| o * w).sum::<f64>() / w_sum;
    let q: Vec<f64> = omega2.iter().map(|o| o / ref2).collect();
    // y = ln 2d; model ln(α + b q).
    let y: Vec<f64> = decay_rates.iter().map(|d| (2.0 * d).ln()).collect();
    let objective = |alpha: f64, b: f64| -> f64 {
        (0..y.len())
            .map(|i| w[i] * (y[i] - (alpha + b * q[i]).ln()).powi(2))
            .sum::<f64>()
    };
    let mean = |v: &dyn Fn(usize) -> f64| (0..y.len()).map(|i| w[i] * v(i)).sum::<f64>() / w_sum;
    let mut candidates = vec![
        (mean(&|i| y[i]).exp(), 0.0),
        (0.0, mean(&|i| y[i] - q[i].ln()).exp()),
    ];
    // Linear least squares of the relative error (α + b q)/e − 1, e = 2d.
    let (mut s11, mut s12, mut s22, mut r1, mut r2) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for i in 0..y.len() {
        let e = y[i].exp();
        let (g1, g2) = (1.0 / e, q[i] / e);
        s11 += w[i] * g1 * g1;
        s12 += w[i] * g1 * g2;
        s22 += w[i] * g2 * g2;
        r1 += w[i] * g1;
        r2 += w[i] * g2;
    }
    let det = s11 * s22 - s12 * s12;
    let linear = (det > 1e-12 * s11 * s22)
        .then(|| ((s22 * r1 - s12 * r2) / det, (s11 * r2 - s12 * r1) / det));
    if let Some((alpha, b)) = linear.filter(|&(a, b)| a > 0.0 && b > 0.0) {
        candidates.push(levenberg_marquardt(&y, &q, w, alpha.ln(), b.ln()));
    }
    let (alpha, b) = candidates
        .into_iter()
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .min_by(|p, r| objective(p.0, p.1).total_cmp(&objective(r.0, r.1)))
        .unwrap_or((0.0, 0.0));
    Ok(RayleighFit {
        alpha,
        beta: b / ref2,
        rms_log_error: (objective(alpha, b) / w_sum).sqrt(),
    })
}

/// Minimises Σ w (y − ln(e^u + e^v q))² over (u, v) from the given start; returns (e^u, e^v).
/// Levenberg–Marquardt ([`crate::numerics::lm`]): μ from 10⁻³, ×0.3 after a step that does not
/// raise the cost (not below 10⁻¹²), ×10 after one that does, given up at 10¹²; at most 200
/// steps, stopping when a step moves u and v by at most 10⁻¹² or lowers the cost by at most
/// 10⁻¹⁵ of its new value.
fn levenberg_marquardt(y: &[f64], q: &[f64], w: &[f64], u: f64, v: f64) -> (f64, f64) {
    let mut fit = RayleighLm {
        y,
        q,
        w,
        at: (u, v),
        trial: (u, v),
    };
    let settings = lm::Settings {
        damping: lm::Damping {
            start: 1e-3,
            min: 1e-12,
            // Tried while μ < 10¹²: the largest f64 below it.
            max: f64::from_bits(1e12f64.to_bits() - 1),
            shrink: 1.0 / 0.3,
            grow: 10.0,
        },
        max_iterations: 200,
        accept: lm::Accept::NoIncrease,
        solve: lm::Solve::Direct,
        stopping: lm::Stopping {
            max_step: Some(1e-12),
            relative_decrease: Some((1e-15, lm::CostReference::After)),
            ..lm::Stopping::default()
        },
    };
    let cost = fit.cost(u, v);
    lm::minimise(&mut fit, cost, &settings);
    (fit.at.0.exp(), fit.at.1.exp())
}

/// [`levenberg_marquardt`]'s problem: the data, the current (u, v) and the last trial.
struct RayleighLm<'a> {
    y: &'a [f64],
    q: &'a [f64],
    w: &'a [f64],
    at: (f64, f64),
    trial: (f64, f64),
}

impl RayleighLm<'_> {
    fn cost(&self, u: f64, v: f64) -> f64 {
        (0..self.y.len())
            .map(|i| self.w[i] * (self.y[i] - (u.exp() + v.exp() * self.q[i]).ln()).powi(2))
            .sum::<f64>()
    }
}

impl lm::Problem for RayleighLm<'_> {
    type Scalar = f64;

    fn normal_equations(&mut self) -> Option<lm::NormalEquations<f64>> {
        // Residual r = ln(α + b q) − y, ∂r/∂u = α/(α + b q), ∂r/∂v = b q/(α + b q).
        let (a, b) = (self.at.0.exp(), self.at.1.exp());
        let (mut h11, mut h12, mut h22, mut g1, mut g2) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for i in 0..self.y.len() {
            let m = a + b * self.q[i];
            let (j1, j2) = (a / m, b * self.q[i] / m);
            let r = m.ln() - self.y[i];
            let w = self.w[i];
            h11 += w * j1 * j1;
            h12 += w * j1 * j2;
            h22 += w * j2 * j2;
            g1 += w * j1 * r;
            g2 += w * j2 * r;
        }
        Some(lm::NormalEquations {
            h: DMatrix::from_row_slice(2, 2, &[h11, h12, h12, h22]),
            g: DVector::from_vec(vec![g1, g2]),
        })
    }

    fn trial(&mut self, step: &DVector<f64>) -> Option<f64> {
        self.trial = (self.at.0 + step[0], self.at.1 + step[1]);
        Some(self.cost(self.trial.0, self.trial.1))
    }

    fn accept(&mut self) {
        self.at = self.trial;
    }
}
