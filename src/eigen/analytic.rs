//! Closed-form natural frequencies of free elastic bodies, used as reference
//! solutions for the convergence tests of the FEM eigen-solver.
//!
//! Everything here is pure `std` Rust: no PETSc, no MPI.
//!
//! # 1. Free homogeneous isotropic sphere (Lamb 1882)
//!
//! A sphere of radius `a` \[m\] with Young's modulus `E` \[Pa\], Poisson ratio
//! `ν` \[-\] and density `ρ` \[kg/m³\], all of whose surface is traction free.
//!
//! References:
//! * H. Lamb, "On the vibrations of an elastic sphere",
//!   *Proc. London Math. Soc.* **13** (1882) 189–212 (the original solution;
//!   his §12 gives `k a/π ≈ 0.842` for the gravest spheroidal mode of degree 2).
//! * A. E. H. Love, *A Treatise on the Mathematical Theory of Elasticity*,
//!   4th ed. (1927), chapter on the vibrations of spheres.
//! * A. C. Eringen & E. S. Şuhubi, *Elastodynamics*, vol. II (1975).
//! * Y. Sato & T. Usami, "Basic study on the oscillation of a homogeneous
//!   elastic sphere, Part I", *Geophys. Mag.* **31** (1962) 15–24.
//!
//! ## Speeds and dimensionless frequency
//!
//! ```text
//! μ   = E / (2(1+ν))                 shear modulus           [Pa]
//! λ   = E ν / ((1+ν)(1−2ν))          Lamé's first parameter  [Pa]
//! c_s = sqrt(μ/ρ)                    shear-wave speed        [m/s]
//! c_p = sqrt((λ+2μ)/ρ)               pressure-wave speed     [m/s]
//! γ   = c_s/c_p = sqrt((1−2ν)/(2(1−ν)))                      [-]
//! k   = ω/c_s,  h = ω/c_p            wavenumbers             [1/m]
//! η   = k a = ω a / c_s              (the `x` of this module) [-]
//! ξ   = h a = γ η                                              [-]
//! ```
//!
//! All roots returned by [`torsional_roots`] and [`spheroidal_roots`] are
//! values of `η`; the angular frequency is `ω = η c_s / a` \[rad/s\].
//! Note that for fixed `ν` the roots do not depend on `a`, `E` or `ρ`.
//!
//! ## Displacement potentials
//!
//! With `Y = Y_ℓm(θ, φ)` a spherical harmonic and `j_ℓ` the spherical Bessel
//! function of the first kind, Navier's equation `μ∇²u + (λ+μ)∇∇·u = −ρω²u`
//! is solved inside the sphere (regular at `r = 0`) by
//!
//! ```text
//! u = ∇[A j_ℓ(hr) Y]  +  ∇×∇×[r B j_ℓ(kr) Y]  +  ∇×[r C j_ℓ(kr) Y]
//!     (dilatational)      (poloidal shear)        (toroidal shear)
//! ```
//!
//! (`r` is the position vector.) Write a displacement as
//! `u = U(r) Y e_r + V(r) ∇₁Y + W(r) e_r×∇₁Y`, with `∇₁` the gradient on the
//! unit sphere, and `L = ℓ(ℓ+1)`. The three potentials give
//!
//! ```text
//! U = A h j_ℓ'(hr) + B L j_ℓ(kr)/r
//! V = A j_ℓ(hr)/r  + B (j_ℓ(kr)/r + k j_ℓ'(kr))
//! W = C j_ℓ(kr)
//! ```
//!
//! and the traction on a sphere `r = const` is
//! `σ_rr = λ∇·u + 2μ ∂_r u_r` (with `∇·u = −h² A j_ℓ(hr) Y`) and, for the
//! tangential part, `μ (∂_r u_t − u_t/r + ∇₁u_r / r)`.
//!
//! ## Torsional (toroidal) modes, ℓ ≥ 1
//!
//! `U = V = 0`, and the only traction is `σ_rt = μ (W' − W/r) = 0` at `r = a`:
//!
//! ```text
//! η j_ℓ'(η) − j_ℓ(η) = 0   ⇔   (ℓ−1) j_ℓ(η) − η j_{ℓ+1}(η) = 0        (T)
//! ```
//!
//! using `z j_ℓ'(z) = ℓ j_ℓ(z) − z j_{ℓ+1}(z)`. For ℓ = 1 this is
//! `η j_2(η) = 0`: the root `η = 0` is the rigid rotation
//! (`W = j_1(kr) → kr/3`, i.e. `u = Ω × r`) and is excluded; the others are the
//! zeros of `j_2`. ℓ = 0 gives no motion at all. Multiplicity `2ℓ+1`.
//!
//! ## Spheroidal modes
//!
//! `σ_rr = 0` and `σ_rt = 0` at `r = a`; multiplying by `a²/μ` and using the
//! Bessel equation `z² j'' = −2z j' − (z² − L) j` and `(λ+2μ)/μ · ξ² = η²`:
//!
//! ```text
//! | M11  M12 | |A|          M11 = (2ℓ(ℓ−1) − η²) j_ℓ(ξ) + 4 ξ j_{ℓ+1}(ξ)
//! |          | | | = 0,     M12 = 2L [(ℓ−1) j_ℓ(η) − η j_{ℓ+1}(η)]
//! | M21  M22 | |B|          M21 = 2 [(ℓ−1) j_ℓ(ξ) − ξ j_{ℓ+1}(ξ)]
//!                           M22 = (2(ℓ²−1) − η²) j_ℓ(η) + 2 η j_{ℓ+1}(η)
//! ```
//!
//! (row 1: `σ_rr`, row 2: `σ_rt`; the `A`- and `B`-columns are in units of
//! length² and the whole system is dimensionless after the scaling). The
//! frequency equation is `D(η) = M11 M22 − M12 M21 = 0`          (S)
//!
//! * ℓ = 0 (breathing / radial mode, multiplicity 1): the poloidal field
//!   vanishes identically, only `σ_rr = 0` remains:
//!   `M11 = 4 ξ j_1(ξ) − η² j_0(ξ) = 0`, i.e.
//!   `4 μ j_1(ha) = (λ+2μ) h a j_0(ha)`, or `ξ cot ξ = 1 − η²/4`.
//!   (For `ν → −1` the bulk modulus vanishes and so does this root.)
//! * ℓ = 1: as `ω → 0` both potential fields tend to the same uniform
//!   displacement (a rigid translation), so `D` has a zero of higher order at
//!   `η = 0`; that zero is excluded, the non-zero roots are elastic modes.
//! * ℓ ≥ 2: every root is an elastic mode; multiplicity `2ℓ+1`.
//!
//! Because `j_ℓ(z) ≈ z^ℓ/(2ℓ+1)!!` for small `z`, the determinant is evaluated
//! with the column scalings `s_ℓ(ξ) s_ℓ(η)`, `s_ℓ(z) = z^ℓ/(2ℓ+1)!! > 0`, which
//! leave its sign (and zeros) unchanged and keep high degrees from
//! underflowing. Near `η = 0` the scaled determinant behaves like `η²` for
//! ℓ ≥ 2 and like `η⁴` for ℓ = 1 (the translation): a unit test checks both.
//!
//! ## Checks
//!
//! Besides the unit tests below (closed forms of `j_0..j_3`, the breathing
//! equation, the rigid-body limits, Lamb's `k a/π ≈ 0.842`), the spectrum was
//! compared once with an independent P2 FEM solve (dolfinx, 55k DOF, sphere
//! `a = 0.1 m`, E = 72 GPa, ν = 0.19, ρ = 2700): the 42 lowest elastic
//! eigenvalues match in order and multiplicity (T₂ 13 324.6 Hz ×5,
//! S₂ 14 017.2 ×5, S₁ 17 522.9 ×3, T₃ ×7, S₃ ×7, S₀ 21 015.4 ×1, …) with FEM
//! frequencies 1.6–2.0 ‰ high, 1.65 ‰ of which is the faceted mesh's smaller
//! volume-equivalent radius.
//!
//! # 2. Free–free solid circular cylinder, torsional family
//!
//! For a cylinder of length `L` \[m\] (any radius `R`), take
//! `u = u_θ(r, z) e_θ` with `u_θ = r cos(nπz/L) e^{iωt}`. Then `∇·u = 0`,
//! `(∇²u)_θ = ∂²_r u_θ + ∂_r u_θ / r − u_θ/r² + ∂²_z u_θ = −r (nπ/L)² cos(nπz/L)`,
//! so Navier's equation holds when `ω = nπ c_s / L`. Tractions: on the lateral
//! surface `σ_rθ = μ(∂_r u_θ − u_θ/r) = 0` identically and `σ_rr = σ_rz = 0`;
//! on the end faces `σ_zθ = μ ∂_z u_θ = −μ r (nπ/L) sin(nπz/L) = 0` at
//! `z = 0, L`, and `σ_zz = σ_zr = 0`. Hence
//!
//! ```text
//! ω_n = n π c_s / L,    n = 1, 2, ...      (n = 0: rigid rotation, excluded)
//! ```
//!
//! is exact for the free–free solid (or hollow) circular cylinder of any
//! radius, multiplicity 1. It is only one family of the cylinder's spectrum:
//! the flexural, longitudinal and non-axisymmetric modes have no closed form,
//! so a FEM test must look these frequencies up among its computed ones.
//!
//! # Numerics
//!
//! `j_ℓ` and `j_{ℓ+1}` come from the downward continued fraction for
//! `j_n/j_{n−1}` (Miller's algorithm in ratio form, stable for every `n` and
//! `x`) normalised by the closed form of `j_0` or `j_1`, whichever is larger.
//! Roots are bracketed by a fine scan and refined with Brent's method to an
//! absolute tolerance of `1e-13` (plus a few ulps).

