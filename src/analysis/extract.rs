//! Modal parameters of a recording with uncertainties: sub-band, multi-channel ESPRIT
//! ([`crate::analysis::estimate`]) refined by nonlinear least squares in every band, and the
//! Gauss–Newton covariance of the refined parameters mapped to frequency, decay rate, amplitude
//! and phase.
//!
//! # Model
//!
//! As in [`crate::analysis::estimate`] (whose module docs define every symbol used here): channels
//! s_c[n] = Σ_k Im(c_{kc} z_kⁿ) + e_c[n], z_k = e^((−d_k + i 2π f_k)/f_s), c_{kc} = a_{kc} e^(iφ_{kc}).
//! Band b with demodulation frequency f_b, low-pass h (T taps) and decimation D turns this into
//! exactly
//!
//! y_c[m] = Σ_{k ∈ band} β_{kc} w_kᵐ + n_c[m],   m = 0 … N_d − 1,
//! w_k = ζ_k^D,  ζ_k = z_k e^(−i ω_b),  β_{kc} = c_{kc} H(ζ_k) / (2i),  H(ζ) = Σ_j h[j] ζ^j.
//!
//! The parameters of the band are the log-poles ℓ_k = ln w_k = ρ_k + i θ_k (ρ = ln|w|, per
//! decimated sample, θ = arg w, rad per decimated sample), shared by every channel, and the
//! complex amplitudes β_{kc}, one per pole and channel. The band's model holds every pole that
//! explains part of its data: the modes ESPRIT reported in the band's centre region, plus as
//! *nuisance poles* every other ESPRIT pole of the band whose band SNR is at least
//! `min_snr_db` − 6 dB (the estimate's own screening) and that does not grow by more than a
//! factor e over the band's samples: modes of the neighbouring bands seen in the guards, the
//! negative-frequency image of low modes in the lowest band, components leaking through the
//! filter's transition band, weak centre poles the estimate dropped. ESPRIT poles below that SNR
//! are left out, so what they fitted counts as noise. All are refined together; only the
//! reported modes come out, as in the estimate (a mode that the refinement moved out of its
//! widened centre region is kept and flagged).
//!
//! # Nonlinear least squares by variable projection
//!
//! With A(ℓ) the N_d × K Vandermonde matrix A_{mk} = e^(m ℓ_k) and channel weights u_c, the cost
//!
//! F(ℓ, β) = Σ_c u_c² ‖y_c − A β_c‖²
//!
//! is linear in β: for given poles β_c = A⁺ y_c, and F(ℓ) = Σ_c u_c² ‖P⊥ y_c‖² with
//! P⊥ = I − A A⁺ depends on the poles alone (variable projection, Golub & Pereyra 1973). A⁺ comes
//! from the Householder QR factorisation A = Q [R; 0] (Q applied implicitly, never formed) and the
//! SVD of the K × K factor R (singular values below 1e-12 of the largest dropped, as in the
//! estimate's band fit): β_c = R⁺ (Qᴴy_c)_top, and in Q's basis P⊥ keeps the rows from K on. The weights u_c² = D / σ²_{bc} come
//! from the estimate's band noise σ²_{bc} (its residual at the ESPRIT poles), so a noisier
//! microphone counts less and F measures the residual in units of the noise level of the
//! centre region, σ²_{bc}/D per complex sample (see "Noise").
//!
//! The model is holomorphic in (ℓ, β): ∂(A β_c)/∂ℓ_k = β_{kc} d_k with d_k[m] = m e^(m ℓ_k), and
//! ∂(A β_c)/∂β_{kc} = a_k, the k-th column of A. Gauss–Newton on all parameters with β
//! eliminated (at the optimal β the amplitude gradient Aᴴ r_c vanishes, so this is the Schur
//! complement of the full system, and equals Kaufman's VarPro step) gives
//!
//! S δ = −g,   S = Σ_c u_c² diag(β̄_c) (P⊥D)ᴴ (P⊥D) diag(β_c),   g = −Σ_c u_c² β̄_c ⊙ (Dᴴ r_c),
//!
//! with D = [d_1 … d_K] (N_d × K), r_c = P⊥ y_c, and S the K × K Hermitian Gauss–Newton matrix.
//! Because the model is holomorphic the complex step equals the real Gauss–Newton step in
//! (ρ, θ). Levenberg–Marquardt ([`crate::numerics::lm`], on the complex ℓ) damps it:
//! (S + λ diag S) δ = −g, Jacobi-scaled; a step that lowers F is taken and λ shrinks tenfold
//! (not below 10⁻¹²), otherwise λ grows tenfold (the fit gives up above 10¹²). The step of pole
//! k is |δ_k| √S_kk standard deviations (with these weights S is the Fisher information of ℓ, so
//! 1/√S_kk is the pole's complex standard deviation with the others held fixed). The refinement
//! has converged when every reported pole's step is below [`ExtractOptions::step_tolerance`]
//! and every nuisance pole's below 100 times that (they matter only through their weak
//! correlation with the modes), whether or not the step lowers F (steps that small that do not
//! lower it mean the minimum to rounding), and stops unconverged after
//! [`ExtractOptions::max_iterations`] steps; a mode whose own last step was below the tolerance
//! still counts as converged. Cost: per evaluation of F the QR, O(N_d K²), and Qᴴ y_c,
//! O(N_d K C); per step also Qᴴ D and (P⊥D)ᴴ(P⊥D), O(N_d K²).
//!
//! # Noise
//!
//! Assumption: in and around the band, e_c is white noise of variance σ_c² per full-rate sample
//! (units²), independent between channels. The band filter shapes it: n_c has variance
//! σ_c² Σ_j h[j]², and at baseband frequency ν (per decimated sample, summed over the D aliases)
//! the spectrum σ_c² S(ν),
//!
//! S(ν) = (1/D) Σ_{a=0}^{D−1} |H(e^(i 2π (ν + a f_d)/f_s))|²,   f_d = f_s / D,
//!
//! whose mean over the band is Σ h². S is flat, 1/D, over the whole centre region (H = 1 in the
//! pass band to 1e-4, and nothing aliases there above −90 dB), but rises towards 2/D at the outer
//! edges of the guards, where the transition band folds back. This is corrected for twice:
//!
//! * σ_c² is estimated from the residual of the whole band with the expected residual energy
//!   under this spectrum, degrees of freedom included:
//!   E‖r_c‖² ≈ σ_c² [N_d Σh² − Σ_k S(ν_k) (1 + q_{kc})],
//!   where each complex amplitude removes one complex degree of freedom at its pole's noise level
//!   S(ν_k), and each pole's two real parameters one more, shared between the channels in
//!   proportion to their weighted power q_{kc} = u_c² |β_{kc}|² / Σ_c' u_c'² |β_{kc'}|². So
//!   σ̂_c² = ‖r_c‖² / [N_d Σh² − Σ_k S(ν_k)(1 + q_{kc})], floored at (1e-10)² times the channel's
//!   mean square like the estimate's band noise.
//! * The covariance uses the noise level of the centre region, ŝ_c² = σ̂_c² / D (complex
//!   variance E|n|² per decimated sample), where every reported mode lies. The nuisance poles in
//!   the guards see up to twice that; their own uncertainties (not reported) are then too small
//!   by up to √2, which leaves the centre modes' uncertainties unaffected except through
//!   correlations across the band, which are weak.
//!
//! Not corrected: in the lowest band (f_b below about the filter's transition) the negative
//! frequencies of the noise fold in as well, so n_c is not circular there and the real and
//! imaginary parts of a parameter have somewhat different variances. Everything the model does
//! not explain — modes below the SNR threshold, the contact transient, reverberation, a mode
//! that is not a pure damped exponential — lands in σ̂_c: the uncertainties are then those the
//! parameters would have if that misfit were white noise, and the residual is what to look at
//! to tell (see [`BandFit::noise_rms`] against [`BandFit::esprit_noise_rms`]).
//!
//! # Covariance
//!
//! The complex Fisher information of (ℓ, β_0, …, β_{C−1}) for circular noise of variance ŝ_c²,
//! v_c² = 1/ŝ_c², has the blocks Σ_c v_c² diag(β̄_c) DᴴD diag(β_c) (ℓℓ), v_c² diag(β̄_c) DᴴA (ℓβ_c)
//! and v_c² AᴴA (β_cβ_c). Its inverse, by the Schur complement S (the matrix above with weights
//! v_c), gives the Gauss–Newton covariance (JᴴJ)⁻¹ of the whole parameter vector:
//!
//! E[δℓ δℓᴴ] = S⁻¹,
//! E[δβ_c δβ_cᴴ] = ŝ_c² (AᴴA)⁻¹ + E_c S⁻¹ E_cᴴ,   E_c = A⁺ D diag(β_c),
//! E[δβ_c δℓᴴ] = −E_c S⁻¹.
//!
//! For a holomorphic model and circular noise the real and imaginary parts of each complex
//! parameter are uncorrelated to first order, each with half its complex variance:
//! Var ρ_k = Var θ_k = ½ [S⁻¹]_{kk}. S is inverted after Jacobi scaling by Cholesky, or, if it is
//! singular (a pole with no amplitude), by a pseudo-inverse whose null directions get the
//! variance of an eigenvalue 1e-13 of the largest: huge, not infinite.
//!
//! # To full rate
//!
//! f = f_b + θ f_d / (2π) and d = −ρ f_d, so
//!
//! σ_f = (f_d / 2π) √(½ [S⁻¹]_{kk})  [Hz],   σ_d = f_d √(½ [S⁻¹]_{kk})  [1/s]   (σ_d = 2π σ_f).
//!
//! The amplitude c_{kc} = 2i β_{kc} / H(ζ_k), ln ζ_k = ℓ_k / D, depends on the pole through the
//! filter: δ ln c = δβ/β − g_k δℓ with g_k = Σ_j j h[j] ζ_k^j / (D H(ζ_k)) (about (T − 1)/(2D):
//! the filter's delay turns a frequency error into a phase error). With
//!
//! V_{kc} = E|δ ln c_{kc}|² = E|δβ_{kc}|²/|β_{kc}|² + |g_k|² [S⁻¹]_{kk} − 2 Re(ḡ_k E[δβ_{kc} δℓ̄_k] / β_{kc}),
//!
//! and ln c = ln a + iφ, σ_a = a √(V/2) (units of the signal) and σ_φ = √(V/2) (rad): first
//! order, so meaningful while σ_a ≪ a. In a channel where the mode's amplitude is exactly zero
//! (a silent microphone) σ_a = (2/|H|) √(E|δβ|²/2) and σ_φ = π/√3, the spread of a uniform phase.
//!
//! # SNR and flags
//!
//! SNR_k = 10 log10(Σ_c E_{kc} / Σ_c σ̂_c²) with E_{kc} = |c_{kc}|²/2 · Σ_n e^(−2 d_k n / f_s),
//! the estimate's definition with the refined values. A mode is flagged when its band's
//! refinement did not converge, when the refinement moved it more than
//! [`ExtractOptions::shift_flag_sigma`] standard deviations (in f or in d) from ESPRIT, or when
//! it left its band's centre region (widened by 0.2/T as in the estimate). ESPRIT is not an
//! efficient estimator, so shifts of one or two σ are normal; large ones mean the two methods
//! disagree about the data (a pair that ESPRIT did not resolve, a pole fitted to misfit).
//!
//! # Accuracy and cost (measured)
//!
//! Tests in this module (release build, one core):
//!
//! * Calibration: 200 noise realisations of three modes (2.3, 2.75, 3.4 kHz; d = 5, 12, 8 1/s)
//!   on two channels, 0.25 s at 16 kHz, noise RMS 0.05 (band SNR 44–53 dB): the z-scores
//!   (estimate − truth)/σ have mean +0.07, +0.02, +0.03, −0.02 and standard deviation 0.99,
//!   1.00, 1.01, 1.00 for f, d, a, φ (mean |z| 0.78–0.81, normal: 0.80), 3600 pooled: 1.003.
//!   Without the filter-spectrum correction every standard deviation came out 0.90–0.92. 2.9 s.
//! * Close pair, Δf = 0.6/T (0.5 s, 2500 and 2501.2 Hz, d = 2 and 3 1/s, four channels, 40 dB):
//!   over 100 realisations the refined frequencies have z-scores of standard deviation 0.91 and
//!   0.88, ESPRIT's 4.7 and 5.4 (in units of the refined σ_f ≈ 0.6 mHz): here ESPRIT is far from
//!   efficient and the refinement is what makes the uncertainties hold.
//! * Separated modes (five modes, four channels, 40 dB): Σz² over 40 frequency and decay errors
//!   49 for ESPRIT, 36 refined (40 expected); the full-rate residual drops on every seed.
//! * The bowl (8 microphones × 1 s at 48 kHz, up to 12 kHz, 12 bands): 58 modes in 2.5–3.6 s
//!   (ESPRIT alone 0.4–0.6 s). The pair 1681.21/1684.24 Hz comes out with σ_f = 0.33 and 0.40 mHz,
//!   d = 3.10 and 3.15 1/s; ESPRIT had it at 1681.10/1684.34 Hz with d ≈ 4.6 1/s, several hundred
//!   refined σ away, and the band's noise estimate falls from 4.4e-4 to 7.8e-5: in that band
//!   ESPRIT's 40-pole subspace explained the data far worse than 8 refined poles do. Every bowl
//!   mode is flagged: 52 moved more than 5σ from ESPRIT, the 33 of the four bands above 6 kHz
//!   (26–37 poles each, fitting clusters of strongly damped poles; F still falling after 50
//!   steps) did not converge, 2 left their band. The full-rate residual (least-squares
//!   amplitudes) is lower with the refined poles on all eight channels (0.743–1.000 of the signal
//!   RMS against 0.746–1.000; most of the RMS lies below 1 kHz, where no mode is found); the
//!   residual of the modes as reported is higher (1.01–2.0), from strongly damped poles fitted in
//!   two bands and from cancelling pairs of a mode and a nuisance pole.
//!
//! # Gliding modes
//!
//! A mode whose pitch glides is not a damped exponential; this extraction breaks it into
//! constant poles a few Hz apart. [`glide::fit_glides`], run on the result, refits each mode or
//! cluster of poles as gliding modes and keeps them where the BIC prefers them (model,
//! criterion and measured accuracy in [`glide`]'s docs); [`ModalExtraction::render_channel`]
//! resynthesises gliding modes gliding.
//!
//! # Residuals
//!
//! [`ModalExtraction::residual_rms_esprit`] is the estimate's full-rate residual (ESPRIT poles,
//! least-squares amplitudes fitted at full rate to all modes at once);
//! [`ModalExtraction::residual_rms_refined`] the same with the refined poles, which compares the
//! poles like for like; [`ModalExtraction::residual_rms_reported`] the residual of the modes
//! exactly as reported (refined poles, amplitudes mapped from the bands).

