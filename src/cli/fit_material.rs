//! The `fit-material` job: damping, Young's modulus and Poisson's ratio from recordings of one
//! strike, by analysis by synthesis.
//!
//! ```text
//! mpirun -np 2 diffsound fit-material --config examples/bowl/fit.toml
//! diffsound fit-material --mesh bowl.msh --recording mic0.wav --recording mic1.wav --out fit.h5
//! ```
//!
//! # Stages
//!
//! 1. **Recording.** Every file is read, resampled to `sample_rate`, cut at the shared strike
//!    onset ([`crate::audio::recording`]; pre-roll before the onset is dropped) and kept for
//!    `duration` s; one gain for all channels (their relative levels are data).
//! 2. **Damping** ([`crate::inverse::damping`], rank 0): many free modes + filtered noise fitted
//!    to all channels at once (frequencies and decay rates shared, amplitudes per channel); the
//!    modes judged real give the damping curve d(f) and, beside it, a Rayleigh fit (α, β).
//! 3. **Target.** The recorded lines (in each kept peak, the poles with at least a tenth of the
//!    energy of its strongest one) below `max_frequency_hz` (faded out over [f_max, 1.1 f_max],
//!    [`crate::inverse::material::band_weight`]) are re-synthesised per channel: the recording
//!    without its noise and without the partials above the band the simulated modes cover.
//! 4. **Material** ([`crate::inverse::material`], every rank): the mesh (P1 or P2) is assembled,
//!    a reduced basis in ν is built from full SLEPc solves at `basis_samples`, and E (with ρ
//!    given), ν and per-channel gains (and, with `free_amplitudes`, per-mode amplitudes) are
//!    fitted by the hybrid transport → spectral schedule with the damping curve held fixed.
//! 5. **Checks.** A full SLEPc solve at the fitted (E, ν) is compared with the reduced basis;
//!    every recorded mode in the band is paired with its nearest simulated mode (one to one,
//!    closest pairs first) and the frequency errors are listed; the spectrogram error
//!    ([`crate::audio::stft::spectrogram_error`], mean over channels) against the target is
//!    reported at the start and at the fit.
//!
//! Every rank runs stages 1–3 identically from rank 0's broadcast, and the fit loop is the same
//! deterministic serial code on every rank between collective solves, so the answer does not
//! depend on the number of ranks beyond the rounding of the distributed solves.
//!
//! # HDF5 result (`out`)
//!
//! | path | contents |
//! |------|----------|
//! | `/` attrs | `format` = `diffsound.fit_material`, `format_version` = 1, `mesh`, `recordings`, `order`, `n_ranks`, `command`, `version` |
//! | `/material` attrs | `youngs_modulus` [Pa], `poisson_ratio`, `density` [kg/m³], `youngs_over_density` [m²/s²], `start_youngs_modulus`, `start_poisson_ratio`, `poisson_learned` (0/1) |
//! | `/fit/history/{step,phase,loss,youngs_modulus,poisson_ratio}` | per step; phase 0 = transport, 1 = spectral |
//! | `/fit/log_gains` `[C]`, `/fit/log_amplitude_offsets` `[K, C]` | learned levels (natural log) |
//! | `/fit` attrs | `steps`, `switched_at` (−1: never), `seconds`, `basis_samples` (string), `max_ritz_residual`, `line_start_youngs_modulus`, `line_start_poisson_ratio`, `line_start_distance` |
//! | `/damping/curve/{frequencies_hz,decay_rates}` | knots of d(f) [Hz, 1/s] |
//! | `/damping/modes/{frequency_hz,decay_rate,level_db,kept}` `[M]`, `…/amplitudes`, `…/phases` `[M, C]` | every stage-1 mode |
//! | `/damping/peaks/{frequency_hz,decay_rate,level_db,kept}` | the peaks the curve is fitted to |
//! | `/damping` attrs | `rayleigh_alpha` [1/s], `rayleigh_beta` [s], `curve_rms_log_error`, `rayleigh_rms_log_error`, `loss_initial`, `loss_final` |
//! | `/modes/simulated/{frequency_hz,eigenvalues,full_eigenvalues,relative_difference}` `[K]` | fitted modes, reduced vs full solve |
//! | `/modes/matched/{recorded_frequency_hz,simulated_frequency_hz,error_hz,relative_error,recorded_decay_rate,simulated_decay_rate,simulated_index}` | one row per recorded mode in the band that found a partner |
//! | `/errors` attrs | `spectrogram_start`, `spectrogram_fit`, `max_relative_eigenvalue_difference`, `mean_abs_relative_frequency_error`, `line_start_mean_abs_relative_frequency_error` |
//! | `/timings` attrs | seconds per stage |
//!
//! Plots (PNG, prefix `plots`): `_spectrogram.png` (recording, target, start, fit of one channel
//! side by side), `_damping.png` (per-mode decay rates, kept and rejected, with the curve and the
//! Rayleigh fit), `_loss.png` (loss history), `_frequencies.png` (relative frequency error of
//! every matched mode).

use super::{fail, Progress};
use crate::assembly;
use crate::audio::chain::{DampingModel, ModalChain, Strike};
use crate::audio::recording::{load_recording, GainPolicy, RecordingOptions};
use crate::audio::stft::{spectrogram_error, StftPlan};
use crate::audio::synth::{render_samples, ModalBank};
use crate::eigen::reduced::PoissonBasis;
use crate::inverse::damping::{fit_damping, DampingFit, DampingFitSettings};
use crate::inverse::material::{
    band_weight, fit_material, render_channels, rms_matched_log_gains, MaterialFit,
    MaterialFitSettings, MaterialProblem,
};
use crate::io::paths::plot_path;
use crate::io::plot::{
    line_plot_png, spectrogram_png, AxisScale, LineFigure, Marker, Series, SpectrogramFigure,
    SpectrogramPanel,
};
use crate::io::results::ResultsFile;
use crate::mesh::{self, ReadOptions, SurfacePoint, TetMesh};
use crate::petsc::{Petsc, PetscInt};
use crate::workflow::broadcast_from_root;
use clap::Args;
use mpi::environment::Universe;
use mpi::traits::CommunicatorCollectives;
use serde::Deserialize;
use std::path::PathBuf;

