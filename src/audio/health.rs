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
//! window; only with a pre-roll: the tail of a slowly decaying object is no floor) unless the
//! strike stands [`MIN_SNR_DB`] dB over the floor in some sub-band of the band (the *band
//! SNR*, below); *misaligned* — its own strike more than [`MAX_ONSET_OFFSET_S`] from the shared
//! one (7 m of extra path: more than a room's microphones differ by, so another take or a
//! shifted file). A channel with any verdict but *healthy* is left out of every fit, with a
//! warning that names its file.
//!
//! # The band against the noise floor
//!
//! A channel can carry the strike and still hold nothing but noise in the top of the band a
//! job analyses (a far or low-passed microphone, a soft strike): modes "found" there are noise.
//! [`band_over_floor`] measures, per channel at the file's own rate, how far up the strike rises
//! over the floor:
//!
//! * the floor's power spectrum N(f) is the Welch mean of Hann frames of L samples (hop L/2)
//!   over up to [`FLOOR_SPAN_S`] of the file before the onset, ending [`FLOOR_GUARD_S`] before
//!   it; L = 256, or 128 or 64 when the pre-roll is short, so that at least
//!   [`MIN_FLOOR_FRAMES`] frames average the floor (with fewer the floor is not measured);
//! * the strike's S(f) is, per bin, the largest power of the same frames over the first
//!   [`STRIKE_SPAN_S`] from the onset (the strike's strongest moment at each frequency);
//! * from 100 Hz to the band's top, sub-bands a sixth of an octave wide (at least
//!   [`MIN_SUBBAND_BINS`] bins) compare ΣS with ΣN; the **reach** is the top edge of the
//!   highest sub-band where the strike stands [`REACH_OVER_FLOOR_DB`] dB or more over the floor
//!   (0 when none does).
//!
//! The **band SNR** is the largest 10 log₁₀(ΣS/ΣN) over the same sub-bands. Why: the broadband
//! SNR sets the strike's peak against the floor's RMS over all frequencies, and a floor that
//! rises towards low frequencies (traffic, ventilation, a cable's hum: the rumble of real
//! rooms) holds most of its power far below the modes. Generator 2's brown noise put two
//! held-out microphones at a broadband SNR of 18 and 19 dB while their strike stood far over
//! the floor across the kHz band (blind seeds 269 case 007 and 283 case 022); left out as
//! noise, the second case lost its only held-out microphone and with it a damping law of ΔBIC
//! 25.1. Both microphones are kept now (band SNR over 20 dB); rerun, case 022 names its law
//! (ΔBIC 25.0, held-out gain 2.8) and case 007 keeps its glide. Chance cannot reach it: over
//! noise alone a sub-band stands at most about 6 dB over the floor (next paragraph).
//!
//! The threshold leaves room for chance: over white noise alone the largest of ~35 frames
//! exceeds the mean by about 6 dB in one bin, less in a sum of bins. A healthy channel whose
//! reach ends below [`REACH_WARN_FRACTION`] of the band's top is kept (its low modes are
//! evidence) with a warning naming the file; when no healthy channel rises over its floor
//! anywhere in the band the job is refused ([`BandHoldsOnlyNoise`]).

/// Window after the onset in which the level is read [s].
pub const PEAK_WINDOW_S: f64 = 0.2;
/// A channel this far or more under the loudest one is dead [dB].
pub const DEAD_BELOW_DB: f64 = 80.0;
/// Below this SNR a channel is noise only [dB].
pub const MIN_SNR_DB: f64 = 20.0;
/// Largest distance of a channel's own strike from the shared onset [s].
pub const MAX_ONSET_OFFSET_S: f64 = 0.02;
/// Longest span of pre-roll that measures the floor's spectrum [s].
pub const FLOOR_SPAN_S: f64 = 0.5;
/// The floor's span ends this long before the onset (the detector's uncertainty) [s].
pub const FLOOR_GUARD_S: f64 = 0.002;
/// Fewest Welch frames that make a floor spectrum.
pub const MIN_FLOOR_FRAMES: usize = 8;
/// Span from the onset whose frames measure the strike's spectrum [s].
pub const STRIKE_SPAN_S: f64 = 0.1;
/// Fewest FFT bins in a sub-band.
pub const MIN_SUBBAND_BINS: usize = 2;
/// A sub-band is reached when the strike stands this far over the floor [dB].
pub const REACH_OVER_FLOOR_DB: f64 = 12.0;
/// A reach under this fraction of the band's top is warned about.
pub const REACH_WARN_FRACTION: f64 = 0.8;

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
    /// How far up the band the strike rises over the floor [Hz]
    /// ([`BandOverFloor::reach_hz`]); `None` when no band was given or the pre-roll is too
    /// short to measure the floor.
    #[serde(default)]
    pub band_reach_hz: Option<f64>,
    /// The strike over the floor in its best sub-band of the band [dB] (module docs, the band
    /// SNR; [`band_over_floor`]); `None` when not measured.
    #[serde(default)]
    pub band_snr_db: Option<f64>,
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

