//! Strike amplitudes from the physics of the contact.
//!
//! A mass-normalised mode φ_k [kg^(−½)] driven by a force J·F(t) at a point, along a unit
//! direction n (J [N·s] the impulse, F [1/s] a pulse of unit area), has modal coordinate
//! q_k [kg^(½)·m] obeying q̈ + 2d q̇ + ω² q = c_k F(t) with c_k = J φ_k(x)·n. With
//! s = −d + iω_d (ω_d the damped angular frequency) and the Laplace transform
//! F̃(s) = ∫ F(τ) e^(−sτ) dτ, after the contact has ended
//!
//! q_k(t) = c_k · Im( F̃(s) e^(st) ) / ω_d
//!
//! exactly, and each time derivative multiplies by s. So the m-th derivative of the response
//! (m = 0 displacement, 1 velocity, 2 acceleration) is a damped sinusoid with complex
//! amplitude
//!
//! z_k = c_k · G(s),   G(s) = s^m F̃(s) / ω_d,
//!
//! i.e. amplitude |z_k| and phase arg z_k in the synthesiser ([`super::synth`]). The
//! radiated pressure far from a compact source follows the surface acceleration, hence
//! [`Response::Acceleration`] by default. The formula is exact from the end of the contact
//! on; the synthesiser extends it back to t = 0, which misrepresents only the first τ (a
//! millisecond or less for a hard strike).
//!
//! Contact forces (unit area):
//!
//! * impulse: F = δ(t), F̃ = 1;
//! * half-sine of duration τ [s] (a Hertz-like contact): F(t) = (π/2τ) sin(πt/τ) on [0, τ],
//!   F̃(s) = (π/2τ) · p (1 + e^(−sτ)) / (s² + p²) with p = π/τ. It is a low-pass: modes
//!   above ~1.5/τ Hz are barely excited.
//!
//! [`modal_factor`] gives G and its derivatives with respect to ω_d and d, which the
//! gradient chain ([`super::chain`]) needs: ∂s/∂ω_d = i, ∂s/∂d = −1, and with
//! H(s) = s^m F̃(s), ∂G/∂ω_d = i H'(s)/ω_d − H/ω_d², ∂G/∂d = −H'(s)/ω_d.

use rustfft::num_complex::Complex64;

/// The time course of the contact force.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ContactForce {
    Impulse,
    HalfSine { duration_s: f64 },
}

/// Which time derivative of the surface motion the sound follows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Response {
    Displacement,
    Velocity,
    Acceleration,
}

impl Response {
    fn order(self) -> i32 {
        match self {
            Response::Displacement => 0,
            Response::Velocity => 1,
            Response::Acceleration => 2,
        }
    }
}

impl std::fmt::Display for ContactForce {
    /// As the command line takes it: `impulse`, `half-sine:0.0005`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ContactForce::Impulse => f.write_str("impulse"),
            ContactForce::HalfSine { duration_s } => write!(f, "half-sine:{duration_s}"),
        }
    }
}

impl std::fmt::Display for Response {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Response::Displacement => "displacement",
            Response::Velocity => "velocity",
            Response::Acceleration => "acceleration",
        })
    }
}

/// A contact force or response quantity that cannot be used, with what was given.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ExcitationError {
    #[error("half-sine duration {0:?} is not a number (seconds)")]
    DurationNotANumber(String),
    #[error("half-sine duration {0} s must lie in (0, 1]")]
    DurationOutOfRange(f64),
    #[error("unknown contact force {0:?}: use `impulse` or `half-sine:<seconds>`")]
    UnknownForce(String),
    #[error("unknown response {0:?}: use displacement, velocity or acceleration")]
    UnknownResponse(String),
}

impl std::str::FromStr for ContactForce {
    type Err = ExcitationError;
    /// `impulse` or `half-sine:<duration in s>`.
    fn from_str(s: &str) -> Result<Self, ExcitationError> {
        let s = s.trim();
        if s.eq_ignore_ascii_case("impulse") {
            return Ok(ContactForce::Impulse);
        }
        if let Some(rest) = s
            .strip_prefix("half-sine:")
            .or_else(|| s.strip_prefix("half_sine:"))
        {
            let duration_s: f64 = rest
                .trim()
                .parse()
                .map_err(|_| ExcitationError::DurationNotANumber(rest.to_string()))?;
            let force = ContactForce::HalfSine { duration_s };
            force.validate()?;
            return Ok(force);
        }
        Err(ExcitationError::UnknownForce(s.to_string()))
    }
}

impl std::str::FromStr for Response {
    type Err = ExcitationError;
    fn from_str(s: &str) -> Result<Self, ExcitationError> {
        match s.trim().to_ascii_lowercase().as_str() {
            "displacement" => Ok(Response::Displacement),
            "velocity" => Ok(Response::Velocity),
            "acceleration" => Ok(Response::Acceleration),
            other => Err(ExcitationError::UnknownResponse(other.to_string())),
        }
    }
}

