//! Steps 1, 3 and 4 of the job: the recording read on rank 0 (its healthy channels and the
//! poles below `fmax`), and the recorded poles matched to clusters of simulated modes
//! (the global frequency scale s = median of f_obs/f_sim; see the module docs of
//! [`super`]).

use super::Job;
use crate::analysis::extract::extract_modes;
use crate::analysis::recording::{load_recording, GainPolicy, RecordingOptions};
use crate::analysis::MeasuredMode;
use crate::inverse::impact::{self, ClusterAmplitudes};
use crate::workflow::Progress;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// What rank 0 read from the recording.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Measured {
    /// The healthy channels' names, and their indices among the recordings.
    pub names: Vec<String>,
    pub kept: Vec<usize>,
    pub onset_s: f64,
    /// Channels from the onset on, recording units.
    pub channels: Vec<Vec<f64>>,
    pub sample_rate: f64,
    /// Recorded poles below fmax: f [Hz], d [1/s] and SNR [dB].
    pub poles: Vec<MeasuredMode>,
    pub seconds: f64,
}

pub fn measure(job: &Job, progress: &Progress) -> Result<Measured, String> {
    let t = Instant::now();
    let options = RecordingOptions {
        target_rate: Some(job.sample_rate),
        pre_roll_s: job.pre_roll,
        duration_s: Some(job.pre_roll + job.window),
        gain: GainPolicy::Unity,
        band_max_hz: Some(job.max_frequency_hz),
        ..Default::default()
    };
    let rec = load_recording(&job.recordings, &options).map_err(|e| e.to_string())?;
    let fs = f64::from(rec.sample_rate);
    let onset = rec.onset_sample();
    // Channel health: a dead, noise-only or misaligned microphone would move the map; it is
    // left out with a warning naming its file.
    let health = crate::audio::health::assess_recording(&rec);
    for h in health.iter().filter(|h| !h.is_healthy()) {
        eprintln!("{}", h.left_out_warning("the map"));
    }
    let kept = crate::audio::health::healthy_channels(&health).map_err(|e| e.to_string())?;
    for w in crate::audio::health::band_warnings(&health, job.max_frequency_hz)
        .map_err(|e| e.to_string())?
    {
        eprintln!("{w}");
    }
    let channels: Vec<Vec<f64>> = kept
        .iter()
        .map(|&c| rec.channels[c][onset..].to_vec())
        .collect();
    let names: Vec<String> = kept.iter().map(|&c| rec.names[c].clone()).collect();
    if (channels[0].len() as f64) < 0.02 * fs {
        return Err(format!(
            "only {:.3} s of recording after the onset at {:.3} s",
            channels[0].len() as f64 / fs,
            rec.onset_s
        ));
    }
    let ex =
        extract_modes(&channels, fs, &job.extract).map_err(|e| format!("mode extraction: {e}"))?;
    let poles: Vec<MeasuredMode> = ex
        .modes
        .iter()
        .filter(|m| m.frequency_hz <= job.max_frequency_hz && m.decay_rate >= 0.0)
        .map(|m| MeasuredMode {
            snr_db: m.snr_db,
            ..MeasuredMode::pole(m.frequency_hz, m.decay_rate)
        })
        .collect();
    progress.say(format!("{} channel(s) at {} Hz, onset at {:.4} s, {:.3} s fitted; {} recorded poles below {:.0} Hz", channels.len(), rec.sample_rate, rec.onset_s, channels[0].len() as f64 / fs, poles.len(), job.max_frequency_hz));
    Ok(Measured {
        names,
        kept,
        onset_s: rec.onset_s,
        channels,
        sample_rate: fs,
        poles,
        seconds: t.elapsed().as_secs_f64(),
    })
}

/// The poles of the amplitude fit and what they stand for (module docs of [`super`], step 3).
pub struct PoleAssignment {
    /// Global frequency scale s = f_obs / f_sim.
    pub scale: f64,
    /// Poles of the amplitude fit: one per recorded pole, then one per unclaimed cluster.
    pub poles: Vec<MeasuredMode>,
    /// Cluster id of each pole (a simulated cluster index), or None for an unclaimed pole.
    pub pole_cluster: Vec<Option<usize>>,
    /// Per simulated cluster: whether a recorded pole was assigned to it.
    pub observed: Vec<bool>,
}

