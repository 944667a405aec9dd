//! Chirp-aware modal extraction: one gliding mode instead of a cluster of constant poles.
//!
//! # Why
//!
//! A mode whose pitch glides while it decays, f(t) = f₀ (1 + g e^(−2dt)) (a Duffing-like shift
//! ∝ the mode's energy, g the relative offset at t = 0, free sign), is not a damped exponential.
//! ESPRIT and the refinement of [`super`] approximate it by two or more constant poles a few Hz
//! apart, and everything downstream then reads the approximation as physics: a split pair
//! (beating), early residual energy (reverb), wrong amplitudes (contact). This stage, run on the
//! extraction's output, fits each mode (or each cluster of poles within a few Hz) as one gliding
//! mode and lets a likelihood criterion decide between that and the constant poles.
//!
//! # Model
//!
//! Channel c of the recording (sample n, t = n / f_s, N samples) near one mode:
//!
//! x_c(t) = Im(c_c s(t)) + (other modes, noise),   s(t) = e^(−d t + i θ(t)),
//! θ(t) = 2π f₀ (t + g Φ(t)),   Φ(t) = ∫₀ᵗ e^(−2dτ) dτ = (1 − e^(−2dt)) / (2d)   [s],
//!
//! the exact phase of f(t) = f₀ (1 + g e^(−2dt)) ([`glide_phase`]); f₀ [Hz] is the
//! small-amplitude (late) frequency, d [1/s] the amplitude decay rate, g [1] the relative glide
//! at t = 0, and c_c = a_c e^(iφ_c) the complex amplitude per channel (the mode is
//! a_c e^(−dt) sin(θ(t) + φ_c), the extraction's convention; g = 0 is the extraction's mode).
//! (f₀, d, g) are shared by the channels and nonlinear; c_c is linear.
//!
//! # Data: a band of DFT bins
//!
//! The fit uses the unitary DFT X_c[k] = N^(−½) Σ_n r_c[n] e^(−2πikn/N) of the recording minus
//! every *other* extracted mode (resynthesised at full rate; the group's own poles are put
//! back), over the first N = min(N_total, 12 f_s / d_min) samples (rounded up to whole blocks
//! of 960: after twelve decay times of the group's slowest pole its amplitude is e^(−12), and
//! the shorter FFTs are what keeps the stage fast), on the bins k of a band around the group: from the lowest pole frequency minus W to
//! the highest plus W, W = 8/T + 4 d/(2π) + 0.3 % f (T = N/f_s; the line's half width, the
//! widest glide, eight bins), at most [`GlideOptions::max_band_hz`] on either side. The
//! model's DFT is computed exactly (the same truncation as the data; a constant component's in
//! closed form over the band's bins, a gliding one's by the DFT of its samples at the band's
//! bins, which come from recurrences restarted exactly every 960 samples:
//! [`Spectra::transforms`]; that DFT by decimation in time, [`BandDft`], when it is cheaper
//! than the whole FFT):
//! with S = DFT(s), Im(c s) has DFT p V[k] + q U[k], c = p + iq, where
//! U[k] = (S[k] + conj S[N−k]) / 2 and V[k] = (S[k] − conj S[N−k]) / (2i) are the DFTs of Re s
//! and Im s. Real and imaginary parts of the band's bins are stacked into real vectors of
//! length n_b = 2M (M bins). Four nuisance columns per channel — a complex constant and a
//! complex linear trend over the band — take up the slowly varying tails of everything outside
//! the band (unmodelled low-frequency content, errors of the subtracted neighbours).
//!
//! White noise of variance σ_c² per sample gives independent bins of complex variance σ_c²
//! (real and imaginary parts σ_c²/2 each), so in the band the noise is white whatever the rest
//! of the spectrum does (pink noise is locally white over a band of tens of Hz).
//!
//! # Fit: variable projection and Gauss–Newton covariance
//!
//! With B(ϑ) the n_b × L matrix of the model's real columns (two per component, four nuisance)
//! and weights w_c = 2/σ̂_c², the cost F(ϑ) = Σ_c w_c ‖P⊥(ϑ) y_c‖² depends on the nonlinear
//! parameters ϑ alone (the linear ones are b_c = B⁺ y_c; B⁺ by SVD, singular values below 1e-12
//! of the largest dropped). Levenberg–Marquardt on Kaufman's Jacobian
//! J_c = −P⊥ (∂B/∂ϑ) b_c, with ∂s/∂f₀ = i 2π (t + gΦ) s, ∂s/∂d = (−t + i 2π f₀ g ∂Φ/∂d) s
//! (∂Φ/∂d = (t e^(−2dt) − Φ)/d), ∂s/∂g = i 2π f₀ Φ s; the step (H + λ diag H) δ = −Σ_c w_c J_cᵀ r_c,
//! H = Σ_c w_c J_cᵀ J_c, converges when the undamped Gauss–Newton step δ = −H⁻¹∇ is below
//! [`GlideOptions::step_tolerance`] in its Mahalanobis norm √(δᵀHδ) (standard deviations of
//! the whole parameter vector: f₀ and g share a narrow valley, along which a test per
//! parameter in conditional standard deviations 1/√H_jj stops far too early). The noise is then
//! re-estimated from the residual, σ̂_c² = 2 ‖r_c‖² / (n_b − L − P/C) (P nonlinear parameters
//! shared by C channels), and the fit repeated once with the new weights. The covariance of ϑ
//! is H⁻¹ (Gauss–Newton, first order); that of b_c is (σ̂_c²/2)(BᵀB)⁺ + E_c H⁻¹ E_cᵀ,
//! E_c = B⁺ (∂B/∂ϑ) b_c, mapped to a_c = |c_c| and φ_c = arg c_c to first order. Hence
//! σ_f₀ [Hz], σ_d [1/s], σ_g [1].
//!
//! # Criterion: one gliding mode or K constant poles
//!
//! For a group of K poles (K ≥ 1: chained neighbours within [`GlideOptions::group_rtol`] of
//! each other, at least one at or above [`GlideOptions::min_snr_db`]) the same band data are
//! fitted under: (a) K constant components (g = 0), started at the extraction's poles; (b) K'
//! gliding components, K' ∈ {1, 2, K}, each with its own (f₀, d, g): K' = 1 started from the
//! loudest pole, and from the lowest pole with g = +spread and the highest with g = −spread
//! (spread = (f_max − f_min)/f_min); K' = 2 < K from the two loudest poles; K' = K from every
//! pole (a near-degenerate pair of modes that both glide); each K' ≥ 2 both with g = 0 and
//! with every g at the best K' = 1 fit's ĝ (the glide at the onset can exceed a pair's
//! spacing many times over, and from g = 0 a component is caught by the wrong pole), the
//! lower BIC kept. Then *forward addition*: from the best hypothesis with fewer than K
//! components, one more gliding component is started at each pole (at g = 0 and at the fit's
//! glide ĝ) or one DFT bin beside each fitted component (a near-degenerate partner); the
//! [`FORWARD_STARTS`] starts of lowest cost as started are fitted, and the best fit enters if
//! it lowers the BIC, until a step lowers none or K components are reached. A near-degenerate
//! pair of gliding modes lies inside one ladder of poles, so started at the two loudest poles
//! its second component is caught by a rung (generator 2's seed 73: a tube's pair at 2307.17
//! and 2306.58 Hz gliding 9.4·10⁻³ and 2.9·10⁻³, found from the two fit microphones, came out
//! of the one held-out microphone as four near-constant poles of g ≤ 3.7·10⁻³ decaying at
//! 10–102 1/s; a cup's mode gliding 7.9·10⁻³ came out beside a component of g = −6.5·10⁻³, and
//! the catalogue read the pair as a support). Each hypothesis h with P_h nonlinear
//! and L_h C linear parameters scores the Bayesian information criterion of its profile
//! likelihood (unknown noise per channel):
//!
//! BIC_h = Σ_c n_b ln(‖r_{c,h}‖² / n_b) + (P_h + L_h C) ln(n_b C),
//!
//! and with ΔBIC = BIC_const − min_h BIC_glide > [`GlideOptions::bic_margin`] the best gliding
//! hypothesis replaces the poles. For K' = K the hypotheses are nested (every g = 0), and
//! ΔBIC > 0 is then a likelihood-ratio test at χ²_K > K ln(n_b C) (one pole: |z| ≳ 2.2–2.6 for
//! 50–500 band values). One glide in place of K ≥ 2 poles needs 2(K−1)(1 + C) − 1 fewer
//! parameters: a true beating pair (two constant poles whose sum beats) cannot be produced by
//! one glide and keeps its poles, a gliding mode that the extraction broke into poles becomes
//! one mode again. Every mode that ends up as a component carries its g and σ_g; poles that
//! stay constant carry those of the K' = K fit (nested: an unbiased measurement, about 0 ± σ_g
//! for a mode that does not glide).
//!
//! A gliding hypothesis must also be *identified* to replace the poles: no component broken
//! ([`glide_component_sound`]: |g| short of the ±`max_glide` bound, σ_g finite, the decay rate
//! within a factor 4 of the group's poles'), and at least one component's |g| at least
//! [`GlideOptions::min_glide_z`] σ_g (weak partners of a gliding group may carry a loose g).
//! A component whose fit ran to the bound or to d → 0 (where f₀ and g trade off and σ_g
//! explodes) is the model absorbing something else (a neighbour's leakage, a reverberant
//! tail, noise), not a measured glide; on the real bowl the unguarded stage marked 42 of 80
//! poles as gliding, several at the bound.
//!
//! # Groups
//!
//! Poles chain into a group when each is within [`GlideOptions::group_rtol`] of the next. A
//! wide glide breaks further apart: e^(i c e^(−2dt)) = Σₙ (ic)ⁿ/n! e^(−2ndt) (c = π f₀ g / d), so
//! the extraction approximates it by a ladder of poles decaying at (2n + 1) d, spread over a
//! good part of the onset offset g f₀ (a cup's loudest mode at 891 Hz gliding 1.05 %: poles at
//! 890.6, 891.8 and 895.7 Hz decaying at 6.5, 17.6 and 38.4 1/s, the last 0.43 % from its
//! neighbour). So two neighbouring chained groups are one group when together they span at
//! most [`GlideOptions::ladder_rtol`] and the group without the slowest pole decays at least
//! twice as fast as it (every rung above the fundamental decays at least 3 d); distinct modes
//! that merge this way keep their constant poles by the criterion below.
//!
//! Groups of more than [`GlideOptions::max_group`] poles are left alone, and so are groups
//! whose every pole lies above [`GlideOptions::max_frequency_hz`] when it is set. The diagnosis
//! sets its own highest frequency there, since it discards every mode above it; those poles
//! stay in the extraction as constant poles, which is how the residual envelopes above that
//! frequency see them. On a plate in a room (generator 2's seed 103 case 012, 1 s at 48 kHz,
//! diagnosed to 12 kHz) the fit microphone's stage tried 32 groups instead of 59, most of the
//! others room combs between 12 and 20 kHz, and took 41 s instead of 60; the verdicts of all
//! 24 cases of that seed were unchanged. Groups are processed loudest first; once one is
//! decided for glides, they replace the extraction's poles in the residual that later groups
//! see.
//!
//! # Accuracy and cost (measured)
//!
//! Tests in this module (release build, one core; 0.5 s at 16 kHz, three channels, white noise
//! σ = 0.01 against amplitudes 0.4–1):
//!
//! * Calibration: 60 draws of one gliding mode (2 kHz, d = 8 1/s, g = 0.3 %) started from one
//!   constant pole: the glide wins every time; z-scores (estimate − truth)/σ have mean +0.20,
//!   −0.07, −0.21 and standard deviation 0.95, 0.96, 0.88 for f₀, d, g.
//! * A constant mode (1.8 kHz, d = 6 1/s), 200 draws: g/σ_g has mean +0.13 and standard
//!   deviation 1.06; the glide was selected in 9 of 200 (4.5 %; the χ²₁ reference at this
//!   band's threshold ln(n_b C) ≈ 5.0 is 2.5 %). On other seeds, 100 draws each: 3, 1, 5, 6
//!   and (seed 99) 12 of 100, z standard deviation 0.97–1.25.
//! * A glide the extraction broke into two poles is merged (ΔBIC > 10, g and f₀ within 4σ);
//!   a true pair 1.6 Hz apart at 2.5 kHz stays two constant poles in 5 of 5 draws.
//! * The bowl benchmark (1 s at 48 kHz, 3 channels, 7–20 groups): 2.5–80 s per extraction,
//!   most of it in groups of 4–5 poles with low decay rates (full-length FFTs, up to 8
//!   hypotheses), measured before the closed form and the recurrences. They took the stage
//!   from 53.8 to 21.1 s on a reverberant tube recording (generator 2, seed 83 case 002: 54
//!   groups; a sin/cos and an expm1 per sample had been 40 % of it), its report unchanged. The
//!   arithmetic differs by 10⁻¹³, and near-singular groups follow it into other local optima:
//!   on the real bowl a six-pole group at 19.5 kHz moved its f₀ by up to 6 Hz, and a
//!   three-pole group at 11.15 kHz gained a covariance it had lacked. Near-degenerate gliding
//!   pairs come out with g within 10⁻⁶ of the injected one; the weak partner of a pair, or a
//!   component the K' = K hypothesis adds for unmodelled residual, can come out with a poorly
//!   determined f₀ and g (large σ).
//! * Then the sampled path's own arithmetic: `perf` on a gliding plate (generator 2, seed 103
//!   case 001, 25 groups per microphone set) put 17 % of the whole case's CPU time in the
//!   Taylor rotation's ten chained divisions. Horner's form with constant inverse factorials,
//!   1/d multiplied instead of divided, and the rows and FFT scratch kept between evaluations
//!   took the stage from 25.5 to 20.2 s (fit microphone) and 29.2 to 24.1 s (held-out); the
//!   FFTs are now about a quarter of it. Re-run in full, the 24 cases of seed 101 gave the
//!   verdicts of the previous build, and so did seed 103's cases 001, 012 and 023.
//! * Then the band's bins alone ([`BandDft`]: Q transforms of a fast length P = N/Q and a sum
//!   of Q terms per bin, 0.45–0.8 of the whole FFT's time): on a plate in a room (generator 2,
//!   seed 433 case 023, 56 and 50 groups, 31 % of whose fits ran to the 30-step limit) the
//!   stage went from 48.2 to 43.4 s (fit microphones) and 51.7 to 48.2 s (held-out).

