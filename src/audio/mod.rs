//! Sound from modes, and sound compared with sound.
//!
//! | module        | what it does |
//! |---------------|--------------|
//! | [`synth`]     | exact discrete-time damped-sinusoid synthesis and its gradient |
//! | [`excitation`]| strike amplitudes and phases: mode shape at the impact × contact-force spectrum |
//! | [`chain`]     | eigenvalues + damping model → frequencies, decays, amplitudes, and back (gradients) |
//! | [`noise`]     | time-varying filtered noise (LTV-FIR) and its gradient |
//! | [`stft`]      | magnitude spectrograms and their gradient |
//! | [`loss`]      | multi-scale spectral loss, 1-D optimal-transport loss, hybrid schedule |
//! | [`resample`], [`onset`], [`recording`] | recordings: rate conversion, onset, trim, gain |
//! | WAV           | [`read_wav`], [`write_wav`] |

pub mod chain;
pub mod excitation;
pub mod loss;
pub mod noise;
pub mod onset;
pub mod recording;
pub mod resample;
pub mod stft;
pub mod synth;
mod wav;
pub use synth::{damped_frequency, rayleigh_decay, render, ModalBank, REANCHOR_INTERVAL};
pub use wav::{read_wav, write_wav, AudioError, WavFormat};

#[cfg(test)]
mod tests;
