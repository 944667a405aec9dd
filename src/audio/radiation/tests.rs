//! Tests of the radiation model against closed forms: the special functions, the pulsating
//! and the oscillating sphere, an off-centre source, a point source inside a cube (any field of
//! sources inside the body is an exact exterior solution), the mesh sampling's convergence,
//! and the bowl (timing, and its limits as measured).
//!
//! Exact solutions (e^(−iωt), module docs), for a sphere of radius a moving with normal
//! displacement u_n (so ∂p/∂r = ρω² u_n at r = a):
//!
//! * pulsating, u_n = U: p = A h₀(kr) with A = ρω²U/(k h₀'(ka)); written out with the normal
//!   velocity v₀ = −iωU, p(r) = ρc v₀ (a/r) (−ika)/(1 − ika) e^(ik(r−a)), and
//!   W = 2πa² ρc |v₀|² (ka)²/(1 + (ka)²);
//! * oscillating (rigid translation U along z), u_n = U cos θ: p = A h₁(kr) cos θ with
//!   A = ρω²U/(k h₁'(ka)), h₁(x) = −e^(ix)(x + i)/x², h₁'(x) = e^(ix)(−ix² + 2x + 2i)/x³;
//!   far away p → −(A/k) cos θ e^(ikr)/r, and σ = (ka)⁴/(4 + (ka)⁴).

use super::*;
use crate::mesh::{lift_to_quadratic, ElementOrder, TetMesh, TET10_EDGES};
use std::f64::consts::PI;

const I: Complex64 = Complex64::new(0.0, 1.0);

fn c(re: f64) -> Complex64 {
    Complex64::new(re, 0.0)
}

/// h₀ and h₁ written out (independent of the recurrence under test).
fn h0_exact(x: f64) -> Complex64 {
    -I * (I * x).exp() / x
}
fn h1_exact(x: f64) -> Complex64 {
    -(I * x).exp() * (x + I) / (x * x)
}
fn dh1_exact(x: f64) -> Complex64 {
    (I * x).exp() * (-I * x * x + 2.0 * x + 2.0 * I) / (x * x * x)
}

/// Equal-area Fibonacci points on the sphere of radius a about `centre`, exact normals.
fn fibonacci_sphere(n: usize, a: f64, centre: [f64; 3]) -> SurfaceSamples {
    let golden = PI * (3.0 - 5f64.sqrt());
    let mut s = SurfaceSamples::default();
    for i in 0..n {
        let z = 1.0 - (2 * i + 1) as f64 / n as f64;
        let rho = (1.0 - z * z).sqrt();
        let phi = golden * i as f64;
        let unit = [rho * phi.cos(), rho * phi.sin(), z];
        s.points
            .push(std::array::from_fn(|d| centre[d] + a * unit[d]));
        s.normals.push(unit);
        s.weights.push(4.0 * PI * a * a / n as f64);
    }
    s
}

/// Directions and weights of a product rule on the unit sphere (Gauss–Legendre in cos θ,
/// uniform in φ), exact for spherical polynomials up to degree 2q−1.
fn sphere_rule(q: usize) -> Vec<([f64; 3], f64)> {
    let (nodes, weights) = crate::fem::quadrature::gauss_legendre_01(q);
    let n_phi = 2 * q;
    let mut out = Vec::new();
    for (t, w) in nodes.iter().zip(&weights) {
        let z = 2.0 * t - 1.0;
        let rho = (1.0 - z * z).sqrt();
        for j in 0..n_phi {
            let phi = 2.0 * PI * j as f64 / n_phi as f64;
            out.push((
                [rho * phi.cos(), rho * phi.sin(), z],
                2.0 * w * 2.0 * PI / n_phi as f64,
            ));
        }
    }
    out
}

/// A tet mesh of the ball of radius a: an icosahedron subdivided `level` times with its
/// vertices on the sphere, each surface triangle coned to the centre (node 0). With
/// `quadratic`, lifted to 10-node tets whose boundary mid-edge nodes are moved onto the
/// sphere (curved, isoparametric faces).
fn coned_icosphere(level: usize, a: f64, quadratic: bool) -> TetMesh {
    let g = (1.0 + 5f64.sqrt()) / 2.0;
    let mut v: Vec<[f64; 3]> = Vec::new();
    for s1 in [-1.0, 1.0] {
        for s2 in [-1.0, 1.0] {
            v.push([0.0, s1, s2 * g]);
            v.push([s1, s2 * g, 0.0]);
            v.push([s2 * g, 0.0, s1]);
        }
    }
    let unit = |p: [f64; 3]| {
        let n = norm(p);
        p.map(|x| x / n)
    };
    let mut vertices: Vec<[f64; 3]> = v.iter().map(|&p| unit(p)).collect();
    // Faces: vertex triples at mutual distance 2 (the icosahedron's edge), outward order.
    let mut faces = Vec::new();
    for i in 0..12 {
        for j in i + 1..12 {
            for k in j + 1..12 {
                let close = |a: usize, b: usize| (norm(sub(v[a], v[b])) - 2.0).abs() < 1e-9;
                if close(i, j) && close(j, k) && close(i, k) {
                    let outward = dot(v[i], cross(v[j], v[k])) > 0.0;
                    faces.push(if outward { [i, j, k] } else { [i, k, j] });
                }
            }
        }
    }
    assert_eq!(faces.len(), 20);
    for _ in 0..level {
        let mut mid: HashMap<(usize, usize), usize> = HashMap::new();
        let mut next = Vec::new();
        for f in &faces {
            let mut m = [0; 3];
            for (e, (a_, b_)) in [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])]
                .into_iter()
                .enumerate()
            {
                let key = (a_.min(b_), a_.max(b_));
                m[e] = *mid.entry(key).or_insert_with(|| {
                    vertices.push(unit(std::array::from_fn(|d| {
                        vertices[a_][d] + vertices[b_][d]
                    })));
                    vertices.len() - 1
                });
            }
            next.push([f[0], m[0], m[2]]);
            next.push([m[0], f[1], m[1]]);
            next.push([m[2], m[1], f[2]]);
            next.push([m[0], m[1], m[2]]);
        }
        faces = next;
    }
    let mut nodes = vec![[0.0; 3]];
    nodes.extend(vertices.iter().map(|p| p.map(|x| a * x)));
    let connectivity = faces
        .iter()
        .flat_map(|f| [0, f[0] + 1, f[1] + 1, f[2] + 1])
        .collect();
    let linear = TetMesh {
        nodes,
        connectivity,
        order: ElementOrder::Linear,
    };
    if !quadratic {
        return linear;
    }
    let mut m = lift_to_quadratic(&linear);
    for e in 0..m.n_tets() {
        let t = m.tet(e).to_vec();
        for (k, &(i, j)) in TET10_EDGES.iter().enumerate() {
            if t[i] != 0 && t[j] != 0 {
                let p = m.nodes[t[4 + k]];
                let r = norm(p);
                m.nodes[t[4 + k]] = p.map(|x| a * x / r);
            }
        }
    }
    m
}

