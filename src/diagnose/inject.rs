//! Hidden effects for the mismatch-diagnosis benchmark (issue 6, section 5): the serial, pure
//! parts of the generator `examples/diagnose_generate.rs`, and the scorer.
//!
//! # The clean case (what the detector's model assumes)
//!
//! P2 FEM modes λ_k = ω_k² [rad²/s²] of the free body with mass-normalised shapes φ_k
//! [kg^(−½)]; Rayleigh decay d_k = (α + β ω_k²)/2 [1/s]; a unit impulse J = 1 N·s at a surface
//! vertex along the inward normal n, so c_k = J |φ_k(x)·n| (the sign of a mode shape is
//! arbitrary, so the generator takes the magnitude); acceleration response, i.e. the
//! complex amplitude z_k = c_k s_k²/ω_d,k with s_k = −d_k + iω_d,k
//! ([`crate::audio::excitation`]); every microphone c hears g_c z_k (one real gain per
//! microphone); white or pink noise. The sound of channel c is
//!
//! x_c(t) = Σ_k Im( g_c z_k e^(s_k t) ),   t ≥ 0 (the strike),
//!
//! rendered by [`crate::audio::synth`] after a noise-only pre-roll.
//!
//! # The effects (labels are the snake_case names)
//!
//! Each effect is injected with a physically more faithful (or simply different) model than
//! the one the detectors of [`crate::diagnose`] fit, so that finding it is not circular. Its
//! strength u ∈ [0, 1] is drawn uniformly and mapped onto a documented realistic range of one
//! parameter ([`Effect::strength_scale`]: log-linear unless stated), so that recall can be
//! plotted against u; the other parameters are drawn independently.
//!
//! | effect | injected model | strength → parameter | other parameters |
//! |---|---|---|---|
//! | `non_rayleigh_damping` | d(f) = π f (η + Δ x/(1+x²)), x = f/f_c: a constant loss factor η plus a Zener (thermoelastic-like) relaxation peak of strength Δ at f_c ([`ZenerDamping`]) | Δ/η ∈ [0.5, 5] | f_c log-uniform over the modes' band; η such that d equals the Rayleigh decay at the band's geometric centre |
//! | `beating_pair` | an inhomogeneous material: in an azimuthal sector about the vertical axis through the centroid the density is scaled by 1 + ε and Young's modulus by 1 + qε (FEM re-solve: M + ερM₁ˢ, K + qε(λK_λˢ + μK_μˢ) with the sector's matrices), so near-degenerate pairs split as the physics splits them ([`sector_mesh`] says why a sector, not a half-space) | ε ∈ [0.2, 2] % | q ~ U[−1, 1]; sector start uniform, width U[40°, 80°]; the axis is the support axis z, the usual symmetry axis of a body resting on its base |
//! | `support_contact` | springs k_n (along z) and k_t = r k_n (in x, y) at the lowest surface vertices (within 1 % of the height of the lowest point, at least 3: [`support_nodes`]; FEM re-solve) and dashpots c = k·2ζ_s/ω_s: Δd_k = ½ Σ_i (c_n φ_iz² + c_t (φ_ix² + φ_iy²)) ([`support_damping`]) | bounce frequency f_s = √(k_total/m)/2π ∈ [20, 150] Hz | ζ_s ∈ [0.05, 0.3], r ∈ [0.1, 0.5]; the six low support modes (f < ½ f_1) are not rendered |
//! | `contact_duration` | Hertz contact force F(t) ∝ sin^(3/2)(πt/T) on [0, T], its Laplace transform at each damped pole by quadrature ([`HertzPulse`]) | T ∈ [0.05, 0.6] ms | – |
//! | `reverb` | direct path + exponentially decaying Gaussian tail after a pre-delay, a new tail per microphone ([`RoomResponse`]) | direct-to-reverberant ratio 15 → 0 dB (linear in dB) | T60 log-uniform in [0.2, 1.0] s, pre-delay in [1, 8] ms |
//! | `radiation` | each mode at each microphone scaled by its acoustic transfer p_k(x_c) from [`crate::audio::radiation`] (multipole fit of the surface normal velocity) instead of a common amplitude: displacement response × conj(p_k(x_c)) (the transfer carries the ρω² of the acceleration and is conjugated from its e^(−iωt) convention into the synthesiser's) | *measured*: RMS of the dB-level residual after the best per-mode + per-microphone (rank-1) fit, energy-weighted ([`rank_one_level_misfit_db`]), 0 → 10 dB (linear) | microphone sphere radius 0.3–0.6 m |
//! | `added_mass` | a lumped mass added to M at a few neighbouring surface vertices (FEM re-solve) | mass / body mass ∈ [1, 10] % | 3–8 vertices around a random surface vertex |
//! | `pitch_glide` | f(t) = f₀ (1 + g (a(t)/a₀)²) = f₀ (1 + g e^(−2dt)) per mode (the same g for every mode, each gliding with its own decay), phase integrated exactly ([`glide_phase`]) | g ∈ [0.05, 0.5] % | – |
//!
//! # Formulas and units
//!
//! * **Zener damping.** A standard linear solid has loss factor η(f) = Δ x/(1 + x²), x = f/f_c
//!   (peak Δ/2 at f_c); with a frequency-independent part η the decay rate is
//!   d(f) = ω η_total/2 = π f (η + Δ x/(1 + x²)) [1/s] (f in Hz). Equivalently
//!   d = π η f + A f²/(1 + (f/f_c)²) with A = πΔ/f_c [s]: linear in f, plus a term that grows
//!   as f² below f_c and levels off at πΔ f_c above it. Neither a power law nor α + βω² follows
//!   it.
//! * **Hertz pulse.** F(t) = sin^(3/2)(πt/T) / (T C) on [0, T], C = ∫₀¹ sin^(3/2)(πu) du =
//!   Γ(5/4)/(√π Γ(7/4)) ≈ 0.556418, so ∫F = 1 [1/s]. F̃(s) = ∫₀ᵀ F(t) e^(−st) dt is computed by
//!   Gauss–Legendre quadrature after the substitution t = T(3u² − 2u³): the integrand becomes
//!   analytic at both ends (sin^(3/2) behaves like t^(3/2) there, and t^(3/2) ∝ u³), so the rule
//!   converges geometrically; the number of panels grows with |s|T. The mode's complex amplitude
//!   is multiplied by F̃(s_k) (exact after the contact ends, as in
//!   [`crate::audio::excitation`]). The detector uses the half-sine instead.
//! * **Room response.** h[0] = 1 (direct sound), h[n] = σ w[n] e^(−3 ln(10) n/(f_s T60)) for
//!   n ≥ n₀ (pre-delay n₀), w[n] standard normal; σ is set on the realised tail so that
//!   10 log₁₀(1 / Σ_{n≥n₀} h[n]²) = DRR exactly. The energy decays by 60 dB in T60 seconds.
//!   The tail is cut at 1.5 T60 (−90 dB) and the convolution at the recording's end.
//! * **Pitch glide.** With amplitude a(t) = a₀ e^(−dt), f(t) = f₀ (1 + g e^(−2dt)) and the
//!   phase θ(t) = 2π ∫₀ᵗ f = 2π f₀ (t + g (1 − e^(−2dt))/(2d)) (→ 2π f₀ (1 + g) t as d → 0),
//!   evaluated in closed form with `expm1`; x(t) = Im(z e^(iθ(t))) e^(−dt).
//! * **Noise.** White: independent N(0, σ²) samples. Pink: white noise shaped in the DFT
//!   domain by 1/√max(f, 20 Hz) (power ∝ 1/f, −10 dB per decade), DC removed. The SNR is
//!   10 log₁₀(P_s/σ²) with P_s the signal power over the strike window (after the onset),
//!   averaged over the microphones; one noise level for all microphones.
//!
//! # Case mix and the scorer
//!
//! [`schedule_effects`] gives about 30 % clean cases, 40 % with one effect and 30 % with two
//! different effects, drawing effects from a shuffled deck so that each appears about equally
//! often. [`score`] compares sealed labels with detections: precision, recall and F1 per
//! effect (F1 = 2TP/(2TP + FP + FN)), the macro F1, the false-positive rate on clean cases
//! (fraction of clean cases with any detection) and recall per strength bin.
//!
//! # Comparing parameters (the scorer)
//!
//! [`compare_parameters`] sets an accepted effect's fitted parameters (the catalogue's
//! [`crate::diagnose::catalogue::AcceptedEffect`]; names and units in its effect modules) next
//! to what they should read given the sealed labels, where both measure one physical quantity.
//! The catalogue names effects as here, except `reverb_noise` for `reverb`
//! ([`Effect::from_catalogue_name`]). The error is detected/expected − 1.
//!
//! * **`non_rayleigh_damping`**: the detector's d at its three knots ("decay rate at F Hz",
//!   1/s) against the injected Zener law d(F); one error per case, the RMS over the knots of
//!   d/d_Zener − 1 ([`zener_knot_rms_error`]).
//! * **`beating_pair`**: the detector's relative split δ_c = ln f_u − ln f_l ≈ δf/f of a cluster
//!   ("relative split δf/f of cluster c (F Hz)", F the observed pair's centre) against the
//!   labels' split of the re-solved cluster over its centre, split_hz/f_centre (the total split,
//!   mesh asymmetry included, as the detector's δ replaces the simulated split). Clusters are
//!   paired one to one by centre frequency within [`SPLIT_PAIRING_TOLERANCE`]
//!   ([`pair_by_frequency`]); one error per pair; unpaired detected splits are reported.
//! * **`support_contact`**: not compared. The detector's Δd_k = γ w_k with w_k the fraction of
//!   mode k's energy at the *CLI's* candidate region, which the report does not carry; the
//!   labels hold the true Δd_k = ½ Σ_i (c_n φ_iz² + c_t(φ_ix² + φ_iy²)) per mode, so only γ
//!   (Δd at w = 1) and the largest true Δd are listed side by side.
//! * **`contact_duration`**: the shapes differ. The generator's Hertz force sin^(3/2)(πt/T_H)
//!   and the detector's half-sine sin(πt/T) are both sin^ν(πt/T) pulses, whose spectrum is
//!   F(x)/F(0) = Γ(1 + ν/2)² / (Γ(1 + (ν + b)/2) Γ(1 + (ν − b)/2)), b = x/π, x = ωT (up to the
//!   phase e^(−ix/2)): first zero at x = (ν + 2)π (3π for the half-sine, 3.5π for Hertz), and
//!   at low frequency |F| ≈ 1 − x²σ²/2 with σ² = ψ′(1 + ν/2)/(2π²) the pulse's variance in
//!   units of T² (ψ′ the trigamma function: 1/4 − 2/π² = 0.04736 for ν = 1,
//!   (π² − 8G − 16/9)/(2π²) = 0.03871 for ν = 3/2, G Catalan's constant). A half-sine matches
//!   a Hertz pulse of duration T_H at low frequency when T/T_H = σ_H/σ_1 = 0.9041, at the
//!   −3 dB frequency when T/T_H = 3.7352/4.1464 = 0.9008, at the first zero when
//!   T/T_H = 3/3.5 = 6/7 ([`contact_shape_ratios`]). So a constant ratio ≈ 0.90 is expected
//!   while the modes lie in the main lobe, but not beyond it: the detector bounds T by
//!   2.9π/ω_max (ω_max its highest matched mode) and cannot follow the Hertz side lobes. The
//!   expected T is therefore fitted per case exactly as the detector's model would fit it
//!   without noise: the half-sine low-pass plus a constant against the labels' Hertz
//!   attenuation of each mode the detector matched ([`equivalent_half_sine_duration`]). The
//!   raw ratio T/T_H is reported beside it.
//! * **`reverb`**: the detector's T60 of the excess residual energy e^(−13.8 t/T60) against the
//!   room tail's T60: the same definition (60 dB of energy). (The residual's excess also holds
//!   the modes' own reverberated tails; when a mode decays more slowly than the room, the
//!   excess follows it.)
//! * **`radiation`**: the transfer variant's η against 1: the generator radiates through the
//!   same multipole transfer the CLI computes, so a right model finds η = 1. The factor
//!   variant is not compared: the labels' strength is the energy-weighted RMS of what a
//!   per-mode + per-microphone dB model leaves of the multipole transfers, and u_k v_c (an
//!   unweighted rank-one factor on the fit channels) is a different quantity.
//! * **`added_mass`**: the detector's μ is *not* the mass fraction. In its model
//!   Δ ln f_k = −½ ln(1 + μ w_k) with w_k = |φ_k|² at its candidate region over the largest
//!   over the modes: μ = Δm |φ|²_max, the added modal mass of the most affected mode relative
//!   to its own (mass-normalised φ), which depends on where the mass sits in the mode shapes.
//!   The same quantity follows from the labels mode by mode: Δm|φ_k(x)|² = (f_base,k/f_k)² − 1
//!   ([`modal_mass_loading`]; the k-th sorted frequency only falls, so base and loaded lists
//!   compare index by index). Expected μ: its largest value over the rendered modes; for the
//!   `fluid_loading` variant (Δ ln f_k = −½ ln(1 + μ_f f_1/f_k)) μ_f is the lowest mode's
//!   loading, so the lowest mode's. Only when no other FEM effect (`beating_pair`,
//!   `support_contact`) moved the frequencies of the case; the mass fraction is listed as the
//!   labels' truth.
//! * **`pitch_glide`**: the generator's g is the relative offset at t = 0 of every mode,
//!   f(t) = f₀(1 + g e^(−2dt)). Reports whose glide observable is the chirp fit's offset at the
//!   onset (`glide_observable = "offset_at_onset"`, the CLI since the chirp-aware stage of
//!   [`crate::analysis::extract::glide`]) detect that same g: expected = the labels' g. For
//!   older reports the detector's g is the early-minus-late frequency
//!   difference y = (f_early − f_late)/f of its most energetic mode (largest mean_c a_c²/ω²),
//!   with f_early, f_late fitted on the two halves of the analysis span L after the onset. A
//!   least-squares frequency of a decaying tone with a slowly varying phase θ(t) is, to first
//!   order, the slope of the regression of θ on t weighted by the amplitude² w = e^(−2dt).
//!   With θ = 2πf₀(t + g Φ), Φ(t) = (1 − e^(−2dt))/(2d), the half [a, a + L/2] gives
//!   f/f₀ = 1 + g e^(−2da) E(L/2), E(h) the w-weighted regression slope of Φ on [0, h], so
//!   y = g (1 − e^(−dL)) E(L/2) ([`glide_half_contrast`]: 0 without decay, → ¼ for dL ≫ 1).
//!   Expected detector g: y of the labels' most energetic mode among those matched. The
//!   detector's model y_k = g Q_k² is itself misspecified for this law (the injected y_k
//!   depends on d_k, not on the energy), so only its reference mode is like for like. This
//!   is a first-order reference, exact for one least-squares tone per half: measured with
//!   [`crate::analysis::extract_modes`] on each half of 1 s of three gliding modes
//!   (g = 0.3 %, d = 4, 12, 27 1/s, about 60 dB SNR), each half of a mode came out as about
//!   four poles spread over a few Hz, and the loudest pole's y/g was 0.37, 0.22, (late half
//!   lost) against 0.31, 0.25, 0.25 here. What the diagnosis reports as early and late
//!   frequencies (which pole, or a merge) sets the true factor.