use std::cell::RefCell;
use std::f64::consts::PI;
use std::sync::Arc;

use nalgebra::{DMatrix, DVector, SVD};
use rustfft::num_complex::Complex64 as C64;
use rustfft::{Fft, FftPlanner};

use super::{ExtractError, ModalExtraction};
use crate::analysis::mode::{
    phase_sd, sd_from_variance, MeasuredMode, ModeSd, Refinement, UNIFORM_PHASE_SD,
};
use crate::numerics::band_dft::BandDft;
use crate::numerics::lm::{self, symmetric_inverse};
use crate::numerics::map_on_threads;

/// Singular values of B below this fraction of the largest are dropped.
const SVD_CUTOFF: f64 = 1e-12;
/// Levenberg–Marquardt damping: start and bounds (relative to diag H).
const LM_LAMBDA_START: f64 = 1e-3;
const LM_LAMBDA_MAX: f64 = 1e10;
/// Nuisance columns per channel: complex constant and complex linear trend over the band.
const NUISANCE_COLUMNS: usize = 4;
/// A group is fitted on this many decay times of its slowest pole (amplitude e^(−12)) …
const FIT_SPAN_DECAYS: f64 = 12.0;
/// … but on at least this span [s] …
const MIN_FIT_SPAN_S: f64 = 0.05;
/// … in whole blocks of this many samples (a smooth FFT length: 2⁶·3·5), at most N.
const FFT_BLOCK: usize = 960;
/// Below this 2dt, Φ and ∂Φ/∂d by their series (the closed forms cancel).
const SERIES_BELOW: f64 = 1e-3;

/// Settings of [`fit_glides`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GlideOptions {
    /// Groups whose loudest pole is below this SNR (dB, the extraction's) are left alone.
    pub min_snr_db: f64,
    /// Neighbouring poles closer than this fraction of their frequency form one group
    /// (default 0.004, the widest glide the benchmark injects is 0.5 %).
    pub group_rtol: f64,
    /// Neighbouring groups whose poles span at most this fraction of their frequency are one
    /// group when they form a ladder (module docs, "Groups"; default 0.015).
    pub ladder_rtol: f64,
    /// Largest group of poles tried (default 6: a near-degenerate pair of gliding modes can come
    /// out of the extraction as five poles).
    pub max_group: usize,
    /// Largest half-width W of the band beyond the group's poles, Hz (default 80).
    pub max_band_hz: f64,
    /// Levenberg–Marquardt steps per fit (default 30).
    pub max_iterations: usize,
    /// Converged when the Gauss–Newton step is below this many standard deviations, in its
    /// Mahalanobis norm (default 1e-3).
    pub step_tolerance: f64,
    /// Steps to |g| above this are refused (default 0.05).
    pub max_glide: f64,
    /// ΔBIC = BIC(constant poles) − BIC(glide) above which the glide is selected (default 0).
    pub bic_margin: f64,
    /// At least one gliding component must have |g| ≥ this many σ_g for the glide to be
    /// selected (default 3; module docs, identification).
    pub min_glide_z: f64,
    /// Groups whose lowest pole lies above this frequency (Hz) are left alone (module docs,
    /// "Groups"); default none. The diagnosis sets its own highest frequency here when the
    /// configuration does not: modes above it are never diagnosed.
    pub max_frequency_hz: Option<f64>,
    /// Threads that fit a group's hypotheses at once; none: one. The answer does not depend
    /// on it. Unset, the `diagnose` job sets its ranks' count (at most the cores here): each
    /// microphone set is extracted on its own rank, and the rank that finishes first sleeps.
    pub threads: Option<usize>,
}

impl Default for GlideOptions {
    fn default() -> Self {
        GlideOptions {
            min_snr_db: 20.0,
            group_rtol: 0.004,
            ladder_rtol: 0.015,
            max_group: 6,
            max_band_hz: 80.0,
            max_iterations: 30,
            step_tolerance: 1e-3,
            max_glide: 0.05,
            bic_margin: 0.0,
            min_glide_z: 3.0,
            max_frequency_hz: None,
            threads: None,
        }
    }
}

/// The glide of one extracted mode (module docs).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ModeGlide {
    /// g, relative frequency offset at t = 0 of f(t) = f₀ (1 + g e^(−2dt)) [1].
    pub glide: f64,
    /// σ_g [1].
    pub glide_sd: f64,
    /// The gliding model won the criterion: the mode's f (= f₀), d, amplitudes and phases are
    /// the glide fit's and it is rendered gliding. Otherwise g is a measurement only and the
    /// mode keeps the extraction's constant-pole values.
    pub selected: bool,
    /// Poles of the extraction this mode stands for (≥ 2: merged).
    pub merged_poles: usize,
    /// ΔBIC = BIC(constant poles) − BIC(glide) on the group's band (> margin: glide).
    pub delta_bic: f64,
}

/// θ(t) = 2π f₀ (t + g (1 − e^(−2dt))/(2d)) [rad]: the exact phase of f(t) = f₀(1 + g e^(−2dt)).
pub fn glide_phase(f0: f64, decay: f64, glide: f64, t: f64) -> f64 {
    2.0 * PI * f0 * (t + glide * phi_integral(decay, t).0)
}

/// Φ(t) = (1 − e^(−2dt))/(2d) [s] and ∂Φ/∂d [s²].
fn phi_integral(d: f64, t: f64) -> (f64, f64) {
    let x = 2.0 * d * t;
    // Φ = t·(−expm1(−x)/x) is exact down to x → 0 (where Φ → t); the generator renders its
    // glides with this same function (`inject::glide_phase`).
    let phi = if x.abs() < 1e-300 {
        t
    } else {
        t * (-(-x).exp_m1() / x)
    };
    (phi, phi_decay_derivative(d, t, phi, (-x).exp()))
}

