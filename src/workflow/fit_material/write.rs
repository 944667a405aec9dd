//! The HDF5 result of a fit-material report, in the layout of [`crate::io::fit_material`].

use super::{Error, Job, Report};
use crate::audio::loss::LossPhase;
use crate::io::fit_material::{
    DampingModeRecord, DampingPeakRecord, DampingRecord, ErrorsRecord, FitMaterialResult,
    FitRecord, FitStepRecord, LineStartRecord, MatchedModeRecord, MaterialRecord,
    SimulatedModesRecord,
};

/// The result file's contents for this job and report; `command` is the command line recorded
/// in it.
pub fn result_record(job: &Job, report: &Report, command: String) -> FitMaterialResult {
    let fit = &report.fit;
    let damping = &report.stage.damping;
    let dm = &damping.modes;
    let t = &report.timings;
    FitMaterialResult {
        mesh: job.mesh.display().to_string(),
        recordings: job
            .recordings
            .iter()
            .map(|p| p.display().to_string())
            .collect(),
        order: job.order,
        n_ranks: report.n_ranks,
        command,
        version: env!("CARGO_PKG_VERSION").to_string(),
        channels: report.targets.len(),
        material: MaterialRecord {
            youngs_modulus: fit.youngs,
            poisson_ratio: fit.poisson,
            density: job.density,
            start_youngs_modulus: job.start_youngs,
            start_poisson_ratio: job.start_poisson,
            poisson_learned: job.fit.learn_poisson,
        },
        fit: FitRecord {
            history: fit
                .history
                .iter()
                .map(|s| FitStepRecord {
                    step: s.step,
                    transport: s.phase == LossPhase::Transport,
                    loss: s.loss,
                    youngs_modulus: s.youngs,
                    poisson_ratio: s.poisson,
                })
                .collect(),
            log_gains: fit.log_gains.clone(),
            log_amplitude_offsets: fit.log_amplitude_offsets.clone(),
            steps: fit.steps,
            switched_at: fit.switched_at,
            seconds: t.fit,
            max_ritz_residual: fit.max_residual,
            basis_samples: fit.basis_samples.clone(),
            start_probes: fit
                .start_probes
                .iter()
                .map(|p| (p.youngs, p.poisson, p.loss))
                .collect(),
            line_start: match (fit.line_start, report.line_start_check) {
                (Some(l), Some(check)) => Some(LineStartRecord {
                    youngs_modulus: l.youngs,
                    poisson_ratio: l.poisson,
                    distance: l.distance,
                    mean_abs_relative_frequency_error: check.mean_abs_error,
                }),
                _ => None,
            },
        },
        damping: DampingRecord {
            curve_frequencies_hz: damping.curve.frequencies_hz.clone(),
            curve_decay_rates: damping.curve.log_decay.iter().map(|v| v.exp()).collect(),
            modes: dm
                .iter()
                .map(|m| DampingModeRecord {
                    frequency_hz: m.frequency_hz,
                    decay_rate: m.decay_rate,
                    level_db: m.verdict().level_db,
                    kept: m.kept(),
                    amplitudes: m.amplitudes.clone(),
                    phases: m.phases.clone(),
                })
                .collect(),
            peaks: damping
                .peaks
                .iter()
                .map(|p| DampingPeakRecord {
                    frequency_hz: p.frequency_hz,
                    decay_rate: p.decay_rate,
                    level_db: p.level_db,
                    kept: p.kept,
                })
                .collect(),
            rayleigh_alpha: damping.rayleigh.alpha,
            rayleigh_beta: damping.rayleigh.beta,
            rayleigh_rms_log_error: damping.rayleigh.rms_log_error,
            curve_rms_log_error: damping.curve_rms_log_error,
            loss_initial: damping.loss_initial,
            loss_final: damping.loss_final,
        },
        simulated: SimulatedModesRecord {
            frequency_hz: report.sim_hz.clone(),
            eigenvalues: report.eigenvalues.clone(),
            full_eigenvalues: report.full_eigenvalues.clone(),
            relative_difference: report.relative_difference.clone(),
        },
        matched: report
            .matches
            .iter()
            .map(|m| MatchedModeRecord {
                recorded_frequency_hz: report.recorded_hz[m.recorded],
                simulated_frequency_hz: report.sim_hz[m.simulated],
                relative_error: m.relative_error,
                recorded_decay_rate: dm[report.in_band[m.recorded]].decay_rate,
                simulated_decay_rate: report.sim_decay[m.simulated],
                simulated_index: m.simulated,
            })
            .collect(),
        errors: ErrorsRecord {
            spectrogram_start: report.error_start,
            spectrogram_fit: report.error_fit,
            max_relative_eigenvalue_difference: report.max_difference,
            mean_abs_relative_frequency_error: report.mean_abs_error,
        },
        timings: [
            ("stage_one", t.stage_one),
            ("basis", t.basis),
            ("fit", t.fit),
            ("full_solve_check", t.full_solve_check),
            ("total", t.total),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect(),
    }
}

/// Writes the HDF5 result to `job.out`, recording this process's command line.
pub fn write_result(job: &Job, report: &Report) -> Result<(), Error> {
    let command = std::env::args().collect::<Vec<_>>().join(" ");
    crate::io::fit_material::write_result(&job.out, &result_record(job, report, command))
        .map_err(|e| Error::Output(e.to_string()))
}
