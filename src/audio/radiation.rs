//! Acoustic transfer of vibration modes: how a vibrating mode radiates sound into free air and
//! how much of it reaches a microphone, by a low-order multipole fit to the surface motion.
//!
//! # Conventions and units
//!
//! Time dependence **e^(−iωt)** throughout: a real quantity is Re{X e^(−iωt)} with X the complex
//! amplitude. A mode vibrating with modal coordinate q(t) = Re{Q e^(−iωt)} moves the surface by
//! u(x, t) = q(t) φ(x) (φ the mode shape, 3 displacement values per node, node-major: u_x, u_y,
//! u_z of node 0, then node 1, …, the crate's dof layout 3·node + component). Every pressure
//! here is **per unit modal amplitude**: the sound pressure is Re{Q·p(x) e^(−iωt)} [Pa], so p is
//! in Pa per unit of q (Pa/m when φ is dimensionless, Pa/(kg^½·m) for the mass-normalised shapes
//! the modes job writes). Lengths are in m, ω in rad/s, k = ω/c in 1/m; air defaults to
//! c = 343 m/s, ρ = 1.225 kg/m³ ([`Air`]). With e^(+iωt) instead, every complex number below is
//! replaced by its conjugate.
//!
//! # Surface data
//!
//! [`SurfaceQuadrature`] samples the boundary of a tet mesh: each boundary face (outward order,
//! see [`crate::mesh`]) is a 3-node (P1) or 6-node (P2, the trace of the 10-node tet: corners
//! a, b, c and the mid-edge nodes of ab, bc, ca) triangle x(s,t) = Σ N_i(s,t) x_i. At the
//! 7 points of Radon's degree-5 rule it stores the position, the outward unit normal
//! n = x_s × x_t / |x_s × x_t| (x_s, x_t the tangents), the area weight w = ½ w_q |x_s × x_t| [m²]
//! and the shape values, so that a mode's normal displacement u_n = Σ N_i (φ_i · n) [m per unit
//! q] is one short sum per point. Curved (isoparametric) P2 faces are followed exactly; P1 faces
//! are flat.
//!
//! # Multipole fit
//!
//! Outside a sphere around a centre x₀ (default: the area centroid of the surface) that holds
//! the sources, the pressure of the radiating field is the outgoing multipole series
//!
//! p(x) = Σ_{l=0..L} Σ_{m=−l..l} c_lm h_l(kr) Y_lm(θ, φ),   r = |x − x₀|,
//!
//! with h_l = h_l⁽¹⁾ = j_l + i y_l the outgoing spherical Hankel function (h_l ~ (−i)^(l+1)
//! e^(ikr)/(kr) far away) and Y_lm the **real orthonormal** spherical harmonics
//! (∫ Y_lm Y_l'm' dΩ = δ; Y_l0 = N_l0 P_l(cos θ), Y_lm = √2 N_lm P_l^m(cos θ) cos mφ and
//! Y_l,−m = √2 N_lm P_l^m(cos θ) sin mφ for m > 0, N_lm² = (2l+1)/(4π)·(l−m)!/(l+m)!, no
//! Condon–Shortley phase). The coefficients c_lm [Pa per unit q] are complex; they sit at index
//! l² + l + m ([`multipole_index`]).
//!
//! The linearised Euler equation ρ ∂v/∂t = −∇p with v = −iω u gives the boundary condition
//! ∂p/∂n = ρω² u_n (the same in either time convention: it says that the pressure gradient
//! accelerates the air with the surface). The c_lm minimise the area-weighted boundary misfit
//!
//! Σ_i w_i |∂p/∂n(x_i) − ρω² u_n(x_i)|²,
//!
//! a complex linear least-squares problem, solved by Givens rotations streaming over the points
//! (an R factor of size (L+1)² is all that is kept), then a column-scaled SVD of the small
//! triangular system, which tolerates multipoles the data cannot see (e.g. the harmonics even in
//! z on a flat plate's mid-plane) by giving them the minimum-norm value 0 (the rank is
//! reported). The basis
//! gradient is ∇[h_l(kr) Y_lm] = (k h_l'(kr) − l h_l/r) Y_lm r̂ + (h_l/r) ∇R_lm(r̂) with
//! R_lm(x) = r^l Y_lm the regular solid harmonic (a homogeneous polynomial, by recurrences in
//! x, y, z, free of the 1/sin θ of the pole).
//!
//! The quality measure is the relative boundary residual
//! ε_L = ‖√w (∂p/∂n − ρω² u_n)‖ / ‖√w ρω² u_n‖ for each degree L. One QR of the full basis
//! (columns ordered by l) gives ε_L for every L ≤ L_max. The degree is chosen as the smallest
//! L whose orders above it would explain less than `gain_tolerance` of the boundary data's
//! weighted energy (ε_L² − ε_Lmax² ≤ gain_tolerance, default 10⁻⁴: the remaining orders would
//! lower ε by less than about 1 % of the data). Looking at all higher orders together matters:
//! a quadrupole mode gains nothing from L = 1 and everything from L = 2.
//!
//! # Transfer, directivity, power
//!
//! * [`MultipoleExpansion::transfer`]: p at each microphone position [Pa per unit q].
//! * [`MultipoleExpansion::far_field`]: the directivity D(r̂) with p ≈ D(r̂) e^(ikr)/r far away,
//!   D = (1/k) Σ c_lm (−i)^(l+1) Y_lm(r̂) [Pa·m per unit q].
//! * [`MultipoleExpansion::radiated_power`]: W = ∮ |p|²/(2ρc) r² dΩ = (1/(2ρck²)) Σ |c_lm|²
//!   [W per unit q²] (orthonormal Y_lm, |h_l| → 1/(kr)).
//! * [`MultipoleExpansion::radiation_efficiency`]: σ = W / (½ρc ∫|v_n|² dS) with
//!   |v_n| = ω|u_n| (1 for a large piston-like radiator, (ka)²/(1+(ka)²) for a pulsating sphere
//!   of radius a, (ka)⁴/(4+(ka)⁴) for an oscillating one).
//!
//! # Unknown microphone positions
//!
//! For the real bowl (`examples/bowl`) the microphone positions were not recorded, so the
//! direction of each microphone is unknown and the transfer cannot be evaluated. The documented
//! fallback is the **direction-averaged** transfer: the RMS over all directions of |p| on a sphere
//! of radius R about the centre,
//!
//! p_rms(R) = ( (1/4π) ∮ |p(R, r̂)|² dΩ )^½ = ( (1/4π) Σ |c_lm|² |h_l(kR)|² )^½,
//!
//! exact at any R outside the source sphere by orthonormality, and → √(ρcW/(2πR²)) far away: mode
//! amplitudes then scale with the square root of the radiated power per unit modal amplitude.
//! [`MultipoleExpansion::transfer_unknown_positions`] returns it (a real number, phase 0, because
//! the phase is unknown too) once per microphone, in the same shape as
//! [`MultipoleExpansion::transfer`]. It is right on average over microphone directions, not
//! for any one microphone: a single microphone in a node of a dipole hears nothing. For the bowl
//! it also inherits the fit's own uncertainty (see Limits).
//!
//! # Limits
//!
//! * The series converges outside the smallest sphere about x₀ that holds the sources; the fit
//!   also relies on it at the surface itself (the Rayleigh hypothesis). It is exact for spheres
//!   and good for compact, convex objects (a cube with a point source 2.6 cm off its centre,
//!   ka ≈ 1.7: 6·10⁻⁴ error at L = 6, see the tests). Accuracy drops for elongated objects, for
//!   large ka (more orders than L ≤ 6 are needed once ka ≳ L), and for microphones inside the
//!   bounding sphere ([`MultipoleExpansion::source_radius`]), where the series is evaluated
//!   but not reliable. ε_L says how well the surface motion is reproduced and is the only
//!   warning the fit can give: in the tests ε ≈ 0.08 went with transfer errors of 0.6–2 %,
//!   ε ≈ 0.4–0.5 with 8–70 %.
//! * **Concave and thin-walled objects such as the bowl are outside its reach.** A bowl's
//!   centroid lies in the air of its cavity, so the expansion puts its singularity in the
//!   exterior domain, and the inner surface lies inside the convergence sphere. Measured on
//!   `examples/bowl` (P2, 6010 faces): ε stays at 0.31–0.56 for rigid translations at L = 2…6
//!   (1 kHz); at 50 Hz the axial translation comes out as a monopole (all power in l = 0,
//!   while a rigid translation displaces no net volume and radiates as a dipole); a point
//!   source inside the bottom wall, an exact exterior field, is reproduced at 0.3 m with
//!   75 % (L = 2) to 190 % (L = 6) error. Transfers for such objects are rough guesses, and
//!   the radiated power changes by a factor 2–3 between L = 2 and L = 6.
//! * Free field only: no table, floor or room (no reflections, no scattering), no air
//!   absorption. P1 meshes approximate curved surfaces by flat faces (a 1280-face sphere:
//!   1 % transfer error against 10⁻⁵ with curved P2 faces).
//! * A boundary-element solution of the exterior Helmholtz problem is the step up: it needs
//!   no assumption on where the sources sit, and would handle the bowl (its wall, about 5 mm
//!   thick, puts the fictitious interior frequencies of a plain boundary integral equation
//!   near c/2t ≈ 35 kHz, above the audio band).

