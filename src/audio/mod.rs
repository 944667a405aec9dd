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

pub mod noise;
pub mod onset;
pub mod recording;
pub mod resample;
mod wav;
pub use wav::{read_wav, write_wav, AudioError, WavFormat};

#[cfg(test)]
mod tests;