use std::f64::consts::PI;

use rustfft::num_complex::Complex64;
use serde::{Deserialize, Serialize};

use crate::audio::synth::{render_samples, ModalBank};
use crate::diagnose::catalogue::{
    sine_power_duration, AcceptedEffect, FittedParam, FIRST_NULL_PARAM,
};
use crate::mesh::TetMesh;
// The mesh helpers the generator shares with the diagnosis live with the mesh; re-exported
// here for the benchmark's examples.
pub use crate::mesh::locate::{
    nearest_points, nearest_surface_vertices, strike_candidates, support_nodes,
};

/// Everything that can be wrong with the input of this module.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum InjectError {
    #[error("unknown effect {0:?}; known effects: non_rayleigh_damping, beating_pair, support_contact, contact_duration, reverb, radiation, added_mass, pitch_glide")]
    UnknownEffect(String),
    #[error("{what} must be {requirement}, got {value}")]
    BadParameter {
        what: &'static str,
        requirement: &'static str,
        value: f64,
    },
    #[error("{what}: {got} values, expected {expected}")]
    LengthMismatch {
        what: &'static str,
        got: usize,
        expected: usize,
    },
    #[error("{0}")]
    Empty(&'static str),
    #[error("labels: {0}")]
    Label(String),
    #[error("diagnosis report: {0}")]
    Report(String),
}

fn require(
    ok: bool,
    what: &'static str,
    requirement: &'static str,
    value: f64,
) -> Result<(), InjectError> {
    if ok && value.is_finite() {
        Ok(())
    } else {
        Err(InjectError::BadParameter {
            what,
            requirement,
            value,
        })
    }
}

// ---------------------------------------------------------------------------------------------
// Randomness
// ---------------------------------------------------------------------------------------------

pub use crate::random::SplitMix64;

// ---------------------------------------------------------------------------------------------
// The catalogue
// ---------------------------------------------------------------------------------------------

/// An effect the generator can hide; serialised as its label (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Effect {
    NonRayleighDamping,
    BeatingPair,
    SupportContact,
    ContactDuration,
    Reverb,
    Radiation,
    AddedMass,
    PitchGlide,
}

/// How an effect's strength u ∈ [0, 1] maps onto its main parameter.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct StrengthScale {
    pub parameter: &'static str,
    pub unit: &'static str,
    /// The parameter at u = 0 (weakest realistic) and u = 1 (strongest).
    pub weakest: f64,
    pub strongest: f64,
    /// Interpolate ln(parameter) (true) or the parameter itself.
    pub logarithmic: bool,
    /// The strength is measured from the case (not drawn): see [`Effect::Radiation`].
    pub measured: bool,
}

impl StrengthScale {
    /// The parameter at strength `u` (clamped to [0, 1]).
    pub fn value(&self, u: f64) -> f64 {
        let u = u.clamp(0.0, 1.0);
        if self.logarithmic {
            (self.weakest.ln() + u * (self.strongest.ln() - self.weakest.ln())).exp()
        } else {
            self.weakest + u * (self.strongest - self.weakest)
        }
    }

    /// The strength of a parameter value (inverse of [`Self::value`], clamped to [0, 1]).
    pub fn strength_of(&self, value: f64) -> f64 {
        let u = if self.logarithmic {
            (value.ln() - self.weakest.ln()) / (self.strongest.ln() - self.weakest.ln())
        } else {
            (value - self.weakest) / (self.strongest - self.weakest)
        };
        if u.is_nan() {
            0.0
        } else {
            u.clamp(0.0, 1.0)
        }
    }
}

impl Effect {
    pub const ALL: [Effect; 8] = [
        Effect::NonRayleighDamping,
        Effect::BeatingPair,
        Effect::SupportContact,
        Effect::ContactDuration,
        Effect::Reverb,
        Effect::Radiation,
        Effect::AddedMass,
        Effect::PitchGlide,
    ];

    /// The label.
    pub fn name(self) -> &'static str {
        match self {
            Effect::NonRayleighDamping => "non_rayleigh_damping",
            Effect::BeatingPair => "beating_pair",
            Effect::SupportContact => "support_contact",
            Effect::ContactDuration => "contact_duration",
            Effect::Reverb => "reverb",
            Effect::Radiation => "radiation",
            Effect::AddedMass => "added_mass",
            Effect::PitchGlide => "pitch_glide",
        }
    }

    pub fn from_name(name: &str) -> Result<Effect, InjectError> {
        let name = name.trim();
        Effect::ALL
            .into_iter()
            .find(|e| e.name() == name)
            .ok_or_else(|| InjectError::UnknownEffect(name.to_string()))
    }

    /// Effects that change K or M, so the modes must be solved again.
    pub fn changes_fem(self) -> bool {
        matches!(
            self,
            Effect::BeatingPair | Effect::SupportContact | Effect::AddedMass
        )
    }

    /// The realistic range of the effect's main parameter (module docs).
    pub fn strength_scale(self) -> StrengthScale {
        let s = |parameter, unit, weakest, strongest, logarithmic| StrengthScale {
            parameter,
            unit,
            weakest,
            strongest,
            logarithmic,
            measured: false,
        };
        match self {
            Effect::NonRayleighDamping => {
                s("relaxation_strength / loss_factor", "-", 0.5, 5.0, true)
            }
            Effect::BeatingPair => s("density_increase", "-", 0.002, 0.02, true),
            Effect::SupportContact => s("bounce_frequency", "Hz", 20.0, 150.0, true),
            Effect::ContactDuration => s("contact_duration", "s", 0.05e-3, 0.6e-3, true),
            Effect::Reverb => s("direct_to_reverberant_ratio", "dB", 15.0, 0.0, false),
            Effect::Radiation => StrengthScale {
                measured: true,
                ..s("rank_one_level_misfit", "dB", 0.0, 10.0, false)
            },
            Effect::AddedMass => s("mass_fraction", "-", 0.01, 0.10, true),
            Effect::PitchGlide => s("glide", "-", 0.0005, 0.005, true),
        }
    }
}