/// The nodal vector of a displacement field u(x).
fn nodal_field(mesh: &TetMesh, u: impl Fn([f64; 3]) -> [f64; 3]) -> Vec<f64> {
    mesh.nodes.iter().flat_map(|&x| u(x)).collect()
}

fn rel(a: Complex64, b: Complex64) -> f64 {
    (a - b).norm() / b.norm()
}

// ---- special functions -------------------------------------------------------------------

#[test]
fn hankel_functions_match_closed_forms_wronskian_and_finite_differences() {
    for &x in &[0.03, 0.4, 1.0, 3.7, 25.0] {
        let (h, dh) = spherical_hankel1(12, x);
        assert!(rel(h[0], h0_exact(x)) < 1e-14, "h0({x})");
        assert!(rel(h[1], h1_exact(x)) < 1e-14, "h1({x})");
        assert!(rel(dh[1], dh1_exact(x)) < 1e-13, "h1'({x})");
        // h₂ = i e^(ix) (x² + 3ix − 3)/x³ (from j₂, y₂).
        let h2 = I * (I * x).exp() * (x * x + 3.0 * I * x - 3.0) / (x * x * x);
        assert!(rel(h[2], h2) < 1e-13, "h2({x}): {} vs {h2}", h[2]);
        for l in 0..=12 {
            // Wronskian j_l y_l' − j_l' y_l = 1/x², i.e. Im(conj(h) h') = 1/x².
            let w = (h[l].conj() * dh[l]).im * x * x;
            assert!((w - 1.0).abs() < 1e-10, "Wronskian l={l} x={x}: {w}");
            let step = 1e-6 * x;
            let (hp, _) = spherical_hankel1(12, x + step);
            let (hm, _) = spherical_hankel1(12, x - step);
            let fd = (hp[l] - hm[l]) / (2.0 * step);
            assert!(rel(fd, dh[l]) < 1e-7, "h_{l}'({x}): fd {fd} vs {}", dh[l]);
        }
        // j₂ written out, on both branches of the j_l computation (upward above l_max = 12,
        // Miller below): exact relative to j₂ itself, not just to |h₂|.
        let j2 = (3.0 / (x * x * x) - 1.0 / x) * x.sin() - 3.0 * x.cos() / (x * x);
        if x > 0.1 {
            assert!(
                (h[2].re - j2).abs() < 1e-12 * j2.abs(),
                "j2({x}): {} vs {j2}",
                h[2].re
            );
        }
        // Far away h_l → (−i)^(l+1) e^(ix)/x.
        if x > 20.0 {
            let far = (-I).powu(3) * (I * x).exp() / x;
            assert!((h[2] - far).norm() < 0.2 * far.norm());
        }
    }
}

#[test]
fn bessel_part_is_accurate_at_small_argument_and_on_both_branches() {
    // j_l(x) = x^l/(2l+1)!! (1 − x²/(2(2l+3)) + …): the radiating part of the near field.
    let x = 1e-3;
    let (h, _) = spherical_hankel1(15, x);
    let mut double_factorial = 1.0;
    for (l, hl) in h.iter().enumerate() {
        if l > 0 {
            double_factorial *= (2 * l + 1) as f64;
        }
        let series =
            x.powi(l as i32) / double_factorial * (1.0 - x * x / (2.0 * (2 * l + 3) as f64));
        assert!(
            (hl.re / series - 1.0).abs() < 1e-10,
            "j_{l}({x}) = {} vs {series}",
            hl.re
        );
    }
    assert_eq!(h.len(), 16);
    // Just below and above the switch x = l_max agree with each other.
    let (below, _) = spherical_hankel1(10, 9.999_999);
    let (above, _) = spherical_hankel1(9, 9.999_999);
    for l in 0..=9 {
        assert!(
            (below[l] - above[l]).norm() < 1e-13 * above[l].norm(),
            "l={l}"
        );
    }
}

#[test]
fn real_harmonics_are_orthonormal_and_their_solid_gradients_match_finite_differences() {
    let l_max = 8;
    let p = (l_max + 1) * (l_max + 1);
    let mut gram = vec![0.0; p * p];
    for (dir, w) in sphere_rule(12) {
        let (y, _) = real_spherical_harmonics(l_max, dir);
        for i in 0..p {
            for j in 0..p {
                gram[i * p + j] += w * y[i] * y[j];
            }
        }
    }
    for i in 0..p {
        for j in 0..p {
            let expected = if i == j { 1.0 } else { 0.0 };
            assert!(
                (gram[i * p + j] - expected).abs() < 1e-12,
                "<Y_{i}, Y_{j}> = {}",
                gram[i * p + j]
            );
        }
    }
    // Known low orders.
    let d = [0.36, -0.48, 0.8];
    let (y, _) = real_spherical_harmonics(2, d);
    assert!((y[0] - 0.5 / PI.sqrt()).abs() < 1e-15);
    let c1 = (3.0 / (4.0 * PI)).sqrt();
    assert!((y[multipole_index(1, -1)] - c1 * d[1]).abs() < 1e-15);
    assert!((y[multipole_index(1, 0)] - c1 * d[2]).abs() < 1e-15);
    assert!((y[multipole_index(1, 1)] - c1 * d[0]).abs() < 1e-15);
    let y20 = (5.0 / (16.0 * PI)).sqrt() * (3.0 * d[2] * d[2] - 1.0);
    assert!((y[multipole_index(2, 0)] - y20).abs() < 1e-14);
    // ∇R_lm at the unit vector against central differences of R_lm(x) = |x|^l Y_lm(x̂).
    let solid = |x: [f64; 3]| {
        let r = norm(x);
        let (y, _) = real_spherical_harmonics(l_max, x);
        (0..p)
            .map(|j| r.powi(degree_of(j) as i32) * y[j])
            .collect::<Vec<_>>()
    };
    let (_, grads) = real_spherical_harmonics(l_max, d);
    let h = 1e-6;
    for dim in 0..3 {
        let mut xp = d;
        let mut xm = d;
        xp[dim] += h;
        xm[dim] -= h;
        let (sp, sm) = (solid(xp), solid(xm));
        for j in 0..p {
            let fd = (sp[j] - sm[j]) / (2.0 * h);
            assert!(
                (fd - grads[j][dim]).abs() < 1e-7 * (1.0 + fd.abs()),
                "∂R_{j}/∂x_{dim}: fd {fd} vs {}",
                grads[j][dim]
            );
        }
    }
    assert_eq!(degree_of(0), 0);
    assert_eq!(degree_of(3), 1);
    assert_eq!(degree_of(4), 2);
    assert_eq!(degree_of(48), 6);
    assert_eq!(multipole_index(6, 6), 48);
}

