//! From eigenvalues to a synthesiser bank, and gradients back to eigenvalues, damping and
//! material.
//!
//! Mode k has eigenvalue λ_k = ω_k² [rad²/s²], a projection c_k = J φ_k(x)·n of its
//! mass-normalised shape on the strike ([`super::excitation`]) and a decay rate d_k [1/s]
//! from a [`DampingModel`]:
//!
//! * Rayleigh: d = (α + βλ)/2 (α in 1/s, β in s);
//! * per mode: d_k given;
//! * a damping curve d(f) of the undamped frequency f = ω/2π [Hz]: piecewise linear in
//!   (ln f, ln d) through knots (f_i, e^(θ_i)), continued as a power law past the end knots
//!   (a single knot: constant). The fitted parameters are θ_i = ln d_i, which keeps d > 0.
//!
//! The bank entry is f_d = ω_d/2π with ω_d = √(λ − d²), decay d, and complex amplitude
//! z = c · G(s) (amplitude |z|, phase arg z). A mode with d ≥ ω (overdamped) or λ ≤ 0 does
//! not ring: it stays in the bank, at frequency 0 and amplitude 0, so indices line up, and
//! gets zero gradient.
//!
//! # Backward
//!
//! From the bank gradient (dL/df_d, dL/dd, dL/dz), per mode:
//!
//! * D_ω = dL/df_d / 2π + Re(ḡ·c ∂G/∂ω_d),   D_d = dL/dd + Re(ḡ·c ∂G/∂d),   dL/dc = Re(ḡ·G)
//!   where Re(ḡ·w) means g_re Re w + g_im Im w for g = dL/dz;
//! * with ω_d² = λ − d²: dL/dλ = D_ω (1 − 2d ∂d/∂λ)/(2ω_d) + D_d ∂d/∂λ, and for a damping
//!   parameter θ: dL/dθ = Σ_k (D_d − D_ω d/ω_d) ∂d_k/∂θ.
//!
//! ∂d/∂λ is β/2 (Rayleigh), 0 (per mode), or d'(f)/(4πω) (curve); ∂d/∂α = ½, ∂d/∂β = λ/2.
//!
//! # Material
//!
//! [`material_gradient`] combines dL/dλ with dλ/dE, dλ/dν, dλ/dρ (from
//! [`crate::eigen::sensitivity`]). Mass-normalised shapes scale as ρ^(−½) at fixed E and ν
//! (K is linear in E, M in ρ), so c_k contributes dc_k/dρ = −c_k/(2ρ). The change of the
//! shapes with ν is not included: the fits treat c_k as free (learned) amplitudes, for which
//! dL/dν through λ is then exact.

use super::excitation::{modal_factor, ContactForce, Response};
use super::synth::{BankGradient, ModalBank};
use rustfft::num_complex::Complex64;

/// Why a damping model, a damping curve or a modal chain was refused; each message names the
/// offending value.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ChainError {
    #[error("a damping curve needs as many decay rates as knot frequencies, at least one ({frequencies} and {decay_rates})")]
    CurveLengths {
        frequencies: usize,
        decay_rates: usize,
    },
    #[error("damping curve knot {knot}: frequency {frequency_hz} Hz and decay e^{log_decay} must be finite and positive")]
    CurveKnot {
        knot: usize,
        frequency_hz: f64,
        log_decay: f64,
    },
    #[error("damping curve knot {knot}: frequencies must increase ({previous_hz} then {frequency_hz} Hz)")]
    CurveOrder {
        knot: usize,
        previous_hz: f64,
        frequency_hz: f64,
    },
    #[error("Rayleigh α = {alpha}, β = {beta} must be finite and ≥ 0")]
    Rayleigh { alpha: f64, beta: f64 },
    #[error("{decay_rates} per-mode decay rates for {modes} modes")]
    PerModeCount { decay_rates: usize, modes: usize },
    #[error("decay rate of mode {mode} is {value} (must be finite and ≥ 0)")]
    PerModeValue { mode: usize, value: f64 },
    #[error("{eigenvalues} eigenvalues but {projections} projections")]
    Lengths {
        eigenvalues: usize,
        projections: usize,
    },
    #[error(transparent)]
    Force(#[from] super::excitation::ExcitationError),
}

