//! Sound from modes: damped-sinusoid synthesis and WAV input/output.
//!
//! # Damping
//!
//! With Rayleigh damping C = αM + βK, each undamped mode of angular frequency
//! ω = √λ (rad/s) decouples into a damped oscillator with
//!
//! * decay rate      d  = (α + β ω²) / 2            (1/s; amplitude ∝ e^(−d t))
//! * damping ratio   ζ  = d / ω                     (dimensionless)
//! * damped angular  ω_d = ω √(1 − ζ²)              (rad/s), f_d = ω_d / 2π (Hz)
//!
//! A mode with ζ ≥ 1 is overdamped: it does not ring, so it has no damped
//! frequency ([`damped_frequency`] returns `None`) and
//! [`ModalBank::from_eigenvalues`] leaves it out.
//!
//! # Synthesis
//!
//! [`render`] evaluates, at sample rate f_s (Hz) and n = 0, 1, …,
//!
//! s[n] = Σ_k a_k · e^(−d_k n / f_s) · sin(2π f_k n / f_s + φ_k)
//!
//! exactly in discrete time. Each mode is the imaginary part of the complex
//! sequence z_n = a e^(iφ) rⁿ with r = e^((−d + i 2π f)/f_s), advanced by one
//! complex multiply per sample. Rounding in that recursion grows linearly with
//! the number of steps, so every [`REANCHOR_INTERVAL`] samples z_n is recomputed
//! directly, with the phase f·n/f_s reduced modulo one cycle in double-double
//! arithmetic. The error therefore stays ~1e-13 of the amplitude however long
//! the signal is, instead of drifting.
//!
//! Modes whose frequency is not strictly between 0 and the Nyquist frequency
//! f_s/2 are skipped: they cannot be represented at that sample rate and would
//! alias to a wrong pitch.
//!
//! # WAV
//!
//! [`write_wav`] writes mono 16-bit PCM or 32-bit float, atomically (temporary
//! file in the same directory, then rename). [`read_wav`] reads 8/16/24/32-bit
//! integer and 32-bit float files with any number of channels. Integer samples
//! map to [-1, 1) by dividing by 2^(bits−1); writing uses the same scale, so a
//! 16-bit round trip is exact to half a quantisation step (1.5e-5).

use std::path::{Path, PathBuf};

/// Samples between direct re-evaluations of each mode in [`render`]; the
/// recursion's rounding error after this many steps is ~1e-13 relative.
pub const REANCHOR_INTERVAL: usize = 1024;

/// A set of exponentially decaying sinusoids, one entry per mode in each vector.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ModalBank {
    /// Hz (the damped frequency f_d when built from eigenvalues).
    pub frequencies_hz: Vec<f64>,
    /// 1/s; amplitude ∝ exp(−d t).
    pub decay_rates: Vec<f64>,
    /// Peak amplitude at t = 0, in output units.
    pub amplitudes: Vec<f64>,
    /// Radians, at t = 0.
    pub phases: Vec<f64>,
}

impl ModalBank {
    /// Number of modes.
    pub fn len(&self) -> usize {
        self.frequencies_hz.len()
    }

    pub fn is_empty(&self) -> bool {
        self.frequencies_hz.is_empty()
    }

    /// Builds a bank from eigenvalues λ = ω² (rad²/s²) with Rayleigh damping
    /// (α in 1/s, β in s), zero phases and the given amplitudes. Overdamped
    /// modes (ζ ≥ 1) and non-positive eigenvalues are dropped.
    ///
    /// # Panics
    /// If `amplitudes.len() != eigenvalues.len()`.
    pub fn from_eigenvalues(
        eigenvalues: &[f64],
        amplitudes: &[f64],
        alpha: f64,
        beta: f64,
    ) -> ModalBank {
        assert_eq!(
            eigenvalues.len(),
            amplitudes.len(),
            "one amplitude per eigenvalue"
        );
        let mut bank = ModalBank::default();
        for (&lambda, &a) in eigenvalues.iter().zip(amplitudes) {
            if lambda.is_nan() || lambda <= 0.0 {
                continue;
            }
            let omega = lambda.sqrt();
            if let Some(omega_d) = damped_frequency(omega, alpha, beta) {
                bank.frequencies_hz
                    .push(omega_d / (2.0 * std::f64::consts::PI));
                bank.decay_rates.push(rayleigh_decay(omega, alpha, beta));
                bank.amplitudes.push(a);
                bank.phases.push(0.0);
            }
        }
        bank
    }
}

/// Decay rate d = (α + β ω²) / 2 in 1/s, for undamped angular frequency ω
/// (rad/s), mass coefficient α (1/s) and stiffness coefficient β (s).
pub fn rayleigh_decay(omega: f64, alpha: f64, beta: f64) -> f64 {
    0.5 * (alpha + beta * omega * omega)
}

/// Damped angular frequency ω_d = ω √(1 − ζ²) in rad/s with ζ = d/ω, or `None`
/// if the mode does not oscillate (ζ ≥ 1, or ω ≤ 0).
pub fn damped_frequency(omega: f64, alpha: f64, beta: f64) -> Option<f64> {
    if omega.is_nan() || omega <= 0.0 {
        return None;
    }
    let zeta = rayleigh_decay(omega, alpha, beta) / omega;
    if zeta >= 1.0 || zeta.is_nan() {
        return None;
    }
    Some(omega * (1.0 - zeta * zeta).sqrt())
}

