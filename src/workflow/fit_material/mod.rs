//! The `fit-material` job: damping, Young's modulus and Poisson's ratio from recordings of one
//! strike, by analysis by synthesis.
//!
//! # Stages
//!
//! 1. **Recording.** Every file is read, resampled to `sample_rate`, cut at the shared strike
//!    onset ([`crate::analysis::recording`]; pre-roll before the onset is dropped) and kept for
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
//!    fitted by the hybrid transport → spectral schedule with the damping curve held fixed;
//!    from a line-spectrum start, after short runs from starts beside it
//!    ([`crate::inverse::material::fit_material`], *Several starts*).
//! 5. **Checks.** A full SLEPc solve at the fitted (E, ν) is compared with the reduced basis;
//!    every recorded mode in the band is paired with its nearest simulated mode (one to one,
//!    closest pairs first) and the frequency errors are listed; the spectrogram error
//!    ([`crate::audio::stft::spectrogram_error`], mean over channels) against the target is
//!    reported at the start and at the fit.
//!
//! Every rank runs stages 1–3 identically from rank 0's broadcast, and the fit loop is the same
//! deterministic serial code on every rank between collective solves, so the answer does not
//! depend on the number of ranks beyond the rounding of the distributed solves. [`run`] returns
//! the same [`Report`] on every rank; rank 0 writes it.
//!
//! # Outputs
//!
//! The HDF5 result (`out`) is written by [`write_result`] in the layout of
//! [`crate::io::fit_material`], which also reads it back.
//!
//! Plots (PNG, prefix `plots`, [`write_plots`]): `_spectrogram.png` (recording, target, start,
//! fit of one channel side by side), `_damping.png` (per-mode decay rates, kept and rejected,
//! with the curve and the Rayleigh fit), `_loss.png` (loss history), `_frequencies.png`
//! (relative frequency error of every matched mode).

mod plots;
mod stages;
mod write;

pub use plots::{write_plots, PlotsWritten};
pub use stages::{match_modes, probe_along, Match, StageOne, MAX_MATCH_ERROR};
pub use write::{result_record, write_result};

use crate::assembly;
use crate::audio::chain::{DampingModel, Strike};
use crate::audio::stft::spectrogram_error;
use crate::eigen::reduced::PoissonBasis;
use crate::inverse::damping::DampingFitSettings;
use crate::inverse::material::{
    fit_material, render_channels, rms_matched_log_gains, MaterialFit, MaterialFitError,
    MaterialFitSettings, MaterialProblem,
};
use crate::mesh::{MeshError, ReadOptions};
use crate::petsc::Petsc;
use crate::workflow::model_mesh;
use crate::workflow::Progress;
use stages::{
    agree_on_fit, band_limited_target, damped_partials, recorded_lines, stage_one, strike_probe,
};
use std::path::PathBuf;

/// Everything resolved and checked before PETSc starts.
#[derive(Clone, Debug)]
pub struct Job {
    pub mesh: PathBuf,
    pub unit_scale: f64,
    /// Straighten folded curved tets instead of refusing the mesh ([`crate::mesh::read_for_fem`]).
    pub straighten_invalid: bool,
    pub order: u32,
    pub recordings: Vec<PathBuf>,
    /// Analysis sample rate [Hz].
    pub sample_rate: u32,
    /// Seconds of each recording used after the onset.
    pub duration: f64,
    /// ρ [kg/m³]; the fit finds E/ρ, reported as E at this ρ.
    pub density: f64,
    /// Starting E [Pa].
    pub start_youngs: f64,
    pub start_poisson: f64,
    /// Simulated modes in the fit.
    pub n_modes: usize,
    /// Upper end of the band the material fit compares [Hz].
    pub max_frequency_hz: f64,
    /// ν of the full solves that span the reduced basis.
    pub basis_samples: Vec<f64>,
    /// Extra modes per sample beyond `n_modes` (modes reorder as ν moves).
    pub basis_margin: usize,
    pub strike_vertex: Option<usize>,
    pub strike_position: Option<[f64; 3]>,
    pub damping: DampingFitSettings,
    pub fit: MaterialFitSettings,
    pub out: PathBuf,
    /// Prefix of the PNG plots.
    pub plots: PathBuf,
    pub petsc_options: Vec<String>,
    pub verbose: bool,
}

/// Why the job stopped. Each variant displays the message the command prints.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// The recording or the damping fit (stage 1, rank 0's message on every rank).
    #[error("{0}")]
    StageOne(String),
    #[error("no real mode below --fmax {max_frequency_hz} Hz in the recording; raise --fmax")]
    NoModeInBand { max_frequency_hz: f64 },
    /// The strike point of the model.
    #[error("{0}")]
    Strike(String),
    /// Assembly, the reduced basis or a full solve (PETSc/SLEPc).
    #[error("{0}")]
    Solver(String),
    /// The material fit, its renders and the checks after it.
    #[error("{0}")]
    Fit(String),
    /// The material fit or one of its renders refused its input.
    #[error(transparent)]
    Model(#[from] MaterialFitError),
    /// Writing the HDF5 result or the plots.
    #[error("{0}")]
    Output(String),
}

