//! Marching tests: every sign configuration of one tet against the exact inside volume of
//! the linear interpolant, convergence and validity on an analytic sphere, finite-difference
//! checks of the vector–Jacobian products (through shell, morph and a P2 eigenvalue), and
//! the shared shapes.

use std::time::Instant;

use nalgebra::{DMatrix, DVector, SymmetricEigen};

use super::*;
use crate::fem::{ElasticCoefficients, ElementKernel, SensitivityKernel};
use crate::mesh::tests::shared_file;
use crate::mesh::{lift_to_quadratic, linear_node_gradient, read_mesh, ReadOptions, TET10_EDGES};
use crate::shape::sdf::SignedDistance;
use crate::shape::surface::{read_obj, TriangleSurface};
use crate::testing::Rng;

// ---------------------------------------------------------------- helpers

fn norm3(a: [f64; 3]) -> f64 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}

fn sphere_values(grid: &BackgroundGrid, centre: [f64; 3], r: f64) -> Vec<f64> {
    grid.vertex_positions()
        .iter()
        .map(|x| r - norm3(sub3(*x, centre)))
        .collect()
}

fn sub3(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// Checks everything the FEM needs and that the mesh is conforming with a closed,
/// connected surface; returns the Euler characteristic of the boundary.
fn check_valid(m: &MarchedMesh) -> i64 {
    let mesh = &m.mesh;
    assert_eq!(mesh.order, ElementOrder::Linear);
    assert_eq!(m.origins.len(), mesh.n_nodes());
    let (lo, hi) = mesh.bounding_box();
    let rule = ZERO_VOLUME_RELATIVE_TOLERANCE * norm3(sub3(hi, lo)).powi(3);
    for e in 0..mesh.n_tets() {
        let v = mesh.corner_volume(e);
        assert!(v > rule, "tet {e}: volume {v:e} ≤ {rule:e}");
        assert!(v >= m.report.min_tet_volume);
    }
    // Every face is shared by at most two tets.
    let mut faces: Vec<[usize; 3]> = (0..mesh.n_tets())
        .flat_map(|e| {
            let t = mesh.tet(e);
            [
                [t[0], t[1], t[2]],
                [t[0], t[1], t[3]],
                [t[0], t[2], t[3]],
                [t[1], t[2], t[3]],
            ]
            .map(|mut f| {
                f.sort_unstable();
                f
            })
        })
        .collect();
    faces.sort_unstable();
    for w in faces.windows(3) {
        assert!(
            !(w[0] == w[1] && w[1] == w[2]),
            "face {:?} shared by 3 tets",
            w[0]
        );
    }
    // The boundary is a closed surface: every boundary edge in exactly two boundary faces.
    let boundary = mesh.boundary_faces();
    let mut edges: Vec<(usize, usize)> = boundary
        .iter()
        .flat_map(|f| [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])].map(|(a, b)| (a.min(b), a.max(b))))
        .collect();
    edges.sort_unstable();
    let mut i = 0;
    let mut n_edges = 0i64;
    while i < edges.len() {
        let mut j = i;
        while j < edges.len() && edges[j] == edges[i] {
            j += 1;
        }
        assert_eq!(j - i, 2, "boundary edge {:?} in {} faces", edges[i], j - i);
        n_edges += 1;
        i = j;
    }
    // ... and every boundary vertex has one fan of boundary faces around it (no pinches).
    let vertices = mesh.surface_vertices();
    let mut star: Vec<Vec<usize>> = vec![Vec::new(); vertices.len()];
    for (f, face) in boundary.iter().enumerate() {
        for n in face {
            star[vertices.binary_search(n).unwrap()].push(f);
        }
    }
    for (slot, faces_here) in star.iter().enumerate() {
        let mut sets = DisjointSets::new(faces_here.len());
        for a in 0..faces_here.len() {
            for b in a + 1..faces_here.len() {
                let shared = boundary[faces_here[a]]
                    .iter()
                    .filter(|n| boundary[faces_here[b]].contains(n))
                    .count();
                if shared == 2 {
                    sets.union(a, b);
                }
            }
        }
        let fans = (0..faces_here.len()).filter(|&a| sets.find(a) == a).count();
        assert_eq!(
            fans, 1,
            "boundary vertex {} is a pinch of {fans} fans",
            vertices[slot]
        );
    }
    assert_eq!(mesh.connected_components(), 1);
    vertices.len() as i64 - n_edges + boundary.len() as i64
}

/// Every element passes the P2 kernel after lifting; returns the P2 volume.
fn check_p2_kernel(m: &TetMesh) -> f64 {
    let q = lift_to_quadratic(m);
    let kernel = ElementKernel::new(10, false);
    let mut volume = 0.0;
    for e in 0..q.n_tets() {
        let coords = q.tet_coords(e);
        volume += kernel
            .volume(&coords)
            .unwrap_or_else(|err| panic!("element {e}: {err}"));
        kernel
            .matrices(&coords)
            .unwrap_or_else(|err| panic!("element {e}: {err}"));
    }
    volume
}

/// Σ_e V_e and Σ_e V_e q(c_e), q(c) = |c|² + c_x c_y + 0.3 c_z (c_e the centroid), with
/// their gradients with respect to the nodes (3 per node).
fn losses(mesh: &TetMesh) -> [(f64, Vec<f64>); 2] {
    let mut value = [0.0; 2];
    let mut grad = [vec![0.0; 3 * mesh.n_nodes()], vec![0.0; 3 * mesh.n_nodes()]];
    for e in 0..mesh.n_tets() {
        let t = mesh.tet(e);
        let x = mesh.corner_coords(e);
        let v = signed_tet_volume(x[0], x[1], x[2], x[3]);
        let e1 = sub3(x[1], x[0]);
        let e2 = sub3(x[2], x[0]);
        let e3 = sub3(x[3], x[0]);
        let d1 = crate::mesh::cross(e2, e3).map(|c| c / 6.0);
        let d2 = crate::mesh::cross(e3, e1).map(|c| c / 6.0);
        let d3 = crate::mesh::cross(e1, e2).map(|c| c / 6.0);
        let d0 = [0, 1, 2].map(|k| -d1[k] - d2[k] - d3[k]);
        let dv = [d0, d1, d2, d3];
        let c = [0, 1, 2].map(|k| 0.25 * (x[0][k] + x[1][k] + x[2][k] + x[3][k]));
        let q = c[0] * c[0] + c[1] * c[1] + c[2] * c[2] + c[0] * c[1] + 0.3 * c[2];
        let dq = [2.0 * c[0] + c[1], 2.0 * c[1] + c[0], 2.0 * c[2] + 0.3];
        value[0] += v;
        value[1] += v * q;
        for a in 0..4 {
            for k in 0..3 {
                grad[0][3 * t[a] + k] += dv[a][k];
                grad[1][3 * t[a] + k] += q * dv[a][k] + v * 0.25 * dq[k];
            }
        }
    }
    let [g0, g1] = grad;
    [(value[0], g0), (value[1], g1)]
}

