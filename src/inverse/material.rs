//! Stage 2 of the material fit: E (or E/ρ) and ν from recorded sound, with the damping fixed.
//!
//! # Model
//!
//! The eigenvalues come from the reduced basis in ν ([`crate::eigen::reduced`]):
//! λ_k = (E/ρ) θ_k(ν). Each mode is heard through the driving-point response at the strike
//! point x along the direction n: a unit impulse there moves the surface at x along n by
//! Σ_k (φ_k(x)·n)² · Im(G_k e^(s_k t)) (mass-normalised φ_k, [`crate::audio::excitation`]), so
//! the projection is c_k = g_c · (φ_k(x)·n)² with a learned gain g_c = e^(γ_c) per channel c
//! (microphone level and distance are unknown). The square makes the model blind to the
//! arbitrary sign of each computed mode. The damping model (a curve d(f) or Rayleigh α, β
//! from stage 1) is held fixed.
//!
//! # Optimisation
//!
//! Parameters: σ = ln E + mean_k ln θ_k(ν) (the log of the spectrum's overall scale, so steps
//! are relative), ν (optional; else held) and γ_c. With σ held, ν changes only the spacing
//! of the partials, not their overall position, so E and ν do not compete while E is far off. Adam
//! ([`super::optim`]) with step sizes `step_log_youngs`, `step_poisson`, `step_log_gain`,
//! bounded ν ∈ [`poisson_bounds`]. The loss follows the hybrid schedule
//! ([`crate::audio::loss::HybridSchedule`]): the 1-D optimal-transport loss first (it pulls
//! partials from far away: a start a factor 3 off in E puts every partial √3 off in
//! frequency), then the multi-scale spectral loss once the transport loss stalls; the Adam
//! moments are reset at the switch and the step sizes decay geometrically in the spectral
//! phase so the fit settles. ν is held during the transport phase (which sets the overall
//! scale σ); at the switch it is chosen by a scan over a grid of ν (spectral loss at fixed σ,
//! a few hundred reduced solves), and from there E and ν descend together. It stops at `max_steps` or when, in the spectral phase, E and ν
//! have moved less than `tolerance` (relative for E, absolute for ν) over `patience` steps.
//!
//! Gradients: dL/dλ_k from the audio chain ([`crate::audio::chain`]), then
//! dL/d ln E = Σ_k λ_k dL/dλ_k, dL/dν = Σ_k (E/ρ) dθ_k/dν · dL/dλ_k, dL/dγ_c = Σ_k c_k dL/dc_k,
//! then dL/dσ = dL/d ln E and dL/dν|σ = dL/dν|E − dL/d ln E · mean_k (dθ_k/dν)/θ_k.
//! The change of the mode shapes with ν (through c_k) is not differentiated; it is small and
//! is re-evaluated at every step. With `check_every` > 0 the reduced basis is checked every
//! `check_every` steps: if a Ritz pair's relative residual exceeds `residual_tolerance` and no
//! sample lies within `min_sample_spacing`, the current ν is added as a sample (one full solve),
//! holding E fixed across the change. Off by default: on the bowl under 2 ranks a sample added
//! near an existing one let rigid-body traces of the solves into the basis and gave spurious
//! Ritz values; the fits build their basis from well-spread samples and check the answer
//! against a full solve instead.

use std::cell::RefCell;

use crate::audio::chain::{ChainError, DampingModel, ModalChain, Strike};
use crate::audio::loss::{
    HybridSchedule, LossError, LossPhase, MultiScaleSpectralLoss, PeakTransportConfig,
    PeakTransportLoss, SpectralLossConfig,
};
use crate::audio::synth::{render_backward, render_samples, BankGradient};
use crate::eigen::reduced::{PoissonBasis, ReducedError, ReducedModes};