use nalgebra::{Cholesky, DMatrix, DVector, SymmetricEigen, SVD};

use crate::analysis::estimate::{
    self, lsq, BandData, BandReport, Decimator, EstimateError, EstimateOptions, C64,
};
use crate::analysis::mode::{
    phase_sd, sd_from_variance, MeasuredMode, ModeSd, RefinedFrom, Refinement, UNIFORM_PHASE_SD,
};
use crate::audio::synth::ModalBank;
use crate::numerics::lm;

pub mod glide;
#[cfg(test)]
mod tests;

pub use glide::{fit_glides, GlideDecision, GlideOptions, GlideStage, ModeGlide};

/// A trial pole may grow by at most e^50 over the band's samples (it overflows long before
/// mattering otherwise); steps beyond are rejected.
const MAX_LOG_GROWTH: f64 = 50.0;

/// Singular values of A below this fraction of the largest are dropped (as in the estimate's
/// band fit): two poles that coincide share one amplitude, minimum-norm.
const SVD_CUTOFF: f64 = 1e-12;

/// Eigenvalues of the Gauss–Newton matrix below this fraction of the largest are raised to it
/// when S is singular: the direction gets a huge, finite variance.
const PSEUDO_INVERSE_FLOOR: f64 = 1e-13;

/// Nuisance poles count as converged at this many times [`ExtractOptions::step_tolerance`]: they
/// matter only through their (weak) correlation with the band's modes.
const NUISANCE_TOLERANCE_FACTOR: f64 = 100.0;

