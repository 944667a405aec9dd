//! Tests for element matrices. Random elements are affine images of the
//! reference tet (random rotation, anisotropic scale, mild shear, translation);
//! curved elements additionally go through a known quadratic map.

use super::*;
use crate::fem::material::Material;
use crate::fem::shape::{P1_NODES, P2_NODES};
use nalgebra::{DMatrix, DVector};

/// The crate's test RNG (also used by the sensitivity tests).
pub(crate) use crate::testing::Rng;

pub(crate) type M3 = [[f64; 3]; 3];

fn mul3(a: &M3, b: &M3) -> M3 {
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            for k in 0..3 {
                c[i][j] += a[i][k] * b[k][j];
            }
        }
    }
    c
}

pub(crate) fn random_rotation(rng: &mut Rng) -> M3 {
    let mut q = [0.0; 4];
    loop {
        for v in q.iter_mut() {
            *v = rng.uniform(-1.0, 1.0);
        }
        let n: f64 = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        if n > 0.1 && n <= 1.0 {
            q.iter_mut().for_each(|v| *v /= n);
            break;
        }
    }
    let [w, x, y, z] = q;
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - z * w),
            2.0 * (x * z + y * w),
        ],
        [
            2.0 * (x * y + z * w),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - x * w),
        ],
        [
            2.0 * (x * z - y * w),
            2.0 * (y * z + x * w),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

/// Random well-shaped affine map x = A ξ + t with det A > 0.
fn random_affine(rng: &mut Rng) -> (M3, [f64; 3]) {
    let r = random_rotation(rng);
    let mut s = [[0.0; 3]; 3];
    for (i, row) in s.iter_mut().enumerate() {
        row[i] = rng.uniform(0.5, 2.0);
        for (j, v) in row.iter_mut().enumerate() {
            if j > i {
                *v = rng.uniform(-0.3, 0.3);
            }
        }
    }
    let t = [
        rng.uniform(-5.0, 5.0),
        rng.uniform(-5.0, 5.0),
        rng.uniform(-5.0, 5.0),
    ];
    (mul3(&r, &s), t)
}

fn apply(a: &M3, t: &[f64; 3], x: [f64; 3]) -> [f64; 3] {
    let mut y = *t;
    for i in 0..3 {
        for j in 0..3 {
            y[i] += a[i][j] * x[j];
        }
    }
    y
}

fn det_m3(a: &M3) -> f64 {
    det3(a)
}

fn ref_nodes(nodes: usize) -> Vec<[f64; 3]> {
    if nodes == 4 {
        P1_NODES.to_vec()
    } else {
        P2_NODES.to_vec()
    }
}

fn mapped(nodes: usize, a: &M3, t: &[f64; 3]) -> Vec<[f64; 3]> {
    ref_nodes(nodes)
        .into_iter()
        .map(|x| apply(a, t, x))
        .collect()
}

/// Quadratic map with known volume: φ(ξ,η,ζ) = (ξ(1+aξ), η(1+bη), ζ),
/// det Dφ = (1+2aξ)(1+2bη), ∫_ref det = 1/6 + (a+b)/12 + ab/30.
fn quad_map(a: f64, b: f64, x: [f64; 3]) -> [f64; 3] {
    [x[0] * (1.0 + a * x[0]), x[1] * (1.0 + b * x[1]), x[2]]
}

fn curved_element(rng: &mut Rng, a: f64, b: f64) -> (Vec<[f64; 3]>, f64) {
    let (am, t) = random_affine(rng);
    let coords = P2_NODES
        .iter()
        .map(|&x| apply(&am, &t, quad_map(a, b, x)))
        .collect();
    let vol = det_m3(&am) * (1.0 / 6.0 + (a + b) / 12.0 + a * b / 30.0);
    (coords, vol)
}

fn dmat(v: &[f64], n: usize) -> DMatrix<f64> {
    DMatrix::from_row_slice(n, n, v)
}

fn sorted_eigs(m: &DMatrix<f64>) -> Vec<f64> {
    let mut e: Vec<f64> = m
        .clone()
        .symmetric_eigen()
        .eigenvalues
        .iter()
        .copied()
        .collect();
    e.sort_by(|a, b| a.partial_cmp(b).unwrap());
    e
}

/// The 6 rigid-body modes sampled at the nodes: translations e_k, rotations e_k × x.
fn rigid_modes(coords: &[[f64; 3]]) -> Vec<DVector<f64>> {
    let n = 3 * coords.len();
    let mut modes = Vec::new();
    for k in 0..3 {
        modes.push(DVector::from_fn(
            n,
            |i, _| if i % 3 == k { 1.0 } else { 0.0 },
        ));
    }
    for k in 0..3 {
        let mut w = [0.0; 3];
        w[k] = 1.0;
        let mut v = DVector::zeros(n);
        for (a, x) in coords.iter().enumerate() {
            let c = [
                w[1] * x[2] - w[2] * x[1],
                w[2] * x[0] - w[0] * x[2],
                w[0] * x[1] - w[1] * x[0],
            ];
            for d in 0..3 {
                v[3 * a + d] = c[d];
            }
        }
        modes.push(v);
    }
    modes
}

fn lame() -> (f64, f64) {
    Material::preset("ceramic").unwrap().lame()
}

fn stiffness(em: &ElementMatrices) -> DMatrix<f64> {
    let (l, m) = lame();
    dmat(&em.stiffness(l, m), em.dofs)
}

fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0, |a, &b| a.max(b.abs()))
}