/// Why the material fit (or one of its pieces: a render, the line-spectrum start) stopped.
#[derive(Debug, thiserror::Error)]
pub enum MaterialFitError {
    #[error("the material fit needs one or more target channels of equal, non-zero length")]
    Targets,
    #[error("the line-spectrum start needs the target's mode frequencies")]
    NoTargetModes,
    /// The damping model or the strike refused by the modal chain.
    #[error(transparent)]
    Chain(#[from] ChainError),
    /// A spectral or transport loss refused its target or a render.
    #[error(transparent)]
    Loss(#[from] LossError),
    /// The caller's check of the reduced basis against a full solve.
    #[error(transparent)]
    Basis(#[from] ReducedError),
}

/// Settings of the material fit (module docs).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MaterialFitSettings {
    pub learn_poisson: bool,
    pub step_log_youngs: f64,
    pub step_poisson: f64,
    pub step_log_gain: f64,
    /// Step sizes in the spectral phase, where the basin is a fraction of a partial's
    /// bandwidth wide.
    pub spectral_step_log_youngs: f64,
    pub spectral_step_poisson: f64,
    /// Search the line-spectrum start (module docs) when the problem lists target modes.
    pub line_spectrum_start: bool,
    /// Largest distance counted per line in the line-spectrum match, in ln f.
    pub line_match_cap: f64,
    /// How far from the given start E the line-spectrum search looks, as a factor either way.
    pub youngs_search_factor: f64,
    pub poisson_bounds: (f64, f64),
    pub max_steps: usize,
    pub schedule_patience: usize,
    pub schedule_min_improvement: f64,
    /// Step-size factor per spectral-phase step.
    pub spectral_decay: f64,
    pub tolerance: f64,
    pub patience: usize,
    pub check_every: usize,
    pub residual_tolerance: f64,
    /// No new basis sample closer than this to an existing one.
    pub min_sample_spacing: f64,
    /// Grid points of the ν scan at the switch to the spectral loss.
    pub poisson_scan: usize,
    /// Learn a log-amplitude offset per mode and channel in the spectral phase (for recordings,
    /// where the microphones do not hear the driving-point amplitudes).
    pub free_amplitudes: bool,
    /// Starts tried on each side of the line-spectrum start, `start_probe_spacing` apart in
    /// ν, each with its own line-matched E and run `start_probe_steps` spectral steps; the fit
    /// goes on from the one with the lowest loss ([`fit_material`], *Several starts*). 0: the
    /// line-spectrum start alone.
    pub start_probes: usize,
    pub start_probe_spacing: f64,
    pub start_probe_steps: usize,
    pub transport: PeakTransportConfig,
    pub spectral: SpectralLossConfig,
}

impl Default for MaterialFitSettings {
    fn default() -> Self {
        MaterialFitSettings {
            learn_poisson: true,
            step_log_youngs: 0.05,
            step_poisson: 0.01,
            step_log_gain: 0.1,
            spectral_step_log_youngs: 0.0005,
            spectral_step_poisson: 0.0005,
            line_spectrum_start: true,
            line_match_cap: 0.02,
            youngs_search_factor: 4.0,
            poisson_bounds: (0.0, 0.49),
            max_steps: 600,
            schedule_patience: 10,
            schedule_min_improvement: 0.002,
            spectral_decay: 0.99,
            tolerance: 1e-6,
            patience: 20,
            check_every: 0,
            residual_tolerance: 1e-2,
            min_sample_spacing: 0.02,
            poisson_scan: 45,
            free_amplitudes: false,
            start_probes: 2,
            start_probe_spacing: 0.005,
            start_probe_steps: 40,
            transport: PeakTransportConfig::default(),
            spectral: SpectralLossConfig::default(),
        }
    }
}

/// What the fit needs to know about the recording and the strike.
pub struct MaterialProblem<'a> {
    /// One target signal per channel, all of the same length, starting at the strike.
    pub targets: &'a [Vec<f64>],
    pub sample_rate: f64,
    /// ρ [kg/m³]; with ρ unknown pass 1 and read the result as E/ρ.
    pub density: f64,
    pub damping: DampingModel,
    pub strike: Strike,
    /// Unit strike direction n, and for each mode the probe values the basis returns are dotted
    /// with it: `direction_weights[i]` multiplies probe value i (e.g. the strike node's x, y, z
    /// DOFs weighted by n, or a shape-function combination of an element's DOFs).
    pub direction_weights: Vec<f64>,
    /// Band limit: modes above f_max are faded out over [f_max, 1.1 f_max] (raised cosine in f,
    /// held fixed within a step, not differentiated), as the target must be. `None`: no limit.
    pub max_frequency_hz: Option<f64>,
    /// Frequencies [Hz] of the modes found in the target (e.g. stage 1's real modes), for the
    /// line-spectrum start; empty: start where told.
    pub target_modes_hz: Vec<f64>,
}

/// The band-limit weight of a mode at `f` Hz: 1 below `f_max`, a raised-cosine fade to 0 at
/// 1.1 `f_max` (module docs of [`MaterialProblem::max_frequency_hz`]).
pub fn band_weight(f: f64, max_frequency_hz: Option<f64>) -> f64 {
    match max_frequency_hz {
        None => 1.0,
        Some(fm) if f <= fm => 1.0,
        Some(fm) if f >= 1.1 * fm => 0.0,
        Some(fm) => 0.5 + 0.5 * (std::f64::consts::PI * (f - fm) / (0.1 * fm)).cos(),
    }
}

/// One step of the history.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct FitStep {
    pub step: usize,
    pub phase: LossPhase,
    pub loss: f64,
    pub youngs: f64,
    pub poisson: f64,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct MaterialFit {
    pub youngs: f64,
    pub poisson: f64,
    pub log_gains: Vec<f64>,
    /// Per mode and channel (mode-major: k·C + c) log-amplitude offsets; zeros unless
    /// `free_amplitudes`.
    pub log_amplitude_offsets: Vec<f64>,
    pub history: Vec<FitStep>,
    pub switched_at: Option<usize>,
    pub steps: usize,
    pub basis_samples: Vec<f64>,
    pub max_residual: f64,
    pub line_start: Option<LineSpectrumStart>,
    /// The starts tried before the fit ([`fit_material`], *Several starts*); empty without.
    #[serde(default)]
    pub start_probes: Vec<StartProbe>,
}

/// One start tried before the fit: where, and the mean spectral loss of its last five steps.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct StartProbe {
    pub youngs: f64,
    pub poisson: f64,
    pub loss: f64,
}

/// (φ_k(x)·n)² for ρ = 1: mode k's driving-point weight at the strike (module docs).
pub(crate) fn driving_point_weight(
    basis: &PoissonBasis,
    modes: &ReducedModes,
    problem: &MaterialProblem,
    k: usize,
) -> f64 {
    let along: f64 = basis
        .probe(modes, k)
        .iter()
        .zip(&problem.direction_weights)
        .map(|(v, w)| v * w)
        .sum();
    along * along
}

/// Projections c_k (without gain) and the eigenvalues at (E, ν).
fn modal_inputs(
    basis: &PoissonBasis,
    modes: &ReducedModes,
    problem: &MaterialProblem,
    youngs: f64,
) -> (Vec<f64>, Vec<f64>) {
    let eigenvalues = modes.eigenvalues(youngs, problem.density);
    let projections = (0..modes.theta.len())
        .map(|k| {
            let f = eigenvalues[k].max(0.0).sqrt() / (2.0 * std::f64::consts::PI);
            band_weight(f, problem.max_frequency_hz)
                * driving_point_weight(basis, modes, problem, k)
                / problem.density
        })
        .collect();
    (eigenvalues, projections)
}