impl std::fmt::Display for Effect {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Parses a comma-separated list of effect names (`all` for the whole catalogue).
pub fn parse_effect_list(list: &str) -> Result<Vec<Effect>, InjectError> {
    if list.trim() == "all" {
        return Ok(Effect::ALL.to_vec());
    }
    let mut out = Vec::new();
    for name in list.split(',').filter(|s| !s.trim().is_empty()) {
        let e = Effect::from_name(name)?;
        if !out.contains(&e) {
            out.push(e);
        }
    }
    if out.is_empty() {
        return Err(InjectError::Empty("the effect list is empty"));
    }
    Ok(out)
}

/// The effects of each of `n_cases` cases: round(0.3 n) clean, round(0.3 n) with two different
/// effects (none if the pool has fewer than two), the rest with one; the case order is
/// shuffled and the effects come from a shuffled deck of `pool`, refilled when empty, so every
/// effect appears about equally often. Each case's list is sorted.
pub fn schedule_effects(n_cases: usize, pool: &[Effect], rng: &mut SplitMix64) -> Vec<Vec<Effect>> {
    if pool.is_empty() {
        return vec![Vec::new(); n_cases];
    }
    let n_clean = (0.3 * n_cases as f64).round() as usize;
    let n_two = if pool.len() >= 2 {
        ((0.3 * n_cases as f64).round() as usize).min(n_cases - n_clean)
    } else {
        0
    };
    let mut sizes: Vec<usize> = std::iter::repeat_n(0, n_clean)
        .chain(std::iter::repeat_n(2, n_two))
        .collect();
    sizes.resize(n_cases, 1);
    rng.shuffle(&mut sizes);
    let mut deck: Vec<Effect> = Vec::new();
    let mut draw = |rng: &mut SplitMix64, avoid: Option<Effect>| -> Effect {
        loop {
            if deck.is_empty() {
                deck = pool.to_vec();
                rng.shuffle(&mut deck);
            }
            // Take the first card that differs from `avoid` (there is one unless the deck
            // holds only `avoid`, in which case it is refilled).
            match deck.iter().position(|&e| Some(e) != avoid) {
                Some(i) => return deck.remove(i),
                None => deck.clear(),
            }
        }
    };
    sizes
        .into_iter()
        .map(|size| {
            let mut effects = Vec::with_capacity(size);
            for _ in 0..size {
                let e = draw(rng, effects.first().copied());
                effects.push(e);
            }
            effects.sort();
            effects
        })
        .collect()
}

// ---------------------------------------------------------------------------------------------
// Damping
// ---------------------------------------------------------------------------------------------

/// d(f) = π f (η + Δ x/(1 + x²)), x = f/f_c: a constant loss factor plus a Zener relaxation
/// peak (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ZenerDamping {
    /// η, the frequency-independent loss factor.
    pub loss_factor: f64,
    /// Δ, the relaxation strength (the loss-factor peak is Δ/2 at f_c).
    pub relaxation_strength: f64,
    /// f_c [Hz].
    pub corner_hz: f64,
}

impl ZenerDamping {
    /// The decay rate [1/s] at undamped frequency `f` [Hz].
    pub fn decay(&self, f: f64) -> f64 {
        let x = f / self.corner_hz;
        PI * f * (self.loss_factor + self.relaxation_strength * x / (1.0 + x * x))
    }

    /// The law with Δ = `ratio`·η and corner `corner_hz` whose decay at `reference_hz` equals
    /// `reference_decay` [1/s].
    pub fn matched(
        reference_hz: f64,
        reference_decay: f64,
        ratio: f64,
        corner_hz: f64,
    ) -> Result<ZenerDamping, InjectError> {
        require(
            reference_hz > 0.0,
            "reference frequency",
            "positive (Hz)",
            reference_hz,
        )?;
        require(
            reference_decay > 0.0,
            "reference decay rate",
            "positive (1/s)",
            reference_decay,
        )?;
        require(
            ratio >= 0.0,
            "relaxation strength / loss factor",
            "≥ 0",
            ratio,
        )?;
        require(
            corner_hz > 0.0,
            "corner frequency",
            "positive (Hz)",
            corner_hz,
        )?;
        let x = reference_hz / corner_hz;
        let loss_factor = reference_decay / (PI * reference_hz * (1.0 + ratio * x / (1.0 + x * x)));
        Ok(ZenerDamping {
            loss_factor,
            relaxation_strength: ratio * loss_factor,
            corner_hz,
        })
    }
}

/// The best Rayleigh law for decays `decays` [1/s] at undamped frequencies `frequencies_hz`:
/// (α [1/s], β [s], RMS of ln(d_fit/d)). Minimises Σ ((α + βω²)/2 − d)²/d² (relative error)
/// over α, β ≥ 0 (the 2 × 2 normal equations, then each bound if violated).
pub fn rayleigh_fit(
    frequencies_hz: &[f64],
    decays: &[f64],
) -> Result<(f64, f64, f64), InjectError> {
    if frequencies_hz.len() != decays.len() {
        return Err(InjectError::LengthMismatch {
            what: "decay rates",
            got: decays.len(),
            expected: frequencies_hz.len(),
        });
    }
    if frequencies_hz.is_empty() {
        return Err(InjectError::Empty("no modes to fit a Rayleigh law to"));
    }
    for (&f, &d) in frequencies_hz.iter().zip(decays) {
        require(f > 0.0, "frequency", "positive (Hz)", f)?;
        require(d > 0.0, "decay rate", "positive (1/s)", d)?;
    }
    // Rows (½/d, ½ω²/(d ω_r²)) against 1, with ω_r² the mean ω² so that both columns are of
    // one scale (the second unknown is β ω_r²).
    let omega_r2 = frequencies_hz
        .iter()
        .map(|f| (2.0 * PI * f).powi(2))
        .sum::<f64>()
        / frequencies_hz.len() as f64;
    let rows: Vec<(f64, f64)> = frequencies_hz
        .iter()
        .zip(decays)
        .map(|(&f, &d)| (0.5 / d, 0.5 * (2.0 * PI * f).powi(2) / (d * omega_r2)))
        .collect();
    let (mut s11, mut s12, mut s22, mut b1, mut b2) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for &(a, b) in &rows {
        s11 += a * a;
        s12 += a * b;
        s22 += b * b;
        b1 += a;
        b2 += b;
    }
    let det = s11 * s22 - s12 * s12;
    let mut candidates = Vec::new();
    if det > 1e-12 * s11 * s22 {
        candidates.push(((b1 * s22 - b2 * s12) / det, (s11 * b2 - s12 * b1) / det));
    }
    candidates.push((b1 / s11, 0.0));
    candidates.push((0.0, b2 / s22));
    let misfit = |alpha: f64, beta: f64| {
        rows.iter()
            .map(|&(a, b)| (alpha * a + beta * b - 1.0).powi(2))
            .sum::<f64>()
    };
    let (alpha, beta_scaled) = candidates
        .into_iter()
        .filter(|&(a, b)| a >= 0.0 && b >= 0.0)
        .min_by(|x, y| misfit(x.0, x.1).total_cmp(&misfit(y.0, y.1)))
        .expect("the single-parameter fits are non-negative");
    let beta = beta_scaled / omega_r2;
    let log_rms = (frequencies_hz
        .iter()
        .zip(decays)
        .map(|(&f, &d)| {
            (0.5 * (alpha + beta * (2.0 * PI * f).powi(2)) / d)
                .ln()
                .powi(2)
        })
        .sum::<f64>()
        / decays.len() as f64)
        .sqrt();
    Ok((alpha, beta, log_rms))
}

// ---------------------------------------------------------------------------------------------
// Hertz contact
// ---------------------------------------------------------------------------------------------

/// ∫₀¹ sin^(3/2)(πu) du = Γ(5/4)/(√π Γ(7/4)).
pub const HERTZ_SHAPE_AREA: f64 = 0.556_417_894_449_382_2;

/// The Hertz contact force F(t) = sin^(3/2)(πt/T)/(T C) on [0, T] (unit area; module docs).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct HertzPulse {
    /// T [s].
    pub duration_s: f64,
}

impl HertzPulse {
    pub fn new(duration_s: f64) -> Result<HertzPulse, InjectError> {
        require(
            duration_s > 0.0 && duration_s <= 0.1,
            "contact duration",
            "in (0, 0.1] s",
            duration_s,
        )?;
        Ok(HertzPulse { duration_s })
    }

    /// F(t) [1/s].
    pub fn force(&self, t: f64) -> f64 {
        if !(0.0..=self.duration_s).contains(&t) {
            return 0.0;
        }
        (PI * t / self.duration_s).sin().max(0.0).powf(1.5) / (self.duration_s * HERTZ_SHAPE_AREA)
    }

    /// F̃(s) = ∫₀ᵀ F(t) e^(−st) dt for complex s [1/s] (module docs: quadrature after
    /// t = T(3u² − 2u³)). F̃(0) = 1 to rounding.
    pub fn laplace(&self, s: Complex64) -> Complex64 {
        let tau = self.duration_s;
        // In the middle dt/du = 1.5 T, so one panel of width 1/P spans 1.5|s|T/P radians of
        // oscillation; two radians per 16-point panel resolve it to rounding.
        let panels = ((1.5 * s.norm() * tau / 2.0).ceil() as usize).clamp(4, 4000);
        let (nodes, weights) = crate::fem::quadrature::gauss_legendre_01(16);
        let mut sum = Complex64::new(0.0, 0.0);
        let h = 1.0 / panels as f64;
        for p in 0..panels {
            for (x, w) in nodes.iter().zip(&weights) {
                let u = (p as f64 + x) * h;
                let t = tau * u * u * (3.0 - 2.0 * u);
                let dt_du = 6.0 * tau * u * (1.0 - u);
                let shape = (PI * t / tau).sin().max(0.0).powf(1.5);
                sum += (-s * t).exp() * (shape * dt_du * w * h);
            }
        }
        sum / (tau * HERTZ_SHAPE_AREA)
    }
}

// ---------------------------------------------------------------------------------------------
// Rendering (with or without pitch glide)
// ---------------------------------------------------------------------------------------------

/// One mode as heard by every channel: x_c(t) = Im(z_c e^(iθ(t))) e^(−dt), θ = 2πf t without
/// glide ([`glide_phase`] with it).
#[derive(Clone, Debug, PartialEq)]
pub struct ModeTrack {
    /// f₀ [Hz], the damped (small-amplitude) frequency.
    pub frequency_hz: f64,
    /// d [1/s].
    pub decay_rate: f64,
    /// z_c = a_c e^(iφ_c) per channel (output units).
    pub amplitudes: Vec<Complex64>,
}

/// θ(t) [rad], the exact phase of a glide f(t) = f₀(1 + g e^(−2dt)): one function for the
/// generator and the extraction that measures it.
pub use crate::analysis::extract::glide::glide_phase;