fn assert_close(a: &[f64], b: &[f64], rel: f64, what: &str) {
    let scale = max_abs(a).max(max_abs(b));
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        assert!(
            (x - y).abs() <= rel * scale,
            "{what}: entry {i}: {x} vs {y}"
        );
    }
}

/// Symmetric, PSD mass (in fact PD), K with exactly 6 zero eigenvalues spanned
/// by the rigid modes, mass summing to the volume.
fn check_element(em: &ElementMatrices, coords: &[[f64; 3]], volume: f64) {
    let n = em.dofs;
    assert_eq!(n, 3 * coords.len());
    for mat in [&em.mass, &em.k_lambda, &em.k_mu] {
        for i in 0..n {
            for j in 0..n {
                assert_eq!(mat[i * n + j], mat[j * n + i], "not symmetric at ({i},{j})");
            }
        }
    }
    // Mass: positive definite, Σ over x-components = volume.
    let me = sorted_eigs(&dmat(&em.mass, n));
    assert!(me[0] > 0.0, "mass not positive definite: {}", me[0]);
    let sx: f64 = (0..n / 3)
        .flat_map(|a| (0..n / 3).map(move |b| (a, b)))
        .map(|(a, b)| em.mass[3 * a * n + 3 * b])
        .sum();
    assert!(
        (sx - volume).abs() < 1e-12 * volume,
        "mass sum {sx} vs volume {volume}"
    );

    // K_λ and K_μ separately PSD; K = λK_λ + μK_μ has exactly 6 zero eigenvalues.
    for part in [&em.k_lambda, &em.k_mu] {
        let e = sorted_eigs(&dmat(part, n));
        assert!(e[0] > -1e-12 * e[n - 1]);
    }
    let k = stiffness(em);
    let e = sorted_eigs(&k);
    let emax = e[n - 1];
    for (i, &ev) in e.iter().enumerate() {
        if i < 6 {
            assert!(
                ev.abs() < 1e-11 * emax,
                "eigenvalue {i} = {ev} should be zero (max {emax})"
            );
        } else {
            assert!(
                ev > 1e-6 * emax,
                "eigenvalue {i} = {ev} should be positive (max {emax})"
            );
        }
    }
    let knorm = k.norm();
    for r in rigid_modes(coords) {
        let kr = &k * &r;
        assert!(
            kr.norm() < 1e-12 * knorm * r.norm(),
            "rigid mode not in null space: {}",
            kr.norm() / (knorm * r.norm())
        );
    }
}

#[test]
fn random_straight_elements_p1_p2() {
    let mut rng = Rng(0x1234_5678_9abc_def1);
    for nodes in [4, 10] {
        let kernel = ElementKernel::new(nodes, false);
        for _ in 0..20 {
            let (a, t) = random_affine(&mut rng);
            let coords = mapped(nodes, &a, &t);
            let vol = det_m3(&a) / 6.0;
            let em = kernel.matrices(&coords).unwrap();
            check_element(&em, &coords, vol);
            // Same result through the generic isoparametric path with the default rule.
            let g = element_matrices(&coords, &default_rule(nodes, false)).unwrap();
            assert_close(&em.mass, &g.mass, 1e-13, "mass affine vs iso");
            assert_close(&em.k_lambda, &g.k_lambda, 1e-12, "k_lambda affine vs iso");
            assert_close(&em.k_mu, &g.k_mu, 1e-12, "k_mu affine vs iso");
            assert!((kernel.volume(&coords).unwrap() - vol).abs() < 1e-13 * vol);
            assert!((element_volume(&coords, &tet_rule(3)).unwrap() - vol).abs() < 1e-13 * vol);
        }
    }
}

