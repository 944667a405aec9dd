//! Losses between a rendered signal x and a target y, each with its exact gradient dL/dx.
//!
//! Spectrograms S = |STFT| are those of [`super::stft`] (periodic Hann window, frames centred
//! on t·H with zero padding, no normalisation).
//!
//! # Multi-scale spectral loss
//!
//! For each FFT size N in `fft_sizes` (default 2048, 1024, 512, 256, 128, 64) with hop
//! H = N·`hop_fraction` (default ¼):
//!
//! L_N = w_lin · mean_{t,k} |S_x − S_y| + w_log · mean_{t,k} |ln(S_x + ε) − ln(S_y + ε)|
//!
//! and L = Σ_N L_N. Defaults w_lin = w_log = 1 and ε_N = `log_epsilon` + `log_epsilon_relative`
//! · max_{t,k} S_y at that FFT size, by default 10⁻⁴ of the target's peak (−80 dB): the
//! dynamic range of a good recording. A much smaller ε (an absolute 10⁻⁷ was our first
//! default, 165–195 dB below the peaks) lets the bins at the nulls of the window's side lobes,
//! S ≈ 10⁻¹⁰, dominate the log term through its slope 1/(S + ε): the loss then becomes rough
//! on a 10⁻⁷ relative scale of the frequencies and finite differences scatter by ~5 %
//! (found by the end-to-end material checks in `tests/mpi_sensitivity.rs`). The means run
//! over all frames and the N/2 + 1 bins. The slope of |·| at 0 is taken as 0.
//!
//! # Optimal-transport loss
//!
//! Where the predicted and the target partials do not overlap in frequency, |S_x − S_y| does
//! not change when a predicted partial moves, so the spectral loss gives no pull towards the
//! target. A transport distance does: moving mass towards where the target has it lowers
//! the cost all the way. We use the exact 1-D Wasserstein-1 distance along frequency, frame
//! by frame:
//!
//! p_k = (S_x[t,k] + ε_p) / Σ_j (S_x[t,j] + ε_p),   q_k likewise for the target,
//! W_t = Σ_{k=0}^{K−2} |P_k − Q_k| (x_(k+1) − x_k),   P_k = Σ_{j≤k} p_j (cumulative)
//!
//! where x_k is the position of bin k: k·f_s/N in Hz on the linear axis (default), or
//! ln max(k·f_s/N, f_floor) on the log axis. On the log axis a change of E, which scales every
//! frequency by the same factor, is a pure translation of the spectrum, so W_t falls
//! steadily as E approaches the target however far it starts.
//!
//! L_OT = Σ_t ω_t W_t,   ω_t = Σ_k S_y[t,k] / Σ_{t,k} S_y   (the target's share of frame t)
//!
//! over the frames that lie wholly inside the signal (t·H − N/2 ≥ 0 and t·H + N/2 ≤ len):
//! a frame that overlaps either end sees the cut as a step whose broadband splatter turns
//! with the phase at the cut, making W_t ripple in f far faster than it drifts.
//!
//! L_OT is in Hz (or nepers on the log axis): the mean distance a unit of spectral mass has to move. ε_p (default 10⁻⁹
//! of the frame's target peak) keeps silent frames defined. ω_t depends on the target only,
//! so quiet target frames weigh little and carry no gradient of their own.
//!
//! Why not a Sinkhorn divergence: along one axis the optimal plan is the monotone
//! rearrangement, so W1 is exact in O(K) per frame through cumulative sums, with no blur
//! (entropic) parameter to tune, no inner iterations, and a gradient that is exact, not an
//! approximation to the unregularised one. Transport across time is not wanted: partials of a
//! strike all start at the onset, and their time structure is left to the spectral loss.
//!
//! Gradient: dL/dP_k = ω_t (x_(k+1) − x_k) sign(P_k − Q_k); dL/dp_j = Σ_{k ≥ j, k ≤ K−2} dL/dP_k (a suffix
//! sum); with Z = Σ_j (S_j + ε_p), dL/dS_i = (dL/dp_i − Σ_j p_j dL/dp_j) / Z.
//!
//! # Hybrid schedule
//!
//! [`HybridSchedule`] starts on the transport loss, which gets partials to the right place,
//! and switches once, for good, to the spectral loss, which then matches magnitudes and
//! decays, when the transport loss has not improved by a relative `min_improvement` over its
//! best for `patience` consecutive steps.

