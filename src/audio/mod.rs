//! Sound from modes, and sound compared with sound.
//!
//! | module        | what it does |
//! |---------------|--------------|
//! | [`synth`]     | exact discrete-time damped-sinusoid synthesis and its gradient |
//! | [`excitation`]| strike amplitudes and phases: mode shape at the impact × contact-force spectrum |
//! | [`chain`]     | eigenvalues + damping model → frequencies, decays, amplitudes, and back (gradients) |
//! | [`noise`]     | time-varying filtered noise (LTV-FIR) and its gradient |
//! | [`radiation`] | acoustic transfer of a mode: multipole fit to the surface motion, pressure at microphones, power |
//! | [`stft`]      | magnitude spectrograms and their gradient |
//! | [`loss`]      | multi-scale spectral loss, 1-D optimal-transport loss, hybrid schedule |
//! | [`resample`] | rate conversion (onset, trim and gain of a recording are in [`crate::analysis`]) |
//! | WAV           | [`read_wav`], [`write_wav`] |

pub mod chain;
pub mod excitation;
pub mod health;
pub mod loss;
pub mod noise;
pub mod radiation;
pub mod resample;
pub mod stft;
pub mod synth;
mod wav;
pub use synth::{damped_frequency, rayleigh_decay, render, ModalBank, REANCHOR_INTERVAL};
pub use wav::{read_wav, write_wav, AudioError, WavFormat};

/// What is wrong with a set of channels that should be one strike recorded in parallel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum ChannelFault {
    NoChannels,
    LengthMismatch {
        channel: usize,
        len: usize,
        expected: usize,
    },
    NonFiniteSample {
        channel: usize,
        index: usize,
        value: f64,
    },
}

/// The common length of `signals`, or the first fault: no channels, a channel whose length
/// differs from channel 0's, or a non-finite sample. Each caller maps the fault into its own
/// error type.
pub(crate) fn check_parallel_channels(signals: &[&[f64]]) -> Result<usize, ChannelFault> {
    let n = signals.first().ok_or(ChannelFault::NoChannels)?.len();
    for (channel, s) in signals.iter().enumerate() {
        if s.len() != n {
            return Err(ChannelFault::LengthMismatch {
                channel,
                len: s.len(),
                expected: n,
            });
        }
        if let Some(index) = s.iter().position(|v| !v.is_finite()) {
            return Err(ChannelFault::NonFiniteSample {
                channel,
                index,
                value: s[index],
            });
        }
    }
    Ok(n)
}

/// Root mean square of `x` (0 for an empty slice).
pub fn rms(x: &[f64]) -> f64 {
    if x.is_empty() {
        return 0.0;
    }
    (x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64).sqrt()
}

/// Σ a_i b_i for two slices of equal length, with four independent partial sums so the compiler
/// keeps four multiply-add chains in flight (a single running sum serialises them). Used by
/// the resampler's and the filtered-noise kernels' inner loops.
pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut partial = [0.0f64; 4];
    let chunks_a = a.chunks_exact(4);
    let chunks_b = b.chunks_exact(4);
    let tail: f64 = chunks_a
        .remainder()
        .iter()
        .zip(chunks_b.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (ca, cb) in chunks_a.zip(chunks_b) {
        for lane in 0..4 {
            partial[lane] += ca[lane] * cb[lane];
        }
    }
    (partial[0] + partial[1]) + (partial[2] + partial[3]) + tail
}

#[cfg(test)]
mod tests;
