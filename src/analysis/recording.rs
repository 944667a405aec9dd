//! Loading a recording of one strike, made by one or more microphones:
//! read, resample, find the strike, trim, level.
//!
//! [`load_recording`] takes these steps:
//!
//! 1. Every file is read with [`read_wav`]; the channels of all files, in
//!    order, become the channel list. A mono file's channel is named after
//!    the file stem (`mic3`), channel k of a multichannel file `stem[k]`.
//! 2. All channels must share the source rate f_src (Hz) and length N.
//! 3. The shared onset n₀ is detected at the source rate
//!    ([`detect_shared_onset`]); t₀ = n₀ / f_src is in seconds of the
//!    original files.
//! 4. With f_out the target rate (or f_src), output sample i sits at time
//!    i / f_out of the original file. The kept span starts at
//!    i_s = round(max(0, t₀ − pre_roll_s) · f_out), i.e. at time
//!    t_s = i_s / f_out, and holds round(duration_s · f_out) samples, or all
//!    that remain if fewer (or if no duration is given).
//! 5. Only that span of the resampled signal is computed
//!    ([`Resampler::process_range`]); the numbers equal resampling the
//!    whole file and cutting afterwards, so the cut has no edge effects of
//!    its own.
//! 6. The gain policy scales all channels ([`GainPolicy`]; by default one
//!    common gain takes the loudest channel's peak to 0.9, so relative
//!    microphone levels survive).
//!
//! The default pre-roll is 5 ms: the resampling kernel is linear-phase and
//! reaches ±33 periods of the lower rate (≈ 1 ms at 32 kHz), so the
//! band-limited strike starts up to that long before t₀, and a few ms of
//! noise before the strike show the floor the strike rises from.

use std::path::{Path, PathBuf};

use crate::analysis::onset::{
    apply_gain_db, detect_shared_onset, normalise_peak, normalise_rms, GainError, OnsetError,
    OnsetOptions,
};
use crate::audio::resample::{ResampleError, Resampler};
use crate::audio::{read_wav, AudioError};

/// Default peak of the loudest channel under [`GainPolicy::CommonPeak`].
pub const DEFAULT_PEAK: f64 = 0.9;
/// Default time kept before the onset, in seconds.
pub const DEFAULT_PRE_ROLL_S: f64 = 0.005;

/// How [`load_recording`] levels the channels. Every policy applies one gain
/// to all channels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GainPolicy {
    /// Keep the samples as read (full scale = 1); gain 1.
    Unity,
    /// The largest |x| of the loudest channel becomes this value.
    CommonPeak(f64),
    /// The RMS over all samples of all channels becomes this value.
    CommonRms(f64),
    /// A fixed gain in dB.
    FixedDb(f64),
}

impl Default for GainPolicy {
    fn default() -> Self {
        GainPolicy::CommonPeak(DEFAULT_PEAK)
    }
}

/// Settings of [`load_recording`].
#[derive(Clone, Debug, PartialEq)]
pub struct RecordingOptions {
    /// Resample to this rate (Hz); `None` keeps the source rate.
    pub target_rate: Option<u32>,
    /// Time kept before the detected onset, in seconds.
    pub pre_roll_s: f64,
    /// Longest span kept from the start of the cut, in seconds; `None`
    /// keeps everything to the end of the files.
    pub duration_s: Option<f64>,
    pub gain: GainPolicy,
    pub onset: OnsetOptions,
    /// The highest frequency the caller will analyse (Hz): it must lie below the Nyquist
    /// frequency of the files as recorded (resampling to a higher rate adds no content above
    /// it, and an aliased file puts energy there that is not the object's).
    pub band_max_hz: Option<f64>,
}

impl Default for RecordingOptions {
    fn default() -> Self {
        RecordingOptions {
            target_rate: None,
            pre_roll_s: DEFAULT_PRE_ROLL_S,
            duration_s: None,
            gain: GainPolicy::default(),
            onset: OnsetOptions::default(),
            band_max_hz: None,
        }
    }
}

