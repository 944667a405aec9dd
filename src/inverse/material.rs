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
//! is re-evaluated at every step. The reduced basis is checked every `check_every` steps: if a
//! Ritz pair's relative residual exceeds `residual_tolerance`, the current ν is added as a
//! sample (one full solve).

use crate::audio::chain::{DampingModel, ModalChain, Strike};
use crate::audio::loss::{HybridSchedule, LossPhase, MultiScaleSpectralLoss, PeakTransportConfig, PeakTransportLoss, SpectralLossConfig};
use crate::audio::synth::{render_backward, render_samples, BankGradient};
use crate::eigen::reduced::{PoissonBasis, ReducedModes};

/// Settings of the material fit (module docs).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MaterialFitSettings {
    pub learn_poisson: bool,
    pub step_log_youngs: f64,
    pub step_poisson: f64,
    pub step_log_gain: f64,
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
    /// Grid points of the ν scan at the switch to the spectral loss.
    pub poisson_scan: usize,
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
            poisson_bounds: (0.0, 0.49),
            max_steps: 600,
            schedule_patience: 10,
            schedule_min_improvement: 0.002,
            spectral_decay: 0.99,
            tolerance: 1e-6,
            patience: 20,
            check_every: 50,
            residual_tolerance: 1e-2,
            poisson_scan: 45,
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
}

/// One step of the history.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FitStep {
    pub step: usize,
    pub phase: LossPhase,
    pub loss: f64,
    pub youngs: f64,
    pub poisson: f64,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct MaterialFit {
    pub youngs: f64,
    pub poisson: f64,
    pub log_gains: Vec<f64>,
    pub history: Vec<FitStep>,
    pub switched_at: Option<usize>,
    pub steps: usize,
    pub basis_samples: Vec<f64>,
    pub max_residual: f64,
}

/// Projections c_k (without gain) and the eigenvalues at (E, ν).
fn modal_inputs(basis: &PoissonBasis, modes: &ReducedModes, problem: &MaterialProblem, youngs: f64) -> (Vec<f64>, Vec<f64>) {
    let eigenvalues = modes.eigenvalues(youngs, problem.density);
    let projections = (0..modes.theta.len())
        .map(|k| {
            let probe = basis.probe(modes, k);
            let along: f64 = probe.iter().zip(&problem.direction_weights).map(|(v, w)| v * w).sum();
            along * along / problem.density
        })
        .collect();
    (eigenvalues, projections)
}