impl ContactForce {
    /// A half-sine needs a duration in (0, 1] s.
    pub fn validate(&self) -> Result<(), ExcitationError> {
        match *self {
            ContactForce::Impulse => Ok(()),
            ContactForce::HalfSine { duration_s } if duration_s > 0.0 && duration_s <= 1.0 => {
                Ok(())
            }
            ContactForce::HalfSine { duration_s } => {
                Err(ExcitationError::DurationOutOfRange(duration_s))
            }
        }
    }

    /// F̃(s) and F̃'(s).
    pub fn laplace(&self, s: Complex64) -> (Complex64, Complex64) {
        match *self {
            ContactForce::Impulse => (Complex64::new(1.0, 0.0), Complex64::new(0.0, 0.0)),
            ContactForce::HalfSine { duration_s: tau } => {
                let p = std::f64::consts::PI / tau;
                let denom = s * s + p * p;
                // Next to s = ±ip numerator and denominator vanish together; there the
                // integral itself, by Gauss–Legendre quadrature, is exact to round-off
                // (|s|τ ≈ π: a smooth integrand of a few oscillations).
                if denom.norm() < 0.25 * p * p {
                    return half_sine_by_quadrature(tau, s);
                }
                let gain = 0.5 * p; // π/(2τ)
                let e = (-s * tau).exp();
                let value = gain * p * (1.0 + e) / denom;
                let derivative =
                    gain * p * ((-tau) * e * denom - (1.0 + e) * 2.0 * s) / (denom * denom);
                (value, derivative)
            }
        }
    }
}

fn half_sine_by_quadrature(tau: f64, s: Complex64) -> (Complex64, Complex64) {
    let (nodes, weights) = crate::fem::quadrature::gauss_legendre_01(24);
    let p = std::f64::consts::PI / tau;
    let mut value = Complex64::new(0.0, 0.0);
    let mut derivative = Complex64::new(0.0, 0.0);
    for (u, w) in nodes.iter().zip(&weights) {
        let t = tau * u;
        let f = 0.5 * p * (p * t).sin();
        let term = (-s * t).exp() * (f * w * tau);
        value += term;
        derivative -= term * t;
    }
    (value, derivative)
}

/// G = s^m F̃(s)/ω_d and its partial derivatives (module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ModalFactor {
    pub value: Complex64,
    pub d_omega_d: Complex64,
    pub d_decay: Complex64,
}

