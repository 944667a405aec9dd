//! Magnitude spectrograms and their exact gradient.
//!
//! For a signal x[n] (n = 0 … len−1, zero outside), FFT size N (even) and hop H, frame t
//! (t = 0 … T−1, T = ⌊len/H⌋ + 1) is centred on sample t·H:
//!
//! X[t,k] = Σ_{j=0}^{N−1} w[j] · x[t·H + j − N/2] · e^(−2πi jk/N),   k = 0 … N/2
//!
//! with the periodic Hann window w[j] = ½ − ½ cos(2πj/N), and no normalisation (X has the
//! units of x). The magnitude is S[t,k] = |X[t,k]|; bin k is at k·f_s/N Hz and frame t at
//! t·H/f_s s. This equals `torch.stft(pad(x, N/2), N, H, hann_window(N), center=False)`.
//!
//! # Gradient
//!
//! Given G[t,k] = dL/dS[t,k], with c = G/S (0 where S = 0, as |·| has no slope there):
//!
//! dL/dx[t·H + j − N/2] += w[j] · Re( Σ_{k=0}^{N/2} c[t,k] · conj(X[t,k]) · e^(−2πi jk/N) )
//!
//! since dS/dx = w·(Re X cos θ − Im X sin θ)/S = w·Re(conj(X) e^(−iθ))/S, θ = 2πjk/N. The inner
//! sum is one forward FFT of length N of the half spectrum padded with zeros, so the backward
//! pass costs one FFT per frame, like the forward one.

use rustfft::num_complex::Complex64;
use rustfft::{Fft, FftPlanner};
use std::sync::Arc;

/// A magnitude spectrogram, frames × bins, row-major, with the complex values kept for the
/// backward pass.
#[derive(Clone, Debug)]
pub struct Spectrogram {
    pub n_fft: usize,
    pub hop: usize,
    pub n_frames: usize,
    /// N/2 + 1.
    pub n_bins: usize,
    /// S[t·n_bins + k].
    pub magnitude: Vec<f64>,
    complex: Vec<Complex64>,
}

impl Spectrogram {
    /// The magnitudes of frame t.
    pub fn frame(&self, t: usize) -> &[f64] {
        &self.magnitude[t * self.n_bins..(t + 1) * self.n_bins]
    }

    /// 20·log10(S / reference), floored at `floor_db`, for plotting.
    pub fn decibels(&self, reference: f64, floor_db: f64) -> Vec<f64> {
        self.magnitude
            .iter()
            .map(|&s| {
                let db = 20.0 * (s / reference).log10();
                if db.is_finite() {
                    db.max(floor_db)
                } else {
                    floor_db
                }
            })
            .collect()
    }
}

/// A reusable short-time Fourier transform of fixed size and hop.
#[derive(Clone)]
pub struct StftPlan {
    n_fft: usize,
    hop: usize,
    window: Vec<f64>,
    fft: Arc<dyn Fft<f64>>,
}

impl std::fmt::Debug for StftPlan {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "StftPlan {{ n_fft: {}, hop: {} }}", self.n_fft, self.hop)
    }
}

/// Why a transform cannot be set up.
#[derive(thiserror::Error, Debug, Clone, PartialEq)]
pub enum StftError {
    #[error("FFT size {0} must be even and at least 4")]
    FftSize(usize),
    #[error("hop {hop} must lie in 1..={n_fft}")]
    Hop { hop: usize, n_fft: usize },
    #[error("the target is silent: a relative spectrogram error is undefined")]
    SilentTarget,
}