/// Renders `n_channels` channels of `n_samples` samples at `sample_rate` [Hz] from `tracks`,
/// with relative pitch glide g (`glide`, module docs) or without (then each channel is a
/// [`crate::audio::synth`] bank). Modes whose highest frequency f₀(1 + g) is not strictly
/// between 0 and the Nyquist frequency are skipped, as the synthesiser does.
pub fn render_tracks(
    tracks: &[ModeTrack],
    n_channels: usize,
    sample_rate: f64,
    n_samples: usize,
    glide: Option<f64>,
) -> Result<Vec<Vec<f64>>, InjectError> {
    require(
        sample_rate > 0.0,
        "sample rate",
        "positive (Hz)",
        sample_rate,
    )?;
    for t in tracks {
        if t.amplitudes.len() != n_channels {
            return Err(InjectError::LengthMismatch {
                what: "mode amplitudes per channel",
                got: t.amplitudes.len(),
                expected: n_channels,
            });
        }
        require(
            t.decay_rate >= 0.0,
            "decay rate",
            "finite and ≥ 0 (1/s)",
            t.decay_rate,
        )?;
        require(
            t.frequency_hz.is_finite(),
            "mode frequency",
            "finite (Hz)",
            t.frequency_hz,
        )?;
    }
    let glide = match glide {
        None => {
            return Ok((0..n_channels)
                .map(|c| {
                    let bank = ModalBank {
                        frequencies_hz: tracks.iter().map(|t| t.frequency_hz).collect(),
                        decay_rates: tracks.iter().map(|t| t.decay_rate).collect(),
                        amplitudes: tracks.iter().map(|t| t.amplitudes[c].norm()).collect(),
                        phases: tracks.iter().map(|t| t.amplitudes[c].arg()).collect(),
                    };
                    render_samples(&bank, sample_rate, n_samples)
                })
                .collect());
        }
        Some(g) => g,
    };
    require(glide > -1.0, "pitch glide", "finite and > −1", glide)?;
    let mut out = vec![vec![0.0; n_samples]; n_channels];
    for t in tracks {
        let top = t.frequency_hz * (1.0 + glide.max(0.0));
        if !(t.frequency_hz > 0.0 && top < 0.5 * sample_rate) {
            continue;
        }
        for n in 0..n_samples {
            let time = n as f64 / sample_rate;
            let envelope = (-t.decay_rate * time).exp();
            let (sin, cos) = glide_phase(t.frequency_hz, t.decay_rate, glide, time).sin_cos();
            // Im(z e^(iθ)) = Re z sin θ + Im z cos θ.
            for (channel, z) in out.iter_mut().zip(&t.amplitudes) {
                channel[n] += envelope * (z.re * sin + z.im * cos);
            }
        }
    }
    Ok(out)
}

// ---------------------------------------------------------------------------------------------
// Room and noise
// ---------------------------------------------------------------------------------------------

/// A synthetic room impulse response (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RoomResponse {
    /// T60 [s]: time for the tail's energy to fall by 60 dB.
    pub t60_s: f64,
    /// Direct-to-reverberant energy ratio [dB].
    pub direct_to_reverberant_db: f64,
    /// Delay of the tail after the direct sound [s].
    pub predelay_s: f64,
}

impl RoomResponse {
    /// One realisation at `sample_rate` [Hz], at most `max_len` samples (and at most the
    /// pre-delay + 1.5 T60).
    pub fn impulse_response(
        &self,
        sample_rate: f64,
        max_len: usize,
        rng: &mut SplitMix64,
    ) -> Result<Vec<f64>, InjectError> {
        require(
            sample_rate > 0.0,
            "sample rate",
            "positive (Hz)",
            sample_rate,
        )?;
        require(self.t60_s > 0.0, "T60", "positive (s)", self.t60_s)?;
        require(
            self.predelay_s >= 0.0,
            "pre-delay",
            "≥ 0 (s)",
            self.predelay_s,
        )?;
        require(
            true,
            "direct-to-reverberant ratio",
            "finite (dB)",
            self.direct_to_reverberant_db,
        )?;
        let start = ((self.predelay_s * sample_rate).round() as usize).max(1);
        let len = (start + (1.5 * self.t60_s * sample_rate).ceil() as usize).min(max_len);
        if len <= start {
            return Err(InjectError::BadParameter {
                what: "room response length",
                requirement: "longer than the pre-delay",
                value: max_len as f64,
            });
        }
        let rate = 3.0 * 10f64.ln() / (self.t60_s * sample_rate); // amplitude decay per sample
        let mut h = vec![0.0; len];
        h[0] = 1.0;
        for (n, v) in h.iter_mut().enumerate().skip(start) {
            *v = rng.normal() * (-rate * n as f64).exp();
        }
        let tail: f64 = h[start..].iter().map(|v| v * v).sum();
        let scale = (10f64.powf(-self.direct_to_reverberant_db / 10.0) / tail).sqrt();
        h[start..].iter_mut().for_each(|v| *v *= scale);
        Ok(h)
    }
}

/// y = x * h (linear convolution by FFT), cut to the length of x.
pub fn convolve_truncated(x: &[f64], h: &[f64]) -> Vec<f64> {
    if x.is_empty() || h.is_empty() {
        return vec![0.0; x.len()];
    }
    let n = (x.len() + h.len() - 1).next_power_of_two();
    let mut planner = rustfft::FftPlanner::<f64>::new();
    let forward = planner.plan_fft_forward(n);
    let inverse = planner.plan_fft_inverse(n);
    let pad = |v: &[f64]| -> Vec<Complex64> {
        let mut out: Vec<Complex64> = v.iter().map(|&r| Complex64::new(r, 0.0)).collect();
        out.resize(n, Complex64::new(0.0, 0.0));
        out
    };
    let (mut a, mut b) = (pad(x), pad(h));
    forward.process(&mut a);
    forward.process(&mut b);
    a.iter_mut().zip(&b).for_each(|(p, q)| *p *= q);
    inverse.process(&mut a);
    a[..x.len()].iter().map(|v| v.re / n as f64).collect()
}

/// T60 [s] of an impulse response from the slope of its Schroeder energy decay curve
/// EDC(n) = Σ_{m≥n} h[m]² (from `start`), fitted by least squares between `from_db` and
/// `to_db` below its start (e.g. −5 and −35: T30) and extrapolated to −60 dB.
pub fn schroeder_t60(
    h: &[f64],
    sample_rate: f64,
    start: usize,
    from_db: f64,
    to_db: f64,
) -> Result<f64, InjectError> {
    if start >= h.len() {
        return Err(InjectError::Empty(
            "no samples after the start of the decay",
        ));
    }
    let mut edc = vec![0.0; h.len() - start];
    let mut acc = 0.0;
    for (i, v) in h[start..].iter().enumerate().rev() {
        acc += v * v;
        edc[i] = acc;
    }
    let total = edc[0];
    if total <= 0.0 {
        return Err(InjectError::Empty("the impulse response has no energy"));
    }
    let (mut sx, mut sy, mut sxx, mut sxy, mut count) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (i, &e) in edc.iter().enumerate() {
        let db = 10.0 * (e / total).log10();
        if db <= from_db && db >= to_db {
            let t = i as f64 / sample_rate;
            sx += t;
            sy += db;
            sxx += t * t;
            sxy += t * db;
            count += 1.0;
        }
    }
    if count < 2.0 {
        return Err(InjectError::Empty(
            "the decay curve does not span the fitting range",
        ));
    }
    let slope = (count * sxy - sx * sy) / (count * sxx - sx * sx); // dB/s
    Ok(-60.0 / slope)
}

/// The spectral colour of the background noise.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NoiseColour {
    White,
    Pink,
}

/// Lower corner of the pink shaping [Hz]: below it the spectrum is flat.
pub const PINK_FLOOR_HZ: f64 = 20.0;

/// `n` samples of zero-mean noise of unit RMS (module docs).
pub fn coloured_noise(
    n: usize,
    colour: NoiseColour,
    sample_rate: f64,
    rng: &mut SplitMix64,
) -> Vec<f64> {
    let mut x: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
    if colour == NoiseColour::Pink && n > 1 {
        let mut planner = rustfft::FftPlanner::<f64>::new();
        let mut spec: Vec<Complex64> = x.iter().map(|&v| Complex64::new(v, 0.0)).collect();
        planner.plan_fft_forward(n).process(&mut spec);
        for (k, v) in spec.iter_mut().enumerate() {
            let f = k.min(n - k) as f64 * sample_rate / n as f64;
            *v *= if k == 0 {
                0.0
            } else {
                1.0 / f.max(PINK_FLOOR_HZ).sqrt()
            };
        }
        planner.plan_fft_inverse(n).process(&mut spec);
        x = spec.iter().map(|v| v.re).collect();
    }
    let rms = crate::audio::rms(&x);
    if rms > 0.0 {
        x.iter_mut().for_each(|v| *v /= rms);
    }
    x
}

/// Adds independent noise of one level to every channel so that the mean signal power over
/// `signal` (sample range, averaged over channels) is `snr_db` above the noise power. Returns
/// the noise RMS.
pub fn add_noise(
    channels: &mut [Vec<f64>],
    signal: std::ops::Range<usize>,
    snr_db: f64,
    colour: NoiseColour,
    sample_rate: f64,
    rng: &mut SplitMix64,
) -> Result<f64, InjectError> {
    require(true, "SNR", "finite (dB)", snr_db)?;
    if channels.is_empty() {
        return Err(InjectError::Empty("no channels to add noise to"));
    }
    let len = channels[0].len();
    if let Some(c) = channels.iter().find(|c| c.len() != len) {
        return Err(InjectError::LengthMismatch {
            what: "channel samples",
            got: c.len(),
            expected: len,
        });
    }
    if signal.start >= signal.end || signal.end > len {
        return Err(InjectError::Empty(
            "the signal window is empty or outside the channels",
        ));
    }
    let power = channels
        .iter()
        .map(|c| c[signal.clone()].iter().map(|v| v * v).sum::<f64>() / signal.len() as f64)
        .sum::<f64>()
        / channels.len() as f64;
    require(power > 0.0, "signal power", "positive", power)?;
    let noise_rms = (power / 10f64.powf(snr_db / 10.0)).sqrt();
    for c in channels.iter_mut() {
        let noise = coloured_noise(len, colour, sample_rate, rng);
        c.iter_mut()
            .zip(&noise)
            .for_each(|(v, n)| *v += noise_rms * n);
    }
    Ok(noise_rms)
}

// ---------------------------------------------------------------------------------------------
// Geometry: strike, support, added mass, stiffened sector
// ---------------------------------------------------------------------------------------------

use crate::numerics::{dot, median};

fn unit(a: [f64; 3]) -> [f64; 3] {
    let n = dot(a, a).sqrt();
    [a[0] / n, a[1] / n, a[2] / n]
}

/// The mesh with the same nodes and only the tets whose corner centroid lies in the wedge
/// (sector) start ≤ ψ < start + width [rad] of azimuth ψ about the axis through `point` along
/// `axis`. ψ is measured from the projection of x̂ (of ŷ if the axis is along x) onto the plane
/// normal to the axis, counter-clockwise seen from +axis. Assembling it gives the stiffness of
/// that sector in the same node numbering.
///
/// Why a sector and not a half-space: on a body of revolution, the two modes of a pair vary as
/// cos nψ and sin nψ, and a stiffness change δ(ψ) splits them at first order in proportion to
/// its Fourier coefficient at 2n. A half-space through the axis is a square wave in ψ, which
/// has odd harmonics only, so it shifts both modes alike and splits nothing; a sector of width
/// w has 2n-th coefficient ∝ sin(n w)/n, non-zero for every n when w/π is not a simple
/// fraction. The density matters as much as the stiffness: on the bowl
/// (`examples/bowl`) stiffening a sector by 1.5 % left its lowest pair's split at 3.49 Hz (the
/// strain energy of those bending modes is nearly even in ψ), while the kinetic energy, mostly
/// radial motion ∝ cos² nψ, is not.
pub fn sector_mesh(
    mesh: &TetMesh,
    point: [f64; 3],
    axis: [f64; 3],
    start: f64,
    width: f64,
) -> TetMesh {
    let a = unit(axis);
    let reference = if a[0].abs() < 0.9 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let along = dot(reference, a);
    let e1 = unit([
        reference[0] - along * a[0],
        reference[1] - along * a[1],
        reference[2] - along * a[2],
    ]);
    let e2 = [
        a[1] * e1[2] - a[2] * e1[1],
        a[2] * e1[0] - a[0] * e1[2],
        a[0] * e1[1] - a[1] * e1[0],
    ];
    let npt = mesh.nodes_per_tet();
    let mut connectivity = Vec::new();
    for e in 0..mesh.n_tets() {
        let corners = mesh.corner_coords(e);
        let r = [0, 1, 2].map(|d| 0.25 * corners.iter().map(|x| x[d]).sum::<f64>() - point[d]);
        let psi = dot(r, e2).atan2(dot(r, e1));
        if (psi - start).rem_euclid(2.0 * PI) < width {
            connectivity.extend_from_slice(&mesh.connectivity[e * npt..(e + 1) * npt]);
        }
    }
    TetMesh {
        nodes: mesh.nodes.clone(),
        connectivity,
        order: mesh.order,
    }
}