/// Levenberg–Marquardt: starting damping and its bounds (relative to diag S).
const LM_LAMBDA_START: f64 = 1e-3;
const LM_LAMBDA_MIN: f64 = 1e-12;
const LM_LAMBDA_MAX: f64 = 1e12;

/// Settings of [`extract_modes`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ExtractOptions {
    /// The ESPRIT stage (bands, model order, SNR threshold, decay limits).
    pub estimate: EstimateOptions,
    /// Levenberg–Marquardt steps allowed per band (default 50).
    pub max_iterations: usize,
    /// Converged when no pole moves by more than this many of its standard deviations in one
    /// step (default 1e-3).
    pub step_tolerance: f64,
    /// A mode the refinement moved further than this many standard deviations from its ESPRIT
    /// estimate, in frequency or decay rate, is flagged (default 5).
    pub shift_flag_sigma: f64,
}

impl Default for ExtractOptions {
    fn default() -> Self {
        ExtractOptions {
            estimate: EstimateOptions::default(),
            max_iterations: 50,
            step_tolerance: 1e-3,
            shift_flag_sigma: 5.0,
        }
    }
}

/// What the refinement did in one band.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BandFit {
    /// Centre region [lo, hi), Hz.
    pub lo_hz: f64,
    pub hi_hz: f64,
    /// f_b, the demodulation frequency, Hz.
    pub demod_hz: f64,
    /// Reported modes of the band.
    pub modes: usize,
    /// Other poles refined with them (see the module docs).
    pub nuisance_poles: usize,
    /// Levenberg–Marquardt steps taken (0 when the band has no mode to refine).
    pub iterations: usize,
    pub converged: bool,
    /// F = Σ_c u_c² ‖r_c‖² at the ESPRIT poles and at the refined poles (dimensionless; about
    /// N_d C D Σh² when the residual is the noise ESPRIT saw); `None` for a band without modes.
    pub cost_esprit: Option<f64>,
    pub cost_refined: Option<f64>,
    /// σ̂_c per channel after the refinement: RMS of full-rate white noise with the band's
    /// residual level, degrees of freedom accounted for, units.
    pub noise_rms: Vec<f64>,
    /// The estimate's σ_{bc} (residual at the ESPRIT poles, no correction for degrees of
    /// freedom), units.
    pub esprit_noise_rms: Vec<f64>,
}

/// The result of [`extract_modes`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ModalExtraction {
    /// f_s, Hz.
    pub sample_rate: f64,
    /// N, samples per channel.
    pub n_samples: usize,
    /// The modes, sorted by frequency.
    pub modes: Vec<MeasuredMode>,
    /// One per band of the estimate.
    pub bands: Vec<BandFit>,
    /// Full-rate RMS of s_c − model per channel for ESPRIT's poles with the estimate's
    /// least-squares amplitudes (its `residual_rms`), units.
    pub residual_rms_esprit: Vec<f64>,
    /// The same for the refined poles (same least-squares amplitudes at full rate), units: the
    /// like-for-like comparison of the poles.
    pub residual_rms_refined: Vec<f64>,
    /// Full-rate RMS of s_c − model for the modes exactly as reported (refined poles, amplitudes
    /// from the bands), units. Above `residual_rms_refined` by about the noise's share of the
    /// amplitudes when the model fits; far above it when strongly damped poles (line width d/π
    /// comparable to the guards) are fitted in two bands, or a reported pole and a nuisance pole
    /// form a cancelling pair.
    pub residual_rms_reported: Vec<f64>,
    /// RMS of s_c per channel, units.
    pub signal_rms: Vec<f64>,
    /// D, the bands' decimation factor.
    pub decimation: usize,
}

impl ModalExtraction {
    /// The modes as seen by one channel, ready for [`crate::audio::synth::render`].
    ///
    /// # Panics
    /// If `channel` is not a channel of the extraction.
    pub fn bank(&self, channel: usize) -> ModalBank {
        ModalBank {
            frequencies_hz: self.modes.iter().map(|m| m.frequency_hz).collect(),
            decay_rates: self.modes.iter().map(|m| m.decay_rate).collect(),
            amplitudes: self.modes.iter().map(|m| m.amplitudes[channel]).collect(),
            phases: self.modes.iter().map(|m| m.phases[channel]).collect(),
        }
    }

    /// `n` samples of one channel's resynthesis: the modes of [`Self::bank`], those with a
    /// selected glide ([`ModeGlide::selected`]) with the glide phase of [`glide::glide_phase`].
    ///
    /// # Panics
    /// If `channel` is not a channel of the extraction.
    pub fn render_channel(&self, channel: usize, n: usize) -> Vec<f64> {
        let gliding = |m: &MeasuredMode| m.glide.as_ref().is_some_and(|g| g.selected);
        let steady: Vec<&MeasuredMode> = self.modes.iter().filter(|m| !gliding(m)).collect();
        let bank = ModalBank {
            frequencies_hz: steady.iter().map(|m| m.frequency_hz).collect(),
            decay_rates: steady.iter().map(|m| m.decay_rate).collect(),
            amplitudes: steady.iter().map(|m| m.amplitudes[channel]).collect(),
            phases: steady.iter().map(|m| m.phases[channel]).collect(),
        };
        let mut out = crate::audio::synth::render_samples(&bank, self.sample_rate, n);
        for m in self.modes.iter().filter(|m| gliding(m)) {
            let g = m.glide.as_ref().map_or(0.0, |g| g.glide);
            glide::add_gliding_mode(
                &mut out,
                self.sample_rate,
                m.frequency_hz,
                m.decay_rate,
                g,
                m.amplitudes[channel],
                m.phases[channel],
            );
        }
        out
    }
}

