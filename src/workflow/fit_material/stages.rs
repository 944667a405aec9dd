//! The pieces of the fit-material job: stage 1 on rank 0 and its broadcast, the recorded lines
//! and the band-limited target, the strike probe of the model, and the matching of recorded with
//! simulated modes.

use super::Job;
use crate::analysis::recording::{load_recording, GainPolicy, RecordingOptions};
use crate::assembly;
use crate::audio::chain::{ChainError, DampingModel, ModalChain, Strike};
use crate::audio::synth::{render_samples, ModalBank};
use crate::inverse::damping::{fit_damping, DampingFit};
use crate::inverse::material::{band_weight, MaterialFit};
use crate::mesh::{SurfacePoint, TetMesh};
use crate::petsc::{Petsc, PetscInt};
use crate::workflow::{broadcast_from_root, Progress};
use mpi::traits::CommunicatorCollectives;

/// What stage 1 hands on, broadcast from rank 0.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct StageOne {
    /// The healthy channels, cut at the onset, at the analysis rate.
    pub channels: Vec<Vec<f64>>,
    /// Their names (file, and channel of a multichannel file).
    pub names: Vec<String>,
    /// The shared strike onset in the recordings [s].
    pub onset_s: f64,
    pub damping: DampingFit,
}

/// Compares the fitted (E, ν) across ranks, reports any difference, and hands every rank rank
/// 0's fit.
pub(super) fn agree_on_fit(
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
pub(super) fn stage_one(petsc: &Petsc, job: &Job, progress: &Progress) -> Result<StageOne, String> {
    let local: Option<Result<StageOne, String>> = (petsc.rank() == 0).then(|| {
        let options = RecordingOptions { target_rate: Some(job.sample_rate), pre_roll_s: 0.0, duration_s: Some(job.duration), gain: GainPolicy::CommonPeak(0.5), band_max_hz: Some(job.max_frequency_hz), ..Default::default() };
        let mut rec = load_recording(&job.recordings, &options).map_err(|e| e.to_string())?;
        // Channel health (pre-roll 0: the floor is the track's last tenth): a dead, noise-only
        // or misaligned microphone is left out with a warning naming its file. The warning is
        // printed here, before the progress lines of the damping fit it precedes.
        let health = crate::audio::health::assess(&rec.names, &rec.channels, 0, f64::from(rec.sample_rate), &rec.channel_onsets_s, rec.onset_s, &rec.band_over_floor);
        for h in health.iter().filter(|h| !h.is_healthy()) {
            eprintln!("{}", h.left_out_warning("the fit"));
        }
        let keep = crate::audio::health::healthy_channels(&health).map_err(|e| e.to_string())?;
        for w in crate::audio::health::band_warnings(&health, job.max_frequency_hz).map_err(|e| e.to_string())? {
            eprintln!("{w}");
        }
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
        let kept = damping.modes.iter().filter(|m| m.kept()).count();
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
pub(super) fn recorded_lines(fit: &DampingFit) -> Vec<usize> {
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
                .filter(|&i| fit.modes[i].kept() && energy(i) >= LINE_ENERGY_FRACTION * strongest),
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
pub(super) fn band_limited_target(
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
pub(super) fn strike_probe(
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
pub fn probe_along(
    mesh: &TetMesh,
    point: &SurfacePoint,
    direction: [f64; 3],
    layout: &assembly::DofLayout,
) -> (Vec<PetscInt>, Vec<f64>) {
    let weights = mesh.shape_weights(point.barycentric);
    let mut dofs = Vec::new();
    let mut w = Vec::new();
    for (a, &node) in mesh.tet(point.tet).iter().enumerate() {
        for (c, &along) in direction.iter().enumerate() {
            dofs.push(layout.global_dof(node, c) as PetscInt);
            w.push(weights[a] * along);
        }
    }
    (dofs, w)
}

/// A recorded mode paired with a simulated one ([`match_modes`]).
#[derive(Clone, Debug)]
pub struct Match {
    /// Index into the recorded frequencies.
    pub recorded: usize,
    /// Index into the simulated frequencies.
    pub simulated: usize,
    /// (f_sim − f_rec) / f_rec.
    pub relative_error: f64,
}

/// Pairs further apart than this (relative) are not the same mode.
pub const MAX_MATCH_ERROR: f64 = 0.1;

/// Recorded modes paired one-to-one with simulated ones, closest (relative) pairs first, none
/// further apart than [`MAX_MATCH_ERROR`]; sorted by recorded mode.
pub fn match_modes(recorded_hz: &[f64], simulated_hz: &[f64]) -> Vec<Match> {
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

/// Damped frequencies [Hz] and decay rates [1/s] of the partials the synthesiser plays for these
/// eigenvalues under `damping` (from the same chain, so report and render agree; an overdamped
/// mode is at 0 Hz).
pub(super) fn damped_partials(
    eigenvalues: &[f64],
    damping: &DampingModel,
) -> Result<(Vec<f64>, Vec<f64>), ChainError> {
    let (bank, _) = ModalChain::new(
        eigenvalues,
        &vec![1.0; eigenvalues.len()],
        damping,
        &Strike::default(),
    )?;
    Ok((bank.frequencies_hz, bank.decay_rates))
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