/// Δd = ½ Σ_i (c_n (φ_i·v)² + c_t (|φ_i|² − (φ_i·v)²)) [1/s] for one mass-normalised mode with
/// displacement `values` [kg^(−½)] at the support nodes, normal dashpot `c_normal` and
/// tangential `c_tangential` per node [N·s/m], v the unit support direction.
pub fn support_damping(
    values: &[[f64; 3]],
    c_normal: f64,
    c_tangential: f64,
    down: [f64; 3],
) -> f64 {
    let v = unit(down);
    0.5 * values
        .iter()
        .map(|phi| {
            let n2 = dot(*phi, v).powi(2);
            c_normal * n2 + c_tangential * (dot(*phi, *phi) - n2)
        })
        .sum::<f64>()
}

/// RMS [dB] of the residual of 20 log₁₀|H_kc| after the best additive fit a_k + b_c (a level per
/// mode, a gain per channel: what a rank-1 amplitude model can explain), with weights w_k per
/// mode (e.g. the mode's share of the energy). |H| below 1e-300 is floored. Alternating
/// weighted least squares (converges in a few sweeps for this two-way layout).
pub fn rank_one_level_misfit_db(levels: &[Vec<f64>], weights: &[f64]) -> Result<f64, InjectError> {
    if levels.len() != weights.len() {
        return Err(InjectError::LengthMismatch {
            what: "mode weights",
            got: weights.len(),
            expected: levels.len(),
        });
    }
    let n_c = levels.first().map_or(0, Vec::len);
    if n_c == 0 {
        return Err(InjectError::Empty("no modes or no channels"));
    }
    if let Some(row) = levels.iter().find(|r| r.len() != n_c) {
        return Err(InjectError::LengthMismatch {
            what: "channel levels",
            got: row.len(),
            expected: n_c,
        });
    }
    let total_w: f64 = weights.iter().sum();
    require(total_w > 0.0, "total mode weight", "positive", total_w)?;
    let db: Vec<Vec<f64>> = levels
        .iter()
        .map(|r| {
            r.iter()
                .map(|&h| 20.0 * h.abs().max(1e-300).log10())
                .collect()
        })
        .collect();
    let mut a = vec![0.0; levels.len()];
    let mut b = vec![0.0; n_c];
    for _ in 0..50 {
        for (k, row) in db.iter().enumerate() {
            a[k] = row.iter().zip(&b).map(|(y, bc)| y - bc).sum::<f64>() / n_c as f64;
        }
        for c in 0..n_c {
            b[c] = db
                .iter()
                .zip(&a)
                .zip(weights)
                .map(|((row, ak), w)| w * (row[c] - ak))
                .sum::<f64>()
                / total_w;
        }
    }
    let ss: f64 = db
        .iter()
        .zip(&a)
        .zip(weights)
        .map(|((row, ak), w)| {
            w * row
                .iter()
                .zip(&b)
                .map(|(y, bc)| (y - ak - bc).powi(2))
                .sum::<f64>()
        })
        .sum();
    Ok((ss / (total_w * n_c as f64)).sqrt())
}

// ---------------------------------------------------------------------------------------------
// Labels and scoring
// ---------------------------------------------------------------------------------------------

/// One hidden effect of a case, as written to the sealed labels.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EffectLabel {
    pub effect: Effect,
    /// u ∈ [0, 1] (module docs).
    pub strength: f64,
    /// The injected parameters (names and units in the generator's docs).
    pub parameters: serde_json::Value,
}

/// The part of a sealed label file the scorer needs (the files hold more: material, modes,
/// noise, …; unknown fields are ignored).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CaseTruth {
    pub case: String,
    pub effects: Vec<EffectLabel>,
}

/// Scores of one effect.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EffectScore {
    pub effect: Effect,
    pub true_positives: usize,
    pub false_positives: usize,
    pub false_negatives: usize,
    /// TP/(TP + FP); `None` without detections.
    pub precision: Option<f64>,
    /// TP/(TP + FN); `None` without cases that hold the effect.
    pub recall: Option<f64>,
    /// 2TP/(2TP + FP + FN); `None` when the effect is neither present nor detected.
    pub f1: Option<f64>,
    /// (strength from, to, detected, present) per bin of equal width on [0, 1].
    pub recall_by_strength: Vec<(f64, f64, usize, usize)>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Score {
    pub per_effect: Vec<EffectScore>,
    /// Mean F1 over the effects that have one.
    pub macro_f1: Option<f64>,
    pub clean_cases: usize,
    /// Fraction of clean cases with at least one detection; `None` without clean cases.
    pub clean_false_positive_rate: Option<f64>,
}

/// Scores `detected` effects per case against the sealed `truth` (same order), with recall in
/// `strength_bins` bins.
pub fn score(
    truth: &[CaseTruth],
    detected: &[Vec<Effect>],
    strength_bins: usize,
) -> Result<Score, InjectError> {
    if truth.len() != detected.len() {
        return Err(InjectError::LengthMismatch {
            what: "detections (one list per case)",
            got: detected.len(),
            expected: truth.len(),
        });
    }
    let bins = strength_bins.max(1);
    let mut per_effect = Vec::new();
    for effect in Effect::ALL {
        let (mut tp, mut fp, mut fn_) = (0, 0, 0);
        let mut by_bin = vec![(0usize, 0usize); bins];
        for (t, d) in truth.iter().zip(detected) {
            let present = t.effects.iter().find(|l| l.effect == effect);
            let found = d.contains(&effect);
            match (present, found) {
                (Some(_), true) => tp += 1,
                (Some(_), false) => fn_ += 1,
                (None, true) => fp += 1,
                (None, false) => {}
            }
            if let Some(l) = present {
                let bin = ((l.strength.clamp(0.0, 1.0) * bins as f64) as usize).min(bins - 1);
                by_bin[bin].1 += 1;
                if found {
                    by_bin[bin].0 += 1;
                }
            }
        }
        let ratio = |num: usize, den: usize| (den > 0).then(|| num as f64 / den as f64);
        per_effect.push(EffectScore {
            effect,
            true_positives: tp,
            false_positives: fp,
            false_negatives: fn_,
            precision: ratio(tp, tp + fp),
            recall: ratio(tp, tp + fn_),
            f1: ratio(2 * tp, 2 * tp + fp + fn_),
            recall_by_strength: by_bin
                .iter()
                .enumerate()
                .map(|(i, &(hit, n))| {
                    (i as f64 / bins as f64, (i + 1) as f64 / bins as f64, hit, n)
                })
                .collect(),
        });
    }
    let f1s: Vec<f64> = per_effect.iter().filter_map(|s| s.f1).collect();
    let clean: Vec<usize> = truth
        .iter()
        .enumerate()
        .filter(|(_, t)| t.effects.is_empty())
        .map(|(i, _)| i)
        .collect();
    let alarms = clean.iter().filter(|&&i| !detected[i].is_empty()).count();
    Ok(Score {
        per_effect,
        macro_f1: (!f1s.is_empty()).then(|| f1s.iter().sum::<f64>() / f1s.len() as f64),
        clean_cases: clean.len(),
        clean_false_positive_rate: (!clean.is_empty()).then(|| alarms as f64 / clean.len() as f64),
    })
}

// ---------------------------------------------------------------------------------------------
// Parameters: what the detector's numbers should read, derived from the labels
// ---------------------------------------------------------------------------------------------

impl Effect {
    /// The effect named by the catalogue of [`crate::diagnose::catalogue`]: the same names,
    /// except `reverb_noise` for [`Effect::Reverb`].
    pub fn from_catalogue_name(name: &str) -> Result<Effect, InjectError> {
        match name.trim() {
            "reverb_noise" => Ok(Effect::Reverb),
            other => Effect::from_name(other),
        }
    }
}

/// Bisection for a sign change of `f` in [lo, hi] (f(lo) and f(hi) of opposite signs).
fn bisect(f: impl Fn(f64) -> f64, mut lo: f64, mut hi: f64) -> f64 {
    let f_lo = f(lo);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if (f(mid) > 0.0) == (f_lo > 0.0) {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo <= 1e-15 * hi.abs() {
            break;
        }
    }
    0.5 * (lo + hi)
}

/// σ²/T² of the pulse shape sin^p(πt/T) on [0, T]: ∫₀¹ s(u)(u − ½)² du / ∫₀¹ s(u) du, the
/// spread of the force about its centre (module docs, "Comparing parameters"). Gauss–Legendre
/// after u = 3v² − 2v³ as in [`HertzPulse::laplace`], so that the t^(p) ends are smooth.
pub fn sine_power_pulse_variance(power: f64) -> f64 {
    let (nodes, weights) = crate::fem::quadrature::gauss_legendre_01(16);
    let panels = 32;
    let (mut m0, mut m2) = (0.0, 0.0);
    for p in 0..panels {
        for (x, w) in nodes.iter().zip(&weights) {
            let v = (p as f64 + x) / panels as f64;
            let u = v * v * (3.0 - 2.0 * v);
            let s = (PI * u).sin().max(0.0).powf(power) * 6.0 * v * (1.0 - v) * w / panels as f64;
            m0 += s;
            m2 += s * (u - 0.5).powi(2);
        }
    }
    m2 / m0
}

/// The Hertz pulse's spectrum at x = ωT as a real amplitude: F̃(iω) e^(iωT/2) (the pulse is
/// symmetric about T/2, so this is real and changes sign at the spectrum's zeros).
fn hertz_amplitude(x: f64) -> f64 {
    let tau = 1e-3;
    let pulse = HertzPulse { duration_s: tau };
    (pulse.laplace(Complex64::new(0.0, x / tau)) * Complex64::new(0.0, 0.5 * x).exp()).re
}