#[derive(Args, Debug, Clone, Default)]
#[command(allow_negative_numbers = true)]
pub struct FitMaterialArgs {
    /// TOML configuration file (see the README); flags given here override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Tet mesh of the object (Gmsh .msh).
    #[arg(long)]
    pub mesh: Option<PathBuf>,
    /// Length unit of the mesh (m, cm, mm, … or metres per unit).
    #[arg(long)]
    pub units: Option<String>,
    /// Element order of the model: 2 (default) or 1.
    #[arg(long)]
    pub order: Option<u32>,
    /// A WAV file of the strike (repeat for several microphones; multichannel files count as
    /// several).
    #[arg(long = "recording")]
    pub recordings: Vec<PathBuf>,
    /// Analysis sample rate in Hz (default 48000).
    #[arg(long)]
    pub sample_rate: Option<u32>,
    /// Seconds of each recording used after the onset (default 1).
    #[arg(long)]
    pub duration: Option<f64>,
    /// Density ρ in kg/m³ (default 2700); the fit finds E/ρ, reported as E at this ρ.
    #[arg(long)]
    pub density: Option<f64>,
    /// Starting Young's modulus in Pa (default 7.2e10).
    #[arg(long)]
    pub youngs: Option<f64>,
    /// Starting Poisson's ratio (default 0.25).
    #[arg(long)]
    pub poisson: Option<f64>,
    /// Hold ν at its starting value.
    #[arg(long)]
    pub fix_poisson: bool,
    /// Simulated modes in the fit (default 32).
    #[arg(long)]
    pub modes: Option<usize>,
    /// Upper end of the band the material fit compares, Hz (default 8000).
    #[arg(long)]
    pub fmax: Option<f64>,
    /// Strike this surface node (0-based) in the model; default: farthest from the centre.
    #[arg(long, conflicts_with = "strike_position")]
    pub strike_vertex: Option<usize>,
    /// Strike the surface point nearest x,y,z (metres).
    #[arg(long, value_parser = super::render::parse_vec3)]
    pub strike_position: Option<[f64; 3]>,
    /// Most fit steps (default 600).
    #[arg(long)]
    pub max_steps: Option<usize>,
    /// HDF5 result (default fit_material.h5).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Prefix of the PNG plots (default: the HDF5 path without its extension).
    #[arg(long)]
    pub plots: Option<PathBuf>,
    /// Print progress even when stderr is not a terminal.
    #[arg(long, short)]
    pub verbose: bool,
    /// PETSc/SLEPc options, after `--`.
    #[arg(last = true, allow_hyphen_values = true)]
    pub petsc_options: Vec<String>,
}

