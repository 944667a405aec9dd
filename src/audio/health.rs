//! Channel health: is each microphone's track a recording of the strike at all?
//!
//! With many microphones per strike a dead cable, a channel of hiss or a file from another take
//! is ordinary, and a fit that uses it as evidence answers wrongly with no error (a silent
//! held-out microphone once "confirmed" an effect). Before any fit every channel is measured
//! on the trimmed recording (`pre` before the shared onset, `post` from it):
//!
//! * **level**: the peak |x| of the first [`PEAK_WINDOW_S`] after the onset;
//! * **floor**: the RMS of the pre-roll (when it has fewer than 64 samples, of the last tenth
//!   of the track, where a struck object has decayed most);
//! * **SNR** = 20 log₁₀(level / floor) \[dB\];
//! * **own onset**: the channel's own strike time from the onset detector, against the
//!   shared one.
//!
//! Verdicts, first match wins: *dead* — no level at all, or a level [`DEAD_BELOW_DB`] dB or
//! more under the loudest channel's; *noise only* — no strike of its own was detected, or an
//! SNR under [`MIN_SNR_DB`] dB (white noise alone peaks about 13 dB over its RMS in such a
//! window; only with a pre-roll: the tail of a slowly decaying object is no floor); *misaligned* — its own strike more than [`MAX_ONSET_OFFSET_S`] from the shared
//! one (7 m of extra path: more than a room's microphones differ by, so another take or a
//! shifted file). A channel with any verdict but *healthy* is left out of every fit, with a
//! warning that names its file.

/// Window after the onset in which the level is read [s].
pub const PEAK_WINDOW_S: f64 = 0.2;
/// A channel this far or more under the loudest one is dead [dB].
pub const DEAD_BELOW_DB: f64 = 80.0;
/// Below this SNR a channel is noise only [dB].
pub const MIN_SNR_DB: f64 = 20.0;
/// Largest distance of a channel's own strike from the shared onset [s].
pub const MAX_ONSET_OFFSET_S: f64 = 0.02;

#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    Healthy,
    Dead,
    NoiseOnly,
    Misaligned,
}

impl Verdict {
    pub fn word(self) -> &'static str {
        match self {
            Verdict::Healthy => "healthy",
            Verdict::Dead => "dead (no signal)",
            Verdict::NoiseOnly => "noise only (no strike above the floor)",
            Verdict::Misaligned => "misaligned (its strike is not at the others' time)",
        }
    }
}

/// One channel's measurements and verdict.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ChannelHealth {
    pub name: String,
    /// Peak |x| after the onset (full scale = 1 before levelling).
    pub level: f64,
    /// RMS of the noise floor.
    pub floor: f64,
    pub snr_db: f64,
    /// Own onset minus the shared onset [s]; `None` when no strike of its own was found.
    pub onset_offset_s: Option<f64>,
    pub verdict: Verdict,
}

impl ChannelHealth {
    pub fn is_healthy(&self) -> bool {
        self.verdict == Verdict::Healthy
    }

    /// The one-line warning for a channel left out of `job` (e.g. "the fit").
    pub fn left_out_warning(&self, job: &str) -> String {
        let offset = self.onset_offset_s.map_or(String::new(), |d| {
            format!(", its strike {d:+.3} s from the others'")
        });
        format!(
            "warning: {} is {} (SNR {:.0} dB{offset}): left out of {job}",
            self.name,
            self.verdict.word(),
            self.snr_db
        )
    }
}

/// No channel of the recording carries the strike.
#[derive(Debug, thiserror::Error)]
#[error("no microphone carries the strike ({verdicts}); check the files and the cables")]
pub struct NoHealthyChannel {
    /// "name: verdict" of every channel.
    pub verdicts: String,
}

/// The indices of the healthy channels, or the error naming every channel's verdict.
pub fn healthy_channels(health: &[ChannelHealth]) -> Result<Vec<usize>, NoHealthyChannel> {
    let kept: Vec<usize> = (0..health.len())
        .filter(|&c| health[c].is_healthy())
        .collect();
    if kept.is_empty() {
        let verdicts = health
            .iter()
            .map(|h| format!("{}: {}", h.name, h.verdict.word()))
            .collect::<Vec<_>>()
            .join("; ");
        return Err(NoHealthyChannel { verdicts });
    }
    Ok(kept)
}

fn rms(x: &[f64]) -> f64 {
    if x.is_empty() {
        return 0.0;
    }
    (x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64).sqrt()
}