/// No healthy channel rises over its noise floor anywhere in the band.
#[derive(Debug, thiserror::Error)]
#[error("the band up to {band_max_hz} Hz holds only noise: in no microphone ({names}) does the strike rise {REACH_OVER_FLOOR_DB} dB over the noise floor measured before it; check the band (--fmax), the gain and the cables")]
pub struct BandHoldsOnlyNoise {
    pub band_max_hz: f64,
    pub names: String,
}

/// One warning for each healthy channel whose reach ends below [`REACH_WARN_FRACTION`] of
/// `band_max_hz` (module docs), or the error when no healthy channel reaches into the band.
pub fn band_warnings(
    health: &[ChannelHealth],
    band_max_hz: f64,
) -> Result<Vec<String>, BandHoldsOnlyNoise> {
    let healthy: Vec<&ChannelHealth> = health.iter().filter(|h| h.is_healthy()).collect();
    let measured: Vec<(&ChannelHealth, f64)> = healthy
        .iter()
        .filter_map(|h| h.band_reach_hz.map(|r| (*h, r)))
        .collect();
    if !measured.is_empty()
        && measured.len() == healthy.len()
        && measured.iter().all(|(_, r)| *r <= 0.0)
    {
        return Err(BandHoldsOnlyNoise {
            band_max_hz,
            names: healthy
                .iter()
                .map(|h| h.name.as_str())
                .collect::<Vec<_>>()
                .join(", "),
        });
    }
    Ok(measured
        .iter()
        .filter(|(_, r)| *r < REACH_WARN_FRACTION * band_max_hz)
        .map(|(h, r)| {
            format!(
                "warning: {}: above {:.0} Hz the strike does not rise {REACH_OVER_FLOOR_DB} dB over the noise floor measured before it, but the band reaches {band_max_hz:.0} Hz: modes found there may be noise (lower --fmax, or record closer or louder)",
                h.name, r
            )
        })
        .collect())
}

/// The strike against the floor across the band (module docs): how far up it rises, and how
/// far over the floor it stands in its best sub-band.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BandOverFloor {
    /// The reach: the top of the highest sub-band where the strike stands
    /// [`REACH_OVER_FLOOR_DB`] over the floor (0 when none does) \[Hz\].
    pub reach_hz: f64,
    /// The band SNR: the largest 10 log₁₀(ΣS/ΣN) over the sub-bands \[dB\] (∞ over a floor
    /// of zeros, −∞ with no strike at all).
    pub snr_db: f64,
}

/// How the strike in `strike` (from the onset) stands over the floor in `noise` (the pre-roll
/// before it, guard already removed) up to `band_max_hz`, at `fs` Hz; see the module docs.
/// `None` when `noise` is too short for [`MIN_FLOOR_FRAMES`] frames of 64 samples or the
/// strike is shorter than one frame.
pub fn band_over_floor(
    noise: &[f64],
    strike: &[f64],
    fs: f64,
    band_max_hz: f64,
) -> Option<BandOverFloor> {
    let noise = &noise[noise.len().saturating_sub((FLOOR_SPAN_S * fs) as usize)..];
    let frames_of = |n: usize, l: usize| if n < l { 0 } else { (n - l) / (l / 2) + 1 };
    let l = [256usize, 128, 64]
        .into_iter()
        .find(|&l| frames_of(noise.len(), l) >= MIN_FLOOR_FRAMES)?;
    let strike = &strike[..strike.len().min(((STRIKE_SPAN_S * fs) as usize).max(l))];
    if strike.len() < l {
        return None;
    }
    let plan = crate::audio::stft::StftPlan::new(l, l / 2).ok()?;
    // Only frames that lie wholly inside the signal (frame t covers t·H − L/2 … t·H + L/2).
    let interior = |x: &[f64]| {
        let spec = plan.forward(x);
        let frames: Vec<Vec<f64>> = (0..spec.n_frames)
            .filter(|&t| t * (l / 2) >= l / 2 && t * (l / 2) + l / 2 <= x.len())
            .map(|t| spec.frame(t).iter().map(|m| m * m).collect())
            .collect();
        frames
    };
    let floor_frames = interior(noise);
    let strike_frames = interior(strike);
    if floor_frames.is_empty() || strike_frames.is_empty() {
        return None;
    }
    let n_bins = l / 2 + 1;
    let floor: Vec<f64> = (0..n_bins)
        .map(|k| floor_frames.iter().map(|f| f[k]).sum::<f64>() / floor_frames.len() as f64)
        .collect();
    let peak: Vec<f64> = (0..n_bins)
        .map(|k| strike_frames.iter().map(|f| f[k]).fold(0.0_f64, f64::max))
        .collect();
    let bin_hz = fs / l as f64;
    let top_bin = ((band_max_hz / bin_hz).floor() as usize).min(n_bins - 1);
    let mut reach = 0.0_f64;
    let mut snr_db = f64::NEG_INFINITY;
    let mut lo = ((100.0 / bin_hz).ceil() as usize).max(1);
    while lo <= top_bin {
        let sixth = ((lo as f64 * 2f64.powf(1.0 / 6.0)).ceil() as usize).max(lo + MIN_SUBBAND_BINS);
        let hi = sixth.min(top_bin + 1);
        let (s, n): (f64, f64) = (lo..hi).fold((0.0, 0.0), |(s, n), k| (s + peak[k], n + floor[k]));
        if s > 0.0 {
            let db = if n > 0.0 {
                10.0 * (s / n).log10()
            } else {
                f64::INFINITY
            };
            snr_db = snr_db.max(db);
            if db >= REACH_OVER_FLOOR_DB {
                reach = if hi > top_bin {
                    band_max_hz
                } else {
                    hi as f64 * bin_hz
                };
            }
        }
        lo = hi;
    }
    Some(BandOverFloor {
        reach_hz: reach,
        snr_db,
    })
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
        &rec.band_over_floor,
    )
}