use std::f64::consts::PI;

/// Angular family of a sphere mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum SphereFamily {
    /// Divergence-free, purely tangential (toroidal) motion; ℓ ≥ 1.
    Torsional,
    /// Coupled dilatational/poloidal motion; ℓ = 0 is the breathing mode.
    Spheroidal,
}

/// One (degenerate) natural frequency of the free sphere.
#[derive(Debug, Clone, PartialEq)]
pub struct SphereMode {
    pub family: SphereFamily,
    /// Angular degree ℓ.
    pub degree: usize,
    /// Overtone index n, 0-based, counting only non-zero roots.
    pub overtone: usize,
    /// Number of independent modes at this frequency: 2ℓ+1.
    pub multiplicity: usize,
    /// Angular frequency ω \[rad/s\].
    pub omega: f64,
    /// Frequency ω/2π \[Hz\].
    pub frequency_hz: f64,
}

impl SphereMode {
    /// Generalised eigenvalue `ω²` \[rad²/s²\] as solved for by `K φ = ω² M φ`.
    pub fn eigenvalue(&self) -> f64 {
        self.omega * self.omega
    }
}

/// One torsional natural frequency of a free–free solid circular cylinder.
#[derive(Debug, Clone, PartialEq)]
pub struct CylinderTorsionalMode {
    /// Axial order n ≥ 1 (number of half-waves along the axis).
    pub overtone: usize,
    /// Angular frequency ω = nπ c_s / L \[rad/s\].
    pub omega: f64,
    /// Frequency ω/2π \[Hz\].
    pub frequency_hz: f64,
}

/// Absolute tolerance on the dimensionless roots.
const ROOT_TOL: f64 = 1e-13;
/// Scan step (in η) used to bracket roots.
const SCAN_STEP: f64 = 4e-3;
/// Scan start for ℓ ≥ 1. Near zero the scaled spheroidal determinant is
/// dominated by its `η²` (ℓ ≥ 2) or `η⁴` (ℓ = 1) leading term, computed with a
/// relative cancellation of that size; at `η = 0.01` that still leaves ≥ 8
/// digits for the sign. The lowest non-zero root is above this for every
/// `ν > −0.9999` (the ℓ = 1 spheroidal root behaves like `2 sqrt(1+ν)` as
/// `ν → −1`, where the bulk modulus vanishes).
const SCAN_START: f64 = 0.01;

