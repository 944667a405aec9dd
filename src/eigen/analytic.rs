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
mod tests;