use super::stft::{Spectrogram, StftError, StftPlan};

/// Why a loss cannot be set up or evaluated.
#[derive(thiserror::Error, Debug, Clone, PartialEq)]
pub enum LossError {
    #[error("{0}")]
    Stft(#[from] StftError),
    #[error("the signal has {got} samples but the target has {expected}")]
    Length { got: usize, expected: usize },
    #[error("the target is empty")]
    EmptyTarget,
    #[error("the target contains a non-finite sample at index {0}")]
    NonFinite(usize),
    #[error("invalid loss setting: {0}")]
    Setting(String),
}

/// Settings of [`MultiScaleSpectralLoss`]; see the module docs.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SpectralLossConfig {
    pub fft_sizes: Vec<usize>,
    pub hop_fraction: f64,
    pub linear_weight: f64,
    pub log_weight: f64,
    /// Absolute part of ε (units of S).
    pub log_epsilon: f64,
    /// Part of ε relative to the target's largest magnitude at each FFT size.
    pub log_epsilon_relative: f64,
}

impl Default for SpectralLossConfig {
    fn default() -> Self {
        SpectralLossConfig {
            fft_sizes: vec![2048, 1024, 512, 256, 128, 64],
            hop_fraction: 0.25,
            linear_weight: 1.0,
            log_weight: 1.0,
            log_epsilon: 0.0,
            log_epsilon_relative: 1e-4,
        }
    }
}

/// Settings of [`TransportLoss`]; see the module docs.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TransportLossConfig {
    pub fft_size: usize,
    pub hop_fraction: f64,
    /// ε_p relative to the target's peak magnitude in that frame.
    pub relative_floor: f64,
    /// The ground distance along frequency: `linear` (Hz) or `log` (ln f, nepers; bins below
    /// `log_floor_hz` sit at ln of it).
    pub axis: FrequencyAxis,
    pub log_floor_hz: f64,
}

/// How [`TransportLoss`] measures distance along frequency.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FrequencyAxis {
    Linear,
    Log,
}

impl Default for TransportLossConfig {
    fn default() -> Self {
        TransportLossConfig {
            fft_size: 2048,
            hop_fraction: 0.25,
            relative_floor: 1e-9,
            axis: FrequencyAxis::Linear,
            log_floor_hz: 20.0,
        }
    }
}

fn hop_of(n_fft: usize, fraction: f64) -> Result<usize, LossError> {
    if !(fraction > 0.0 && fraction <= 1.0) {
        return Err(LossError::Setting(format!(
            "hop_fraction {fraction} must lie in (0, 1]"
        )));
    }
    Ok(((n_fft as f64 * fraction).round() as usize).max(1))
}

fn check_target(target: &[f64]) -> Result<(), LossError> {
    if target.is_empty() {
        return Err(LossError::EmptyTarget);
    }
    if let Some(i) = target.iter().position(|v| !v.is_finite()) {
        return Err(LossError::NonFinite(i));
    }
    Ok(())
}

/// sign with sign(0) = 0, the slope |·| is given at its kink.
fn sign(v: f64) -> f64 {
    if v > 0.0 {
        1.0
    } else if v < 0.0 {
        -1.0
    } else {
        0.0
    }
}

/// The multi-scale spectral loss against a fixed target (see the module docs).
#[derive(Clone, Debug)]
pub struct MultiScaleSpectralLoss {
    config: SpectralLossConfig,
    plans: Vec<StftPlan>,
    targets: Vec<Spectrogram>,
    epsilons: Vec<f64>,
    target_len: usize,
}