fn check_poisson(poisson: f64) {
    assert!(
        poisson.is_finite() && poisson > -1.0 && poisson < 0.5,
        "Poisson ratio must lie in (-1, 0.5), got {poisson}"
    );
}

fn check_material(youngs: f64, poisson: f64, density: f64) {
    assert!(
        youngs.is_finite() && youngs > 0.0,
        "Young's modulus must be > 0, got {youngs}"
    );
    assert!(
        density.is_finite() && density > 0.0,
        "density must be > 0, got {density}"
    );
    check_poisson(poisson);
}

/// Shear modulus μ = E/(2(1+ν)) \[Pa\].
pub fn shear_modulus(youngs: f64, poisson: f64) -> f64 {
    youngs / (2.0 * (1.0 + poisson))
}

/// Shear-wave speed c_s = sqrt(μ/ρ) \[m/s\].
pub fn shear_speed(youngs: f64, poisson: f64, density: f64) -> f64 {
    (shear_modulus(youngs, poisson) / density).sqrt()
}

/// Pressure-wave speed c_p = sqrt((λ+2μ)/ρ) \[m/s\].
pub fn pressure_speed(youngs: f64, poisson: f64, density: f64) -> f64 {
    let p_modulus = youngs * (1.0 - poisson) / ((1.0 + poisson) * (1.0 - 2.0 * poisson));
    (p_modulus / density).sqrt()
}

/// Speed ratio γ = c_s/c_p = sqrt((1−2ν)/(2(1−ν))), depends on ν only.
pub fn speed_ratio(poisson: f64) -> f64 {
    ((1.0 - 2.0 * poisson) / (2.0 * (1.0 - poisson))).sqrt()
}

// ---------------------------------------------------------------------------
// Spherical Bessel functions
// ---------------------------------------------------------------------------

/// Downward continued fraction: returns `r_n = j_n(x)/j_{n−1}(x)` for
/// `n = 1..=n_max` (index 0 unused). Requires `x > 0`.
fn bessel_ratios(n_max: usize, x: f64) -> Vec<f64> {
    // Start far enough above both n_max and x that the neglected tail is
    // below double precision: beyond the turning point n ≈ x the functions
    // decay super-exponentially.
    let start = n_max.max(x.ceil() as usize) + 40 + (4.0 * x.cbrt()).ceil() as usize;
    let mut ratios = vec![0.0; n_max + 1];
    // r_{start+1} ≈ x/(2 start + 3) (small-argument limit), good enough as seed.
    let mut r = x / (2.0 * start as f64 + 3.0);
    for n in (1..=start).rev() {
        r = x / ((2 * n + 1) as f64 - x * r);
        if n <= n_max {
            ratios[n] = r;
        }
    }
    ratios
}

/// `j_0(x) = sin x / x` and `j_1(x) = sin x / x² − cos x / x`, with series
/// for small `x` (where the closed form of `j_1` cancels).
fn j0_j1(x: f64) -> (f64, f64) {
    if x.abs() < 0.1 {
        let x2 = x * x;
        // Taylor series to O(x^10): more than enough for |x| < 0.1.
        let j0 = 1.0 - x2 / 6.0 * (1.0 - x2 / 20.0 * (1.0 - x2 / 42.0 * (1.0 - x2 / 72.0)));
        let j1 =
            x / 3.0 * (1.0 - x2 / 10.0 * (1.0 - x2 / 28.0 * (1.0 - x2 / 54.0 * (1.0 - x2 / 88.0))));
        (j0, j1)
    } else {
        let (s, c) = x.sin_cos();
        (s / x, (s / x - c) / x)
    }
}

/// Spherical Bessel function of the first kind `j_l(x)`, for `x ≥ 0`.
///
/// Accurate to a few ulps relative to `max |j_n(x)|` nearby; underflows to
/// zero (correctly) for very high orders at small arguments.
pub fn spherical_jn(l: usize, x: f64) -> f64 {
    assert!(
        x >= 0.0 && x.is_finite(),
        "spherical_jn: x must be finite and >= 0, got {x}"
    );
    let (a, _) = scaled_pair(l, x);
    // Undo the scaling s_l(x) = x^l / (2l+1)!! in log space.
    if a == 0.0 {
        return 0.0;
    }
    if x == 0.0 {
        return if l == 0 { 1.0 } else { 0.0 };
    }
    let mut log_s = l as f64 * x.ln();
    for k in 1..=l {
        log_s -= ((2 * k + 1) as f64).ln();
    }
    a * log_s.exp()
}

/// Scaled pair `(j_l(x)/s_l(x), j_{l+1}(x)/s_l(x))` with `s_l(x) = x^l/(2l+1)!!`.
/// Both stay O(1)..O(moderate) for small `x` and high `l`, where `j_l` itself
/// would underflow. At `x = 0` returns `(1, 0)`.
fn scaled_pair(l: usize, x: f64) -> (f64, f64) {
    if x == 0.0 {
        return (1.0, 0.0);
    }
    let ratios = bessel_ratios(l + 1, x);
    let (j0, j1) = j0_j1(x);
    // Normalise on whichever of j0, j1 is larger in magnitude (they cannot be
    // small together: j0² + j1² ≈ 1/x² for large x, j0 ≈ 1 for small x).
    let mut a;
    if j0.abs() >= j1.abs() || l == 0 {
        a = j0;
        for (n, r) in ratios.iter().enumerate().take(l + 1).skip(1) {
            a *= r * (2 * n + 1) as f64 / x;
        }
    } else {
        // start at j1 / s_1 = 3 j1 / x
        a = 3.0 * j1 / x;
        for (n, r) in ratios.iter().enumerate().take(l + 1).skip(2) {
            a *= r * (2 * n + 1) as f64 / x;
        }
    }
    let b = a * ratios[l + 1];
    (a, b)
}