#[test]
fn p1_reference_values() {
    // Unit reference tet: M_ab = V(1+δ_ab)/20 per component; ∇N constant so K_λ = V G_a G_bᵀ.
    let em = ElementKernel::new(4, false).matrices(&P1_NODES).unwrap();
    let v = 1.0 / 6.0;
    let g = crate::fem::shape::p1_grad_ref();
    for a in 0..4 {
        for b in 0..4 {
            let m = em.mass[(3 * a) * 12 + 3 * b];
            assert!((m - v * if a == b { 2.0 } else { 1.0 } / 20.0).abs() < 1e-16);
            for k in 0..3 {
                for l in 0..3 {
                    let kl = em.k_lambda[(3 * a + k) * 12 + 3 * b + l];
                    assert!((kl - v * g[a][k] * g[b][l]).abs() < 1e-15);
                    assert_eq!(
                        em.mass[(3 * a + k) * 12 + 3 * b + l],
                        if k == l { m } else { 0.0 }
                    );
                }
            }
        }
    }
}

#[test]
fn p2_mass_reference_values() {
    // Entries from barycentric moments ∫ L0^a L1^b L2^c L3^d dV = 6V a!b!c!d!/(a+b+c+d+3)!.
    let em = ElementKernel::new(10, false).matrices(&P2_NODES).unwrap();
    let v = 1.0 / 6.0;
    // corner 0 with itself: ∫ L0²(2L0−1)² = ∫ 4L0⁴ − 4L0³ + L0² = 6V(4·24/7! − 4·6/6! + 2/5!)
    let f = |k: u32| (1..=k).map(|x| x as f64).product::<f64>();
    let c00 = 6.0 * v * (4.0 * f(4) / f(7) - 4.0 * f(3) / f(6) + f(2) / f(5));
    assert!((em.mass[0] - c00).abs() < 1e-15, "{} vs {c00}", em.mass[0]);
    assert!((c00 - v / 70.0).abs() < 1e-15);
    // mid-edge 4 (=4L0L1) with itself: 16 ∫ L0² L1² = 16·6V·2·2/7! = 8V/105.
    let m44 = em.mass[(3 * 4) * 30 + 3 * 4];
    assert!((m44 - 8.0 * v / 105.0).abs() < 1e-15, "{m44}");
}

#[test]
fn rotation_invariance() {
    let mut rng = Rng(42);
    for nodes in [4, 10] {
        let kernel = ElementKernel::new(nodes, false);
        let (a, t) = random_affine(&mut rng);
        let coords = mapped(nodes, &a, &t);
        let r = random_rotation(&mut rng);
        let rotated: Vec<_> = coords
            .iter()
            .map(|&x| apply(&r, &[1.0, -2.0, 0.5], x))
            .collect();
        let (e1, e2) = (
            kernel.matrices(&coords).unwrap(),
            kernel.matrices(&rotated).unwrap(),
        );
        let n = e1.dofs;
        for (m1, m2) in [
            (&e1.mass, &e2.mass),
            (&e1.k_lambda, &e2.k_lambda),
            (&e1.k_mu, &e2.k_mu),
        ] {
            let (s1, s2) = (sorted_eigs(&dmat(m1, n)), sorted_eigs(&dmat(m2, n)));
            assert_close(&s1, &s2, 1e-11, "eigenvalues under rotation");
        }
    }
    // Curved too.
    let (coords, _) = curved_element(&mut rng, 0.3, -0.2);
    let kernel = ElementKernel::new(10, false);
    let r = random_rotation(&mut rng);
    let rotated: Vec<_> = coords.iter().map(|&x| apply(&r, &[0.0; 3], x)).collect();
    let (e1, e2) = (
        kernel.matrices(&coords).unwrap(),
        kernel.matrices(&rotated).unwrap(),
    );
    let s1 = sorted_eigs(&stiffness(&e1));
    let s2 = sorted_eigs(&stiffness(&e2));
    assert_close(&s1, &s2, 1e-11, "curved K eigenvalues under rotation");
}