/// How fast each mode decays.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum DampingModel {
    Rayleigh { alpha: f64, beta: f64 },
    PerMode { decay_rates: Vec<f64> },
    Curve(DampingCurve),
}

/// d(f) through knots, piecewise linear in (ln f, ln d); see the module docs.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DampingCurve {
    /// Knot frequencies [Hz], strictly increasing, > 0.
    pub frequencies_hz: Vec<f64>,
    /// θ_i = ln d_i at the knots (d in 1/s).
    pub log_decay: Vec<f64>,
}

impl DampingCurve {
    /// A curve through (f_i, d_i); errors name the offending knot.
    pub fn new(frequencies_hz: Vec<f64>, decay_rates: &[f64]) -> Result<DampingCurve, ChainError> {
        if frequencies_hz.is_empty() || frequencies_hz.len() != decay_rates.len() {
            return Err(ChainError::CurveLengths {
                frequencies: frequencies_hz.len(),
                decay_rates: decay_rates.len(),
            });
        }
        let curve = DampingCurve {
            log_decay: decay_rates.iter().map(|d| d.ln()).collect(),
            frequencies_hz,
        };
        curve.validate()?;
        Ok(curve)
    }

    pub fn validate(&self) -> Result<(), ChainError> {
        if self.frequencies_hz.is_empty() || self.frequencies_hz.len() != self.log_decay.len() {
            return Err(ChainError::CurveLengths {
                frequencies: self.frequencies_hz.len(),
                decay_rates: self.log_decay.len(),
            });
        }
        for (i, (&f, &t)) in self.frequencies_hz.iter().zip(&self.log_decay).enumerate() {
            if !(f > 0.0 && f.is_finite() && t.is_finite()) {
                return Err(ChainError::CurveKnot {
                    knot: i,
                    frequency_hz: f,
                    log_decay: t,
                });
            }
            if i > 0 && !(f > self.frequencies_hz[i - 1]) {
                return Err(ChainError::CurveOrder {
                    knot: i,
                    previous_hz: self.frequencies_hz[i - 1],
                    frequency_hz: f,
                });
            }
        }
        Ok(())
    }

    /// d(f) [1/s], d'(f) [1/s per Hz], and the two knots (index, ∂d/∂θ_index) it depends on.
    pub fn evaluate(&self, f: f64) -> (f64, f64, [(usize, f64); 2]) {
        let n = self.frequencies_hz.len();
        if n == 1 {
            let d = self.log_decay[0].exp();
            return (d, 0.0, [(0, d), (0, 0.0)]);
        }
        let x = f.ln();
        // Segment [i, i+1]; the end segments extend beyond the knots.
        let i = match self.frequencies_hz.iter().position(|&k| k > f) {
            None => n - 2,
            Some(0) => 0,
            Some(j) => (j - 1).min(n - 2),
        };
        let (x0, x1) = (self.frequencies_hz[i].ln(), self.frequencies_hz[i + 1].ln());
        let w = (x - x0) / (x1 - x0);
        let slope = (self.log_decay[i + 1] - self.log_decay[i]) / (x1 - x0);
        let d = ((1.0 - w) * self.log_decay[i] + w * self.log_decay[i + 1]).exp();
        (d, d * slope / f, [(i, d * (1.0 - w)), (i + 1, d * w)])
    }

    pub fn decay(&self, f: f64) -> f64 {
        self.evaluate(f).0
    }
}

impl DampingModel {
    /// Checks the model against `n_modes` modes.
    pub fn validate(&self, n_modes: usize) -> Result<(), ChainError> {
        match self {
            DampingModel::Rayleigh { alpha, beta } => {
                if !(alpha.is_finite() && beta.is_finite() && *alpha >= 0.0 && *beta >= 0.0) {
                    return Err(ChainError::Rayleigh {
                        alpha: *alpha,
                        beta: *beta,
                    });
                }
                Ok(())
            }
            DampingModel::PerMode { decay_rates } => {
                if decay_rates.len() != n_modes {
                    return Err(ChainError::PerModeCount {
                        decay_rates: decay_rates.len(),
                        modes: n_modes,
                    });
                }
                match decay_rates
                    .iter()
                    .position(|d| !(d.is_finite() && *d >= 0.0))
                {
                    Some(i) => Err(ChainError::PerModeValue {
                        mode: i,
                        value: decay_rates[i],
                    }),
                    None => Ok(()),
                }
            }
            DampingModel::Curve(c) => c.validate(),
        }
    }