/// Why no extraction was made.
#[derive(thiserror::Error, Debug, Clone, PartialEq)]
pub enum ExtractError {
    #[error(transparent)]
    Estimate(#[from] EstimateError),
    #[error("extract option {name} = {value} is invalid: {reason}")]
    InvalidOption {
        name: &'static str,
        value: f64,
        reason: &'static str,
    },
}

/// Extracts the modes of one strike recorded on one or more channels (equal lengths, starting at
/// the onset) at `sample_rate` Hz, each parameter with its standard deviation; see the module
/// docs for the method and its assumptions.
pub fn extract_modes(
    channels: &[Vec<f64>],
    sample_rate: f64,
    options: &ExtractOptions,
) -> Result<ModalExtraction, ExtractError> {
    check_options(options)?;
    let signals: Vec<&[f64]> = channels.iter().map(|c| c.as_slice()).collect();
    let detailed = estimate::estimate_with_bands(&signals, sample_rate, &options.estimate, true)?;
    let est = &detailed.estimate;
    let n = est.n_samples;
    let setup = Setup {
        options,
        sample_rate,
        n,
        dec: &detailed.decimator,
        noise_gain: detailed.decimator.taps.iter().map(|h| h * h).sum(),
        power: signals
            .iter()
            .map(|s| s.iter().map(|v| v * v).sum::<f64>() / n as f64)
            .collect(),
        widen_hz: estimate::MERGE_RAYLEIGH_FRACTION * sample_rate / n as f64,
    };

    let mut modes: Vec<Option<MeasuredMode>> = vec![None; est.modes.len()];
    let mut coeffs: Vec<Vec<C64>> = vec![vec![]; est.modes.len()];
    let mut log_zs: Vec<C64> = vec![C64::new(0.0, 0.0); est.modes.len()];
    let mut bands = Vec::with_capacity(est.bands.len());
    for (b, (report, data)) in est.bands.iter().zip(&detailed.bands).enumerate() {
        let esprit: Vec<(usize, &MeasuredMode, usize)> = (0..est.modes.len())
            .filter(|&i| est.modes[i].band == Some(b))
            .map(|i| (i, &est.modes[i], detailed.mode_poles[i]))
            .collect();
        let (fit, found) = refine_band(&setup, b, report, data, &esprit);
        bands.push(fit);
        for f in found {
            modes[f.index] = Some(f.mode);
            coeffs[f.index] = f.coeffs;
            log_zs[f.index] = f.log_z;
        }
    }
    let reported_residual = lsq::residuals(&signals, &log_zs, &coeffs);
    // Like for like with ESPRIT's residual: the same full-rate least-squares amplitudes, at the
    // refined poles.
    let refined_residual = match lsq::fit_full_rate(&signals, &log_zs) {
        Some(ls) => lsq::residuals(&signals, &log_zs, &ls)
            .iter()
            .map(|r| crate::audio::rms(r))
            .collect(),
        None => vec![f64::NAN; signals.len()],
    };
    let mut modes: Vec<MeasuredMode> = modes.into_iter().flatten().collect();
    modes.sort_by(|a, b| a.frequency_hz.total_cmp(&b.frequency_hz));
    Ok(ModalExtraction {
        sample_rate,
        n_samples: n,
        modes,
        bands,
        residual_rms_esprit: est.residual_rms.clone(),
        residual_rms_refined: refined_residual,
        residual_rms_reported: reported_residual
            .iter()
            .map(|r| crate::audio::rms(r))
            .collect(),
        signal_rms: est.signal_rms.clone(),
        decimation: detailed.decimator.factor,
    })
}

/// What every band of one extraction shares.
struct Setup<'a> {
    options: &'a ExtractOptions,
    sample_rate: f64,
    /// N, samples per channel.
    n: usize,
    dec: &'a Decimator,
    /// Σ h².
    noise_gain: f64,
    /// Mean square of each channel (for the rounding floor of the noise).
    power: Vec<f64>,
    /// δ = 0.2/T, the widening of the centre regions (Hz).
    widen_hz: f64,
}

/// A refined mode and what the full-rate residuals need of it.
struct RefinedMode {
    /// Index of the mode in the estimate.
    index: usize,
    mode: MeasuredMode,
    /// c_c per channel.
    coeffs: Vec<C64>,
    /// ln z, per full-rate sample.
    log_z: C64,
}

/// Refines band `b` (module docs): `esprit` holds its reported modes as (index in the estimate,
/// the mode, index of its pole in `data.poles`).
fn refine_band(
    setup: &Setup,
    b: usize,
    report: &BandReport,
    data: &BandData,
    esprit: &[(usize, &MeasuredMode, usize)],
) -> (BandFit, Vec<RefinedMode>) {
    let options = setup.options;
    let factor = setup.dec.factor as f64;
    let esprit_noise_rms = report.noise_rms.clone();
    let mut fit = BandFit {
        lo_hz: report.lo_hz,
        hi_hz: report.hi_hz,
        demod_hz: report.demod_hz,
        modes: esprit.len(),
        nuisance_poles: 0,
        iterations: 0,
        converged: true,
        cost_esprit: None,
        cost_refined: None,
        noise_rms: esprit_noise_rms.clone(),
        esprit_noise_rms,
    };
    if esprit.is_empty() {
        return (fit, vec![]);
    }
    // The band's model: reported poles first, then the nuisance poles.
    let reported_poles: Vec<usize> = esprit.iter().map(|e| e.2).collect();
    let nuisance_snr_db = options.estimate.min_snr_db - estimate::BAND_SNR_MARGIN_DB;
    let nuisance = nuisance_poles(data, &reported_poles, nuisance_snr_db);
    let start: Vec<C64> = reported_poles
        .iter()
        .chain(&nuisance)
        .map(|&p| data.poles[p].ln())
        .collect();
    // u_c² = D / σ²_{bc}; a channel without noise is silent (the estimate floors the noise at the
    // rounding level of the channel's power) and carries no weight.
    let weights: Vec<f64> = data
        .noise_var
        .iter()
        .map(|&v| if v > 0.0 { (factor / v).sqrt() } else { 0.0 })
        .collect();
    let y = &data.y;
    let lm = refine_poles(y, &weights, &start, reported_poles.len(), options);
    let log_w = lm
        .as_ref()
        .map_or_else(|| start.clone(), |o| o.log_w.clone());
    fit.nuisance_poles = nuisance.len();
    fit.iterations = lm.as_ref().map_or(0, |o| o.iterations);
    fit.converged = lm.as_ref().is_some_and(|o| o.converged);
    fit.cost_esprit = lm.as_ref().map(|o| o.cost_start);
    fit.cost_refined = lm.as_ref().map(|o| o.cost_end);

    let model = BandModel::new(y, &log_w);
    let band_noise = model.as_ref().map_or_else(
        || data.noise_var.clone(),
        |m| {
            residual_noise(
                m,
                &weights,
                &log_w,
                setup.dec,
                setup.noise_gain,
                &setup.power,
            )
        },
    );
    fit.noise_rms = band_noise.iter().map(|v| v.sqrt()).collect();
    let cov = model.as_ref().map(|m| {
        let centre: Vec<f64> = band_noise.iter().map(|v| v / factor).collect();
        covariance(m, &centre)
    });
    let noise_total: f64 = band_noise.iter().sum();
    let found = esprit
        .iter()
        .enumerate()
        .map(|(slot, &(index, esprit_mode, _))| {
            // A mode has converged if its band has, or if its own last step was below the
            // tolerance.
            let converged = lm
                .as_ref()
                .is_some_and(|o| o.converged || o.last_step_sigma[slot] < options.step_tolerance);
            let fitted = match (&model, &cov) {
                (Some(m), Some(c)) => Some((m, c)),
                _ => None,
            };
            let (mode, coeffs, log_z) = map_to_full_rate(
                setup,
                b,
                report,
                slot,
                log_w[slot],
                fitted,
                esprit_mode,
                noise_total,
                converged,
            );
            RefinedMode {
                index,
                mode,
                coeffs,
                log_z,
            }
        })
        .collect();
    (fit, found)
}