impl StftPlan {
    pub fn new(n_fft: usize, hop: usize) -> Result<StftPlan, StftError> {
        if n_fft < 4 || n_fft % 2 != 0 {
            return Err(StftError::FftSize(n_fft));
        }
        if hop == 0 || hop > n_fft {
            return Err(StftError::Hop { hop, n_fft });
        }
        let window = (0..n_fft)
            .map(|j| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * j as f64 / n_fft as f64).cos())
            .collect();
        let fft = FftPlanner::new().plan_fft_forward(n_fft);
        Ok(StftPlan {
            n_fft,
            hop,
            window,
            fft,
        })
    }

    pub fn n_fft(&self) -> usize {
        self.n_fft
    }

    pub fn hop(&self) -> usize {
        self.hop
    }

    /// Frames for a signal of `len` samples: ⌊len/H⌋ + 1.
    pub fn n_frames(&self, len: usize) -> usize {
        len / self.hop + 1
    }

    /// The spectrogram of `x` (see the module docs).
    pub fn forward(&self, x: &[f64]) -> Spectrogram {
        let n = self.n_fft;
        let n_bins = n / 2 + 1;
        let n_frames = self.n_frames(x.len());
        let mut complex = vec![Complex64::new(0.0, 0.0); n_frames * n_bins];
        let mut buffer = vec![Complex64::new(0.0, 0.0); n];
        let mut scratch = vec![Complex64::new(0.0, 0.0); self.fft.get_inplace_scratch_len()];
        // Two real frames per complex FFT: z = a + ib gives A_k = (Z_k + conj Z_(N−k))/2 and
        // B_k = (Z_k − conj Z_(N−k))/(2i).
        for t in (0..n_frames).step_by(2) {
            let second = t + 1 < n_frames;
            for (j, b) in buffer.iter_mut().enumerate() {
                let re = self.windowed_sample(x, t, j);
                let im = if second {
                    self.windowed_sample(x, t + 1, j)
                } else {
                    0.0
                };
                *b = Complex64::new(re, im);
            }
            self.fft.process_with_scratch(&mut buffer, &mut scratch);
            for k in 0..n_bins {
                let z = buffer[k];
                let zc = buffer[(n - k) % n].conj();
                complex[t * n_bins + k] = (z + zc) * 0.5;
                if second {
                    let d = z - zc;
                    complex[(t + 1) * n_bins + k] = Complex64::new(0.5 * d.im, -0.5 * d.re);
                }
            }
        }
        let magnitude = complex.iter().map(|c| c.norm()).collect();
        Spectrogram {
            n_fft: n,
            hop: self.hop,
            n_frames,
            n_bins,
            magnitude,
            complex,
        }
    }

    /// w[j] · x[t·H + j − N/2], zero outside the signal.
    #[inline]
    fn windowed_sample(&self, x: &[f64], t: usize, j: usize) -> f64 {
        let i = (t * self.hop + j).wrapping_sub(self.n_fft / 2);
        if i < x.len() {
            self.window[j] * x[i]
        } else {
            0.0
        }
    }

    /// Adds dL/dx to `grad_signal` (length = the signal's) given dL/dS for the spectrogram
    /// `spec` that [`Self::forward`] made from that signal.
    ///
    /// # Panics
    /// If `grad_magnitude` does not match `spec` or `spec` does not come from this plan and a
    /// signal of `grad_signal.len()` samples.
    pub fn backward(&self, spec: &Spectrogram, grad_magnitude: &[f64], grad_signal: &mut [f64]) {
        let n = self.n_fft;
        assert_eq!(spec.n_fft, n, "spectrogram from another FFT size");
        assert_eq!(
            spec.n_frames,
            self.n_frames(grad_signal.len()),
            "spectrogram of another length"
        );
        assert_eq!(
            grad_magnitude.len(),
            spec.magnitude.len(),
            "one gradient per magnitude"
        );
        let n_bins = spec.n_bins;
        let mut buffer = vec![Complex64::new(0.0, 0.0); n];
        let mut scratch = vec![Complex64::new(0.0, 0.0); self.fft.get_inplace_scratch_len()];
        // Y_k = c_k conj(X_k) on the half spectrum. Re Σ_k Y_k e^(−iθ) equals Σ over the full
        // circle of the Hermitian extension Ỹ (Ỹ_0 = Re Y_0, Ỹ_(N/2) = Re Y_(N/2),
        // Ỹ_k = Y_k/2 and Ỹ_(N−k) = conj(Y_k)/2 otherwise), whose transform is real; so the
        // transform of Ỹ_a + iỸ_b carries frame a in its real part and frame b in its
        // imaginary part.
        let half_spectrum = |t: usize, k: usize| -> Complex64 {
            let i = t * n_bins + k;
            let s = spec.magnitude[i];
            if s > 0.0 && grad_magnitude[i] != 0.0 {
                spec.complex[i].conj() * (grad_magnitude[i] / s)
            } else {
                Complex64::new(0.0, 0.0)
            }
        };
        let i_unit = Complex64::new(0.0, 1.0);
        for t in (0..spec.n_frames).step_by(2) {
            let second = t + 1 < spec.n_frames;
            buffer
                .iter_mut()
                .for_each(|b| *b = Complex64::new(0.0, 0.0));
            for (frame, factor) in [(t, Complex64::new(1.0, 0.0)), (t + 1, i_unit)] {
                if frame == t + 1 && !second {
                    break;
                }
                for k in 0..n_bins {
                    let y = half_spectrum(frame, k);
                    if k == 0 || k == n / 2 {
                        buffer[k] += factor * y.re;
                    } else {
                        buffer[k] += factor * y * 0.5;
                        buffer[n - k] += factor * y.conj() * 0.5;
                    }
                }
            }
            self.fft.process_with_scratch(&mut buffer, &mut scratch);
            for (frame, second_part) in [(t, false), (t + 1, true)] {
                if second_part && !second {
                    break;
                }
                let origin = (frame * self.hop).wrapping_sub(n / 2);
                for (j, b) in buffer.iter().enumerate() {
                    let i = origin.wrapping_add(j);
                    if i < grad_signal.len() {
                        grad_signal[i] += self.window[j] * if second_part { b.im } else { b.re };
                    }
                }
            }
        }
    }
}

/// FFT size and hop of [`spectrogram_error`], the figure reported by the fits and benchmarks.
pub const SPECTROGRAM_ERROR_FFT: usize = 2048;
pub const SPECTROGRAM_ERROR_HOP: usize = 512;