/// ln(RMS(target) / RMS(rendered)) per channel: the gains that level each rendered channel with
/// its target (0 where either is silent).
pub fn rms_matched_log_gains(rendered: &[Vec<f64>], targets: &[Vec<f64>]) -> Vec<f64> {
    rendered
        .iter()
        .zip(targets)
        .map(|(r, t)| {
            let (r, t) = (crate::audio::rms(r), crate::audio::rms(t));
            if r > 0.0 && t > 0.0 {
                (t / r).ln()
            } else {
                0.0
            }
        })
        .collect()
}

/// Renders every channel at (E, ν, gains, and per mode·channel log-amplitude offsets if given).
pub fn render_channels(
    basis: &PoissonBasis,
    problem: &MaterialProblem,
    youngs: f64,
    poisson: f64,
    log_gains: &[f64],
    offsets: Option<&[f64]>,
) -> Result<Vec<Vec<f64>>, MaterialFitError> {
    let modes = basis.solve(poisson);
    let (eigenvalues, projections) = modal_inputs(basis, &modes, problem, youngs);
    let n = problem.targets[0].len();
    let n_channels = log_gains.len();
    log_gains
        .iter()
        .enumerate()
        .map(|(ch, g)| {
            let c: Vec<f64> = projections
                .iter()
                .enumerate()
                .map(|(k, p)| p * (g + offsets.map_or(0.0, |o| o[k * n_channels + ch])).exp())
                .collect();
            let (bank, _) = ModalChain::new(&eigenvalues, &c, &problem.damping, &problem.strike)?;
            Ok(render_samples(&bank, problem.sample_rate, n))
        })
        .collect()
}

enum Losses {
    Transport(Vec<PeakTransportLoss>),
    Spectral(Vec<MultiScaleSpectralLoss>),
}

/// The ν on a grid of `poisson_scan` points over the bounds with the lowest spectral loss at
/// fixed σ and gains: a global search in one dimension, which makes the fit independent of
/// the starting ν, at the cost of a few hundred cheap reduced solves.
fn scan_poisson(
    basis: &PoissonBasis,
    problem: &MaterialProblem,
    spectral: &[MultiScaleSpectralLoss],
    sigma: f64,
    log_gains: &[f64],
    settings: &MaterialFitSettings,
) -> Result<f64, MaterialFitError> {
    let (lo, hi) = settings.poisson_bounds;
    let n = settings.poisson_scan.max(2);
    let mut best = (f64::INFINITY, lo);
    for i in 0..n {
        let nu = lo + (hi - lo) * i as f64 / (n - 1) as f64;
        let modes = basis.solve(nu);
        let m = modes.theta.iter().map(|t| t.ln()).sum::<f64>() / modes.theta.len() as f64;
        let rendered = render_channels(basis, problem, (sigma - m).exp(), nu, log_gains, None)?;
        let mut total = 0.0;
        for (loss, x) in spectral.iter().zip(&rendered) {
            total += loss.value(x)?;
        }
        if total < best.0 {
            best = (total, nu);
        }
    }
    Ok(best.1)
}

/// Where the line-spectrum start landed.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
pub struct LineSpectrumStart {
    pub youngs: f64,
    pub poisson: f64,
    /// The match distance there (mean capped |Δ ln f| of both sides, module docs).
    pub distance: f64,
    /// Grid points tried.
    pub evaluations: usize,
    /// The ν range searched (`poisson_bounds`, or the held ν twice).
    #[serde(default)]
    pub poisson_range: (f64, f64),
}

impl LineSpectrumStart {
    /// Whether ν ended on an end of a searched range (one that had a width): the recorded
    /// lines then pulled ν as far as it was let go, and the match is not an answer but a bound
    /// (`workflow::diagnose::material`, *Within the basis*).
    pub fn poisson_at_edge(&self) -> bool {
        let (lo, hi) = self.poisson_range;
        hi - lo > POISSON_EDGE
            && (self.poisson - lo < POISSON_EDGE || hi - self.poisson < POISSON_EDGE)
    }
}

/// How near an end of the searched range ν must be to count as on it: twice the refinement
/// step of [`line_spectrum_start`] (0.00025) and well under its coarse step (0.0025).
const POISSON_EDGE: f64 = 5e-4;

/// Mean over `from` of min(cap, distance in ln f to the nearest of `to` shifted by `shift`);
/// both sorted ascending.
pub(crate) fn capped_nearest(from: &[f64], to: &[f64], shift: f64, cap: f64) -> f64 {
    if from.is_empty() {
        return 0.0;
    }
    let mut total = 0.0;
    let mut i = 0;
    for &x in from {
        // `to` sorted: advance to the first element whose shifted value is ≥ x.
        while i < to.len() && to[i] + shift < x {
            i += 1;
        }
        let mut best = cap;
        if i < to.len() {
            best = best.min(to[i] + shift - x);
        }
        if i > 0 {
            best = best.min(x - to[i - 1] - shift);
        }
        total += best;
    }
    total / from.len() as f64
}

/// The line match's targets: ln of the target's mode frequencies (finite and positive ones),
/// ascending, and the ceiling (ln Hz) above which simulated partials are not compared: 1.02 ×
/// the highest target mode, or the band limit if lower.
pub(crate) fn line_match_targets(
    problem: &MaterialProblem,
) -> Result<(Vec<f64>, f64), MaterialFitError> {
    let mut target: Vec<f64> = problem
        .target_modes_hz
        .iter()
        .filter(|f| f.is_finite() && **f > 0.0)
        .map(|f| f.ln())
        .collect();
    if target.is_empty() {
        return Err(MaterialFitError::NoTargetModes);
    }
    target.sort_by(f64::total_cmp);
    let mut ceiling = target[target.len() - 1] + 0.02_f64.ln_1p();
    if let Some(fm) = problem.max_frequency_hz {
        ceiling = ceiling.min(fm.ln());
    }
    Ok((target, ceiling))
}