#[test]
fn basis_functions_solve_helmholtz_and_their_gradient_matches_finite_differences() {
    let (l_max, k) = (6, 7.0);
    let x = [0.21, -0.13, 0.34];
    let (f0, grads) = basis_with_gradient(l_max, k, x);
    // Fourth-order central differences (error O(h⁴)), step 1e-3 of |x| ≈ 0.42.
    let h = 1e-3;
    let mut laplacian = vec![c(0.0); f0.len()];
    let mut second_size = vec![0.0; f0.len()];
    for dim in 0..3 {
        let shifted = |steps: f64| {
            let mut y = x;
            y[dim] += steps * h;
            basis_with_gradient(l_max, k, y).0
        };
        let (fp2, fp, fm, fm2) = (shifted(2.0), shifted(1.0), shifted(-1.0), shifted(-2.0));
        for j in 0..f0.len() {
            let fd = (fm2[j] - fm[j] * 8.0 + fp[j] * 8.0 - fp2[j]) / (12.0 * h);
            assert!(
                (fd - grads[j][dim]).norm() < 1e-7 * grads[j].iter().map(|g| g.norm()).sum::<f64>(),
                "basis {j} ∂/∂x_{dim}: {fd} vs {}",
                grads[j][dim]
            );
            let second =
                (-fp2[j] + fp[j] * 16.0 - f0[j] * 30.0 + fm[j] * 16.0 - fm2[j]) / (12.0 * h * h);
            laplacian[j] += second;
            second_size[j] += second.norm();
        }
    }
    for j in 0..f0.len() {
        let helmholtz = laplacian[j] + f0[j] * (k * k);
        assert!(
            helmholtz.norm() < 1e-7 * second_size[j],
            "basis {j}: Δf + k²f = {helmholtz} (second derivatives ~{})",
            second_size[j]
        );
    }
}

#[test]
fn triangle_rule_is_exact_to_degree_five() {
    // ∫ over the reference triangle of s^i t^j = i! j! / (i+j+2)!.
    let fact = |n: u32| (1..=n).map(|v| v as f64).product::<f64>();
    for i in 0..=5u32 {
        for j in 0..=(5 - i) {
            let q: f64 = triangle_rule()
                .iter()
                .map(|(l, w)| 0.5 * w * l[1].powi(i as i32) * l[2].powi(j as i32))
                .sum();
            let exact = fact(i) * fact(j) / fact(i + j + 2);
            assert!((q - exact).abs() < 1e-15, "s^{i} t^{j}: {q} vs {exact}");
        }
    }
}

// ---- spheres with exact geometry -----------------------------------------------------------

#[test]
fn pulsating_sphere_matches_the_exact_monopole_in_magnitude_phase_and_power() {
    let air = Air::default();
    let (rho, c0) = (air.density, air.speed_of_sound);
    let a = 0.1;
    let samples = fibonacci_sphere(400, a, [0.02, -0.01, 0.03]);
    let centre = [0.02, -0.01, 0.03];
    for &ka in &[0.1, 1.0, 5.0] {
        let k = ka / a;
        let omega = k * c0;
        let u = 1e-6; // normal displacement amplitude [m]
        let settings = MultipoleSettings {
            centre: Some(centre),
            ..Default::default()
        };
        let fit = fit_multipoles(&samples, &vec![u; samples.len()], omega, &settings).unwrap();
        assert_eq!(
            fit.degree, 0,
            "ka={ka}: a monopole needs no more ({:?})",
            fit.residual_by_degree
        );
        assert!(fit.residual < 1e-10, "ka={ka}: residual {}", fit.residual);
        let v0 = -I * omega * u;
        for &r in &[a, 2.0 * a, 10.0 * a, 100.0 * a] {
            let exact =
                rho * c0 * v0 * (a / r) * (-I * ka) / (1.0 - I * ka) * (I * k * (r - a)).exp();
            let dir = [0.6, 0.0, -0.8];
            let x = std::array::from_fn(|d| centre[d] + r * dir[d]);
            let p = fit.pressure(x).unwrap();
            assert!(
                (p.norm() / exact.norm() - 1.0).abs() < 1e-9,
                "ka={ka} r={r}: |p| {} vs {}",
                p.norm(),
                exact.norm()
            );
            let phase = (p / exact).arg();
            assert!(
                phase.abs() < 1e-9,
                "ka={ka} r={r}: phase off by {phase} rad"
            );
            // The fitted field obeys the boundary condition at the surface: ∂p/∂r = ρω²u.
            if r == a {
                let g = fit.pressure_gradient(x).unwrap();
                let dp_dr = g[0] * dir[0] + g[1] * dir[1] + g[2] * dir[2];
                assert!(rel(dp_dr, c(rho * omega * omega * u)) < 1e-9);
            }
        }
        let w_exact = 2.0 * PI * a * a * rho * c0 * v0.norm_sqr() * ka * ka / (1.0 + ka * ka);
        assert!(
            (fit.radiated_power() / w_exact - 1.0).abs() < 1e-9,
            "ka={ka}: W {} vs {w_exact}",
            fit.radiated_power()
        );
        assert!((fit.radiation_efficiency() - ka * ka / (1.0 + ka * ka)).abs() < 1e-9);
        // The direction average of a monopole is its pressure; far away it is √(ρcW/(2πR²)).
        let big_r = 7.0 * a;
        let avg = fit.direction_averaged_pressure(big_r).unwrap();
        let p = fit
            .pressure([centre[0], centre[1] + big_r, centre[2]])
            .unwrap();
        assert!((avg / p.norm() - 1.0).abs() < 1e-12);
        let far = 1e5 * a;
        let far_avg = fit.direction_averaged_pressure(far).unwrap();
        let from_power = (rho * c0 * fit.radiated_power() / (2.0 * PI * far * far)).sqrt();
        assert!(
            (far_avg / from_power - 1.0).abs() < 1e-6,
            "{far_avg} vs {from_power}"
        );
        let fallback = fit.transfer_unknown_positions(3, big_r).unwrap();
        assert_eq!(fallback, vec![c(avg); 3]);
    }
}