/// Measures every channel (module docs). `channels` hold the pre-roll, then the strike from
/// sample `onset`; `own_onsets_s` are each channel's own strike times and `shared_onset_s`
/// the shared one, in any common time origin; `band` each channel's strike against its floor
/// across the band ([`band_over_floor`], measured on the files as read; empty or `None` when
/// not measured).
pub fn assess(
    names: &[String],
    channels: &[Vec<f64>],
    onset: usize,
    fs: f64,
    own_onsets_s: &[Option<f64>],
    shared_onset_s: f64,
    band: &[Option<BandOverFloor>],
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
            let band_here = band.get(i).copied().flatten();
            // A floor that is mostly rumble below the modes is no reason to call the strike
            // noise (module docs, the band SNR).
            let over_floor_in_band = band_here.is_some_and(|b| b.snr_db >= MIN_SNR_DB);
            let verdict =
                if !finite || level <= 0.0 || 20.0 * (level / loudest).log10() <= -DEAD_BELOW_DB {
                    Verdict::Dead
                } else if onset_offset_s.is_none()
                    || (has_floor && snr_db < MIN_SNR_DB && !over_floor_in_band)
                {
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
                band_reach_hz: band_here.map(|b| b.reach_hz),
                band_snr_db: band_here.map(|b| b.snr_db),
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
        let h = assess(&names, &channels, onset, fs, &own, shared, &[]);
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
        let h = assess(
            &names,
            &channels,
            800,
            fs,
            &[Some(0.1), Some(0.101)],
            0.1,
            &[],
        );
        assert!(h.iter().all(|c| c.verdict == Verdict::Healthy), "{h:?}");
    }

    /// Modes at 0.5–3.9 kHz over a floor 80 dB down, at 48 kHz: nothing rises above 3.9 kHz.
    fn low_passed(fs: f64, noise: f64, seed: u64) -> (Vec<f64>, Vec<f64>) {
        let x = strike(48_000, 0, fs, 0.0, noise, seed);
        let pre = x[..24_000].to_vec();
        let post = (0..24_000)
            .map(|i| {
                let t = i as f64 / fs;
                let s: f64 = [500.0, 900.0, 1700.0, 2600.0, 3900.0]
                    .iter()
                    .map(|f| (-30.0 * t).exp() * (2.0 * std::f64::consts::PI * f * t).sin())
                    .sum();
                0.1 * s + x[24_000 + i]
            })
            .collect();
        (pre, post)
    }

    /// A floor of low rumble (a 60 Hz hum and its harmonics, 0.1 of full scale) under a strike
    /// at 2–5 kHz that peaks at 0.5: a broadband SNR under 20 dB, but the strike stands far
    /// over the floor in its own sub-bands, so the channel is kept. Rumble alone stays noise.
    #[test]
    fn a_strike_over_low_rumble_is_not_noise() {
        let fs = 48_000.0;
        let (n, onset) = (72_000, 24_000);
        let rumble = |i: usize| {
            let t = i as f64 / fs;
            0.1 * [60.0, 120.0, 180.0]
                .iter()
                .map(|f| (2.0 * std::f64::consts::PI * f * t).sin())
                .sum::<f64>()
        };
        let hiss = strike(n, onset, fs, 0.0, 1e-4, 5);
        let with_strike: Vec<f64> = (0..n)
            .map(|i| {
                let t = (i as f64 - onset as f64) / fs;
                let s = if i >= onset {
                    0.17 * [2100.0, 3300.0, 4900.0]
                        .iter()
                        .map(|f| (-25.0 * t).exp() * (2.0 * std::f64::consts::PI * f * t).sin())
                        .sum::<f64>()
                } else {
                    0.0
                };
                s + rumble(i) + hiss[i]
            })
            .collect();
        let rumble_only: Vec<f64> = (0..n).map(|i| rumble(i) + hiss[i]).collect();
        let channels = vec![with_strike, rumble_only];
        let guard = (FLOOR_GUARD_S * fs).ceil() as usize;
        let band: Vec<Option<BandOverFloor>> = channels
            .iter()
            .map(|x| band_over_floor(&x[..onset - guard], &x[onset..], fs, 12_000.0))
            .collect();
        let names = vec!["strike.wav".to_string(), "rumble.wav".to_string()];
        let own = [Some(0.5), Some(0.5)];
        let h = assess(&names, &channels, onset, fs, &own, 0.5, &band);
        assert!(h[0].snr_db < MIN_SNR_DB, "{h:?}");
        assert!(h[0].band_snr_db.is_some_and(|b| b > 40.0), "{h:?}");
        assert_eq!(h[0].verdict, Verdict::Healthy, "{h:?}");
        assert!(h[1].band_snr_db.is_some_and(|b| b < 10.0), "{h:?}");
        assert_eq!(h[1].verdict, Verdict::NoiseOnly, "{h:?}");
        // Without the band measured the broadband rule alone decides, as before.
        let bare = assess(&names, &channels, onset, fs, &own, 0.5, &[]);
        assert_eq!(bare[0].verdict, Verdict::NoiseOnly, "{bare:?}");
    }

    /// The reach alone ([`BandOverFloor::reach_hz`]).
    fn band_reach_hz(noise: &[f64], strike: &[f64], fs: f64, band_max_hz: f64) -> Option<f64> {
        band_over_floor(noise, strike, fs, band_max_hz).map(|b| b.reach_hz)
    }

    #[test]
    fn the_reach_ends_where_the_strike_sinks_into_the_floor() {
        let fs = 48_000.0;
        let (pre, post) = low_passed(fs, 1e-3, 7);
        let reach = band_reach_hz(&pre, &post, fs, 12_000.0).expect("a long pre-roll");
        assert!((3900.0..5000.0).contains(&reach), "reach {reach} Hz");
        // A strike that fills the band reaches its top.
        let broad = strike(24_000, 0, fs, 0.5, 1e-3, 9);
        let click: Vec<f64> = broad
            .iter()
            .enumerate()
            .map(|(i, v)| v + if i == 300 { 0.5 } else { 0.0 })
            .collect();
        assert_eq!(band_reach_hz(&pre, &click, fs, 12_000.0), Some(12_000.0));
    }

    #[test]
    fn noise_alone_reaches_almost_nothing_and_a_short_pre_roll_measures_nothing() {
        let fs = 48_000.0;
        for seed in 1..=20 {
            let x = strike(48_000, 0, fs, 0.0, 0.1, seed);
            let reach = band_reach_hz(&x[..24_000], &x[24_000..], fs, 12_000.0).expect("measured");
            assert!(
                reach < 0.25 * 12_000.0,
                "seed {seed}: noise reached {reach} Hz"
            );
        }
        let x = strike(48_000, 0, fs, 0.0, 0.1, 1);
        assert_eq!(band_reach_hz(&x[..200], &x[24_000..], fs, 12_000.0), None);
    }

    #[test]
    fn a_short_reach_is_warned_with_the_file_and_no_reach_at_all_refused() {
        let fs = 48_000.0;
        let (pre, post) = low_passed(fs, 1e-3, 3);
        let reach = band_reach_hz(&pre, &post, fs, 12_000.0);
        let channel = |name: &str, reach: Option<f64>| ChannelHealth {
            name: name.to_string(),
            level: 0.5,
            floor: 1e-3,
            snr_db: 54.0,
            onset_offset_s: Some(0.0),
            verdict: Verdict::Healthy,
            band_reach_hz: reach,
            band_snr_db: None,
        };
        let health = vec![
            channel("far.wav", reach),
            channel("near.wav", Some(12_000.0)),
        ];
        let warnings = band_warnings(&health, 12_000.0).expect("one channel reaches");
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        assert!(warnings[0].contains("far.wav") && warnings[0].contains("--fmax"));
        let silent = vec![channel("a.wav", Some(0.0)), channel("b.wav", Some(0.0))];
        let err = band_warnings(&silent, 12_000.0).expect_err("only noise");
        assert!(err.to_string().contains("a.wav, b.wav"), "{err}");
        // Unmeasured channels never cause a refusal.
        assert!(band_warnings(&[channel("c.wav", None)], 12_000.0)
            .unwrap()
            .is_empty());
    }
}