// ---------------------------------------------------------------------------
// Characteristic functions
// ---------------------------------------------------------------------------

/// Torsional characteristic function `(ℓ−1) j_ℓ(η) − η j_{ℓ+1}(η)`, scaled by
/// `1/s_ℓ(η) > 0` (same zeros and sign). `η > 0`.
pub fn torsional_characteristic(l: usize, eta: f64) -> f64 {
    let (a, b) = scaled_pair(l, eta);
    (l as f64 - 1.0) * a - eta * b
}

/// Spheroidal characteristic function of degree `l` at `η = ω a / c_s > 0`:
/// the determinant `D` of the module docs divided by `s_ℓ(ξ) s_ℓ(η) > 0`;
/// for ℓ = 0, `M11/η² = 4γ² j_1(ξ)/ξ − j_0(ξ)`.
pub fn spheroidal_characteristic(l: usize, poisson: f64, eta: f64) -> f64 {
    check_poisson(poisson);
    spheroidal_char_gamma(l, speed_ratio(poisson), eta)
}

fn spheroidal_char_gamma(l: usize, gamma: f64, eta: f64) -> f64 {
    let xi = gamma * eta;
    let (ap, bp) = scaled_pair(l, xi);
    if l == 0 {
        // 4 ξ j1(ξ) − η² j0(ξ), divided by η².
        return 4.0 * gamma * gamma * (bp / xi) - ap;
    }
    let (as_, bs) = scaled_pair(l, eta);
    let lf = l as f64;
    let big_l = lf * (lf + 1.0);
    let eta2 = eta * eta;
    let m11 = (2.0 * lf * (lf - 1.0) - eta2) * ap + 4.0 * xi * bp;
    let m21 = 2.0 * ((lf - 1.0) * ap - xi * bp);
    let m12 = 2.0 * big_l * ((lf - 1.0) * as_ - eta * bs);
    let m22 = (2.0 * (lf * lf - 1.0) - eta2) * as_ + 2.0 * eta * bs;
    m11 * m22 - m12 * m21
}

// ---------------------------------------------------------------------------
// Root finding
// ---------------------------------------------------------------------------

/// Brent's method on a bracket `[a, b]` with `f(a) f(b) < 0`.
fn brent<F: Fn(f64) -> f64>(f: &F, mut a: f64, mut b: f64, mut fa: f64, mut fb: f64) -> f64 {
    if fa == 0.0 {
        return a;
    }
    if fb == 0.0 {
        return b;
    }
    debug_assert!(fa.signum() != fb.signum());
    let mut c = a;
    let mut fc = fa;
    let mut d = b - a;
    let mut e = d;
    for _ in 0..200 {
        if fb.signum() == fc.signum() {
            c = a;
            fc = fa;
            d = b - a;
            e = d;
        }
        if fc.abs() < fb.abs() {
            a = b;
            b = c;
            c = a;
            fa = fb;
            fb = fc;
            fc = fa;
        }
        let tol = 2.0 * f64::EPSILON * b.abs() + 0.5 * ROOT_TOL;
        let m = 0.5 * (c - b);
        if m.abs() <= tol || fb == 0.0 {
            return b;
        }
        if e.abs() >= tol && fa.abs() > fb.abs() {
            // interpolation (secant or inverse quadratic)
            let s = fb / fa;
            let (mut p, mut q);
            if a == c {
                p = 2.0 * m * s;
                q = 1.0 - s;
            } else {
                let qq = fa / fc;
                let r = fb / fc;
                p = s * (2.0 * m * qq * (qq - r) - (b - a) * (r - 1.0));
                q = (qq - 1.0) * (r - 1.0) * (s - 1.0);
            }
            if p > 0.0 {
                q = -q;
            } else {
                p = -p;
            }
            if 2.0 * p < (3.0 * m * q - (tol * q).abs()).min((e * q).abs()) {
                e = d;
                d = p / q;
            } else {
                d = m;
                e = m;
            }
        } else {
            d = m;
            e = m;
        }
        a = b;
        fa = fb;
        b += if d.abs() > tol { d } else { tol.copysign(m) };
        fb = f(b);
    }
    b
}

/// Scans `f` upwards from `x_start` in steps of [`SCAN_STEP`], returning the
/// refined roots, until `count` are found or `x` exceeds `x_stop`.
fn scan_roots<F: Fn(f64) -> f64>(f: F, x_start: f64, x_stop: f64, count: usize) -> Vec<f64> {
    let mut roots = Vec::new();
    if count == 0 {
        return roots;
    }
    let mut x0 = x_start;
    let mut f0 = f(x0);
    let mut i = 0u64;
    while x0 < x_stop {
        i += 1;
        let x1 = (x_start + i as f64 * SCAN_STEP).min(x_stop);
        let f1 = f(x1);
        if f0 == 0.0 {
            roots.push(x0);
        } else if f1 != 0.0 && f0.signum() != f1.signum() {
            roots.push(brent(&f, x0, x1, f0, f1));
        }
        if roots.len() >= count {
            break;
        }
        x0 = x1;
        f0 = f1;
    }
    roots.truncate(count);
    roots
}

/// The first `count` non-zero roots `η = ω a / c_s` of the torsional frequency
/// equation `(ℓ−1) j_ℓ(η) − η j_{ℓ+1}(η) = 0`, ascending. ℓ = 0 has no
/// torsional motion and returns an empty vector; for ℓ = 1 the rigid-rotation
/// root `η = 0` is excluded.
pub fn torsional_roots(l: usize, count: usize) -> Vec<f64> {
    if l == 0 {
        return Vec::new();
    }
    scan_roots(
        |x| torsional_characteristic(l, x),
        SCAN_START,
        f64::INFINITY,
        count,
    )
}