/// Seconds per stage (`/timings` of the result).
#[derive(Clone, Debug)]
pub struct Timings {
    pub stage_one: f64,
    pub basis: f64,
    pub fit: f64,
    pub full_solve_check: f64,
    pub total: f64,
}

/// The frequency check at the fit's line-spectrum start.
#[derive(Clone, Copy, Debug)]
pub struct LineStartCheck {
    /// Mean |relative frequency error| of the matched modes there.
    pub mean_abs_error: f64,
    /// Recorded modes matched there.
    pub matched: usize,
}

/// What the job found (the same on every rank).
#[derive(Clone, Debug)]
pub struct Report {
    /// The recording as fitted and its damping fit.
    pub stage: StageOne,
    /// The recorded lines below the band limit: indices into `stage.damping.modes`, by
    /// frequency.
    pub in_band: Vec<usize>,
    /// Their frequencies [Hz].
    pub recorded_hz: Vec<f64>,
    /// Per channel, the target the material fit compares with.
    pub targets: Vec<Vec<f64>>,
    /// Per channel, the render at the start (levelled to the target's RMS) and at the fit.
    pub start_render: Vec<Vec<f64>>,
    pub fit_render: Vec<Vec<f64>>,
    pub fit: MaterialFit,
    /// Reduced-basis eigenvalues at the fit [rad²/s²].
    pub eigenvalues: Vec<f64>,
    /// Full-solve eigenvalues at the fit [rad²/s²].
    pub full_eigenvalues: Vec<f64>,
    /// (reduced − full) / full, per mode, in θ = λ ρ / E.
    pub relative_difference: Vec<f64>,
    pub max_difference: f64,
    /// Damped frequencies [Hz] and decay rates [1/s] of the fitted simulated modes.
    pub sim_hz: Vec<f64>,
    pub sim_decay: Vec<f64>,
    pub matches: Vec<Match>,
    /// Mean |relative frequency error| over `matches`.
    pub mean_abs_error: f64,
    pub line_start_check: Option<LineStartCheck>,
    /// Mean spectrogram error against the target at the start and at the fit.
    pub error_start: f64,
    pub error_fit: f64,
    pub timings: Timings,
    pub n_ranks: usize,
}

