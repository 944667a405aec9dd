//! Serial tests of the geometry task's pure parts: the voxelisation and its staircase surface,
//! the loss terms against finite differences (and the eigenvalue term against the shape
//! module's loss), and a small pre-fit on a ball. The chain θ → field → marching → λ is checked
//! under MPI in `tests/mpi_sensitivity.rs`.

use super::*;
use crate::inverse::shape::spectrum_loss;
use crate::testing::{icosphere, Rng};

fn ball(r: f64) -> (TriangleSurface, SignedDistance) {
    let (v, t) = icosphere(r, 3);
    let s = TriangleSurface::new(v, t).unwrap();
    let d = SignedDistance::new(&s).unwrap();
    (s, d)
}

#[test]
fn voxels_of_a_ball_have_its_volume_and_a_closed_staircase() {
    let r = 0.03;
    let (_, sdf) = ball(r);
    let v = Voxels::of_sdf(&sdf, [-r; 3], [r; 3], 16).unwrap();
    assert_eq!(v.len(), 18 * 18 * 18);
    assert!((v.min_edge() - 2.0 * r / 16.0).abs() < 1e-15);
    // The ring is empty by construction.
    for k in 0..18 {
        for j in 0..18 {
            assert!(!v.inside[v.index(0, j, k)] && !v.inside[v.index(17, j, k)]);
            assert!(!v.inside[v.index(j, 0, k)] && !v.inside[v.index(j, k, 17)]);
        }
    }
    // Centre sampling of a ball: the voxel volume is within a few % of 4/3 π r³ (an icosphere of
    // 1280 faces holds 0.99 of it).
    let exact = 4.0 / 3.0 * std::f64::consts::PI * r.powi(3);
    assert!(
        (v.volume() / exact - 1.0).abs() < 0.04,
        "voxel volume {} vs {exact}",
        v.volume()
    );
    let s = v.boundary_surface();
    // Closed and outward: the enclosed volume is the voxels' volume, exactly.
    assert!(
        (s.signed_volume() - v.volume()).abs() < 1e-12 * v.volume().max(1e-30),
        "{} vs {}",
        s.signed_volume(),
        v.volume()
    );
    let mut edges: HashMap<(usize, usize), i32> = HashMap::new();
    for t in &s.triangles {
        for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
            *edges.entry((a.min(b), a.max(b))).or_default() += if a < b { 1 } else { -1 };
        }
    }
    // Every edge is used once in each direction (closed, consistently oriented; edges where two
    // voxels touch along an edge only are used twice each way, which also sums to 0).
    assert!(edges.values().all(|&n| n == 0));
    assert!(Voxels::of_sdf(&sdf, [-r; 3], [r; 3], 1).is_err());
    assert!(Voxels::of_sdf(&sdf, [r; 3], [r; 3], 8).is_err());
    assert!(
        Voxels::of_sdf(&sdf, [0.05; 3], [0.06; 3], 4).is_err(),
        "no voxel inside"
    );
}

#[test]
fn eigenvalue_loss_is_the_shape_modules_loss_with_its_derivative_per_mode() {
    let target =
        SpectrumTarget::new(vec![1.0e8, 1.004e8, 3.0e8, 5.0e8, 5.02e8, 7.0e8], 1e-2).unwrap();
    let model = vec![1.05e8, 0.98e8, 2.9e8, 5.3e8, 5.1e8, 7.2e8];
    let mut rng = Rng(21);
    let (loss, d) = eigenvalue_loss(&model, &target).unwrap();
    // Any direction dλ/dp: Σ_k ∂L/∂λ_k dλ_k/dp is the shape module's dL/dp.
    for _ in 0..4 {
        let dlambda = rng.uniform_vec(6, -1e7, 1e7);
        let reference = spectrum_loss(&model, &dlambda, &target, false).unwrap();
        let chain: f64 = d.iter().zip(&dlambda).map(|(a, b)| a * b).sum();
        assert!((reference.loss - loss).abs() < 1e-15 * loss.max(1.0));
        assert!(
            (reference.gradient - chain).abs() < 1e-12 * reference.gradient.abs().max(1e-12),
            "{} vs {chain}",
            reference.gradient
        );
    }
    assert!(eigenvalue_loss(&model[..3], &target).is_err());
    assert!(eigenvalue_loss(&[1.0, -1.0, 1.0, 1.0, 1.0, 1.0], &target).is_err());
}