/// How long a half-sine contact must last to look like a Hertz contact of duration T_H
/// (module docs, "Comparing parameters"): the x = ωT of the features of both spectra and the
/// ratios T_half-sine / T_Hertz that match them.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ContactShapeRatios {
    /// x = ωT where |F(x)/F(0)| = 1/√2, half-sine and Hertz.
    pub half_sine_minus_3db_x: f64,
    pub hertz_minus_3db_x: f64,
    /// x = ωT of the first zero (3π for the half-sine).
    pub half_sine_first_zero_x: f64,
    pub hertz_first_zero_x: f64,
    /// σ/T of the two force shapes ([`sine_power_pulse_variance`]).
    pub half_sine_spread: f64,
    pub hertz_spread: f64,
    /// T_half-sine / T_Hertz for the same low-frequency roll-off |F| ≈ 1 − ω²σ²/2 (equal σ).
    pub ratio_low_frequency: f64,
    /// … for the same −3 dB frequency.
    pub ratio_minus_3db: f64,
    /// … for the same first zero.
    pub ratio_first_zero: f64,
}

/// [`ContactShapeRatios`], computed (bisection on the closed-form half-sine spectrum of
/// [`crate::diagnose::catalogue::half_sine_spectrum`] and on [`HertzPulse::laplace`]).
pub fn contact_shape_ratios() -> ContactShapeRatios {
    use crate::diagnose::catalogue::half_sine_spectrum;
    let target = std::f64::consts::FRAC_1_SQRT_2;
    // Both magnitudes fall monotonically from 1 to 0 over their main lobes; |F| = π/4 > 1/√2
    // at x = π for the half-sine, so its −3 dB point lies in (π, 3π).
    let half_sine_minus_3db_x = bisect(|x| half_sine_spectrum(x) - target, PI, 3.0 * PI);
    // The Hertz shape is more peaked in time, so its main lobe is wider: scan for the first
    // sign change of its real amplitude.
    let mut hertz_first_zero_x = f64::NAN;
    let step = 0.05 * PI;
    let mut x = PI;
    while x < 12.0 * PI {
        if hertz_amplitude(x + step) <= 0.0 {
            hertz_first_zero_x = bisect(hertz_amplitude, x, x + step);
            break;
        }
        x += step;
    }
    let hertz_minus_3db_x = bisect(|x| hertz_amplitude(x) - target, 1e-6, hertz_first_zero_x);
    let half_sine_spread = sine_power_pulse_variance(1.0).sqrt();
    let hertz_spread = sine_power_pulse_variance(1.5).sqrt();
    ContactShapeRatios {
        half_sine_minus_3db_x,
        hertz_minus_3db_x,
        half_sine_first_zero_x: 3.0 * PI,
        hertz_first_zero_x,
        half_sine_spread,
        hertz_spread,
        ratio_low_frequency: hertz_spread / half_sine_spread,
        ratio_minus_3db: half_sine_minus_3db_x / hertz_minus_3db_x,
        ratio_first_zero: 3.0 * PI / hertz_first_zero_x,
    }
}

/// The half-sine duration T [s] the detector's model fits to mode levels attenuated by
/// `attenuation_db` [dB] (20 log₁₀|F̃|, e.g. the Hertz pulse's) at `frequencies_hz`: the
/// minimiser of Σ_k (y_k − ln|F(ω_k T)/F(0)| − c)² over T ∈ (0, 2.9π/ω_max] and a constant c
/// (the channel gains absorb constants), y_k = attenuation_k ln 10 / 20, unweighted. Grid
/// of 400 log-spaced T over [10⁻⁴ T_max, T_max], then golden section between the best point's
/// neighbours.
pub fn equivalent_half_sine_duration(
    frequencies_hz: &[f64],
    attenuation_db: &[f64],
) -> Result<f64, InjectError> {
    use crate::diagnose::catalogue::half_sine_spectrum;
    if frequencies_hz.len() != attenuation_db.len() {
        return Err(InjectError::LengthMismatch {
            what: "mode attenuations",
            got: attenuation_db.len(),
            expected: frequencies_hz.len(),
        });
    }
    if frequencies_hz.len() < 2 {
        return Err(InjectError::Empty(
            "at least two modes are needed to fit a contact duration",
        ));
    }
    for (&f, &a) in frequencies_hz.iter().zip(attenuation_db) {
        require(f > 0.0, "mode frequency", "positive (Hz)", f)?;
        require(true, "mode attenuation", "finite (dB)", a)?;
    }
    let omega: Vec<f64> = frequencies_hz.iter().map(|f| 2.0 * PI * f).collect();
    let y: Vec<f64> = attenuation_db
        .iter()
        .map(|a| a * 10f64.ln() / 20.0)
        .collect();
    let cost = |ln_t: f64| {
        let t = ln_t.exp();
        let r: Vec<f64> = omega
            .iter()
            .zip(&y)
            .map(|(w, yk)| yk - half_sine_spectrum(w * t).max(1e-15).ln())
            .collect();
        let mean = r.iter().sum::<f64>() / r.len() as f64;
        r.iter().map(|v| (v - mean).powi(2)).sum::<f64>()
    };
    let t_max = 2.9 * PI / omega.iter().copied().fold(0.0, f64::max);
    let n = 400;
    let grid: Vec<f64> = (0..n)
        .map(|i| (t_max * 1e-4).ln() + (i as f64 / (n - 1) as f64) * 1e4f64.ln())
        .collect();
    let best = (0..n)
        .min_by(|&a, &b| cost(grid[a]).total_cmp(&cost(grid[b])))
        .expect("grid is not empty");
    let (lo, hi) = crate::numerics::golden_section(
        grid[best.saturating_sub(1)],
        grid[(best + 1).min(n - 1)],
        100,
        &cost,
        |ca, cb| ca < cb,
    );
    Ok((0.5 * (lo + hi)).exp())
}

/// E(h) = ∫₀ʰ w (τ − τ̄) Φ dτ / ∫₀ʰ w (τ − τ̄)² dτ with w = e^(−2dτ), τ̄ the w-weighted mean
/// time and Φ(τ) = (1 − e^(−2dτ))/(2d): the slope of the w-weighted regression of Φ on τ
/// (module docs, "Comparing parameters"). Gauss–Legendre, 32 panels of 32 points over
/// [0, min(h, 20/d)] (beyond, w < e^(−40)).
fn glide_regression_mean(decay: f64, h: f64) -> f64 {
    let (nodes, weights) = crate::fem::quadrature::gauss_legendre_01(32);
    let span = if decay > 0.0 { h.min(20.0 / decay) } else { h };
    let panels = 32;
    let mut points = Vec::with_capacity(panels * nodes.len());
    for p in 0..panels {
        for (x, w) in nodes.iter().zip(&weights) {
            let tau = span * (p as f64 + x) / panels as f64;
            let two_d_tau = 2.0 * decay * tau;
            let phi = if two_d_tau.abs() < 1e-300 {
                tau
            } else {
                tau * (-(-two_d_tau).exp_m1() / two_d_tau)
            };
            points.push((tau, phi, (-two_d_tau).exp() * w * span / panels as f64));
        }
    }
    let m0: f64 = points.iter().map(|p| p.2).sum();
    let mean = points.iter().map(|p| p.2 * p.0).sum::<f64>() / m0;
    let sxy: f64 = points.iter().map(|p| p.2 * (p.0 - mean) * p.1).sum();
    let sxx: f64 = points.iter().map(|p| p.2 * (p.0 - mean).powi(2)).sum();
    sxy / sxx
}

/// (f_early − f_late)/(g f₀) for a mode of decay rate `decay` [1/s] gliding as
/// f(t) = f₀(1 + g e^(−2dt)), when f_early and f_late are least-squares frequencies of the
/// first and second halves of [0, `span_s`] after the onset: (1 − e^(−d span)) E(span/2)
/// (module docs, "Comparing parameters"). 0 without decay (the glide is then constant).
pub fn glide_half_contrast(decay: f64, span_s: f64) -> Result<f64, InjectError> {
    require(decay >= 0.0, "decay rate", "finite and ≥ 0 (1/s)", decay)?;
    require(span_s > 0.0, "analysis span", "positive (s)", span_s)?;
    Ok(-(-decay * span_s).exp_m1() * glide_regression_mean(decay, 0.5 * span_s))
}

/// (f_early − f_late)/(g f₀) as [`glide_half_contrast`], for an early window [0, `early_end_s`]
/// and a late window [`early_end_s`, `late_end_s`] after the onset: a window [a, a + h] gives
/// f/f₀ = 1 + g e^(−2da) E(h), so the contrast is E(T₁) − e^(−2dT₁) E(T₂ − T₁) (the halves of L
/// are T₁ = L/2, T₂ = L).
pub fn glide_window_contrast(
    decay: f64,
    early_end_s: f64,
    late_end_s: f64,
) -> Result<f64, InjectError> {
    require(decay >= 0.0, "decay rate", "finite and ≥ 0 (1/s)", decay)?;
    require(
        early_end_s > 0.0,
        "end of the early window",
        "positive (s)",
        early_end_s,
    )?;
    require(
        late_end_s > early_end_s,
        "end of the late window",
        "after the early window's end (s)",
        late_end_s,
    )?;
    Ok(glide_regression_mean(decay, early_end_s)
        - (-2.0 * decay * early_end_s).exp()
            * glide_regression_mean(decay, late_end_s - early_end_s))
}

/// (f_base/f)² − 1: the added modal mass of a mode relative to its own, from its frequency
/// before (`base_hz`) and after (`loaded_hz`) the mass was added (Rayleigh quotient with an
/// unchanged shape: λ = λ_base/(1 + Δm/m)).
pub fn modal_mass_loading(base_hz: f64, loaded_hz: f64) -> f64 {
    (base_hz / loaded_hz).powi(2) - 1.0
}

/// RMS over the knots (f [Hz], d [1/s]) of d/d_Zener(f) − 1.
pub fn zener_knot_rms_error(law: &ZenerDamping, knots: &[(f64, f64)]) -> Result<f64, InjectError> {
    if knots.is_empty() {
        return Err(InjectError::Empty("no damping-curve knots to compare"));
    }
    let mut sum = 0.0;
    for &(f, d) in knots {
        require(f > 0.0, "knot frequency", "positive (Hz)", f)?;
        require(d.is_finite(), "knot decay rate", "finite (1/s)", d)?;
        sum += (d / law.decay(f) - 1.0).powi(2);
    }
    Ok((sum / knots.len() as f64).sqrt())
}

/// One-to-one pairs (truth index, detected index) of frequencies within `tolerance` in
/// |ln(f_detected/f_truth)|, nearest first; sorted by the detected index.
pub fn pair_by_frequency(
    truth_hz: &[f64],
    detected_hz: &[f64],
    tolerance: f64,
) -> Vec<(usize, usize)> {
    let mut candidates: Vec<(f64, usize, usize)> = Vec::new();
    for (i, &t) in truth_hz.iter().enumerate() {
        for (j, &d) in detected_hz.iter().enumerate() {
            let distance = (d / t).ln().abs();
            if distance <= tolerance {
                candidates.push((distance, i, j));
            }
        }
    }
    candidates.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (mut used_t, mut used_d) = (vec![false; truth_hz.len()], vec![false; detected_hz.len()]);
    let mut pairs = Vec::new();
    for (_, i, j) in candidates {
        if !used_t[i] && !used_d[j] {
            used_t[i] = true;
            used_d[j] = true;
            pairs.push((i, j));
        }
    }
    pairs.sort_by_key(|p| p.1);
    pairs
}