/// The first `count` non-zero roots `η = ω a / c_s` of the spheroidal
/// frequency equation of degree `l` for Poisson ratio `poisson`, ascending.
/// ℓ = 0 gives the breathing modes; for ℓ = 1 the rigid-translation zero at
/// `η = 0` is excluded.
pub fn spheroidal_roots(l: usize, poisson: f64, count: usize) -> Vec<f64> {
    check_poisson(poisson);
    let gamma = speed_ratio(poisson);
    let start = if l == 0 { 1e-3 } else { SCAN_START };
    scan_roots(
        |x| spheroidal_char_gamma(l, gamma, x),
        start,
        f64::INFINITY,
        count,
    )
}

/// All natural frequencies of a free sphere below `f_max_hz`, ascending in ω
/// (ties: torsional first, then by degree). Rigid-body modes (ω = 0) are
/// excluded; each entry stands for `multiplicity = 2ℓ+1` eigenpairs.
///
/// Units: `radius` \[m\], `youngs` \[Pa\], `density` \[kg/m³\], `f_max_hz` \[Hz\].
///
/// # Panics
/// On non-positive radius, modulus or density, or `ν ∉ (−1, 0.5)`.
pub fn sphere_modes(
    radius: f64,
    youngs: f64,
    poisson: f64,
    density: f64,
    f_max_hz: f64,
) -> Vec<SphereMode> {
    assert!(
        radius.is_finite() && radius > 0.0,
        "radius must be > 0, got {radius}"
    );
    check_material(youngs, poisson, density);
    let cs = shear_speed(youngs, poisson, density);
    let gamma = speed_ratio(poisson);
    let mut modes = Vec::new();
    if f_max_hz.is_nan() || f_max_hz <= 0.0 {
        return modes;
    }
    let eta_max = 2.0 * PI * f_max_hz * radius / cs;
    // For ℓ ≥ 2 every root lies above 0.55 (ℓ+½) for all ν ∈ (−1, 0.5) (the
    // fundamental is a Rayleigh-type surface wave, η ≈ (ℓ+½) c_R/c_s with
    // c_R/c_s ≥ 0.69; torsional roots lie above ℓ; checked in the tests), so
    // degrees up to 2 η_max + 2 are more than enough.
    let l_max = (2.0 * eta_max).ceil() as usize + 2;
    let push = |modes: &mut Vec<SphereMode>, family, l: usize, roots: Vec<f64>| {
        for (n, eta) in roots.into_iter().enumerate() {
            let omega = eta * cs / radius;
            modes.push(SphereMode {
                family,
                degree: l,
                overtone: n,
                multiplicity: 2 * l + 1,
                omega,
                frequency_hz: omega / (2.0 * PI),
            });
        }
    };
    for l in 0..=l_max {
        if l >= 1 {
            let t = scan_roots(
                |x| torsional_characteristic(l, x),
                SCAN_START,
                eta_max,
                usize::MAX,
            );
            push(&mut modes, SphereFamily::Torsional, l, t);
        }
        let start = if l == 0 { 1e-3 } else { SCAN_START };
        let s = scan_roots(
            |x| spheroidal_char_gamma(l, gamma, x),
            start,
            eta_max,
            usize::MAX,
        );
        push(&mut modes, SphereFamily::Spheroidal, l, s);
    }
    // A root found exactly at the scan end may sit a hair above f_max.
    modes.retain(|m| m.frequency_hz < f_max_hz);
    modes.sort_by(|a, b| {
        a.omega
            .partial_cmp(&b.omega)
            .unwrap()
            .then(a.family.cmp(&b.family))
            .then(a.degree.cmp(&b.degree))
    });
    modes
}

/// Expands `modes` into one ω per eigenpair (each repeated `multiplicity`
/// times), ascending: directly comparable with a sorted FEM spectrum with
/// its six rigid modes removed.
pub fn omegas_with_multiplicity(modes: &[SphereMode]) -> Vec<f64> {
    let mut out: Vec<f64> = modes
        .iter()
        .flat_map(|m| std::iter::repeat_n(m.omega, m.multiplicity))
        .collect();
    out.sort_by(|a, b| a.partial_cmp(b).unwrap());
    out
}