/// Central differences of a loss of the values against its derivative.
fn check_derivative(name: &str, values: &[f64], f: impl Fn(&[f64]) -> (f64, Vec<f64>), h: f64) {
    let (_, d) = f(values);
    for i in 0..values.len() {
        let mut v = values.to_vec();
        v[i] += h;
        let plus = f(&v).0;
        v[i] -= 2.0 * h;
        let minus = f(&v).0;
        let fd = (plus - minus) / (2.0 * h);
        assert!(
            (fd - d[i]).abs() <= 1e-6 * (1.0 + d[i].abs()),
            "{name} value {i}: {} vs FD {fd}",
            d[i]
        );
    }
}

#[test]
fn loss_terms_match_finite_differences() {
    let mut rng = Rng(4);
    let values = rng.uniform_vec(24, -0.004, 0.004);
    let labels: Vec<f64> = (0..24)
        .map(|i| if i % 3 == 0 { 1.0 } else { -1.0 })
        .collect();
    check_derivative("sign", &values, |v| sign_loss(v, &labels, 0.001), 1e-8);
    check_derivative("hinge", &values, |v| hinge_loss(v, &labels, 0.002), 1e-8);
    let stencil_values = rng.uniform_vec(30, -0.01, 0.01);
    check_derivative("eikonal", &stencil_values, |v| eikonal_loss(v, 0.004), 1e-9);
    // A hinge only counts violations: values of the right sign cost nothing.
    let right: Vec<f64> = labels.iter().map(|y| 0.003 * y).collect();
    assert_eq!(hinge_loss(&right, &labels, 0.002).0, 0.0);
}

#[test]
fn eikonal_loss_vanishes_on_a_distance_and_measures_a_scaled_one() {
    // s = n·x for a unit n is a distance: |Ds| = 1 exactly (central differences of a linear
    // field); 2·n·x has |Ds| = 2, so the loss is (2 − 1)² = 1.
    let n = [0.48, 0.6, 0.64];
    let mut rng = Rng(8);
    let points: Vec<[f64; 3]> = (0..10)
        .map(|_| {
            [
                rng.uniform(-1.0, 1.0),
                rng.uniform(-1.0, 1.0),
                rng.uniform(-1.0, 1.0),
            ]
        })
        .collect();
    let around = stencil(&points, 0.01);
    assert_eq!(around.len(), 60);
    let plane: Vec<f64> = around
        .iter()
        .map(|p| n[0] * p[0] + n[1] * p[1] + n[2] * p[2])
        .collect();
    assert!(eikonal_loss(&plane, 0.01).0 < 1e-20);
    let doubled: Vec<f64> = plane.iter().map(|v| 2.0 * v).collect();
    assert!((eikonal_loss(&doubled, 0.01).0 - 1.0).abs() < 1e-10);
}

#[test]
fn prefit_to_a_voxelised_ball_gets_the_signs_and_a_distance_scale() {
    let r = 0.03;
    let (truth, sdf) = ball(r);
    let voxels = Voxels::of_sdf(&sdf, [-r; 3], [r; 3], 8).unwrap();
    let (lo, hi) = voxels.padded_box();
    let config = NeuralSdfConfig::for_box(lo, hi, 2, vec![16, 16]).unwrap();
    let mut net = NeuralSdf::new(config, 3).unwrap();
    let settings = PrefitSettings {
        steps: 400,
        batch: 256,
        eikonal_batch: 64,
        learning_rate: 1e-2,
        final_learning_rate: 1e-3,
        ..Default::default()
    };
    let report = prefit(&mut net, &voxels, &settings).unwrap();
    assert_eq!(report.loss.len(), 400);
    let early = report.loss[..20].iter().sum::<f64>() / 20.0;
    let late = report.loss[380..].iter().sum::<f64>() / 20.0;
    assert!(late < 0.3 * early, "loss {early} → {late}");
    assert!(
        report.centre_accuracy > 0.97,
        "centre accuracy {}",
        report.centre_accuracy
    );
    // A distance-like field: s near the centre is close to the ball's radius (the zero level
    // sits on the voxel faces, up to a voxel edge e = 7.5 mm off the sphere), and the body
    // marched on a grid overlaps the ball.
    let centre = net.value([0.0; 3]);
    assert!(centre > 0.5 * r && centre < 1.6 * r, "s(0) = {centre}");
    assert!(report.eikonal_loss < 0.1, "eikonal {}", report.eikonal_loss);
    let grid = BackgroundGrid::covering([-r; 3], [r; 3], 12, 1.0).unwrap();
    let values = net.values(&grid.vertex_positions());
    let marched = shape::march(&grid, &values, None, &MarchingOptions::default()).unwrap();
    let surface = TriangleSurface::from_mesh_boundary(&marched.mesh);
    let c = shape::compare_shapes(&surface, &truth, 2000, 20_000, 1).unwrap();
    assert!(c.iou > 0.75 && c.chamfer < 0.2 * r, "{c:?}");
    // Same seed, same network.
    let mut again = NeuralSdf::new(net.config().clone(), 3).unwrap();
    prefit(
        &mut again,
        &voxels,
        &PrefitSettings {
            steps: 5,
            ..settings.clone()
        },
    )
    .unwrap();
    let mut twice = NeuralSdf::new(net.config().clone(), 3).unwrap();
    prefit(
        &mut twice,
        &voxels,
        &PrefitSettings {
            steps: 5,
            ..settings.clone()
        },
    )
    .unwrap();
    assert_eq!(again.parameters(), twice.parameters());
    assert!(prefit(
        &mut twice,
        &voxels,
        &PrefitSettings {
            steps: 0,
            ..settings
        }
    )
    .is_err());
}

