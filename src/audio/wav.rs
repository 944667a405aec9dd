//! WAV input and output.
//!
//! [`write_wav`] writes mono 16-bit PCM or 32-bit float, atomically (temporary
//! file in the same directory, then rename). [`read_wav`] reads 8/16/24/32-bit
//! integer and 32-bit float files with any number of channels. Integer samples
//! map to [-1, 1) by dividing by 2^(bits−1); writing uses the same scale, so a
//! 16-bit round trip is exact to half a quantisation step (1.5e-5).

use std::path::{Path, PathBuf};

/// Sample encoding for [`write_wav`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WavFormat {
    /// 16-bit signed integer PCM; samples outside [−1, 1] saturate.
    Pcm16,
    /// 32-bit IEEE float; samples are stored as given (rounded to f32).
    Float32,
}

/// Errors of this module; every variant names the file it concerns.
#[derive(thiserror::Error, Debug)]
pub enum AudioError {
    #[error("{path}: {context}: {source}")]
    Wav {
        path: PathBuf,
        context: String,
        #[source]
        source: hound::Error,
    },
    #[error("{path}: {context}: {source}")]
    Fs {
        path: PathBuf,
        context: String,
        #[source]
        source: std::io::Error,
    },
    /// The samples or parameters handed to a writer are unusable (nothing was written).
    #[error("{path}: refusing to write: {reason}")]
    InvalidInput { path: PathBuf, reason: String },
    /// A well-formed WAV file in an encoding this module does not read.
    #[error("{path}: unsupported WAV encoding: {reason}")]
    Unsupported { path: PathBuf, reason: String },
    /// Writing failed for a cause found by [`crate::io::atomic::replace_atomically`] (disk
    /// full, quota, file size limit, …); nothing was written at `path`.
    #[error("cannot write {path}: {reason}")]
    WriteFailed { path: PathBuf, reason: String },
    /// A float WAV holding NaN or infinite samples (an integer file cannot).
    #[error("{path}: holds NaN or infinite samples ({count} in all), the first ({value}) at sample {frame} of channel {channel} ({seconds:.6} s): re-export the recording with finite samples")]
    NonFinite {
        path: PathBuf,
        /// How many samples (over all channels) are NaN or ±∞.
        count: usize,
        /// The first one: its frame (0-based sample index within a channel), channel (0-based),
        /// time from the start [s] and value.
        frame: usize,
        channel: usize,
        seconds: f64,
        value: f64,
    },
}

/// Writes mono `samples` to `path` as a WAV file at `sample_rate` Hz.
///
/// With `normalise_peak = Some(p)` the samples are first scaled so that the
/// largest magnitude equals `p` (an all-zero signal is left as is). The file
/// appears atomically: it is written to `<dir>/.<name>.tmp.<pid>`, synced and
/// renamed (via [`crate::io::atomic::replace_atomically`]); on any error the
/// temporary is removed and `path` is untouched.
pub fn write_wav(
    path: &Path,
    samples: &[f64],
    sample_rate: u32,
    format: WavFormat,
    normalise_peak: Option<f64>,
) -> Result<(), AudioError> {
    let invalid = |reason: String| {
        Err(AudioError::InvalidInput {
            path: path.to_path_buf(),
            reason,
        })
    };
    if sample_rate == 0 {
        return invalid("sample rate is 0".into());
    }
    if let Some(i) = samples.iter().position(|s| !s.is_finite()) {
        return invalid(format!("sample {i} is {}", samples[i]));
    }
    let gain = match normalise_peak {
        None => 1.0,
        Some(p) if !(p > 0.0 && p.is_finite()) => {
            return invalid(format!("normalise_peak {p} is not a positive number"))
        }
        Some(p) => {
            let peak = samples.iter().fold(0.0_f64, |m, s| m.max(s.abs()));
            if peak > 0.0 {
                p / peak
            } else {
                1.0
            }
        }
    };
    let spec = hound::WavSpec {
        channels: 1,
        sample_rate,
        bits_per_sample: match format {
            WavFormat::Pcm16 => 16,
            WavFormat::Float32 => 32,
        },
        sample_format: match format {
            WavFormat::Pcm16 => hound::SampleFormat::Int,
            WavFormat::Float32 => hound::SampleFormat::Float,
        },
    };
    // hound checks the RIFF size limit only when the header is finalised; failing here gives
    // the clearer message, names the final path and writes nothing.
    let bytes = samples.len() as u64 * u64::from(spec.bits_per_sample / 8);
    if bytes > u64::from(u32::MAX) - 64 {
        return invalid(format!(
            "{} samples exceed the 4 GiB WAV size limit",
            samples.len()
        ));
    }

    crate::io::atomic::replace_atomically(path, |tmp| {
        write_wav_file(tmp, spec, samples, gain, format)
    })
}

