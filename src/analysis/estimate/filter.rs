//! Band extraction: complex demodulation, a Kaiser-windowed-sinc low-pass and decimation
//! (equations in the parent module's docs, "Sub-bands").

use nalgebra::Complex;

pub(crate) type C64 = Complex<f64>;

/// The shared low-pass of every band and the decimation after it.
#[derive(Clone, Debug)]
pub(crate) struct Decimator {
    /// h[0..T), symmetric, unity gain at DC.
    pub taps: Vec<f64>,
    /// D: one output every D input samples.
    pub factor: usize,
    /// Σ h[j]²: the variance gain of the filter for white noise.
    pub noise_gain: f64,
}

impl Decimator {
    /// Outputs y[0..n) obtainable from `n_samples` inputs: y[m] needs x[mD .. mD + T).
    pub fn outputs(&self, n_samples: usize) -> usize {
        if n_samples < self.taps.len() {
            0
        } else {
            (n_samples - self.taps.len()) / self.factor + 1
        }
    }

    /// Samples of the input that [`Self::outputs`] outputs read.
    pub fn inputs_used(&self, n_out: usize) -> usize {
        if n_out == 0 {
            0
        } else {
            (n_out - 1) * self.factor + self.taps.len()
        }
    }

    /// The decimated complex baseband of `x` around `centre_hz`:
    /// y[m] = Σ_j h[j] x[mD + j] e^(−i ω_c (mD + j)), m = 0 … n_out − 1, with `phasor` holding
    /// e^(−i ω_c n) for every input sample used. The filter looks forward (anti-causal), so y[m]
    /// belongs to time mD and the first output is at the start of the signal.
    pub fn baseband(&self, x: &[f64], phasor: &[C64], n_out: usize) -> Vec<C64> {
        let used = self.inputs_used(n_out);
        // Demodulate once; each input sample is read by about T/D outputs.
        let shifted: Vec<C64> = x[..used]
            .iter()
            .zip(&phasor[..used])
            .map(|(&v, p)| p * v)
            .collect();
        (0..n_out)
            .map(|m| {
                let start = m * self.factor;
                let window = &shifted[start..start + self.taps.len()];
                let (mut re, mut im) = (0.0, 0.0);
                for (h, s) in self.taps.iter().zip(window) {
                    re += h * s.re;
                    im += h * s.im;
                }
                C64::new(re, im)
            })
            .collect()
    }

    /// H(ζ) = Σ_j h[j] ζ^j: the gain that a component ζⁿ of the (demodulated) input
    /// picks up in the forward-looking filter.
    pub fn response(&self, zeta: C64) -> C64 {
        // Horner from the last tap; |ζ| ≤ 1 for decaying components so nothing overflows.
        self.taps
            .iter()
            .rev()
            .fold(C64::new(0.0, 0.0), |acc, &h| acc * zeta + h)
    }
}

/// e^(−i 2π f n / f_s) for n = 0 … n − 1. The phase is taken modulo one cycle before the
/// sine and cosine, so it is exact to rounding for every n (no drifting recursion).
pub(super) fn phasor(freq_hz: f64, sample_rate: f64, n: usize) -> Vec<C64> {
    let cycles_per_sample = freq_hz / sample_rate;
    (0..n)
        .map(|k| {
            let turns = (cycles_per_sample * k as f64).fract();
            let (s, c) = (-2.0 * std::f64::consts::PI * turns).sin_cos();
            C64::new(c, s)
        })
        .collect()
}

/// Kaiser-windowed-sinc low-pass: cutoff (−6 dB point) `cutoff_hz`, transition width
/// `transition_hz` (pass edge to stop edge) and stop-band attenuation `stopband_db`, at
/// `sample_rate`. Length and window shape from Kaiser's empirical formulas:
/// T = ⌈(A − 7.95) / (2.285 · 2π Δf / f_s)⌉ + 1 (made odd), β = 0.1102 (A − 8.7) for A > 50.
pub(crate) fn kaiser_lowpass(
    cutoff_hz: f64,
    transition_hz: f64,
    stopband_db: f64,
    sample_rate: f64,
) -> Vec<f64> {
    let dw = 2.0 * std::f64::consts::PI * transition_hz / sample_rate;
    let mut len = ((stopband_db - 7.95) / (2.285 * dw)).ceil().max(1.0) as usize + 1;
    len |= 1; // odd, so the centre tap is a sample
    let beta = if stopband_db > 50.0 {
        0.1102 * (stopband_db - 8.7)
    } else if stopband_db >= 21.0 {
        0.5842 * (stopband_db - 21.0).powf(0.4) + 0.07886 * (stopband_db - 21.0)
    } else {
        0.0
    };
    let centre = (len - 1) as f64 / 2.0;
    let fc = cutoff_hz / sample_rate; // cycles per sample
    let i0_beta = bessel_i0(beta);
    let mut taps: Vec<f64> = (0..len)
        .map(|j| {
            let t = j as f64 - centre;
            let sinc = if t == 0.0 {
                2.0 * fc
            } else {
                (2.0 * std::f64::consts::PI * fc * t).sin() / (std::f64::consts::PI * t)
            };
            let r = t / centre.max(1.0);
            let window = bessel_i0(beta * (1.0 - r * r).max(0.0).sqrt()) / i0_beta;
            sinc * window
        })
        .collect();
    // Unity gain at DC, so a component in the pass band keeps its amplitude.
    let sum: f64 = taps.iter().sum();
    for h in &mut taps {
        *h /= sum;
    }
    taps
}