#[test]
fn settings_are_validated() {
    assert!(GeometrySettings::default().validate().is_ok());
    for bad in [
        GeometrySettings {
            voxels: 1,
            ..Default::default()
        },
        GeometrySettings {
            cells: 32,
            target_cells: 31,
            ..Default::default()
        },
        GeometrySettings {
            modes: 0,
            ..Default::default()
        },
        GeometrySettings {
            modes: 1,
            refine: RefineSettings {
                free_scale: true,
                ..Default::default()
            },
            ..Default::default()
        },
        GeometrySettings {
            hidden: vec![],
            ..Default::default()
        },
        GeometrySettings {
            refine: RefineSettings {
                learning_rate: 0.0,
                ..Default::default()
            },
            ..Default::default()
        },
        GeometrySettings {
            prefit: PrefitSettings {
                margin: f64::NAN,
                ..Default::default()
            },
            ..Default::default()
        },
    ] {
        assert!(
            matches!(
                bad.validate(),
                Err(GeometryError::Invalid(_) | GeometryError::Network(_))
            ),
            "{bad:?}"
        );
    }
}

/// A small network on the box of a voxelised ball, a grid over it, and a made-up per-mode
/// sensitivity dλ_k/ds_i (smooth in i), for the least-squares rows.
/// The group rows on this process alone.
fn serial(
    net: &NeuralSdf,
    points: &[[f64; 3]],
    rows: &[Vec<f64>],
) -> Result<Vec<Vec<f64>>, GeometryError> {
    Ok(net.vjp_rows(points, rows)?)
}

/// The least-squares test case: network, grid points, per-mode rows, eigenvalues, target,
/// voxels, eikonal points and settings.
type LeastSquaresCase = (
    NeuralSdf,
    Vec<[f64; 3]>,
    Vec<Vec<f64>>,
    Vec<f64>,
    SpectrumTarget,
    Voxels,
    Vec<[f64; 3]>,
    RefineSettings,
);

fn least_squares_case() -> LeastSquaresCase {
    let r = 0.03;
    let (_, sdf) = ball(r);
    let voxels = Voxels::of_sdf(&sdf, [-r; 3], [r; 3], 4).unwrap();
    let (lo, hi) = voxels.padded_box();
    let net = NeuralSdf::new(NeuralSdfConfig::for_box(lo, hi, 1, vec![6]).unwrap(), 5).unwrap();
    let grid_points = BackgroundGrid::covering([-r; 3], [r; 3], 3, 1.0)
        .unwrap()
        .vertex_positions();
    let per_mode: Vec<Vec<f64>> = (0..4)
        .map(|k| {
            grid_points
                .iter()
                .map(|p| 1e9 * (1.0 + k as f64) * (p[0] + 2.0 * p[1] - p[2] + 0.1))
                .collect()
        })
        .collect();
    let target = SpectrumTarget::new(vec![1.0e8, 1.003e8, 2.5e8, 4.0e8], 1e-2).unwrap();
    let eigenvalues = vec![1.1e8, 0.97e8, 2.4e8, 4.3e8];
    let eik_points = uniform_points(lo, hi, 7, &mut SplitMix64::new(3));
    let settings = RefineSettings {
        voxel_weight: 2.0,
        eikonal_weight: 0.3,
        ..Default::default()
    };
    (
        net,
        grid_points,
        per_mode,
        eigenvalues,
        target,
        voxels,
        eik_points,
        settings,
    )
}