    /// d, ∂d/∂λ for mode k with eigenvalue λ.
    fn decay(&self, k: usize, lambda: f64) -> (f64, f64) {
        match self {
            DampingModel::Rayleigh { alpha, beta } => (0.5 * (alpha + beta * lambda), 0.5 * beta),
            DampingModel::PerMode { decay_rates } => (decay_rates[k], 0.0),
            DampingModel::Curve(c) => {
                let omega = lambda.sqrt();
                let (d, slope, _) = c.evaluate(omega / (2.0 * std::f64::consts::PI));
                (d, slope / (4.0 * std::f64::consts::PI * omega))
            }
        }
    }
}

/// How the object is struck.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Strike {
    pub force: ContactForce,
    pub response: Response,
}

impl Default for Strike {
    fn default() -> Self {
        Strike {
            force: ContactForce::Impulse,
            response: Response::Acceleration,
        }
    }
}

/// What [`ModalChain::backward`] returns.
#[derive(Clone, Debug, PartialEq)]
pub struct ChainGradient {
    /// dL/dλ_k.
    pub eigenvalues: Vec<f64>,
    /// dL/dc_k.
    pub projections: Vec<f64>,
    pub damping: DampingGradient,
}

/// dL/d(damping parameters), in the shape of the [`DampingModel`].
#[derive(Clone, Debug, PartialEq)]
pub enum DampingGradient {
    Rayleigh {
        alpha: f64,
        beta: f64,
    },
    PerMode {
        decay_rates: Vec<f64>,
    },
    /// dL/dθ_i, θ_i = ln d_i.
    Curve {
        log_decay: Vec<f64>,
    },
}

#[derive(Clone, Debug)]
struct ModeLink {
    rings: bool,
    omega_d: f64,
    decay: f64,
    ddecay_dlambda: f64,
    projection: f64,
    factor: Complex64,
    dfactor_domega_d: Complex64,
    dfactor_ddecay: Complex64,
}

/// The forward map of the module docs, kept for the backward pass.
#[derive(Clone, Debug)]
pub struct ModalChain {
    damping: DampingModel,
    eigenvalues: Vec<f64>,
    links: Vec<ModeLink>,
}

impl ModalChain {
    /// The bank for eigenvalues λ_k and projections c_k, and the chain to differentiate it.
    pub fn new(
        eigenvalues: &[f64],
        projections: &[f64],
        damping: &DampingModel,
        strike: &Strike,
    ) -> Result<(ModalBank, ModalChain), ChainError> {
        if eigenvalues.len() != projections.len() {
            return Err(ChainError::Lengths {
                eigenvalues: eigenvalues.len(),
                projections: projections.len(),
            });
        }
        damping.validate(eigenvalues.len())?;
        strike.force.validate()?;
        let two_pi = 2.0 * std::f64::consts::PI;
        let mut bank = ModalBank::default();
        let mut links = Vec::with_capacity(eigenvalues.len());
        for (k, (&lambda, &c)) in eigenvalues.iter().zip(projections).enumerate() {
            let (decay, ddecay_dlambda) = if lambda > 0.0 {
                damping.decay(k, lambda)
            } else {
                (0.0, 0.0)
            };
            let wd2 = lambda - decay * decay;
            let rings = lambda > 0.0 && wd2 > 0.0 && c.is_finite();
            let link = if rings {
                let omega_d = wd2.sqrt();
                let g = modal_factor(&strike.force, strike.response, decay, omega_d);
                ModeLink {
                    rings,
                    omega_d,
                    decay,
                    ddecay_dlambda,
                    projection: c,
                    factor: g.value,
                    dfactor_domega_d: g.d_omega_d,
                    dfactor_ddecay: g.d_decay,
                }
            } else {
                let zero = Complex64::new(0.0, 0.0);
                ModeLink {
                    rings,
                    omega_d: 0.0,
                    decay: 0.0,
                    ddecay_dlambda: 0.0,
                    projection: c,
                    factor: zero,
                    dfactor_domega_d: zero,
                    dfactor_ddecay: zero,
                }
            };
            let z = link.factor * c;
            bank.frequencies_hz.push(link.omega_d / two_pi);
            bank.decay_rates.push(link.decay);
            bank.amplitudes.push(if rings { z.norm() } else { 0.0 });
            bank.phases.push(if rings { z.arg() } else { 0.0 });
            links.push(link);
        }
        Ok((
            bank,
            ModalChain {
                damping: damping.clone(),
                eigenvalues: eigenvalues.to_vec(),
                links,
            },
        ))
    }