/// Same connectivity and the same kind of origin (grid vertex or crossing edge) per node.
fn same_topology(a: &MarchedMesh, b: &MarchedMesh) -> bool {
    a.mesh.connectivity == b.mesh.connectivity
        && a.origins.len() == b.origins.len()
        && a.origins.iter().zip(&b.origins).all(|(x, y)| match (x, y) {
            (VertexOrigin::Grid { vertex: p }, VertexOrigin::Grid { vertex: q }) => p == q,
            (
                VertexOrigin::Crossing { a: p, b: q, .. },
                VertexOrigin::Crossing { a: r, b: s, .. },
            ) => (p, q) == (r, s),
            _ => false,
        })
}

/// Central difference of `f` at `x` along coordinate `k`, or `None` if the perturbed meshes
/// change topology (the derivative is then not defined).
fn central_difference(
    x: &[f64],
    k: usize,
    eps: f64,
    base: &MarchedMesh,
    f: &dyn Fn(&[f64]) -> (MarchedMesh, f64),
) -> Option<f64> {
    let mut plus = x.to_vec();
    plus[k] += eps;
    let mut minus = x.to_vec();
    minus[k] -= eps;
    let (mp, fp) = f(&plus);
    let (mm, fm) = f(&minus);
    (same_topology(base, &mp) && same_topology(base, &mm)).then(|| (fp - fm) / (2.0 * eps))
}

/// A bumpy ellipsoid: s = 1 − |D⁻¹(x − c)| + 0.05 sin(7x + 3y) sin(5z).
fn bumpy(x: [f64; 3]) -> f64 {
    let c = [0.02, -0.01, 0.03];
    let d = [0.45, 0.35, 0.3];
    let y = [0, 1, 2].map(|k| (x[k] - c[k]) / d[k]);
    1.0 - norm3(y) + 0.05 * (7.0 * x[0] + 3.0 * x[1]).sin() * (5.0 * x[2]).sin()
}

// ---------------------------------------------------------------- one tet

/// Exact fraction of a tet where the linear interpolant of `s` is positive: the B-spline
/// identity P(Σλ_i s_i > 0) = Σ_{s_i > 0} s_i³ / Π_{j≠i} (s_i − s_j) for λ uniform on the
/// simplex (positive values distinct; zero and negative values may repeat).
fn exact_inside_fraction(s: &[f64; 4]) -> f64 {
    (0..4)
        .filter(|&i| s[i] > 0.0)
        .map(|i| {
            s[i].powi(3)
                / (0..4)
                    .filter(|&j| j != i)
                    .map(|j| s[i] - s[j])
                    .product::<f64>()
        })
        .sum()
}

fn local_position(x: &[[f64; 3]; 4], sv: &[f64; 4], p: Local) -> [f64; 3] {
    let l = barycentric(sv, p);
    [0, 1, 2].map(|k| (0..4).map(|c| l[c] * x[c][k]).sum())
}

#[test]
fn every_sign_configuration_of_one_tet_partitions_its_inside() {
    let mut rng = Rng(21);
    let x: [[f64; 3]; 4] = [
        [0.1, -0.2, 0.0],
        [1.3, 0.1, -0.1],
        [0.2, 1.1, 0.3],
        [0.0, 0.2, 0.9],
    ];
    let parent = signed_tet_volume(x[0], x[1], x[2], x[3]);
    assert!(parent > 0.0);
    let mut pieces = Vec::new();
    let mut cases = 0;
    let mut smallest = f64::INFINITY;
    // All 3⁴ patterns of (−, 0, +), each with every ordering of the global vertex ids (which
    // picks the quad diagonals) and random magnitudes.
    for pattern in 0..81usize {
        let signs: [i32; 4] = [0, 1, 2, 3].map(|k| (pattern / 3usize.pow(k as u32) % 3) as i32 - 1);
        if !signs.contains(&1) {
            continue;
        }
        for perm in 0..24usize {
            let mut ids: Vec<usize> = vec![3, 11, 40, 57];
            let mut order = Vec::new();
            let mut rest = perm;
            for n in (1..=4).rev() {
                order.push(ids.remove(rest % n));
                rest /= n;
            }
            let g = [order[0], order[1], order[2], order[3]];
            // Magnitudes at least 0.2 apart keep the reference formula well conditioned.
            let rank = [perm % 4, (perm + 1) % 4, (perm + 2) % 4, (perm + 3) % 4];
            let sv: [f64; 4] = std::array::from_fn(|c| {
                signs[c] as f64 * (0.2 + 0.5 * rank[c] as f64 + 0.3 * rng.next())
            });
            let whole = inside_pieces(&g, &sv, &mut pieces);
            assert_eq!(whole, !signs.contains(&-1));
            let expected = match (
                signs.iter().filter(|&&c| c > 0).count(),
                signs.iter().filter(|&&c| c < 0).count(),
            ) {
                (_, 0) => 1,
                (1, _) => 1,
                (2, 1) => 2,
                _ => 3,
            };
            assert_eq!(pieces.len(), expected, "signs {signs:?}");
            let corners: Vec<[[f64; 3]; 4]> = pieces
                .iter()
                .map(|p| p.map(|l| local_position(&x, &sv, l)))
                .collect();
            let mut total = 0.0;
            for c in &corners {
                let v = signed_tet_volume(c[0], c[1], c[2], c[3]);
                assert!(
                    v > 1e-6 * parent,
                    "signs {signs:?} values {sv:?}: sub-tet volume {v}"
                );
                total += v;
            }
            let exact = exact_inside_fraction(&sv) * parent;
            smallest = smallest.min(
                corners
                    .iter()
                    .map(|c| signed_tet_volume(c[0], c[1], c[2], c[3]))
                    .fold(f64::INFINITY, f64::min)
                    / parent,
            );
            assert!(
                (total - exact).abs() < 1e-12 * parent,
                "signs {signs:?} values {sv:?}: {total} vs {exact}"
            );
            // The pieces do not overlap: random points of the tet lie in exactly one piece
            // when inside and in none when outside.
            for _ in 0..60 {
                let mut l = [0, 1, 2, 3].map(|_| -rng.next().max(1e-300).ln());
                let sum: f64 = l.iter().sum();
                l = l.map(|v| v / sum);
                let p = [0, 1, 2].map(|k| (0..4).map(|c| l[c] * x[c][k]).sum::<f64>());
                let value: f64 = (0..4).map(|c| l[c] * sv[c]).sum();
                if value.abs() < 1e-9 {
                    continue;
                }
                let containing = corners
                    .iter()
                    .filter(|c| {
                        let v = signed_tet_volume(c[0], c[1], c[2], c[3]);
                        (0..4).all(|r| {
                            let mut d = **c;
                            d[r] = p;
                            signed_tet_volume(d[0], d[1], d[2], d[3]) >= -1e-12 * v
                        })
                    })
                    .count();
                assert_eq!(
                    containing,
                    usize::from(value > 0.0),
                    "signs {signs:?} point {p:?}"
                );
            }
            cases += 1;
        }
    }
    assert_eq!(cases, (81 - 16) * 24);
    eprintln!("one tet: {cases} cases, smallest sub-tet {smallest:.2e} of the tet");
}