#[test]
fn scaling_laws() {
    let mut rng = Rng(7);
    let s = 0.37;
    for (nodes, curved) in [(4, false), (10, false), (10, true)] {
        let coords = if curved {
            curved_element(&mut rng, 0.25, 0.15).0
        } else {
            let (a, t) = random_affine(&mut rng);
            mapped(nodes, &a, &t)
        };
        let scaled: Vec<_> = coords
            .iter()
            .map(|x| [s * x[0], s * x[1], s * x[2]])
            .collect();
        let kernel = ElementKernel::new(nodes, curved);
        let (e1, e2) = (
            kernel.matrices(&coords).unwrap(),
            kernel.matrices(&scaled).unwrap(),
        );
        let m1s: Vec<f64> = e1.mass.iter().map(|v| v * s * s * s).collect();
        assert_close(&m1s, &e2.mass, 1e-13, "mass ~ s^3");
        let kl: Vec<f64> = e1.k_lambda.iter().map(|v| v * s).collect();
        let km: Vec<f64> = e1.k_mu.iter().map(|v| v * s).collect();
        assert_close(&kl, &e2.k_lambda, 1e-12, "k_lambda ~ s");
        assert_close(&km, &e2.k_mu, 1e-12, "k_mu ~ s");
    }
}

#[test]
fn straight_p2_equals_curved_mode_computation() {
    let mut rng = Rng(99);
    let (a, t) = random_affine(&mut rng);
    let coords = mapped(10, &a, &t);
    assert!(!is_curved(&coords));
    let fast = ElementKernel::new(10, false).matrices(&coords).unwrap();
    let curved = ElementKernel::new(10, true).matrices(&coords).unwrap();
    assert_close(&fast.mass, &curved.mass, 1e-13, "mass");
    assert_close(&fast.k_lambda, &curved.k_lambda, 1e-12, "k_lambda");
    assert_close(&fast.k_mu, &curved.k_mu, 1e-12, "k_mu");
}

#[test]
fn curved_element_volume_modes_and_mass() {
    let mut rng = Rng(2024);
    for (a, b) in [(0.3, -0.2), (-0.25, 0.4), (0.1, 0.1)] {
        let (coords, vol) = curved_element(&mut rng, a, b);
        assert!(is_curved(&coords));
        // Volume: analytic vs default curved rule vs a degree-12 rule.
        let v_hi = element_volume(&coords, &tet_rule(12)).unwrap();
        let v_def = element_volume(&coords, &default_rule(10, true)).unwrap();
        assert!((v_hi - vol).abs() < 1e-13 * vol, "{v_hi} vs analytic {vol}");
        assert!((v_def - vol).abs() < 1e-13 * vol);
        // The straight-edge volume differs: the test can tell curved from straight.
        let corners_vol = ElementKernel::new(4, false).volume(&coords[..4]).unwrap();
        assert!((corners_vol - vol).abs() > 1e-3 * vol);
        for kernel in [ElementKernel::new(10, false), ElementKernel::new(10, true)] {
            assert!((kernel.volume(&coords).unwrap() - vol).abs() < 1e-13 * vol);
            let em = kernel.matrices(&coords).unwrap();
            check_element(&em, &coords, vol);
        }
    }
}

#[test]
fn randomly_perturbed_mid_nodes() {
    let mut rng = Rng(5);
    let kernel = ElementKernel::new(10, false);
    for _ in 0..10 {
        let (a, t) = random_affine(&mut rng);
        let mut coords = mapped(10, &a, &t);
        for x in coords[4..].iter_mut() {
            for c in x.iter_mut() {
                *c += rng.uniform(-0.05, 0.05);
            }
        }
        let vol = element_volume(&coords, &tet_rule(12)).unwrap();
        let em = kernel.matrices(&coords).unwrap();
        check_element(&em, &coords, vol);
    }
}