/// The mode in `slot` of band `b` at full rate with its standard deviations (module docs, "To
/// full rate"), its coefficients c_c and ln z. Without a fitted band model (its Vandermonde
/// matrix could not be factorised) ESPRIT's amplitudes are kept, with infinite uncertainties.
#[allow(clippy::too_many_arguments)]
fn map_to_full_rate(
    setup: &Setup,
    b: usize,
    report: &BandReport,
    slot: usize,
    ell: C64,
    fitted: Option<(&BandModel, &BandCovariance)>,
    esprit_mode: &MeasuredMode,
    noise_total: f64,
    converged: bool,
) -> (MeasuredMode, Vec<C64>, C64) {
    let (dec, sample_rate) = (setup.dec, setup.sample_rate);
    let factor = dec.factor as f64;
    let rate_d = sample_rate / factor;
    let omega_b = C64::new(
        0.0,
        2.0 * std::f64::consts::PI * report.demod_hz / sample_rate,
    );
    let log_zeta = ell / factor;
    let log_z = log_zeta + omega_b;
    let frequency_hz = log_z.im * sample_rate / (2.0 * std::f64::consts::PI);
    let decay_rate = -log_z.re * sample_rate;
    let zeta = log_zeta.exp();
    let gain = dec.response(zeta);
    let g = response_log_derivative(dec, zeta) / (factor * gain);
    let channels = esprit_mode.amplitudes.len();
    let (beta, var_ell, var_beta, cross): (Vec<C64>, f64, Vec<f64>, Vec<C64>) = match fitted {
        Some((m, c)) => (
            (0..channels).map(|ch| m.beta[(slot, ch)]).collect(),
            c.log_w[(slot, slot)].re,
            (0..channels).map(|ch| c.beta_var[(slot, ch)]).collect(),
            (0..channels).map(|ch| c.beta_log_w[(slot, ch)]).collect(),
        ),
        None => (
            esprit_mode
                .amplitudes
                .iter()
                .zip(&esprit_mode.phases)
                .map(|(a, p)| C64::from_polar(*a, *p) * gain / C64::new(0.0, 2.0))
                .collect(),
            f64::INFINITY,
            vec![f64::INFINITY; channels],
            vec![C64::new(0.0, 0.0); channels],
        ),
    };
    let sd_ell = (0.5 * var_ell).sqrt();
    let frequency_sd_hz = rate_d / (2.0 * std::f64::consts::PI) * sd_ell;
    let decay_rate_sd = rate_d * sd_ell;
    let coeffs: Vec<C64> = beta.iter().map(|b| C64::new(0.0, 2.0) * b / gain).collect();
    // (σ_a, σ_φ) per channel; a channel without the mode has no phase: σ_φ is then that of a
    // uniformly distributed phase.
    let spread: Vec<(f64, f64)> = beta
        .iter()
        .zip(&var_beta)
        .zip(&cross)
        .map(|((b, vb), x)| {
            if b.norm_sqr() > 0.0 {
                let v = vb / b.norm_sqr() + g.norm_sqr() * var_ell - 2.0 * (g.conj() * x / b).re;
                // σ of ln a and of φ; a band model near singular measures neither.
                let half = sd_from_variance(0.5 * v);
                (2.0 * b.norm() / gain.norm() * half, phase_sd(half))
            } else {
                (2.0 / gain.norm() * (0.5 * vb).sqrt(), UNIFORM_PHASE_SD)
            }
        })
        .collect();
    let energy: f64 = energies(log_z, &coeffs, setup.n).iter().sum();
    let z_f = (frequency_hz - esprit_mode.frequency_hz) / frequency_sd_hz;
    let z_d = (decay_rate - esprit_mode.decay_rate) / decay_rate_sd;
    let shift_sigma = z_f.abs().max(z_d.abs());
    let widen = setup.widen_hz;
    let in_band = frequency_hz >= report.lo_hz - widen && frequency_hz < report.hi_hz + widen;
    let mode = MeasuredMode {
        amplitudes: coeffs.iter().map(|v| v.norm()).collect(),
        phases: coeffs.iter().map(|v| v.arg()).collect(),
        snr_db: Some(10.0 * (energy / noise_total).log10()),
        band: Some(b),
        sd: Some(ModeSd {
            frequency_hz: frequency_sd_hz,
            decay_rate: decay_rate_sd,
            amplitudes: spread.iter().map(|s| s.0).collect(),
            phases: spread.iter().map(|s| s.1).collect(),
        }),
        refined_from: Some(RefinedFrom {
            frequency_hz: esprit_mode.frequency_hz,
            decay_rate: esprit_mode.decay_rate,
        }),
        refinement: Some(Refinement {
            shift_sigma,
            converged,
            // An undefined shift (0/0) is flagged too.
            moved: shift_sigma.is_nan() || shift_sigma > setup.options.shift_flag_sigma,
            left_band: !in_band,
        }),
        ..MeasuredMode::pole(frequency_hz, decay_rate)
    };
    (mode, coeffs, log_z)
}

fn check_options(options: &ExtractOptions) -> Result<(), ExtractError> {
    let invalid = |name, value, reason| {
        Err(ExtractError::InvalidOption {
            name,
            value,
            reason,
        })
    };
    if options.max_iterations == 0 {
        return invalid("max_iterations", 0.0, "must be at least 1");
    }
    if !(options.step_tolerance > 0.0 && options.step_tolerance.is_finite()) {
        return invalid(
            "step_tolerance",
            options.step_tolerance,
            "must be a positive number",
        );
    }
    if options.shift_flag_sigma.is_nan() || options.shift_flag_sigma <= 0.0 {
        return invalid(
            "shift_flag_sigma",
            options.shift_flag_sigma,
            "must be positive",
        );
    }
    Ok(())
}

/// The poles of a band refined beside its reported ones: every other pole with a band SNR of at
/// least `min_snr_db` that does not grow over the band's samples.
fn nuisance_poles(data: &BandData, reported: &[usize], min_snr_db: f64) -> Vec<usize> {
    let n_d = data.y.first().map_or(0, |y| y.len()) as f64;
    (0..data.poles.len())
        .filter(|p| !reported.contains(p))
        .filter(|&p| data.pole_snr_db[p] >= min_snr_db && data.poles[p].norm().ln() * n_d < 1.0)
        .collect()
}

/// The columns a_k[m] = e^(m ℓ_k) of the Vandermonde matrix A, or `None` if a pole is not
/// finite or grows by more than e^[`MAX_LOG_GROWTH`] over the samples.
fn vandermonde(log_w: &[C64], n: usize) -> Option<Vec<Vec<C64>>> {
    let span = n.saturating_sub(1) as f64;
    let usable = log_w
        .iter()
        .all(|l| l.re.is_finite() && l.im.is_finite() && l.re * span <= MAX_LOG_GROWTH);
    usable.then(|| vandermonde_columns(log_w, n))
}

/// The columns of A by recursion (relative rounding ~√N_d ε), for poles already checked by
/// [`vandermonde`].
fn vandermonde_columns(log_w: &[C64], n: usize) -> Vec<Vec<C64>> {
    log_w
        .iter()
        .map(|l| {
            let w = l.exp();
            let mut p = C64::new(1.0, 0.0);
            (0..n)
                .map(|_| {
                    let v = p;
                    p *= w;
                    v
                })
                .collect()
        })
        .collect()
}