/// Matches recorded poles to clusters of simulated modes (module docs of [`super`], step 3).
pub fn assign_poles(
    measured: &Measured,
    sim_hz: &[f64],
    cluster_of: &[usize],
    decay_of: impl Fn(f64) -> f64,
    tolerance: f64,
) -> Result<PoleAssignment, String> {
    let n_clusters = cluster_of.iter().max().map_or(0, |m| m + 1);
    // Cluster centres in the simulation.
    let mut centre = vec![(0.0, 0usize); n_clusters];
    for (k, &c) in cluster_of.iter().enumerate() {
        centre[c].0 += sim_hz[k].ln();
        centre[c].1 += 1;
    }
    let centre: Vec<f64> = centre.iter().map(|(s, n)| (s / *n as f64).exp()).collect();
    // Global scale: median ratio of each recorded pole to its nearest simulated cluster.
    let mut ratios: Vec<f64> = measured
        .poles
        .iter()
        .filter_map(|p| {
            centre
                .iter()
                .map(|c| (p.frequency_hz / c).ln())
                .min_by(|a, b| a.abs().total_cmp(&b.abs()))
        })
        .collect();
    if ratios.is_empty() {
        return Err("no recorded pole to match against the simulated modes".into());
    }
    ratios.sort_by(f64::total_cmp);
    let ln_scale = ratios[ratios.len() / 2];
    let mut poles = Vec::new();
    let mut pole_cluster = Vec::new();
    let mut observed = vec![false; n_clusters];
    for p in &measured.poles {
        let (f, d) = (p.frequency_hz, p.decay_rate);
        let nearest = (0..n_clusters)
            .map(|c| (c, (f.ln() - ln_scale - centre[c].ln()).abs()))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        poles.push(MeasuredMode::pole(f, d));
        match nearest {
            Some((c, dist)) if dist <= tolerance => {
                observed[c] = true;
                pole_cluster.push(Some(c));
            }
            _ => pole_cluster.push(None),
        }
    }
    let nyquist = 0.5 * measured.sample_rate;
    for c in 0..n_clusters {
        if !observed[c] {
            let f = ln_scale.exp() * centre[c];
            if f >= 0.95 * nyquist {
                return Err(format!("simulated mode at {f:.0} Hz is too close to the recording's Nyquist frequency ({nyquist:.0} Hz); lower max_frequency_hz"));
            }
            poles.push(MeasuredMode::pole(f, decay_of(f)));
            pole_cluster.push(Some(c));
        }
    }
    Ok(PoleAssignment {
        scale: ln_scale.exp(),
        poles,
        pole_cluster,
        observed,
    })
}

/// The cluster amplitudes of the simulated clusters only, relabelled with the simulated modes
/// each cluster stands for (`cluster_of`), so that they line up with the forward table. Every
/// simulated cluster has a pole (recorded or predicted), so the ids are 0..n_clusters in order.
pub fn keep_simulated_clusters(
    all: ClusterAmplitudes,
    ids: &[usize],
    cluster_of: &[usize],
) -> Result<ClusterAmplitudes, String> {
    let n_clusters = cluster_of.iter().max().map_or(0, |m| m + 1);
    let keep: Vec<bool> = all
        .clusters
        .iter()
        .map(|members| ids[members[0]] < n_clusters)
        .collect();
    let kept_ids: Vec<usize> = all
        .clusters
        .iter()
        .map(|members| ids[members[0]])
        .filter(|&c| c < n_clusters)
        .collect();
    if kept_ids != (0..n_clusters).collect::<Vec<_>>() {
        return Err(format!(
            "internal: clusters {kept_ids:?} have poles, expected every one of 0..{n_clusters}"
        ));
    }
    let pick = |v: Vec<Vec<f64>>| {
        v.into_iter()
            .zip(&keep)
            .filter(|(_, k)| **k)
            .map(|(x, _)| x)
            .collect::<Vec<_>>()
    };
    let below = all
        .below_limit
        .into_iter()
        .zip(&keep)
        .filter(|(_, k)| **k)
        .map(|(x, _)| x)
        .collect();
    Ok(ClusterAmplitudes {
        clusters: impact::cluster_members(cluster_of),
        amplitude: pick(all.amplitude),
        sd: pick(all.sd),
        detection_limit: pick(all.detection_limit),
        below_limit: below,
    })
}

/// The decay rate of the (first) pole assigned to a cluster.
pub fn cluster_decay(
    assignment: &PoleAssignment,
    fit: &impact::AmplitudeFit,
    cluster: usize,
) -> Option<f64> {
    assignment
        .pole_cluster
        .iter()
        .position(|c| *c == Some(cluster))
        .map(|i| fit.poles[i].decay_rate)
}