use std::collections::{HashMap, HashSet};

use nalgebra::{DMatrix, DVector};
use rustfft::num_complex::Complex64;

use crate::mesh::{ElementOrder, TetMesh, TET10_EDGES};
use crate::numerics::{cross, dot, norm, sub};

/// Highest multipole degree a fit may use ((L+1)² unknowns; 441 at L = 20).
pub const MAX_SUPPORTED_DEGREE: usize = 20;

/// Properties of the air the sound travels in.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Air {
    /// c [m/s].
    pub speed_of_sound: f64,
    /// ρ [kg/m³].
    pub density: f64,
}

impl Default for Air {
    /// Air at about 20 °C: c = 343 m/s, ρ = 1.225 kg/m³.
    fn default() -> Self {
        Air {
            speed_of_sound: 343.0,
            density: 1.225,
        }
    }
}

/// Everything that can be wrong with the input of the radiation model.
#[derive(thiserror::Error, Debug, Clone, PartialEq)]
pub enum RadiationError {
    #[error(
        "the mesh has no boundary faces (no tetrahedra?), so there is no surface to radiate from"
    )]
    NoSurface,
    #[error("the surface has zero total area: every sample weight is 0")]
    ZeroArea,
    #[error("mode vector has {got} values; the mesh has {n_nodes} nodes, so 3 x {n_nodes} = {expected} are needed (u_x, u_y, u_z per node)")]
    ModeLength {
        got: usize,
        expected: usize,
        n_nodes: usize,
    },
    #[error("{what} has {got} entries but the surface has {expected} sample points")]
    LengthMismatch {
        what: &'static str,
        got: usize,
        expected: usize,
    },
    #[error("{what} [{index}] is not finite ({value})")]
    NonFinite {
        what: &'static str,
        index: usize,
        value: f64,
    },
    #[error("sample weight [{index}] is negative ({value} m^2)")]
    NegativeWeight { index: usize, value: f64 },
    #[error("angular frequency must be positive and finite, got {0} rad/s")]
    BadFrequency(f64),
    #[error("air properties must be positive and finite, got c = {speed_of_sound} m/s, rho = {density} kg/m^3")]
    BadAir { speed_of_sound: f64, density: f64 },
    #[error("multipole degree {requested} is above the supported maximum {MAX_SUPPORTED_DEGREE}")]
    DegreeTooHigh { requested: usize },
    #[error("degree {degree} needs {unknowns} coefficients but the surface has only {points} sample points")]
    TooFewPoints {
        degree: usize,
        unknowns: usize,
        points: usize,
    },
    #[error("gain tolerance must lie in [0, 1), got {0}")]
    BadGainTolerance(f64),
    #[error("point [{index}] ({point:?}) is at the expansion centre {centre:?}, where the multipoles are singular")]
    AtCentre {
        index: usize,
        point: [f64; 3],
        centre: [f64; 3],
    },
    #[error("a microphone {distance_m:.3} m from the radiation fit's centre lies inside its source sphere ({source_radius_m:.3} m); the transfer there is not defined")]
    InsideSources {
        distance_m: f64,
        source_radius_m: f64,
    },
    #[error("direction must be a non-zero finite vector, got {0:?}")]
    BadDirection([f64; 3]),
    #[error("radius must be positive and finite, got {0} m")]
    BadRadius(f64),
    #[error("the multipole basis of degree {degree} overflows at k·r = {kr:e} (frequency too low for this degree; lower the degree)")]
    BasisOverflow { degree: usize, kr: f64 },
    #[error("the singular value decomposition of the degree-{degree} least-squares problem did not converge")]
    SvdFailed { degree: usize },
}