/// A trimmed, levelled recording of one strike.
#[derive(Clone, Debug, PartialEq)]
pub struct Recording {
    /// One vector per microphone channel, all of equal length.
    pub channels: Vec<Vec<f64>>,
    /// Rate of `channels`, in Hz.
    pub sample_rate: u32,
    /// Rate of the files read, in Hz.
    pub source_rate: u32,
    /// Shared onset, in seconds from the start of the original files.
    pub onset_s: f64,
    /// Time of `channels[_][0]` in the original files, in seconds.
    pub start_s: f64,
    /// Each channel's own onset in seconds of the original files; `None` for
    /// a channel with no detectable strike (silent or noise only).
    pub channel_onsets_s: Vec<Option<f64>>,
    /// Linear gain applied to the samples as read (full scale = 1).
    pub gain: f64,
    /// One name per channel (see the module docs).
    pub names: Vec<String>,
    /// Per channel, how far up to [`RecordingOptions::band_max_hz`] the strike rises over the
    /// noise floor before it and how far over it it stands in its best sub-band, measured on
    /// the files as read ([`crate::audio::health::band_over_floor`]); empty without a band.
    pub band_over_floor: Vec<Option<crate::audio::health::BandOverFloor>>,
}

impl Recording {
    /// Index of the shared onset within `channels` (0 without pre-roll).
    pub fn onset_sample(&self) -> usize {
        let fs = f64::from(self.sample_rate);
        (((self.onset_s - self.start_s) * fs).round().max(0.0) as usize)
            .min(self.channels.first().map_or(0, Vec::len))
    }
}