/// ½uᵀKu for u = A x + b equals ½V(λ tr(ε)² + 2μ ε:ε), ε = sym(A).
#[test]
fn patch_test_linear_fields() {
    let mut rng = Rng(31337);
    let (lam, mu) = lame();
    let mut cases: Vec<(ElementKernel, Vec<[f64; 3]>, f64)> = Vec::new();
    for nodes in [4, 10] {
        let (a, t) = random_affine(&mut rng);
        cases.push((
            ElementKernel::new(nodes, false),
            mapped(nodes, &a, &t),
            det_m3(&a) / 6.0,
        ));
    }
    let (c, v) = curved_element(&mut rng, 0.3, -0.15);
    cases.push((ElementKernel::new(10, false), c.clone(), v));
    cases.push((ElementKernel::with_rule(10, &tet_rule(5)).unwrap(), c, v));
    for (kernel, coords, vol) in cases {
        let em = kernel.matrices(&coords).unwrap();
        let n = em.dofs;
        for _ in 0..5 {
            let mut am = [[0.0; 3]; 3];
            am.iter_mut()
                .flatten()
                .for_each(|v| *v = rng.uniform(-1.0, 1.0));
            let b = [
                rng.uniform(-1.0, 1.0),
                rng.uniform(-1.0, 1.0),
                rng.uniform(-1.0, 1.0),
            ];
            let u = DVector::from_iterator(n, coords.iter().flat_map(|&x| apply(&am, &b, x)));
            let mut eps = [[0.0; 3]; 3];
            for i in 0..3 {
                for j in 0..3 {
                    eps[i][j] = 0.5 * (am[i][j] + am[j][i]);
                }
            }
            let tr = eps[0][0] + eps[1][1] + eps[2][2];
            let ee: f64 = eps.iter().flatten().map(|v| v * v).sum();
            let ul = u.dot(&(dmat(&em.k_lambda, n) * &u));
            let um = u.dot(&(dmat(&em.k_mu, n) * &u));
            assert!(
                (ul - vol * tr * tr).abs() < 1e-11 * vol * (tr * tr + ee),
                "{ul} vs {}",
                vol * tr * tr
            );
            assert!((um - 2.0 * vol * ee).abs() < 1e-11 * vol * ee);
            let energy = 0.5 * u.dot(&(stiffness(&em) * &u));
            let exact = 0.5 * vol * (lam * tr * tr + 2.0 * mu * ee);
            assert!(
                (energy - exact).abs() < 1e-11 * exact,
                "{energy} vs {exact}"
            );
        }
    }
}

#[test]
fn inverted_and_degenerate_elements() {
    let mut rng = Rng(11);
    for nodes in [4, 10] {
        let (a, t) = random_affine(&mut rng);
        // Mirror image: det J < 0 everywhere.
        let coords: Vec<_> = mapped(nodes, &a, &t)
            .into_iter()
            .map(|x| [-x[0], x[1], x[2]])
            .collect();
        for kernel in [
            ElementKernel::new(nodes, false),
            ElementKernel::new(nodes, true),
        ] {
            match kernel.matrices(&coords) {
                Err(ElementError::NonPositiveJacobian { det, .. }) => assert!(det < 0.0),
                other => panic!("expected NonPositiveJacobian, got {other:?}"),
            }
            assert!(kernel.volume(&coords).is_err());
        }
        assert!(matches!(
            element_matrices(&coords, &tet_rule(4)),
            Err(ElementError::NonPositiveJacobian { .. })
        ));
        // Flat element: all nodes in the plane z = 0.
        let flat: Vec<_> = ref_nodes(nodes)
            .into_iter()
            .map(|x| [x[0], x[1], 0.0])
            .collect();
        let err = ElementKernel::new(nodes, false)
            .matrices(&flat)
            .unwrap_err();
        assert!(matches!(err, ElementError::NonPositiveJacobian { det, .. } if det <= 0.0));
        assert!(err.to_string().contains("Jacobian determinant"));
    }
    // Curved element folded over itself: a mid-edge node pushed past the far corner.
    let mut coords = P2_NODES.to_vec();
    coords[4] = [1.6, 0.0, 0.0];
    let err = ElementKernel::new(10, false).matrices(&coords).unwrap_err();
    assert!(
        matches!(err, ElementError::NonPositiveJacobian { .. }),
        "{err}"
    );
}

#[test]
fn bad_node_counts() {
    let five = [[0.0; 3]; 5];
    assert!(matches!(
        element_matrices(&five, &tet_rule(2)),
        Err(ElementError::BadNodeCount(5))
    ));
    assert!(matches!(
        ElementKernel::try_new(8, false),
        Err(ElementError::BadNodeCount(8))
    ));
    let k = ElementKernel::new(10, false);
    assert!(matches!(
        k.matrices(&P1_NODES),
        Err(ElementError::BadNodeCount(4))
    ));
    assert!(!is_curved(&P1_NODES) && !is_curved(&P2_NODES));
}