// ---------------------------------------------------------------------------------------------
// Special functions
// ---------------------------------------------------------------------------------------------

/// Outgoing spherical Hankel functions h_l⁽¹⁾(x) = j_l(x) + i y_l(x) and their derivatives for
/// l = 0..=l_max at x > 0. y_l by upward recurrence from y₀ = −cos x/x, y₁ = −cos x/x² − sin x/x
/// (stable: y_l grows with l); j_l upward from j₀ = sin x/x, j₁ = sin x/x² − cos x/x where
/// l_max ≤ x (stable there), otherwise by Miller's downward recurrence from l_max + 30 + x,
/// normalised to j₀ or j₁ (upward, j_l would drown in the rounding of y_l once l > x, and the
/// radiating part of the near field, Re(p v̄), lives in j_l). Both obey
/// f_(l+1) = (2l+1)/x f_l − f_(l−1); derivatives h₀' = −h₁, h_l' = h_(l−1) − (l+1)/x h_l.
/// At x ≤ 0 the values are not finite.
pub fn spherical_hankel1(l_max: usize, x: f64) -> (Vec<Complex64>, Vec<Complex64>) {
    let (sin, cos) = x.sin_cos();
    // At least h₀ and h₁, for h₀' = −h₁.
    let n = l_max.max(1);
    let mut y = vec![-cos / x, -cos / (x * x) - sin / x];
    for l in 1..n {
        y.push((2 * l + 1) as f64 / x * y[l] - y[l - 1]);
    }
    let j = spherical_bessel_j(n, x, sin, cos);
    let mut h: Vec<Complex64> = (0..=n).map(|l| Complex64::new(j[l], y[l])).collect();
    let mut dh = vec![-h[1]];
    for l in 1..=n {
        dh.push(h[l - 1] - h[l] * ((l + 1) as f64 / x));
    }
    h.truncate(l_max + 1);
    dh.truncate(l_max + 1);
    (h, dh)
}

/// j_l(x) for l = 0..=n, n ≥ 1 (see [`spherical_hankel1`]); `sin`, `cos` of x given.
fn spherical_bessel_j(n: usize, x: f64, sin: f64, cos: f64) -> Vec<f64> {
    let j0 = sin / x;
    let j1 = sin / (x * x) - cos / x;
    if x >= n as f64 {
        let mut j = vec![j0, j1];
        for l in 1..n {
            j.push((2 * l + 1) as f64 / x * j[l] - j[l - 1]);
        }
        return j;
    }
    let start = n + 30 + x.ceil() as usize;
    let mut f = vec![0.0; start + 2];
    f[start] = 1.0;
    for l in (1..=start).rev() {
        f[l - 1] = (2 * l + 1) as f64 / x * f[l] - f[l + 1];
        if f[l - 1].abs() > 1e250 {
            // Rescale everything computed so far; the normalisation fixes the scale anyway.
            for v in &mut f[l - 1..] {
                *v *= 1e-250;
            }
        }
    }
    let scale = if j0.abs() >= j1.abs() {
        j0 / f[0]
    } else {
        j1 / f[1]
    };
    f.truncate(n + 1);
    f.iter_mut().for_each(|v| *v *= scale);
    f
}

/// Index of (l, m) in coefficient and harmonic vectors: l² + l + m, for |m| ≤ l.
pub fn multipole_index(l: usize, m: i64) -> usize {
    ((l * l + l) as i64 + m) as usize
}

/// The real orthonormal spherical harmonics Y_lm (module docs) at the unit vector `direction`
/// (normalised here; a zero vector gives NaN), and the gradients ∇R_lm of the regular solid
/// harmonics R_lm(x) = |x|^l Y_lm(x/|x|) at that unit vector, for l = 0..=l_max, at
/// [`multipole_index`].
///
/// With Q_lm = r^l P_l^m(cos θ) e^(imφ) (m ≥ 0, no Condon–Shortley phase), polynomials in
/// x, y, z: Q_mm = (2m−1) (x + iy) Q_(m−1)(m−1), Q_(m+1)m = (2m+1) z Q_mm and
/// (l−m+1) Q_(l+1)m = (2l+1) z Q_lm − (l+m) r² Q_(l−1)m; the gradients follow by the product
/// rule through the same recurrences.
pub fn real_spherical_harmonics(l_max: usize, direction: [f64; 3]) -> (Vec<f64>, Vec<[f64; 3]>) {
    let r =
        (direction[0] * direction[0] + direction[1] * direction[1] + direction[2] * direction[2])
            .sqrt();
    let [x, y, z] = direction.map(|c| c / r);
    let n_tri = (l_max + 1) * (l_max + 2) / 2;
    let tri = |l: usize, m: usize| l * (l + 1) / 2 + m;
    let zero = Complex64::new(0.0, 0.0);
    let mut q = vec![zero; n_tri];
    let mut gq = vec![[zero; 3]; n_tri];
    let w = Complex64::new(x, y);
    let grad_w = [Complex64::new(1.0, 0.0), Complex64::new(0.0, 1.0), zero];
    let r2 = x * x + y * y + z * z;
    let grad_r2 = [2.0 * x, 2.0 * y, 2.0 * z];
    q[0] = Complex64::new(1.0, 0.0);
    for m in 0..=l_max {
        if m > 0 {
            let f = (2 * m - 1) as f64;
            let (prev, gprev) = (q[tri(m - 1, m - 1)], gq[tri(m - 1, m - 1)]);
            q[tri(m, m)] = w * prev * f;
            gq[tri(m, m)] = std::array::from_fn(|d| (grad_w[d] * prev + w * gprev[d]) * f);
        }
        if m < l_max {
            let f = (2 * m + 1) as f64;
            let (prev, gprev) = (q[tri(m, m)], gq[tri(m, m)]);
            q[tri(m + 1, m)] = prev * z * f;
            gq[tri(m + 1, m)] =
                std::array::from_fn(|d| (gprev[d] * z + if d == 2 { prev } else { zero }) * f);
        }
        for l in (m + 1)..l_max {
            let a = (2 * l + 1) as f64;
            let b = (l + m) as f64;
            let inv = 1.0 / (l - m + 1) as f64;
            let (ql, gl) = (q[tri(l, m)], gq[tri(l, m)]);
            let (qm, gm) = (q[tri(l - 1, m)], gq[tri(l - 1, m)]);
            q[tri(l + 1, m)] = (ql * z * a - qm * r2 * b) * inv;
            gq[tri(l + 1, m)] = std::array::from_fn(|d| {
                let dz = if d == 2 { ql } else { zero };
                ((gl[d] * z + dz) * a - (qm * grad_r2[d] + gm[d] * r2) * b) * inv
            });
        }
    }
    let n = (l_max + 1) * (l_max + 1);
    let mut values = vec![0.0; n];
    let mut grads = vec![[0.0; 3]; n];
    let four_pi = 4.0 * std::f64::consts::PI;
    for l in 0..=l_max {
        // (l−m)!/(l+m)! built up as m grows.
        let mut ratio = 1.0;
        for m in 0..=l {
            if m > 0 {
                ratio /= ((l + m) * (l - m + 1)) as f64;
            }
            let norm = ((2 * l + 1) as f64 / four_pi * ratio).sqrt();
            let (v, g) = (q[tri(l, m)], gq[tri(l, m)]);
            let centre = l * l + l;
            if m == 0 {
                values[centre] = norm * v.re;
                grads[centre] = g.map(|c| norm * c.re);
            } else {
                let s = std::f64::consts::SQRT_2 * norm;
                values[centre + m] = s * v.re;
                grads[centre + m] = g.map(|c| s * c.re);
                values[centre - m] = s * v.im;
                grads[centre - m] = g.map(|c| s * c.im);
            }
        }
    }
    (values, grads)
}