// ---------------------------------------------------------------- the sphere

#[test]
fn sphere_volume_converges_and_the_mesh_is_valid() {
    let centre = [0.013, -0.021, 0.007];
    let r = 0.5;
    let exact = 4.0 / 3.0 * std::f64::consts::PI * r * r * r;
    let mut errors = Vec::new();
    for n in [8usize, 16, 32] {
        let lo = centre.map(|c| c - r);
        let hi = centre.map(|c| c + r);
        let grid = BackgroundGrid::covering(lo, hi, n, 1.0).unwrap();
        let h = grid.spacing()[0];
        let values = sphere_values(&grid, centre, r);
        let start = Instant::now();
        let m = march(&grid, &values, None, &MarchingOptions::default()).unwrap();
        let seconds = start.elapsed().as_secs_f64();
        let euler = check_valid(&m);
        assert_eq!(euler, 2, "the boundary of a ball is a sphere");
        assert_eq!(m.report.components, 1);
        assert_eq!(
            m.report.dropped_small_tets + m.report.dropped_inverted_tets,
            0,
            "{}",
            m.report
        );
        // Every boundary vertex lies on the sphere up to the interpolation error of the
        // crossing (< ℓ²/8r along an edge of length ℓ ≤ √3 h) or the snapping (≤ τ √3 h).
        let mut worst: f64 = 0.0;
        for v in m.mesh.surface_vertices() {
            let off = (norm3(sub3(m.mesh.nodes[v], centre)) - r).abs();
            worst = worst.max(off);
            let tau = MarchingOptions::default().snap_fraction;
            assert!(
                off <= 3.0 * h * h / (8.0 * r) + tau * 3f64.sqrt() * h + 1e-12,
                "n = {n}: vertex {v} off by {off}"
            );
        }
        let error = (m.mesh.volume() - exact).abs() / exact;
        eprintln!(
            "sphere n = {n}: {} tets, {} nodes, relative volume error {error:.3e}, surface offset ≤ {:.2e} h, \
             smallest tet {:.2e} of a grid tet, {:.3} s; {}",
            m.mesh.n_tets(),
            m.mesh.n_nodes(),
            worst / h,
            m.report.min_tet_volume / (h * h * h / 6.0),
            seconds,
            m.report
        );
        errors.push(error);
        if n == 16 {
            let p2 = check_p2_kernel(&m.mesh);
            assert!((p2 - m.mesh.volume()).abs() < 1e-12 * exact);
        }
    }
    let orders: Vec<f64> = errors.windows(2).map(|w| (w[0] / w[1]).log2()).collect();
    eprintln!("observed orders of the volume error: {orders:.2?}");
    assert!(errors[2] < 0.01, "{errors:?}");
    assert!(orders.iter().all(|&p| p > 1.5), "orders {orders:?}");
}