impl MultiScaleSpectralLoss {
    pub fn new(target: &[f64], config: SpectralLossConfig) -> Result<Self, LossError> {
        check_target(target)?;
        if config.fft_sizes.is_empty() {
            return Err(LossError::Setting("fft_sizes is empty".into()));
        }
        for (name, w) in [
            ("linear_weight", config.linear_weight),
            ("log_weight", config.log_weight),
        ] {
            if !(w >= 0.0 && w.is_finite()) {
                return Err(LossError::Setting(format!(
                    "{name} {w} must be a finite number ≥ 0"
                )));
            }
        }
        let eps_ok = |v: f64| v >= 0.0 && v.is_finite();
        if !(eps_ok(config.log_epsilon)
            && eps_ok(config.log_epsilon_relative)
            && config.log_epsilon + config.log_epsilon_relative > 0.0)
        {
            return Err(LossError::Setting(format!(
                "log_epsilon {} and log_epsilon_relative {} must be ≥ 0 and not both 0",
                config.log_epsilon, config.log_epsilon_relative
            )));
        }
        let plans = config
            .fft_sizes
            .iter()
            .map(|&n| StftPlan::new(n, hop_of(n, config.hop_fraction)?).map_err(LossError::from))
            .collect::<Result<Vec<_>, _>>()?;
        let targets: Vec<Spectrogram> = plans.iter().map(|p| p.forward(target)).collect();
        let epsilons = targets
            .iter()
            .map(|t| {
                config.log_epsilon
                    + config.log_epsilon_relative
                        * t.magnitude.iter().fold(0.0_f64, |m, &v| m.max(v))
            })
            .collect::<Vec<f64>>();
        if let Some(i) = epsilons.iter().position(|e| !(*e > 0.0)) {
            return Err(LossError::Setting(format!(
                "the target is silent at FFT size {}: set an absolute log_epsilon",
                config.fft_sizes[i]
            )));
        }
        Ok(MultiScaleSpectralLoss {
            config,
            plans,
            targets,
            epsilons,
            target_len: target.len(),
        })
    }

    pub fn config(&self) -> &SpectralLossConfig {
        &self.config
    }

    pub fn target_len(&self) -> usize {
        self.target_len
    }

    /// L(x).
    pub fn value(&self, x: &[f64]) -> Result<f64, LossError> {
        self.evaluate(x, false).map(|(v, _)| v)
    }

    /// L(x) and dL/dx.
    pub fn value_and_gradient(&self, x: &[f64]) -> Result<(f64, Vec<f64>), LossError> {
        self.evaluate(x, true)
            .map(|(v, g)| (v, g.unwrap_or_default()))
    }