/// ∂Φ/∂d [s²] at t from Φ(t) and e^(−2dt) (`decayed`), whichever way they were computed.
fn phi_decay_derivative(d: f64, t: f64, phi: f64, decayed: f64) -> f64 {
    let x = 2.0 * d * t;
    if x.abs() < SERIES_BELOW {
        phi_decay_series(t, x)
    } else {
        (t * decayed - phi) / d
    }
}

/// [`phi_decay_derivative`] with 1/d given: the sampled path's per-sample form (a division
/// per sample is a visible share of its cost).
fn phi_decay_derivative_fast(d: f64, inv_d: f64, t: f64, phi: f64, decayed: f64) -> f64 {
    let x = 2.0 * d * t;
    if x.abs() < SERIES_BELOW {
        phi_decay_series(t, x)
    } else {
        (t * decayed - phi) * inv_d
    }
}

/// (t e^(−x) − Φ)/d cancels for small x = 2dt: ∂Φ/∂d = 2t² h'(x), h(x) = (1 − e^(−x))/x,
/// h' = −½ + x/3 − x²/8.
fn phi_decay_series(t: f64, x: f64) -> f64 {
    2.0 * t * t * (-0.5 + x / 3.0 - x * x / 8.0)
}

/// Renders a_c e^(−dt) sin(θ(t) + φ) with the glide phase into `out` (added), N samples at f_s.
pub fn add_gliding_mode(
    out: &mut [f64],
    sample_rate: f64,
    f0: f64,
    decay: f64,
    glide: f64,
    amplitude: f64,
    phase: f64,
) {
    for (n, v) in out.iter_mut().enumerate() {
        let t = n as f64 / sample_rate;
        *v += amplitude * (-decay * t).exp() * (glide_phase(f0, decay, glide, t) + phase).sin();
    }
}

/// One component of a band model.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Component {
    f: f64,
    d: f64,
    g: f64,
    /// g is a free parameter (else fixed at its value, 0 for a constant pole).
    glide_free: bool,
}

impl Component {
    fn n_params(&self) -> usize {
        if self.glide_free {
            3
        } else {
            2
        }
    }
}

/// The FFT and everything the components' spectra need.
struct Spectra {
    fft: Arc<dyn Fft<f64>>,
    n: usize,
    sample_rate: f64,
    /// The band's transform by decimation ([`BandDft`]) when it beats the whole FFT; the
    /// sampled rows then go through it instead of `fft`.
    band: Option<BandDft>,
}

/// The buffers of [`Spectra::transforms`]: the sampled path's rows, the FFT's scratch and the
/// band transform's work.
#[derive(Default)]
struct SpectraWork {
    rows: Vec<Vec<C64>>,
    scratch: Vec<C64>,
    band: Vec<C64>,
}

thread_local! {
    /// Each thread's [`SpectraWork`], kept between evaluations: a group's fits take hundreds,
    /// and fresh zeroed buffers of N samples for each were a few per cent of the stage's time.
    /// Per thread, so that the hypotheses of a group can be fitted on several at once.
    static SPECTRA_WORK: RefCell<SpectraWork> = RefCell::new(SpectraWork::default());
}

/// Samples between exact re-evaluations of the recurrences in [`Spectra::transforms`]: their
/// rounding grows by about one ulp per step, so a block keeps it near 10⁻¹³.
const RECURRENCE_BLOCK: usize = 960;
/// A constant component (g = 0) whose decay over the fitted span, N d / f_s, is at least this
/// has its band spectrum in closed form ([`Spectra::closed_form`]); below it the geometric
/// sums' differences cancel and the sampled path is used.
const CLOSED_FORM_MIN_DECAY: f64 = 0.5;
/// |δ| up to which e^(iδ) is its Taylor polynomial (degree 11: error below 10⁻¹⁷).
const TAYLOR_ROTATION_MAX: f64 = 0.2;

/// e^z − 1 for complex z, without cancellation for small |z|.
fn cexpm1(z: C64) -> C64 {
    let half = (0.5 * z.im).sin();
    C64::new(
        z.re.exp_m1() * z.im.cos() - 2.0 * half * half,
        z.re.exp() * z.im.sin(),
    )
}

/// e^(iδ) for a small angle δ (|δ| ≤ [`TAYLOR_ROTATION_MAX`]) by its Taylor series, exactly
/// otherwise: the glide phase's per-sample increment, which a sin/cos per sample made the
/// stage's largest cost.
fn small_rotation(delta: f64) -> C64 {
    if delta.abs() > TAYLOR_ROTATION_MAX {
        return C64::from_polar(1.0, delta);
    }
    taylor_rotation(delta)
}

/// e^(iδ) by its Taylor polynomial of degree 11 ([`small_rotation`] for |δ| ≤
/// [`TAYLOR_ROTATION_MAX`]).
#[inline(always)]
fn taylor_rotation(delta: f64) -> C64 {
    // Horner's scheme in δ² with the inverse factorials as constants: divisions in the loop
    // (the earlier nested form) cost as much as the rest of the sampling together.
    const C: [f64; 5] = [
        -1.0 / 2.0,
        1.0 / 24.0,
        -1.0 / 720.0,
        1.0 / 40_320.0,
        -1.0 / 3_628_800.0,
    ];
    const S: [f64; 5] = [
        -1.0 / 6.0,
        1.0 / 120.0,
        -1.0 / 5_040.0,
        1.0 / 362_880.0,
        -1.0 / 39_916_800.0,
    ];
    let x2 = delta * delta;
    let cos = 1.0 + x2 * (C[0] + x2 * (C[1] + x2 * (C[2] + x2 * (C[3] + x2 * C[4]))));
    let sin = delta * (1.0 + x2 * (S[0] + x2 * (S[1] + x2 * (S[2] + x2 * (S[3] + x2 * S[4])))));
    C64::new(cos, sin)
}

/// One transform over a band: (S[k], S[(N − k) mod N]) per band bin k.
type BandSpectrum = Vec<(C64, C64)>;

impl Spectra {
    fn new(fft: Arc<dyn Fft<f64>>, n: usize, sample_rate: f64) -> Spectra {
        Spectra {
            fft,
            n,
            sample_rate,
            band: None,
        }
    }

    /// The same, with the sampled rows transformed at `bins` alone by decimation when that is
    /// cheaper ([`BandDft::plan`]); [`Spectra::transforms`] must then be asked for `bins`.
    fn with_band(mut self, planner: &mut FftPlanner<f64>, bins: &[usize]) -> Spectra {
        self.band = BandDft::plan(planner, self.n, bins);
        self
    }

    /// Unitary DFT of the sampled s(t) of `comp` and, with `derivatives`, of ∂s/∂f, ∂s/∂d and
    /// (if g is free) ∂s/∂g, in that order, at the band's `bins` and their mirrors.
    fn transforms(&self, comp: &Component, derivatives: bool, bins: &[usize]) -> Vec<BandSpectrum> {
        if comp.g == 0.0 && self.n as f64 * comp.d / self.sample_rate >= CLOSED_FORM_MIN_DECAY {
            return self.closed_form(comp, derivatives, bins);
        }
        SPECTRA_WORK.with(|work| {
            let SpectraWork {
                rows,
                scratch,
                band: band_work,
            } = &mut *work.borrow_mut();
            self.sample(comp, derivatives, rows);
            scratch.resize(self.fft.get_inplace_scratch_len(), C64::new(0.0, 0.0));
            let n = self.n;
            let scale = 1.0 / (n as f64).sqrt();
            if let Some(band) = &self.band {
                debug_assert_eq!(
                    band.bins(),
                    bins,
                    "Spectra: asked for other bins than planned"
                );
                return rows
                    .iter()
                    .map(|v| {
                        let mut out = Vec::with_capacity(bins.len());
                        band.transform(v, band_work, scratch, &mut out);
                        out.iter_mut().for_each(|(a, b)| {
                            *a *= scale;
                            *b *= scale;
                        });
                        out
                    })
                    .collect();
            }
            rows.iter_mut()
                .map(|v| {
                    self.fft.process_with_scratch(v, scratch);
                    bins.iter()
                        .map(|&k| (v[k] * scale, v[(n - k) % n] * scale))
                        .collect()
                })
                .collect()
        })
    }

    /// The transforms of a constant component (g = 0) in closed form, O(bins) instead of an
    /// FFT: s[n] = zⁿ e^(2πikn/N) with ln z = λ_k = −d/f_s + i 2π (f/f_s − k/N), so
    /// S[k] = Σₙ zⁿ = (e^(Nλ) − 1)/(e^λ − 1), and with T[k] = Σₙ n zⁿ = dS/dλ
    /// = (N e^(Nλ)(e^λ − 1) − (e^(Nλ) − 1) e^λ)/(e^λ − 1)²:
    /// ∂s/∂f = i2πt s → i2π T/f_s; ∂s/∂d = −t s → −T/f_s (the g-terms vanish at g = 0);
    /// ∂s/∂g = i2πf Φ s, Φₙ = (1 − qⁿ)/(2d), q = e^(−2d/f_s) → i2πf (S(λ) − S(λ − 2d/f_s))/(2d).
    /// Every transform times N^(−½) (unitary).
    fn closed_form(
        &self,
        comp: &Component,
        derivatives: bool,
        bins: &[usize],
    ) -> Vec<BandSpectrum> {
        let count = if derivatives { 1 + comp.n_params() } else { 1 };
        let (n, fs) = (self.n as f64, self.sample_rate);
        let scale = 1.0 / n.sqrt();
        // f N / f_s − k, wrapped to (−N/2, N/2]: the bin offset whose 2π/N is λ's angle.
        let offset = |k: usize| {
            let x = comp.f * n / fs - k as f64;
            x - n * (x / n).round()
        };
        let sums = |x: f64, shift: f64| {
            let lambda = C64::new(-comp.d / fs - shift, 2.0 * PI * x / n);
            let (e1, en) = (cexpm1(lambda), cexpm1(lambda * n));
            let s = en / e1;
            let t = (n * (en + 1.0) * e1 - en * (e1 + 1.0)) / (e1 * e1);
            (s, t)
        };
        let mut out = vec![Vec::with_capacity(bins.len()); count];
        for &k in bins {
            let mirror = (self.n - k) % self.n;
            let at = |bin: usize| -> Vec<C64> {
                let x = offset(bin);
                let (s, t) = sums(x, 0.0);
                let mut v = vec![s * scale];
                if derivatives {
                    v.push(C64::new(0.0, 2.0 * PI / fs) * t * scale);
                    v.push(-t * scale / fs);
                    if comp.glide_free {
                        let (s_q, _) = sums(x, 2.0 * comp.d / fs);
                        v.push(
                            C64::new(0.0, 2.0 * PI * comp.f) * (s - s_q) * scale / (2.0 * comp.d),
                        );
                    }
                }
                v
            };
            let (direct, mirrored) = (at(k), at(mirror));
            for (j, row) in out.iter_mut().enumerate() {
                row.push((direct[j], mirrored[j]));
            }
        }
        out
    }