/// Σ_i ā_i b_i.
fn dot_conj(a: &[C64], b: &[C64]) -> C64 {
    let (mut re, mut im) = (0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        re += x.re * y.re + x.im * y.im;
        im += x.re * y.im - x.im * y.re;
    }
    C64::new(re, im)
}

/// [`dot_conj`] of `a` with four vectors (each at least as long as `a`), side by side: each the
/// same arithmetic as alone.
fn dot_conj_four(a: &[C64], bs: [&[C64]; 4]) -> [C64; 4] {
    let n = a.len();
    let [b0, b1, b2, b3] = bs.map(|b| &b[..n]);
    let (mut re, mut im) = ([0.0; 4], [0.0; 4]);
    for i in 0..n {
        let x = a[i];
        let ys = [b0[i], b1[i], b2[i], b3[i]];
        for q in 0..4 {
            re[q] += x.re * ys[q].re + x.im * ys[q].im;
            im[q] += x.re * ys[q].im - x.im * ys[q].re;
        }
    }
    std::array::from_fn(|q| C64::new(re[q], im[q]))
}

/// Householder QR of a tall N × K matrix given by its columns: A = Q [R; 0] with
/// Q = H_0 H_1 … H_{K−1}, H_k = I − τ_k v_k v_kᴴ acting on rows k … N − 1 (τ_k = 2 / v_kᴴv_k, or 0
/// where the column is already zero). Each H_k is Hermitian and unitary, so Qᴴ = H_{K−1} … H_0.
struct HouseholderQr {
    /// v_k, of length N − k.
    reflectors: Vec<Vec<C64>>,
    taus: Vec<f64>,
    /// R, K × K, upper triangular.
    r: DMatrix<C64>,
}

impl HouseholderQr {
    fn new(mut columns: Vec<Vec<C64>>) -> HouseholderQr {
        let k = columns.len();
        let mut reflectors = Vec::with_capacity(k);
        let mut taus = Vec::with_capacity(k);
        let mut r = DMatrix::<C64>::zeros(k, k);
        for j in 0..k {
            let (done, rest) = columns.split_at_mut(j + 1);
            let x = &done[j][j..];
            for (i, value) in done[j][..j].iter().enumerate() {
                r[(i, j)] = *value;
            }
            let norm = x.iter().map(|v| v.norm_sqr()).sum::<f64>().sqrt();
            let head = x.first().copied().unwrap_or_default();
            if norm == 0.0 {
                reflectors.push(vec![C64::new(0.0, 0.0); x.len()]);
                taus.push(0.0);
                continue;
            }
            // α = −e^(i arg x₀) ‖x‖, v = x − α e₀: v₀ = e^(i arg x₀)(|x₀| + ‖x‖), no cancellation.
            let phase = if head.norm() > 0.0 {
                head / head.norm()
            } else {
                C64::new(1.0, 0.0)
            };
            let alpha = -phase * norm;
            let mut v = x.to_vec();
            v[0] -= alpha;
            let tau = 1.0 / (norm * (norm + head.norm()));
            r[(j, j)] = alpha;
            reflect_all(&v, tau, j, rest);
            reflectors.push(v);
            taus.push(tau);
        }
        HouseholderQr {
            reflectors,
            taus,
            r,
        }
    }

    /// x ← Qᴴ x for every x of `xs` (each of length N).
    fn apply_adjoint(&self, xs: &mut [Vec<C64>]) {
        for (j, (v, &tau)) in self.reflectors.iter().zip(&self.taus).enumerate() {
            if tau != 0.0 {
                reflect_all(v, tau, j, xs);
            }
        }
    }
}

/// x ← (I − τ v vᴴ) x.
fn reflect(v: &[C64], tau: f64, x: &mut [C64]) {
    let s = dot_conj(v, x) * tau;
    for (xi, vi) in x.iter_mut().zip(v) {
        *xi -= vi * s;
    }
}

/// [`reflect`] on x[from..] of every x of `xs`, four at a time ([`reflect_four`]).
fn reflect_all(v: &[C64], tau: f64, from: usize, xs: &mut [Vec<C64>]) {
    let mut chunks = xs.chunks_exact_mut(4);
    for chunk in &mut chunks {
        let [a, b, c, d] = chunk else {
            unreachable!("chunks of four")
        };
        reflect_four(
            v,
            tau,
            [
                &mut a[from..],
                &mut b[from..],
                &mut c[from..],
                &mut d[from..],
            ],
        );
    }
    for x in chunks.into_remainder() {
        reflect(v, tau, &mut x[from..]);
    }
}

/// [`reflect`] on four vectors, each with the arithmetic it has alone (test
/// `four_reflections_at_once_are_four_alone`): a dot product is a chain of additions, each
/// waiting on the one before, and four side by side overlap. The Householder QR of the band
/// fits and its products were a sixth of the extraction's time on a plate with six
/// microphones, most of it in those chains.
fn reflect_four(v: &[C64], tau: f64, xs: [&mut [C64]; 4]) {
    let n = v.len();
    let [a, b, c, d] = xs;
    let (a, b, c, d) = (&mut a[..n], &mut b[..n], &mut c[..n], &mut d[..n]);
    let s = dot_conj_four(v, [&*a, &*b, &*c, &*d]).map(|dot| dot * tau);
    for i in 0..n {
        let vi = v[i];
        a[i] -= vi * s[0];
        b[i] -= vi * s[1];
        c[i] -= vi * s[2];
        d[i] -= vi * s[3];
    }
}

/// The linear part of the band model solved for given poles, in the basis of A's QR
/// factorisation A = Q [R; 0]: β = R⁺ (Qᴴy)_top (R⁺ from the SVD of the K × K matrix R, singular
/// values below 1e-12 of the largest dropped), residual energy ‖(Qᴴy)_bottom‖² + ‖(Qᴴy)_top − Rβ‖².
struct BandModel {
    /// The poles' log e^(ℓ_k), for the derivative columns.
    log_w: Vec<C64>,
    qr: HouseholderQr,
    /// R⁺, K × K.
    r_pinv: DMatrix<C64>,
    /// Qᴴ y_c per channel, with the top K entries replaced by (Qᴴy)_top − Rβ: Qᴴ r_c.
    q_resid: Vec<Vec<C64>>,
    /// β, K × C.
    beta: DMatrix<C64>,
    /// ‖r_c‖² per channel.
    energy: Vec<f64>,
}

impl BandModel {
    fn new(y: &[Vec<C64>], log_w: &[C64]) -> Option<BandModel> {
        let n = y.first().map_or(0, |c| c.len());
        let k = log_w.len();
        if n <= k {
            return None;
        }
        let qr = HouseholderQr::new(vandermonde(log_w, n)?);
        let svd = SVD::try_new(qr.r.clone(), true, true, f64::EPSILON, 1000 * k.max(10))?;
        let (u, v_t) = (svd.u?, svd.v_t?);
        let top = svd.singular_values.iter().cloned().fold(0.0, f64::max);
        let inv: Vec<f64> = svd
            .singular_values
            .iter()
            .map(|&s| if s > SVD_CUTOFF * top { 1.0 / s } else { 0.0 })
            .collect();
        let r_pinv = DMatrix::from_fn(k, k, |i, j| {
            (0..k)
                .map(|l| v_t[(l, i)].conj() * inv[l] * u[(j, l)].conj())
                .sum()
        });
        let mut beta = DMatrix::<C64>::zeros(k, y.len());
        let mut q_resid = Vec::with_capacity(y.len());
        let mut energy = Vec::with_capacity(y.len());
        let mut q_y = y.to_vec();
        qr.apply_adjoint(&mut q_y);
        for (c, mut q) in q_y.into_iter().enumerate() {
            let head = DVector::from_column_slice(&q[..k]);
            let b = &r_pinv * &head;
            let fitted = &qr.r * &b;
            for i in 0..k {
                q[i] -= fitted[i];
            }
            beta.set_column(c, &b);
            energy.push(q.iter().map(|v| v.norm_sqr()).sum::<f64>());
            q_resid.push(q);
        }
        if energy.iter().any(|e| !e.is_finite())
            || beta.iter().any(|b| !(b.re.is_finite() && b.im.is_finite()))
        {
            return None;
        }
        Some(BandModel {
            log_w: log_w.to_vec(),
            qr,
            r_pinv,
            q_resid,
            beta,
            energy,
        })
    }