/// The frequency a catalogue parameter's name carries: the number just before its last
/// "Hz" ("decay rate at 1234 Hz" → 1234, "relative split δf/f of cluster 3 (1662.5 Hz)" →
/// 1662.5).
pub fn frequency_in_name(name: &str) -> Option<f64> {
    let head = name[..name.rfind("Hz")?].trim_end();
    let start = head
        .rfind(|c: char| {
            !(c.is_ascii_digit() || c == '.' || c == 'e' || c == 'E' || c == '+' || c == '-')
        })
        .map_or(0, |i| {
            i + head[i..].chars().next().map_or(1, char::len_utf8)
        });
    let value: f64 = head[start..].parse().ok()?;
    (value > 0.0 && value.is_finite()).then_some(value)
}

/// Relative errors of one parameter over the cases.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ErrorSummary {
    pub n: usize,
    /// Median and largest |error|.
    pub median_abs: f64,
    pub max_abs: f64,
    /// Median signed error (the bias).
    pub median: f64,
}

impl ErrorSummary {
    /// The summary of the finite `errors`; `None` if there are none.
    pub fn of(errors: &[f64]) -> Option<ErrorSummary> {
        let finite: Vec<f64> = errors.iter().copied().filter(|e| e.is_finite()).collect();
        let abs: Vec<f64> = finite.iter().map(|e| e.abs()).collect();
        Some(ErrorSummary {
            n: finite.len(),
            median_abs: median(&abs)?,
            max_abs: abs.iter().copied().fold(0.0, f64::max),
            median: median(&finite)?,
        })
    }
}

/// Held-out error before and after the accepted effects, over the cases.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HeldOutSummary {
    pub cases: usize,
    /// after < before.
    pub dropped: usize,
    pub not_dropped: usize,
    /// Pairs with a non-finite value or before ≤ 0 (counted in neither).
    pub invalid: usize,
    /// Median of (before − after)/before over the valid pairs.
    pub median_relative_drop: Option<f64>,
}

impl HeldOutSummary {
    pub fn of(before_after: &[(f64, f64)]) -> HeldOutSummary {
        let valid: Vec<(f64, f64)> = before_after
            .iter()
            .copied()
            .filter(|&(b, a)| b > 0.0 && b.is_finite() && a.is_finite())
            .collect();
        let dropped = valid.iter().filter(|(b, a)| a < b).count();
        let drops: Vec<f64> = valid.iter().map(|(b, a)| (b - a) / b).collect();
        HeldOutSummary {
            cases: before_after.len(),
            dropped,
            not_dropped: valid.len() - dropped,
            invalid: before_after.len() - valid.len(),
            median_relative_drop: median(&drops),
        }
    }
}

/// One detected number next to what it should read.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ComparedValue {
    pub quantity: String,
    pub unit: String,
    /// The injected parameter as labelled.
    pub truth: Option<f64>,
    /// What the detector's parameter should read, derived from the labels (module docs).
    pub expected: Option<f64>,
    pub detected: Option<f64>,
    /// detected/expected − 1, where the two measure the same quantity.
    pub relative_error: Option<f64>,
}

impl ComparedValue {
    fn new(
        quantity: impl Into<String>,
        unit: &str,
        truth: Option<f64>,
        expected: Option<f64>,
        detected: Option<f64>,
    ) -> ComparedValue {
        let relative_error = match (expected, detected) {
            (Some(e), Some(d)) if e != 0.0 => Some(d / e - 1.0),
            _ => None,
        };
        ComparedValue {
            quantity: quantity.into(),
            unit: unit.to_string(),
            truth,
            expected,
            detected,
            relative_error,
        }
    }
}

/// The parameters of one accepted effect against the labels of its case.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ParameterComparison {
    pub effect: Effect,
    pub variant: String,
    pub values: Vec<ComparedValue>,
    /// The errors that enter the effect's summary: one per case (the RMS over the knots for
    /// the damping curve), one per paired cluster for beating pairs.
    pub errors: Vec<f64>,
    /// Why nothing, or not everything, is compared.
    pub not_comparable: Option<String>,
}

/// What the scorer knows about a case besides its labels.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct ScoringContext {
    /// Seconds after the onset whose halves give the early and late frequencies (pitch glide).
    pub glide_span_s: Option<f64>,
    /// Ends of the early and the late glide windows after the onset [s], when the report gives
    /// them; they take precedence over the halves of `glide_span_s`.
    pub glide_windows_s: Option<(f64, f64)>,
    /// The report's glide observable is the chirp fit's relative offset at the onset
    /// (`glide_observable = "offset_at_onset"`): then the detected g compares with the labels'
    /// g directly, and the windows above are not used.
    pub glide_offset_at_onset: bool,
    /// Undamped frequencies [Hz] of the observed modes the catalogue matched (its report's
    /// `matching.pairs[].observed_hz`): the contact fit and the glide's reference mode use
    /// the rendered modes within [`MATCHED_MODE_TOLERANCE`] of one of them, as the detector
    /// saw only those. Empty: every rendered mode.
    pub matched_hz: Vec<f64>,
}

/// Largest |ln(f_rendered/f_matched)| at which a rendered mode counts as seen by the detector.
pub const MATCHED_MODE_TOLERANCE: f64 = 0.01;

impl ScoringContext {
    /// Whether a rendered mode at `undamped_hz` is one the detector matched.
    fn seen(&self, undamped_hz: f64) -> bool {
        self.matched_hz.is_empty()
            || self
                .matched_hz
                .iter()
                .any(|&f| (undamped_hz / f).ln().abs() <= MATCHED_MODE_TOLERANCE)
    }
}

/// Largest |ln(f_detected/f_true)| at which a detected split cluster is paired with a labelled
/// one (the centres are both the pair's mean frequency; the bowl's closest clusters are ~0.3 %
/// apart above 10 kHz).
pub const SPLIT_PAIRING_TOLERANCE: f64 = 0.002;

/// A rendered mode of the labels.
struct LabelMode {
    index: usize,
    undamped_hz: f64,
    frequency_hz: f64,
    decay_rate: f64,
    amplitudes: Vec<f64>,
}

fn label_err(what: impl Into<String>) -> InjectError {
    InjectError::Label(what.into())
}

fn label_f64(v: &serde_json::Value, key: &str) -> Result<f64, InjectError> {
    v.get(key)
        .and_then(serde_json::Value::as_f64)
        .ok_or_else(|| label_err(format!("no number {key:?}")))
}

fn label_f64_list(v: &serde_json::Value, key: &str) -> Result<Vec<f64>, InjectError> {
    v.get(key)
        .and_then(serde_json::Value::as_array)
        .and_then(|a| {
            a.iter()
                .map(serde_json::Value::as_f64)
                .collect::<Option<Vec<f64>>>()
        })
        .ok_or_else(|| label_err(format!("no list of numbers {key:?}")))
}

fn label_modes(labels: &serde_json::Value) -> Result<Vec<LabelMode>, InjectError> {
    let modes = labels
        .get("modes")
        .and_then(serde_json::Value::as_array)
        .ok_or_else(|| label_err("no \"modes\" list"))?;
    modes
        .iter()
        .enumerate()
        .map(|(i, m)| {
            let index = m
                .get("index")
                .and_then(serde_json::Value::as_u64)
                .ok_or_else(|| label_err(format!("mode {i}: no \"index\"")))?
                as usize;
            Ok(LabelMode {
                index,
                undamped_hz: label_f64(m, "undamped_hz")?,
                frequency_hz: label_f64(m, "frequency_hz")?,
                decay_rate: label_f64(m, "decay_rate")?,
                amplitudes: label_f64_list(m, "amplitudes")?,
            })
        })
        .collect()
}

fn label_effects(labels: &serde_json::Value) -> Result<Vec<EffectLabel>, InjectError> {
    let effects = labels
        .get("effects")
        .ok_or_else(|| label_err("no \"effects\""))?;
    serde_json::from_value(effects.clone()).map_err(|e| label_err(format!("effects: {e}")))
}

/// The accepted effect's parameter whose name starts with `prefix`.
fn detected_param<'a>(
    accepted: &'a AcceptedEffect,
    prefix: &str,
) -> Result<&'a FittedParam, InjectError> {
    accepted
        .params
        .iter()
        .find(|p| p.name.starts_with(prefix))
        .ok_or_else(|| {
            let names: Vec<&str> = accepted.params.iter().map(|p| p.name.as_str()).collect();
            InjectError::Report(format!(
                "{}: no parameter named {prefix:?}… (has {names:?})",
                accepted.name
            ))
        })
}

