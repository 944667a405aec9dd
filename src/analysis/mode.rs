//! The one type for a mode measured from a recording.
//!
//! Every analysis of a recording returns its modes as [`MeasuredMode`]s: the modal estimate
//! ([`super::estimate`]), the extraction with uncertainties ([`super::extract`]) and its
//! chirp-aware stage ([`super::extract::glide`]), the damping fit
//! ([`crate::inverse::damping`]); the impact localisation ([`crate::inverse::impact`]) takes
//! its known poles as bare measured modes ([`MeasuredMode::pole`]). What only some stages
//! measure is optional, so no stage invents a value it did not measure:
//!
//! | field | estimate | extraction | damping fit | pole |
//! |-------|----------|------------|-------------|------|
//! | f, d | ✓ | ✓ | ✓ | ✓ |
//! | a_c, φ_c | ✓ | ✓ | ✓ | — |
//! | SNR | ✓ | ✓ | ✓ (the estimate's) | — |
//! | [`band`](MeasuredMode::band), [`energies`](MeasuredMode::energies) | ✓ | band only | — | — |
//! | [`sd`](MeasuredMode::sd) (σ of f, d, a_c, φ_c) | — | ✓ | — | — |
//! | [`refined_from`](MeasuredMode::refined_from) | — | ESPRIT's f, d | the estimate's f, d | — |
//! | [`refinement`](MeasuredMode::refinement) (shift, convergence, flags) | — | ✓ | — | — |
//! | [`glide`](MeasuredMode::glide) | — | chirp stage | — | — |
//! | [`verdict`](MeasuredMode::verdict) (level, kept, reason, peak) | — | — | ✓ | — |
//!
//! The diagnosis compares the recording with the simulation through its own observation,
//! [`crate::diagnose::catalogue::ObservedMode`], built from extracted modes.

use super::extract::glide::ModeGlide;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// A damped mode measured from a recording: on channel c, a_c e^(−d t) sin(2π f t + φ_c).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeasuredMode {
    /// f, the damped frequency (as heard), Hz.
    pub frequency_hz: f64,
    /// d, 1/s (amplitude ∝ e^(−d t)).
    pub decay_rate: f64,
    /// a_c per channel, units of the signal (peak at t = 0, the onset); empty for a pole.
    #[serde(default)]
    pub amplitudes: Vec<f64>,
    /// φ_c per channel, rad, in (−π, π]; empty for a pole.
    #[serde(default)]
    pub phases: Vec<f64>,
    /// Σ_c E_c over the band's noise energy per sample, dB (module docs of
    /// [`super::estimate`]; the extraction's with its refined values, the damping fit's that of
    /// the estimate it started from); `None` for a pole.
    #[serde(default)]
    pub snr_db: Option<f64>,
    /// Index into the bands of the estimate or extraction that found it.
    #[serde(default)]
    pub band: Option<usize>,
    /// E_c per channel: the mode's energy Σ_n (its samples)², units² (the estimate's).
    #[serde(default)]
    pub energies: Option<Vec<f64>>,
    /// Standard deviations of f, d, a_c and φ_c (the extraction's).
    #[serde(default)]
    pub sd: Option<ModeSd>,
    /// f and d of the estimate the refinement started from (ESPRIT's for the extraction).
    #[serde(default)]
    pub refined_from: Option<RefinedFrom>,
    /// How the extraction's refinement went.
    #[serde(default)]
    pub refinement: Option<Refinement>,
    /// The chirp-aware stage's glide ([`super::extract::glide`]): `None` from
    /// [`super::extract_modes`] and for the poles of a group that stays split; with `selected`
    /// the mode glides, f(t) = f (1 + g e^(−2dt)), and `frequency_hz` is its small-amplitude
    /// frequency f₀.
    #[serde(default)]
    pub glide: Option<ModeGlide>,
    /// The damping fit's verdict on the mode.
    #[serde(default)]
    pub verdict: Option<Verdict>,
}

/// Standard deviations of a measured mode.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModeSd {
    /// σ_f, Hz.
    pub frequency_hz: f64,
    /// σ_d, 1/s.
    pub decay_rate: f64,
    /// σ_a per channel, units of the signal.
    pub amplitudes: Vec<f64>,
    /// σ_φ per channel, rad.
    pub phases: Vec<f64>,
}

/// σ_φ of a phase the data do not determine: that of a phase uniform on (−π, π], π/√3 rad.
pub const UNIFORM_PHASE_SD: f64 = PI / 1.732_050_807_568_877_2;

/// A standard deviation from a first-order variance. A variance that is not positive and
/// finite (a covariance near singular: parameters that trade off) measures nothing, so its σ
/// is ∞; a clamp to 0 would claim an exact measurement (generator 2's seed 223 case 002, a
/// bar: σ_a = 0 beside a = 0.128, which the catalogue refused, aborting the diagnosis).
pub fn sd_from_variance(variance: f64) -> f64 {
    if variance > 0.0 && variance.is_finite() {
        variance.sqrt()
    } else {
        f64::INFINITY
    }
}