#[test]
fn least_squares_rows_sum_to_the_loss_and_match_finite_differences_in_theta() {
    let (mut net, grid_points, per_mode, eigenvalues, target, voxels, eik_points, settings) =
        least_squares_case();
    let delta = 0.25 * voxels.min_edge();
    let system = least_squares(
        &serial,
        &net,
        &grid_points,
        &per_mode,
        &eigenvalues,
        &target,
        &voxels,
        &eik_points,
        delta,
        &settings,
    )
    .unwrap();
    // Σ r² is the loss of the three terms.
    let (le, _) = eigenvalue_loss(&eigenvalues, &target).unwrap();
    let (lv, _) = hinge_loss(
        &net.values(&voxels.centres()),
        &voxels.labels(),
        voxels.min_edge(),
    );
    let lk = eikonal_loss(&net.values(&stencil(&eik_points, delta)), delta).0;
    let total = le + settings.voxel_weight * lv + settings.eikonal_weight * lk;
    let squares: f64 = system.residuals.iter().map(|r| r * r).sum();
    assert!(
        (squares - total).abs() <= 1e-12 * total,
        "{squares} vs {total}"
    );
    assert!(
        lv > 0.0,
        "an untrained network violates some voxels, so the case has voxel rows"
    );
    assert_eq!(system.rows.len(), system.residuals.len());
    // The voxel and eikonal rows are ∂r/∂θ: central differences in θ with the active set held.
    // (The eigenvalue rows' λ do not follow θ here; their θ-part is the network's VJP of a
    // fixed dλ/ds, checked for the network itself in neural_sdf.)
    let theta = net.parameters().to_vec();
    let groups = target.groups.len();
    let residuals_at = |net: &NeuralSdf| {
        least_squares(
            &serial,
            net,
            &grid_points,
            &per_mode,
            &eigenvalues,
            &target,
            &voxels,
            &eik_points,
            delta,
            &settings,
        )
        .unwrap()
        .residuals
    };
    let h = 1e-6;
    for i in (0..theta.len()).step_by(7) {
        let mut t = theta.clone();
        t[i] += h;
        net.set_parameters(&t).unwrap();
        let plus = residuals_at(&net);
        t[i] -= 2.0 * h;
        net.set_parameters(&t).unwrap();
        let minus = residuals_at(&net);
        if plus.len() != system.residuals.len() || minus.len() != system.residuals.len() {
            continue; // a voxel crossed its bound: the active set changed
        }
        for j in groups..system.residuals.len() {
            let fd = (plus[j] - minus[j]) / (2.0 * h);
            assert!(
                (fd - system.rows[j][i]).abs() <= 1e-5 * (1.0 + fd.abs()),
                "row {j}, θ_{i}: {} vs FD {fd}",
                system.rows[j][i]
            );
        }
    }
    net.set_parameters(&theta).unwrap();
    // The eigenvalue rows: √|G| · mean_{k∈G} (1/λ_k) dλ_k/ds pushed through the network.
    let g = &target.groups[0];
    assert_eq!(g.len(), 2, "the first two target modes form a cluster");
    let mut d_values = vec![0.0; grid_points.len()];
    for k in g.clone() {
        add_scaled(
            &mut d_values,
            2f64.sqrt() / 2.0 / eigenvalues[k],
            &per_mode[k],
        );
    }
    let expected = net.vjp(&grid_points, &d_values).unwrap();
    assert!(system.rows[0]
        .iter()
        .zip(&expected)
        .all(|(a, b)| (a - b).abs() <= 1e-14 * b.abs().max(1e-300)));
}

#[test]
fn the_minimum_norm_step_solves_the_linearised_rows_in_their_row_space() {
    let mut rng = Rng(12);
    let rows: Vec<Vec<f64>> = (0..3).map(|_| rng.uniform_vec(8, -1.0, 1.0)).collect();
    let residuals = rng.uniform_vec(3, -0.5, 0.5);
    let system = LeastSquares {
        residuals: residuals.clone(),
        rows: rows.clone(),
    };
    let step = minimum_norm_step(&system, 1e-12).unwrap();
    // J δ = −r: an underdetermined system solved exactly …
    for (row, r) in rows.iter().zip(&residuals) {
        let jd: f64 = row.iter().zip(&step).map(|(a, b)| a * b).sum();
        assert!((jd + r).abs() < 1e-9, "{jd} vs {}", -r);
    }
    // … by the smallest step: δ lies in the span of the rows, so any other solution δ + n
    // (n in the null space) is longer. Take n = a random vector minus its projection on the rows.
    let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
    let mut n = rng.uniform_vec(8, -1.0, 1.0);
    for _ in 0..50 {
        for row in &rows {
            let c = row.iter().zip(&n).map(|(a, b)| a * b).sum::<f64>()
                / row.iter().map(|a| a * a).sum::<f64>();
            add_scaled(&mut n, -c, row);
        }
    }
    let other: Vec<f64> = step.iter().zip(&n).map(|(a, b)| a + b).collect();
    assert!(norm(&other) > norm(&step));
    // Damping shortens it.
    assert!(norm(&minimum_norm_step(&system, 1.0).unwrap()) < norm(&step));
}