/// Relative spectrogram error of `prediction` against `target`:
///
/// e = Σ_{t,k} | |P[t,k]| − |T[t,k]| | / Σ_{t,k} |T[t,k]|
///
/// over linear STFT magnitudes (Hann, N = [`SPECTROGRAM_ERROR_FFT`], H = [`SPECTROGRAM_ERROR_HOP`],
/// module conventions), on the common length of the two signals. 0 is a perfect match; silence
/// scores 1; a prediction with the target's energy in the wrong bins scores up to 2. It does not
/// depend on the overall level of the target, but it does on the prediction's level, so fits
/// report it after their own gain. Multichannel figures are the mean over channels.
pub fn spectrogram_error(prediction: &[f64], target: &[f64]) -> Result<f64, StftError> {
    let len = prediction.len().min(target.len());
    let plan = StftPlan::new(SPECTROGRAM_ERROR_FFT, SPECTROGRAM_ERROR_HOP)?;
    let p = plan.forward(&prediction[..len]);
    let t = plan.forward(&target[..len]);
    let norm: f64 = t.magnitude.iter().sum();
    if norm <= 0.0 {
        return Err(StftError::SilentTarget);
    }
    Ok(p.magnitude
        .iter()
        .zip(&t.magnitude)
        .map(|(a, b)| (a - b).abs())
        .sum::<f64>()
        / norm)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn test_signal(len: usize, seed: u64) -> Vec<f64> {
        let mut rng = crate::testing::Rng(seed);
        (0..len)
            .map(|i| {
                (0.05 * i as f64).sin() * (-(i as f64) / 300.0).exp() + 0.1 * rng.uniform(-0.5, 0.5)
            })
            .collect()
    }

    #[test]
    fn a_bin_centred_sine_peaks_in_its_bin_with_the_hann_gain() {
        let (n, fs) = (256, 8000.0);
        let plan = StftPlan::new(n, 64).unwrap();
        let k0 = 20;
        let f = k0 as f64 * fs / n as f64;
        let x: Vec<f64> = (0..4096)
            .map(|i| (2.0 * std::f64::consts::PI * f * i as f64 / fs).sin())
            .collect();
        let s = plan.forward(&x);
        assert_eq!(s.n_frames, 4096 / 64 + 1);
        // An interior frame: |X| = A·Σw/2 = N/4 for the periodic Hann window.
        let frame = s.frame(30);
        let peak = (0..s.n_bins)
            .max_by(|&a, &b| frame[a].total_cmp(&frame[b]))
            .unwrap();
        assert_eq!(peak, k0);
        assert!((frame[k0] - n as f64 / 4.0).abs() < 1e-9 * n as f64);
        // Hann leaks only into the neighbouring bins for a bin-centred tone.
        assert!(frame[k0 + 3] < 1e-9 * n as f64);
    }

    #[test]
    fn backward_matches_finite_differences() {
        let plan = StftPlan::new(64, 16).unwrap();
        let x = test_signal(200, 3);
        let spec = plan.forward(&x);
        // L = Σ G ⊙ S with a fixed random G.
        let g = test_signal(spec.magnitude.len(), 9);
        let loss = |x: &[f64]| -> f64 {
            plan.forward(x)
                .magnitude
                .iter()
                .zip(&g)
                .map(|(s, g)| s * g)
                .sum()
        };
        let mut grad = vec![0.0; x.len()];
        plan.backward(&spec, &g, &mut grad);
        let h = 1e-6;
        let mut worst: f64 = 0.0;
        for i in [0, 1, 31, 32, 33, 100, 150, 198, 199] {
            let mut xp = x.clone();
            xp[i] += h;
            let mut xm = x.clone();
            xm[i] -= h;
            let fd = (loss(&xp) - loss(&xm)) / (2.0 * h);
            worst = worst.max((fd - grad[i]).abs() / grad[i].abs().max(1e-3));
        }
        assert!(worst < 1e-6, "worst relative error {worst}");
    }

    #[test]
    fn bad_sizes_are_errors() {
        assert_eq!(StftPlan::new(63, 16).unwrap_err(), StftError::FftSize(63));
        assert_eq!(StftPlan::new(2, 1).unwrap_err(), StftError::FftSize(2));
        assert!(matches!(StftPlan::new(64, 0), Err(StftError::Hop { .. })));
        assert!(matches!(StftPlan::new(64, 65), Err(StftError::Hop { .. })));
    }

    #[test]
    fn spectrogram_error_scores_match_silence_and_level() {
        let x = test_signal(8000, 3);
        assert_eq!(spectrogram_error(&x, &x).unwrap(), 0.0);
        assert!((spectrogram_error(&vec![0.0; 8000], &x).unwrap() - 1.0).abs() < 1e-12);
        let half: Vec<f64> = x.iter().map(|v| 0.5 * v).collect();
        assert!((spectrogram_error(&half, &x).unwrap() - 0.5).abs() < 1e-12);
        assert!(matches!(
            spectrogram_error(&x, &vec![0.0; 8000]),
            Err(StftError::SilentTarget)
        ));
    }
}