    /// Samples s(t) of any component into `out[0]` and, with `derivatives`, ∂s/∂f, ∂s/∂d and
    /// (if g is free) ∂s/∂g into the next rows, N samples each, for [`Spectra::transforms`]
    /// to transform. The samples come from recurrences (amplitude e^(−d/f_s) per step,
    /// e^(−2dt) − 1 by its expm1 step, the phase rotated by 2πf/f_s plus the glide's increment
    /// 2πfg (Φₙ₊₁ − Φₙ) = κ e^(−2dtₙ)), each restarted exactly every [`RECURRENCE_BLOCK`]
    /// samples. The blocks are therefore independent, and whole ones are advanced
    /// [`SAMPLE_LANES`] at a time ([`Sampler::blocks_in_lockstep`]).
    fn sample(&self, comp: &Component, derivatives: bool, out: &mut Vec<Vec<C64>>) {
        let count = if derivatives { 1 + comp.n_params() } else { 1 };
        // Every sample of every row is written below.
        out.resize_with(count, Vec::new);
        out.iter_mut()
            .for_each(|row| row.resize(self.n, C64::new(0.0, 0.0)));
        let sampler = Sampler::new(comp, self.sample_rate);
        let whole = self.n / RECURRENCE_BLOCK;
        let mut block = 0;
        while block + SAMPLE_LANES <= whole {
            sampler.blocks_in_lockstep(block * RECURRENCE_BLOCK, derivatives, out);
            block += SAMPLE_LANES;
        }
        while block * RECURRENCE_BLOCK < self.n {
            let start = block * RECURRENCE_BLOCK;
            let stop = (start + RECURRENCE_BLOCK).min(self.n);
            sampler.block(start, stop, derivatives, out);
            block += 1;
        }
    }
}

/// Whole recurrence blocks that [`Spectra::sample`] advances side by side, one lane each, so
/// that the compiler can keep them in vector registers. Each lane does the single block's
/// arithmetic in its order, so the samples are the same to the bit (test
/// `lockstep_blocks_sample_as_one_block_at_a_time`).
const SAMPLE_LANES: usize = 4;

/// One component's constants for the sampled path ([`Spectra::sample`]).
#[derive(Clone, Copy)]
struct Sampler {
    fs: f64,
    f: f64,
    d: f64,
    g: f64,
    half_inv_d: f64,
    inv_d: f64,
    /// e^(−d/f_s), e^(−2d/f_s) − 1, e^(2πif/f_s) and the glide increment's factor κ.
    decay_step: f64,
    c: f64,
    turn: C64,
    kappa: f64,
    glide_free: bool,
}

impl Sampler {
    fn new(comp: &Component, fs: f64) -> Sampler {
        let (f, d, g) = (comp.f, comp.d, comp.g);
        let c = (-2.0 * d / fs).exp_m1();
        Sampler {
            fs,
            f,
            d,
            g,
            half_inv_d: 0.5 / d,
            inv_d: 1.0 / d,
            decay_step: (-d / fs).exp(),
            c,
            turn: C64::from_polar(1.0, 2.0 * PI * f / fs),
            kappa: -2.0 * PI * f * g * c / (2.0 * d),
            glide_free: comp.glide_free,
        }
    }

    /// The recurrences' exact state at sample `start`: amplitude e^(−dt), m = e^(−2dt) − 1 and
    /// the phase's rotation.
    fn restart(&self, start: usize) -> (f64, f64, C64) {
        let t0 = start as f64 / self.fs;
        (
            (-self.d * t0).exp(),
            (-2.0 * self.d * t0).exp_m1(),
            C64::from_polar(1.0, glide_phase(self.f, self.d, self.g, t0)),
        )
    }

    /// ∂s/∂f, ∂s/∂d and ∂s/∂g at time t from the sample s and m = e^(−2dt) − 1.
    #[inline(always)]
    fn derivatives(&self, t: f64, m: f64, s: C64) -> [C64; 3] {
        let (f, d, g) = (self.f, self.d, self.g);
        let phi = if (2.0 * d * t).abs() < 1e-300 {
            t
        } else {
            -m * self.half_inv_d
        };
        let phi_d = phi_decay_derivative_fast(d, self.inv_d, t, phi, 1.0 + m);
        [
            s * C64::new(0.0, 2.0 * PI * (t + g * phi)),
            s * C64::new(-t, 2.0 * PI * f * g * phi_d),
            s * C64::new(0.0, 2.0 * PI * f * phi),
        ]
    }

    /// The phase's rotation from one sample to the next, given m at the first.
    #[inline(always)]
    fn step(&self, m: f64) -> C64 {
        if self.kappa == 0.0 {
            self.turn
        } else {
            self.turn * small_rotation(self.kappa * (1.0 + m))
        }
    }

    /// Samples start..stop, one at a time.
    fn block(&self, start: usize, stop: usize, derivatives: bool, out: &mut [Vec<C64>]) {
        let (mut amplitude, mut m, mut rotation) = self.restart(start);
        // Sample i of every row at once: an index loop, not one iterator per row.
        #[allow(clippy::needless_range_loop)]
        for i in start..stop {
            let t = i as f64 / self.fs;
            let s = rotation * amplitude;
            out[0][i] = s;
            if derivatives {
                let [by_f, by_d, by_g] = self.derivatives(t, m, s);
                out[1][i] = by_f;
                out[2][i] = by_d;
                if self.glide_free {
                    out[3][i] = by_g;
                }
            }
            rotation *= self.step(m);
            amplitude *= self.decay_step;
            m += self.c + m * self.c;
        }
    }

    /// [`SAMPLE_LANES`] whole blocks from sample `first` on, side by side: the same values as
    /// [`Sampler::block`] on each, term by term (the complex products written out as
    /// `num_complex` forms them), with every lane's branch taken as a select so that the lanes
    /// stay in vector registers.
    fn blocks_in_lockstep(&self, first: usize, derivatives: bool, out: &mut [Vec<C64>]) {
        if derivatives {
            self.lockstep::<true>(first, out)
        } else {
            self.lockstep::<false>(first, out)
        }
    }

    fn lockstep<const DERIVATIVES: bool>(&self, first: usize, out: &mut [Vec<C64>]) {
        const L: usize = SAMPLE_LANES;
        type Lanes = [f64; L];
        let starts: [usize; L] = std::array::from_fn(|l| first + l * RECURRENCE_BLOCK);
        // Sample indices as floats: exact integers, so (start + j) as f64 is start_l + j.
        let start_f: Lanes = std::array::from_fn(|l| starts[l] as f64);
        let (mut amplitude, mut m, mut re, mut im): (Lanes, Lanes, Lanes, Lanes) =
            ([0.0; L], [0.0; L], [0.0; L], [0.0; L]);
        for l in 0..L {
            let (a, m0, r) = self.restart(starts[l]);
            (amplitude[l], m[l], re[l], im[l]) = (a, m0, r.re, r.im);
        }
        let (f, d, g) = (self.f, self.d, self.g);
        let rows = match (DERIVATIVES, self.glide_free) {
            (false, _) => 1,
            (true, false) => 3,
            (true, true) => 4,
        };
        // Row r's (re, im) per lane.
        let mut values = [[[0.0; L]; 2]; 4];
        for j in 0..RECURRENCE_BLOCK {
            let j_f = j as f64;
            let mut t: Lanes = [0.0; L];
            let mut s_re: Lanes = [0.0; L];
            let mut s_im: Lanes = [0.0; L];
            for l in 0..L {
                t[l] = (start_f[l] + j_f) / self.fs;
                s_re[l] = re[l] * amplitude[l];
                s_im[l] = im[l] * amplitude[l];
            }
            values[0] = [s_re, s_im];
            if DERIVATIVES {
                for l in 0..L {
                    let (t, m, s_re, s_im) = (t[l], m[l], s_re[l], s_im[l]);
                    let x = 2.0 * d * t;
                    let phi = if x.abs() < 1e-300 {
                        t
                    } else {
                        -m * self.half_inv_d
                    };
                    // phi_decay_derivative_fast, both branches formed.
                    let series = phi_decay_series(t, x);
                    let formula = (t * (1.0 + m) - phi) * self.inv_d;
                    let phi_d = if x.abs() < SERIES_BELOW {
                        series
                    } else {
                        formula
                    };
                    let y1 = 2.0 * PI * (t + g * phi);
                    values[1][0][l] = s_re * 0.0 - s_im * y1;
                    values[1][1][l] = s_re * y1 + s_im * 0.0;
                    let y2 = 2.0 * PI * f * g * phi_d;
                    values[2][0][l] = s_re * -t - s_im * y2;
                    values[2][1][l] = s_re * y2 + s_im * -t;
                    let y3 = 2.0 * PI * f * phi;
                    values[3][0][l] = s_re * 0.0 - s_im * y3;
                    values[3][1][l] = s_re * y3 + s_im * 0.0;
                }
            }
            // The step's rotation: `turn`, or `turn` times the glide's small rotation.
            let (mut step_re, mut step_im): (Lanes, Lanes) = ([self.turn.re; L], [self.turn.im; L]);
            if self.kappa != 0.0 {
                let mut small: [C64; L] = [C64::new(0.0, 0.0); L];
                let mut exact = false;
                for l in 0..L {
                    let delta = self.kappa * (1.0 + m[l]);
                    small[l] = taylor_rotation(delta);
                    exact |= delta.abs() > TAYLOR_ROTATION_MAX;
                }
                if exact {
                    for (l, small) in small.iter_mut().enumerate() {
                        *small = small_rotation(self.kappa * (1.0 + m[l]));
                    }
                }
                let turn = self.turn;
                for l in 0..L {
                    step_re[l] = turn.re * small[l].re - turn.im * small[l].im;
                    step_im[l] = turn.re * small[l].im + turn.im * small[l].re;
                }
            }
            for l in 0..L {
                let a = re[l];
                re[l] = re[l] * step_re[l] - im[l] * step_im[l];
                im[l] = im[l] * step_re[l] + a * step_im[l];
                amplitude[l] *= self.decay_step;
                m[l] += self.c + m[l] * self.c;
            }
            for (row, [lane_re, lane_im]) in out[..rows].iter_mut().zip(&values) {
                for l in 0..L {
                    row[starts[l] + j] = C64::new(lane_re[l], lane_im[l]);
                }
            }
        }
    }
}