#[test]
fn stiffness_is_linear_in_material_parameters() {
    let em = ElementKernel::new(10, false).matrices(&P2_NODES).unwrap();
    let mat = Material::preset("glass").unwrap();
    let k = |m: &Material| em.stiffness(m.lame_lambda(), m.lame_mu());
    let (dl, dm) = mat.dlame_dE();
    let dk = em.stiffness(dl, dm);
    let h = mat.youngs_modulus * 1e-6;
    let kp = k(&Material {
        youngs_modulus: mat.youngs_modulus + h,
        ..mat
    });
    let km = k(&Material {
        youngs_modulus: mat.youngs_modulus - h,
        ..mat
    });
    let fd: Vec<f64> = kp
        .iter()
        .zip(&km)
        .map(|(p, m)| (p - m) / (2.0 * h))
        .collect();
    assert_close(&dk, &fd, 1e-6, "dK/dE");
    let (dl, dm) = mat.dlame_dnu();
    let dk = em.stiffness(dl, dm);
    let h = 1e-6;
    let kp = k(&Material {
        poisson_ratio: mat.poisson_ratio + h,
        ..mat
    });
    let km = k(&Material {
        poisson_ratio: mat.poisson_ratio - h,
        ..mat
    });
    let fd: Vec<f64> = kp
        .iter()
        .zip(&km)
        .map(|(p, m)| (p - m) / (2.0 * h))
        .collect();
    assert_close(&dk, &fd, 1e-6, "dK/dnu");
}

#[test]
fn matrices_into_reuses_buffers() {
    let kernel = ElementKernel::new(10, false);
    let mut out = ElementMatrices::zeros(10);
    let ptrs = (out.mass.as_ptr(), out.k_lambda.as_ptr(), out.k_mu.as_ptr());
    kernel.matrices_into(&P2_NODES, &mut out).unwrap();
    let first = out.clone();
    let scaled: Vec<_> = P2_NODES
        .iter()
        .map(|x| [2.0 * x[0], 2.0 * x[1], 2.0 * x[2]])
        .collect();
    kernel.matrices_into(&scaled, &mut out).unwrap();
    kernel.matrices_into(&P2_NODES, &mut out).unwrap();
    assert_eq!(out, first, "stale values leaked between calls");
    assert_eq!(
        ptrs,
        (out.mass.as_ptr(), out.k_lambda.as_ptr(), out.k_mu.as_ptr())
    );
    // A wrongly sized buffer is resized.
    let mut small = ElementMatrices::zeros(4);
    kernel.matrices_into(&P2_NODES, &mut small).unwrap();
    assert_eq!(small, first);
}

/// Timing; run with `cargo test --release -- --ignored --nocapture bench`.
#[test]
#[ignore]
fn bench_element_kernels() {
    use std::hint::black_box;
    use std::time::Instant;
    let mut rng = Rng(1);
    let (a, t) = random_affine(&mut rng);
    let straight = mapped(10, &a, &t);
    let p1 = mapped(4, &a, &t);
    let (curved, _) = curved_element(&mut rng, 0.2, 0.1);
    let iso4 = ElementKernel::with_rule(10, &tet_rule(4)).unwrap();
    let cases: [(&str, ElementKernel, &[[f64; 3]]); 4] = [
        ("P1 (affine)", ElementKernel::new(4, false), &p1),
        (
            "P2 straight (affine fast path)",
            ElementKernel::new(10, false),
            &straight,
        ),
        (
            "P2 straight, isoparametric degree-4 (14 pts)",
            iso4,
            &straight,
        ),
        (
            "P2 curved, degree-8 (125 pts)",
            ElementKernel::new(10, false),
            &curved,
        ),
    ];
    for (name, kernel, coords) in cases {
        let mut out = ElementMatrices::zeros(kernel.nodes_per_tet());
        let iters = 200_000;
        for _ in 0..1000 {
            kernel.matrices_into(black_box(coords), &mut out).unwrap();
        }
        let t0 = Instant::now();
        for _ in 0..iters {
            kernel.matrices_into(black_box(coords), &mut out).unwrap();
            black_box(&out);
        }
        let dt = t0.elapsed().as_secs_f64() / iters as f64;
        println!("{name}: {:.3} µs/element", dt * 1e6);
    }
}