/// Renders every channel at (E, ν, gains).
pub fn render_channels(basis: &PoissonBasis, problem: &MaterialProblem, youngs: f64, poisson: f64, log_gains: &[f64]) -> Result<Vec<Vec<f64>>, String> {
    let modes = basis.solve(poisson);
    let (eigenvalues, projections) = modal_inputs(basis, &modes, problem, youngs);
    let n = problem.targets[0].len();
    log_gains
        .iter()
        .map(|g| {
            let c: Vec<f64> = projections.iter().map(|p| p * g.exp()).collect();
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
fn scan_poisson(basis: &PoissonBasis, problem: &MaterialProblem, spectral: &[MultiScaleSpectralLoss], sigma: f64, log_gains: &[f64], settings: &MaterialFitSettings) -> Result<f64, String> {
    let (lo, hi) = settings.poisson_bounds;
    let n = settings.poisson_scan.max(2);
    let mut best = (f64::INFINITY, lo);
    for i in 0..n {
        let nu = lo + (hi - lo) * i as f64 / (n - 1) as f64;
        let modes = basis.solve(nu);
        let m = modes.theta.iter().map(|t| t.ln()).sum::<f64>() / modes.theta.len() as f64;
        let rendered = render_channels(basis, problem, (sigma - m).exp(), nu, log_gains)?;
        let mut total = 0.0;
        for (loss, x) in spectral.iter().zip(&rendered) {
            total += loss.value(x).map_err(|e| e.to_string())?;
        }
        if total < best.0 {
            best = (total, nu);
        }
    }
    Ok(best.1)
}

/// Fits E (and ν) from `start = (E, ν)`. `on_step` sees every step (progress display).
/// `check` is called every `check_every` steps with the current ν and returns whether the basis
/// was refreshed (the caller owns the PETSc objects): it returns the largest Ritz residual.
pub fn fit_material<'p>(
    basis: &mut PoissonBasis<'p>,
    problem: &MaterialProblem,
    start: (f64, f64),
    settings: &MaterialFitSettings,
    mut check: impl FnMut(&mut PoissonBasis<'p>, f64) -> Result<f64, String>,
    mut on_step: impl FnMut(&FitStep),
) -> Result<MaterialFit, String> {
    let n_channels = problem.targets.len();
    if n_channels == 0 || problem.targets.iter().any(|t| t.len() != problem.targets[0].len() || t.is_empty()) {
        return Err("the material fit needs one or more target channels of equal, non-zero length".into());
    }
    let transport: Vec<PeakTransportLoss> = problem
        .targets
        .iter()
        .map(|t| PeakTransportLoss::new(t, problem.sample_rate, settings.transport.clone()))
        .collect::<Result<_, _>>()
        .map_err(|e| e.to_string())?;
    let mut losses = Losses::Transport(transport);
    let mut schedule = HybridSchedule::new(settings.schedule_patience, settings.schedule_min_improvement);

    // Parameters: [σ, ν, γ_0 … γ_(C−1)] with σ = ln E + m(ν), m(ν) = mean_k ln θ_k(ν): the
    // mean log-eigenvalue up to ln ρ. At fixed σ a change of ν keeps the spectrum's overall
    // scale and only changes its spacing, so ν cannot stand in for E while E is still far off.
    let (lo, hi) = settings.poisson_bounds;
    let mean_log_theta = |modes: &ReducedModes| modes.theta.iter().map(|t| t.ln()).sum::<f64>() / modes.theta.len() as f64;
    let start_nu = start.1.clamp(lo, hi);
    let mut params = vec![start.0.ln() + mean_log_theta(&basis.solve(start_nu)), start_nu];
    // Gains that match each channel's RMS at the start.
    let first = render_channels(basis, problem, start.0, params[1], &vec![0.0; n_channels])?;
    for (rendered, target) in first.iter().zip(problem.targets) {
        let rms = |x: &[f64]| (x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64).sqrt();
        let (r, t) = (rms(rendered), rms(target));
        params.push(if r > 0.0 && t > 0.0 { (t / r).ln() } else { 0.0 });
    }
    let steps: Vec<f64> = [settings.step_log_youngs, if settings.learn_poisson { settings.step_poisson } else { 0.0 }]
        .into_iter()
        .chain(std::iter::repeat_n(settings.step_log_gain, n_channels))
        .collect();
    let mut lower = vec![f64::NEG_INFINITY; params.len()];
    let mut upper = vec![f64::INFINITY; params.len()];
    lower[1] = lo;
    upper[1] = hi;
    let mut adam = super::optim::Adam::new(steps).with_bounds(lower, upper);

    let mut history = Vec::new();
    let mut max_residual = 0.0_f64;
    let n = problem.targets[0].len();
    let mut recent: std::collections::VecDeque<(f64, f64)> = std::collections::VecDeque::new();
    for step in 0..settings.max_steps {
        if settings.check_every > 0 && step > 0 && step % settings.check_every == 0 {
            max_residual = check(basis, params[1])?;
        }
        let nu = params[1];
        let modes = basis.solve(nu);
        let youngs = (params[0] - mean_log_theta(&modes)).exp();
        let (eigenvalues, projections) = modal_inputs(basis, &modes, problem, youngs);
        let mut grad = vec![0.0; params.len()];
        let mut total = 0.0;
        for c in 0..n_channels {
            let gain = params[2 + c].exp();
            let proj: Vec<f64> = projections.iter().map(|p| p * gain).collect();
            let (bank, chain) = ModalChain::new(&eigenvalues, &proj, &problem.damping, &problem.strike)?;
            let signal = render_samples(&bank, problem.sample_rate, n);
            let (value, g_signal) = match &losses {
                Losses::Transport(l) => l[c].value_and_gradient(&signal),
                Losses::Spectral(l) => l[c].value_and_gradient(&signal),
            }
            .map_err(|e| e.to_string())?;
            total += value;
            let g_bank: BankGradient = render_backward(&bank, problem.sample_rate, &g_signal);
            let g = chain.backward(&g_bank);
            for k in 0..eigenvalues.len() {
                grad[0] += g.eigenvalues[k] * eigenvalues[k];
                grad[1] += g.eigenvalues[k] * youngs / problem.density * modes.dtheta_dnu[k];
                grad[2 + c] += g.projections[k] * proj[k];
            }
        }
        // From (ln E, ν) to (σ, ν): dL/dσ = dL/dlnE, dL/dν|σ = dL/dν|E − dL/dlnE · m'(ν).
        let dm_dnu = modes.theta.iter().zip(&modes.dtheta_dnu).map(|(t, d)| d / t).sum::<f64>() / modes.theta.len() as f64;
        grad[1] -= grad[0] * dm_dnu;
        if schedule.phase() == LossPhase::Transport {
            // ν waits for the scan at the switch, and the gains keep their RMS match: the
            // peak-transport loss counts dB above a floor, so a louder prediction spreads its
            // mass and blunts the pull on E (module docs).
            grad[1] = 0.0;
            grad[2..].iter_mut().for_each(|g| *g = 0.0);
        }
        let record = FitStep { step, phase: schedule.phase(), loss: total, youngs, poisson: nu };
        on_step(&record);
        history.push(record);
        adam.step(&mut params, &grad);
        let before = schedule.phase();
        let after = schedule.observe(total);
        if before == LossPhase::Transport && after == LossPhase::Spectral {
            let spectral: Vec<MultiScaleSpectralLoss> = problem
                .targets
                .iter()
                .map(|t| MultiScaleSpectralLoss::new(t, settings.spectral.clone()))
                .collect::<Result<_, _>>()
                .map_err(|e| e.to_string())?;
            if settings.learn_poisson {
                params[1] = scan_poisson(basis, problem, &spectral, params[0], &params[2..], settings)?;
            }
            losses = Losses::Spectral(spectral);
            adam.reset_moments();
        } else if after == LossPhase::Spectral {
            adam.scale_steps(settings.spectral_decay);
            recent.push_back((youngs.ln(), params[1]));
            if recent.len() > settings.patience {
                recent.pop_front();
                let (e0, n0) = recent[0];
                let moved = recent.iter().map(|(e, n)| ((e - e0).abs()).max((n - n0).abs())).fold(0.0, f64::max);
                if moved < settings.tolerance {
                    break;
                }
            }
        }
    }
    max_residual = max_residual.max(check(basis, params[1])?);
    let youngs = (params[0] - mean_log_theta(&basis.solve(params[1]))).exp();
    Ok(MaterialFit {
        youngs,
        poisson: params[1],
        log_gains: params[2..].to_vec(),
        steps: history.len(),
        history,
        switched_at: schedule.switched_at(),
        basis_samples: basis.samples().to_vec(),
        max_residual,
    })
}