/// From a band spectrum to the two real stacked columns (V, U) over its bins (module docs).
fn columns(band: &[(C64, C64)]) -> [DVector<f64>; 2] {
    let m = band.len();
    let mut v = DVector::zeros(2 * m);
    let mut u = DVector::zeros(2 * m);
    for (j, &(s, mirror)) in band.iter().enumerate() {
        let mirror = mirror.conj();
        let uk = (s + mirror) * 0.5;
        let vk = (s - mirror) * C64::new(0.0, -0.5);
        v[j] = vk.re;
        v[m + j] = vk.im;
        u[j] = uk.re;
        u[m + j] = uk.im;
    }
    [v, u]
}

/// A band model evaluated at one ϑ.
struct Evaluation {
    /// B, n_b × L.
    basis: DMatrix<f64>,
    /// Retained left singular vectors of B (n_b × r) and B⁺ (L × n_b).
    left: DMatrix<f64>,
    pinv: DMatrix<f64>,
    /// b_c and r_c per channel.
    coeffs: Vec<DVector<f64>>,
    residuals: Vec<DVector<f64>>,
    rss: Vec<f64>,
    /// ∂B/∂ϑ_j as (column index of the component's V, its two derivative columns), one per
    /// free parameter; only with derivatives.
    derivatives: Vec<(usize, [DVector<f64>; 2])>,
}

impl Evaluation {
    fn cost(&self, weights: &[f64]) -> f64 {
        self.rss.iter().zip(weights).map(|(r, w)| r * w).sum()
    }

    /// P⊥ x.
    fn project_out(&self, x: &DVector<f64>) -> DVector<f64> {
        x - &self.left * (self.left.transpose() * x)
    }

    /// Kaufman's Jacobian per channel: J_c[:, j] = −P⊥ (∂B/∂ϑ_j) b_c.
    fn jacobians(&self) -> Vec<DMatrix<f64>> {
        self.coeffs
            .iter()
            .map(|b| {
                let rows = self.basis.nrows();
                let mut j = DMatrix::zeros(rows, self.derivatives.len());
                for (col, (first, d)) in self.derivatives.iter().enumerate() {
                    let db = &d[0] * b[*first] + &d[1] * b[first + 1];
                    j.set_column(col, &(-self.project_out(&db)));
                }
                j
            })
            .collect()
    }
}

/// The band data of one group and its fixed nuisance columns.
struct BandProblem<'a> {
    spectra: &'a Spectra,
    bins: Vec<usize>,
    /// y_c, stacked real (n_b).
    data: Vec<DVector<f64>>,
    /// Band limits for f, Hz.
    f_range: (f64, f64),
    max_glide: f64,
    /// With the four nuisance columns per channel.
    nuisance: bool,
}

impl BandProblem<'_> {
    fn rows(&self) -> usize {
        2 * self.bins.len()
    }

    fn evaluate(&self, comps: &[Component], derivatives: bool) -> Option<Evaluation> {
        let rows = self.rows();
        let m = self.bins.len();
        let l = 2 * comps.len() + if self.nuisance { NUISANCE_COLUMNS } else { 0 };
        let mut basis = DMatrix::zeros(rows, l);
        let mut derivs = Vec::new();
        for (q, comp) in comps.iter().enumerate() {
            let transforms = self.spectra.transforms(comp, derivatives, &self.bins);
            let [v, u] = columns(&transforms[0]);
            basis.set_column(2 * q, &v);
            basis.set_column(2 * q + 1, &u);
            for t in transforms.iter().skip(1) {
                derivs.push((2 * q, columns(t)));
            }
        }
        // Nuisance: complex constant and complex trend over the band's bins.
        let centre = 0.5 * (m as f64 - 1.0);
        let half = (0.5 * m as f64).max(1.0);
        for j in (0..m).filter(|_| self.nuisance) {
            let x = (j as f64 - centre) / half;
            let base = 2 * comps.len();
            basis[(j, base)] = 1.0;
            basis[(m + j, base + 1)] = 1.0;
            basis[(j, base + 2)] = x;
            basis[(m + j, base + 3)] = x;
        }
        if basis.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let svd = SVD::new(basis.clone(), true, true);
        let (u, vt) = (svd.u.as_ref()?, svd.v_t.as_ref()?);
        let top = svd.singular_values.iter().cloned().fold(0.0, f64::max);
        if !(top > 0.0) {
            return None;
        }
        let keep: Vec<usize> = (0..svd.singular_values.len())
            .filter(|&i| svd.singular_values[i] > SVD_CUTOFF * top)
            .collect();
        let left = DMatrix::from_fn(rows, keep.len(), |i, j| u[(i, keep[j])]);
        let pinv = DMatrix::from_fn(l, rows, |i, j| {
            keep.iter()
                .map(|&s| vt[(s, i)] * u[(j, s)] / svd.singular_values[s])
                .sum()
        });
        let coeffs: Vec<DVector<f64>> = self.data.iter().map(|y| &pinv * y).collect();
        let residuals: Vec<DVector<f64>> = self
            .data
            .iter()
            .zip(&coeffs)
            .map(|(y, b)| y - &basis * b)
            .collect();
        let rss = residuals.iter().map(|r| r.norm_squared()).collect();
        Some(Evaluation {
            basis,
            left,
            pinv,
            coeffs,
            residuals,
            rss,
            derivatives: derivs,
        })
    }

    /// Free parameters of `comps` as a vector (f, d[, g] per component).
    fn pack(comps: &[Component]) -> Vec<f64> {
        comps
            .iter()
            .flat_map(|c| {
                if c.glide_free {
                    vec![c.f, c.d, c.g]
                } else {
                    vec![c.f, c.d]
                }
            })
            .collect()
    }

    fn unpack(&self, comps: &[Component], x: &[f64]) -> Option<Vec<Component>> {
        let mut out = Vec::with_capacity(comps.len());
        let mut i = 0;
        for c in comps {
            let mut n = *c;
            n.f = x[i];
            n.d = x[i + 1];
            if c.glide_free {
                n.g = x[i + 2];
            }
            i += c.n_params();
            let ok = n.f > self.f_range.0
                && n.f < self.f_range.1
                && n.d > 0.0
                && n.d.is_finite()
                && n.g.abs() <= self.max_glide;
            if !ok {
                return None;
            }
            out.push(n);
        }
        Some(out)
    }

    /// Levenberg–Marquardt from `start` with channel weights `weights` (module docs; the
    /// driver is [`crate::numerics::lm`]).
    fn levenberg_marquardt(
        &self,
        start: &[Component],
        weights: &[f64],
        options: &GlideOptions,
    ) -> Option<(Vec<Component>, Evaluation)> {
        let eval = self.evaluate(start, true)?;
        let cost = eval.cost(weights);
        let mut fit = GlideLm {
            band: self,
            weights,
            comps: start.to_vec(),
            eval: Some(eval),
            trial: vec![],
        };
        let settings = lm::Settings {
            damping: lm::Damping {
                start: LM_LAMBDA_START,
                min: 1e-12,
                max: LM_LAMBDA_MAX,
                shrink: 10.0,
                grow: 10.0,
            },
            max_iterations: options.max_iterations,
            accept: lm::Accept::NoIncrease,
            solve: lm::Solve::Direct,
            stopping: lm::Stopping {
                // The full Gauss–Newton step below the tolerance in its own Mahalanobis norm,
                // δᵀHδ = gᵀH⁻¹g: a per-parameter test in conditional standard deviations stops
                // early along the narrow valley that f₀ and g share.
                newton_decrement: Some(options.step_tolerance),
                relative_decrease: Some((1e-15, lm::CostReference::Before)),
                ..lm::Stopping::default()
            },
        };
        lm::minimise(&mut fit, cost, &settings);
        let eval = match fit.eval {
            Some(eval) => eval,
            None => self.evaluate(&fit.comps, true)?,
        };
        Some((fit.comps, eval))
    }

    /// Σ_c w_c ‖P⊥ y_c‖² at `comps` as they are (no fit), w_c = 2/σ_c²: the cost a start is
    /// ranked by. None where the model cannot be evaluated.
    fn start_cost(&self, comps: &[Component], noise_var: &[f64]) -> Option<f64> {
        Some(
            self.evaluate(comps, false)?
                .cost(&channel_weights(noise_var)),
        )
    }

    /// The fit of module docs: LM, noise from the residual, LM again; with its covariance.
    fn fit(
        &self,
        start: &[Component],
        noise_var: &[f64],
        options: &GlideOptions,
    ) -> Option<BandFitResult> {
        let weights = channel_weights(noise_var);
        let (comps, eval) = self.levenberg_marquardt(start, &weights, options)?;
        let n_b = self.rows() as f64;
        let channels = self.data.len() as f64;
        let n_nonlinear: usize = comps.iter().map(|c| c.n_params()).sum();
        let dof = n_b - eval.basis.ncols() as f64 - n_nonlinear as f64 / channels;
        if dof <= 1.0 {
            return None;
        }
        let noise: Vec<f64> = eval
            .rss
            .iter()
            .map(|r| (2.0 * r / dof).max(f64::MIN_POSITIVE))
            .collect();
        let weights: Vec<f64> = noise.iter().map(|v| 2.0 / v).collect();
        let (comps, eval) = self.levenberg_marquardt(&comps, &weights, options)?;
        let noise: Vec<f64> = eval
            .rss
            .iter()
            .map(|r| (2.0 * r / dof).max(f64::MIN_POSITIVE))
            .collect();
        let weights: Vec<f64> = noise.iter().map(|v| 2.0 / v).collect();
        let (h, _) = gauss_newton(&eval, &weights);
        let cov = symmetric_inverse(&h)?;
        let l = eval.basis.ncols() as f64;
        let bic = eval
            .rss
            .iter()
            .map(|r| n_b * (r / n_b).max(f64::MIN_POSITIVE).ln())
            .sum::<f64>()
            + (n_nonlinear as f64 + l * channels) * (n_b * channels).ln();
        Some(BandFitResult {
            comps,
            eval,
            cov,
            noise,
            bic,
        })
    }
}