    fn evaluate(
        &self,
        x: &[f64],
        with_gradient: bool,
    ) -> Result<(f64, Option<Vec<f64>>), LossError> {
        if x.len() != self.target_len {
            return Err(LossError::Length {
                got: x.len(),
                expected: self.target_len,
            });
        }
        let scale = |plan: &StftPlan, target: &Spectrogram, eps: f64| -> (f64, Option<Vec<f64>>) {
            let spec = plan.forward(x);
            let count = spec.magnitude.len() as f64;
            let (w_lin, w_log) = (
                self.config.linear_weight / count,
                self.config.log_weight / count,
            );
            let mut value = 0.0;
            let mut grad_mag = if with_gradient {
                vec![0.0; spec.magnitude.len()]
            } else {
                Vec::new()
            };
            for (i, (&s, &y)) in spec.magnitude.iter().zip(&target.magnitude).enumerate() {
                let lin = s - y;
                let log = (s + eps).ln() - (y + eps).ln();
                value += w_lin * lin.abs() + w_log * log.abs();
                if with_gradient {
                    grad_mag[i] = w_lin * sign(lin) + w_log * sign(log) / (s + eps);
                }
            }
            let grad = with_gradient.then(|| {
                let mut g = vec![0.0; x.len()];
                plan.backward(&spec, &grad_mag, &mut g);
                g
            });
            (value, grad)
        };
        // The scales are independent; two threads roughly halve the time on two cores.
        let threads = super::synth::worker_threads().min(self.plans.len()).max(1);
        let results: Vec<(f64, Option<Vec<f64>>)> = if threads == 1 {
            self.plans
                .iter()
                .zip(&self.targets)
                .zip(&self.epsilons)
                .map(|((p, t), &e)| scale(p, t, e))
                .collect()
        } else {
            let jobs: Vec<usize> = balanced_order(&self.config.fft_sizes);
            let per_thread: Vec<Vec<usize>> = (0..threads)
                .map(|r| jobs.iter().copied().skip(r).step_by(threads).collect())
                .collect();
            let mut slots: Vec<Option<(f64, Option<Vec<f64>>)>> = vec![None; self.plans.len()];
            std::thread::scope(|s| {
                let handles: Vec<_> = per_thread
                    .iter()
                    .map(|idx| {
                        let scale = &scale;
                        s.spawn(move || {
                            idx.iter()
                                .map(|&i| {
                                    (i, scale(&self.plans[i], &self.targets[i], self.epsilons[i]))
                                })
                                .collect::<Vec<_>>()
                        })
                    })
                    .collect();
                for h in handles {
                    for (i, r) in h.join().expect("loss worker panicked") {
                        slots[i] = Some(r);
                    }
                }
            });
            slots
                .into_iter()
                .map(|r| r.expect("every scale evaluated"))
                .collect()
        };
        let mut value = 0.0;
        let mut grad = with_gradient.then(|| vec![0.0; x.len()]);
        for (v, g) in results {
            value += v;
            if let (Some(total), Some(g)) = (grad.as_mut(), g) {
                total.iter_mut().zip(&g).for_each(|(a, b)| *a += b);
            }
        }
        Ok((value, grad))
    }
}

/// Scale indices ordered by decreasing cost (N log N · frames ∝ log N), so a round-robin
/// split over threads balances the work.
fn balanced_order(sizes: &[usize]) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..sizes.len()).collect();
    idx.sort_by(|&a, &b| sizes[b].cmp(&sizes[a]));
    idx
}

/// W = Σ_{k<K−1} (x_(k+1) − x_k) |P_k − Q_k| between the distribution p = mass/Σmass (P its
/// cumulative sum) and a target given by its cumulative `q_cdf`, with `spacing[k]` =
/// x_(k+1) − x_k. With `grad`, writes dW/dmass_i = (dW/dp_i − Σ_j p_j dW/dp_j)/Σmass, where
/// dW/dp_j = Σ_{j ≤ k < K−1} spacing[k] sign(P_k − Q_k) (suffix sums of dW/dP). The mass must
/// have a positive total.
fn wasserstein_1d(mass: &[f64], q_cdf: &[f64], spacing: &[f64], grad: Option<&mut [f64]>) -> f64 {
    let n = mass.len();
    let total: f64 = mass.iter().sum();
    let mut value = 0.0;
    let mut cum = 0.0;
    let mut dp = grad;
    for k in 0..n {
        cum += mass[k] / total;
        let slope = if k + 1 < n {
            let diff = cum - q_cdf[k];
            value += spacing[k] * diff.abs();
            spacing[k] * sign(diff)
        } else {
            // The last P is 1 by construction: no slope.
            0.0
        };
        if let Some(d) = dp.as_deref_mut() {
            d[k] = slope;
        }
    }
    if let Some(d) = dp {
        for k in (0..n.saturating_sub(1)).rev() {
            d[k] += d[k + 1];
        }
        let mean: f64 = mass.iter().zip(d.iter()).map(|(m, g)| m / total * g).sum();
        d.iter_mut().for_each(|g| *g = (*g - mean) / total);
    }
    value
}