/// Renders `bank` at `sample_rate` Hz for `duration_s` seconds
/// (round(duration·rate) samples); see the module docs for the formula and
/// which modes are skipped.
///
/// # Panics
/// If the four vectors of `bank` differ in length.
pub fn render(bank: &ModalBank, sample_rate: f64, duration_s: f64) -> Vec<f64> {
    let n = bank.len();
    assert!(
        bank.decay_rates.len() == n && bank.amplitudes.len() == n && bank.phases.len() == n,
        "ModalBank vectors differ in length: {} frequencies, {} decay rates, {} amplitudes, {} phases",
        n,
        bank.decay_rates.len(),
        bank.amplitudes.len(),
        bank.phases.len()
    );
    let n_samples = (duration_s * sample_rate).round();
    let n_samples = if n_samples.is_finite() && n_samples > 0.0 {
        n_samples as usize
    } else {
        0
    };
    let mut out = vec![0.0; n_samples];
    let nyquist = 0.5 * sample_rate;
    for k in 0..n {
        let mode = Mode {
            freq: bank.frequencies_hz[k],
            decay: bank.decay_rates[k],
            amplitude: bank.amplitudes[k],
            phase: bank.phases[k],
            sample_rate,
        };
        // Written as a negated range test so NaN frequencies are skipped too.
        if !(mode.freq > 0.0 && mode.freq < nyquist) || mode.amplitude == 0.0 {
            continue;
        }
        mode.add_to(&mut out);
    }
    out
}

/// One damped sinusoid at a given sample rate.
struct Mode {
    freq: f64,
    decay: f64,
    amplitude: f64,
    phase: f64,
    sample_rate: f64,
}

impl Mode {
    /// a e^(iφ) rⁿ evaluated directly, as (re, im).
    fn z_at(&self, n: usize) -> (f64, f64) {
        let angle = 2.0 * std::f64::consts::PI * cycles_mod_one(self.freq, self.sample_rate, n)
            + self.phase;
        let envelope = self.amplitude * (-self.decay * (n as f64 / self.sample_rate)).exp();
        let (s, c) = angle.sin_cos();
        (envelope * c, envelope * s)
    }

    /// The per-sample ratio r = e^((−d + i 2π f)/f_s), as (re, im).
    fn ratio(&self) -> (f64, f64) {
        let angle = 2.0 * std::f64::consts::PI * cycles_mod_one(self.freq, self.sample_rate, 1);
        let m = (-self.decay / self.sample_rate).exp();
        let (s, c) = angle.sin_cos();
        (m * c, m * s)
    }

    fn add_to(&self, out: &mut [f64]) {
        let (r_re, r_im) = self.ratio();
        for (block, chunk) in out.chunks_mut(REANCHOR_INTERVAL).enumerate() {
            let (mut re, mut im) = self.z_at(block * REANCHOR_INTERVAL);
            // Once the envelope has underflowed nothing more can be added.
            if re == 0.0 && im == 0.0 {
                break;
            }
            for s in chunk.iter_mut() {
                *s += im;
                let next_re = re * r_re - im * r_im;
                im = re * r_im + im * r_re;
                re = next_re;
            }
        }
    }
}

/// f·n/f_s modulo 1, in [−0.5, 0.5], accurate to ~1e-16 absolute for any n
/// below 2^53. Plain `f * n / fs` loses about log10(f n/f_s) digits of the
/// phase, i.e. ~1e-9 rad after a minute at 20 kHz; here the quotient f/f_s and
/// the product with n are carried as unevaluated sums hi + lo (error-free
/// transformations via fused multiply-add).
fn cycles_mod_one(freq: f64, sample_rate: f64, n: usize) -> f64 {
    let c_hi = freq / sample_rate;
    // Exact remainder of the division, then its share of the quotient.
    let c_lo = (-c_hi).mul_add(sample_rate, freq) / sample_rate;
    let n = n as f64;
    let p_hi = n * c_hi;
    let p_lo = n.mul_add(c_hi, -p_hi) + n * c_lo;
    // p_hi − round(p_hi) is exact: both are within one ulp-scale of each other.
    (p_hi - p_hi.round()) + p_lo
}

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
    // hound checks the RIFF size limit only when the header is finalised;
    // failing here gives the clearer message and writes nothing.
    let bytes = samples.len() as u64 * u64::from(spec.bits_per_sample / 8);
    if bytes > u64::from(u32::MAX) - 64 {
        return Err(AudioError::InvalidInput {
            path: tmp.to_path_buf(),
            reason: format!("{} samples exceed the 4 GiB WAV size limit", samples.len()),
        });
    }
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
/// files are accepted; a truncated or corrupt file is an error, never a panic.
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
    let frames = interleaved.len() / n_channels;
    let mut channels = vec![Vec::with_capacity(frames); n_channels];
    for frame in interleaved.chunks_exact(n_channels) {
        for (channel, &s) in channels.iter_mut().zip(frame) {
            channel.push(s);
        }
    }
    Ok((channels, spec.sample_rate))
}

#[cfg(test)]
mod tests;