impl crate::io::atomic::AtomicWriteError for AudioError {
    fn fs(path: &Path, context: String, source: std::io::Error) -> Self {
        AudioError::Fs {
            path: path.to_path_buf(),
            context,
            source,
        }
    }
    fn no_file_name(path: &Path) -> Self {
        AudioError::InvalidInput {
            path: path.to_path_buf(),
            reason: "path has no file name".into(),
        }
    }
    fn write_failed(path: &Path, reason: String) -> Self {
        AudioError::WriteFailed {
            path: path.to_path_buf(),
            reason,
        }
    }
    fn os_error(&self) -> Option<std::io::Error> {
        let io = match self {
            AudioError::Fs { source, .. } => source,
            AudioError::Wav {
                source: hound::Error::IoError(source),
                ..
            } => source,
            _ => return None,
        };
        io.raw_os_error().map(std::io::Error::from_raw_os_error)
    }
}

fn write_wav_file(
    tmp: &Path,
    spec: hound::WavSpec,
    samples: &[f64],
    gain: f64,
    format: WavFormat,
) -> Result<(), AudioError> {
    let wav_err = |context: &str| {
        let context = context.to_string();
        move |source| AudioError::Wav {
            path: tmp.to_path_buf(),
            context,
            source,
        }
    };
    let mut writer = hound::WavWriter::create(tmp, spec).map_err(wav_err("creating WAV file"))?;
    match format {
        WavFormat::Pcm16 => {
            for &s in samples {
                writer
                    .write_sample(pcm16(s * gain))
                    .map_err(wav_err("writing samples"))?;
            }
        }
        WavFormat::Float32 => {
            for &s in samples {
                writer
                    .write_sample((s * gain) as f32)
                    .map_err(wav_err("writing samples"))?;
            }
        }
    }
    writer.finalize().map_err(wav_err("finalising WAV header"))
}

/// [−1, 1] → i16 with full scale 2^15, rounding to nearest and saturating.
fn pcm16(x: f64) -> i16 {
    (x * 32768.0).round().clamp(-32768.0, 32767.0) as i16
}

/// Reads a WAV file into one vector per channel, scaled to [−1, 1], and its
/// sample rate in Hz. Integer files of 8, 16, 24 or 32 bits and 32-bit float
/// files are accepted; a truncated or corrupt file is an error, never a panic, and so is a
/// float file holding NaN or infinite samples ([`AudioError::NonFinite`], naming the first).
pub fn read_wav(path: &Path) -> Result<(Vec<Vec<f64>>, u32), AudioError> {
    let wav_err = |context: &str| {
        let context = context.to_string();
        move |source| AudioError::Wav {
            path: path.to_path_buf(),
            context,
            source,
        }
    };
    let mut reader = hound::WavReader::open(path).map_err(wav_err("reading WAV header"))?;
    let spec = reader.spec();
    let n_channels = usize::from(spec.channels);
    if n_channels == 0 {
        return Err(AudioError::Unsupported {
            path: path.to_path_buf(),
            reason: "zero channels".into(),
        });
    }
    let interleaved: Vec<f64> = match (spec.sample_format, spec.bits_per_sample) {
        (hound::SampleFormat::Int, bits @ (8 | 16 | 24 | 32)) => {
            let scale = 1.0 / f64::from(1u32 << (bits - 1));
            reader
                .samples::<i32>()
                .map(|s| s.map(|v| f64::from(v) * scale))
                .collect::<Result<_, _>>()
                .map_err(wav_err("reading samples"))?
        }
        (hound::SampleFormat::Float, 32) => reader
            .samples::<f32>()
            .map(|s| s.map(f64::from))
            .collect::<Result<_, _>>()
            .map_err(wav_err("reading samples"))?,
        (format, bits) => {
            return Err(AudioError::Unsupported {
                path: path.to_path_buf(),
                reason: format!(
                    "{bits}-bit {format:?} samples (supported: 8/16/24/32-bit Int, 32-bit Float)"
                ),
            })
        }
    };
    // hound stops quietly at the end of a short final frame; a partial frame
    // means the data chunk was cut mid-frame.
    if interleaved.len() % n_channels != 0 {
        return Err(AudioError::Wav {
            path: path.to_path_buf(),
            context: "reading samples".into(),
            source: hound::Error::FormatError("data ends inside a sample frame"),
        });
    }
    // A float file can hold NaN or ±∞, which every analysis would spread silently (a
    // spectrogram draws them black, an onset detector never fires).
    if let Some(i) = interleaved.iter().position(|s| !s.is_finite()) {
        return Err(AudioError::NonFinite {
            path: path.to_path_buf(),
            count: interleaved.iter().filter(|s| !s.is_finite()).count(),
            frame: i / n_channels,
            channel: i % n_channels,
            seconds: (i / n_channels) as f64 / f64::from(spec.sample_rate.max(1)),
            value: interleaved[i],
        });
    }
    let frames = interleaved.len() / n_channels;
    let mut channels = vec![Vec::with_capacity(frames); n_channels];
    for frame in interleaved.chunks_exact(n_channels) {
        for (channel, &s) in channels.iter_mut().zip(frame) {
            channel.push(s);
        }
    }
    Ok((channels, spec.sample_rate))
}