/// Degree l of the coefficient at index j (inverse of [`multipole_index`] in l).
fn degree_of(j: usize) -> usize {
    let mut l = (j as f64).sqrt() as usize;
    while (l + 1) * (l + 1) <= j {
        l += 1;
    }
    while l * l > j {
        l -= 1;
    }
    l
}

/// Value and gradient of every basis function h_l(k|x−x₀|) Y_lm at `d = x − x₀` (|d| = r > 0),
/// l ≤ l_max (module docs for the gradient).
fn basis_with_gradient(l_max: usize, k: f64, d: [f64; 3]) -> (Vec<Complex64>, Vec<[Complex64; 3]>) {
    let r = norm(d);
    let unit = d.map(|c| c / r);
    let (h, dh) = spherical_hankel1(l_max, k * r);
    let (y, grad_r) = real_spherical_harmonics(l_max, unit);
    let n = y.len();
    let mut values = Vec::with_capacity(n);
    let mut grads = Vec::with_capacity(n);
    for j in 0..n {
        let l = degree_of(j);
        let radial = (dh[l] * k - h[l] * (l as f64 / r)) * y[j];
        let tangential = h[l] / r;
        values.push(h[l] * y[j]);
        grads.push(std::array::from_fn(|c| {
            radial * unit[c] + tangential * grad_r[j][c]
        }));
    }
    (values, grads)
}

// ---------------------------------------------------------------------------------------------
// Surface sampling
// ---------------------------------------------------------------------------------------------

/// Points on a surface with outward unit normals and area weights, where a normal displacement
/// is known. Built by [`SurfaceQuadrature`] from a mesh, or directly (e.g. on an exact sphere).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SurfaceSamples {
    /// Positions [m].
    pub points: Vec<[f64; 3]>,
    /// Outward unit normals.
    pub normals: Vec<[f64; 3]>,
    /// Area weights [m²] (Σ = surface area).
    pub weights: Vec<f64>,
}

impl SurfaceSamples {
    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Σ w [m²].
    pub fn area(&self) -> f64 {
        self.weights.iter().sum()
    }

    /// Σ w x / Σ w [m] (NaN for zero area).
    pub fn area_centroid(&self) -> [f64; 3] {
        let area = self.area();
        let mut c = [0.0; 3];
        for (p, w) in self.points.iter().zip(&self.weights) {
            for d in 0..3 {
                c[d] += w * p[d];
            }
        }
        c.map(|v| v / area)
    }

    fn validate(&self) -> Result<(), RadiationError> {
        let n = self.points.len();
        if n == 0 {
            return Err(RadiationError::NoSurface);
        }
        if self.normals.len() != n {
            return Err(RadiationError::LengthMismatch {
                what: "normals",
                got: self.normals.len(),
                expected: n,
            });
        }
        if self.weights.len() != n {
            return Err(RadiationError::LengthMismatch {
                what: "weights",
                got: self.weights.len(),
                expected: n,
            });
        }
        check_finite("point coordinate", self.points.iter().flatten().copied())?;
        check_finite("normal component", self.normals.iter().flatten().copied())?;
        check_finite("weight", self.weights.iter().copied())?;
        if let Some(index) = self.weights.iter().position(|&w| w < 0.0) {
            return Err(RadiationError::NegativeWeight {
                index,
                value: self.weights[index],
            });
        }
        if self.area() <= 0.0 {
            return Err(RadiationError::ZeroArea);
        }
        Ok(())
    }
}

fn check_finite(
    what: &'static str,
    values: impl Iterator<Item = f64>,
) -> Result<(), RadiationError> {
    for (index, value) in values.enumerate() {
        if !value.is_finite() {
            return Err(RadiationError::NonFinite { what, index, value });
        }
    }
    Ok(())
}

/// Radon's 7-point rule on the triangle, exact to degree 5: barycentric points and weights
/// summing to 1 (multiply by the area).
fn triangle_rule() -> [([f64; 3], f64); 7] {
    let s15 = 15f64.sqrt();
    let (a1, a2) = ((6.0 - s15) / 21.0, (6.0 + s15) / 21.0);
    let (b1, b2) = (1.0 - 2.0 * a1, 1.0 - 2.0 * a2);
    let (w1, w2) = ((155.0 - s15) / 1200.0, (155.0 + s15) / 1200.0);
    let third = 1.0 / 3.0;
    [
        ([third, third, third], 9.0 / 40.0),
        ([b1, a1, a1], w1),
        ([a1, b1, a1], w1),
        ([a1, a1, b1], w1),
        ([b2, a2, a2], w2),
        ([a2, b2, a2], w2),
        ([a2, a2, b2], w2),
    ]
}

/// Points per boundary face of [`SurfaceQuadrature`].
pub const POINTS_PER_FACE: usize = 7;