/// Modified Bessel function I₀(x) by its power series Σ ((x/2)^k / k!)², which converges for
/// every x; the Kaiser window needs x ≤ β ≈ 10, where ~40 terms suffice.
fn bessel_i0(x: f64) -> f64 {
    let q = 0.25 * x * x;
    let mut term = 1.0;
    let mut sum = 1.0;
    for k in 1..500 {
        term *= q / (k as f64 * k as f64);
        sum += term;
        if term < 1e-17 * sum {
            break;
        }
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;

    /// |H(e^{iω})| of a real filter at frequency f.
    fn gain(taps: &[f64], f_hz: f64, fs: f64) -> f64 {
        let w = 2.0 * std::f64::consts::PI * f_hz / fs;
        let (mut re, mut im) = (0.0, 0.0);
        for (j, h) in taps.iter().enumerate() {
            re += h * (w * j as f64).cos();
            im += h * (w * j as f64).sin();
        }
        (re * re + im * im).sqrt()
    }

    #[test]
    fn bessel_matches_reference_values() {
        // I0(1) = 1.2660658777520082, I0(10) = 2815.716628466254 (tabulated).
        assert!((bessel_i0(0.0) - 1.0).abs() < 1e-16);
        assert!((bessel_i0(1.0) - 1.266_065_877_752_008_2).abs() < 1e-14);
        assert!((bessel_i0(10.0) / 2_815.716_628_466_254 - 1.0).abs() < 1e-13);
    }

    #[test]
    fn kaiser_lowpass_meets_its_specification() {
        let fs = 48_000.0;
        let taps = kaiser_lowpass(1250.0, 500.0, 90.0, fs);
        assert_eq!(taps.len() % 2, 1);
        // Pass band (≤ 1000 Hz) flat to 1e-4, stop band (≥ 1500 Hz) below −88 dB.
        for k in 0..=100 {
            let f = 10.0 * k as f64;
            assert!(
                (gain(&taps, f, fs) - 1.0).abs() < 1e-4,
                "pass band {f} Hz: {}",
                gain(&taps, f, fs)
            );
        }
        let mut worst: f64 = 0.0;
        for k in 0..2000 {
            let f = 1500.0 + 11.3 * k as f64;
            worst = worst.max(gain(&taps, f, fs));
        }
        assert!(
            20.0 * worst.log10() < -88.0,
            "stop band peak {} dB",
            20.0 * worst.log10()
        );
    }

    #[test]
    fn baseband_of_a_damped_exponential_is_the_predicted_exponential() {
        // x[n] = Im(c zⁿ) → y[m] = (c H(ζ)/(2i)) ζ^{mD}: the model the band analysis relies on
        // (the negative-frequency half lies in the stop band).
        let fs = 48_000.0;
        let (f, d, fc) = (5_230.0, 7.0, 5_000.0);
        let c = C64::new(0.3, -0.8);
        let z = (C64::new(-d, 2.0 * std::f64::consts::PI * f) / fs).exp();
        let n = 6000;
        let x: Vec<f64> = (0..n).map(|k| (c * z.powu(k as u32)).im).collect();
        let dec = Decimator {
            taps: kaiser_lowpass(1250.0, 500.0, 100.0, fs),
            factor: 24,
            noise_gain: 0.0,
        };
        let n_out = dec.outputs(n);
        let y = dec.baseband(&x, &phasor(fc, fs, n), n_out);
        let zeta = z * C64::from_polar(1.0, -2.0 * std::f64::consts::PI * fc / fs);
        let beta = c * dec.response(zeta) / C64::new(0.0, 2.0);
        for (m, ym) in y.iter().enumerate() {
            let want = beta * zeta.powu((m * dec.factor) as u32);
            assert!(
                (ym - want).norm() < 1e-6 * c.norm(),
                "m = {m}: {ym} vs {want}"
            );
        }
    }
}