/// Why a recording could not be loaded.
#[derive(thiserror::Error, Debug)]
pub enum RecordingError {
    #[error("no input files given")]
    NoFiles,
    #[error(transparent)]
    Audio(#[from] AudioError),
    #[error("{path}: sample rate {rate} Hz differs from the {first_rate} Hz of {first_path}")]
    RateMismatch {
        path: PathBuf,
        rate: u32,
        first_path: PathBuf,
        first_rate: u32,
    },
    #[error("{path}: {frames} samples per channel differ from the {first_frames} of {first_path}")]
    LengthMismatch {
        path: PathBuf,
        frames: usize,
        first_path: PathBuf,
        first_frames: usize,
    },
    #[error("recording option {name} = {value} is invalid: {reason}")]
    InvalidOption {
        name: &'static str,
        value: f64,
        reason: &'static str,
    },
    #[error("resampling {from_hz} Hz → {to_hz} Hz: {source}")]
    Resample {
        from_hz: u32,
        to_hz: u32,
        #[source]
        source: ResampleError,
    },
    #[error("finding the strike in {files}: {source}")]
    Onset {
        files: String,
        #[source]
        source: OnsetError,
    },
    #[error("{path}: the band up to {band_hz} Hz passes this file's Nyquist frequency {} Hz (recorded at {rate} Hz); lower the band's top (--fmax) below {} Hz or give a recording sampled at more than {} Hz", 0.5 * f64::from(*rate), 0.5 * f64::from(*rate), 2.0 * band_hz)]
    BandPastNyquist {
        path: PathBuf,
        rate: u32,
        band_hz: f64,
    },
    #[error("applying the gain: {0}")]
    Gain(#[from] GainError),
}

/// Reads, resamples, trims and levels a recording; see the module docs.
/// `paths` may be `&[PathBuf]`, `&[&Path]`, `&[&str]`, ….
pub fn load_recording<P: AsRef<Path>>(
    paths: &[P],
    opts: &RecordingOptions,
) -> Result<Recording, RecordingError> {
    check_options(opts)?;
    let first_path = paths.first().ok_or(RecordingError::NoFiles)?.as_ref();

    let mut channels: Vec<Vec<f64>> = Vec::new();
    let mut names = Vec::new();
    let mut source_rate = 0;
    for (file_index, path) in paths.iter().enumerate() {
        let path = path.as_ref();
        let (file_channels, rate) = read_wav(path)?;
        let frames = file_channels.first().map_or(0, Vec::len);
        if file_index == 0 {
            source_rate = rate;
            if let Some(band_hz) = opts.band_max_hz.filter(|b| *b >= 0.5 * f64::from(rate)) {
                return Err(RecordingError::BandPastNyquist {
                    path: path.to_path_buf(),
                    rate,
                    band_hz,
                });
            }
        } else if rate != source_rate {
            return Err(RecordingError::RateMismatch {
                path: path.to_path_buf(),
                rate,
                first_path: first_path.to_path_buf(),
                first_rate: source_rate,
            });
        } else if frames != channels[0].len() {
            return Err(RecordingError::LengthMismatch {
                path: path.to_path_buf(),
                frames,
                first_path: first_path.to_path_buf(),
                first_frames: channels[0].len(),
            });
        }
        let stem = path.file_stem().map_or_else(
            || path.display().to_string(),
            |s| s.to_string_lossy().into_owned(),
        );
        let n_channels = file_channels.len();
        for (k, channel) in file_channels.into_iter().enumerate() {
            names.push(if n_channels == 1 {
                stem.clone()
            } else {
                format!("{stem}[{k}]")
            });
            channels.push(channel);
        }
    }

    let onset = detect_shared_onset(&channels, source_rate, &opts.onset).map_err(|source| {
        RecordingError::Onset {
            files: describe_files(paths),
            source,
        }
    })?;
    let onset_s = onset.time_s;
    let band_over_floor = match opts.band_max_hz {
        Some(band_hz) => {
            let fs = f64::from(source_rate);
            let n0 = ((onset_s * fs).round() as usize).min(channels[0].len());
            let floor_end =
                n0.saturating_sub((crate::audio::health::FLOOR_GUARD_S * fs).ceil() as usize);
            channels
                .iter()
                .map(|x| {
                    crate::audio::health::band_over_floor(&x[..floor_end], &x[n0..], fs, band_hz)
                })
                .collect()
        }
        None => Vec::new(),
    };

    let out_rate = opts.target_rate.unwrap_or(source_rate);
    let resample_err = |source| RecordingError::Resample {
        from_hz: source_rate,
        to_hz: out_rate,
        source,
    };
    let resampler = Resampler::new(source_rate, out_rate).map_err(resample_err)?;
    let available = resampler
        .output_len(channels[0].len())
        .ok_or(ResampleError::OutputTooLarge {
            input_len: channels[0].len(),
            from_hz: source_rate,
            to_hz: out_rate,
        })
        .map_err(resample_err)?;
    let out_hz = f64::from(out_rate);
    // The onset lies inside the files, so the start lies inside the output.
    let start = (((onset_s - opts.pre_roll_s).max(0.0) * out_hz).round() as usize).min(available);
    let count = match opts.duration_s {
        Some(d) if (d * out_hz).round() < 1.0 => {
            return Err(RecordingError::InvalidOption {
                name: "duration_s",
                value: d,
                reason: "is shorter than one sample",
            })
        }
        Some(d) => ((d * out_hz).round() as usize).min(available - start),
        None => available - start,
    };
    let mut trimmed = Vec::with_capacity(channels.len());
    for x in &channels {
        trimmed.push(
            resampler
                .process_range(x, start, count)
                .map_err(resample_err)?,
        );
    }

    let gain = match opts.gain {
        GainPolicy::Unity => 1.0,
        GainPolicy::CommonPeak(p) => normalise_peak(&mut trimmed, p)?,
        GainPolicy::CommonRms(r) => normalise_rms(&mut trimmed, r)?,
        GainPolicy::FixedDb(db) => apply_gain_db(&mut trimmed, db)?,
    };

    Ok(Recording {
        channels: trimmed,
        sample_rate: out_rate,
        source_rate,
        onset_s,
        start_s: start as f64 / out_hz,
        channel_onsets_s: onset
            .per_channel
            .iter()
            .map(|o| o.as_ref().map(|o| o.time_s))
            .collect(),
        gain,
        names,
        band_over_floor,
    })
}

/// Rejects options that cannot work before any file is read.
fn check_options(opts: &RecordingOptions) -> Result<(), RecordingError> {
    let invalid = |name, value, reason| {
        Err(RecordingError::InvalidOption {
            name,
            value,
            reason,
        })
    };
    if opts.target_rate == Some(0) {
        return invalid("target_rate", 0.0, "must be a positive number of Hz");
    }
    if !(opts.pre_roll_s >= 0.0 && opts.pre_roll_s.is_finite()) {
        return invalid("pre_roll_s", opts.pre_roll_s, "must be a finite number ≥ 0");
    }
    if let Some(d) = opts.duration_s {
        if !(d > 0.0 && d.is_finite()) {
            return invalid("duration_s", d, "must be a positive finite number");
        }
    }
    let target_ok = |v: f64| v > 0.0 && v.is_finite();
    match opts.gain {
        GainPolicy::CommonPeak(p) if !target_ok(p) => {
            invalid("gain (CommonPeak)", p, "must be a positive finite number")
        }
        GainPolicy::CommonRms(r) if !target_ok(r) => {
            invalid("gain (CommonRms)", r, "must be a positive finite number")
        }
        GainPolicy::FixedDb(db) if !db.is_finite() => {
            invalid("gain (FixedDb)", db, "must be a finite number of dB")
        }
        _ => Ok(()),
    }
}

/// "a.wav" or "a.wav, b.wav and 6 more", for error messages.
fn describe_files<P: AsRef<Path>>(paths: &[P]) -> String {
    let shown: Vec<String> = paths
        .iter()
        .take(2)
        .map(|p| p.as_ref().display().to_string())
        .collect();
    let mut text = shown.join(", ");
    if paths.len() > 2 {
        text.push_str(&format!(" and {} more", paths.len() - 2));
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::onset::test_support::{bowl_dir, synthetic_strike};
    use crate::audio::resample::resample;
    use crate::audio::{write_wav, WavFormat};

    /// A fresh directory under the system temp dir, removed on drop.
    struct TempDir(PathBuf);

    impl TempDir {
        fn new(tag: &str) -> TempDir {
            use std::sync::atomic::{AtomicUsize, Ordering};
            static COUNTER: AtomicUsize = AtomicUsize::new(0);
            let nanos = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.subsec_nanos());
            let dir = std::env::temp_dir().join(format!(
                "diffsound_recording_{tag}_{}_{nanos}_{}",
                std::process::id(),
                COUNTER.fetch_add(1, Ordering::Relaxed)
            ));
            std::fs::create_dir_all(&dir).unwrap();
            TempDir(dir)
        }
    }

    impl Drop for TempDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    const RATE: u32 = 48_000;
    const STRIKE: usize = 14_400; // 0.3 s

    /// Mono float WAV of a synthetic strike at 0.3 s, scaled by `level`.
    fn write_strike(dir: &Path, name: &str, seed: u64, level: f64) -> PathBuf {
        let path = dir.join(name);
        let x: Vec<f64> = synthetic_strike(seed, STRIKE, 48_000, f64::from(RATE), 1e-4)
            .into_iter()
            .map(|v| v * level)
            .collect();
        write_wav(&path, &x, RATE, WavFormat::Float32, None).unwrap();
        path
    }

    #[test]
    fn mono_files_keep_their_relative_levels() {
        let tmp = TempDir::new("mono");
        let paths = [
            write_strike(&tmp.0, "near.wav", 1, 0.5),
            write_strike(&tmp.0, "far.wav", 2, 0.1),
        ];
        let raw: Vec<Vec<f64>> = paths
            .iter()
            .map(|p| read_wav(p).unwrap().0.remove(0))
            .collect();
        let rec = load_recording(&paths, &RecordingOptions::default()).unwrap();
        assert_eq!(rec.names, ["near", "far"]);
        assert_eq!((rec.sample_rate, rec.source_rate), (RATE, RATE));
        assert!(
            (rec.onset_s - 0.3).abs() < 3.0 / 48_000.0,
            "onset {}",
            rec.onset_s
        );
        assert!((rec.start_s - (rec.onset_s - DEFAULT_PRE_ROLL_S)).abs() < 0.6 / 48_000.0);
        let start = (rec.start_s * 48_000.0).round() as usize;
        assert_eq!(rec.channels[0].len(), 48_000 - start);
        let peaks: Vec<f64> = rec
            .channels
            .iter()
            .map(|c| c.iter().fold(0.0_f64, |m, v| m.max(v.abs())))
            .collect();
        assert!((peaks[0] - DEFAULT_PEAK).abs() < 1e-12);
        // One gain for both: the samples are the raw ones, cut and scaled.
        for (c, x) in rec.channels.iter().zip(&raw) {
            for (a, b) in c.iter().zip(&x[start..]) {
                assert!((a - rec.gain * b).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn multichannel_file_resampled_and_cut() {
        let tmp = TempDir::new("multi");
        let left = synthetic_strike(3, STRIKE, 48_000, f64::from(RATE), 1e-4);
        let right = synthetic_strike(4, STRIKE + 24, 48_000, f64::from(RATE), 1e-4);
        let stereo = tmp.0.join("pair.wav");
        let spec = hound::WavSpec {
            channels: 2,
            sample_rate: RATE,
            bits_per_sample: 16,
            sample_format: hound::SampleFormat::Int,
        };
        let mut writer = hound::WavWriter::create(&stereo, spec).unwrap();
        for (l, r) in left.iter().zip(&right) {
            writer.write_sample((l * 32_768.0).round() as i16).unwrap();
            writer.write_sample((r * 32_768.0).round() as i16).unwrap();
        }
        writer.finalize().unwrap();
        let mono = write_strike(&tmp.0, "solo.wav", 5, 0.3);

        let opts = RecordingOptions {
            target_rate: Some(32_000),
            duration_s: Some(0.5),
            gain: GainPolicy::Unity,
            ..RecordingOptions::default()
        };
        let paths = [stereo.as_path(), mono.as_path()];
        let rec = load_recording(&paths, &opts).unwrap();
        assert_eq!(rec.names, ["pair[0]", "pair[1]", "solo"]);
        assert_eq!(
            (rec.sample_rate, rec.source_rate, rec.gain),
            (32_000, RATE, 1.0)
        );
        assert!(
            (rec.onset_s - 0.3).abs() < 3.0 / 48_000.0,
            "onset {}",
            rec.onset_s
        );
        assert!(rec.channel_onsets_s[1].unwrap() - rec.onset_s > 20.0 / 48_000.0);
        assert!(rec.channels.iter().all(|c| c.len() == 16_000));
        // The cut equals resampling everything and cutting afterwards.
        let start = (rec.start_s * 32_000.0).round() as usize;
        let full = resample(&read_wav(&mono).unwrap().0[0], RATE, 32_000).unwrap();
        assert_eq!(rec.channels[2], full[start..start + 16_000]);
    }

    #[test]
    fn mismatched_files_are_errors() {
        let tmp = TempDir::new("mismatch");
        let a = write_strike(&tmp.0, "a.wav", 1, 0.5);
        let x = synthetic_strike(2, STRIKE, 48_000, f64::from(RATE), 1e-4);
        let slow = tmp.0.join("slow.wav");
        write_wav(&slow, &x, 44_100, WavFormat::Float32, None).unwrap();
        let short = tmp.0.join("short.wav");
        write_wav(&short, &x[..40_000], RATE, WavFormat::Float32, None).unwrap();
        let opts = RecordingOptions::default();

        let err = load_recording(&[&a, &slow], &opts).unwrap_err();
        assert!(
            matches!(
                err,
                RecordingError::RateMismatch {
                    rate: 44_100,
                    first_rate: 48_000,
                    ..
                }
            ),
            "{err}"
        );
        let err = load_recording(&[&a, &short], &opts).unwrap_err();
        assert!(
            matches!(err, RecordingError::LengthMismatch { frames: 40_000, .. }),
            "{err}"
        );
        assert!(err.to_string().contains("short.wav"), "{err}");
        let none: [&Path; 0] = [];
        assert!(matches!(
            load_recording(&none, &opts),
            Err(RecordingError::NoFiles)
        ));
        let missing = tmp.0.join("missing.wav");
        assert!(matches!(
            load_recording(&[&missing], &opts),
            Err(RecordingError::Audio(_))
        ));

        let noise = tmp.0.join("noise.wav");
        let mut rng = crate::analysis::onset::test_support::SplitMix64(8);
        let hiss: Vec<f64> = (0..48_000).map(|_| 1e-3 * rng.normal()).collect();
        write_wav(&noise, &hiss, RATE, WavFormat::Float32, None).unwrap();
        let err = load_recording(&[&noise], &opts).unwrap_err();
        assert!(matches!(err, RecordingError::Onset { .. }), "{err}");
        assert!(err.to_string().contains("noise.wav"), "{err}");
    }

    #[test]
    fn a_band_past_the_files_nyquist_is_refused_with_the_file_named() {
        let tmp = TempDir::new("nyquist");
        let a = write_strike(&tmp.0, "low_rate.wav", 1, 0.5);
        let nyquist = 0.5 * f64::from(RATE);
        // Resampling to a higher rate does not make the band valid.
        let opts = RecordingOptions {
            target_rate: Some(4 * RATE),
            band_max_hz: Some(1.2 * nyquist),
            ..RecordingOptions::default()
        };
        let err = load_recording(&[&a], &opts).unwrap_err();
        assert!(
            matches!(err, RecordingError::BandPastNyquist { .. }),
            "{err}"
        );
        assert!(
            err.to_string().contains("low_rate.wav") && err.to_string().contains("--fmax"),
            "{err}"
        );
        let fine = RecordingOptions {
            band_max_hz: Some(0.8 * nyquist),
            ..RecordingOptions::default()
        };
        assert!(load_recording(&[&a], &fine).is_ok());
    }

    #[test]
    fn bad_options_are_errors() {
        let tmp = TempDir::new("options");
        let a = write_strike(&tmp.0, "a.wav", 1, 0.5);
        let base = RecordingOptions::default();
        for bad in [
            RecordingOptions {
                target_rate: Some(0),
                ..base.clone()
            },
            RecordingOptions {
                pre_roll_s: -0.1,
                ..base.clone()
            },
            RecordingOptions {
                duration_s: Some(f64::NAN),
                ..base.clone()
            },
            RecordingOptions {
                target_rate: Some(8_000),
                duration_s: Some(1e-5),
                ..base.clone()
            },
            RecordingOptions {
                gain: GainPolicy::CommonPeak(0.0),
                ..base.clone()
            },
            RecordingOptions {
                gain: GainPolicy::FixedDb(f64::INFINITY),
                ..base.clone()
            },
        ] {
            let err = load_recording(&[&a], &bad).unwrap_err();
            assert!(
                matches!(err, RecordingError::InvalidOption { .. }),
                "{bad:?}: {err}"
            );
        }
        let bad_onset = RecordingOptions {
            onset: OnsetOptions {
                frame_s: -1.0,
                ..OnsetOptions::default()
            },
            ..base
        };
        assert!(matches!(
            load_recording(&[&a], &bad_onset),
            Err(RecordingError::Onset { .. })
        ));
    }

    #[test]
    fn bowl_eight_mics_at_32_khz() {
        let Some(dir) = bowl_dir() else {
            println!("note: bowl recordings not found; skipping");
            return;
        };
        let paths: Vec<PathBuf> = (0..8).map(|i| dir.join(format!("mic{i}.wav"))).collect();
        let opts = RecordingOptions {
            target_rate: Some(32_000),
            duration_s: Some(2.0),
            ..RecordingOptions::default()
        };
        let t = std::time::Instant::now();
        let rec = load_recording(&paths, &opts).unwrap();
        println!(
            "bowl: {} channels, onset {:.5} s, start {:.5} s, gain {:.2}, loaded in {:.0} ms",
            rec.channels.len(),
            rec.onset_s,
            rec.start_s,
            rec.gain,
            t.elapsed().as_secs_f64() * 1e3
        );
        assert_eq!(rec.channels.len(), 8);
        assert_eq!(rec.names[7], "mic7");
        assert_eq!((rec.sample_rate, rec.source_rate), (32_000, 48_000));
        assert!((rec.onset_s - 1.0).abs() < 0.01, "onset {}", rec.onset_s);
        assert!(rec.channels.iter().all(|c| c.len() == 64_000));
        let peak = rec
            .channels
            .iter()
            .flatten()
            .fold(0.0_f64, |m, v| m.max(v.abs()));
        assert!((peak - DEFAULT_PEAK).abs() < 1e-12);
        // The strike starts after the pre-roll: the first 4 ms (the pre-roll
        // less the kernel's reach) are quiet compared with the strike, once
        // the microphones' DC offsets are set aside.
        for c in &rec.channels {
            let offset = c[..128].iter().sum::<f64>() / 128.0;
            let deviation = |s: &[f64]| s.iter().fold(0.0_f64, |m, v| m.max((v - offset).abs()));
            let (before, after) = (deviation(&c[..128]), deviation(&c[160..1_000]));
            assert!(
                after > 20.0 * before,
                "pre-roll peak {before}, strike peak {after}"
            );
        }
    }
}