    /// F = Σ_c u_c² ‖r_c‖².
    fn cost(&self, weights: &[f64]) -> f64 {
        self.energy
            .iter()
            .zip(weights)
            .map(|(e, u)| u * u * e)
            .sum()
    }

    /// Qᴴ D, D = [d_1 … d_K] with d_k[m] = m e^(m ℓ_k), by columns.
    fn q_adjoint_derivatives(&self) -> Vec<Vec<C64>> {
        let n = self.q_resid.first().map_or(0, |q| q.len());
        // The poles passed `vandermonde` when this model was made.
        let mut columns = vandermonde_columns(&self.log_w, n);
        for column in &mut columns {
            for (m, v) in column.iter_mut().enumerate() {
                *v *= m as f64;
            }
        }
        self.qr.apply_adjoint(&mut columns);
        columns
    }

    /// The Gauss–Newton matrix S = Σ_c w_c² diag(β̄_c) (P⊥D)ᴴ(P⊥D) diag(β_c) for channel weights
    /// `weights`, the gradient g = −Σ_c w_c² β̄_c ⊙ (Dᴴ r_c) (with respect to ℓ̄, Wirtinger; the
    /// real gradient in (ρ, θ) is 2(Re g, Im g)), and Qᴴ D. In Q's basis P⊥ keeps the rows from
    /// K on, so (P⊥D)ᴴ(P⊥D) = (QᴴD)_bottomᴴ (QᴴD)_bottom and Dᴴ r_c = (QᴴD)ᴴ (Qᴴ r_c).
    fn gauss_newton(&self, weights: &[f64]) -> (DMatrix<C64>, DVector<C64>, Vec<Vec<C64>>) {
        let k = self.log_w.len();
        let qd = self.q_adjoint_derivatives();
        let mut q = DMatrix::<C64>::zeros(k, k);
        for j in 0..k {
            // Four columns at a time ([`dot_conj_four`]), the rest one by one.
            let mut l = j;
            while l + 4 <= k {
                let dots = dot_conj_four(
                    &qd[j][k..],
                    [
                        &qd[l][k..],
                        &qd[l + 1][k..],
                        &qd[l + 2][k..],
                        &qd[l + 3][k..],
                    ],
                );
                for (o, v) in dots.into_iter().enumerate() {
                    q[(j, l + o)] = v;
                    q[(l + o, j)] = v.conj();
                }
                l += 4;
            }
            for l in l..k {
                let v = dot_conj(&qd[j][k..], &qd[l][k..]);
                q[(j, l)] = v;
                q[(l, j)] = v.conj();
            }
        }
        let channels = self.beta.ncols();
        let s = DMatrix::from_fn(k, k, |j, l| {
            let mix: C64 = (0..channels)
                .map(|c| self.beta[(j, c)].conj() * self.beta[(l, c)] * weights[c] * weights[c])
                .sum();
            q[(j, l)] * mix
        });
        let g = DVector::from_fn(k, |j, _| {
            -(0..channels)
                .map(|c| {
                    self.beta[(j, c)].conj()
                        * dot_conj(&qd[j], &self.q_resid[c])
                        * weights[c]
                        * weights[c]
                })
                .sum::<C64>()
        });
        (s, g, qd)
    }
}

/// Outcome of the Levenberg–Marquardt refinement of one band.
#[derive(Clone, Debug)]
struct Refined {
    log_w: Vec<C64>,
    iterations: usize,
    /// Every pole's last step was below its tolerance.
    converged: bool,
    /// Each pole's last accepted step, in standard deviations (∞ if none was accepted).
    last_step_sigma: Vec<f64>,
    cost_start: f64,
    cost_end: f64,
}

/// Variable-projection Levenberg–Marquardt on the log-poles of one band (module docs; the driver
/// is [`crate::numerics::lm`], on the complex log-poles); the first `reported` poles are the
/// band's modes, the rest nuisance poles. `None` if the start itself cannot be evaluated.
fn refine_poles(
    y: &[Vec<C64>],
    weights: &[f64],
    start: &[C64],
    reported: usize,
    options: &ExtractOptions,
) -> Option<Refined> {
    let model = BandModel::new(y, start)?;
    let cost_start = model.cost(weights);
    let tolerance: Vec<f64> = (0..start.len())
        .map(|k| {
            let factor = if k < reported {
                1.0
            } else {
                NUISANCE_TOLERANCE_FACTOR
            };
            factor * options.step_tolerance
        })
        .collect();
    let settings = lm::Settings {
        damping: lm::Damping {
            start: LM_LAMBDA_START,
            min: LM_LAMBDA_MIN,
            max: LM_LAMBDA_MAX,
            shrink: 10.0,
            grow: 10.0,
        },
        max_iterations: options.max_iterations,
        accept: lm::Accept::Decrease,
        solve: lm::Solve::Scaled,
        stopping: lm::Stopping {
            step_sigma: Some(tolerance),
            ..lm::Stopping::default()
        },
    };
    let mut fit = PoleFit {
        y,
        weights,
        log_w: start.to_vec(),
        model,
        trial: None,
    };
    let outcome = lm::minimise(&mut fit, cost_start, &settings);
    Some(Refined {
        log_w: fit.log_w,
        iterations: outcome.iterations,
        // No pole with any amplitude (nothing to move) counts as converged.
        converged: matches!(
            outcome.stop,
            lm::Stop::Converged(_) | lm::Stop::NothingToMove
        ),
        last_step_sigma: outcome
            .step_sigma
            .unwrap_or_else(|| vec![f64::INFINITY; start.len()]),
        cost_start,
        cost_end: outcome.cost,
    })
}

/// [`refine_poles`]' problem: the band's data and weights, the current log-poles with their
/// model, and the last trial.
struct PoleFit<'a> {
    y: &'a [Vec<C64>],
    weights: &'a [f64],
    log_w: Vec<C64>,
    model: BandModel,
    trial: Option<(Vec<C64>, BandModel)>,
}

impl lm::Problem for PoleFit<'_> {
    type Scalar = C64;

    fn normal_equations(&mut self) -> Option<lm::NormalEquations<C64>> {
        let (h, g, _) = self.model.gauss_newton(self.weights);
        Some(lm::NormalEquations { h, g })
    }

    fn trial(&mut self, step: &DVector<C64>) -> Option<f64> {
        let trial: Vec<C64> = self
            .log_w
            .iter()
            .zip(step.iter())
            .map(|(l, dl)| l + dl)
            .collect();
        let model = BandModel::new(self.y, &trial)?;
        let cost = model.cost(self.weights);
        self.trial = Some((trial, model));
        Some(cost)
    }

    fn accept(&mut self) {
        if let Some((log_w, model)) = self.trial.take() {
            self.log_w = log_w;
            self.model = model;
        }
    }
}