#[test]
fn the_free_scale_loss_is_the_shape_modules_and_ignores_a_common_factor() {
    let target =
        SpectrumTarget::new(vec![1.0e8, 1.004e8, 3.0e8, 5.0e8, 5.02e8, 7.0e8], 1e-2).unwrap();
    let model = vec![1.05e8, 0.98e8, 2.9e8, 5.3e8, 5.1e8, 7.2e8];
    let mut rng = Rng(22);
    let (loss, d) = eigenvalue_loss_with(&model, &target, true).unwrap();
    assert!(loss > 0.0 && loss < eigenvalue_loss(&model, &target).unwrap().0);
    for _ in 0..4 {
        let dlambda = rng.uniform_vec(6, -1e7, 1e7);
        let reference = spectrum_loss(&model, &dlambda, &target, true).unwrap();
        let chain: f64 = d.iter().zip(&dlambda).map(|(a, b)| a * b).sum();
        assert!(
            (reference.loss - loss).abs() < 1e-14 * loss,
            "{} vs {loss}",
            reference.loss
        );
        assert!(
            (reference.gradient - chain).abs() < 1e-10 * reference.gradient.abs().max(1e-12),
            "{} vs {chain}",
            reference.gradient
        );
    }
    // A stiffness factor common to every mode is invisible to it.
    let stiffer: Vec<f64> = model.iter().map(|l| 1.7 * l).collect();
    let (scaled, _) = eigenvalue_loss_with(&stiffer, &target, true).unwrap();
    assert!((scaled - loss).abs() < 1e-12 * loss, "{scaled} vs {loss}");
}

#[test]
fn free_scale_rows_are_the_plain_rows_less_their_weighted_mean_and_sum_to_the_loss() {
    let (net, grid_points, per_mode, eigenvalues, target, voxels, eik_points, plain_settings) =
        least_squares_case();
    let delta = 0.25 * voxels.min_edge();
    let free_settings = RefineSettings {
        free_scale: true,
        ..plain_settings.clone()
    };
    let plain = least_squares(
        &serial,
        &net,
        &grid_points,
        &per_mode,
        &eigenvalues,
        &target,
        &voxels,
        &eik_points,
        delta,
        &plain_settings,
    )
    .unwrap();
    let free = least_squares(
        &serial,
        &net,
        &grid_points,
        &per_mode,
        &eigenvalues,
        &target,
        &voxels,
        &eik_points,
        delta,
        &free_settings,
    )
    .unwrap();
    assert_eq!(plain.residuals.len(), free.residuals.len());
    // Σ r² is the free-scale eigenvalue loss plus the same voxel and eikonal terms.
    let groups = &target.groups;
    let (le_plain, _) = eigenvalue_loss(&eigenvalues, &target).unwrap();
    let (le_free, _) = eigenvalue_loss_with(&eigenvalues, &target, true).unwrap();
    let squares = |s: &LeastSquares| s.residuals.iter().map(|r| r * r).sum::<f64>();
    let expected = squares(&plain) - le_plain + le_free;
    assert!(
        (squares(&free) - expected).abs() <= 1e-12 * expected,
        "{} vs {expected}",
        squares(&free)
    );
    // Eigenvalue rows: J_G − J̄ (J_G = row_G/√|G|, J̄ the |G|-weighted mean), times √|G|.
    let total: f64 = groups.iter().map(|g| g.len() as f64).sum();
    let n_theta = plain.rows[0].len();
    let mean: Vec<f64> = (0..n_theta)
        .map(|j| {
            groups
                .iter()
                .enumerate()
                .map(|(i, g)| g.len() as f64 * plain.rows[i][j] / (g.len() as f64).sqrt())
                .sum::<f64>()
                / total
        })
        .collect();
    for (i, g) in groups.iter().enumerate() {
        let root = (g.len() as f64).sqrt();
        for (j, &mean_j) in mean.iter().enumerate() {
            let want = root * (plain.rows[i][j] / root - mean_j);
            assert!(
                (free.rows[i][j] - want).abs() <= 1e-12 * (want.abs() + mean_j.abs()).max(1e-300),
                "group {i}, θ_{j}: {} vs {want}",
                free.rows[i][j]
            );
        }
    }
    // The voxel and eikonal rows do not change.
    for j in groups.len()..plain.rows.len() {
        assert_eq!(plain.residuals[j], free.residuals[j]);
        assert_eq!(plain.rows[j], free.rows[j]);
    }
}