/// The boundary of a tet mesh sampled for radiation: positions, normals, area weights, and the
/// face shape functions to read any mode's normal displacement there (module docs).
#[derive(Clone, Debug)]
pub struct SurfaceQuadrature {
    samples: SurfaceSamples,
    /// 3 (P1) or 6 (P2) face nodes per point.
    nodes_per_point: usize,
    stencil_nodes: Vec<usize>,
    stencil_values: Vec<f64>,
    n_nodes: usize,
}

impl SurfaceQuadrature {
    /// Samples every boundary face of `mesh` (P1: flat 3-node faces, P2: the curved 6-node
    /// faces) at [`POINTS_PER_FACE`] points.
    pub fn new(mesh: &TetMesh) -> Result<Self, RadiationError> {
        check_finite("node coordinate", mesh.nodes.iter().flatten().copied())?;
        let faces = mesh.boundary_faces();
        if faces.is_empty() {
            return Err(RadiationError::NoSurface);
        }
        let quadratic = mesh.order == ElementOrder::Quadratic;
        // Mid-edge node of every boundary edge (P2 only), found from the tets that own it.
        let mut mid_node: HashMap<(usize, usize), usize> = HashMap::new();
        if quadratic {
            let key = |a: usize, b: usize| if a < b { (a, b) } else { (b, a) };
            let boundary_edges: HashSet<(usize, usize)> = faces
                .iter()
                .flat_map(|f| [key(f[0], f[1]), key(f[1], f[2]), key(f[2], f[0])])
                .collect();
            for e in 0..mesh.n_tets() {
                let t = mesh.tet(e);
                for (k, &(a, b)) in TET10_EDGES.iter().enumerate() {
                    let edge = key(t[a], t[b]);
                    if boundary_edges.contains(&edge) {
                        mid_node.entry(edge).or_insert(t[4 + k]);
                    }
                }
            }
        }
        let nodes_per_point = if quadratic { 6 } else { 3 };
        let n_points = faces.len() * POINTS_PER_FACE;
        let mut samples = SurfaceSamples {
            points: Vec::with_capacity(n_points),
            normals: Vec::with_capacity(n_points),
            weights: Vec::with_capacity(n_points),
        };
        let mut stencil_nodes = Vec::with_capacity(n_points * nodes_per_point);
        let mut stencil_values = Vec::with_capacity(n_points * nodes_per_point);
        let rule = triangle_rule();
        for face in &faces {
            let mut face_nodes = face.to_vec();
            if quadratic {
                for (a, b) in [(face[0], face[1]), (face[1], face[2]), (face[2], face[0])] {
                    let edge = if a < b { (a, b) } else { (b, a) };
                    // Every boundary edge belongs to a tet, so its mid node is in the map.
                    face_nodes.push(mid_node[&edge]);
                }
            }
            let x: Vec<[f64; 3]> = face_nodes.iter().map(|&n| mesh.nodes[n]).collect();
            for &(l, wq) in &rule {
                let (values, d_ds, d_dt) = face_shape(quadratic, l);
                let mut position = [0.0; 3];
                let (mut xs, mut xt) = ([0.0; 3], [0.0; 3]);
                for i in 0..nodes_per_point {
                    for d in 0..3 {
                        position[d] += values[i] * x[i][d];
                        xs[d] += d_ds[i] * x[i][d];
                        xt[d] += d_dt[i] * x[i][d];
                    }
                }
                let area_normal = cross(xs, xt);
                let jacobian = norm(area_normal);
                let normal = if jacobian > 0.0 {
                    area_normal.map(|c| c / jacobian)
                } else {
                    [0.0; 3]
                };
                samples.points.push(position);
                samples.normals.push(normal);
                // Reference triangle area ½, rule weights sum to 1.
                samples.weights.push(0.5 * wq * jacobian);
                stencil_nodes.extend_from_slice(&face_nodes);
                stencil_values.extend_from_slice(&values[..nodes_per_point]);
            }
        }
        Ok(SurfaceQuadrature {
            samples,
            nodes_per_point,
            stencil_nodes,
            stencil_values,
            n_nodes: mesh.n_nodes(),
        })
    }

    /// The sample points, normals and weights.
    pub fn samples(&self) -> &SurfaceSamples {
        &self.samples
    }

    /// u_n = u · n at every sample point for a mode vector `mode` (3 values per node,
    /// node-major), in the mode's length unit (m per unit modal amplitude).
    pub fn normal_displacement(&self, mode: &[f64]) -> Result<Vec<f64>, RadiationError> {
        if mode.len() != 3 * self.n_nodes {
            return Err(RadiationError::ModeLength {
                got: mode.len(),
                expected: 3 * self.n_nodes,
                n_nodes: self.n_nodes,
            });
        }
        check_finite("mode value", mode.iter().copied())?;
        let k = self.nodes_per_point;
        Ok(self
            .samples
            .normals
            .iter()
            .enumerate()
            .map(|(p, normal)| {
                let nodes = &self.stencil_nodes[p * k..(p + 1) * k];
                let values = &self.stencil_values[p * k..(p + 1) * k];
                nodes
                    .iter()
                    .zip(values)
                    .map(|(&node, &v)| {
                        v * dot(
                            *normal,
                            [mode[3 * node], mode[3 * node + 1], mode[3 * node + 2]],
                        )
                    })
                    .sum()
            })
            .collect())
    }
}

/// Face shape functions at barycentric point (L_a, L_b, L_c) with s = L_b, t = L_c: values
/// and ∂/∂s, ∂/∂t, for the 3-node or the 6-node triangle (a, b, c, ab, bc, ca).
fn face_shape(quadratic: bool, l: [f64; 3]) -> ([f64; 6], [f64; 6], [f64; 6]) {
    let [la, lb, lc] = l;
    if !quadratic {
        return (
            [la, lb, lc, 0.0, 0.0, 0.0],
            [-1.0, 1.0, 0.0, 0.0, 0.0, 0.0],
            [-1.0, 0.0, 1.0, 0.0, 0.0, 0.0],
        );
    }
    // ∂L_a/∂s = −1, ∂L_b/∂s = 1, ∂L_c/∂s = 0; ∂L_a/∂t = −1, ∂L_b/∂t = 0, ∂L_c/∂t = 1.
    let values = [
        la * (2.0 * la - 1.0),
        lb * (2.0 * lb - 1.0),
        lc * (2.0 * lc - 1.0),
        4.0 * la * lb,
        4.0 * lb * lc,
        4.0 * lc * la,
    ];
    let d_ds = [
        -(4.0 * la - 1.0),
        4.0 * lb - 1.0,
        0.0,
        4.0 * (la - lb),
        4.0 * lc,
        -4.0 * lc,
    ];
    let d_dt = [
        -(4.0 * la - 1.0),
        0.0,
        4.0 * lc - 1.0,
        -4.0 * lb,
        4.0 * lb,
        4.0 * (la - lc),
    ];
    (values, d_ds, d_dt)
}