/// w_c = 2/σ_c² per channel (0 where σ_c² is not positive): the weights of the band's cost.
fn channel_weights(noise_var: &[f64]) -> Vec<f64> {
    noise_var
        .iter()
        .map(|&v| if v > 0.0 { 2.0 / v } else { 0.0 })
        .collect()
}

/// A fitted hypothesis.
struct BandFitResult {
    comps: Vec<Component>,
    eval: Evaluation,
    /// H⁻¹ of the free parameters.
    cov: DMatrix<f64>,
    /// σ̂_c² per channel (complex variance per bin = per full-rate sample).
    noise: Vec<f64>,
    bic: f64,
}

impl BandFitResult {
    /// Component `q` as an extracted mode with its standard deviations (module docs).
    fn mode(
        &self,
        q: usize,
        template: &MeasuredMode,
        spectra: &Spectra,
        merged: usize,
        delta_bic: f64,
        glide_selected: bool,
    ) -> MeasuredMode {
        let comp = self.comps[q];
        let offset: usize = self.comps[..q].iter().map(|c| c.n_params()).sum();
        let sd = |i: usize| self.cov[(offset + i, offset + i)].max(0.0).sqrt();
        let mut amplitudes = Vec::new();
        let mut amplitude_sds = Vec::new();
        let mut phases = Vec::new();
        let mut phase_sds = Vec::new();
        let gram_pinv = &self.eval.pinv * self.eval.pinv.transpose();
        for (c, b) in self.eval.coeffs.iter().enumerate() {
            // E_c = B⁺ (∂B/∂ϑ) b_c; cov(b_c) = (σ²/2) (BᵀB)⁺ + E_c H⁻¹ E_cᵀ.
            let p_count = self.eval.derivatives.len();
            let mut e = DMatrix::zeros(b.len(), p_count);
            for (j, (first, d)) in self.eval.derivatives.iter().enumerate() {
                let db = &d[0] * b[*first] + &d[1] * b[first + 1];
                e.set_column(j, &(&self.eval.pinv * db));
            }
            let cov_b = &gram_pinv * (0.5 * self.noise[c]) + &e * &self.cov * e.transpose();
            let (i, k) = (2 * q, 2 * q + 1);
            let (p, qv) = (b[i], b[k]);
            let a2 = p * p + qv * qv;
            let (vpp, vqq, vpq) = (cov_b[(i, i)], cov_b[(k, k)], cov_b[(i, k)]);
            amplitudes.push(a2.sqrt());
            phases.push(qv.atan2(p));
            // Components that trade off leave a covariance near singular: σ = ∞, no
            // measurement ([`sd_from_variance`]), and an undetermined phase.
            if a2 > 0.0 {
                amplitude_sds.push(sd_from_variance(
                    (p * p * vpp + qv * qv * vqq + 2.0 * p * qv * vpq) / a2,
                ));
                phase_sds.push(phase_sd(sd_from_variance(
                    (qv * qv * vpp + p * p * vqq - 2.0 * p * qv * vpq) / (a2 * a2),
                )));
            } else {
                amplitude_sds.push((0.5 * (vpp + vqq)).max(0.0).sqrt());
                phase_sds.push(UNIFORM_PHASE_SD);
            }
        }
        let envelope: f64 = if comp.d > 0.0 {
            -(-2.0 * comp.d * spectra.n as f64 / spectra.sample_rate).exp_m1()
                / -(-2.0 * comp.d / spectra.sample_rate).exp_m1()
        } else {
            spectra.n as f64
        };
        let energy: f64 = amplitudes.iter().map(|a| 0.5 * a * a * envelope).sum();
        let noise_total: f64 = self.noise.iter().sum();
        let frequency_sd_hz = sd(0);
        let decay_rate_sd = sd(1);
        let esprit = template
            .refined_from
            .expect("an extracted mode records where its refinement started");
        let z_f = (comp.f - esprit.frequency_hz) / frequency_sd_hz;
        let z_d = (comp.d - esprit.decay_rate) / decay_rate_sd;
        let glide = comp.glide_free.then(|| ModeGlide {
            glide: comp.g,
            glide_sd: sd(2),
            selected: glide_selected,
            merged_poles: merged,
            delta_bic,
        });
        let was = template.refinement();
        MeasuredMode {
            amplitudes,
            phases,
            snr_db: Some(10.0 * (energy / noise_total).log10()),
            band: template.band,
            sd: Some(ModeSd {
                frequency_hz: frequency_sd_hz,
                decay_rate: decay_rate_sd,
                amplitudes: amplitude_sds,
                phases: phase_sds,
            }),
            refined_from: Some(esprit),
            refinement: Some(Refinement {
                shift_sigma: z_f.abs().max(z_d.abs()),
                converged: was.converged,
                moved: was.moved,
                left_band: was.left_band,
            }),
            glide,
            ..MeasuredMode::pole(comp.f, comp.d)
        }
    }
}

/// H = Σ_c w_c J_cᵀ J_c and the gradient Σ_c w_c J_cᵀ r_c.
fn gauss_newton(eval: &Evaluation, weights: &[f64]) -> (DMatrix<f64>, DVector<f64>) {
    let p = eval.derivatives.len();
    let mut h = DMatrix::zeros(p, p);
    let mut g = DVector::zeros(p);
    for ((j, r), w) in eval.jacobians().iter().zip(&eval.residuals).zip(weights) {
        h += j.transpose() * j * *w;
        g += j.transpose() * r * *w;
    }
    (h, g)
}

/// [`BandProblem::levenberg_marquardt`]'s problem: the current components with their
/// evaluation (with derivatives; `None` until needed after a step) and the last trial.
struct GlideLm<'a, 'b> {
    band: &'a BandProblem<'b>,
    weights: &'a [f64],
    comps: Vec<Component>,
    eval: Option<Evaluation>,
    trial: Vec<Component>,
}

impl lm::Problem for GlideLm<'_, '_> {
    type Scalar = f64;

    fn normal_equations(&mut self) -> Option<lm::NormalEquations<f64>> {
        if self.eval.is_none() {
            self.eval = self.band.evaluate(&self.comps, true);
        }
        let (h, g) = gauss_newton(self.eval.as_ref()?, self.weights);
        Some(lm::NormalEquations { h, g })
    }

    fn trial(&mut self, step: &DVector<f64>) -> Option<f64> {
        let x = BandProblem::pack(&self.comps);
        let trial_x: Vec<f64> = x.iter().zip(step.iter()).map(|(a, b)| a + b).collect();
        self.trial = self.band.unpack(&self.comps, &trial_x)?;
        // The trial's cost needs no derivatives; they are computed if the step is kept.
        Some(self.band.evaluate(&self.trial, false)?.cost(self.weights))
    }

    fn accept(&mut self) {
        self.comps = std::mem::take(&mut self.trial);
        self.eval = None;
    }
}

/// What [`fit_glides`] decided for one group (for logs and tests).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GlideDecision {
    /// Frequencies of the extraction's poles in the group, Hz.
    pub poles_hz: Vec<f64>,
    /// The best gliding hypothesis, per component: f₀ [Hz], d [1/s], g and σ_g [1].
    pub f0_hz: Vec<f64>,
    pub decay_rate: Vec<f64>,
    pub glide: Vec<f64>,
    pub glide_sd: Vec<f64>,
    /// BIC(constant poles) − BIC(glide).
    pub delta_bic: f64,
    pub selected: bool,
}

/// The extraction with every group of poles decided (module docs) and the decisions.
#[derive(Clone, Debug, PartialEq)]
pub struct GlideStage {
    pub extraction: ModalExtraction,
    pub decisions: Vec<GlideDecision>,
}

/// Decay rate ratio between a ladder's rungs and its slowest pole (module docs, "Groups"): the
/// rungs of a glide decay at (2n + 1) d, at least 3 d; 2 leaves room for the extraction's
/// error.
const LADDER_DECAY_RATIO: f64 = 2.0;

/// Whether the neighbouring groups `lower` and `upper` (by frequency) of `modes` are one glide's
/// ladder (module docs, "Groups"): together within `ladder_rtol` of their frequency, and every
/// pole of the group without the slowest pole decaying at least [`LADDER_DECAY_RATIO`] times
/// faster than it.
fn forms_ladder(
    modes: &[MeasuredMode],
    lower: &[usize],
    upper: &[usize],
    ladder_rtol: f64,
) -> bool {
    let all = || lower.iter().chain(upper).map(|&i| &modes[i]);
    let f_lo = all().map(|m| m.frequency_hz).fold(f64::INFINITY, f64::min);
    let f_hi = all()
        .map(|m| m.frequency_hz)
        .fold(f64::NEG_INFINITY, f64::max);
    if !(f_hi - f_lo <= ladder_rtol * f_hi) {
        return false;
    }
    let slowest = |g: &[usize]| {
        g.iter()
            .map(|&i| modes[i].decay_rate)
            .fold(f64::INFINITY, f64::min)
    };
    let (d_lower, d_upper) = (slowest(lower), slowest(upper));
    let (anchor, rungs) = if d_lower <= d_upper {
        (d_lower, d_upper)
    } else {
        (d_upper, d_lower)
    };
    anchor > 0.0 && rungs >= LADDER_DECAY_RATIO * anchor
}