/// Partials quieter than this fraction of the loudest one in the compared band (driving-point
/// weight (φ_k·n)²) are not expected in the recording.
pub(crate) const AUDIBLE_FRACTION: f64 = 1e-3;

/// A model's partials for the line match: u_k = ½ ln θ_k ascending (θ_k = ω_k² ρ/E, so that
/// ln f_k = u_k + shift), each with its driving-point weight (φ_k·n)² at the strike.
#[derive(Clone, Debug, Default)]
pub(crate) struct LinePattern {
    u: Vec<f64>,
    weight: Vec<f64>,
    /// The audible partials last asked for by [`line_distance`], keyed by how many partials
    /// lie under the ceiling and the audible fraction's bits: they depend on the shift only
    /// through that count, and a scan asks for the same set at hundreds of shifts (the loaded
    /// match's 221 per pattern, the line match's thousands per ν).
    heard_memo: RefCell<Option<(usize, u64, Vec<f64>)>>,
}

impl LinePattern {
    /// From (θ_k, weight_k) in any order; θ ≤ 0 (rigid traces) is dropped.
    pub(crate) fn new(partials: impl IntoIterator<Item = (f64, f64)>) -> Self {
        let mut kept: Vec<(f64, f64)> = partials
            .into_iter()
            .filter(|p| p.0 > 0.0)
            .map(|(theta, w)| (0.5 * theta.ln(), w))
            .collect();
        kept.sort_by(|a, b| a.0.total_cmp(&b.0));
        LinePattern {
            u: kept.iter().map(|p| p.0).collect(),
            weight: kept.iter().map(|p| p.1).collect(),
            heard_memo: RefCell::default(),
        }
    }

    /// How many partials lie at or below `ceiling` (ln Hz) at `shift`.
    fn in_band(&self, shift: f64, ceiling: f64) -> usize {
        self.u.partition_point(|x| x + shift <= ceiling)
    }

    /// u of the partials the recording should hold at `shift`: at or below `ceiling` (ln Hz)
    /// and at least `audible` × the loudest of those ([`line_distance`] remembers them).
    #[cfg(test)]
    pub(crate) fn heard(&self, shift: f64, ceiling: f64, audible: f64) -> Vec<f64> {
        self.heard_below(self.in_band(shift, ceiling), audible)
    }

    /// The same for the first `in_band` partials.
    fn heard_below(&self, in_band: usize, audible: f64) -> Vec<f64> {
        let loudest = self.weight[..in_band]
            .iter()
            .fold(0.0_f64, |m, w| m.max(*w));
        (0..in_band)
            .filter(|&k| self.weight[k] >= audible * loudest)
            .map(|k| self.u[k])
            .collect()
    }
}

/// The line match's symmetric distance between the sorted `target` (ln Hz) and a model's
/// `pattern` shifted by `shift` (module docs of [`line_spectrum_start`]): the capped nearest
/// distance of every target line to any partial, plus that of every partial the recording
/// should hold ([`LinePattern::heard`]) to the nearest target line.
pub(crate) fn line_distance(
    target: &[f64],
    pattern: &LinePattern,
    shift: f64,
    ceiling: f64,
    cap: f64,
    audible: f64,
) -> f64 {
    let in_band = pattern.in_band(shift, ceiling);
    let mut memo = pattern.heard_memo.borrow_mut();
    let key = (in_band, audible.to_bits());
    let heard = match &mut *memo {
        Some((n, a, heard)) if (*n, *a) == key => heard,
        slot => {
            &mut slot
                .insert((key.0, key.1, pattern.heard_below(in_band, audible)))
                .2
        }
    };
    capped_nearest(target, &pattern.u, shift, cap) + capped_nearest(heard, target, -shift, cap)
}

/// The coarse ν step of [`line_spectrum_start`]'s grid (the loaded match's split-free search
/// uses the same grid).
pub(crate) const LINE_MATCH_POISSON_STEP: f64 = 0.0025;