// ---------------------------------------------------------------------------------------------
// Fit
// ---------------------------------------------------------------------------------------------

/// How [`fit_multipoles`] works.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MultipoleSettings {
    pub air: Air,
    /// Highest degree tried when choosing L automatically (default 6).
    pub max_degree: usize,
    /// Use exactly this degree instead of choosing one.
    pub degree: Option<usize>,
    /// Choose the smallest L with ε_L² − ε_Lmax² ≤ this (module docs; default 1e-4).
    pub gain_tolerance: f64,
    /// Expansion centre [m] (default: the area centroid of the surface samples).
    pub centre: Option<[f64; 3]>,
}

impl Default for MultipoleSettings {
    fn default() -> Self {
        MultipoleSettings {
            air: Air::default(),
            max_degree: 6,
            degree: None,
            gain_tolerance: 1e-4,
            centre: None,
        }
    }
}

/// The exterior pressure of one mode as a multipole series (module docs), per unit modal
/// amplitude.
#[derive(Clone, Debug, PartialEq)]
pub struct MultipoleExpansion {
    /// x₀ [m].
    pub centre: [f64; 3],
    /// ω [rad/s].
    pub angular_frequency: f64,
    /// k = ω/c [1/m].
    pub wavenumber: f64,
    pub air: Air,
    /// The degree L used.
    pub degree: usize,
    /// c_lm [Pa per unit modal amplitude] at [`multipole_index`], (L+1)² of them.
    pub coefficients: Vec<Complex64>,
    /// Numerical rank of the least-squares problem of the degree used: (L+1)² when the
    /// boundary data determine every multipole; below that, the combinations they cannot see
    /// get the minimum-norm value 0.
    pub rank: usize,
    /// ε_L, the relative boundary residual of the degree used.
    pub residual: f64,
    /// ε_l for l = 0..=L_max (the degrees tried).
    pub residual_by_degree: Vec<f64>,
    /// Largest distance of a surface point from the centre [m]: the series is reliable outside
    /// this sphere.
    pub source_radius: f64,
    /// ∫ |v_n|² dS = ω² ∫ u_n² dS [m⁴/s² per unit modal amplitude²].
    pub surface_velocity_squared: f64,
}

/// Fits the multipole series to a real normal displacement (a mode), see the module docs.
/// `normal_displacement` [m per unit modal amplitude] is given at the sample points;
/// `angular_frequency` ω [rad/s].
pub fn fit_multipoles(
    samples: &SurfaceSamples,
    normal_displacement: &[f64],
    angular_frequency: f64,
    settings: &MultipoleSettings,
) -> Result<MultipoleExpansion, RadiationError> {
    let complex: Vec<Complex64> = normal_displacement
        .iter()
        .map(|&u| Complex64::new(u, 0.0))
        .collect();
    fit_multipoles_complex(samples, &complex, angular_frequency, settings)
}

