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
            SphereFamily::Spheroidal => spheroidal_roots(m.degree, nu, m.overtone + 1)[m.overtone],
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