/// The line-spectrum start: the (E, ν) whose audible simulated partials best match the
/// target's modes. For each ν on a grid the pattern u_k = ½ ln θ_k(ν) is fixed and E only
/// shifts it (ln f_k = u_k + ½ ln(E/ρ) − ln 2π), so the search is over that shift on a grid
/// of 5·10⁻⁴ in ln f (0.05 % in frequency) across [E₀/F, E₀·F] (F =
/// `youngs_search_factor`), then refined tenfold around the best point. The distance is
/// symmetric: the mean over target modes of the capped distance to the nearest simulated
/// partial, plus the mean over audible simulated partials below 1.02 × the highest target
/// mode (and the band limit) of the capped distance to the nearest target mode. The cap
/// (`line_match_cap`, ln f) keeps a missing or extra mode from outweighing the rest.
///
/// The two sides are not alike. A recorded line proves that its mode is heard, so it may pair
/// with any partial of the model. A partial of the model needs a recorded partner only if it
/// should be heard: its driving-point weight (φ_k·n)² is at least [`AUDIBLE_FRACTION`] of the
/// loudest partial *in the compared band at this shift*. Why both: the first version filtered
/// every partial against the loudest of all the solved ones, which can lie far above the band.
/// A blind case (set 1, seed 101, case 028: clean, struck at the bowl's bottom, E = 90.8 GPa,
/// three recorded pairs at 1.79, 4.49 and 8.00 kHz below a 9.2 kHz band) has its loudest
/// partial, a breathing mode at 14.4 kHz, 250 times louder than the loudest in the band, so
/// the 4.49 and 8.00 kHz pairs were "inaudible", the true E scored 1.37·10⁻² and E = 521 GPa
/// (one model pair on the recorded 4.49 kHz pair, nothing else in band) 1.34·10⁻², and the
/// diagnosis stopped with two matched modes.
pub fn line_spectrum_start(
    basis: &PoissonBasis,
    problem: &MaterialProblem,
    start: (f64, f64),
    settings: &MaterialFitSettings,
) -> Result<LineSpectrumStart, MaterialFitError> {
    let (target, ceiling) = line_match_targets(problem)?;
    let (lo, hi) = settings.poisson_bounds;
    let nus: Vec<f64> = if settings.learn_poisson {
        let n = ((hi - lo) / LINE_MATCH_POISSON_STEP).ceil().max(1.0) as usize;
        (0..=n)
            .map(|i| lo + (hi - lo) * i as f64 / n as f64)
            .collect()
    } else {
        vec![start.1.clamp(lo, hi)]
    };
    let two_pi_ln = (2.0 * std::f64::consts::PI).ln();
    let shift_of = |youngs: f64| 0.5 * (youngs / problem.density).ln() - two_pi_ln;
    let factor = settings.youngs_search_factor.max(1.0);
    let (c_lo, c_hi) = (shift_of(start.0 / factor), shift_of(start.0 * factor));
    let cap = settings.line_match_cap;
    // The partials at ν with their driving-point weights.
    let pattern = |nu: f64| -> LinePattern {
        let modes = basis.solve(nu);
        LinePattern::new((0..modes.theta.len()).map(|k| {
            (
                modes.theta[k],
                driving_point_weight(basis, &modes, problem, k),
            )
        }))
    };
    let distance =
        |u: &LinePattern, c: f64| line_distance(&target, u, c, ceiling, cap, AUDIBLE_FRACTION);
    let mut evaluations = 0;
    let mut best = (f64::INFINITY, c_lo, nus[0]);
    let coarse = 5e-4;
    let n_c = ((c_hi - c_lo) / coarse).ceil() as usize;
    for &nu in &nus {
        let u = pattern(nu);
        for i in 0..=n_c {
            let c = c_lo + i as f64 * coarse;
            let d = distance(&u, c);
            evaluations += 1;
            if d < best.0 {
                best = (d, c, nu);
            }
        }
    }
    // Refine tenfold around the best grid point.
    let (c0, nu0) = (best.1, best.2);
    let nu_step = if settings.learn_poisson { 0.00025 } else { 0.0 };
    for j in -10..=10 {
        let nu = (nu0 + j as f64 * nu_step).clamp(lo, hi);
        let u = pattern(nu);
        for i in -10..=10 {
            let c = c0 + i as f64 * coarse / 10.0;
            let d = distance(&u, c);
            evaluations += 1;
            if d < best.0 {
                best = (d, c, nu);
            }
        }
        if nu_step == 0.0 {
            break;
        }
    }
    let youngs = problem.density * (2.0 * (best.1 + two_pi_ln)).exp();
    Ok(LineSpectrumStart {
        youngs,
        poisson: best.2,
        distance: best.0,
        evaluations,
        poisson_range: if settings.learn_poisson {
            (lo, hi)
        } else {
            (best.2, best.2)
        },
    })
}

/// Fits E (and ν) from `start = (E, ν)`. `on_step` sees every step (progress display).
/// `check` is called every `check_every` steps with the current ν and returns whether the basis
/// was refreshed (the caller owns the PETSc objects): it returns the largest Ritz residual.
///
/// *Several starts.* From a line-spectrum start the spectral loss alone is followed, and its
/// basin is a fraction of a partial's bandwidth wide: where it ends depends on where it
/// starts, finer than the line match can rank starts. On the real bowl, two line-match
/// rankings put the start at ν 0.1835 and 0.1890; the fits ended at losses 2.23 (ν 0.1905) and
/// 2.75 (ν 0.2024), and the second basin's diagnosis explained nothing. On 64 saved benchmark
/// cases the line match's ν was off by up to 0.006–0.009 (90th percentile,
/// `docs/diagnose_benchmarks.md`, twenty-eighth). So with `start_probes` = m, the ν at
/// ±`start_probe_spacing` × 1..=m around the line-spectrum start are tried too, each with the
/// E the line match gives at that ν; each runs `start_probe_steps` spectral steps from fresh
/// (no basis refresh), and the fit runs from the start whose last five steps' mean loss is the
/// lowest. The basin is chosen by the loss the fit minimises, not by the line distance.
pub fn fit_material<'p>(
    basis: &mut PoissonBasis<'p>,
    problem: &MaterialProblem,
    start: (f64, f64),
    settings: &MaterialFitSettings,
    check: impl FnMut(&mut PoissonBasis<'p>, f64) -> Result<f64, ReducedError>,
    on_step: impl FnMut(&FitStep),
) -> Result<MaterialFit, MaterialFitError> {
    let line_start = if settings.line_spectrum_start && !problem.target_modes_hz.is_empty() {
        Some(line_spectrum_start(basis, problem, start, settings)?)
    } else {
        None
    };
    let Some(line) = line_start else {
        return fit_from(basis, problem, start, None, settings, check, on_step);
    };
    let mut chosen = (line.youngs, line.poisson);
    let mut probes: Vec<StartProbe> = Vec::new();
    if settings.learn_poisson && settings.start_probes > 0 && settings.start_probe_steps > 0 {
        let probe_settings = MaterialFitSettings {
            max_steps: settings.start_probe_steps,
            check_every: 0,
            ..settings.clone()
        };
        // E at a held ν: the line match's shift search alone, near the start's E.
        let at_nu = MaterialFitSettings {
            learn_poisson: false,
            youngs_search_factor: 1.1,
            ..settings.clone()
        };
        let (lo, hi) = settings.poisson_bounds;
        let m = settings.start_probes as i64;
        let mut best = f64::INFINITY;
        for i in -m..=m {
            let nu = (line.poisson + i as f64 * settings.start_probe_spacing).clamp(lo, hi);
            if probes.iter().any(|p| (p.poisson - nu).abs() < 1e-12) {
                continue;
            }
            let youngs = if i == 0 {
                line.youngs
            } else {
                line_spectrum_start(basis, problem, (line.youngs, nu), &at_nu)?.youngs
            };
            let probe = fit_from(
                basis,
                problem,
                (youngs, nu),
                Some(line),
                &probe_settings,
                |_: &mut PoissonBasis<'p>, _: f64| Ok(0.0),
                |_: &FitStep| {},
            )?;
            let tail: Vec<f64> = probe.history.iter().rev().take(5).map(|s| s.loss).collect();
            let loss = tail.iter().sum::<f64>() / tail.len().max(1) as f64;
            probes.push(StartProbe {
                youngs,
                poisson: nu,
                loss,
            });
            if loss < best {
                best = loss;
                chosen = (youngs, nu);
            }
        }
    }
    let mut fit = fit_from(basis, problem, chosen, Some(line), settings, check, on_step)?;
    fit.start_probes = probes;
    Ok(fit)
}