/// The TOML file (every key optional; see the README for an example).
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FitFileConfig {
    pub mesh: Option<PathBuf>,
    pub units: Option<String>,
    pub order: Option<u32>,
    #[serde(default)]
    pub recordings: Vec<PathBuf>,
    pub out: Option<PathBuf>,
    pub plots: Option<PathBuf>,
    #[serde(default)]
    pub recording: RecordingConfig,
    #[serde(default)]
    pub damping: DampingFitSettings,
    #[serde(default)]
    pub material: MaterialConfig,
    #[serde(default)]
    pub fit: MaterialFitSettings,
    #[serde(default)]
    pub solver: SolverConfig,
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordingConfig {
    pub sample_rate: Option<u32>,
    pub duration: Option<f64>,
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialConfig {
    pub density: Option<f64>,
    pub youngs_modulus: Option<f64>,
    pub poisson_ratio: Option<f64>,
    pub modes: Option<usize>,
    pub max_frequency_hz: Option<f64>,
    /// ν of the full solves that span the reduced basis.
    pub basis_samples: Option<Vec<f64>>,
    /// Extra modes per sample beyond `modes` (modes reorder as ν moves).
    pub basis_margin: Option<usize>,
    pub strike_vertex: Option<usize>,
    pub strike_position: Option<[f64; 3]>,
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SolverConfig {
    #[serde(default)]
    pub petsc_options: Vec<String>,
}

/// Everything resolved and checked before PETSc starts.
#[derive(Clone, Debug)]
pub struct Job {
    pub mesh: PathBuf,
    pub unit_scale: f64,
    pub order: u32,
    pub recordings: Vec<PathBuf>,
    pub sample_rate: u32,
    pub duration: f64,
    pub density: f64,
    pub start_youngs: f64,
    pub start_poisson: f64,
    pub n_modes: usize,
    pub max_frequency_hz: f64,
    pub basis_samples: Vec<f64>,
    pub basis_margin: usize,
    pub strike_vertex: Option<usize>,
    pub strike_position: Option<[f64; 3]>,
    pub damping: DampingFitSettings,
    pub fit: MaterialFitSettings,
    pub out: PathBuf,
    pub plots: PathBuf,
    pub petsc_options: Vec<String>,
    pub verbose: bool,
}

/// Merges defaults < config file < flags and validates.
pub fn resolve(args: &FitMaterialArgs) -> Result<Job, String> {
    let file = match &args.config {
        Some(p) => {
            let text = std::fs::read_to_string(p).map_err(|e| format!("{}: {e}", p.display()))?;
            toml::from_str::<FitFileConfig>(&text).map_err(|e| format!("{}: {e}", p.display()))?
        }
        None => FitFileConfig::default(),
    };
    let super::resolve::MeshChoice {
        mesh,
        unit_scale,
        order,
        ..
    } = super::resolve::resolve_mesh(
        &args.mesh,
        &file.mesh,
        &args.units,
        &file.units,
        args.order.or(file.order),
    )?;
    let recordings = if args.recordings.is_empty() {
        file.recordings.clone()
    } else {
        args.recordings.clone()
    };
    if recordings.is_empty() {
        return Err("no recordings given: use --recording FILE (repeatable) or `recordings = [...]` in the config file".into());
    }
    for r in &recordings {
        if !r.is_file() {
            return Err(format!("recording {} does not exist", r.display()));
        }
    }
    let sample_rate = args
        .sample_rate
        .or(file.recording.sample_rate)
        .unwrap_or(48_000);
    if !(8_000..=192_000).contains(&sample_rate) {
        return Err(format!(
            "the sample rate must lie in 8000..=192000 Hz, got {sample_rate}"
        ));
    }
    let duration = args.duration.or(file.recording.duration).unwrap_or(1.0);
    if !(duration >= 0.05 && duration <= 30.0) {
        return Err(format!(
            "the duration must lie in [0.05, 30] s, got {duration}"
        ));
    }
    let density = args.density.or(file.material.density).unwrap_or(2700.0);
    if !(density.is_finite() && density > 0.0) {
        return Err(format!("the density must be positive, got {density}"));
    }
    let start_youngs = args
        .youngs
        .or(file.material.youngs_modulus)
        .unwrap_or(7.2e10);
    if !(start_youngs.is_finite() && start_youngs > 0.0) {
        return Err(format!(
            "the starting Young's modulus must be positive, got {start_youngs}"
        ));
    }
    let mut fit = file.fit.clone();
    if args.fix_poisson {
        fit.learn_poisson = false;
    }
    if let Some(n) = args.max_steps {
        fit.max_steps = n;
    }
    let start_poisson = args.poisson.or(file.material.poisson_ratio).unwrap_or(0.25);
    let (lo, hi) = fit.poisson_bounds;
    if !(lo >= -0.99 && lo < hi && hi < 0.5) {
        return Err(format!(
            "poisson_bounds must satisfy −0.99 ≤ lo < hi < 0.5, got ({lo}, {hi})"
        ));
    }
    if !(start_poisson >= lo && start_poisson <= hi) {
        return Err(format!(
            "the starting Poisson's ratio {start_poisson} lies outside the bounds [{lo}, {hi}]"
        ));
    }
    let n_modes = args.modes.or(file.material.modes).unwrap_or(32);
    if !(1..=500).contains(&n_modes) {
        return Err(format!("--modes must lie in 1..=500, got {n_modes}"));
    }
    let max_frequency_hz = args
        .fmax
        .or(file.material.max_frequency_hz)
        .unwrap_or(8000.0);
    if !(max_frequency_hz > 0.0 && 1.1 * max_frequency_hz < 0.5 * f64::from(sample_rate)) {
        return Err(format!("--fmax must be positive and 1.1 × fmax below the Nyquist frequency {} Hz, got {max_frequency_hz}", 0.5 * f64::from(sample_rate)));
    }
    let basis_samples = file
        .material
        .basis_samples
        .clone()
        .unwrap_or_else(|| vec![0.05, 0.15, 0.25, 0.35, 0.45]);
    if basis_samples.is_empty() || basis_samples.iter().any(|nu| !(*nu > -0.99 && *nu < 0.499)) {
        return Err(format!(
            "basis_samples must be one or more ν in (−0.99, 0.499), got {basis_samples:?}"
        ));
    }
    let out = args
        .out
        .clone()
        .or(file.out.clone())
        .unwrap_or_else(|| PathBuf::from("fit_material.h5"));
    let plots = args
        .plots
        .clone()
        .or(file.plots.clone())
        .unwrap_or_else(|| out.with_extension(""));
    let given = super::resolve::inputs(&mesh, &recordings);
    super::resolve::check_output(&out, &given)?;
    super::resolve::check_output(&plots, &given)?;
    let mut petsc_options = file.solver.petsc_options.clone();
    petsc_options.extend(args.petsc_options.iter().cloned());
    Ok(Job {
        mesh,
        unit_scale,
        order,
        recordings,
        sample_rate,
        duration,
        density,
        start_youngs,
        start_poisson,
        n_modes,
        max_frequency_hz,
        basis_samples,
        basis_margin: file.material.basis_margin.unwrap_or(8),
        strike_vertex: args.strike_vertex.or(file.material.strike_vertex),
        strike_position: args.strike_position.or(file.material.strike_position),
        damping: file.damping.clone(),
        fit,
        out,
        plots,
        petsc_options,
        verbose: args.verbose,
    })
}

pub fn run(universe: Universe, args: FitMaterialArgs) -> Result<(), String> {
    let job = resolve(&args)?;
    let petsc =
        Petsc::initialize(universe, "diffsound", &job.petsc_options).map_err(|e| e.to_string())?;
    let (rank, size) = (petsc.rank(), petsc.size());
    match compute(&petsc, &job) {
        Ok(()) => Ok(()),
        Err(message) => fail(rank, size, &message),
    }
}

/// What stage 1 hands on, broadcast from rank 0.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
struct StageOne {
    channels: Vec<Vec<f64>>,
    names: Vec<String>,
    onset_s: f64,
    damping: DampingFit,
}

/// Compares the fitted (E, ν) across ranks, reports any difference, and hands every rank rank
/// 0's fit.
fn agree_on_fit(
    petsc: &Petsc,
    fit: MaterialFit,
    progress: &Progress,
) -> Result<MaterialFit, String> {
    if petsc.size() == 1 {
        return Ok(fit);
    }
    let mine = [fit.youngs, fit.poisson];
    let mut all = vec![0.0_f64; 2 * petsc.size()];
    petsc.world().all_gather_into(&mine[..], &mut all[..]);
    let spread = all
        .chunks(2)
        .map(|p| ((p[0] / all[0] - 1.0).abs()).max((p[1] - all[1]).abs()))
        .fold(0.0_f64, f64::max);
    if spread > 0.0 {
        progress.say(format!(
            "ranks' fits differ by up to {spread:.2e} (relative E / absolute ν); using rank 0's"
        ));
    }
    let root = if petsc.rank() == 0 { Some(fit) } else { None };
    broadcast_from_root(petsc, root)
}

/// Stage 1 on rank 0: the recording and the damping fit. Errors travel with the broadcast so
/// that every rank stops together.
fn stage_one(petsc: &Petsc, job: &Job, progress: &Progress) -> Result<StageOne, String> {
    let local: Option<Result<StageOne, String>> = (petsc.rank() == 0).then(|| {
        let options = RecordingOptions { target_rate: Some(job.sample_rate), pre_roll_s: 0.0, duration_s: Some(job.duration), gain: GainPolicy::CommonPeak(0.5), band_max_hz: Some(job.max_frequency_hz), ..Default::default() };
        let mut rec = load_recording(&job.recordings, &options).map_err(|e| e.to_string())?;
        // Channel health (pre-roll 0: the floor is the track's last tenth): a dead, noise-only
        // or misaligned microphone is left out with a warning naming its file.
        let health = crate::audio::health::assess(&rec.names, &rec.channels, 0, f64::from(rec.sample_rate), &rec.channel_onsets_s, rec.onset_s);
        for h in health.iter().filter(|h| !h.is_healthy()) {
            eprintln!("{}", h.left_out_warning("the fit"));
        }
        let keep = crate::audio::health::healthy_channels(&health).map_err(|e| e.to_string())?;
        rec.channels = keep.iter().map(|&c| std::mem::take(&mut rec.channels[c])).collect();
        rec.names = keep.iter().map(|&c| rec.names[c].clone()).collect();
        progress.say(format!("{} channel(s) at {} Hz, onset at {:.4} s, {:.3} s each", rec.channels.len(), rec.sample_rate, rec.onset_s, rec.channels[0].len() as f64 / f64::from(rec.sample_rate)));
        let t = std::time::Instant::now();
        let damping = fit_damping(&rec.channels, f64::from(rec.sample_rate), &job.damping, |s| {
            if s.step % 25 == 0 {
                progress.say(format!("damping fit step {:4}: loss {:.5e}", s.step, s.loss));
            }
        })
        .map_err(|e| format!("damping fit: {e}"))?;
        let kept = damping.modes.iter().filter(|m| m.kept).count();
        progress.say(format!("damping fit: {} modes, {} kept, loss {:.4e} → {:.4e}, α = {:.3} 1/s, β = {:.3e} s, {:.1} s", damping.modes.len(), kept, damping.loss_initial, damping.loss_final, damping.rayleigh.alpha, damping.rayleigh.beta, t.elapsed().as_secs_f64()));
        Ok(StageOne { channels: rec.channels, names: rec.names, onset_s: rec.onset_s, damping })
    });
    let shared: Result<StageOne, String> = broadcast_from_root(petsc, local)?;
    shared
}

/// A pole carrying less than this fraction of its peak's largest member energy is part of the
/// peak's shape (beating, a fast transient under a long line), not a mode of its own.
const LINE_ENERGY_FRACTION: f64 = 0.1;

/// The recorded modes: in every kept peak, the members with at least [`LINE_ENERGY_FRACTION`]
/// of the energy of its strongest member, energy Σ_c a_c² / (2 d) (the integral of a decaying
/// sinusoid's square). A degenerate pair split by the object's imperfections stays two modes;
/// the short-lived poles the free fit adds around a long line do not count. Sorted by frequency.
fn recorded_lines(fit: &DampingFit) -> Vec<usize> {
    let energy = |i: usize| {
        let m = &fit.modes[i];
        m.amplitudes.iter().map(|a| a * a).sum::<f64>() / (2.0 * m.decay_rate.max(1e-9))
    };
    let mut lines: Vec<usize> = Vec::new();
    for peak in fit.peaks.iter().filter(|p| p.kept) {
        let strongest = peak
            .members
            .iter()
            .map(|&i| energy(i))
            .fold(0.0_f64, f64::max);
        lines.extend(
            peak.members
                .iter()
                .copied()
                .filter(|&i| fit.modes[i].kept && energy(i) >= LINE_ENERGY_FRACTION * strongest),
        );
    }
    lines.sort_by(|&a, &b| {
        fit.modes[a]
            .frequency_hz
            .total_cmp(&fit.modes[b].frequency_hz)
    });
    lines
}

/// The stage-2 target: the recorded lines ([`recorded_lines`]) below the band limit,
/// re-synthesised per channel.
fn band_limited_target(
    stage: &StageOne,
    lines: &[usize],
    fs: f64,
    n: usize,
    f_max: f64,
) -> Vec<Vec<f64>> {
    (0..stage.channels.len())
        .map(|c| {
            let mut bank = ModalBank {
                frequencies_hz: Vec::new(),
                decay_rates: Vec::new(),
                amplitudes: Vec::new(),
                phases: Vec::new(),
            };
            for m in lines.iter().map(|&i| &stage.damping.modes[i]) {
                let w = band_weight(m.frequency_hz, Some(f_max));
                if w > 0.0 {
                    bank.frequencies_hz.push(m.frequency_hz);
                    bank.decay_rates.push(m.decay_rate);
                    bank.amplitudes.push(w * m.amplitudes[c]);
                    bank.phases.push(m.phases[c]);
                }
            }
            render_samples(&bank, fs, n)
        })
        .collect()
}

/// The strike point of the model and the probe DOFs / weights that read φ(x)·n from a mode.
fn strike_probe(
    mesh: &TetMesh,
    job: &Job,
    layout: &assembly::DofLayout,
) -> Result<(SurfacePoint, Vec<PetscInt>, Vec<f64>), String> {
    let point = match (job.strike_vertex, job.strike_position) {
        (Some(v), _) => mesh
            .surface_point_at_vertex(v)
            .ok_or_else(|| format!("strike vertex {v} is not a surface corner node of the mesh"))?,
        (None, Some(p)) => mesh
            .closest_surface_point(p)
            .ok_or("the mesh has no surface")?,
        (None, None) => mesh
            .default_strike_point()
            .ok_or("the mesh has no surface")?,
    };
    let (dofs, w) = probe_along(mesh, &point, point.normal, layout);
    Ok((point, dofs, w))
}

/// The PETSc dofs of the tet holding `point` and the weights that read φ(x)·`direction` from
/// them (shape functions at the point times the direction's components).
pub(crate) fn probe_along(
    mesh: &TetMesh,
    point: &SurfacePoint,
    direction: [f64; 3],
    layout: &assembly::DofLayout,
) -> (Vec<PetscInt>, Vec<f64>) {
    let weights = mesh.shape_weights(point.barycentric);
    let mut dofs = Vec::new();
    let mut w = Vec::new();
    for (a, &node) in mesh.tet(point.tet).iter().enumerate() {
        for c in 0..3 {
            dofs.push(layout.global_dof(node, c) as PetscInt);
            w.push(weights[a] * direction[c]);
        }
    }
    (dofs, w)
}

/// Recorded modes paired one-to-one with simulated ones, closest (relative) pairs first.
#[derive(Clone, Debug)]
struct Match {
    recorded: usize,
    simulated: usize,
    relative_error: f64,
}

/// Pairs further apart than this (relative) are not the same mode.
const MAX_MATCH_ERROR: f64 = 0.1;

fn match_modes(recorded_hz: &[f64], simulated_hz: &[f64]) -> Vec<Match> {
    let mut pairs: Vec<Match> = Vec::new();
    for (i, fr) in recorded_hz.iter().enumerate() {
        for (j, fs) in simulated_hz.iter().enumerate() {
            let relative_error = (fs - fr) / fr;
            if relative_error.abs() <= MAX_MATCH_ERROR {
                pairs.push(Match {
                    recorded: i,
                    simulated: j,
                    relative_error,
                });
            }
        }
    }
    pairs.sort_by(|a, b| a.relative_error.abs().total_cmp(&b.relative_error.abs()));
    let (mut used_r, mut used_s) = (
        vec![false; recorded_hz.len()],
        vec![false; simulated_hz.len()],
    );
    let mut out = Vec::new();
    for p in pairs {
        if !used_r[p.recorded] && !used_s[p.simulated] {
            used_r[p.recorded] = true;
            used_s[p.simulated] = true;
            out.push(p);
        }
    }
    out.sort_by_key(|m| m.recorded);
    out
}

fn compute(petsc: &Petsc, job: &Job) -> Result<(), String> {
    let total = std::time::Instant::now();
    let rank = petsc.rank();
    let progress = super::stderr_progress(rank, job.verbose);
    let fs = f64::from(job.sample_rate);

    // Check the mesh before the long stage 1.
    let read = mesh::read_mesh(
        &job.mesh,
        &ReadOptions {
            unit_scale: job.unit_scale,
            fix_inverted: false,
        },
    )
    .map_err(|e| e.to_string())?;
    let mesh_model: TetMesh = if job.order == 2 {
        mesh::lift_to_quadratic(&read.mesh)
    } else {
        mesh::to_linear(&read.mesh)
    };
    drop(read);

    let t1 = std::time::Instant::now();
    let stage = stage_one(petsc, job, &progress)?;
    let stage_one_seconds = t1.elapsed().as_secs_f64();
    let n = stage.channels[0].len();
    let lines = recorded_lines(&stage.damping);
    let targets = band_limited_target(&stage, &lines, fs, n, job.max_frequency_hz);
    let in_band: Vec<usize> = lines
        .into_iter()
        .filter(|&i| stage.damping.modes[i].frequency_hz <= job.max_frequency_hz)
        .collect();
    if in_band.is_empty() {
        return Err(format!(
            "no real mode below --fmax {} Hz in the recording; raise --fmax",
            job.max_frequency_hz
        ));
    }
    progress.say(format!(
        "target: the real modes below {} Hz; {} recorded lines there: {:?} Hz",
        job.max_frequency_hz,
        in_band.len(),
        in_band
            .iter()
            .map(|&i| (stage.damping.modes[i].frequency_hz * 10.0).round() / 10.0)
            .collect::<Vec<_>>()
    ));

    let t2 = std::time::Instant::now();
    let assembled = assembly::assemble(petsc, &mesh_model).map_err(|e| e.to_string())?;
    let (lo, hi) = mesh_model.bounding_box();
    let diagonal = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
    let (point, probe_dofs, direction_weights) = strike_probe(&mesh_model, job, &assembled.layout)?;
    progress.say(format!("mesh: {} tets, {} nodes (P{}), strike at ({:.4}, {:.4}, {:.4}) m; building the reduced basis at ν = {:?}", mesh_model.n_tets(), mesh_model.n_nodes(), job.order, point.position[0], point.position[1], point.position[2], job.basis_samples));
    let mut basis = PoissonBasis::build(
        petsc,
        &assembled,
        diagonal,
        job.n_modes,
        job.basis_margin,
        &job.basis_samples,
        probe_dofs,
    )
    .map_err(|e| e.to_string())?;
    let basis_seconds = t2.elapsed().as_secs_f64();
    progress.say(format!(
        "basis: {} full solves in {:.1} s, dimension {:?}",
        basis.full_solves,
        basis.full_solve_seconds,
        basis.dimensions()
    ));

    let damping_model = DampingModel::Curve(stage.damping.curve.clone());
    let problem = MaterialProblem {
        targets: &targets,
        sample_rate: fs,
        density: job.density,
        damping: damping_model,
        strike: Strike::default(),
        direction_weights,
        max_frequency_hz: Some(job.max_frequency_hz),
        target_modes_hz: in_band
            .iter()
            .map(|&i| stage.damping.modes[i].frequency_hz)
            .collect(),
    };
    let t3 = std::time::Instant::now();
    let fit: MaterialFit = fit_material(
        &mut basis,
        &problem,
        (job.start_youngs, job.start_poisson),
        &job.fit,
        |b, nu| {
            b.refresh_if_needed(
                petsc,
                &assembled,
                nu,
                job.fit.residual_tolerance,
                job.fit.min_sample_spacing,
            )
            .map_err(|e| e.to_string())
        },
        |s| {
            if s.step % 20 == 0 {
                progress.say(format!(
                    "material step {:4} ({:?}): loss {:.5e}, E = {:.5e} Pa, ν = {:.4}",
                    s.step, s.phase, s.loss, s.youngs, s.poisson
                ));
            }
        },
    )?;
    let fit_seconds = t3.elapsed().as_secs_f64();
    // Every rank ran the same fit; they must agree exactly, since the full-solve check below and
    // every later collective step assemble with this ν on each rank's own rows (a mismatch would
    // silently assemble a stiffness matrix mixing two materials). Rank 0's fit is authoritative.
    let fit = agree_on_fit(petsc, fit, &progress)?;
    progress.say(format!(
        "fit: E = {:.5e} Pa, ν = {:.4} after {} steps in {:.1} s",
        fit.youngs, fit.poisson, fit.steps, fit_seconds
    ));

    // Check against a full solve at the optimum.
    let t4 = std::time::Instant::now();
    let reduced = basis.solve(fit.poisson);
    let (full_theta, _) =
        PoissonBasis::full_theta(petsc, &assembled, diagonal, fit.poisson, job.n_modes)
            .map_err(|e| e.to_string())?;
    let relative_difference: Vec<f64> = reduced
        .theta
        .iter()
        .zip(&full_theta)
        .map(|(r, f)| (r - f) / f)
        .collect();
    let max_difference = relative_difference
        .iter()
        .fold(0.0_f64, |m, v| m.max(v.abs()));
    let check_seconds = t4.elapsed().as_secs_f64();
    progress.say(format!(
        "full solve at the fit: largest relative eigenvalue difference {max_difference:.2e}"
    ));
    if rank == 0 && max_difference > 1e-4 {
        eprintln!("warning: the reduced basis differs from a full solve at the fit by {max_difference:.2e} (relative eigenvalue); add a basis sample near ν = {:.3} ([material] basis_samples) and run again", fit.poisson);
    }

    // Spectrogram errors and renders at the start and the fit. The start is levelled as the fit
    // levels its own start: each channel scaled to the target's RMS.
    let mut start_render = render_channels(
        &basis,
        &problem,
        job.start_youngs,
        job.start_poisson,
        &vec![0.0; targets.len()],
        None,
    )?;
    let start_gains = rms_matched_log_gains(&start_render, &targets);
    for (channel, gain) in start_render.iter_mut().zip(start_gains) {
        channel.iter_mut().for_each(|v| *v *= gain.exp());
    }
    let fit_render = render_channels(
        &basis,
        &problem,
        fit.youngs,
        fit.poisson,
        &fit.log_gains,
        Some(&fit.log_amplitude_offsets),
    )?;
    let mean_error = |renders: &[Vec<f64>]| -> Result<f64, String> {
        let mut total = 0.0;
        for (r, t) in renders.iter().zip(&targets) {
            total += spectrogram_error(r, t).map_err(|e| e.to_string())?;
        }
        Ok(total / targets.len() as f64)
    };
    let (error_start, error_fit) = (mean_error(&start_render)?, mean_error(&fit_render)?);

    // Recorded modes in the band against the fitted simulated modes.
    let eigenvalues = reduced.eigenvalues(fit.youngs, job.density);
    let (sim_hz, sim_decay) = damped_partials(&eigenvalues, &problem.damping)?;
    let recorded_hz: Vec<f64> = in_band
        .iter()
        .map(|&i| stage.damping.modes[i].frequency_hz)
        .collect();
    let matches = match_modes(&recorded_hz, &sim_hz);
    let mean_abs_error =
        matches.iter().map(|m| m.relative_error.abs()).sum::<f64>() / matches.len().max(1) as f64;
    // The same figure at the line-spectrum start, for comparison with the audio-loss optimum.
    let line_start_error = match fit.line_start {
        Some(l) => {
            let (hz, _) = damped_partials(
                &basis.solve(l.poisson).eigenvalues(l.youngs, job.density),
                &problem.damping,
            )?;
            let m = match_modes(&recorded_hz, &hz);
            Some((
                m.iter().map(|m| m.relative_error.abs()).sum::<f64>() / m.len().max(1) as f64,
                m.len(),
            ))
        }
        None => None,
    };

    if rank == 0 {
        println!(
            "fit-material: E = {:.6e} Pa (ρ = {} kg/m³, E/ρ = {:.6e} m²/s²), ν = {:.5}",
            fit.youngs,
            job.density,
            fit.youngs / job.density,
            fit.poisson
        );
        println!("  damping: {} real modes, Rayleigh α = {:.4} 1/s, β = {:.4e} s; curve knots at {:?} Hz", stage.damping.modes.iter().filter(|m| m.kept).count(), stage.damping.rayleigh.alpha, stage.damping.rayleigh.beta, stage.damping.curve.frequencies_hz.iter().map(|f| f.round()).collect::<Vec<_>>());
        println!("  spectrogram error vs target: start {error_start:.4}, fit {error_fit:.4}");
        if let (Some(l), Some((err, n))) = (fit.line_start, line_start_error) {
            println!("  line-spectrum start: E = {:.5e} Pa, ν = {:.4} (distance {:.2e}); {n} lines matched there, mean |relative frequency error| {:.3} %", l.youngs, l.poisson, l.distance, 100.0 * err);
        }
        println!("  reduced basis vs full solve at the fit: max relative eigenvalue difference {max_difference:.2e}");
        println!(
            "  {} recorded modes below {} Hz matched; mean |relative frequency error| {:.3} %",
            matches.len(),
            job.max_frequency_hz,
            100.0 * mean_abs_error
        );
        println!(
            "  {:>10} {:>10} {:>9} {:>8}",
            "recorded", "simulated", "error", "d [1/s]"
        );
        for m in &matches {
            let r = &stage.damping.modes[in_band[m.recorded]];
            println!(
                "  {:>10.2} {:>10.2} {:>8.3}% {:>8.2}",
                r.frequency_hz,
                sim_hz[m.simulated],
                100.0 * m.relative_error,
                r.decay_rate
            );
        }
        let timings = [
            ("stage_one", stage_one_seconds),
            ("basis", basis_seconds),
            ("fit", fit_seconds),
            ("full_solve_check", check_seconds),
            ("total", total.elapsed().as_secs_f64()),
        ];
        let mut file = ResultsFile::new("diffsound.fit_material", 1);
        file.text("/", "mesh", &job.mesh.display().to_string())
            .text(
                "/",
                "recordings",
                &job.recordings
                    .iter()
                    .map(|p| p.display().to_string())
                    .collect::<Vec<_>>()
                    .join(", "),
            )
            .number("/", "order", f64::from(job.order))
            .number("/", "n_ranks", petsc.size() as f64)
            .text(
                "/",
                "command",
                &std::env::args().collect::<Vec<_>>().join(" "),
            )
            .text("/", "version", env!("CARGO_PKG_VERSION"))
            .number("/material", "youngs_modulus", fit.youngs)
            .number("/material", "poisson_ratio", fit.poisson)
            .number("/material", "density", job.density)
            .number("/material", "youngs_over_density", fit.youngs / job.density)
            .number("/material", "start_youngs_modulus", job.start_youngs)
            .number("/material", "start_poisson_ratio", job.start_poisson)
            .number(
                "/material",
                "poisson_learned",
                f64::from(u8::from(job.fit.learn_poisson)),
            );
        let h = &fit.history;
        file.column(
            "/fit/history/step",
            h.iter().map(|s| s.step as f64).collect(),
            "",
        )
        .column(
            "/fit/history/phase",
            h.iter()
                .map(|s| {
                    if s.phase == crate::audio::loss::LossPhase::Transport {
                        0.0
                    } else {
                        1.0
                    }
                })
                .collect(),
            "",
        )
        .column("/fit/history/loss", h.iter().map(|s| s.loss).collect(), "1")
        .column(
            "/fit/history/youngs_modulus",
            h.iter().map(|s| s.youngs).collect(),
            "Pa",
        )
        .column(
            "/fit/history/poisson_ratio",
            h.iter().map(|s| s.poisson).collect(),
            "1",
        )
        .column("/fit/log_gains", fit.log_gains.clone(), "1")
        .dataset(
            "/fit/log_amplitude_offsets",
            &[
                fit.log_amplitude_offsets.len() / targets.len(),
                targets.len(),
            ],
            fit.log_amplitude_offsets.clone(),
            "1",
        )
        .number("/fit", "steps", fit.steps as f64)
        .number(
            "/fit",
            "switched_at",
            fit.switched_at.map_or(-1.0, |s| s as f64),
        )
        .number("/fit", "seconds", fit_seconds)
        .number("/fit", "max_ritz_residual", fit.max_residual)
        .text("/fit", "basis_samples", &format!("{:?}", fit.basis_samples));
        let dm = &stage.damping.modes;
        let c = targets.len();
        file.column(
            "/damping/curve/frequencies_hz",
            stage.damping.curve.frequencies_hz.clone(),
            "Hz",
        )
        .column(
            "/damping/curve/decay_rates",
            stage
                .damping
                .curve
                .log_decay
                .iter()
                .map(|v| v.exp())
                .collect(),
            "1/s",
        )
        .column(
            "/damping/modes/frequency_hz",
            dm.iter().map(|m| m.frequency_hz).collect(),
            "Hz",
        )
        .column(
            "/damping/modes/decay_rate",
            dm.iter().map(|m| m.decay_rate).collect(),
            "1/s",
        )
        .column(
            "/damping/modes/level_db",
            dm.iter().map(|m| m.level_db).collect(),
            "dB",
        )
        .column(
            "/damping/modes/kept",
            dm.iter().map(|m| f64::from(u8::from(m.kept))).collect(),
            "",
        )
        .dataset(
            "/damping/modes/amplitudes",
            &[dm.len(), c],
            dm.iter().flat_map(|m| m.amplitudes.clone()).collect(),
            "full scale",
        )
        .dataset(
            "/damping/modes/phases",
            &[dm.len(), c],
            dm.iter().flat_map(|m| m.phases.clone()).collect(),
            "rad",
        )
        .column(
            "/damping/peaks/frequency_hz",
            stage.damping.peaks.iter().map(|p| p.frequency_hz).collect(),
            "Hz",
        )
        .column(
            "/damping/peaks/decay_rate",
            stage.damping.peaks.iter().map(|p| p.decay_rate).collect(),
            "1/s",
        )
        .column(
            "/damping/peaks/level_db",
            stage.damping.peaks.iter().map(|p| p.level_db).collect(),
            "dB",
        )
        .column(
            "/damping/peaks/kept",
            stage
                .damping
                .peaks
                .iter()
                .map(|p| f64::from(u8::from(p.kept)))
                .collect(),
            "",
        )
        .number("/damping", "rayleigh_alpha", stage.damping.rayleigh.alpha)
        .number("/damping", "rayleigh_beta", stage.damping.rayleigh.beta)
        .number(
            "/damping",
            "rayleigh_rms_log_error",
            stage.damping.rayleigh.rms_log_error,
        )
        .number(
            "/damping",
            "curve_rms_log_error",
            stage.damping.curve_rms_log_error,
        )
        .number("/damping", "loss_initial", stage.damping.loss_initial)
        .number("/damping", "loss_final", stage.damping.loss_final);
        file.column("/modes/simulated/frequency_hz", sim_hz.clone(), "Hz")
            .column(
                "/modes/simulated/eigenvalues",
                eigenvalues.clone(),
                "rad^2/s^2",
            )
            .column(
                "/modes/simulated/full_eigenvalues",
                full_theta
                    .iter()
                    .map(|t| t * fit.youngs / job.density)
                    .collect(),
                "rad^2/s^2",
            )
            .column(
                "/modes/simulated/relative_difference",
                relative_difference.clone(),
                "1",
            )
            .column(
                "/modes/matched/recorded_frequency_hz",
                matches.iter().map(|m| recorded_hz[m.recorded]).collect(),
                "Hz",
            )
            .column(
                "/modes/matched/simulated_frequency_hz",
                matches.iter().map(|m| sim_hz[m.simulated]).collect(),
                "Hz",
            )
            .column(
                "/modes/matched/error_hz",
                matches
                    .iter()
                    .map(|m| sim_hz[m.simulated] - recorded_hz[m.recorded])
                    .collect(),
                "Hz",
            )
            .column(
                "/modes/matched/relative_error",
                matches.iter().map(|m| m.relative_error).collect(),
                "1",
            )
            .column(
                "/modes/matched/recorded_decay_rate",
                matches
                    .iter()
                    .map(|m| dm[in_band[m.recorded]].decay_rate)
                    .collect(),
                "1/s",
            )
            .column(
                "/modes/matched/simulated_decay_rate",
                matches.iter().map(|m| sim_decay[m.simulated]).collect(),
                "1/s",
            )
            .column(
                "/modes/matched/simulated_index",
                matches.iter().map(|m| m.simulated as f64).collect(),
                "",
            )
            .number("/errors", "spectrogram_start", error_start)
            .number("/errors", "spectrogram_fit", error_fit)
            .number(
                "/errors",
                "max_relative_eigenvalue_difference",
                max_difference,
            )
            .number(
                "/errors",
                "mean_abs_relative_frequency_error",
                mean_abs_error,
            );
        if let (Some(l), Some((err, _))) = (fit.line_start, line_start_error) {
            file.number("/fit", "line_start_youngs_modulus", l.youngs)
                .number("/fit", "line_start_poisson_ratio", l.poisson)
                .number("/fit", "line_start_distance", l.distance)
                .number(
                    "/errors",
                    "line_start_mean_abs_relative_frequency_error",
                    err,
                );
        }
        for (k, v) in timings {
            file.number("/timings", k, v);
        }
        file.write(&job.out).map_err(|e| e.to_string())?;
        println!("wrote {}", job.out.display());
        write_plots(
            job,
            &stage,
            &targets,
            &start_render,
            &fit_render,
            &fit,
            &matches,
            &recorded_hz,
            &sim_hz,
        )?;
    }
    Ok(())
}

/// Damped frequencies [Hz] and decay rates [1/s] of the partials the synthesiser plays for these
/// eigenvalues under `damping` (from the same chain, so report and render agree; an overdamped
/// mode is at 0 Hz).
fn damped_partials(
    eigenvalues: &[f64],
    damping: &DampingModel,
) -> Result<(Vec<f64>, Vec<f64>), String> {
    let (bank, _) = ModalChain::new(
        eigenvalues,
        &vec![1.0; eigenvalues.len()],
        damping,
        &Strike::default(),
    )?;
    Ok((bank.frequencies_hz, bank.decay_rates))
}

#[allow(clippy::too_many_arguments)]
fn write_plots(
    job: &Job,
    stage: &StageOne,
    targets: &[Vec<f64>],
    start: &[Vec<f64>],
    fitted: &[Vec<f64>],
    fit: &MaterialFit,
    matches: &[Match],
    recorded_hz: &[f64],
    sim_hz: &[f64],
) -> Result<(), String> {
    let fs = f64::from(job.sample_rate);
    // Spectrograms of channel 0: recording, target, start, fit; one dB scale (the recording's peak).
    let plan = StftPlan::new(2048, 256).map_err(|e| e.to_string())?;
    let signals: [(&str, &[f64]); 4] = [
        ("recording", &stage.channels[0]),
        ("target (recorded lines in band)", &targets[0]),
        ("start", &start[0]),
        ("fit", &fitted[0]),
    ];
    let specs: Vec<_> = signals.iter().map(|(_, s)| plan.forward(s)).collect();
    let peak = specs
        .iter()
        .flat_map(|s| s.magnitude.iter())
        .fold(0.0_f64, |m, &v| m.max(v));
    let dbs: Vec<Vec<f64>> = specs
        .iter()
        .map(|s| s.decibels(peak.max(1e-300), -120.0))
        .collect();
    let panels: Vec<SpectrogramPanel> = signals
        .iter()
        .zip(&specs)
        .zip(&dbs)
        .map(|(((title, _), s), db)| SpectrogramPanel {
            title: format!("{title} ({})", stage.names[0]),
            db,
            n_frames: s.n_frames,
            n_bins: s.n_bins,
            time_step_s: plan.hop() as f64 / fs,
            time_offset_s: 0.0,
            freq_step_hz: fs / plan.n_fft() as f64,
        })
        .collect();
    // The plot font is ASCII: Greek letters are spelled out.
    let mut figure = SpectrogramFigure::new(
        format!(
            "fit-material: E = {:.4e} Pa, nu = {:.4}",
            fit.youngs, fit.poisson
        ),
        panels,
    );
    figure.max_freq_hz = Some((1.3 * job.max_frequency_hz).min(fs / 2.0));
    figure.db_max = Some(0.0);
    figure.db_min = Some(-90.0);
    let p = plot_path(&job.plots, "_spectrogram.png");
    spectrogram_png(&p, &figure).map_err(|e| e.to_string())?;

    // Damping: per-mode decay rates (kept / rejected), the curve, the Rayleigh fit.
    let modes = &stage.damping.modes;
    let (kept, rejected): (Vec<_>, Vec<_>) = modes.iter().partition(|m| m.kept);
    let f_lo = modes
        .iter()
        .map(|m| m.frequency_hz)
        .fold(f64::INFINITY, f64::min)
        .max(1.0);
    let f_hi = modes
        .iter()
        .map(|m| m.frequency_hz)
        .fold(0.0_f64, f64::max)
        .max(2.0 * f_lo);
    let grid: Vec<f64> = (0..200)
        .map(|i| f_lo * (f_hi / f_lo).powf(i as f64 / 199.0))
        .collect();
    let (alpha, beta) = (stage.damping.rayleigh.alpha, stage.damping.rayleigh.beta);
    let mut fig = LineFigure::new(
        "damping: measured decay rates, curve d(f) and Rayleigh fit",
        "frequency [Hz]",
        "decay rate d [1/s]",
    );
    fig.x_scale = AxisScale::Log;
    fig.y_scale = AxisScale::Log;
    let peaks: Vec<_> = stage.damping.peaks.iter().filter(|p| p.kept).collect();
    fig.series = vec![
        Series::markers(
            "peaks (curve data)",
            peaks.iter().map(|p| p.frequency_hz).collect(),
            peaks.iter().map(|p| p.decay_rate).collect(),
            Marker::Diamond,
        ),
        Series::markers(
            "kept poles",
            kept.iter().map(|m| m.frequency_hz).collect(),
            kept.iter().map(|m| m.decay_rate).collect(),
            Marker::Circle,
        ),
        Series::markers(
            "rejected poles",
            rejected.iter().map(|m| m.frequency_hz).collect(),
            rejected.iter().map(|m| m.decay_rate.max(1e-3)).collect(),
            Marker::Cross,
        ),
        Series::line(
            "curve d(f)",
            grid.clone(),
            grid.iter().map(|&f| stage.damping.curve.decay(f)).collect(),
        ),
        Series::line(
            format!("Rayleigh alpha={alpha:.3}, beta={beta:.2e}"),
            grid.clone(),
            grid.iter()
                .map(|&f| 0.5 * (alpha + beta * (2.0 * std::f64::consts::PI * f).powi(2)))
                .collect(),
        ),
    ];
    line_plot_png(&plot_path(&job.plots, "_damping.png"), &fig).map_err(|e| e.to_string())?;

    let mut fig = LineFigure::new(
        "material fit: loss per step (transport, then spectral)",
        "step",
        "loss",
    );
    fig.y_scale = AxisScale::Log;
    let (tr, sp): (Vec<_>, Vec<_>) = fit
        .history
        .iter()
        .partition(|s| s.phase == crate::audio::loss::LossPhase::Transport);
    fig.series = vec![
        Series::line(
            "transport",
            tr.iter().map(|s| s.step as f64).collect(),
            tr.iter().map(|s| s.loss.max(1e-300)).collect(),
        ),
        Series::line(
            "spectral",
            sp.iter().map(|s| s.step as f64).collect(),
            sp.iter().map(|s| s.loss.max(1e-300)).collect(),
        ),
    ];
    line_plot_png(&plot_path(&job.plots, "_loss.png"), &fig).map_err(|e| e.to_string())?;

    if matches.is_empty() {
        eprintln!("warning: no recorded mode has a simulated partner within {:.0} %; {}_frequencies.png not written", 100.0 * MAX_MATCH_ERROR, job.plots.display());
        println!(
            "wrote {}_{{spectrogram,damping,loss}}.png",
            job.plots.display()
        );
        return Ok(());
    }
    let mut fig = LineFigure::new(
        "recorded vs simulated modes: relative frequency error",
        "recorded frequency [Hz]",
        "(f_sim − f_rec) / f_rec [%]",
    );
    fig.series = vec![Series::markers(
        "matched modes",
        matches.iter().map(|m| recorded_hz[m.recorded]).collect(),
        matches
            .iter()
            .map(|m| {
                100.0 * (sim_hz[m.simulated] - recorded_hz[m.recorded]) / recorded_hz[m.recorded]
            })
            .collect(),
        Marker::Diamond,
    )];
    line_plot_png(&plot_path(&job.plots, "_frequencies.png"), &fig).map_err(|e| e.to_string())?;
    println!(
        "wrote {}_{{spectrogram,damping,loss,frequencies}}.png",
        job.plots.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn modes_pair_one_to_one_closest_first() {
        let m = match_modes(&[100.0, 101.0, 300.0], &[100.5, 250.0, 299.0, 1000.0]);
        let pairs: Vec<(usize, usize)> = m.iter().map(|m| (m.recorded, m.simulated)).collect();
        // 101 → 100.5 is closer than 100 → 100.5; 100 has no partner within 10 %.
        assert_eq!(pairs, vec![(1, 0), (2, 2)]);
    }
}