/// The frame-wise 1-D Wasserstein-1 loss along frequency against a fixed target (see the
/// module docs). Values are in Hz.
#[derive(Clone, Debug)]
pub struct TransportLoss {
    config: TransportLossConfig,
    plan: StftPlan,
    /// Q per frame (cumulative target distribution), frames × bins.
    target_cdf: Vec<f64>,
    frame_weights: Vec<f64>,
    frame_floors: Vec<f64>,
    /// x_(k+1) − x_k: Δf in Hz on the linear axis, Δ ln f on the log axis.
    spacing: Vec<f64>,
    target_len: usize,
}

impl TransportLoss {
    pub fn new(
        target: &[f64],
        sample_rate: f64,
        config: TransportLossConfig,
    ) -> Result<Self, LossError> {
        check_target(target)?;
        if !(sample_rate > 0.0 && sample_rate.is_finite()) {
            return Err(LossError::Setting(format!(
                "sample rate {sample_rate} must be > 0"
            )));
        }
        if !(config.relative_floor > 0.0 && config.relative_floor < 1.0) {
            return Err(LossError::Setting(format!(
                "relative_floor {} must lie in (0, 1)",
                config.relative_floor
            )));
        }
        let plan = StftPlan::new(
            config.fft_size,
            hop_of(config.fft_size, config.hop_fraction)?,
        )?;
        let spec = plan.forward(target);
        let (n_frames, n_bins) = (spec.n_frames, spec.n_bins);
        let total: f64 = spec.magnitude.iter().sum();
        if !(total > 0.0) {
            return Err(LossError::Setting(
                "the target is silent: a transport loss needs some spectral mass".into(),
            ));
        }
        let global_peak = spec.magnitude.iter().fold(0.0_f64, |m, &v| m.max(v));
        let mut target_cdf = Vec::with_capacity(n_frames * n_bins);
        let mut frame_weights = Vec::with_capacity(n_frames);
        let mut frame_floors = Vec::with_capacity(n_frames);
        for t in 0..n_frames {
            let frame = spec.frame(t);
            let peak = frame.iter().fold(0.0_f64, |m, &v| m.max(v));
            // A silent target frame borrows the global peak so its floor stays positive.
            let floor = config.relative_floor * if peak > 0.0 { peak } else { global_peak };
            let z: f64 = frame.iter().map(|s| s + floor).sum();
            let mut cum = 0.0;
            for &s in frame {
                cum += (s + floor) / z;
                target_cdf.push(cum);
            }
            // Only frames wholly inside the signal: a frame that runs past either end sees
            // the cut as a step, whose broadband splatter turns with the phase at the cut
            // (∂phase/∂f = 2πt) and would swamp the transport gradient with ripple.
            let start = (t * plan.hop()) as isize - (config.fft_size / 2) as isize;
            let inside = start >= 0 && start as usize + config.fft_size <= target.len();
            frame_weights.push(if inside {
                frame.iter().sum::<f64>()
            } else {
                0.0
            });
            frame_floors.push(floor);
        }
        let inside_total: f64 = frame_weights.iter().sum();
        if !(inside_total > 0.0) {
            return Err(LossError::Setting(format!(
                "the target has no spectral mass in frames wholly inside it ({} samples, FFT size {}): use a longer signal or a smaller fft_size",
                target.len(),
                config.fft_size
            )));
        }
        frame_weights.iter_mut().for_each(|w| *w /= inside_total);
        if config.axis == FrequencyAxis::Log && !(config.log_floor_hz > 0.0) {
            return Err(LossError::Setting(format!(
                "log_floor_hz {} must be > 0",
                config.log_floor_hz
            )));
        }
        let bin_hz = sample_rate / config.fft_size as f64;
        let position = |k: usize| match config.axis {
            FrequencyAxis::Linear => k as f64 * bin_hz,
            FrequencyAxis::Log => (k as f64 * bin_hz).max(config.log_floor_hz).ln(),
        };
        let spacing = (0..n_bins)
            .map(|k| {
                if k + 1 < n_bins {
                    position(k + 1) - position(k)
                } else {
                    0.0
                }
            })
            .collect();
        Ok(TransportLoss {
            spacing,
            config,
            plan,
            target_cdf,
            frame_weights,
            frame_floors,
            target_len: target.len(),
        })
    }