/// σ̂_c², the full-rate white-noise variance of each channel from the band residual, corrected
/// for the filter's noise spectrum and the degrees of freedom (module docs, "Noise"), floored at
/// the rounding level of the channel's power.
fn residual_noise(
    model: &BandModel,
    weights: &[f64],
    log_w: &[C64],
    dec: &Decimator,
    noise_gain: f64,
    power: &[f64],
) -> Vec<f64> {
    let n_d = model.q_resid.first().map_or(0, |q| q.len()) as f64;
    let levels: Vec<f64> = log_w.iter().map(|l| noise_spectrum(dec, l.im)).collect();
    (0..model.beta.ncols())
        .map(|c| {
            let removed: f64 = (0..model.beta.nrows())
                .map(|k| {
                    let total: f64 = (0..model.beta.ncols())
                        .map(|c2| weights[c2] * weights[c2] * model.beta[(k, c2)].norm_sqr())
                        .sum();
                    let own = weights[c] * weights[c] * model.beta[(k, c)].norm_sqr();
                    let share = if total > 0.0 { own / total } else { 0.0 };
                    levels[k] * (1.0 + share)
                })
                .sum();
            let dof = n_d * noise_gain - removed;
            let floor = estimate::ROUNDING_FLOOR * estimate::ROUNDING_FLOOR * power[c];
            if dof > 0.0 {
                (model.energy[c] / dof).max(floor)
            } else {
                // More parameters than the band's noise can pin down: no estimate.
                f64::INFINITY
            }
        })
        .collect()
}

/// S(ν) = (1/D) Σ_{a=0}^{D−1} |H(e^(i(θ + 2π a)/D))|² for a baseband angle θ per decimated sample
/// (θ = 2π ν / f_d): the filtered, decimated spectrum of unit white noise at full rate.
fn noise_spectrum(dec: &Decimator, theta: f64) -> f64 {
    let factor = dec.factor as f64;
    (0..dec.factor)
        .map(|a| {
            let omega = (theta + 2.0 * std::f64::consts::PI * a as f64) / factor;
            dec.response(C64::from_polar(1.0, omega)).norm_sqr()
        })
        .sum::<f64>()
        / factor
}

/// Σ_j j h[j] ζ^j = ζ H'(ζ) (Horner).
fn response_log_derivative(dec: &Decimator, zeta: C64) -> C64 {
    dec.taps
        .iter()
        .enumerate()
        .rev()
        .fold(C64::new(0.0, 0.0), |acc, (j, &h)| acc * zeta + h * j as f64)
}

/// E_c ≈ |c_c|²/2 · Σ_n e^(−2dn/f_s) per channel (as in the estimate).
fn energies(log_z: C64, coeffs: &[C64], n: usize) -> Vec<f64> {
    let env = lsq::envelope_energy(log_z, n);
    coeffs.iter().map(|c| 0.5 * c.norm_sqr() * env).collect()
}

/// The Gauss–Newton covariance of one band's parameters (module docs, "Covariance").
#[derive(Clone, Debug)]
struct BandCovariance {
    /// E[δℓ δℓᴴ], K × K.
    log_w: DMatrix<C64>,
    /// E|δβ_{kc}|², K × C.
    beta_var: DMatrix<f64>,
    /// E[δβ_{kc} δℓ̄_k], K × C.
    beta_log_w: DMatrix<C64>,
}

/// The covariance for complex noise variances `centre_var` (ŝ_c², per decimated sample).
fn covariance(model: &BandModel, centre_var: &[f64]) -> BandCovariance {
    let weights: Vec<f64> = centre_var
        .iter()
        .map(|&v| if v > 0.0 { 1.0 / v.sqrt() } else { 0.0 })
        .collect();
    let (s, _, qd) = model.gauss_newton(&weights);
    let s_inv = hermitian_inverse(&s);
    let k = s.nrows();
    let channels = model.beta.ncols();
    // A⁺ D = R⁺ (QᴴD)_top and (AᴴA)⁺ = R⁺ R⁺ᴴ.
    let pinv_d = DMatrix::from_fn(k, k, |i, j| {
        (0..k).map(|l| model.r_pinv[(i, l)] * qd[j][l]).sum::<C64>()
    });
    let gram_inv_diag: Vec<f64> = (0..k)
        .map(|i| (0..k).map(|j| model.r_pinv[(i, j)].norm_sqr()).sum())
        .collect();
    let mut beta_var = DMatrix::<f64>::zeros(k, channels);
    let mut beta_log_w = DMatrix::<C64>::zeros(k, channels);
    for c in 0..channels {
        // E_c = A⁺D diag(β_c); E_c S⁻¹.
        let e = DMatrix::from_fn(k, k, |i, j| pinv_d[(i, j)] * model.beta[(j, c)]);
        let es = &e * &s_inv;
        for i in 0..k {
            let quad: C64 = (0..k).map(|j| es[(i, j)] * e[(i, j)].conj()).sum();
            beta_var[(i, c)] = centre_var[c] * gram_inv_diag[i] + quad.re;
            beta_log_w[(i, c)] = -es[(i, i)];
        }
    }
    BandCovariance {
        log_w: s_inv,
        beta_var,
        beta_log_w,
    }
}

/// Inverse of a Hermitian positive semi-definite matrix: Jacobi-scaled Cholesky, or an
/// eigen-decomposition whose small eigenvalues are raised to [`PSEUDO_INVERSE_FLOOR`] of the
/// largest.
fn hermitian_inverse(s: &DMatrix<C64>) -> DMatrix<C64> {
    let k = s.nrows();
    let diag: Vec<f64> = (0..k).map(|i| s[(i, i)].re).collect();
    let top = diag.iter().cloned().fold(0.0, f64::max);
    let scale: Vec<f64> = diag
        .iter()
        .map(|&v| {
            1.0 / v
                .max(PSEUDO_INVERSE_FLOOR * top)
                .max(f64::MIN_POSITIVE)
                .sqrt()
        })
        .collect();
    let scaled = DMatrix::from_fn(k, k, |i, j| s[(i, j)] * scale[i] * scale[j]);
    let inv = match Cholesky::new(scaled.clone()) {
        Some(ch) => ch.inverse(),
        None => {
            let Some(eig) = SymmetricEigen::try_new(scaled, f64::EPSILON, 1000 * k.max(10)) else {
                // The scaled matrix has a unit diagonal: this is a variance of 1e13 per unit of
                // each parameter's conditional variance, i.e. "unknown".
                let inv =
                    DMatrix::from_diagonal_element(k, k, C64::new(1.0 / PSEUDO_INVERSE_FLOOR, 0.0));
                return DMatrix::from_fn(k, k, |i, j| inv[(i, j)] * scale[i] * scale[j]);
            };
            let big = eig.eigenvalues.iter().cloned().fold(0.0, f64::max);
            let floor = (PSEUDO_INVERSE_FLOOR * big).max(f64::MIN_POSITIVE);
            let v = &eig.eigenvectors;
            let inv_eig = DMatrix::from_fn(k, k, |i, j| {
                if i == j {
                    C64::new(1.0 / eig.eigenvalues[i].max(floor), 0.0)
                } else {
                    C64::new(0.0, 0.0)
                }
            });
            v * inv_eig * v.adjoint()
        }
    };
    DMatrix::from_fn(k, k, |i, j| inv[(i, j)] * scale[i] * scale[j])
}