/// [`fit_multipoles`] for a complex normal displacement (e.g. several modes in phase
/// quadrature, or data from another solver).
pub fn fit_multipoles_complex(
    samples: &SurfaceSamples,
    normal_displacement: &[Complex64],
    angular_frequency: f64,
    settings: &MultipoleSettings,
) -> Result<MultipoleExpansion, RadiationError> {
    samples.validate()?;
    let n = samples.len();
    if normal_displacement.len() != n {
        return Err(RadiationError::LengthMismatch {
            what: "normal displacement",
            got: normal_displacement.len(),
            expected: n,
        });
    }
    check_finite(
        "normal displacement (real part)",
        normal_displacement.iter().map(|u| u.re),
    )?;
    check_finite(
        "normal displacement (imaginary part)",
        normal_displacement.iter().map(|u| u.im),
    )?;
    if !(angular_frequency.is_finite() && angular_frequency > 0.0) {
        return Err(RadiationError::BadFrequency(angular_frequency));
    }
    let air = settings.air;
    if !(air.speed_of_sound.is_finite()
        && air.speed_of_sound > 0.0
        && air.density.is_finite()
        && air.density > 0.0)
    {
        return Err(RadiationError::BadAir {
            speed_of_sound: air.speed_of_sound,
            density: air.density,
        });
    }
    if !(settings.gain_tolerance >= 0.0 && settings.gain_tolerance < 1.0) {
        return Err(RadiationError::BadGainTolerance(settings.gain_tolerance));
    }
    let l_max = match settings.degree {
        Some(d) => d,
        None => settings.max_degree,
    };
    if l_max > MAX_SUPPORTED_DEGREE {
        return Err(RadiationError::DegreeTooHigh { requested: l_max });
    }
    let l_max = match settings.degree {
        Some(d) if (d + 1) * (d + 1) > n => {
            return Err(RadiationError::TooFewPoints {
                degree: d,
                unknowns: (d + 1) * (d + 1),
                points: n,
            })
        }
        Some(d) => d,
        // Automatic: never more unknowns than points.
        None => (0..=l_max)
            .rev()
            .find(|&l| (l + 1) * (l + 1) <= n)
            .unwrap_or(0),
    };
    let centre = match settings.centre {
        Some(c) => {
            check_finite("centre coordinate", c.iter().copied())?;
            c
        }
        None => samples.area_centroid(),
    };
    let k = angular_frequency / air.speed_of_sound;
    let p = (l_max + 1) * (l_max + 1);

    // Distances; the centre must not sit on a sample point.
    let mut source_radius: f64 = 0.0;
    let mut mean_r2 = 0.0;
    for (index, x) in samples.points.iter().enumerate() {
        let r = norm(sub(*x, centre));
        if r == 0.0 {
            return Err(RadiationError::AtCentre {
                index,
                point: *x,
                centre,
            });
        }
        source_radius = source_radius.max(r);
        mean_r2 += samples.weights[index] * r * r;
    }
    let r_ref = (mean_r2 / samples.area()).sqrt();
    // Column scale 1/|k h_l'(k r_ref)| keeps the columns O(1) whatever k r (h_l grows like
    // (kr)^−(l+1) at small kr); the coefficients are unscaled at the end.
    let (_, dh_ref) = spherical_hankel1(l_max, k * r_ref);
    let column_scale: Vec<f64> = (0..p)
        .map(|j| 1.0 / (k * dh_ref[degree_of(j)].norm()))
        .collect();
    if column_scale.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
        return Err(RadiationError::BasisOverflow {
            degree: l_max,
            kr: k * r_ref,
        });
    }

    // Streaming least squares: rows √w (n·∇f_j) scale_j, right-hand side √w u_n (the factor ρω²
    // is put back on the coefficients).
    let zero = Complex64::new(0.0, 0.0);
    let mut r_factor = vec![zero; p * p];
    let mut qb = vec![zero; p];
    let mut leftover = 0.0;
    // Σ w |u_n|² [m⁴]: the data norm (before the factor ρω²) and ∫|v_n|² dS / ω².
    let mut data_norm2 = 0.0;
    let mut row = vec![zero; p];
    for (((x, normal), &w), &u) in samples
        .points
        .iter()
        .zip(&samples.normals)
        .zip(&samples.weights)
        .zip(normal_displacement)
    {
        data_norm2 += w * u.norm_sqr();
        if w == 0.0 {
            continue;
        }
        let sw = w.sqrt();
        let (_, grads) = basis_with_gradient(l_max, k, sub(*x, centre));
        for ((slot, g), scale) in row.iter_mut().zip(&grads).zip(&column_scale) {
            *slot = (g[0] * normal[0] + g[1] * normal[1] + g[2] * normal[2]) * (sw * scale);
        }
        if row.iter().any(|v| !(v.re.is_finite() && v.im.is_finite())) {
            return Err(RadiationError::BasisOverflow {
                degree: l_max,
                kr: k * norm(sub(*x, centre)),
            });
        }
        let beta = givens_insert_row(&mut r_factor, &mut qb, &mut row, u * sw, p);
        leftover += beta.norm_sqr();
    }

    // Each degree's problem is the leading block of R (module docs).
    let mut residual2_by_degree = Vec::with_capacity(l_max + 1);
    let mut solutions = Vec::with_capacity(l_max + 1);
    for l in 0..=l_max {
        let pl = (l + 1) * (l + 1);
        let (y, rank, misfit2) = solve_triangular_block(&r_factor, &qb, p, pl)
            .ok_or(RadiationError::SvdFailed { degree: l })?;
        let tail: f64 = qb[pl..].iter().map(|v| v.norm_sqr()).sum();
        residual2_by_degree.push(misfit2 + tail + leftover);
        solutions.push((y, rank));
    }
    let relative = |r2: f64| {
        if data_norm2 > 0.0 {
            (r2.max(0.0) / data_norm2).sqrt()
        } else {
            0.0
        }
    };
    let residual_by_degree: Vec<f64> = residual2_by_degree.iter().map(|&r2| relative(r2)).collect();
    let degree = match settings.degree {
        Some(d) => d,
        None => {
            let best = residual_by_degree[l_max].powi(2);
            (0..=l_max)
                .find(|&l| residual_by_degree[l].powi(2) - best <= settings.gain_tolerance)
                .unwrap_or(l_max)
        }
    };
    let (y, rank) = solutions.swap_remove(degree);
    let rho_omega2 = air.density * angular_frequency * angular_frequency;
    let coefficients: Vec<Complex64> = y
        .iter()
        .enumerate()
        .map(|(j, v)| v * (column_scale[j] * rho_omega2))
        .collect();
    Ok(MultipoleExpansion {
        centre,
        angular_frequency,
        wavenumber: k,
        air,
        degree,
        coefficients,
        rank,
        residual: residual_by_degree[degree],
        residual_by_degree,
        source_radius,
        surface_velocity_squared: angular_frequency * angular_frequency * data_norm2,
    })
}

/// Rotates one weighted row `a` (length p, right-hand side `beta`) into the upper-triangular
/// `r` (p × p, row-major) and `qb` = Qᴴb by complex Givens rotations; returns what is left of
/// the right-hand side, whose squared magnitude is this row's share of the residual no column
/// can explain. With c = |r_jj|/ρ, s = (r_jj/|r_jj|) ā_j/ρ, ρ = √(|r_jj|² + |a_j|²) the
/// rotation [c s; −s̄ c] maps (r_jj, a_j) to (ρ r_jj/|r_jj|, 0).
fn givens_insert_row(
    r: &mut [Complex64],
    qb: &mut [Complex64],
    a: &mut [Complex64],
    mut beta: Complex64,
    p: usize,
) -> Complex64 {
    for j in 0..p {
        let aj = a[j];
        let a_abs = aj.norm();
        if a_abs == 0.0 {
            continue;
        }
        let rjj = r[j * p + j];
        let r_abs = rjj.norm();
        let (c, s) = if r_abs == 0.0 {
            (0.0, aj.conj() / a_abs)
        } else {
            let rho = r_abs.hypot(a_abs);
            (r_abs / rho, (rjj / r_abs) * aj.conj() / rho)
        };
        let sc = s.conj();
        let row = &mut r[j * p..(j + 1) * p];
        for kk in j..p {
            let (rk, ak) = (row[kk], a[kk]);
            row[kk] = rk * c + s * ak;
            a[kk] = ak * c - sc * rk;
        }
        a[j] = Complex64::new(0.0, 0.0);
        let q = qb[j];
        qb[j] = q * c + s * beta;
        beta = beta * c - sc * q;
    }
    beta
}