    pub fn config(&self) -> &TransportLossConfig {
        &self.config
    }

    /// L_OT(x) in Hz.
    pub fn value(&self, x: &[f64]) -> Result<f64, LossError> {
        self.evaluate(x, false).map(|(v, _)| v)
    }

    /// L_OT(x) in Hz and dL/dx.
    pub fn value_and_gradient(&self, x: &[f64]) -> Result<(f64, Vec<f64>), LossError> {
        self.evaluate(x, true)
            .map(|(v, g)| (v, g.unwrap_or_default()))
    }

    fn evaluate(
        &self,
        x: &[f64],
        with_gradient: bool,
    ) -> Result<(f64, Option<Vec<f64>>), LossError> {
        if x.len() != self.target_len {
            return Err(LossError::Length {
                got: x.len(),
                expected: self.target_len,
            });
        }
        let spec = self.plan.forward(x);
        let n_bins = spec.n_bins;
        let mut value = 0.0;
        let mut grad_mag = if with_gradient {
            vec![0.0; spec.magnitude.len()]
        } else {
            Vec::new()
        };
        let mut mass = vec![0.0; n_bins];
        let mut dw = vec![0.0; n_bins];
        for t in 0..spec.n_frames {
            let weight = self.frame_weights[t];
            if weight == 0.0 {
                continue;
            }
            let floor = self.frame_floors[t];
            mass.iter_mut()
                .zip(spec.frame(t))
                .for_each(|(m, s)| *m = s + floor);
            let q_cdf = &self.target_cdf[t * n_bins..(t + 1) * n_bins];
            value += weight
                * wasserstein_1d(
                    &mass,
                    q_cdf,
                    &self.spacing,
                    with_gradient.then_some(&mut dw[..]),
                );
            if with_gradient {
                grad_mag[t * n_bins..(t + 1) * n_bins]
                    .iter_mut()
                    .zip(&dw)
                    .for_each(|(g, d)| *g = weight * d);
            }
        }
        let grad = with_gradient.then(|| {
            let mut g = vec![0.0; x.len()];
            self.plan.backward(&spec, &grad_mag, &mut g);
            g
        });
        Ok((value, grad))
    }
}

/// Settings of [`PeakTransportLoss`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PeakTransportConfig {
    pub fft_size: usize,
    pub hop_fraction: f64,
    /// Levels more than this many dB below the target's peak carry no mass.
    pub range_db: f64,
    /// Bins below this frequency [Hz] sit at ln of it on the axis.
    pub log_floor_hz: f64,
}

impl Default for PeakTransportConfig {
    fn default() -> Self {
        PeakTransportConfig {
            fft_size: 4096,
            hop_fraction: 0.25,
            range_db: 60.0,
            log_floor_hz: 20.0,
        }
    }
}

/// Transport of the spectral *peaks*: the 1-D Wasserstein-1 distance along ln f between the
/// level profiles of the time-averaged magnitude spectra,
///
/// M_k = mean_t S[t,k] (frames wholly inside the signal),
/// m_k = max(20 log10(M_k / M_ref) + R, 0)          [dB above the floor; M_ref the target's peak]
/// p = m / Σm,  W = Σ_k |P_k − Q_k| (ln f_(k+1) − ln f_k)   [nepers]
///
/// Counting decibels above a floor gives every audible partial a comparable mass whatever its
/// amplitude and decay, and averaging over time removes the way decay reshapes each frame; so
/// a change of E, which multiplies every frequency by one factor, moves the whole profile
/// rigidly along ln f and W falls steadily towards the target from any start. It is the
/// transport loss of the material fit, where the frame-wise loss of [`TransportLoss`] is
/// distorted by frequency-dependent damping (modes moved down also ring longer).
///
/// Gradient: dW/dP_k = Δx_k sign(P_k − Q_k), suffix sums to dW/dp, dW/dm_i = (dW/dp_i −
/// Σ_j p_j dW/dp_j)/Σm, dm_k/dM_k = 20/(ln 10 · M_k) above the floor (0 below),
/// dM_k/dS[t,k] = 1/T.
#[derive(Clone, Debug)]
pub struct PeakTransportLoss {
    config: PeakTransportConfig,
    plan: StftPlan,
    frames: std::ops::Range<usize>,
    reference: f64,
    target_cdf: Vec<f64>,
    spacing: Vec<f64>,
    target_len: usize,
}