/// σ_φ from a phase's σ that may be ∞ ([`sd_from_variance`]): a phase nothing measured is
/// uniform ([`UNIFORM_PHASE_SD`]).
pub fn phase_sd(sd: f64) -> f64 {
    if sd.is_finite() {
        sd
    } else {
        UNIFORM_PHASE_SD
    }
}

/// Where a refinement started: the estimate's f and d.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RefinedFrom {
    /// f, Hz.
    pub frequency_hz: f64,
    /// d, 1/s.
    pub decay_rate: f64,
}

/// How the extraction's refinement of one mode went.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Refinement {
    /// max(|Δf|/σ_f, |Δd|/σ_d) of the refinement's move from ESPRIT.
    pub shift_sigma: f64,
    /// The band's refinement converged, or this mode's own last step was below the tolerance.
    pub converged: bool,
    /// The refinement moved it more than [`super::ExtractOptions::shift_flag_sigma`] from
    /// ESPRIT.
    pub moved: bool,
    /// The refined frequency left the band's (widened) centre region.
    pub left_band: bool,
}

/// Why a mode was kept or rejected (the first test it fails, in the order of the module docs
/// of [`crate::inverse::damping`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ModeVerdict {
    Kept,
    /// d ≤ min_decay_rate.
    DecayTooSlow,
    /// d > max_decay_rate.
    DecayTooFast,
    /// SNR of the estimate below min_snr_db.
    LowSnr,
    /// Level below min_level_db.
    Weak,
    /// The mode's peak has d more than max_curve_ratio times off the robust curve through the
    /// kept peaks.
    OffCurve,
}

/// The damping fit's verdict on a mode.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Verdict {
    /// ℓ, dB relative to the strongest mode (module docs of [`crate::inverse::damping`]).
    pub level_db: f64,
    /// Whether the mode counts: it passed the mode thresholds and its peak is kept.
    pub kept: bool,
    pub reason: ModeVerdict,
    /// Index into [`crate::inverse::damping::DampingFit::peaks`] of the peak the mode belongs
    /// to, if it passed the mode thresholds.
    pub peak: Option<usize>,
}

impl MeasuredMode {
    /// A bare pole: f and d, nothing else measured (the known poles of the impact
    /// localisation, from the recording or the model).
    pub fn pole(frequency_hz: f64, decay_rate: f64) -> MeasuredMode {
        MeasuredMode {
            frequency_hz,
            decay_rate,
            amplitudes: Vec::new(),
            phases: Vec::new(),
            snr_db: None,
            band: None,
            energies: None,
            sd: None,
            refined_from: None,
            refinement: None,
            glide: None,
            verdict: None,
        }
    }

    /// f₀ = √(f² + (d/2π)²), the undamped frequency, Hz.
    pub fn undamped_frequency_hz(&self) -> f64 {
        self.frequency_hz.hypot(self.decay_rate / (2.0 * PI))
    }

    /// The SNR, dB; NaN for a pole, which has none.
    pub fn snr(&self) -> f64 {
        self.snr_db.unwrap_or(f64::NAN)
    }

    /// The standard deviations. Panics for a mode that has none: only the extraction's modes
    /// carry them.
    pub fn sd(&self) -> &ModeSd {
        self.sd
            .as_ref()
            .expect("standard deviations are measured by the extraction only")
    }

    /// How the refinement went. Panics for a mode the extraction did not refine.
    pub fn refinement(&self) -> &Refinement {
        self.refinement
            .as_ref()
            .expect("the refinement record is kept by the extraction only")
    }

    /// The damping fit's verdict. Panics for a mode the damping fit did not judge.
    pub fn verdict(&self) -> &Verdict {
        self.verdict
            .as_ref()
            .expect("the verdict is given by the damping fit only")
    }

    /// The damping fit's verdict, to update. Panics as [`MeasuredMode::verdict`].
    pub fn verdict_mut(&mut self) -> &mut Verdict {
        self.verdict
            .as_mut()
            .expect("the verdict is given by the damping fit only")
    }

    /// Whether the damping fit kept the mode (false for a mode it did not judge).
    pub fn kept(&self) -> bool {
        self.verdict.as_ref().is_some_and(|v| v.kept)
    }

    /// Any reason to distrust an extracted mode: not converged, moved far from ESPRIT, or out
    /// of band (false for a mode the extraction did not refine).
    pub fn is_flagged(&self) -> bool {
        self.refinement
            .as_ref()
            .is_some_and(|r| !r.converged || r.moved || r.left_band)
    }
}