/// The fit from `start`: the spectral loss alone when `line_start` is given (the start is then
/// a line-spectrum match or a probe about one), else the transport phase first.
fn fit_from<'p>(
    basis: &mut PoissonBasis<'p>,
    problem: &MaterialProblem,
    start: (f64, f64),
    line_start: Option<LineSpectrumStart>,
    settings: &MaterialFitSettings,
    mut check: impl FnMut(&mut PoissonBasis<'p>, f64) -> Result<f64, ReducedError>,
    mut on_step: impl FnMut(&FitStep),
) -> Result<MaterialFit, MaterialFitError> {
    let n_channels = problem.targets.len();
    if n_channels == 0
        || problem
            .targets
            .iter()
            .any(|t| t.len() != problem.targets[0].len() || t.is_empty())
    {
        return Err(MaterialFitError::Targets);
    }
    let transport: Vec<PeakTransportLoss> = problem
        .targets
        .iter()
        .map(|t| PeakTransportLoss::new(t, problem.sample_rate, settings.transport.clone()))
        .collect::<Result<_, _>>()?;
    let mut losses = Losses::Transport(transport);
    let mut schedule = HybridSchedule::new(
        settings.schedule_patience,
        settings.schedule_min_improvement,
    );
    let spectral_losses = || -> Result<Vec<MultiScaleSpectralLoss>, LossError> {
        problem
            .targets
            .iter()
            .map(|t| MultiScaleSpectralLoss::new(t, settings.spectral.clone()))
            .collect()
    };

    // Parameters: [σ, ν, γ_0 … γ_(C−1)] with σ = ln E + m(ν), m(ν) = mean_k ln θ_k(ν): the
    // mean log-eigenvalue up to ln ρ. At fixed σ a change of ν keeps the spectrum's overall
    // scale and only changes its spacing, so ν cannot stand in for E while E is still far off.
    let (lo, hi) = settings.poisson_bounds;
    let mean_log_theta = |modes: &ReducedModes| {
        modes.theta.iter().map(|t| t.ln()).sum::<f64>() / modes.theta.len() as f64
    };
    let start_nu = start.1.clamp(lo, hi);
    let mut params = vec![
        start.0.ln() + mean_log_theta(&basis.solve(start_nu)),
        start_nu,
    ];
    // Gains that match each channel's RMS at the start.
    let first = render_channels(
        basis,
        problem,
        start.0,
        params[1],
        &vec![0.0; n_channels],
        None,
    )?;
    params.extend(rms_matched_log_gains(&first, problem.targets));
    let n_modes = basis.solve(start_nu).theta.len();
    let n_offsets = if settings.free_amplitudes {
        n_modes * n_channels
    } else {
        0
    };
    let offsets_at = 2 + n_channels;
    params.extend(std::iter::repeat_n(0.0, n_offsets));
    let steps: Vec<f64> = [
        settings.step_log_youngs,
        if settings.learn_poisson {
            settings.step_poisson
        } else {
            0.0
        },
    ]
    .into_iter()
    .chain(std::iter::repeat_n(
        settings.step_log_gain,
        n_channels + n_offsets,
    ))
    .collect();
    let spectral_steps: Vec<f64> = [
        settings.spectral_step_log_youngs,
        if settings.learn_poisson {
            settings.spectral_step_poisson
        } else {
            0.0
        },
    ]
    .into_iter()
    .chain(std::iter::repeat_n(
        settings.step_log_gain,
        n_channels + n_offsets,
    ))
    .collect();
    let mut lower = vec![f64::NEG_INFINITY; params.len()];
    let mut upper = vec![f64::INFINITY; params.len()];
    lower[1] = lo;
    upper[1] = hi;
    let mut adam = super::optim::Adam::new(steps).with_bounds(lower, upper);
    if line_start.is_some() {
        // The line-spectrum start has done the transport phase's work, more finely than the
        // transport loss resolves (a bin of its FFT is ~1 % of a partial's frequency): go
        // straight to the spectral loss.
        losses = Losses::Spectral(spectral_losses()?);
        schedule = HybridSchedule::fixed(LossPhase::Spectral);
        adam.set_step_sizes(spectral_steps.clone());
    }

    let mut history = Vec::new();
    let mut max_residual = 0.0_f64;
    let n = problem.targets[0].len();
    let mut recent: std::collections::VecDeque<(f64, f64)> = std::collections::VecDeque::new();
    for step in 0..settings.max_steps {
        if settings.check_every > 0 && step > 0 && step % settings.check_every == 0 {
            // Hold E across a refresh: σ is tied to the basis through mean ln θ, which a new sample
            // can move.
            let youngs_before = (params[0] - mean_log_theta(&basis.solve(params[1]))).exp();
            max_residual = check(basis, params[1])?;
            params[0] = youngs_before.ln() + mean_log_theta(&basis.solve(params[1]));
        }
        let nu = params[1];
        let modes = basis.solve(nu);
        let youngs = (params[0] - mean_log_theta(&modes)).exp();
        let (eigenvalues, projections) = modal_inputs(basis, &modes, problem, youngs);
        let mut grad = vec![0.0; params.len()];
        let mut total = 0.0;
        for c in 0..n_channels {
            let offset = |k: usize| {
                if n_offsets > 0 {
                    params[offsets_at + k * n_channels + c]
                } else {
                    0.0
                }
            };
            let proj: Vec<f64> = projections
                .iter()
                .enumerate()
                .map(|(k, p)| p * (params[2 + c] + offset(k)).exp())
                .collect();
            let (bank, chain) =
                ModalChain::new(&eigenvalues, &proj, &problem.damping, &problem.strike)?;
            let signal = render_samples(&bank, problem.sample_rate, n);
            let (value, g_signal) = match &losses {
                Losses::Transport(l) => l[c].value_and_gradient(&signal),
                Losses::Spectral(l) => l[c].value_and_gradient(&signal),
            }?;
            total += value;
            let g_bank: BankGradient = render_backward(&bank, problem.sample_rate, &g_signal);
            let g = chain.backward(&g_bank);
            for k in 0..eigenvalues.len() {
                grad[0] += g.eigenvalues[k] * eigenvalues[k];
                grad[1] += g.eigenvalues[k] * youngs / problem.density * modes.dtheta_dnu[k];
                grad[2 + c] += g.projections[k] * proj[k];
                if n_offsets > 0 {
                    grad[offsets_at + k * n_channels + c] = g.projections[k] * proj[k];
                }
            }
        }
        // From (ln E, ν) to (σ, ν): dL/dσ = dL/dlnE, dL/dν|σ = dL/dν|E − dL/dlnE · m'(ν).
        let dm_dnu = modes
            .theta
            .iter()
            .zip(&modes.dtheta_dnu)
            .map(|(t, d)| d / t)
            .sum::<f64>()
            / modes.theta.len() as f64;
        grad[1] -= grad[0] * dm_dnu;
        if schedule.phase() == LossPhase::Transport {
            // ν waits for the scan at the switch, and the gains keep their RMS match: the
            // peak-transport loss counts dB above a floor, so a louder prediction spreads its
            // mass and blunts the pull on E (module docs).
            grad[1] = 0.0;
            grad[2..].iter_mut().for_each(|g| *g = 0.0);
        }
        let record = FitStep {
            step,
            phase: schedule.phase(),
            loss: total,
            youngs,
            poisson: nu,
        };
        on_step(&record);
        history.push(record);
        adam.step(&mut params, &grad);
        let before = schedule.phase();
        let after = schedule.observe(total);
        if before == LossPhase::Transport && after == LossPhase::Spectral {
            let spectral = spectral_losses()?;
            if settings.learn_poisson && line_start.is_none() && settings.poisson_scan > 0 {
                params[1] = scan_poisson(
                    basis,
                    problem,
                    &spectral,
                    params[0],
                    &params[2..offsets_at],
                    settings,
                )?;
            }
            losses = Losses::Spectral(spectral);
            adam.reset_moments();
            adam.set_step_sizes(spectral_steps.clone());
        } else if after == LossPhase::Spectral {
            adam.scale_steps(settings.spectral_decay);
            recent.push_back((youngs.ln(), params[1]));
            if recent.len() > settings.patience {
                recent.pop_front();
                let (e0, n0) = recent[0];
                let moved = recent
                    .iter()
                    .map(|(e, n)| ((e - e0).abs()).max((n - n0).abs()))
                    .fold(0.0, f64::max);
                if moved < settings.tolerance {
                    break;
                }
            }
        }
    }
    // E from the basis the last step used; a final refresh only reports (the caller checks the
    // answer against a full solve).
    let youngs = (params[0] - mean_log_theta(&basis.solve(params[1]))).exp();
    if settings.check_every > 0 {
        max_residual = max_residual.max(check(basis, params[1])?);
    }
    Ok(MaterialFit {
        youngs,
        poisson: params[1],
        log_gains: params[2..offsets_at].to_vec(),
        log_amplitude_offsets: if n_offsets > 0 {
            params[offsets_at..].to_vec()
        } else {
            vec![0.0; n_modes * n_channels]
        },
        steps: history.len(),
        history,
        switched_at: schedule.switched_at(),
        basis_samples: basis.samples().to_vec(),
        max_residual,
        line_start,
        start_probes: Vec::new(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_remembered_audible_partials_give_the_distance_of_a_fresh_pattern() {
        // Partials (θ, weight) whose band edge crosses several of them over the scan, one of
        // them too quiet to be required: the memo must follow the edge both ways and the
        // audible fraction.
        let partials: Vec<(f64, f64)> = [
            (1000.0, 1.0),
            (1510.0, 0.5),
            (2300.0, 1e-4),
            (3100.0, 2.0),
            (4700.0, 0.8),
            (6900.0, 5.0),
        ]
        .iter()
        .map(|&(f, w): &(f64, f64)| (f * f, w))
        .collect();
        let target: Vec<f64> = [1003.0, 1500.0, 3120.0, 4650.0]
            .iter()
            .map(|f: &f64| f.ln())
            .collect();
        let ceiling = 4800.0_f64.ln();
        let remembered = LinePattern::new(partials.iter().copied());
        let shifts = (0..400)
            .map(|i| -0.6 + 0.003 * i as f64)
            .chain((0..400).map(|i| 0.6 - 0.003 * i as f64));
        for (i, c) in shifts.enumerate() {
            let audible = if i % 7 == 0 { 0.3 } else { AUDIBLE_FRACTION };
            let fresh = LinePattern::new(partials.iter().copied());
            let a = line_distance(&target, &remembered, c, ceiling, 0.02, audible);
            let b = line_distance(&target, &fresh, c, ceiling, 0.02, audible);
            assert_eq!(
                a.to_bits(),
                b.to_bits(),
                "shift {c}, audible {audible}: {a} vs {b}"
            );
        }
    }

    #[test]
    fn capped_nearest_measures_shifted_lines() {
        let a = [0.0, 1.0, 2.0];
        // Each line of `a` is 0.01 from a line of `b` shifted by 0.5.
        let b = [-0.49, 0.51, 1.51];
        assert!((capped_nearest(&a, &b, 0.5, 0.1) - 0.01).abs() < 1e-12);
        // A line with no partner within the cap counts the cap.
        assert!((capped_nearest(&[0.0, 5.0], &[0.0], 0.0, 0.1) - 0.05).abs() < 1e-12);
        assert_eq!(capped_nearest(&[], &b, 0.0, 0.1), 0.0);
    }

    /// Set 1 case 028 (module docs of [`line_spectrum_start`]): the bowl struck at its bottom,
    /// its partials at the true E (Hz) with their driving-point weights as the reduced basis gave
    /// them, and the six recorded lines. The loudest partial (14.4 kHz) lies far above the band;
    /// the match must still put the scale at the truth and not pair the lowest model pair with
    /// the recorded 4.49 kHz pair.
    #[test]
    fn the_line_match_holds_when_the_loudest_partial_lies_above_the_band() {
        let partials = [
            (1792.0, 1.708e-1),
            (1795.7, 1.836e2),
            (4493.0, 2.232),
            (4495.9, 7.963e-1),
            (8000.9, 1.645e-2),
            (8002.2, 9.208e-3),
            (12223.8, 1.508),
            (12225.2, 5.262e-1),
            (13272.6, 2.059e4),
            (14370.8, 4.510e4),
            (14479.8, 1.992e1),
            (16743.8, 8.723e1),
        ];
        let pattern = LinePattern::new(partials.iter().map(|&(f, w): &(f64, f64)| (f * f, w)));
        let target: Vec<f64> = [1791.98, 1795.76, 4493.03, 4495.90, 8001.12, 8002.79]
            .iter()
            .map(|f: &f64| f.ln())
            .collect();
        let ceiling = (1.02_f64 * 8002.79).ln();
        let d = |c: f64| line_distance(&target, &pattern, c, ceiling, 0.02, AUDIBLE_FRACTION);
        // At the truth every recorded line has a partner and every heard partial one too; the
        // weak 8.0 kHz pair (below 10⁻³ of the band's loudest) may pair without being required.
        assert!(d(0.0) < 1e-3, "distance at the truth {}", d(0.0));
        let heard = pattern.heard(0.0, ceiling, AUDIBLE_FRACTION);
        assert_eq!(
            heard.len(),
            3,
            "heard {:?}",
            heard.iter().map(|u| u.exp()).collect::<Vec<_>>()
        );
        // The scale that put the lowest model pair on the recorded 4.49 kHz pair loses.
        let wrong = (4493.0_f64 / 1795.7).ln();
        assert!(
            d(wrong) > 10.0 * d(0.0),
            "wrong {} truth {}",
            d(wrong),
            d(0.0)
        );
        // A scan over E within a factor 8 either way lands at the truth.
        let half = 0.5 * 8.0_f64.ln();
        let best = (0..=4200)
            .map(|i| -half + i as f64 * 2.0 * half / 4200.0)
            .min_by(|a, b| d(*a).total_cmp(&d(*b)))
            .unwrap();
        assert!(best.abs() < 1e-3, "best shift {best}");
    }

    #[test]
    fn a_poisson_ratio_on_an_end_of_its_searched_range_is_flagged() {
        let at = |poisson: f64, poisson_range: (f64, f64)| LineSpectrumStart {
            youngs: 7e10,
            poisson,
            distance: 1e-3,
            evaluations: 1,
            poisson_range,
        };
        assert!(at(0.1, (0.1, 0.4)).poisson_at_edge());
        assert!(at(0.4, (0.1, 0.4)).poisson_at_edge());
        assert!(at(0.3998, (0.1, 0.4)).poisson_at_edge());
        assert!(!at(0.101, (0.1, 0.4)).poisson_at_edge());
        assert!(!at(0.25, (0.1, 0.4)).poisson_at_edge());
        // A held ν was not searched: nothing to flag.
        assert!(!at(0.3, (0.3, 0.3)).poisson_at_edge());
    }

    #[test]
    fn band_weight_fades_out_over_ten_percent() {
        assert_eq!(band_weight(5000.0, None), 1.0);
        assert_eq!(band_weight(1000.0, Some(1000.0)), 1.0);
        assert!((band_weight(1050.0, Some(1000.0)) - 0.5).abs() < 1e-12);
        assert_eq!(band_weight(1100.0, Some(1000.0)), 0.0);
        assert_eq!(band_weight(2000.0, Some(1000.0)), 0.0);
    }
}