impl PeakTransportLoss {
    pub fn new(
        target: &[f64],
        sample_rate: f64,
        config: PeakTransportConfig,
    ) -> Result<Self, LossError> {
        check_target(target)?;
        if !(sample_rate > 0.0 && config.range_db > 0.0 && config.log_floor_hz > 0.0) {
            return Err(LossError::Setting(
                "sample rate, range_db and log_floor_hz must be > 0".into(),
            ));
        }
        let plan = StftPlan::new(
            config.fft_size,
            hop_of(config.fft_size, config.hop_fraction)?,
        )?;
        let n = config.fft_size;
        let n_frames = plan.n_frames(target.len());
        // Frames t with t·H − N/2 ≥ 0 and t·H + N/2 ≤ len.
        let first = (n / 2).div_ceil(plan.hop());
        let last = if target.len() >= n / 2 {
            (target.len() - n / 2) / plan.hop() + 1
        } else {
            0
        };
        let frames = first..last.min(n_frames);
        if frames.is_empty() {
            return Err(LossError::Setting(format!(
                "the target ({} samples) is shorter than one FFT of {n}",
                target.len()
            )));
        }
        let mean = Self::mean_spectrum(&plan.forward(target), &frames);
        let reference = mean.iter().fold(0.0_f64, |m, &v| m.max(v));
        if !(reference > 0.0) {
            return Err(LossError::Setting("the target is silent".into()));
        }
        let bin_hz = sample_rate / n as f64;
        let n_bins = n / 2 + 1;
        let x = |k: usize| (k as f64 * bin_hz).max(config.log_floor_hz).ln();
        let spacing = (0..n_bins)
            .map(|k| if k + 1 < n_bins { x(k + 1) - x(k) } else { 0.0 })
            .collect();
        let mut loss = PeakTransportLoss {
            config,
            plan,
            frames,
            reference,
            target_cdf: Vec::new(),
            spacing,
            target_len: target.len(),
        };
        let levels: Vec<f64> = mean.iter().map(|&m| loss.level(m)).collect();
        let total: f64 = levels.iter().sum();
        let mut cum = 0.0;
        loss.target_cdf = levels
            .iter()
            .map(|l| {
                cum += l / total;
                cum
            })
            .collect();
        Ok(loss)
    }

    fn mean_spectrum(spec: &Spectrogram, frames: &std::ops::Range<usize>) -> Vec<f64> {
        let mut mean = vec![0.0; spec.n_bins];
        for t in frames.clone() {
            mean.iter_mut()
                .zip(spec.frame(t))
                .for_each(|(m, s)| *m += s);
        }
        let count = frames.len() as f64;
        mean.iter_mut().for_each(|m| *m /= count);
        mean
    }

    fn level(&self, m: f64) -> f64 {
        let db = 20.0 * (m / self.reference).log10() + self.config.range_db;
        if db > 0.0 {
            db
        } else {
            0.0
        }
    }

    pub fn value(&self, x: &[f64]) -> Result<f64, LossError> {
        self.evaluate(x, false).map(|(v, _)| v)
    }

    pub fn value_and_gradient(&self, x: &[f64]) -> Result<(f64, Vec<f64>), LossError> {
        self.evaluate(x, true)
            .map(|(v, g)| (v, g.unwrap_or_default()))
    }