/// The complex amplitude per unit c_k of a mode with decay rate d [1/s] and damped angular
/// frequency ω_d [rad/s] (ω_d > 0).
pub fn modal_factor(
    force: &ContactForce,
    response: Response,
    decay: f64,
    omega_d: f64,
) -> ModalFactor {
    let s = Complex64::new(-decay, omega_d);
    let (f, df) = force.laplace(s);
    let m = response.order();
    let s_m = s.powi(m);
    let h = s_m * f;
    let dh = if m == 0 {
        df
    } else {
        s.powi(m - 1) * f * m as f64 + s_m * df
    };
    let i = Complex64::new(0.0, 1.0);
    ModalFactor {
        value: h / omega_d,
        d_omega_d: i * dh / omega_d - h / (omega_d * omega_d),
        d_decay: -dh / omega_d,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::audio::synth::{render_samples, ModalBank};

    /// Direct simulation of q̈ + 2d q̇ + ω² q = F(t) (unit c) with a fine RK4 step, against
    /// the closed form after the contact.
    #[test]
    fn half_sine_response_matches_time_integration() {
        let (omega, d, tau) = (2.0 * std::f64::consts::PI * 700.0, 15.0, 4e-4);
        let omega_d = (omega * omega - d * d).sqrt();
        let force = ContactForce::HalfSine { duration_s: tau };
        let f = |t: f64| {
            if t <= tau {
                0.5 * std::f64::consts::PI / tau * (std::f64::consts::PI * t / tau).sin()
            } else {
                0.0
            }
        };
        let rhs = |t: f64, q: f64, v: f64| (v, f(t) - 2.0 * d * v - omega * omega * q);
        let dt = tau / 2000.0;
        let (mut t, mut q, mut v) = (0.0, 0.0, 0.0);
        let t_end = 3e-3;
        while t < t_end - 0.5 * dt {
            let (k1q, k1v) = rhs(t, q, v);
            let (k2q, k2v) = rhs(t + dt / 2.0, q + dt / 2.0 * k1q, v + dt / 2.0 * k1v);
            let (k3q, k3v) = rhs(t + dt / 2.0, q + dt / 2.0 * k2q, v + dt / 2.0 * k2v);
            let (k4q, k4v) = rhs(t + dt, q + dt * k3q, v + dt * k3v);
            q += dt / 6.0 * (k1q + 2.0 * k2q + 2.0 * k3q + k4q);
            v += dt / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v);
            t += dt;
        }
        for (response, simulated) in [(Response::Displacement, q), (Response::Velocity, v)] {
            let g = modal_factor(&force, response, d, omega_d).value;
            let closed = (g * (Complex64::new(-d, omega_d) * t).exp()).im;
            assert!(
                (closed - simulated).abs() < 1e-9 * simulated.abs().max(1e-12) + 1e-12,
                "{response:?}: {closed} vs {simulated}"
            );
        }
    }

    #[test]
    fn impulse_velocity_matches_the_synthesiser_bank() {
        // Impulse, velocity: z = s/ω_d, a unit-ish amplitude with phase just past π/2.
        let (d, omega_d) = (3.0, 2.0 * std::f64::consts::PI * 440.0);
        let g = modal_factor(&ContactForce::Impulse, Response::Velocity, d, omega_d).value;
        let bank = ModalBank {
            frequencies_hz: vec![omega_d / (2.0 * std::f64::consts::PI)],
            decay_rates: vec![d],
            amplitudes: vec![g.norm()],
            phases: vec![g.arg()],
        };
        let fs = 48_000.0;
        let x = render_samples(&bank, fs, 1000);
        for (n, &xn) in x.iter().enumerate() {
            let t = n as f64 / fs;
            // q̇ of h(t) = e^(−dt) sin(ω_d t)/ω_d.
            let exact = (-d * t).exp() * (omega_d * (omega_d * t).cos() - d * (omega_d * t).sin())
                / omega_d;
            assert!((xn - exact).abs() < 1e-12, "sample {n}");
        }
    }

    #[test]
    fn factor_derivatives_match_finite_differences() {
        for force in [
            ContactForce::Impulse,
            ContactForce::HalfSine { duration_s: 1e-3 },
            ContactForce::HalfSine {
                duration_s: 1.0 / 1200.0,
            },
        ] {
            for response in [
                Response::Displacement,
                Response::Velocity,
                Response::Acceleration,
            ] {
                // ω_d near π/τ for the second half-sine exercises the quadrature branch.
                let (d, w) = (20.0, 2.0 * std::f64::consts::PI * 600.0);
                let m = modal_factor(&force, response, d, w);
                let h = 1e-4;
                let fd_w = (modal_factor(&force, response, d, w + h).value
                    - modal_factor(&force, response, d, w - h).value)
                    / (2.0 * h);
                let fd_d = (modal_factor(&force, response, d + h, w).value
                    - modal_factor(&force, response, d - h, w).value)
                    / (2.0 * h);
                let scale = m.value.norm() / w;
                assert!(
                    (fd_w - m.d_omega_d).norm() < 1e-6 * scale,
                    "{force:?} {response:?} dω: {fd_w} vs {}",
                    m.d_omega_d
                );
                assert!(
                    (fd_d - m.d_decay).norm() < 1e-6 * scale,
                    "{force:?} {response:?} dd: {fd_d} vs {}",
                    m.d_decay
                );
            }
        }
    }

    #[test]
    fn closed_form_and_quadrature_agree_near_the_removable_singularity() {
        let tau = 1e-3;
        let p = std::f64::consts::PI / tau;
        let s = Complex64::new(-5.0, p * 1.3); // outside the quadrature zone
        let (closed, dclosed) = ContactForce::HalfSine { duration_s: tau }.laplace(s);
        let (quad, dquad) = half_sine_by_quadrature(tau, s);
        assert!((closed - quad).norm() < 1e-13, "{closed} vs {quad}");
        assert!((dclosed - dquad).norm() < 1e-13 * tau);
        // At s = ip exactly the closed form is 0/0; the value must be finite and continuous.
        let (at, _) = ContactForce::HalfSine { duration_s: tau }.laplace(Complex64::new(0.0, p));
        let (near, _) =
            ContactForce::HalfSine { duration_s: tau }.laplace(Complex64::new(0.0, p * 1.0001));
        assert!(at.norm().is_finite() && (at - near).norm() < 1e-3 * at.norm());
    }

    #[test]
    fn half_sine_is_a_low_pass_and_parses() {
        let force: ContactForce = "half-sine:0.001".parse().unwrap();
        let low = force
            .laplace(Complex64::new(0.0, 2.0 * std::f64::consts::PI * 100.0))
            .0
            .norm();
        let high = force
            .laplace(Complex64::new(0.0, 2.0 * std::f64::consts::PI * 5000.0))
            .0
            .norm();
        assert!((low - 1.0).abs() < 0.02 && high < 0.05, "{low} {high}");
        assert!("half-sine:0".parse::<ContactForce>().is_err());
        assert!("hammer".parse::<ContactForce>().is_err());
        assert_eq!(
            "impulse".parse::<ContactForce>().unwrap(),
            ContactForce::Impulse
        );
        assert_eq!(
            "Acceleration".parse::<Response>().unwrap(),
            Response::Acceleration
        );
    }
}