/// [`assess`] on a loaded recording, its pre-roll before [`crate::analysis::recording::Recording::onset_sample`].
pub fn assess_recording(rec: &crate::analysis::recording::Recording) -> Vec<ChannelHealth> {
    assess(
        &rec.names,
        &rec.channels,
        rec.onset_sample(),
        f64::from(rec.sample_rate),
        &rec.channel_onsets_s,
        rec.onset_s,
    )
}

/// Measures every channel (module docs). `channels` hold the pre-roll, then the strike from
/// sample `onset`; `own_onsets_s` are each channel's own strike times and `shared_onset_s`
/// the shared one, in any common time origin.
pub fn assess(
    names: &[String],
    channels: &[Vec<f64>],
    onset: usize,
    fs: f64,
    own_onsets_s: &[Option<f64>],
    shared_onset_s: f64,
) -> Vec<ChannelHealth> {
    let window = ((PEAK_WINDOW_S * fs) as usize).max(1);
    let levels: Vec<f64> = channels
        .iter()
        .map(|c| {
            let start = onset.min(c.len());
            c[start..(start + window).min(c.len())]
                .iter()
                .fold(0.0_f64, |m, v| m.max(v.abs()))
        })
        .collect();
    let loudest = levels.iter().copied().fold(0.0_f64, f64::max);
    channels
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let start = onset.min(c.len());
            // Without a pre-roll the tail stands in for the floor, but an object still ringing
            // there would read as noise: the SNR then only informs, the own onset decides.
            let has_floor = start >= 64;
            let floor = if has_floor {
                rms(&c[..start])
            } else {
                rms(&c[c.len() - c.len() / 10..])
            };
            let level = levels[i];
            let snr_db = 20.0 * (level / floor.max(1e-300)).log10();
            let onset_offset_s = own_onsets_s
                .get(i)
                .copied()
                .flatten()
                .map(|t| t - shared_onset_s);
            let finite = c.iter().all(|v| v.is_finite());
            let verdict =
                if !finite || level <= 0.0 || 20.0 * (level / loudest).log10() <= -DEAD_BELOW_DB {
                    Verdict::Dead
                } else if onset_offset_s.is_none() || (has_floor && snr_db < MIN_SNR_DB) {
                    Verdict::NoiseOnly
                } else if onset_offset_s.is_some_and(|d| d.abs() > MAX_ONSET_OFFSET_S) {
                    Verdict::Misaligned
                } else {
                    Verdict::Healthy
                };
            ChannelHealth {
                name: names
                    .get(i)
                    .cloned()
                    .unwrap_or_else(|| format!("channel {i}")),
                level,
                floor,
                snr_db,
                onset_offset_s,
                verdict,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn strike(n: usize, onset: usize, fs: f64, amp: f64, noise: f64, seed: u64) -> Vec<f64> {
        let mut state = seed;
        let mut rnd = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        (0..n)
            .map(|i| {
                let t = (i as f64 - onset as f64) / fs;
                let s = if i >= onset {
                    amp * (-20.0 * t).exp() * (2.0 * std::f64::consts::PI * 700.0 * t).sin()
                } else {
                    0.0
                };
                s + noise * rnd()
            })
            .collect()
    }

    #[test]
    fn dead_noise_and_late_channels_are_told_from_healthy_ones() {
        let fs = 8000.0;
        let (n, onset) = (8000, 800);
        let names: Vec<String> = (0..4).map(|i| format!("mic{i}.wav")).collect();
        let channels = vec![
            strike(n, onset, fs, 0.5, 1e-4, 1),
            vec![0.0; n],
            strike(n, onset, fs, 0.0, 0.1, 3),
            strike(n, onset, fs, 0.4, 1e-4, 4),
        ];
        let shared = 0.1;
        let own = [Some(0.1), None, None, Some(2.1)];
        let h = assess(&names, &channels, onset, fs, &own, shared);
        let v: Vec<Verdict> = h.iter().map(|c| c.verdict).collect();
        assert_eq!(
            v,
            [
                Verdict::Healthy,
                Verdict::Dead,
                Verdict::NoiseOnly,
                Verdict::Misaligned
            ],
            "{h:?}"
        );
        assert!(h[0].snr_db > 60.0, "{h:?}");
    }

    #[test]
    fn a_quiet_but_clean_channel_stays_healthy() {
        let fs = 8000.0;
        let names = vec!["a".to_string(), "b".to_string()];
        let channels = vec![
            strike(8000, 800, fs, 0.5, 1e-5, 1),
            strike(8000, 800, fs, 0.005, 1e-5, 2),
        ];
        let h = assess(&names, &channels, 800, fs, &[Some(0.1), Some(0.101)], 0.1);
        assert!(h.iter().all(|c| c.verdict == Verdict::Healthy), "{h:?}");
    }
}