    fn evaluate(
        &self,
        x: &[f64],
        with_gradient: bool,
    ) -> Result<(f64, Option<Vec<f64>>), LossError> {
        if x.len() != self.target_len {
            return Err(LossError::Length {
                got: x.len(),
                expected: self.target_len,
            });
        }
        let spec = self.plan.forward(x);
        let mean = Self::mean_spectrum(&spec, &self.frames);
        let levels: Vec<f64> = mean.iter().map(|&m| self.level(m)).collect();
        let total: f64 = levels.iter().sum();
        let n_bins = spec.n_bins;
        if !(total > 0.0) {
            // Nothing within range of the target's level: the largest possible distance, and no
            // slope (no bin can move mass it does not have).
            let span: f64 = self.spacing.iter().sum();
            return Ok((span, with_gradient.then(|| vec![0.0; x.len()])));
        }
        let mut dw = vec![0.0; n_bins];
        let value = wasserstein_1d(
            &levels,
            &self.target_cdf,
            &self.spacing,
            with_gradient.then_some(&mut dw[..]),
        );
        if !with_gradient {
            return Ok((value, None));
        }
        let count = self.frames.len() as f64;
        let mut grad_mag = vec![0.0; spec.magnitude.len()];
        for k in 0..n_bins {
            if levels[k] > 0.0 {
                let d_mean = dw[k] * 20.0 / (std::f64::consts::LN_10 * mean[k]) / count;
                for t in self.frames.clone() {
                    grad_mag[t * n_bins + k] = d_mean;
                }
            }
        }
        let mut g = vec![0.0; x.len()];
        self.plan.backward(&spec, &grad_mag, &mut g);
        Ok((value, Some(g)))
    }
}

/// Which loss a [`HybridSchedule`] asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LossPhase {
    Transport,
    Spectral,
}

impl std::fmt::Display for LossPhase {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            LossPhase::Transport => "transport",
            LossPhase::Spectral => "spectral",
        })
    }
}

/// Transport first, then spectral once the transport loss stops improving (module docs).
#[derive(Clone, Debug)]
pub struct HybridSchedule {
    pub patience: usize,
    pub min_improvement: f64,
    phase: LossPhase,
    best: f64,
    steps_since_best: usize,
    switched_at: Option<usize>,
    steps: usize,
}

impl HybridSchedule {
    /// `patience` steps without a relative improvement of `min_improvement` end the
    /// transport phase.
    pub fn new(patience: usize, min_improvement: f64) -> HybridSchedule {
        HybridSchedule {
            patience: patience.max(1),
            min_improvement,
            phase: LossPhase::Transport,
            best: f64::INFINITY,
            steps_since_best: 0,
            switched_at: None,
            steps: 0,
        }
    }

    /// A schedule that never leaves `phase` (for runs that use one loss only).
    pub fn fixed(phase: LossPhase) -> HybridSchedule {
        let mut s = HybridSchedule::new(usize::MAX, 0.0);
        s.phase = phase;
        s
    }

    pub fn phase(&self) -> LossPhase {
        self.phase
    }

    /// The step at which the switch to the spectral loss happened.
    pub fn switched_at(&self) -> Option<usize> {
        self.switched_at
    }

    /// Records the loss of the step just taken (in the current phase) and returns the phase
    /// for the next step.
    pub fn observe(&mut self, loss: f64) -> LossPhase {
        self.steps += 1;
        if self.phase == LossPhase::Transport {
            if loss < self.best * (1.0 - self.min_improvement) || !self.best.is_finite() {
                self.best = loss.min(self.best);
                self.steps_since_best = 0;
            } else {
                self.best = self.best.min(loss);
                self.steps_since_best += 1;
                if self.steps_since_best >= self.patience {
                    self.phase = LossPhase::Spectral;
                    self.switched_at = Some(self.steps);
                }
            }
        }
        self.phase
    }
}

#[cfg(test)]
mod tests;