/// Runs the chirp-aware stage on `extraction` of `channels` (the same channels, from the
/// onset, that it was extracted from).
pub fn fit_glides(
    channels: &[Vec<f64>],
    extraction: &ModalExtraction,
    options: &GlideOptions,
) -> Result<GlideStage, ExtractError> {
    check_options(options)?;
    let fs = extraction.sample_rate;
    let n = channels.first().map_or(0, |c| c.len());
    let n_channels = channels.len();
    if n == 0
        || channels.iter().any(|c| c.len() != n)
        || extraction
            .modes
            .iter()
            .any(|m| m.amplitudes.len() != n_channels)
    {
        return Err(ExtractError::InvalidOption {
            name: "channels",
            value: n_channels as f64,
            reason: "must be non-empty, of equal lengths and match the extraction's channels",
        });
    }
    let mut planner = FftPlanner::new();
    // Residual: recording − every extracted mode (with its glide when selected).
    let mut residual: Vec<Vec<f64>> = (0..n_channels)
        .map(|c| {
            let model = extraction.render_channel(c, n);
            channels[c].iter().zip(&model).map(|(x, m)| x - m).collect()
        })
        .collect();
    let modes = &extraction.modes;
    let mut order: Vec<usize> = (0..modes.len()).collect();
    order.sort_by(|&a, &b| modes[a].frequency_hz.total_cmp(&modes[b].frequency_hz));
    let mut chained: Vec<Vec<usize>> = Vec::new();
    for &i in &order {
        match chained.last_mut() {
            Some(g)
                if modes[i].frequency_hz - modes[*g.last().expect("non-empty")].frequency_hz
                    <= options.group_rtol * modes[i].frequency_hz =>
            {
                g.push(i)
            }
            _ => chained.push(vec![i]),
        }
    }
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for g in chained {
        match groups.last_mut() {
            Some(last) if forms_ladder(modes, last, &g, options.ladder_rtol) => last.extend(g),
            _ => groups.push(g),
        }
    }
    let mut out_modes: Vec<MeasuredMode> = Vec::with_capacity(modes.len());
    let mut decisions = Vec::new();
    // Loudest groups first: their glides leak furthest, and once decided they are subtracted as
    // they are for the groups that follow.
    let loudness = |g: &Vec<usize>| {
        g.iter()
            .map(|&i| modes[i].snr())
            .fold(f64::NEG_INFINITY, f64::max)
    };
    groups.sort_by(|a, b| loudness(b).total_cmp(&loudness(a)));
    for group in groups {
        let members: Vec<&MeasuredMode> = group.iter().map(|&i| &modes[i]).collect();
        let loudest = *members
            .iter()
            .max_by(|a, b| a.snr().total_cmp(&b.snr()))
            .expect("non-empty");
        let f_lo = members
            .iter()
            .map(|m| m.frequency_hz)
            .fold(f64::INFINITY, f64::min);
        let above = options.max_frequency_hz.is_some_and(|f_max| f_lo > f_max);
        let skip = members.len() > options.max_group
            || above
            || loudest.snr() < options.min_snr_db
            || members
                .iter()
                .any(|m| m.glide.as_ref().is_some_and(|g| g.selected))
            || !(members
                .iter()
                .all(|m| m.frequency_hz > 0.0 && m.decay_rate > 0.0));
        if skip {
            out_modes.extend(members.into_iter().cloned());
            continue;
        }
        let f_hi = members.iter().map(|m| m.frequency_hz).fold(0.0, f64::max);
        let d_max = members.iter().map(|m| m.decay_rate).fold(0.0, f64::max);
        let d_min = members
            .iter()
            .map(|m| m.decay_rate)
            .fold(f64::INFINITY, f64::min);
        // The span that holds the group's modes: FIT_SPAN_DECAYS decay times of the slowest
        // (amplitude e^(−12)), in whole FFT_BLOCKs (a smooth FFT length), at most N.
        let needed = ((FIT_SPAN_DECAYS / d_min).max(MIN_FIT_SPAN_S) * fs).ceil() as usize;
        let n_fit = (needed.div_ceil(FFT_BLOCK) * FFT_BLOCK).min(n);
        let nyquist_bin = n_fit / 2;
        let df = fs / n_fit as f64;
        let w = (8.0 * df + 4.0 * d_max / (2.0 * PI) + 0.003 * f_hi)
            .min(options.max_band_hz)
            .max(4.0 * df);
        let k_lo = (((f_lo - w) / df).floor().max(1.0)) as usize;
        let k_hi = (((f_hi + w) / df).ceil() as usize).min(nyquist_bin.saturating_sub(1));
        if k_hi <= k_lo + 4 {
            out_modes.extend(members.into_iter().cloned());
            continue;
        }
        let bins: Vec<usize> = (k_lo..=k_hi).collect();
        let spectra =
            Spectra::new(planner.plan_fft_forward(n_fit), n_fit, fs).with_band(&mut planner, &bins);
        // The group's own poles back into the data.
        let data: Vec<DVector<f64>> = (0..n_channels)
            .map(|c| {
                let mut x = residual[c][..n_fit].to_vec();
                for m in &members {
                    add_gliding_mode(
                        &mut x,
                        fs,
                        m.frequency_hz,
                        m.decay_rate,
                        0.0,
                        m.amplitudes[c],
                        m.phases[c],
                    );
                }
                let scale = 1.0 / (n_fit as f64).sqrt();
                let mut y: Vec<C64> = x.iter().map(|&v| C64::new(v * scale, 0.0)).collect();
                spectra.fft.process(&mut y);
                let m = bins.len();
                let mut v = DVector::zeros(2 * m);
                for (j, &k) in bins.iter().enumerate() {
                    v[j] = y[k].re;
                    v[m + j] = y[k].im;
                }
                v
            })
            .collect();
        let band = loudest.band.and_then(|b| extraction.bands.get(b));
        let noise_var: Vec<f64> = (0..n_channels)
            .map(|c| {
                band.and_then(|b| b.noise_rms.get(c))
                    .map_or(1.0, |s| (s * s).max(f64::MIN_POSITIVE))
            })
            .collect();
        let problem = BandProblem {
            spectra: &spectra,
            bins,
            data,
            f_range: ((k_lo as f64) * df, (k_hi as f64) * df),
            max_glide: options.max_glide,
            nuisance: true,
        };
        let constant: Vec<Component> = members
            .iter()
            .map(|m| Component {
                f: m.frequency_hz,
                d: m.decay_rate,
                g: 0.0,
                glide_free: false,
            })
            .collect();
        let spread = (f_hi - f_lo) / f_lo;
        let mean_d = members.iter().map(|m| m.decay_rate).sum::<f64>() / members.len() as f64;
        // Gliding hypotheses with K' = 1 … K components. K' = 1: from the loudest pole, and from
        // either end of the group with the glide spanning it. K' ≥ 2: from the K' loudest poles
        // (K' = K: every pole, in the members' order, so component q is pole q).
        let mut by_snr: Vec<usize> = (0..members.len()).collect();
        by_snr.sort_by(|&a, &b| members[b].snr().total_cmp(&members[a].snr()));
        let gliding = |m: &MeasuredMode| Component {
            f: m.frequency_hz,
            d: m.decay_rate,
            g: 0.0,
            glide_free: true,
        };
        let mut hypotheses: Vec<Vec<Component>> = vec![vec![gliding(loudest)]];
        if members.len() > 1 {
            let g0 = spread.min(0.8 * options.max_glide);
            hypotheses.push(vec![Component {
                f: f_lo,
                d: mean_d,
                g: g0,
                glide_free: true,
            }]);
            hypotheses.push(vec![Component {
                f: f_hi,
                d: mean_d,
                g: -g0,
                glide_free: true,
            }]);
            if members.len() > 2 {
                let mut chosen: Vec<usize> = by_snr[..2].to_vec();
                chosen.sort_unstable();
                hypotheses.push(chosen.iter().map(|&q| gliding(members[q])).collect());
            }
            hypotheses.push(members.iter().map(|m| gliding(m)).collect());
        }
        // K' = 1 first; its glide then also starts the K' ≥ 2 hypotheses (every component at ĝ):
        // the glide at the onset can exceed the spacing of a near-degenerate pair many times
        // over, and from g = 0 each component is caught by the wrong pole.
        // The fits of each phase are independent and run on `threads` threads; they are
        // collected in order, so the answer does not depend on the count. The constant poles'
        // fit runs with the first phase.
        let threads = options.threads.unwrap_or(1);
        let fit = |start: &Vec<Component>| problem.fit(start, &noise_var, options);
        let single = if members.len() > 1 { 3 } else { 1 };
        let mut first: Vec<Vec<Component>> = hypotheses[..single].to_vec();
        first.push(constant.clone());
        let mut first = map_on_threads(&first, threads, fit);
        let const_fit = first.pop().expect("the constant poles' slot");
        let mut fits: Vec<(usize, BandFitResult)> = first
            .into_iter()
            .enumerate()
            .filter_map(|(h, f)| f.map(|f| (h, f)))
            .collect();
        let g1 = fits
            .iter()
            .min_by(|a, b| a.1.bic.total_cmp(&b.1.bic))
            .map(|f| f.1.comps[0].g);
        // Each further hypothesis from its poles and, with the single glide's ĝ, from that.
        let tries: Vec<(usize, Vec<Component>)> = hypotheses
            .iter()
            .enumerate()
            .skip(single)
            .flat_map(|(h, start)| {
                let glided = g1.map(|g| (h, start.iter().map(|c| Component { g, ..*c }).collect()));
                std::iter::once((h, start.clone())).chain(glided)
            })
            .collect();
        let mut tried = map_on_threads(&tries, threads, |(_, start)| fit(start));
        for h in single..hypotheses.len() {
            // The first of the least BIC among the hypothesis's tries, as they were listed.
            let bic = |i: usize| tried[i].as_ref().map_or(f64::NAN, |f| f.bic);
            let best = (0..tries.len())
                .filter(|&i| tries[i].0 == h && tried[i].is_some())
                .min_by(|&a, &b| bic(a).total_cmp(&bic(b)));
            if let Some(best) = best.and_then(|i| tried[i].take()) {
                fits.push((h, best));
            }
        }
        // Forward addition from the best fit so far with fewer than K components (module docs,
        // "Criterion", *forward addition*): a near-degenerate gliding pair sits inside one
        // ladder, and started at the two loudest poles its second component is caught by a
        // rung; from the fitted components plus one more it is not. Every step's fit enters the
        // comparison below, keyed `usize::MAX` (not one of `hypotheses`: the per-pole lookup
        // keys on the last of those); a step that lowers no BIC ends it.
        if members.len() > 1 {
            let mut current = fits
                .iter()
                .filter(|(_, f)| f.comps.len() < members.len())
                .min_by(|a, b| a.1.bic.total_cmp(&b.1.bic))
                .map(|(_, f)| (f.comps.clone(), f.bic));
            // A new component at each pole, or beside a fitted one (a near-degenerate partner),
            // one bin of the band's data away on either side.
            let bin_hz = spectra.sample_rate / spectra.n as f64;
            while let Some((comps, bic)) = current.take() {
                if comps.len() >= members.len() {
                    break;
                }
                let g_hat = comps[0].g;
                let at_poles = members
                    .iter()
                    .flat_map(|m| [0.0, g_hat].map(|g| Component { g, ..gliding(m) }));
                let beside = comps
                    .iter()
                    .flat_map(|c| [-bin_hz, bin_hz].map(|df| Component { f: c.f + df, ..*c }));
                // Ranked by their weighted cost as started (one evaluation each), the
                // [`FORWARD_STARTS`] best are fitted: a fit costs tens of evaluations.
                let candidates: Vec<Vec<Component>> = at_poles
                    .chain(beside)
                    .map(|new| {
                        let mut start = comps.clone();
                        start.push(new);
                        start
                    })
                    .collect();
                let costs = map_on_threads(&candidates, threads, |start| {
                    problem.start_cost(start, &noise_var)
                });
                let mut starts: Vec<(f64, Vec<Component>)> = costs
                    .into_iter()
                    .zip(candidates)
                    .filter_map(|(c, start)| Some((c?, start)))
                    .collect();
                starts.sort_by(|a, b| a.0.total_cmp(&b.0));
                let best_starts: Vec<Vec<Component>> = starts
                    .into_iter()
                    .take(FORWARD_STARTS)
                    .map(|(_, start)| start)
                    .collect();
                let step = map_on_threads(&best_starts, threads, fit)
                    .into_iter()
                    .flatten()
                    .min_by(|a, b| a.bic.total_cmp(&b.bic));
                if let Some(next) = step.filter(|f| f.bic < bic) {
                    current = Some((next.comps.clone(), next.bic));
                    fits.push((usize::MAX, next));
                }
            }
        }
        let Some(const_fit) = const_fit else {
            out_modes.extend(members.into_iter().cloned());
            continue;
        };
        let Some((_, glide_fit)) = fits.iter().min_by(|a, b| a.1.bic.total_cmp(&b.1.bic)) else {
            out_modes.extend(members.into_iter().cloned());
            continue;
        };
        let delta_bic = const_fit.bic - glide_fit.bic;
        let g_sd = |fit: &BandFitResult, q: usize| {
            let offset: usize = fit.comps[..q].iter().map(|c| c.n_params()).sum();
            fit.cov[(offset + 2, offset + 2)].max(0.0).sqrt()
        };
        let comps = 0..glide_fit.comps.len();
        let identified = comps.clone().all(|q| {
            glide_component_sound(
                &glide_fit.comps[q],
                g_sd(glide_fit, q),
                (d_min, d_max),
                options,
            )
        }) && comps
            .into_iter()
            .any(|q| glide_fit.comps[q].g.abs() >= options.min_glide_z * g_sd(glide_fit, q));
        let selected = delta_bic > options.bic_margin && identified;
        decisions.push(GlideDecision {
            poles_hz: members.iter().map(|m| m.frequency_hz).collect(),
            f0_hz: glide_fit.comps.iter().map(|c| c.f).collect(),
            decay_rate: glide_fit.comps.iter().map(|c| c.d).collect(),
            glide: glide_fit.comps.iter().map(|c| c.g).collect(),
            glide_sd: (0..glide_fit.comps.len())
                .map(|q| g_sd(glide_fit, q))
                .collect(),
            delta_bic,
            selected,
        });
        if selected {
            // Each component as a mode, its bookkeeping from the pole it is nearest to.
            let new_modes: Vec<MeasuredMode> = (0..glide_fit.comps.len())
                .map(|q| {
                    let f = glide_fit.comps[q].f;
                    let template = members
                        .iter()
                        .min_by(|a, b| {
                            (a.frequency_hz - f)
                                .abs()
                                .total_cmp(&(b.frequency_hz - f).abs())
                        })
                        .expect("non-empty");
                    glide_fit.mode(q, template, &spectra, members.len(), delta_bic, true)
                })
                .collect();
            // The residual now holds the glides instead of the poles.
            for (c, r) in residual.iter_mut().enumerate() {
                for m in &members {
                    add_gliding_mode(
                        r,
                        fs,
                        m.frequency_hz,
                        m.decay_rate,
                        0.0,
                        m.amplitudes[c],
                        m.phases[c],
                    );
                }
                for (comp, mode) in glide_fit.comps.iter().zip(&new_modes) {
                    add_gliding_mode(
                        r,
                        fs,
                        comp.f,
                        comp.d,
                        comp.g,
                        -mode.amplitudes[c],
                        mode.phases[c],
                    );
                }
            }
            out_modes.extend(new_modes);
        } else {
            // The extraction's constant poles stand; each gets its g as a measurement from the
            // fit with one gliding component per pole (nested in it: unbiased, ≈ 0 ± σ_g).
            let per_pole = fits
                .iter()
                .find(|(h, _)| *h == hypotheses.len() - 1)
                .map(|(_, f)| f)
                .filter(|f| f.comps.len() == members.len());
            for (q, m) in members.into_iter().enumerate() {
                let mut mode = m.clone();
                mode.glide = per_pole.map(|f| ModeGlide {
                    glide: f.comps[q].g,
                    glide_sd: g_sd(f, q),
                    selected: false,
                    merged_poles: 1,
                    delta_bic,
                });
                out_modes.push(mode);
            }
        }
    }
    out_modes.sort_by(|a, b| a.frequency_hz.total_cmp(&b.frequency_hz));
    let mut extraction = extraction.clone();
    extraction.modes = out_modes;
    Ok(GlideStage {
        extraction,
        decisions,
    })
}