#[test]
fn oscillating_sphere_matches_the_exact_dipole_in_directivity_magnitude_and_power() {
    let air = Air::default();
    let (rho, c0) = (air.density, air.speed_of_sound);
    let a = 0.05;
    let samples = fibonacci_sphere(600, a, [0.0; 3]);
    for &ka in &[0.1, 1.0, 5.0] {
        let k = ka / a;
        let omega = k * c0;
        let u = 2e-6;
        // Rigid translation along z: u_n = u n_z.
        let un: Vec<f64> = samples.normals.iter().map(|n| u * n[2]).collect();
        let fit = fit_multipoles(
            &samples,
            &un,
            omega,
            &MultipoleSettings {
                centre: Some([0.0; 3]),
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(fit.degree, 1, "ka={ka}: {:?}", fit.residual_by_degree);
        assert!(
            fit.residual_by_degree[0] > 0.99 && fit.residual < 1e-10,
            "ka={ka}: {:?}",
            fit.residual_by_degree
        );
        let amp = rho * omega * omega * u / (k * dh1_exact(ka));
        for &r in &[a, 3.0 * a, 20.0 * a] {
            for &theta in &[0.0, 0.4, 1.1, PI / 2.0 - 0.1, 2.5] {
                let x = [
                    r * theta.sin() * 0.8,
                    r * theta.sin() * 0.6,
                    r * theta.cos(),
                ];
                let exact = amp * h1_exact(k * r) * theta.cos();
                let p = fit.pressure(x).unwrap();
                assert!(
                    (p - exact).norm() < 1e-9 * (amp * h1_exact(k * r)).norm(),
                    "ka={ka} r={r} θ={theta}: {p} vs {exact}"
                );
            }
        }
        // Far field: D(θ) = −(A/k) cos θ, so |D(θ)|/|D(0)| = |cos θ| and the phase is fixed.
        let d0 = fit.far_field([0.0, 0.0, 1.0]).unwrap();
        assert!(
            rel(d0, -amp / k) < 1e-9,
            "ka={ka}: D(0) {d0} vs {}",
            -amp / k
        );
        for &theta in &[0.3f64, 1.0, 2.0, 3.0] {
            let d = fit.far_field([theta.sin(), 0.0, theta.cos()]).unwrap();
            assert!(
                (d - d0 * theta.cos()).norm() < 1e-9 * d0.norm(),
                "ka={ka} θ={theta}"
            );
        }
        // The far field is the large-r limit of the pressure.
        // (The next term of h₁ is i/(kr) relative: 1e-7 here.)
        let far_r = 1e8 * a;
        let p_far = fit.pressure([0.0, 0.0, far_r]).unwrap();
        assert!(
            rel(p_far, d0 * (I * k * far_r).exp() / far_r) < 1e-6,
            "ka={ka}: {p_far} vs {}",
            d0 * (I * k * far_r).exp() / far_r
        );
        let sigma = ka.powi(4) / (4.0 + ka.powi(4));
        let w_exact = sigma * 0.5 * rho * c0 * (omega * u).powi(2) * 4.0 * PI * a * a / 3.0;
        assert!(
            (fit.radiated_power() / w_exact - 1.0).abs() < 1e-9,
            "ka={ka}: W {} vs {w_exact}",
            fit.radiated_power()
        );
        // σ divides by ∫|v_n|² dS, here the equal-weight quadrature of cos²θ (error ~1e-6).
        let v2: f64 = un
            .iter()
            .zip(&samples.weights)
            .map(|(x, w)| w * (omega * x).powi(2))
            .sum();
        assert!(
            (fit.radiation_efficiency() - fit.radiated_power() / (0.5 * rho * c0 * v2)).abs()
                < 1e-12 * sigma
        );
        assert!(
            (fit.radiation_efficiency() / sigma - 1.0).abs() < 1e-5,
            "ka={ka}: σ {} vs {sigma}",
            fit.radiation_efficiency()
        );
        // Direction average of a dipole: |A h₁(kR)| / √3.
        let big_r = 4.0 * a;
        let avg = fit.direction_averaged_pressure(big_r).unwrap();
        assert!((avg / ((amp * h1_exact(k * big_r)).norm() / 3f64.sqrt()) - 1.0).abs() < 1e-9);
    }
}

#[test]
fn a_quadrupole_is_found_although_the_dipole_order_adds_nothing() {
    let samples = fibonacci_sphere(500, 1.0, [0.0; 3]);
    let un: Vec<f64> = samples
        .normals
        .iter()
        .map(|n| real_spherical_harmonics(2, *n).0[multipole_index(2, 0)])
        .collect();
    let fit = fit_multipoles(
        &samples,
        &un,
        2.0 * 343.0,
        &MultipoleSettings {
            centre: Some([0.0; 3]),
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(fit.degree, 2, "{:?}", fit.residual_by_degree);
    let r = &fit.residual_by_degree;
    assert!(r[0] > 0.99 && r[1] > 0.99 && r[2] < 1e-10, "{r:?}");
    assert_eq!(r.len(), 7);
    // All the power sits in (2, 0).
    let total: f64 = fit.coefficients.iter().map(|c| c.norm_sqr()).sum();
    assert!(fit.coefficients[multipole_index(2, 0)].norm_sqr() > (1.0 - 1e-12) * total);
}

#[test]
fn an_off_centre_source_needs_higher_orders_and_converges_with_l() {
    // A point source at s inside the unit sphere: p = h₀(k|x − s|). Its normal derivative on
    // the sphere is the data; the fit about the sphere's centre must reproduce p outside.
    let (a, k) = (1.0, 2.0);
    let air = Air::default();
    let omega = k * air.speed_of_sound;
    let s = [0.3, 0.2, -0.25];
    let samples = fibonacci_sphere(3000, a, [0.0; 3]);
    let field = |x: [f64; 3]| {
        let d = sub(x, s);
        let r = norm(d);
        let dh0 = -h1_exact(k * r) * k; // h₀' = −h₁
        (h0_exact(k * r), d.map(|v| dh0 * (v / r)))
    };
    let rho_omega2 = air.density * omega * omega;
    let un: Vec<Complex64> = samples
        .points
        .iter()
        .zip(&samples.normals)
        .map(|(&x, n)| {
            let (_, g) = field(x);
            (g[0] * n[0] + g[1] * n[1] + g[2] * n[2]) / rho_omega2
        })
        .collect();
    let mics: Vec<[f64; 3]> = sphere_rule(3)
        .into_iter()
        .map(|(d, _)| d.map(|v| 3.0 * a * v))
        .collect();
    let mut errors = Vec::new();
    for l in [0, 1, 2, 4, 6] {
        let settings = MultipoleSettings {
            degree: Some(l),
            centre: Some([0.0; 3]),
            ..Default::default()
        };
        let fit = fit_multipoles_complex(&samples, &un, omega, &settings).unwrap();
        let p = fit.transfer(&mics).unwrap();
        let err = mics
            .iter()
            .zip(&p)
            .map(|(&x, &pi)| (pi - field(x).0).norm())
            .fold(0.0, f64::max)
            / mics.iter().map(|&x| field(x).0.norm()).fold(0.0, f64::max);
        errors.push((l, err, fit.residual));
    }
    println!("off-centre source (|s| = {:.3} a, mics at 3a): (L, max rel. error, boundary residual) {errors:?}", norm(s));
    assert!(
        errors[0].1 > 0.1,
        "a monopole alone cannot place the source: {errors:?}"
    );
    for w in errors.windows(2) {
        assert!(
            w[1].1 < w[0].1 && w[1].2 < w[0].2,
            "error and residual must fall with L: {errors:?}"
        );
    }
    assert!(
        errors[4].1 < 1e-3 && errors[4].2 < 1e-2,
        "L = 6: {errors:?}"
    );
    // The default (automatic) choice goes to high order too.
    let auto = fit_multipoles_complex(
        &samples,
        &un,
        omega,
        &MultipoleSettings {
            centre: Some([0.0; 3]),
            ..Default::default()
        },
    )
    .unwrap();
    assert!(auto.degree >= 4, "{:?}", auto.residual_by_degree);
    // The fallback's direction average is the RMS of |p| over directions at that radius.
    let fit = fit_multipoles_complex(
        &samples,
        &un,
        omega,
        &MultipoleSettings {
            degree: Some(6),
            centre: Some([0.0; 3]),
            ..Default::default()
        },
    )
    .unwrap();
    let big_r = 2.5 * a;
    let mean_sq: f64 = sphere_rule(10)
        .into_iter()
        .map(|(d, w)| w * fit.pressure(d.map(|v| big_r * v)).unwrap().norm_sqr())
        .sum::<f64>()
        / (4.0 * PI);
    assert!(
        (fit.direction_averaged_pressure(big_r).unwrap() / mean_sq.sqrt() - 1.0).abs() < 1e-12,
        "{} vs {}",
        fit.direction_averaged_pressure(big_r).unwrap(),
        mean_sq.sqrt()
    );
}

// ---- mesh sampling -------------------------------------------------------------------------

#[test]
fn mesh_sampling_converges_p1_at_second_and_p2_at_higher_order() {
    // Area 4πa², and the flux ∫ u·n dS of u = (e^(x/a), 0, 0), which by the divergence
    // theorem is ∫ e^(x/a)/a dV = 4πa²/e.
    let a = 0.3;
    let flux_exact = 4.0 * PI * a * a / std::f64::consts::E;
    let mut table = Vec::new();
    for quadratic in [false, true] {
        let mut errs = Vec::new();
        for level in 1..=3 {
            let mesh = coned_icosphere(level, a, quadratic);
            let quad = SurfaceQuadrature::new(&mesh).unwrap();
            let s = quad.samples();
            assert_eq!(s.len(), 20 * 4usize.pow(level as u32) * POINTS_PER_FACE);
            // Normals point outwards.
            assert!(s
                .points
                .iter()
                .zip(&s.normals)
                .all(|(x, n)| dot(*n, *x) > 0.9 * a));
            let area_err = (s.area() / (4.0 * PI * a * a) - 1.0).abs();
            let un = quad
                .normal_displacement(&nodal_field(&mesh, |x| [(x[0] / a).exp(), 0.0, 0.0]))
                .unwrap();
            let flux: f64 = un.iter().zip(&s.weights).map(|(u, w)| u * w).sum();
            errs.push((area_err, (flux / flux_exact - 1.0).abs()));
        }
        table.push(errs);
    }
    println!(
        "P1 (area, flux) errors by level: {:?}\nP2: {:?}",
        table[0], table[1]
    );
    let order = |e: &[(f64, f64)], pick: fn(&(f64, f64)) -> f64| (pick(&e[1]) / pick(&e[2])).log2();
    let (p1, p2) = (&table[0], &table[1]);
    assert!(
        (1.8..2.3).contains(&order(p1, |e| e.0)) && (1.8..2.3).contains(&order(p1, |e| e.1)),
        "P1 orders: {p1:?}"
    );
    assert!(
        order(p2, |e| e.0) > 3.5 && order(p2, |e| e.1) > 3.5,
        "P2 orders: {p2:?}"
    );
    assert!(p2[2].0 < 1e-5 && p2[2].1 < 1e-5, "P2 level 3: {p2:?}");
}

#[test]
fn mesh_based_pulsating_and_translating_spheres_match_the_exact_fields() {
    let air = Air::default();
    let a = 0.08;
    let mesh = coned_icosphere(3, a, true);
    let quad = SurfaceQuadrature::new(&mesh).unwrap();
    let ka = 1.0;
    let k = ka / a;
    let omega = k * air.speed_of_sound;
    let rho_omega2 = air.density * omega * omega;
    // Pulsation u = x/a (u_n = 1 on the sphere).
    let un = quad
        .normal_displacement(&nodal_field(&mesh, |x| x.map(|v| v / a)))
        .unwrap();
    let mono = fit_multipoles(quad.samples(), &un, omega, &MultipoleSettings::default()).unwrap();
    assert!(
        mono.degree == 0 && mono.residual < 1e-4,
        "{:?}",
        mono.residual_by_degree
    );
    let amp0 = rho_omega2 / (k * -h1_exact(ka));
    let r = 3.0 * a;
    let p = mono
        .transfer(&[[0.0, r, 0.0], [r * 0.6, 0.0, -r * 0.8]])
        .unwrap();
    for pi in p {
        assert!(
            rel(pi, amp0 * h0_exact(k * r)) < 1e-5,
            "{pi} vs {}",
            amp0 * h0_exact(k * r)
        );
    }
    // Rigid translation along x, first about the centre, then about a shifted centre where
    // L = 1 no longer suffices.
    let un = quad
        .normal_displacement(&nodal_field(&mesh, |_| [1.0, 0.0, 0.0]))
        .unwrap();
    let amp1 = rho_omega2 / (k * dh1_exact(ka));
    let mics = [
        [r, 0.0, 0.0],
        [r * 0.6, r * 0.8, 0.0],
        [0.0, 0.0, -r],
        [-r * 0.36, r * 0.48, r * 0.8],
    ];
    let exact: Vec<Complex64> = mics
        .iter()
        .map(|m| amp1 * h1_exact(k * r) * (m[0] / r))
        .collect();
    let scale = (amp1 * h1_exact(k * r)).norm();
    let dip = fit_multipoles(quad.samples(), &un, omega, &MultipoleSettings::default()).unwrap();
    assert!(
        dip.degree == 1 && dip.residual < 1e-3,
        "{:?}",
        dip.residual_by_degree
    );
    let err2 = dip
        .transfer(&mics)
        .unwrap()
        .iter()
        .zip(&exact)
        .map(|(p, e)| (p - e).norm())
        .fold(0.0, f64::max)
        / scale;
    assert!(err2 < 1e-5, "P2 dipole error {err2}");
    let shifted = MultipoleSettings {
        centre: Some([0.2 * a, -0.1 * a, 0.15 * a]),
        ..Default::default()
    };
    let mut errors = Vec::new();
    for l in [1, 3, 6] {
        let fit = fit_multipoles(
            quad.samples(),
            &un,
            omega,
            &MultipoleSettings {
                degree: Some(l),
                ..shifted
            },
        )
        .unwrap();
        let err = fit
            .transfer(&mics)
            .unwrap()
            .iter()
            .zip(&exact)
            .map(|(p, e)| (p - e).norm())
            .fold(0.0, f64::max)
            / scale;
        errors.push((l, err, fit.residual));
    }
    println!("translating sphere, centre shifted by 0.27 a: (L, max rel. error at 3a, residual) {errors:?}");
    assert!(
        errors[0].1 > 1e-2
            && errors[2].1 < 1e-3
            && errors[2].1 < errors[1].1
            && errors[1].1 < errors[0].1,
        "{errors:?}"
    );
    // P1 sampling of the same sphere is much less accurate (flat faces).
    let mesh1 = coned_icosphere(3, a, false);
    let quad1 = SurfaceQuadrature::new(&mesh1).unwrap();
    let un1 = quad1
        .normal_displacement(&nodal_field(&mesh1, |_| [1.0, 0.0, 0.0]))
        .unwrap();
    let fit1 = fit_multipoles(
        quad1.samples(),
        &un1,
        omega,
        &MultipoleSettings {
            degree: Some(1),
            ..Default::default()
        },
    )
    .unwrap();
    let err1 = fit1
        .transfer(&mics)
        .unwrap()
        .iter()
        .zip(&exact)
        .map(|(p, e)| (p - e).norm())
        .fold(0.0, f64::max)
        / scale;
    println!("level-3 sphere (1280 faces), dipole error at 3a: P1 {err1:.2e}, P2 {err2:.2e}; boundary residual P1 {:.2e}, P2 {:.2e}", fit1.residual, dip.residual);
    assert!(err1 > 1e-4 && err1 < 2e-2, "{err1}");
}

// ---- bad input -----------------------------------------------------------------------------

#[test]
fn bad_input_gives_errors_not_panics() {
    let mesh = coned_icosphere(1, 1.0, true);
    let quad = SurfaceQuadrature::new(&mesh).unwrap();
    assert!(matches!(
        quad.normal_displacement(&[0.0; 5]),
        Err(RadiationError::ModeLength { got: 5, .. })
    ));
    let mut mode = vec![0.0; 3 * mesh.n_nodes()];
    mode[7] = f64::NAN;
    assert!(matches!(
        quad.normal_displacement(&mode),
        Err(RadiationError::NonFinite { index: 7, .. })
    ));
    let empty = TetMesh {
        nodes: vec![],
        connectivity: vec![],
        order: ElementOrder::Linear,
    };
    assert_eq!(
        SurfaceQuadrature::new(&empty).unwrap_err(),
        RadiationError::NoSurface
    );

    let s = quad.samples();
    let un = vec![1.0; s.len()];
    let fit =
        |u: &[f64], omega: f64, settings: MultipoleSettings| fit_multipoles(s, u, omega, &settings);
    let ok = MultipoleSettings::default();
    for omega in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        assert!(matches!(
            fit(&un, omega, ok),
            Err(RadiationError::BadFrequency(_))
        ));
    }
    assert!(matches!(
        fit(&un[1..], 1e3, ok),
        Err(RadiationError::LengthMismatch { .. })
    ));
    assert!(matches!(
        fit(
            &un,
            1e3,
            MultipoleSettings {
                air: Air {
                    speed_of_sound: 0.0,
                    density: 1.2
                },
                ..ok
            }
        ),
        Err(RadiationError::BadAir { .. })
    ));
    assert!(matches!(
        fit(
            &un,
            1e3,
            MultipoleSettings {
                degree: Some(21),
                ..ok
            }
        ),
        Err(RadiationError::DegreeTooHigh { requested: 21 })
    ));
    assert!(matches!(
        fit(
            &un,
            1e3,
            MultipoleSettings {
                gain_tolerance: 1.5,
                ..ok
            }
        ),
        Err(RadiationError::BadGainTolerance(_))
    ));
    assert!(matches!(
        fit(
            &un,
            1e3,
            MultipoleSettings {
                centre: Some(s.points[3]),
                ..ok
            }
        ),
        Err(RadiationError::AtCentre { index: 3, .. })
    ));
    let few = SurfaceSamples {
        points: s.points[..10].to_vec(),
        normals: s.normals[..10].to_vec(),
        weights: s.weights[..10].to_vec(),
    };
    assert!(matches!(
        fit_multipoles(
            &few,
            &un[..10],
            1e3,
            &MultipoleSettings {
                degree: Some(3),
                ..ok
            }
        ),
        Err(RadiationError::TooFewPoints { .. })
    ));
    // Automatic choice caps the degree at what the points can carry: 10 points, L ≤ 2.
    assert_eq!(
        fit_multipoles(&few, &un[..10], 1e3, &ok)
            .unwrap()
            .residual_by_degree
            .len(),
        3
    );
    let mut bad = s.clone();
    bad.weights[0] = -1.0;
    assert!(matches!(
        fit_multipoles(&bad, &un, 1e3, &ok),
        Err(RadiationError::NegativeWeight { index: 0, .. })
    ));
    bad.weights = vec![0.0; s.len()];
    assert_eq!(
        fit_multipoles(&bad, &un, 1e3, &ok).unwrap_err(),
        RadiationError::ZeroArea
    );
    bad = s.clone();
    bad.normals.pop();
    assert!(matches!(
        fit_multipoles(&bad, &un, 1e3, &ok),
        Err(RadiationError::LengthMismatch {
            what: "normals",
            ..
        })
    ));

    let expansion = fit(&un, 1e3, ok).unwrap();
    let centre = expansion.centre;
    assert!(matches!(
        expansion.transfer(&[[1.0, 2.0, 3.0], centre]),
        Err(RadiationError::AtCentre { index: 1, .. })
    ));
    assert!(matches!(
        expansion.transfer(&[[f64::NAN, 0.0, 0.0]]),
        Err(RadiationError::NonFinite { .. })
    ));
    assert!(matches!(
        expansion.far_field([0.0; 3]),
        Err(RadiationError::BadDirection(_))
    ));
    assert!(matches!(
        expansion.transfer_unknown_positions(2, 0.0),
        Err(RadiationError::BadRadius(_))
    ));
    assert!(matches!(
        expansion.direction_averaged_pressure(f64::NAN),
        Err(RadiationError::BadRadius(_))
    ));
    // At an absurdly low frequency the degree-20 basis overflows: an error, not NaN.
    assert!(matches!(
        fit(
            &un,
            1e-12,
            MultipoleSettings {
                degree: Some(20),
                ..ok
            }
        ),
        Err(RadiationError::BasisOverflow { degree: 20, .. })
    ));
    // A surface that does not move radiates nothing, without dividing by zero.
    let still = fit(&vec![0.0; s.len()], 1e3, ok).unwrap();
    assert_eq!(
        (
            still.radiated_power(),
            still.radiation_efficiency(),
            still.residual,
            still.degree
        ),
        (0.0, 0.0, 0.0, 0)
    );
    // Every error message says what is wrong.
    assert!(RadiationError::ModeLength {
        got: 5,
        expected: 9,
        n_nodes: 3
    }
    .to_string()
    .contains("3 x 3 = 9"));
}

#[test]
fn a_flat_plate_leaves_the_invisible_multipoles_at_zero() {
    // Points on the plane z = 0 with normals +z see only harmonics odd in z; the others are
    // undetermined and must come out 0 (minimum norm, up to rounding), not blow up.
    let mut s = SurfaceSamples::default();
    let n = 30;
    for i in 0..n {
        for j in 0..n {
            let (x, y) = (
                (i as f64 + 0.5) / n as f64 - 0.5,
                (j as f64 + 0.5) / n as f64 - 0.5,
            );
            s.points.push([0.1 * x, 0.1 * y, 0.0]);
            s.normals.push([0.0, 0.0, 1.0]);
            s.weights.push(0.01 / (n * n) as f64);
        }
    }
    let un = vec![1e-6; s.len()];
    let fit = fit_multipoles(
        &s,
        &un,
        2.0 * PI * 2000.0,
        &MultipoleSettings {
            degree: Some(4),
            centre: Some([0.0, 0.0, 0.0]),
            ..Default::default()
        },
    )
    .unwrap();
    // Of the 25 harmonics up to degree 4, those with l + m odd are odd in z: 10 of them.
    assert_eq!(fit.rank, 10, "{:?}", fit.residual_by_degree);
    let largest = fit
        .coefficients
        .iter()
        .map(|c| c.norm())
        .fold(0.0, f64::max);
    for l in 0..=4usize {
        for m in -(l as i64)..=(l as i64) {
            let value = fit.coefficients[multipole_index(l, m)].norm();
            if (l as i64 + m) % 2 == 0 {
                assert!(value < 1e-9 * largest, "({l}, {m}): {value} of {largest}");
            }
        }
    }
    assert!(fit.coefficients.iter().all(|c| c.norm().is_finite()));
}

// ---- non-spherical shapes: a point source inside the body is an exact exterior solution ----

/// Neumann data u_n = ∂p/∂n / (ρω²) of the field of a point source, p = h₀(k|x − s|), or of a
/// point dipole along z, p = ∂h₀(k|x − s|)/∂s_z. By uniqueness of the exterior Neumann problem
/// that p is the exact exterior field of the surface moving with this u_n.
fn point_source_data(
    samples: &SurfaceSamples,
    s: [f64; 3],
    k: f64,
    omega: f64,
    dipole: bool,
) -> (Vec<Complex64>, impl Fn([f64; 3]) -> Complex64) {
    let air = Air::default();
    let rho_omega2 = air.density * omega * omega;
    // Monopole: h₀(kr); dipole along z: −∂/∂z h₀(k|x−s|) = k h₁(kr) (z − s_z)/r.
    let field = move |x: [f64; 3]| {
        let d = sub(x, s);
        let r = norm(d);
        if dipole {
            h1_exact(k * r) * k * (d[2] / r)
        } else {
            h0_exact(k * r)
        }
    };
    let gradient = move |x: [f64; 3]| -> [Complex64; 3] {
        let d = sub(x, s);
        let r = norm(d);
        if dipole {
            // ∇[k h₁(kr) z/r] = k (k h₁'(kr) − h₁/r) (z/r) r̂ + k h₁(kr) ẑ/r.
            let radial = (dh1_exact(k * r) * k - h1_exact(k * r) / r) * k * (d[2] / r);
            std::array::from_fn(|c| {
                radial * (d[c] / r)
                    + if c == 2 {
                        h1_exact(k * r) * k / r
                    } else {
                        Complex64::new(0.0, 0.0)
                    }
            })
        } else {
            let dh0 = -h1_exact(k * r) * k;
            d.map(|v| dh0 * (v / r))
        }
    };
    let un = samples
        .points
        .iter()
        .zip(&samples.normals)
        .map(|(&x, n)| {
            let g = gradient(x);
            (g[0] * n[0] + g[1] * n[1] + g[2] * n[2]) / rho_omega2
        })
        .collect();
    (un, field)
}

/// Largest error of the fitted pressure at `mics` relative to the largest exact value.
fn transfer_error(
    fit: &MultipoleExpansion,
    mics: &[[f64; 3]],
    exact: &impl Fn([f64; 3]) -> Complex64,
) -> f64 {
    let p = fit.transfer(mics).unwrap();
    let scale = mics.iter().map(|&x| exact(x).norm()).fold(0.0, f64::max);
    mics.iter()
        .zip(&p)
        .map(|(&x, pi)| (pi - exact(x)).norm())
        .fold(0.0, f64::max)
        / scale
}

#[test]
fn a_box_with_an_off_centre_source_inside_converges_with_l() {
    // A convex, non-spherical P2 mesh (0.1 m cube), source 2.6 cm from the centre, ka ≈ 1.7.
    let mesh = lift_to_quadratic(&crate::mesh::box_mesh([4, 4, 4], [0.1, 0.1, 0.1]));
    let quad = SurfaceQuadrature::new(&mesh).unwrap();
    let (k, air) = (20.0, Air::default());
    let omega = k * air.speed_of_sound;
    let s = [0.06, 0.035, 0.07];
    let mics: Vec<[f64; 3]> = sphere_rule(3)
        .into_iter()
        .map(|(d, _)| std::array::from_fn(|c| 0.05 + 0.3 * d[c]))
        .collect();
    let mut rows = Vec::new();
    for dipole in [false, true] {
        let (un, exact) = point_source_data(quad.samples(), s, k, omega, dipole);
        for l in [1, 3, 6] {
            let fit = fit_multipoles_complex(
                quad.samples(),
                &un,
                omega,
                &MultipoleSettings {
                    degree: Some(l),
                    ..Default::default()
                },
            )
            .unwrap();
            // The farthest sample points sit just inside the corners (half diagonal 0.0866 m).
            assert!(
                fit.source_radius > 0.08 && fit.source_radius < 0.0867,
                "{}",
                fit.source_radius
            );
            rows.push((dipole, l, transfer_error(&fit, &mics, &exact), fit.residual));
        }
    }
    println!(
        "box, source inside (dipole?, L, max rel. error at 0.3 m, boundary residual): {rows:?}"
    );
    // Measured: monopole 9.1e-2 → 7.7e-3 → 6.4e-4, dipole 0.35 → 7.8e-2 → 8.9e-3.
    for (r, limit) in rows.chunks(3).zip([2e-3, 2e-2]) {
        assert!(
            r[0].2 > 10.0 * r[2].2 && r[1].2 > r[2].2 && r[2].2 < limit,
            "{r:?}"
        );
        assert!(r[0].3 > r[1].3 && r[1].3 > r[2].3, "{r:?}");
    }
}

// ---- the bowl --------------------------------------------------------------------------------

/// The centroid of the tet whose centroid is nearest to `target`: a point inside the material.
fn point_inside(mesh: &TetMesh, target: [f64; 3]) -> [f64; 3] {
    (0..mesh.n_tets())
        .map(|e| {
            let c = mesh.corner_coords(e);
            std::array::from_fn(|d| (c[0][d] + c[1][d] + c[2][d] + c[3][d]) / 4.0)
        })
        .min_by(|a: &[f64; 3], b: &[f64; 3]| {
            norm(sub(*a, target)).total_cmp(&norm(sub(*b, target)))
        })
        .unwrap()
}

#[test]
fn bowl_fit_timing_residuals_and_its_limits() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/bowl/bowl.msh");
    let read = crate::mesh::read_mesh(&path, &crate::mesh::ReadOptions::default()).unwrap();
    let mesh = lift_to_quadratic(&read.mesh);
    let t0 = std::time::Instant::now();
    let quad = SurfaceQuadrature::new(&mesh).unwrap();
    let t_quad = t0.elapsed().as_secs_f64();
    let s = quad.samples();
    println!(
        "bowl: {} boundary faces, {} points, area {:.4e} m², sampling {:.3} s",
        s.len() / POINTS_PER_FACE,
        s.len(),
        s.area(),
        t_quad
    );
    let fit_and_report = |what: &str, un: &[Complex64], f: f64, l: usize| {
        let t = std::time::Instant::now();
        let fit = fit_multipoles_complex(
            s,
            un,
            2.0 * PI * f,
            &MultipoleSettings {
                degree: Some(l),
                ..Default::default()
            },
        )
        .unwrap();
        let dt = t.elapsed().as_secs_f64();
        let total: f64 = fit.coefficients.iter().map(|c| c.norm_sqr()).sum();
        let share = |d: usize| {
            (d * d..(d + 1) * (d + 1))
                .map(|j| fit.coefficients[j].norm_sqr())
                .sum::<f64>()
                / total
        };
        println!(
            "bowl {what}, {f} Hz (k·source radius {:.2}), L = {l}: fit {dt:.3} s, residual {:.4}, power shares l=0 {:.3} l=1 {:.3} l=2 {:.3}, W = {:.3e}, σ = {:.3}",
            fit.wavenumber * fit.source_radius, fit.residual, share(0), share(1), share(2), fit.radiated_power(), fit.radiation_efficiency()
        );
        fit
    };
    // Rigid translations (made-up modes, unit displacement): timing and residual per L.
    let mut z_translation = Vec::new();
    for (name, dir) in [("x", [1.0, 0.0, 0.0]), ("z", [0.0, 0.0, 1.0])] {
        let un: Vec<Complex64> = quad
            .normal_displacement(&nodal_field(&mesh, |_| dir))
            .unwrap()
            .into_iter()
            .map(c)
            .collect();
        // A closed surface translating rigidly displaces no net volume.
        let flux: f64 = un.iter().zip(&s.weights).map(|(u, w)| u.re * w).sum();
        assert!(flux.abs() < 1e-12 * s.area(), "net flux {flux}");
        let mut previous = f64::INFINITY;
        for l in [2, 4, 6] {
            let fit = fit_and_report(&format!("translation {name}"), &un, 1000.0, l);
            assert!(
                fit.residual < previous && fit.rank == (l + 1) * (l + 1),
                "{:?}",
                fit.residual_by_degree
            );
            previous = fit.residual;
        }
        z_translation = un;
    }
    // The limits, measured (module docs). At 50 Hz (ka ≈ 0.06) a translating body radiates as
    // a dipole, yet the fit about the centroid, which lies in the air of the bowl's cavity,
    // explains the axial translation as a monopole. A point source inside the bottom wall (an
    // exact exterior field) is not reproduced at 0.3 m either.
    fit_and_report("translation z", &z_translation, 50.0, 6);
    let (lo, hi) = mesh.bounding_box();
    let centre = [
        0.5 * (lo[0] + hi[0]),
        0.5 * (lo[1] + hi[1]),
        0.5 * (lo[2] + hi[2]),
    ];
    let bottom = point_inside(&mesh, [centre[0], centre[1], lo[2]]);
    let mics: Vec<[f64; 3]> = sphere_rule(3)
        .into_iter()
        .map(|(d, _)| std::array::from_fn(|c| centre[c] + 0.3 * d[c]))
        .collect();
    let omega = 2.0 * PI * 1000.0;
    let (un, exact) = point_source_data(
        s,
        bottom,
        omega / Air::default().speed_of_sound,
        omega,
        false,
    );
    for l in [2, 6] {
        let fit = fit_and_report("point source in the bottom wall", &un, 1000.0, l);
        println!(
            "  transfer error at 0.3 m: {:.2}",
            transfer_error(&fit, &mics, &exact)
        );
    }
}