/// Solves min ‖R_LL y − qb_L‖ for the leading pl × pl block of the p × p triangular `r` by an
/// SVD of the column-normalised block, dropping singular values below 1e-10 of the largest
/// (multipoles the data cannot distinguish get the minimum-norm value). Returns y, the rank
/// and the squared misfit that remains inside the block; `None` if the SVD does not converge.
fn solve_triangular_block(
    r: &[Complex64],
    qb: &[Complex64],
    p: usize,
    pl: usize,
) -> Option<(Vec<Complex64>, usize, f64)> {
    let block = DMatrix::<Complex64>::from_fn(pl, pl, |i, j| {
        if i <= j {
            r[i * p + j]
        } else {
            Complex64::new(0.0, 0.0)
        }
    });
    let scales: Vec<f64> = (0..pl)
        .map(|j| {
            let s = block.column(j).norm();
            if s > 0.0 {
                1.0 / s
            } else {
                1.0
            }
        })
        .collect();
    let scaled = DMatrix::<Complex64>::from_fn(pl, pl, |i, j| block[(i, j)] * scales[j]);
    let rhs = DVector::<Complex64>::from_iterator(pl, qb[..pl].iter().copied());
    let svd = scaled.clone().try_svd(true, true, f64::EPSILON, 10_000)?;
    let sigma_max = svd.singular_values.iter().cloned().fold(0.0, f64::max);
    let cutoff = 1e-10 * sigma_max;
    let rank = svd
        .singular_values
        .iter()
        .filter(|&&s| s > cutoff && s > 0.0)
        .count();
    let z = if rank == 0 {
        DVector::<Complex64>::zeros(pl)
    } else {
        // `solve` only fails when U or Vᵀ were not computed; both were requested.
        svd.solve(&rhs, cutoff.max(f64::MIN_POSITIVE))
            .unwrap_or_else(|_| DVector::zeros(pl))
    };
    let misfit2 = (&scaled * &z - &rhs).norm_squared();
    let y = (0..pl).map(|j| z[j] * scales[j]).collect();
    Some((y, rank, misfit2))
}

// ---------------------------------------------------------------------------------------------
// Evaluation
// ---------------------------------------------------------------------------------------------

impl MultipoleExpansion {
    fn offset(&self, index: usize, x: [f64; 3]) -> Result<[f64; 3], RadiationError> {
        check_finite("evaluation point coordinate", x.iter().copied())?;
        let d = sub(x, self.centre);
        if norm(d) == 0.0 {
            return Err(RadiationError::AtCentre {
                index,
                point: x,
                centre: self.centre,
            });
        }
        Ok(d)
    }

    /// p(x) [Pa per unit modal amplitude]; reliable outside the source sphere
    /// (|x − x₀| > [`Self::source_radius`]).
    pub fn pressure(&self, x: [f64; 3]) -> Result<Complex64, RadiationError> {
        let d = self.offset(0, x)?;
        let r = norm(d);
        let (h, _) = spherical_hankel1(self.degree, self.wavenumber * r);
        let (y, _) = real_spherical_harmonics(self.degree, d);
        Ok(self
            .coefficients
            .iter()
            .enumerate()
            .map(|(j, c)| c * h[degree_of(j)] * y[j])
            .sum())
    }

    /// ∇p(x) [Pa/m per unit modal amplitude]; the air's normal displacement is then
    /// ∂p/∂n / (ρω²).
    pub fn pressure_gradient(&self, x: [f64; 3]) -> Result<[Complex64; 3], RadiationError> {
        let d = self.offset(0, x)?;
        let (_, grads) = basis_with_gradient(self.degree, self.wavenumber, d);
        let mut g = [Complex64::new(0.0, 0.0); 3];
        for (c, gj) in self.coefficients.iter().zip(grads) {
            for dim in 0..3 {
                g[dim] += c * gj[dim];
            }
        }
        Ok(g)
    }

    /// The pressure at each microphone position [Pa per unit modal amplitude].
    pub fn transfer(&self, microphones: &[[f64; 3]]) -> Result<Vec<Complex64>, RadiationError> {
        microphones
            .iter()
            .enumerate()
            .map(|(index, &x)| {
                self.offset(index, x)?;
                self.pressure(x)
            })
            .collect()
    }

    /// Far-field directivity D(r̂) [Pa·m per unit modal amplitude]: p ≈ D e^(ikr)/r as r → ∞
    /// along `direction` (any non-zero length).
    pub fn far_field(&self, direction: [f64; 3]) -> Result<Complex64, RadiationError> {
        if !direction.iter().all(|c| c.is_finite()) || norm(direction) == 0.0 {
            return Err(RadiationError::BadDirection(direction));
        }
        let (y, _) = real_spherical_harmonics(self.degree, direction);
        let minus_i = Complex64::new(0.0, -1.0);
        Ok(self
            .coefficients
            .iter()
            .enumerate()
            .map(|(j, c)| c * minus_i.powu(degree_of(j) as u32 + 1) * y[j])
            .sum::<Complex64>()
            / self.wavenumber)
    }

    /// W = (1/(2ρck²)) Σ |c_lm|² [W per unit modal amplitude²].
    pub fn radiated_power(&self) -> f64 {
        let sum: f64 = self.coefficients.iter().map(|c| c.norm_sqr()).sum();
        sum / (2.0 * self.air.density * self.air.speed_of_sound * self.wavenumber * self.wavenumber)
    }

    /// σ = W / (½ρc ∫|v_n|² dS) (0 if the surface does not move).
    pub fn radiation_efficiency(&self) -> f64 {
        let reference =
            0.5 * self.air.density * self.air.speed_of_sound * self.surface_velocity_squared;
        if reference > 0.0 {
            self.radiated_power() / reference
        } else {
            0.0
        }
    }

    /// RMS over directions of |p| on the sphere of radius `radius` [m] about the centre:
    /// ((1/4π) Σ |c_lm|² |h_l(kR)|²)^½ [Pa per unit modal amplitude] (module docs).
    pub fn direction_averaged_pressure(&self, radius: f64) -> Result<f64, RadiationError> {
        if !(radius.is_finite() && radius > 0.0) {
            return Err(RadiationError::BadRadius(radius));
        }
        let (h, _) = spherical_hankel1(self.degree, self.wavenumber * radius);
        let sum: f64 = self
            .coefficients
            .iter()
            .enumerate()
            .map(|(j, c)| c.norm_sqr() * h[degree_of(j)].norm_sqr())
            .sum();
        Ok((sum / (4.0 * std::f64::consts::PI)).sqrt())
    }

    /// The fallback for unknown microphone positions (module docs): the direction-averaged
    /// pressure at distance `radius` [m], as a real value (phase unknown, 0) repeated for each
    /// of `n_microphones`, the same shape as [`Self::transfer`].
    pub fn transfer_unknown_positions(
        &self,
        n_microphones: usize,
        radius: f64,
    ) -> Result<Vec<Complex64>, RadiationError> {
        let p = self.direction_averaged_pressure(radius)?;
        Ok(vec![Complex64::new(p, 0.0); n_microphones])
    }
}

mod modes;
pub use modes::{mode_transfers, Listeners, ModeTransfers};

#[cfg(test)]
mod tests;