#[test]
fn snapping_and_zero_values_are_handled_deterministically() {
    // A sphere whose radius puts it exactly through grid vertices, and values that are tiny
    // against their edges: both become zero values and the mesh stays valid and closed.
    let grid = BackgroundGrid::new([-1.0; 3], [0.25; 3], [8, 8, 8]).unwrap();
    let mut values = sphere_values(&grid, [0.0; 3], 0.75);
    assert!(values.iter().filter(|&&s| s == 0.0).count() >= 6);
    let plain = march(
        &grid,
        &values,
        None,
        &MarchingOptions {
            snap_fraction: 0.0,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(plain.report.snapped_vertices, 0);
    assert_eq!(check_valid(&plain), 2);
    for (v, x) in grid.vertex_positions().iter().enumerate() {
        if (norm3(*x) - 0.75).abs() < 0.13 {
            values[v] += 1e-4 * (x[0] + 2.0 * x[1]).sin();
        }
    }
    let snapped = march(&grid, &values, None, &MarchingOptions::default()).unwrap();
    assert!(snapped.report.snapped_vertices > 0, "{}", snapped.report);
    assert_eq!(check_valid(&snapped), 2);
    let again = march(&grid, &values, None, &MarchingOptions::default()).unwrap();
    assert_eq!(again.mesh, snapped.mesh);
    // Every remaining crossing keeps its distance τ from both grid vertices.
    for o in &snapped.origins {
        if let VertexOrigin::Crossing { t, .. } = *o {
            assert!((0.05..=0.95).contains(&t), "t = {t}");
        }
    }
}

#[test]
fn largest_component_is_kept_and_offsets_are_guarded() {
    // Two balls, the second smaller: only the first survives.
    let grid = BackgroundGrid::new([-1.0, -0.5, -0.5], [0.1; 3], [20, 10, 10]).unwrap();
    let values: Vec<f64> = grid
        .vertex_positions()
        .iter()
        .map(|x| {
            (0.4 - norm3(sub3(*x, [-0.5, 0.0, 0.0]))).max(0.25 - norm3(sub3(*x, [0.5, 0.0, 0.0])))
        })
        .collect();
    let m = march(&grid, &values, None, &MarchingOptions::default()).unwrap();
    assert_eq!(m.report.components, 2);
    assert!(m.report.dropped_component_tets > 0);
    let small = 4.0 / 3.0 * std::f64::consts::PI * 0.25f64.powi(3);
    assert!(
        (m.report.dropped_component_volume - small).abs() < 0.1 * small,
        "{}",
        m.report
    );
    assert!(m.mesh.nodes.iter().all(|x| x[0] < 0.0));
    let both = march(
        &grid,
        &values,
        None,
        &MarchingOptions {
            keep_largest_component: false,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(both.mesh.connected_components(), 2);

    // Offsets up to half a cell may invert background tets: their pieces are dropped and
    // counted, and what is left is still a valid mesh for the FEM.
    let mut rng = Rng(8);
    let theta = rng.uniform_vec(3 * grid.n_vertices(), -0.1, 0.1);
    let m = march(
        &grid,
        &values,
        Some(&theta),
        &MarchingOptions {
            max_offset_fraction: 0.5,
            ..Default::default()
        },
    )
    .unwrap();
    eprintln!("random offsets up to half a cell: {}", m.report);
    assert!(m.report.inverted_background_tets > 0 && m.report.dropped_inverted_tets > 0);
    let (lo, hi) = m.mesh.bounding_box();
    let rule = ZERO_VOLUME_RELATIVE_TOLERANCE * norm3(sub3(hi, lo)).powi(3);
    assert!((0..m.mesh.n_tets()).all(|e| m.mesh.corner_volume(e) > rule));
    check_p2_kernel(&m.mesh);
    // Below a sixth of a cell no background tet inverts (the default is an eighth).
    let m = march(&grid, &values, Some(&theta), &MarchingOptions::default()).unwrap();
    eprintln!("random offsets up to an eighth of a cell: {}", m.report);
    assert_eq!(m.report.inverted_background_tets, 0, "{}", m.report);
    assert_eq!(
        m.report.dropped_small_tets + m.report.dropped_inverted_tets,
        0,
        "{}",
        m.report
    );
    assert_eq!(check_valid(&m), 2);
}

// ---------------------------------------------------------------- gradients

#[test]
fn vjp_matches_finite_differences_for_values_and_offsets() {
    let grid = BackgroundGrid::covering([-0.45, -0.35, -0.3], [0.45, 0.35, 0.3], 7, 1.0).unwrap();
    let h = grid.spacing()[0];
    let values: Vec<f64> = grid.vertex_positions().iter().map(|&x| bumpy(x)).collect();
    let mut rng = Rng(99);
    let mut theta = rng.uniform_vec(3 * grid.n_vertices(), -0.15 * h, 0.15 * h);
    // A few offsets beyond the bound, whose derivative is zero.
    for v in (0..grid.n_vertices()).step_by(5) {
        theta[3 * v] = 0.7 * h;
    }
    let options = MarchingOptions::default();
    let base = march(&grid, &values, Some(&theta), &options).unwrap();
    check_valid(&base);
    for which in 0..2 {
        let (_, d_x) = &losses(&base.mesh)[which];
        let grad = base.vjp(d_x).unwrap();
        let scale_s = grad.values.iter().fold(0.0f64, |a, b| a.max(b.abs()));
        let scale_t = grad.offsets.iter().fold(0.0f64, |a, b| a.max(b.abs()));
        let f_values = |s: &[f64]| {
            let m = march(&grid, s, Some(&theta), &options).unwrap();
            let l = losses(&m.mesh)[which].0;
            (m, l)
        };
        let f_offsets = |t: &[f64]| {
            let m = march(&grid, &values, Some(t), &options).unwrap();
            let l = losses(&m.mesh)[which].0;
            (m, l)
        };
        let (mut checked, mut skipped, mut nonzero) = (0, 0, 0);
        for v in 0..grid.n_vertices() {
            match central_difference(&values, v, 1e-6, &base, &f_values) {
                Some(fd) => {
                    checked += 1;
                    nonzero += usize::from(grad.values[v] != 0.0);
                    assert!(
                        (fd - grad.values[v]).abs() <= 1e-6 * scale_s,
                        "loss {which}, dL/ds[{v}]: fd {fd} vs {}",
                        grad.values[v]
                    );
                }
                None => skipped += 1,
            }
        }
        eprintln!("loss {which}: dL/ds checked at {checked} grid values ({nonzero} non-zero), {skipped} skipped (topology change)");
        assert!(
            nonzero > 50 && skipped * 20 < checked,
            "loss {which}: {checked} checked ({nonzero} non-zero), {skipped} skipped"
        );
        let (mut checked, mut skipped, mut clamped) = (0, 0, 0);
        for k in 0..theta.len() {
            match central_difference(&theta, k, 1e-7 * h, &base, &f_offsets) {
                Some(fd) => {
                    checked += 1;
                    clamped += usize::from(
                        theta[k] > 0.5 * h
                            && base.origins.iter().any(
                                |o| matches!(*o, VertexOrigin::Grid { vertex } if vertex == k / 3),
                            ),
                    );
                    assert!(
                        (fd - grad.offsets[k]).abs() <= 1e-6 * scale_t,
                        "loss {which}, dL/dθ[{k}]: fd {fd} vs {}",
                        grad.offsets[k]
                    );
                }
                None => skipped += 1,
            }
        }
        eprintln!("loss {which}: dL/dθ checked at {checked} offsets ({clamped} clamped), {skipped} skipped");
        assert!(
            clamped > 0 && skipped * 20 < checked,
            "loss {which}: {checked} checked, {skipped} skipped, {clamped} clamped"
        );
    }
    assert!(matches!(
        base.vjp(&[0.0; 3]),
        Err(MarchingError::LengthMismatch { .. })
    ));
}

#[test]
fn shell_thickness_and_morph_derivatives_match_finite_differences() {
    // h = 0.1: every grid edge is shorter than the wall (t·max s = 0.235), so the wall has
    // no holes and the boundary is two spheres.
    let grid = BackgroundGrid::covering([-0.5; 3], [0.5; 3], 12, 1.0).unwrap();
    let points = grid.vertex_positions();
    let sphere: Vec<f64> = points
        .iter()
        .map(|x| 0.47 - norm3(sub3(*x, [0.031, -0.017, 0.011])))
        .collect();
    let options = MarchingOptions::default();

    // Shell: L(march(min(s, t·max s − s))).
    let thickness = 0.5;
    let sh = shell(&sphere, thickness).unwrap();
    assert_eq!(sh.values.len(), sphere.len());
    assert!(sh
        .values
        .iter()
        .zip(&sphere)
        .all(|(g, s)| (*g > 0.0) == (*s > 0.0 && *s < thickness * sh.max_value)));
    let base = march(&grid, &sh.values, None, &options).unwrap();
    assert_eq!(
        check_valid(&base),
        4,
        "a hollow ball has two boundary spheres"
    );
    let (_, d_x) = &losses(&base.mesh)[1];
    let d_g = base.vjp(d_x).unwrap().values;
    let d = sh.vjp(&d_g).unwrap();
    let f_t = |t: &[f64]| {
        let m = march(&grid, &shell(&sphere, t[0]).unwrap().values, None, &options).unwrap();
        let l = losses(&m.mesh)[1].0;
        (m, l)
    };
    let fd = central_difference(&[thickness], 0, 1e-7, &base, &f_t).expect("stable topology");
    eprintln!("shell: dL/dt = {} (finite difference {fd})", d.thickness);
    assert!(
        (fd - d.thickness).abs() < 1e-6 * d.thickness.abs(),
        "{fd} vs {}",
        d.thickness
    );
    let f_s = |s: &[f64]| {
        let m = march(&grid, &shell(s, thickness).unwrap().values, None, &options).unwrap();
        let l = losses(&m.mesh)[1].0;
        (m, l)
    };
    let scale = d.values.iter().fold(0.0f64, |a, b| a.max(b.abs()));
    assert!(
        d.values[sh.argmax] != 0.0,
        "the maximum moves the inner wall"
    );
    // Every 6th grid value with a non-zero derivative, the argmax, and some zero ones.
    let nonzero: Vec<usize> = (0..sphere.len()).filter(|&v| d.values[v] != 0.0).collect();
    let mut picked: Vec<usize> = nonzero
        .iter()
        .copied()
        .step_by(6)
        .chain([sh.argmax])
        .chain((0..sphere.len()).step_by(97))
        .collect();
    picked.sort_unstable();
    picked.dedup();
    let mut checked = 0;
    for v in picked {
        if let Some(fd) = central_difference(&sphere, v, 1e-6, &base, &f_s) {
            assert!(
                (fd - d.values[v]).abs() <= 1e-6 * scale,
                "dL/ds[{v}]: {fd} vs {}",
                d.values[v]
            );
            checked += 1;
        }
    }
    eprintln!(
        "shell: dL/ds checked at {checked} grid values ({} non-zero)",
        nonzero.len()
    );
    assert!(checked > 50, "{checked}");

    // Morph between the sphere and a rounded box: L(march(c·A + (1 − c)·B)).
    let rounded_box: Vec<f64> = points
        .iter()
        .map(|x| 0.38 - x.iter().map(|c| c.powi(4)).sum::<f64>().powf(0.25))
        .collect();
    let c = 0.37;
    let morphed = morph(&sphere, &rounded_box, c).unwrap();
    let base = march(&grid, &morphed, None, &options).unwrap();
    check_valid(&base);
    let (_, d_x) = &losses(&base.mesh)[1];
    let d_m = base.vjp(d_x).unwrap().values;
    let d = morph_vjp(&sphere, &rounded_box, c, &d_m).unwrap();
    let f_c = |c: &[f64]| {
        let m = march(
            &grid,
            &morph(&sphere, &rounded_box, c[0]).unwrap(),
            None,
            &options,
        )
        .unwrap();
        let l = losses(&m.mesh)[1].0;
        (m, l)
    };
    let fd = central_difference(&[c], 0, 1e-7, &base, &f_c).expect("stable topology");
    eprintln!("morph: dL/dc = {} (finite difference {fd})", d.c);
    assert!(
        (fd - d.c).abs() < 1e-6 * d.c.abs().max(1e-3),
        "{fd} vs {}",
        d.c
    );
    let f_a = |a: &[f64]| {
        let m = march(&grid, &morph(a, &rounded_box, c).unwrap(), None, &options).unwrap();
        let l = losses(&m.mesh)[1].0;
        (m, l)
    };
    let scale = d.a.iter().fold(0.0f64, |x, y| x.max(y.abs()));
    for v in (0..sphere.len()).filter(|&v| d.a[v] != 0.0).step_by(10) {
        if let Some(fd) = central_difference(&sphere, v, 1e-6, &base, &f_a) {
            assert!(
                (fd - d.a[v]).abs() <= 1e-6 * scale,
                "dL/dA[{v}]: {fd} vs {}",
                d.a[v]
            );
            assert!((d.b[v] - d.a[v] * (1.0 - c) / c).abs() <= 1e-12 * scale);
        }
    }
    assert!(matches!(
        shell(&sphere, 0.0),
        Err(MarchingError::BadThickness { .. })
    ));
    assert!(matches!(
        shell(&[-1.0, 0.0], 0.5),
        Err(MarchingError::NothingInside)
    ));
    assert!(matches!(
        morph(&sphere, &sphere[1..], c),
        Err(MarchingError::LengthMismatch { .. })
    ));
}

/// Dense P2 elasticity (λ_L = μ = ρ = 1) of a linear mesh: eigenvalues ascending and the
/// M-normalised mode of eigenvalue `index`, on the lifted mesh.
fn p2_mode(linear: &TetMesh, index: usize) -> (TetMesh, Vec<f64>, f64, Vec<f64>) {
    let q = lift_to_quadratic(linear);
    let n = 3 * q.n_nodes();
    let kernel = ElementKernel::new(10, false);
    let mut k = DMatrix::<f64>::zeros(n, n);
    let mut m = DMatrix::<f64>::zeros(n, n);
    for e in 0..q.n_tets() {
        let em = kernel.matrices(&q.tet_coords(e)).unwrap();
        let t = q.tet(e);
        for a in 0..30 {
            for b in 0..30 {
                let (ga, gb) = (3 * t[a / 3] + a % 3, 3 * t[b / 3] + b % 3);
                k[(ga, gb)] += em.k_lambda[a * 30 + b] + em.k_mu[a * 30 + b];
                m[(ga, gb)] += em.mass[a * 30 + b];
            }
        }
    }
    let l = m.cholesky().expect("mass is positive definite").l();
    let a = l.solve_lower_triangular(&k).unwrap();
    let c = l.solve_lower_triangular(&a.transpose()).unwrap();
    let eig = SymmetricEigen::new((&c + c.transpose()) * 0.5);
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
    let values: Vec<f64> = order.iter().map(|&i| eig.eigenvalues[i]).collect();
    let y: DVector<f64> = eig.eigenvectors.column(order[index]).into_owned();
    let phi = l.transpose().solve_upper_triangular(&y).unwrap();
    let lambda = values[index];
    (q, phi.iter().copied().collect(), lambda, values)
}

#[test]
fn eigenvalue_gradient_flows_to_the_sdf_parameter() {
    // The whole chain: an implicit ellipsoid s = r − |D⁻¹(x − c)| with parameter r → grid
    // values → marched P1 mesh → lifted P2 mesh → first elastic eigenvalue λ₇ of the free
    // body (dense solve); dλ/dx from the FEM sensitivity kernel, back to the P1 nodes, the
    // grid values and r, against a central difference in r.
    let grid = BackgroundGrid::covering([-0.5, -0.4, -0.3], [0.5, 0.4, 0.3], 5, 1.0).unwrap();
    let points = grid.vertex_positions();
    let centre = [0.021, -0.013, 0.008];
    let axes = [0.5, 0.4, 0.3];
    let values_at = |r: f64| -> Vec<f64> {
        points
            .iter()
            .map(|x| r - norm3([0, 1, 2].map(|k| (x[k] - centre[k]) / axes[k])))
            .collect()
    };
    let r = 1.07;
    let options = MarchingOptions::default();
    let marched = march(&grid, &values_at(r), None, &options).unwrap();
    check_valid(&marched);
    let first_elastic = 6;
    let start = Instant::now();
    let (q, phi, lambda, spectrum) = p2_mode(&marched.mesh, first_elastic);
    let solve = start.elapsed().as_secs_f64();
    assert!(
        spectrum[..6].iter().all(|v| v.abs() < 1e-8 * lambda),
        "rigid modes {:?}",
        &spectrum[..7]
    );
    let gap = (spectrum[7] - lambda).min(lambda - spectrum[5]) / lambda;
    eprintln!(
        "eigenvalue chain: {} P1 tets, {} P2 nodes, λ₇ = {lambda:.6} (relative gap {gap:.3}), dense solve {solve:.2} s",
        marched.mesh.n_tets(),
        q.n_nodes()
    );
    assert!(gap > 1e-3);
    // dλ/dx on the P2 nodes.
    let sens = SensitivityKernel::new(10, false);
    let coef = ElasticCoefficients {
        lambda: 1.0,
        mu: 1.0,
        rho: 1.0,
    };
    let mut d_p2 = vec![0.0; 3 * q.n_nodes()];
    let mut grad = vec![[0.0; 3]; 10];
    for e in 0..q.n_tets() {
        let t = q.tet(e);
        let phi_e: Vec<f64> = t
            .iter()
            .flat_map(|&n| [phi[3 * n], phi[3 * n + 1], phi[3 * n + 2]])
            .collect();
        sens.gradient_into(&q.tet_coords(e), &phi_e, lambda, coef, &mut grad)
            .unwrap();
        for (a, &n) in t.iter().enumerate() {
            for d in 0..3 {
                d_p2[3 * n + d] += grad[a][d];
            }
        }
    }
    let d_p1 = linear_node_gradient(&marched.mesh, &q, &d_p2).unwrap();
    let d_s = marched.vjp(&d_p1).unwrap().values;
    // ∂s_v/∂r = 1.
    let d_r: f64 = d_s.iter().sum();
    let eps = 1e-6;
    let lambda_at = |r: f64| {
        let m = march(&grid, &values_at(r), None, &options).unwrap();
        assert!(same_topology(&marched, &m), "topology changed at r = {r}");
        p2_mode(&m.mesh, first_elastic).2
    };
    let fd = (lambda_at(r + eps) - lambda_at(r - eps)) / (2.0 * eps);
    eprintln!("dλ₇/dr = {d_r:.8e}, central difference {fd:.8e}");
    assert!((fd - d_r).abs() < 1e-5 * d_r.abs(), "{fd} vs {d_r}");
    // The mid-edge nodes matter: the P2 mesh has them as their own nodes.
    assert!(q.n_nodes() > marched.mesh.n_nodes() && TET10_EDGES.len() == 6);
}

// ---------------------------------------------------------------- shared shapes

fn mesh_surface(
    name: &str,
    surface: &TriangleSurface,
    resolution: usize,
) -> (MarchedMesh, f64, f64) {
    let start = Instant::now();
    let sdf = SignedDistance::new(surface).unwrap();
    let (lo, hi) = surface.bounding_box();
    let grid = BackgroundGrid::covering(lo, hi, resolution, 1.5).unwrap();
    let values = sdf.evaluate(&grid.vertex_positions());
    let sdf_seconds = start.elapsed().as_secs_f64();
    let start = Instant::now();
    let m = march(&grid, &values, None, &MarchingOptions::default())
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    let march_seconds = start.elapsed().as_secs_f64();
    (m, sdf_seconds, march_seconds)
}

#[test]
fn shared_shapes_mesh_into_valid_p2_meshes() {
    for name in ["bob_surf", "spot_surf", "oloid_surf"] {
        let Some(path) = shared_file(&format!("data/meshes/{name}.obj")) else {
            return;
        };
        let read = read_obj(&path).unwrap();
        let surface = read.surface;
        let (m, sdf_seconds, march_seconds) = mesh_surface(name, &surface, 24);
        let start = Instant::now();
        let p2_volume = check_p2_kernel(&m.mesh);
        let kernel_seconds = start.elapsed().as_secs_f64();
        let pieces = m.mesh.connected_components();
        assert_eq!(pieces, 1);
        let (lo, hi) = m.mesh.bounding_box();
        let rule = ZERO_VOLUME_RELATIVE_TOLERANCE * norm3(sub3(hi, lo)).powi(3);
        assert!(m.report.min_tet_volume > rule);
        let enclosed = surface.signed_volume().abs();
        let relative = (m.mesh.volume() - enclosed) / enclosed;
        eprintln!(
            "{name} at 24 cells: {} triangles -> {} tets, {} nodes, volume {:.4} vs enclosed {:.4} ({relative:+.3}); \
             SDF {sdf_seconds:.2} s, march {march_seconds:.3} s, P2 kernel {kernel_seconds:.2} s; {}",
            surface.n_triangles(),
            m.mesh.n_tets(),
            m.mesh.n_nodes(),
            p2_volume,
            enclosed,
            m.report
        );
        assert!(relative.abs() < 0.05, "{name}: volume off by {relative}");
    }
    // The boundary of a .msh file works the same way: spot.msh's own boundary, marched at
    // 24 cells, has about the tet mesh's volume.
    let Some(path) = shared_file("data/meshes/spot.msh") else {
        return;
    };
    let tets = read_mesh(&path, &ReadOptions::default()).unwrap().mesh;
    let surface = TriangleSurface::from_mesh_boundary(&tets);
    let (m, _, _) = mesh_surface("spot.msh", &surface, 24);
    let relative = (m.mesh.volume() - tets.volume()) / tets.volume();
    eprintln!(
        "spot.msh boundary at 24 cells: {} tets, volume {relative:+.3} relative to the tet mesh",
        m.mesh.n_tets()
    );
    assert!(relative.abs() < 0.05);
}

/// Timings for the report: `cargo test --release --lib shape::marching::tests::timings --
/// --ignored --nocapture`.
#[test]
#[ignore]
fn timings() {
    for name in ["spot_surf", "bob_surf", "oloid_surf"] {
        let Some(path) = shared_file(&format!("data/meshes/{name}.obj")) else {
            return;
        };
        let surface = read_obj(&path).unwrap().surface;
        for n in [16, 32, 64] {
            let (m, sdf_seconds, march_seconds) = mesh_surface(name, &surface, n);
            let start = Instant::now();
            check_p2_kernel(&m.mesh);
            let kernel_seconds = start.elapsed().as_secs_f64();
            let g = m.n_grid_vertices();
            eprintln!(
                "{name} n = {n}: {g} grid values, SDF {sdf_seconds:.3} s ({:.2} µs/point), march {march_seconds:.3} s, \
                 {} tets / {} nodes, lift + P2 kernel on every element {kernel_seconds:.2} s; {}",
                1e6 * sdf_seconds / g as f64,
                m.mesh.n_tets(),
                m.mesh.n_nodes(),
                m.report
            );
        }
    }
}

// ---------------------------------------------------------------- errors

#[test]
fn bad_inputs_are_errors() {
    assert!(matches!(
        BackgroundGrid::new([0.0; 3], [0.1, 0.0, 0.1], [1, 1, 1]),
        Err(MarchingError::BadGrid { .. })
    ));
    assert!(matches!(
        BackgroundGrid::new([0.0; 3], [0.1; 3], [1, 0, 1]),
        Err(MarchingError::BadGrid { .. })
    ));
    assert!(matches!(
        BackgroundGrid::new([f64::NAN, 0.0, 0.0], [0.1; 3], [1, 1, 1]),
        Err(MarchingError::BadGrid { .. })
    ));
    assert!(matches!(
        BackgroundGrid::new([0.0; 3], [0.1; 3], [usize::MAX / 2, 2, 2]),
        Err(MarchingError::BadGrid { .. })
    ));
    assert!(matches!(
        BackgroundGrid::covering([0.0; 3], [1.0; 3], 2, 1.0),
        Err(MarchingError::BadGrid { .. })
    ));
    assert!(matches!(
        BackgroundGrid::covering([0.0; 3], [0.0; 3], 8, 1.0),
        Err(MarchingError::BadGrid { .. })
    ));
    let grid = BackgroundGrid::covering([0.0; 3], [1.0, 0.5, 0.25], 10, 1.0).unwrap();
    assert_eq!(grid.cells(), [10, 6, 4]);
    assert!((grid.spacing()[0] - 0.125).abs() < 1e-15);
    let o = MarchingOptions::default();
    let n = grid.n_vertices();
    let e = march(&grid, &vec![1.0; n - 1], None, &o).unwrap_err();
    assert_eq!(
        e,
        MarchingError::LengthMismatch {
            what: "values",
            expected: n,
            found: n - 1
        }
    );
    let mut values = vec![1.0; n];
    values[3] = f64::NAN;
    assert!(matches!(
        march(&grid, &values, None, &o),
        Err(MarchingError::NonFinite {
            what: "values",
            index: 3,
            ..
        })
    ));
    assert_eq!(
        march(&grid, &vec![-1.0; n], None, &o).unwrap_err(),
        MarchingError::NothingInside
    );
    assert!(matches!(
        march(&grid, &vec![1.0; n], Some(&[0.0]), &o),
        Err(MarchingError::LengthMismatch {
            what: "offsets",
            ..
        })
    ));
    for bad in [
        MarchingOptions {
            snap_fraction: 0.5,
            ..Default::default()
        },
        MarchingOptions {
            min_volume_fraction: -1.0,
            ..Default::default()
        },
        MarchingOptions {
            max_offset_fraction: 0.6,
            ..Default::default()
        },
    ] {
        assert!(matches!(
            march(&grid, &vec![1.0; n], None, &bad),
            Err(MarchingError::BadOption { .. })
        ));
    }
    // All inside: the whole box, every background tet kept.
    let m = march(&grid, &vec![1.0; n], None, &o).unwrap();
    assert_eq!(m.mesh.n_tets(), grid.n_tets());
    assert!((m.mesh.volume() - 1.25 * 0.75 * 0.5).abs() < 1e-12);
    assert_eq!(check_valid(&m), 2);
}

#[test]
fn shell_of_given_depth_uses_that_depth_and_has_no_argmax_term() {
    let grid = BackgroundGrid::covering([-0.5; 3], [0.5; 3], 12, 1.0).unwrap();
    let sphere: Vec<f64> = grid
        .vertex_positions()
        .iter()
        .map(|x| 0.47 - norm3(sub3(*x, [0.031, -0.017, 0.011])))
        .collect();
    // The continuous maximum (0.47) exceeds every sample: t means t·0.47, not t·max(samples).
    let depth = 0.47;
    let thickness = 0.5;
    let given = shell_of_depth(&sphere, thickness, depth).unwrap();
    let sampled = shell(&sphere, thickness).unwrap();
    assert!(sampled.max_value < depth);
    assert_eq!(given.max_value, depth);
    for (g, s) in given.values.iter().zip(&sphere) {
        assert_eq!(*g, s.min(thickness * depth - s));
    }
    // dL/dt through the marched mesh against central differences; dL/ds has no argmax term.
    let options = MarchingOptions::default();
    let base = march(&grid, &given.values, None, &options).unwrap();
    let (_, d_x) = &losses(&base.mesh)[1];
    let d_g = base.vjp(d_x).unwrap().values;
    let d = given.vjp(&d_g).unwrap();
    let f_t = |t: &[f64]| {
        let m = march(
            &grid,
            &shell_of_depth(&sphere, t[0], depth).unwrap().values,
            None,
            &options,
        )
        .unwrap();
        let l = losses(&m.mesh)[1].0;
        (m, l)
    };
    let fd = central_difference(&[thickness], 0, 1e-7, &base, &f_t).expect("stable topology");
    assert!(
        (fd - d.thickness).abs() < 1e-6 * d.thickness.abs(),
        "{fd} vs {}",
        d.thickness
    );
    let with_argmax = sampled.vjp(&d_g).unwrap();
    let expected: Vec<f64> = d_g
        .iter()
        .zip(&given.values)
        .zip(&sphere)
        .map(|((g, _), s)| if *s > thickness * depth - s { -g } else { *g })
        .collect();
    assert_eq!(d.values, expected);
    assert_ne!(
        with_argmax.values[sampled.argmax], d.values[sampled.argmax],
        "the sampled shell's maximum moves its wall"
    );
    for bad in [0.0, -1.0, f64::NAN] {
        assert!(matches!(
            shell_of_depth(&sphere, thickness, bad),
            Err(MarchingError::BadOption { .. })
        ));
    }
}

/// A thin spherical shell (wall 0.6 h) refined near its walls: the refined grid marches into
/// a valid mesh, its volume error falls below the unrefined grid's and that of the uniformly
/// finer grid with as many cells as the refinement's finest, the values' gradient still meets
/// central differences, and offsets are refused.
#[test]
fn a_locally_refined_grid_marches_a_thin_shell_closer_to_its_volume() {
    let centre = [0.011, -0.017, 0.005];
    let (r_out, n) = (0.5, 12usize);
    let lo = centre.map(|c| c - r_out);
    let hi = centre.map(|c| c + r_out);
    let grid = BackgroundGrid::covering(lo, hi, n, 1.0).unwrap();
    let h = grid.spacing()[0];
    let wall = 0.6 * h;
    let r_in = r_out - wall;
    let field = move |x: [f64; 3]| {
        let d = norm3(sub3(x, centre));
        (r_out - d).min(d - r_in)
    };
    let exact = 4.0 / 3.0 * std::f64::consts::PI * (r_out.powi(3) - r_in.powi(3));
    let values: Vec<f64> = grid.vertex_positions().iter().map(|&x| field(x)).collect();
    let options = MarchingOptions::default();
    let error_of = |g: &BackgroundGrid, v: &[f64]| {
        let m = march(g, v, None, &options).unwrap();
        check_valid(&m);
        ((m.mesh.volume() - exact).abs() / exact, m)
    };
    let (coarse_error, _) = error_of(&grid, &values);
    // Tets whose value range, widened by their longest edge, reaches the wall's middle.
    let band = |v: &crate::shape::refine::TetView| {
        let (a, b) = v
            .values
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            });
        a - v.longest_edge <= 0.0 && b + v.longest_edge >= 0.0
    };
    let (refined, refined_values) = grid.refined(2, &values, &field, &band).unwrap();
    assert!(refined.is_refined() && !grid.is_refined());
    assert_eq!(refined_values.len(), refined.n_vertices());
    assert!((0..grid.n_vertices())
        .all(|v| refined.vertex_position(v) == grid.vertex_position(v)
            && refined_values[v] == values[v]));
    let (refined_error, marched) = error_of(&refined, &refined_values);
    let fine = BackgroundGrid::covering(lo, hi, 4 * n - 6, 1.0).unwrap();
    let fine_values: Vec<f64> = fine.vertex_positions().iter().map(|&x| field(x)).collect();
    let (fine_error, _) = error_of(&fine, &fine_values);
    eprintln!(
        "thin shell: volume error {coarse_error:.3e} on {} tets, {refined_error:.3e} refined on {} tets ({} cut), {fine_error:.3e} on a uniform {}-cell grid of {} tets",
        grid.n_tets(),
        refined.n_tets(),
        marched.report.cut_tets,
        4 * n - 6,
        fine.n_tets()
    );
    assert!(
        refined_error < 0.25 * coarse_error,
        "{refined_error} vs {coarse_error}"
    );
    // Closer than the uniform grid of about the refinement's finest spacing, with fewer tets.
    assert!(
        refined_error < fine_error && refined.n_tets() < fine.n_tets(),
        "{refined_error} on {} tets vs {fine_error} on {}",
        refined.n_tets(),
        fine.n_tets()
    );
    assert!(refined.smallest_rest_tet_volume() < grid.smallest_rest_tet_volume() / 60.0);

    // dV/ds through the refined grid's crossings against central differences.
    let (_, d_x) = &losses(&marched.mesh)[0];
    let grad = marched.vjp(d_x).unwrap();
    let volume_of = |s: &[f64]| {
        let m = march(&refined, s, None, &options).unwrap();
        let v = m.mesh.volume();
        (m, v)
    };
    let scale = grad.values.iter().fold(0.0f64, |a, b| a.max(b.abs()));
    let (mut checked, mut beyond_structured) = (0, 0);
    let moving: Vec<usize> = (0..refined.n_vertices())
        .filter(|&v| grad.values[v] != 0.0)
        .collect();
    for &v in moving.iter().step_by((moving.len() / 60).max(1)) {
        if let Some(fd) = central_difference(&refined_values, v, 1e-5 * h, &marched, &volume_of) {
            checked += 1;
            beyond_structured += usize::from(v >= grid.n_vertices());
            assert!(
                (fd - grad.values[v]).abs() <= 1e-5 * scale,
                "dV/ds[{v}]: fd {fd} vs {}",
                grad.values[v]
            );
        }
    }
    assert!(
        checked > 30 && beyond_structured > 10,
        "{checked} checked, {beyond_structured} at midpoints"
    );

    let theta = vec![0.0; 3 * refined.n_vertices()];
    assert!(matches!(
        march(&refined, &refined_values, Some(&theta), &options),
        Err(MarchingError::BadGrid { .. })
    ));
    assert!(matches!(
        refined.refined(1, &refined_values, &field, &band),
        Err(MarchingError::BadGrid { .. })
    ));
}