/// Torsional natural frequencies `ω_n = nπ c_s / L` (n ≥ 1) of a free–free
/// solid circular cylinder of length `length` \[m\], below `f_max_hz`. Exact
/// for any radius; see the module docs for the proof and for the other
/// (non-closed-form) families this leaves out.
///
/// # Panics
/// On non-positive length, modulus or density, or `ν ∉ (−1, 0.5)`.
pub fn cylinder_torsional_modes(
    length: f64,
    youngs: f64,
    poisson: f64,
    density: f64,
    f_max_hz: f64,
) -> Vec<CylinderTorsionalMode> {
    assert!(
        length.is_finite() && length > 0.0,
        "length must be > 0, got {length}"
    );
    check_material(youngs, poisson, density);
    let cs = shear_speed(youngs, poisson, density);
    let mut out = Vec::new();
    let mut n = 1usize;
    loop {
        let omega = n as f64 * PI * cs / length;
        let f = omega / (2.0 * PI);
        if f.is_nan() || f >= f_max_hz {
            break;
        }
        out.push(CylinderTorsionalMode {
            overtone: n,
            omega,
            frequency_hz: f,
        });
        n += 1;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol * b.abs().max(1e-300)
    }

    // --- Bessel functions -------------------------------------------------

    /// Closed forms of j_0..j_3.
    fn j_closed(l: usize, x: f64) -> f64 {
        let (s, c) = x.sin_cos();
        match l {
            0 => s / x,
            1 => s / (x * x) - c / x,
            2 => (3.0 / (x * x) - 1.0) * s / x - 3.0 * c / (x * x),
            3 => (15.0 / (x * x * x) - 6.0 / x) * s / x - (15.0 / (x * x) - 1.0) * c / x,
            _ => unreachable!(),
        }
    }

    #[test]
    fn bessel_matches_closed_forms() {
        // At moderate/large x the closed forms are accurate.
        for &x in &[1.3, 2.0, 3.7, 5.5, 10.0, 27.3, 80.1] {
            for l in 0..=3 {
                let got = spherical_jn(l, x);
                let want = j_closed(l, x);
                assert!(
                    (got - want).abs() < 2e-15 * (1.0 / x).max(want.abs()) * 8.0,
                    "l={l} x={x}: {got} vs {want}"
                );
            }
        }
    }

    #[test]
    fn bessel_small_argument_series() {
        // j_l(x) ≈ x^l/(2l+1)!! (1 − x²/(2(2l+3))) for small x.
        for l in [0usize, 1, 2, 5, 10, 30] {
            let x: f64 = 1e-3;
            let mut dfact = 1.0;
            for k in 1..=l {
                dfact *= (2 * k + 1) as f64;
            }
            let want = x.powi(l as i32) / dfact * (1.0 - x * x / (2.0 * (2 * l + 3) as f64));
            let got = spherical_jn(l, x);
            assert!(close(got, want, 1e-12), "l={l}: {got} vs {want}");
        }
    }

    #[test]
    fn bessel_sum_rule_and_wronskian_like_identity() {
        // Σ (2n+1) j_n(x)² = 1 and the three-term recurrence.
        for &x in &[0.3, 1.0, 4.2, 17.0, 63.5, 150.0] {
            let n_max = (x as usize) + 60;
            let s: f64 = (0..=n_max)
                .map(|n| (2 * n + 1) as f64 * spherical_jn(n, x).powi(2))
                .sum();
            assert!((s - 1.0).abs() < 1e-13, "x={x}: sum rule {s}");
            for n in 1..20 {
                let lhs = spherical_jn(n - 1, x) + spherical_jn(n + 1, x);
                let rhs = (2 * n + 1) as f64 / x * spherical_jn(n, x);
                assert!(
                    (lhs - rhs).abs() < 1e-14 * (1.0 + rhs.abs()) * 10.0,
                    "x={x} n={n}"
                );
            }
        }
    }

    #[test]
    fn bessel_zero_free_near_j0_zero() {
        // Normalisation switches to j1 near zeros of j0 (x = π).
        let x = PI;
        assert!((spherical_jn(1, x) - 1.0 / PI).abs() < 1e-15);
        assert!(spherical_jn(0, x).abs() < 1e-15);
        assert!((spherical_jn(2, x) - 3.0 / (PI * PI)).abs() < 1e-15);
    }

    // --- Torsional roots --------------------------------------------------

    #[test]
    fn torsional_l1_are_zeros_of_j2() {
        // ℓ = 1: η j_2(η) = 0; zeros of j_2 solve tan x = 3x/(3 − x²).
        let r = torsional_roots(1, 3);
        for &x in &r {
            assert!(j_closed(2, x).abs() < 1e-14, "{x}");
        }
        assert!(close(r[0], 5.763_459_196_894_55, 1e-13), "{}", r[0]);
        // rigid rotation excluded: first root far from zero
        assert!(r[0] > 5.0);
    }

    #[test]
    fn torsional_l2_fundamental() {
        // ℓ = 2: j_2(η) = η j_3(η). Classical value η ≈ 2.5011 (Lamb 1882:
        // k a/π ≈ 0.796). Checked against the closed forms.
        let r = torsional_roots(2, 2);
        assert!((r[0] - 2.5011).abs() < 1e-4, "{}", r[0]);
        let f = |x: f64| j_closed(2, x) - x * j_closed(3, x);
        assert!(f(r[0]).abs() < 1e-13);
        assert!(f(r[1]).abs() < 1e-13);
        assert!((r[1] - 7.136).abs() < 1e-3, "{}", r[1]);
    }

    #[test]
    fn torsional_roots_above_degree() {
        for l in [3usize, 10, 40] {
            let r = torsional_roots(l, 2);
            assert!(r[0] > l as f64, "l={l}: {}", r[0]);
            assert!(r[0] < r[1]);
        }
    }

    // --- Spheroidal roots -------------------------------------------------

    /// Breathing equation ξ cot ξ = 1 − η²/4 written without poles:
    /// ξ cos ξ − (1 − η²/4) sin ξ.
    fn breathing_closed(gamma: f64, eta: f64) -> f64 {
        let xi = gamma * eta;
        xi * xi.cos() - (1.0 - eta * eta / 4.0) * xi.sin()
    }

    #[test]
    fn breathing_mode_closed_form() {
        for &nu in &[-0.5, 0.0, 0.19, 0.25, 0.3, 0.45] {
            let g = speed_ratio(nu);
            for eta in spheroidal_roots(0, nu, 4) {
                assert!(
                    breathing_closed(g, eta).abs() < 1e-12 * eta * eta,
                    "nu={nu} eta={eta}"
                );
            }
        }
        // ν = 1/4 (λ = μ): ξ cot ξ = 1 − 3ξ²/4 → ξ = h a ≈ 2.5635 (the
        // classical h a/π ≈ 0.816 of Lamb and Love), η = √3 ξ.
        let eta = spheroidal_roots(0, 0.25, 1)[0];
        let xi = eta * speed_ratio(0.25);
        assert!((xi - 2.5635).abs() < 1e-4, "xi = {xi}");
        assert!((xi / PI - 0.816).abs() < 1e-3);
    }

    #[test]
    fn breathing_mode_vanishes_with_bulk_modulus() {
        // ν → −1: K = λ + 2μ/3 → 0 and the breathing root goes to zero.
        let a = spheroidal_roots(0, -0.9, 1)[0];
        let b = spheroidal_roots(0, -0.99, 1)[0];
        let c = spheroidal_roots(0, -0.999, 1)[0];
        assert!(a > b && b > c && c < 0.2, "{a} {b} {c}");
    }

    #[test]
    fn spheroidal_l2_fundamental_poisson_quarter() {
        // The "football" mode: η ≈ 2.6399 for ν = 1/4 (Lamb 1882 §12 quotes
        // k a/π ≈ 0.84).
        let r = spheroidal_roots(2, 0.25, 1)[0];
        assert!((r - 2.6399).abs() < 1e-4, "{r}");
        assert!((r / PI - 0.84).abs() < 3e-3);
        // Steel with c_p = 6009 m/s, c_s = 3212 m/s (ν ≈ 0.300) reproduces
        // the k a/π = 0.842 quoted from Lamb's §12.
        let nu = {
            let g2 = (3212.0f64 / 6009.0).powi(2);
            (1.0 - 2.0 * g2) / (2.0 * (1.0 - g2))
        };
        let r = spheroidal_roots(2, nu, 1)[0];
        assert!((r / PI - 0.842).abs() < 5e-4, "{}", r / PI);
    }

    #[test]
    fn spheroidal_determinant_matches_unscaled_closed_forms() {
        // Recompute D from the closed-form j_2, j_3 (no scaling) at ℓ = 2 and
        // check it vanishes at the computed roots.
        let nu = 0.3;
        let g = speed_ratio(nu);
        let det = |eta: f64| {
            let l = 2.0;
            let xi = g * eta;
            let (jp, jp1) = (j_closed(2, xi), j_closed(3, xi));
            let (js, js1) = (j_closed(2, eta), j_closed(3, eta));
            let m11 = (2.0 * l * (l - 1.0) - eta * eta) * jp + 4.0 * xi * jp1;
            let m21 = 2.0 * ((l - 1.0) * jp - xi * jp1);
            let m12 = 2.0 * 6.0 * ((l - 1.0) * js - eta * js1);
            let m22 = (2.0 * (l * l - 1.0) - eta * eta) * js + 2.0 * eta * js1;
            m11 * m22 - m12 * m21
        };
        for eta in spheroidal_roots(2, nu, 5) {
            // scale: each product is O(1)·O(j²); compare with neighbours
            let d0 = det(eta);
            let d1 = det(eta + 1e-6);
            assert!(
                d0.abs() < 1e-7 * d1.abs().max(1e-12),
                "eta={eta}: {d0} vs {d1}"
            );
        }
    }

    #[test]
    fn rigid_body_limits() {
        // Scaled determinant near η = 0: ~η² for ℓ ≥ 2, ~η⁴ for ℓ = 1 (the
        // translation makes the ℓ = 1 determinant vanish to higher order).
        for &nu in &[0.0, 0.25, 0.4] {
            let g = speed_ratio(nu);
            let p = |l: usize| {
                let (x1, x2) = (0.02, 0.04);
                let d1 = spheroidal_char_gamma(l, g, x1);
                let d2 = spheroidal_char_gamma(l, g, x2);
                (d2 / d1).abs().ln() / 2f64.ln()
            };
            assert!((p(1) - 4.0).abs() < 0.05, "nu={nu}: l=1 order {}", p(1));
            assert!((p(2) - 2.0).abs() < 0.05, "nu={nu}: l=2 order {}", p(2));
            assert!((p(3) - 2.0).abs() < 0.05, "nu={nu}: l=3 order {}", p(3));
        }
        // Torsional ℓ = 1: (ℓ−1) j_1 − η j_2 = −η j_2 → scaled ~ −η²/5·…→ 0:
        // the rotation root sits at η = 0.
        let t = torsional_characteristic(1, 1e-4);
        assert!(t.abs() < 1e-7);
        // Its first non-zero root is the first zero of j_2.
        assert!(close(torsional_roots(1, 1)[0], 5.763_459_196_894_55, 1e-13));
    }

    #[test]
    fn l1_spheroidal_roots_are_genuine() {
        for &nu in &[0.0, 0.19, 0.25, 0.45] {
            let r = spheroidal_roots(1, nu, 3);
            assert!(r[0] > 2.0, "nu={nu}: {:?}", r);
            assert!(r.windows(2).all(|w| w[1] > w[0] + 1e-6));
        }
    }

    #[test]
    fn roots_converge_to_tolerance() {
        for (l, nu) in [(2usize, 0.25), (5, 0.19), (1, 0.3), (0, 0.1)] {
            let g = speed_ratio(nu);
            for eta in spheroidal_roots(l, nu, 4) {
                let lo = spheroidal_char_gamma(l, g, eta - 2e-13);
                let hi = spheroidal_char_gamma(l, g, eta + 2e-13);
                assert!(
                    lo.signum() != hi.signum() || lo == 0.0 || hi == 0.0,
                    "l={l} eta={eta}"
                );
            }
        }
        for eta in torsional_roots(3, 4) {
            let lo = torsional_characteristic(3, eta - 2e-13);
            let hi = torsional_characteristic(3, eta + 2e-13);
            assert!(lo.signum() != hi.signum(), "eta={eta}");
        }
    }

    #[test]
    fn high_degrees_do_not_underflow_and_approach_rayleigh_limit() {
        // For large ℓ the fundamental spheroidal mode is a Rayleigh surface
        // wave: η/(ℓ+½) → c_R/c_s ≈ 0.9194 for ν = 1/4, from above.
        let r60 = spheroidal_roots(60, 0.25, 1)[0] / 60.5;
        let r150 = spheroidal_roots(150, 0.25, 1)[0] / 150.5;
        assert!(r60 > r150 && r150 > 0.9194 && r150 < 0.935, "{r60} {r150}");
        // The lower bound used by `sphere_modes` to stop at ℓ = 2 η_max + 2:
        // η > 0.55 (ℓ+½) for ℓ ≥ 2, even at extreme ν.
        for &nu in &[-0.9999, -0.95, -0.5, 0.0, 0.25, 0.49] {
            for l in [2usize, 3, 5, 12, 40] {
                let r = spheroidal_roots(l, nu, 1)[0];
                assert!(r > 0.55 * (l as f64 + 0.5), "nu={nu} l={l}: {r}");
                assert!(torsional_roots(l, 1)[0] > l as f64);
            }
        }
        // ℓ = 1 near ν = −1: root ≈ 2 sqrt(1+ν), still found above the scan start.
        let r = spheroidal_roots(1, -0.999, 1)[0];
        assert!((r - 2.0 * 0.001f64.sqrt()).abs() < 0.005, "{r}");
    }

    // --- sphere_modes -----------------------------------------------------

    #[test]
    fn sphere_modes_assembles_families() {
        // Steel-ish sphere, a = 0.1 m.
        let (a, e, nu, rho) = (0.1, 200e9, 0.25, 7800.0);
        let cs = shear_speed(e, nu, rho);
        let f_max = 12.0 * cs / (2.0 * PI * a); // η_max = 12
        let modes = sphere_modes(a, e, nu, rho, f_max);
        assert!(modes.windows(2).all(|w| w[0].omega <= w[1].omega));
        assert!(modes
            .iter()
            .all(|m| m.frequency_hz < f_max && m.omega > 0.0));
        // Lowest: ℓ=2 torsional (2.5011) then ℓ=2 spheroidal (2.6399).
        assert_eq!(modes[0].family, SphereFamily::Torsional);
        assert_eq!(
            (modes[0].degree, modes[0].overtone, modes[0].multiplicity),
            (2, 0, 5)
        );
        assert_eq!(modes[1].family, SphereFamily::Spheroidal);
        assert_eq!(modes[1].degree, 2);
        assert!(close(
            modes[0].omega * a / cs,
            torsional_roots(2, 1)[0],
            1e-14
        ));
        // Cross-check every entry against the per-degree root functions.
        for m in &modes {
            let eta = m.omega * a / cs;
            let want = match m.family {
                SphereFamily::Torsional => torsional_roots(m.degree, m.overtone + 1)[m.overtone],
                SphereFamily::Spheroidal => {
                    spheroidal_roots(m.degree, nu, m.overtone + 1)[m.overtone]
                }
            };
            assert!(close(eta, want, 1e-13), "{m:?}");
            assert!(close(m.frequency_hz, m.omega / (2.0 * PI), 1e-15));
            assert_eq!(m.multiplicity, 2 * m.degree + 1);
        }
        // Nothing missed: count roots per degree independently.
        for l in 0..20 {
            let nt = if l == 0 {
                0
            } else {
                torsional_roots(l, 10)
                    .into_iter()
                    .filter(|&x| x < 12.0)
                    .count()
            };
            let ns = spheroidal_roots(l, nu, 10)
                .into_iter()
                .filter(|&x| x < 12.0)
                .count();
            let got_t = modes
                .iter()
                .filter(|m| m.family == SphereFamily::Torsional && m.degree == l)
                .count();
            let got_s = modes
                .iter()
                .filter(|m| m.family == SphereFamily::Spheroidal && m.degree == l)
                .count();
            assert_eq!((got_t, got_s), (nt, ns), "l={l}");
        }
        let w = omegas_with_multiplicity(&modes);
        assert_eq!(w.len(), modes.iter().map(|m| m.multiplicity).sum::<usize>());
        assert!(w[..5].iter().all(|&x| x == modes[0].omega));
    }

    #[test]
    fn sphere_modes_scale_with_radius_and_speed() {
        let m1 = sphere_modes(0.05, 72e9, 0.19, 2700.0, 200e3);
        let m2 = sphere_modes(0.10, 72e9, 0.19, 2700.0, 100e3);
        assert_eq!(m1.len(), m2.len());
        for (a, b) in m1.iter().zip(&m2) {
            assert!(close(a.omega, 2.0 * b.omega, 1e-12));
        }
        assert!(sphere_modes(0.1, 72e9, 0.19, 2700.0, 0.0).is_empty());
    }

    // --- cylinder ---------------------------------------------------------

    #[test]
    fn cylinder_torsion() {
        let (len, e, nu, rho) = (0.5, 72e9, 0.19, 2700.0);
        let cs = shear_speed(e, nu, rho);
        let f1 = cs / (2.0 * len);
        let modes = cylinder_torsional_modes(len, e, nu, rho, 3.5 * f1);
        assert_eq!(modes.len(), 3);
        for (i, m) in modes.iter().enumerate() {
            assert_eq!(m.overtone, i + 1);
            assert!(close(m.frequency_hz, (i + 1) as f64 * f1, 1e-14));
            assert!(close(m.omega, (i + 1) as f64 * PI * cs / len, 1e-14));
        }
    }

    #[test]
    fn cylinder_field_satisfies_equations() {
        // u_θ = r cos(kz): check Navier's θ-equation and the tractions by
        // finite differences (independent of the hand derivation).
        let (e, nu, rho, len) = (72e9, 0.19, 2700.0, 0.3);
        let mu = shear_modulus(e, nu);
        let m = &cylinder_torsional_modes(len, e, nu, rho, 1e9)[1];
        let k = m.overtone as f64 * PI / len;
        let u = |r: f64, z: f64| r * (k * z).cos();
        let h = 1e-4;
        let (r, z) = (0.013, 0.071);
        let urr = (u(r + h, z) - 2.0 * u(r, z) + u(r - h, z)) / (h * h);
        let ur = (u(r + h, z) - u(r - h, z)) / (2.0 * h);
        let uzz = (u(r, z + h) - 2.0 * u(r, z) + u(r, z - h)) / (h * h);
        let lap = urr + ur / r - u(r, z) / (r * r) + uzz;
        assert!(close(mu * lap, -rho * m.omega * m.omega * u(r, z), 1e-5));
        // σ_rθ = μ(∂_r u_θ − u_θ/r) = 0 anywhere (so on any lateral radius)
        assert!((ur - u(r, z) / r).abs() < 1e-8);
        // σ_zθ = μ ∂_z u_θ = 0 at z = 0 and z = L
        for zz in [0.0, len] {
            let uz = (u(r, zz + h) - u(r, zz - h)) / (2.0 * h);
            assert!(uz.abs() < 1e-9, "{uz}");
        }
    }
}