    /// dL/dλ, dL/dc and dL/d(damping) from the gradient of the bank this chain made.
    ///
    /// # Panics
    /// If `grad` is for a bank of another size.
    pub fn backward(&self, grad: &BankGradient) -> ChainGradient {
        assert_eq!(grad.len(), self.links.len(), "gradient of another bank");
        let two_pi = 2.0 * std::f64::consts::PI;
        let n = self.links.len();
        let mut d_lambda = vec![0.0; n];
        let mut d_projection = vec![0.0; n];
        // dL/dd_k at fixed λ, through both d and ω_d = √(λ − d²): D_d − D_ω d/ω_d.
        let mut d_decay_total = vec![0.0; n];
        for (k, link) in self.links.iter().enumerate() {
            if !link.rings {
                continue;
            }
            let [g_re, g_im] = grad.complex_amplitudes[k];
            let dot = |w: Complex64| g_re * w.re + g_im * w.im;
            let c = link.projection;
            let d_omega = grad.frequencies_hz[k] / two_pi + dot(link.dfactor_domega_d * c);
            let d_decay = grad.decay_rates[k] + dot(link.dfactor_ddecay * c);
            d_projection[k] = dot(link.factor);
            d_lambda[k] = d_omega * (1.0 - 2.0 * link.decay * link.ddecay_dlambda)
                / (2.0 * link.omega_d)
                + d_decay * link.ddecay_dlambda;
            d_decay_total[k] = d_decay - d_omega * link.decay / link.omega_d;
        }
        let damping = match &self.damping {
            DampingModel::Rayleigh { .. } => DampingGradient::Rayleigh {
                alpha: d_decay_total.iter().map(|g| 0.5 * g).sum(),
                beta: d_decay_total
                    .iter()
                    .zip(&self.eigenvalues)
                    .map(|(g, l)| 0.5 * l * g)
                    .sum(),
            },
            DampingModel::PerMode { .. } => DampingGradient::PerMode {
                decay_rates: d_decay_total,
            },
            DampingModel::Curve(curve) => {
                let mut log_decay = vec![0.0; curve.log_decay.len()];
                for (k, link) in self.links.iter().enumerate() {
                    if link.rings {
                        let (_, _, knots) = curve.evaluate(self.eigenvalues[k].sqrt() / two_pi);
                        for (i, w) in knots {
                            log_decay[i] += d_decay_total[k] * w;
                        }
                    }
                }
                DampingGradient::Curve { log_decay }
            }
        };
        ChainGradient {
            eigenvalues: d_lambda,
            projections: d_projection,
            damping,
        }
    }
}

/// dL/dE [1/Pa], dL/dν, dL/dρ [m³/kg] from the chain gradient and the eigenvalue
/// sensitivities (per mode, same order), including c_k ∝ ρ^(−½) (module docs). Modes past the
/// end of the sensitivity vectors are ignored.
pub fn material_gradient(
    grad: &ChainGradient,
    d_lambda_d_youngs: &[f64],
    d_lambda_d_poisson: &[f64],
    d_lambda_d_density: &[f64],
    projections: &[f64],
    density: f64,
) -> [f64; 3] {
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let shape_term: f64 = grad
        .projections
        .iter()
        .zip(projections)
        .map(|(g, c)| -g * c / (2.0 * density))
        .sum();
    [
        dot(&grad.eigenvalues, d_lambda_d_youngs),
        dot(&grad.eigenvalues, d_lambda_d_poisson),
        dot(&grad.eigenvalues, d_lambda_d_density) + shape_term,
    ]
}

#[cfg(test)]
mod tests;