/// Compares the parameters of an `accepted` effect of the catalogue with the sealed `labels`
/// (the whole label file of the case, as written by `examples/diagnose_generate.rs`) of a case
/// that holds the effect. The mapping of each effect is in the module docs ("Comparing
/// parameters"). Fails if the effect is not in the labels, a label field is missing, or the
/// report lacks the parameter the mapping reads.
pub fn compare_parameters(
    labels: &serde_json::Value,
    accepted: &AcceptedEffect,
    context: &ScoringContext,
) -> Result<ParameterComparison, InjectError> {
    let effect = Effect::from_catalogue_name(&accepted.name)?;
    let effects = label_effects(labels)?;
    let label = effects
        .iter()
        .find(|l| l.effect == effect)
        .ok_or_else(|| label_err(format!("the case does not hold {effect}")))?;
    let p = &label.parameters;
    let mut out = ParameterComparison {
        effect,
        variant: accepted.variant.clone(),
        values: Vec::new(),
        errors: Vec::new(),
        not_comparable: None,
    };
    match effect {
        Effect::NonRayleighDamping => {
            let law = ZenerDamping {
                loss_factor: label_f64(p, "loss_factor")?,
                relaxation_strength: label_f64(p, "relaxation_strength")?,
                corner_hz: label_f64(p, "corner_hz")?,
            };
            let mut knots = Vec::new();
            for q in accepted
                .params
                .iter()
                .filter(|q| q.name.starts_with("decay rate at"))
            {
                let f = frequency_in_name(&q.name).ok_or_else(|| {
                    InjectError::Report(format!("cannot read a frequency in {:?}", q.name))
                })?;
                knots.push((f, q.value));
                out.values.push(ComparedValue::new(
                    format!("decay rate at {f:.0} Hz (Zener law)"),
                    "1/s",
                    Some(law.decay(f)),
                    Some(law.decay(f)),
                    Some(q.value),
                ));
            }
            if knots.is_empty() {
                return Err(InjectError::Report(format!(
                    "{}: no \"decay rate at … Hz\" knots",
                    accepted.name
                )));
            }
            out.errors.push(zener_knot_rms_error(&law, &knots)?);
        }
        Effect::BeatingPair => {
            let modes = label_modes(labels)?;
            let base = label_f64_list(labels, "base_undamped_hz")?;
            let clusters = p
                .get("clusters")
                .and_then(serde_json::Value::as_array)
                .ok_or_else(|| label_err("beating_pair: no \"clusters\""))?;
            // (centre Hz, relative split, split Hz) of every labelled cluster.
            let mut truth = Vec::new();
            for c in clusters {
                let ends: Vec<usize> = c
                    .get("modes")
                    .and_then(serde_json::Value::as_array)
                    .map(|a| {
                        a.iter()
                            .filter_map(|v| v.as_u64().map(|u| u as usize))
                            .collect()
                    })
                    .unwrap_or_default();
                if ends.len() != 2 {
                    return Err(label_err(
                        "beating_pair: a cluster without its two end modes",
                    ));
                }
                let split = label_f64(c, "split_hz")?;
                let at = |i: usize| {
                    modes
                        .iter()
                        .find(|m| m.index == i)
                        .map(|m| m.undamped_hz)
                        .or_else(|| base.get(i).copied())
                };
                let (lo, hi) = (
                    at(ends[0])
                        .ok_or_else(|| label_err(format!("no frequency of mode {}", ends[0])))?,
                    at(ends[1])
                        .ok_or_else(|| label_err(format!("no frequency of mode {}", ends[1])))?,
                );
                let centre = 0.5 * (lo + hi);
                truth.push((centre, split / centre, split));
            }
            let detected: Vec<(f64, f64)> = accepted
                .params
                .iter()
                .filter(|q| q.name.starts_with("relative split"))
                .map(|q| {
                    frequency_in_name(&q.name)
                        .map(|f| (f, q.value))
                        .ok_or_else(|| {
                            InjectError::Report(format!("cannot read a frequency in {:?}", q.name))
                        })
                })
                .collect::<Result<_, _>>()?;
            let pairs = pair_by_frequency(
                &truth.iter().map(|t| t.0).collect::<Vec<_>>(),
                &detected.iter().map(|d| d.0).collect::<Vec<_>>(),
                SPLIT_PAIRING_TOLERANCE,
            );
            for &(i, j) in &pairs {
                let v = ComparedValue::new(
                    format!(
                        "relative split δf/f of the cluster at {:.1} Hz (true split {:.2} Hz)",
                        truth[i].0, truth[i].2
                    ),
                    "1",
                    Some(truth[i].1),
                    Some(truth[i].1),
                    Some(detected[j].1),
                );
                out.errors.extend(v.relative_error);
                out.values.push(v);
            }
            let unpaired: Vec<String> = (0..detected.len())
                .filter(|j| !pairs.iter().any(|p| p.1 == *j))
                .map(|j| format!("{:.1} Hz", detected[j].0))
                .collect();
            if !unpaired.is_empty() {
                out.not_comparable = Some(format!(
                    "detected split(s) at {} match no labelled cluster within {:.1} %",
                    unpaired.join(", "),
                    100.0 * SPLIT_PAIRING_TOLERANCE
                ));
            }
        }
        Effect::SupportContact => {
            let gamma = detected_param(accepted, "support damping")?.value;
            out.values.push(ComparedValue::new(
                "support damping γ (Δd at support weight w = 1)",
                "1/s",
                None,
                None,
                Some(gamma),
            ));
            let extra = label_f64_list(p, "added_decay_per_mode")?;
            let modes = label_modes(labels)?;
            let rendered: Vec<f64> = modes
                .iter()
                .filter_map(|m| extra.get(m.index).copied())
                .collect();
            let largest = rendered.iter().copied().fold(f64::NAN, f64::max);
            out.values.push(ComparedValue::new(
                "largest injected Δd over the rendered modes",
                "1/s",
                Some(largest),
                None,
                None,
            ));
            out.not_comparable = Some(
                "the detector's Δd_k = γ w_k needs the support weights w_k of the simulated modes the CLI gave the catalogue, which the report does not carry; γ (Δd at w = 1) and the labels' Δd_k = ½Σ c φ² are listed side by side".into(),
            );
        }
        Effect::ContactDuration => {
            let t_hertz = label_f64(p, "duration_s")?;
            let attenuation = label_f64_list(p, "mode_attenuation_db")?;
            let modes = label_modes(labels)?;
            if attenuation.len() != modes.len() {
                return Err(InjectError::LengthMismatch {
                    what: "contact_duration mode_attenuation_db (one per rendered mode)",
                    got: attenuation.len(),
                    expected: modes.len(),
                });
            }
            let (mut freqs, mut att): (Vec<f64>, Vec<f64>) = modes
                .iter()
                .zip(&attenuation)
                .filter(|(m, _)| context.seen(m.undamped_hz))
                .map(|(m, a)| (m.frequency_hz, *a))
                .unzip();
            if freqs.len() < 2 {
                (freqs, att) = (
                    modes.iter().map(|m| m.frequency_hz).collect(),
                    attenuation.clone(),
                );
            }
            let expected = equivalent_half_sine_duration(&freqs, &att)?;
            // The sin^p variant reports its first null f₀; the half-sine (p = 1) with that
            // null is the duration compared.
            let t = match detected_param(accepted, "contact duration") {
                Ok(q) => q.value,
                Err(e) => match detected_param(accepted, FIRST_NULL_PARAM) {
                    Ok(q) => sine_power_duration(q.value, 1.0),
                    Err(_) => return Err(e),
                },
            };
            let v = ComparedValue::new(
                "contact duration T (half-sine fitted to the case's Hertz attenuations)",
                "s",
                Some(t_hertz),
                Some(expected),
                Some(t),
            );
            out.errors.extend(v.relative_error);
            out.values.push(v);
            out.values.push(ComparedValue::new(
                "T_half-sine / T_Hertz",
                "1",
                None,
                Some(expected / t_hertz),
                Some(t / t_hertz),
            ));
        }
        Effect::Reverb => {
            let t60 = label_f64(p, "t60_s")?;
            let v = ComparedValue::new(
                "reverberation time T60",
                "s",
                Some(t60),
                Some(t60),
                Some(detected_param(accepted, "reverberation time")?.value),
            );
            out.errors.extend(v.relative_error);
            out.values.push(v);
        }
        Effect::Radiation if accepted.variant == "transfer" => {
            // The generator radiates through the same multipole transfer the CLI computes.
            let eta = detected_param(accepted, "transfer exponent")?.value;
            let v = ComparedValue::new("transfer exponent η (the generator radiates through the multipole transfer itself)", "1", Some(1.0), Some(1.0), Some(eta));
            out.errors.extend(v.relative_error);
            out.values.push(v);
        }
        Effect::Radiation => {
            out.not_comparable = Some(
                "the labels' strength is the energy-weighted RMS dB misfit of a per-mode + per-microphone level model to the multipole transfers; the factor variant's u_k v_c (an unweighted factor on the fit channels, without microphone positions) is not that quantity".into(),
            );
        }
        Effect::AddedMass => {
            let fraction = label_f64(p, "mass_fraction")?;
            let mu = accepted
                .params
                .first()
                .ok_or_else(|| InjectError::Report("added_mass: no parameter".into()))?
                .value;
            let others: Vec<&str> = effects
                .iter()
                .filter(|l| l.effect != effect && l.effect.changes_fem())
                .map(|l| l.effect.name())
                .collect();
            if !others.is_empty() {
                out.values.push(ComparedValue::new(
                    "added-mass ratio",
                    "1",
                    Some(fraction),
                    None,
                    Some(mu),
                ));
                out.not_comparable = Some(format!("{} also moved the frequencies, so the labels' frequency drops are not the mass's alone", others.join(", ")));
                return Ok(out);
            }
            let base = label_f64_list(labels, "base_undamped_hz")?;
            let loads: Vec<(f64, f64)> = label_modes(labels)?
                .iter()
                .filter(|m| m.index < base.len())
                .map(|m| {
                    (
                        m.undamped_hz,
                        modal_mass_loading(base[m.index], m.undamped_hz),
                    )
                })
                .collect();
            if loads.is_empty() {
                return Err(label_err(
                    "added_mass: no rendered mode with a base frequency",
                ));
            }
            let (quantity, expected) = if accepted.variant == "fluid_loading" {
                let lowest = loads
                    .iter()
                    .min_by(|a, b| a.0.total_cmp(&b.0))
                    .expect("not empty");
                (
                    format!(
                        "fluid added-mass ratio μ_f (true loading of the lowest mode, {:.0} Hz)",
                        lowest.0
                    ),
                    lowest.1,
                )
            } else {
                (
                    "added-mass ratio μ (largest true loading (f_base/f)² − 1 over the modes)"
                        .to_string(),
                    loads.iter().map(|l| l.1).fold(f64::NEG_INFINITY, f64::max),
                )
            };
            let v = ComparedValue::new(quantity, "1", Some(fraction), Some(expected), Some(mu));
            out.errors.extend(v.relative_error);
            out.values.push(v);
        }
        Effect::PitchGlide => {
            let g = label_f64(p, "glide")?;
            let detected = detected_param(accepted, "relative glide")?.value;
            if context.glide_offset_at_onset {
                // Same quantity on both sides: the offset at t = 0 of f₀(1 + g e^(−2dt)), the
                // same for every mode in the generator (so for the detector's reference mode).
                let v = ComparedValue::new(
                    "relative glide g at the onset, f(t) = f₀(1 + g e^(−2dt))",
                    "1",
                    Some(g),
                    Some(g),
                    Some(detected),
                );
                out.errors.extend(v.relative_error);
                out.values.push(v);
                return Ok(out);
            }
            // The early/late windows the CLI used: given by the report, else the halves of the span.
            let (t1, t2) = match (context.glide_windows_s, context.glide_span_s) {
                (Some(w), _) => w,
                (None, Some(span)) => (0.5 * span, span),
                (None, None) => {
                    out.values.push(ComparedValue::new(
                        "relative glide g",
                        "1",
                        Some(g),
                        None,
                        Some(detected),
                    ));
                    out.not_comparable =
                        Some("no analysis span known for the early/late halves".into());
                    return Ok(out);
                }
            };
            // The detector's reference: the mode with the largest mean_c a² / ω².
            let modes = label_modes(labels)?;
            let energy = |m: &LabelMode| {
                m.amplitudes.iter().map(|a| a * a).sum::<f64>()
                    / (m.amplitudes.len().max(1) as f64 * (2.0 * PI * m.frequency_hz).powi(2))
            };
            let seen: Vec<&LabelMode> = modes
                .iter()
                .filter(|m| context.seen(m.undamped_hz))
                .collect();
            let pool = if seen.is_empty() {
                modes.iter().collect()
            } else {
                seen
            };
            let reference = *pool
                .iter()
                .max_by(|a, b| energy(a).total_cmp(&energy(b)))
                .ok_or_else(|| label_err("no rendered modes"))?;
            let expected = g * glide_window_contrast(reference.decay_rate, t1, t2)?;
            let v = ComparedValue::new(
                format!("relative glide (f_early − f_late)/f of the most energetic mode ({:.0} Hz, d = {:.1} 1/s, windows 0–{t1} s and {t1}–{t2} s)", reference.frequency_hz, reference.decay_rate),
                "1",
                Some(g),
                Some(expected),
                Some(detected),
            );
            out.errors.extend(v.relative_error);
            out.values.push(v);
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests;