/// Starts fitted per step of the forward addition (`fit_glides`): the best by their cost as
/// started, of one new component at each pole (at g = 0 and at the glide ĝ of the fit so far)
/// or one DFT bin either side of each fitted component.
const FORWARD_STARTS: usize = 2;

/// Decay rates of a gliding component further than this factor from the group's poles' range
/// mean the fit ran away (module docs, identification).
const DECAY_RANGE_FACTOR: f64 = 4.0;

/// Whether a fitted gliding component is not broken (module docs): σ_g finite, |g| < 0.98
/// `max_glide`, and d within [`DECAY_RANGE_FACTOR`] of the poles' range `decays`.
fn glide_component_sound(
    comp: &Component,
    glide_sd: f64,
    decays: (f64, f64),
    options: &GlideOptions,
) -> bool {
    let (d_min, d_max) = decays;
    glide_sd.is_finite()
        && comp.g.abs() < 0.98 * options.max_glide
        && comp.d >= d_min / DECAY_RANGE_FACTOR
        && comp.d <= d_max * DECAY_RANGE_FACTOR
}

fn check_options(options: &GlideOptions) -> Result<(), ExtractError> {
    let invalid = |name, value, reason| {
        Err(ExtractError::InvalidOption {
            name,
            value,
            reason,
        })
    };
    if !(options.group_rtol >= 0.0 && options.group_rtol < 0.1) {
        return invalid(
            "glide.group_rtol",
            options.group_rtol,
            "must be in [0, 0.1)",
        );
    }
    if !(options.ladder_rtol >= 0.0 && options.ladder_rtol < 0.1) {
        return invalid(
            "glide.ladder_rtol",
            options.ladder_rtol,
            "must be in [0, 0.1)",
        );
    }
    if options.max_group == 0 {
        return invalid("glide.max_group", 0.0, "must be at least 1");
    }
    if options.max_iterations == 0 {
        return invalid("glide.max_iterations", 0.0, "must be at least 1");
    }
    if !(options.step_tolerance > 0.0 && options.step_tolerance.is_finite()) {
        return invalid(
            "glide.step_tolerance",
            options.step_tolerance,
            "must be a positive number",
        );
    }
    if !(options.max_glide > 0.0 && options.max_glide < 1.0) {
        return invalid("glide.max_glide", options.max_glide, "must be in (0, 1)");
    }
    if !(options.max_band_hz > 0.0) {
        return invalid(
            "glide.max_band_hz",
            options.max_band_hz,
            "must be positive (Hz)",
        );
    }
    if options.bic_margin.is_nan() {
        return invalid("glide.bic_margin", options.bic_margin, "must be a number");
    }
    if !(options.min_glide_z >= 0.0) {
        return invalid("glide.min_glide_z", options.min_glide_z, "must be ≥ 0");
    }
    if let Some(f) = options.max_frequency_hz.filter(|f| !(*f > 0.0)) {
        return invalid("glide.max_frequency_hz", f, "must be positive (Hz)");
    }
    Ok(())
}

#[cfg(test)]
mod tests;