/// Runs the job on every rank (collective).
pub fn run(petsc: &Petsc, job: &Job, progress: &Progress) -> Result<Report, Error> {
    let started = std::time::Instant::now();
    let rank = petsc.rank();
    let fs = f64::from(job.sample_rate);

    // Check the mesh before the long stage 1.
    let (mesh_model, _) = model_mesh(
        petsc,
        &job.mesh,
        &ReadOptions {
            unit_scale: job.unit_scale,
            fix_inverted: false,
        },
        job.straighten_invalid,
        job.order,
    )?;

    let t1 = std::time::Instant::now();
    let stage = stage_one(petsc, job, progress).map_err(Error::StageOne)?;
    let stage_one_seconds = t1.elapsed().as_secs_f64();
    let n = stage.channels[0].len();
    let lines = recorded_lines(&stage.damping);
    let targets = band_limited_target(&stage, &lines, fs, n, job.max_frequency_hz);
    let in_band: Vec<usize> = lines
        .into_iter()
        .filter(|&i| stage.damping.modes[i].frequency_hz <= job.max_frequency_hz)
        .collect();
    if in_band.is_empty() {
        return Err(Error::NoModeInBand {
            max_frequency_hz: job.max_frequency_hz,
        });
    }
    progress.say(format!(
        "target: the real modes below {} Hz; {} recorded lines there: {} Hz",
        job.max_frequency_hz,
        in_band.len(),
        super::short_list(
            &in_band
                .iter()
                .map(|&i| format!("{:.1}", stage.damping.modes[i].frequency_hz))
                .collect::<Vec<_>>(),
            12
        )
    ));

    let t2 = std::time::Instant::now();
    let assembled =
        assembly::assemble(petsc, &mesh_model).map_err(|e| Error::Solver(e.to_string()))?;
    let (lo, hi) = mesh_model.bounding_box();
    let diagonal = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
    let (point, probe_dofs, direction_weights) =
        strike_probe(&mesh_model, job, &assembled.layout).map_err(Error::Strike)?;
    progress.say(format!("mesh: {} tets, {} nodes (P{}), strike at ({:.4}, {:.4}, {:.4}) m; building the reduced basis at ν = {}", mesh_model.n_tets(), mesh_model.n_nodes(), job.order, point.position[0], point.position[1], point.position[2], super::short_list(&job.basis_samples, 8)));
    let mut basis = PoissonBasis::build(
        petsc,
        &assembled,
        diagonal,
        job.n_modes,
        job.basis_margin,
        &job.basis_samples,
        probe_dofs,
    )
    .map_err(|e| Error::Solver(e.to_string()))?;
    let basis_seconds = t2.elapsed().as_secs_f64();
    progress.say(format!(
        "basis: {} full solves in {:.1} s, {} vectors (rank {})",
        basis.full_solves,
        basis.full_solve_seconds,
        basis.dimensions().0,
        basis.dimensions().1
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
        },
        |s| {
            if s.step % 20 == 0 {
                progress.say(format!(
                    "material step {:4} ({}): loss {:.5e}, E = {:.5e} Pa, ν = {:.4}",
                    s.step, s.phase, s.loss, s.youngs, s.poisson
                ));
            }
        },
    )?;
    let fit_seconds = t3.elapsed().as_secs_f64();
    // Every rank ran the same fit; they must agree exactly, since the full-solve check below and
    // every later collective step assemble with this ν on each rank's own rows (a mismatch would
    // silently assemble a stiffness matrix mixing two materials). Rank 0's fit is authoritative.
    let fit = agree_on_fit(petsc, fit, progress).map_err(Error::Fit)?;
    if let Some(first) = fit.history.first() {
        if !fit.start_probes.is_empty() {
            let tried: Vec<String> = fit
                .start_probes
                .iter()
                .map(|p| format!("ν {:.4}: {:.4e}", p.poisson, p.loss))
                .collect();
            progress.say(format!(
                "starts tried ({} spectral steps each, mean loss of the last five): {}; the fit ran from ν = {:.4}",
                job.fit.start_probe_steps,
                tried.join(", "),
                first.poisson
            ));
        }
    }
    progress.say(format!(
        "fit: E = {:.5e} Pa, ν = {:.4} after {} steps in {:.1} s",
        fit.youngs, fit.poisson, fit.steps, fit_seconds
    ));

    // Check against a full solve at the optimum.
    let t4 = std::time::Instant::now();
    let reduced = basis.solve(fit.poisson);
    let (full_theta, _) =
        PoissonBasis::full_theta(petsc, &assembled, diagonal, fit.poisson, job.n_modes)
            .map_err(|e| Error::Solver(e.to_string()))?;
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
    // Printed here, in its place among the progress lines, rather than left to the caller.
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
    let mean_error = |renders: &[Vec<f64>]| -> Result<f64, Error> {
        let mut total = 0.0;
        for (r, t) in renders.iter().zip(&targets) {
            total += spectrogram_error(r, t).map_err(|e| Error::Fit(e.to_string()))?;
        }
        Ok(total / targets.len() as f64)
    };
    let (error_start, error_fit) = (mean_error(&start_render)?, mean_error(&fit_render)?);

    // Recorded modes in the band against the fitted simulated modes.
    let eigenvalues = reduced.eigenvalues(fit.youngs, job.density);
    let (sim_hz, sim_decay) =
        damped_partials(&eigenvalues, &problem.damping).map_err(MaterialFitError::from)?;
    let recorded_hz: Vec<f64> = in_band
        .iter()
        .map(|&i| stage.damping.modes[i].frequency_hz)
        .collect();
    let matches = match_modes(&recorded_hz, &sim_hz);
    let mean_abs_error =
        matches.iter().map(|m| m.relative_error.abs()).sum::<f64>() / matches.len().max(1) as f64;
    // The same figure at the line-spectrum start, for comparison with the audio-loss optimum.
    let line_start_check = match fit.line_start {
        Some(l) => {
            let (hz, _) = damped_partials(
                &basis.solve(l.poisson).eigenvalues(l.youngs, job.density),
                &problem.damping,
            )
            .map_err(MaterialFitError::from)?;
            let m = match_modes(&recorded_hz, &hz);
            Some(LineStartCheck {
                mean_abs_error: m.iter().map(|m| m.relative_error.abs()).sum::<f64>()
                    / m.len().max(1) as f64,
                matched: m.len(),
            })
        }
        None => None,
    };
    let full_eigenvalues = full_theta
        .iter()
        .map(|t| t * fit.youngs / job.density)
        .collect();

    Ok(Report {
        stage,
        in_band,
        recorded_hz,
        targets,
        start_render,
        fit_render,
        fit,
        eigenvalues,
        full_eigenvalues,
        relative_difference,
        max_difference,
        sim_hz,
        sim_decay,
        matches,
        mean_abs_error,
        line_start_check,
        error_start,
        error_fit,
        timings: Timings {
            stage_one: stage_one_seconds,
            basis: basis_seconds,
            fit: fit_seconds,
            full_solve_check: check_seconds,
            total: started.elapsed().as_secs_f64(),
        },
        n_ranks: petsc.size(),
    })
}
