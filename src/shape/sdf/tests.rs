//! Signed distance tests: exact distances against brute force and boxes, the fast winding
//! number against the exact sum, the shared sphere against its analytic bounds, and signs
//! that survive holes and flipped triangles.

use super::*;
use crate::mesh::box_mesh;
use crate::mesh::tests::shared_file;
use crate::shape::surface::read_obj;
use crate::testing::Rng;

/// The shared icosphere ([`crate::testing::icosphere`]) as a surface.
pub(crate) fn icosphere(r: f64, levels: usize) -> TriangleSurface {
    let (vertices, triangles) = crate::testing::icosphere(r, levels);
    TriangleSurface::new(vertices, triangles).unwrap()
}

fn brute_force_distance(surface: &TriangleSurface, q: [f64; 3]) -> f64 {
    (0..surface.n_triangles())
        .map(|t| triangle_nearest(&surface.triangle_coords(t), q).0)
        .fold(f64::INFINITY, f64::min)
        .sqrt()
}

fn random_point(rng: &mut Rng, half_width: f64) -> [f64; 3] {
    [0, 1, 2].map(|_| rng.uniform(-half_width, half_width))
}

#[test]
fn distance_matches_brute_force_and_the_bounded_search() {
    let surface = icosphere(0.7, 3);
    let sdf = SignedDistance::new(&surface).unwrap();
    assert!(!sdf.flipped());
    let mut rng = Rng(7);
    let points: Vec<[f64; 3]> = (0..400).map(|_| random_point(&mut rng, 1.2)).collect();
    let evaluated = sdf.evaluate(&points);
    for (q, s) in points.iter().zip(&evaluated) {
        let exact = brute_force_distance(&surface, *q);
        let d = sdf.unsigned_distance(*q);
        assert!((d - exact).abs() <= 1e-14, "{q:?}: {d} vs {exact}");
        assert!(
            (s.abs() - exact).abs() <= 1e-14,
            "bounded search at {q:?}: {s} vs {exact}"
        );
        // The facets lie between radius 0.698 and 0.7.
        let r = norm(*q);
        if !(0.69..=0.7).contains(&r) {
            assert_eq!(*s > 0.0, r < 0.69, "sign at {q:?} (|q| = {r})");
        }
    }
}

#[test]
fn box_boundary_gives_the_exact_box_distance() {
    // Boundary of a tet mesh of [0,1]×[0,2]×[0,0.5]: the signed distance is known in closed
    // form inside (distance to the nearest face) and outside (distance to the box).
    let surface = TriangleSurface::from_mesh_boundary(&box_mesh([2, 3, 1], [1.0, 2.0, 0.5]));
    let sdf = SignedDistance::new(&surface).unwrap();
    let size = [1.0, 2.0, 0.5];
    let mut rng = Rng(11);
    for _ in 0..300 {
        let q = [
            rng.uniform(-0.5, 1.5),
            rng.uniform(-0.5, 2.5),
            rng.uniform(-0.5, 1.0),
        ];
        let inside = (0..3).all(|k| q[k] > 0.0 && q[k] < size[k]);
        let exact = if inside {
            (0..3)
                .map(|k| q[k].min(size[k] - q[k]))
                .fold(f64::INFINITY, f64::min)
        } else {
            -(0..3)
                .map(|k| (-q[k]).max(q[k] - size[k]).max(0.0).powi(2))
                .sum::<f64>()
                .sqrt()
        };
        let s = sdf.signed_distance(q);
        assert!((s - exact).abs() < 1e-13, "{q:?}: {s} vs {exact}");
    }
}

#[test]
fn fast_winding_number_matches_the_exact_sum() {
    let surface = icosphere(0.7, 3);
    let mut rng = Rng(3);
    let points: Vec<[f64; 3]> = (0..300).map(|_| random_point(&mut rng, 1.5)).collect();
    let sdf = SignedDistance::new(&surface).unwrap();
    for &q in &points {
        let exact = sdf.winding_number_exact(q);
        let expected = if norm(q) < 0.69 {
            1.0
        } else if norm(q) > 0.71 {
            0.0
        } else {
            exact
        };
        assert!(
            (exact - expected).abs() < 1e-9,
            "exact winding {exact} at {q:?}"
        );
    }
    // The error is that of the far-field expansion: largest where many nodes are seen from
    // just beyond β r (near the centre of the sphere), smaller for larger β.
    let mut worst = Vec::new();
    for beta in [FAR_FIELD_RATIO, 4.0, 8.0] {
        let sdf = SignedDistance::new(&surface)
            .unwrap()
            .with_far_field_ratio(beta);
        let error = points
            .iter()
            .map(|&q| (sdf.winding_number(q) - sdf.winding_number_exact(q)).abs())
            .fold(0.0, f64::max);
        worst.push(error);
    }
    eprintln!("fast winding number: largest error over 300 points {worst:?} for β = 2, 4, 8");
    assert!(
        worst[0] < 0.1 && worst[1] < 0.02 && worst[2] < 2e-3,
        "{worst:?}"
    );
}

#[test]
fn sphere_obj_within_its_faceting_bounds() {
    let Some(path) = shared_file("data/meshes/sphere.obj") else {
        return;
    };
    let surface = read_obj(&path).unwrap().surface;
    let sdf = SignedDistance::new(&surface).unwrap();
    // The file is a subdivided cube pushed towards a sphere: its surface lies between the
    // ball of radius r_in (distance from the centre) and r_out (largest vertex radius).
    // For the true signed distance s of a star-shaped surface around 0 that gives
    // r_in − |x| ≤ s(x) ≤ r_out − |x| everywhere.
    let r_in = sdf.unsigned_distance([0.0; 3]);
    let r_out = surface
        .vertices
        .iter()
        .map(|&v| norm(v))
        .fold(0.0, f64::max);
    eprintln!(
        "sphere.obj: {} triangles, radius between {r_in:.6} and {r_out:.6}",
        surface.n_triangles()
    );
    assert!(r_in > 0.88 && r_out < 0.92, "{r_in} {r_out}");
    let mut rng = Rng(5);
    let points: Vec<[f64; 3]> = (0..2000).map(|_| random_point(&mut rng, 1.3)).collect();
    let values = sdf.evaluate(&points);
    for (q, s) in points.iter().zip(values) {
        let r = norm(*q);
        assert!(
            s >= r_in - r - 1e-12 && s <= r_out - r + 1e-12,
            "{q:?} (|q| = {r}): s = {s}"
        );
        if r < r_in {
            assert!(s > 0.0);
        } else if r > r_out {
            assert!(s < 0.0);
        }
    }
}

#[test]
fn holes_and_flipped_triangles_keep_the_sign() {
    let surface = match shared_file("data/meshes/sphere.obj") {
        Some(path) => read_obj(&path).unwrap().surface,
        None => icosphere(0.9, 4),
    };
    let r_out = surface
        .vertices
        .iter()
        .map(|&v| norm(v))
        .fold(0.0, f64::max);
    let clean = SignedDistance::new(&surface).unwrap();
    let r_in = clean.unsigned_distance([0.0; 3]);
    // A hole: every triangle whose centroid lies within 0.3 of the +x pole (a few dozen).
    let pole = [r_out, 0.0, 0.0];
    let mut holed = surface.clone();
    holed.triangles.retain(|t| {
        let c = [0, 1, 2].map(|k| t.iter().map(|&v| surface.vertices[v][k]).sum::<f64>() / 3.0);
        norm(sub(c, pole)) > 0.3
    });
    let removed = surface.n_triangles() - holed.n_triangles();
    // And 5 % of the others flipped.
    let mut rng = Rng(17);
    let mut flipped = 0;
    for t in &mut holed.triangles {
        if rng.next() < 0.05 {
            t.swap(1, 2);
            flipped += 1;
        }
    }
    eprintln!("hole of {removed} triangles, {flipped} flipped");
    assert!(removed >= 10 && flipped > 50);
    let sdf = SignedDistance::new(&holed).unwrap();
    for _ in 0..1000 {
        let q = random_point(&mut rng, 2.0);
        let r = norm(q);
        if r < 0.75 * r_in {
            assert!(
                sdf.signed_distance(q) > 0.0,
                "inside point {q:?}: w = {}",
                sdf.winding_number_exact(q)
            );
        } else if r > 1.2 * r_out {
            assert!(
                sdf.signed_distance(q) < 0.0,
                "outside point {q:?}: w = {}",
                sdf.winding_number_exact(q)
            );
        }
    }
    // Inside, right behind the hole: the winding number drops but stays above ½.
    let behind = [0.5 * r_in, 0.0, 0.0];
    assert!(sdf.winding_number(behind) > 0.5 && sdf.signed_distance(behind) > 0.0);
    // A surface turned inside out as a whole is turned back.
    let mut inverted = surface.clone();
    inverted.flip();
    let sdf = SignedDistance::new(&inverted).unwrap();
    assert!(sdf.flipped());
    assert!(
        sdf.signed_distance([0.1, 0.2, 0.0]) > 0.0 && sdf.signed_distance([1.5, 0.0, 0.0]) < 0.0
    );
}

#[test]
fn degenerate_triangles_and_bad_surfaces() {
    let mut surface = icosphere(1.0, 1);
    // A collinear triangle sticking out of the sphere along +z.
    let n = surface.vertices.len();
    surface
        .vertices
        .extend([[0.0, 0.0, 1.0], [0.0, 0.0, 1.5], [0.0, 0.0, 2.0]]);
    surface.triangles.push([n, n + 1, n + 2]);
    let sdf = SignedDistance::new(&surface).unwrap();
    let d = sdf.unsigned_distance([0.3, 0.0, 1.8]);
    assert!((d - 0.3).abs() < 1e-14, "{d}");
    let flat = TriangleSurface::new(
        vec![[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]],
        vec![[0, 1, 2]],
    )
    .unwrap();
    assert!(matches!(
        SignedDistance::new(&flat),
        Err(SurfaceError::NoArea { n_triangles: 1 })
    ));
    let broken = TriangleSurface {
        vertices: vec![[0.0; 3]],
        triangles: vec![[0, 0, 3]],
    };
    assert!(matches!(
        SignedDistance::new(&broken),
        Err(SurfaceError::BadTriangle { vertex: 3, .. })
    ));
}

#[test]
fn far_field_expansion_is_third_order() {
    // A curved open patch: a quarter of a sphere. Its far-field expansion about the
    // area-weighted centroid must have an error falling like (r/ρ)³ (second order kept).
    let full = icosphere(1.0, 2);
    let tris: Vec<[[f64; 3]; 3]> = (0..full.n_triangles())
        .map(|t| full.triangle_coords(t))
        .filter(|t| t.iter().all(|v| v[0] > -0.1 && v[1] > -0.1))
        .collect();
    let (lo, hi) =
        crate::mesh::bounding_box_of(&tris.iter().flatten().copied().collect::<Vec<_>>());
    let (center, area_normal, moment, radius) = expansion(&tris, lo, hi);
    let dir = [0.3, -0.5, 0.81];
    let dir = dir.map(|c| c / norm(dir));
    let mut errors = Vec::new();
    for ratio in [4.0, 8.0, 16.0] {
        let q = [0, 1, 2].map(|k| center[k] + ratio * radius * dir[k]);
        let exact: f64 = tris.iter().map(|t| solid_angle(t, q)).sum();
        let y = sub(center, q);
        let rho2 = dot(y, y);
        let rho3 = rho2 * rho2.sqrt();
        let my = [dot(moment[0], y), dot(moment[1], y), dot(moment[2], y)];
        let first = dot(y, area_normal) / rho3;
        let second =
            (moment[0][0] + moment[1][1] + moment[2][2]) / rho3 - 3.0 * dot(y, my) / (rho3 * rho2);
        errors.push(((exact - first).abs(), (exact - first - second).abs()));
    }
    eprintln!("far field errors (first order, second order) at ρ/r = 4, 8, 16: {errors:?}");
    for w in errors.windows(2) {
        assert!(
            w[0].0 / w[1].0 > 6.0,
            "first order: error falls like (r/ρ)³: {errors:?}"
        );
        assert!(
            w[0].1 / w[1].1 > 12.0,
            "second order: error falls like (r/ρ)⁴: {errors:?}"
        );
    }
}

#[test]
fn deepest_point_of_a_ball_and_a_box() {
    // A ball of radius 0.7 faceted by 1280 triangles: the deepest point is its centre, at
    // the distance of the nearest face plane, which lies between r cos(θ) (θ the largest
    // angle from a face centre to its corners) and r.
    let ball = icosphere(0.7, 3);
    let sdf = SignedDistance::new(&ball).unwrap();
    let centre_depth = sdf.unsigned_distance([0.0; 3]);
    let (p, s) = sdf.deepest_point(&[[0.31, -0.2, 0.15]], 0.1, 1e-9);
    assert!(norm(p) < 1e-3, "deepest point {p:?}");
    assert!(
        (s - centre_depth).abs() < 1e-6 && s > 0.69 * 0.98,
        "S = {s}, centre {centre_depth}"
    );
    // A box 0.06 × 0.04 × 0.02: s = distance to the nearest face, largest (0.01) on the
    // rectangle z = 0, |x| ≤ 0.02, |y| ≤ 0.01; from a start off that ridge.
    let mesh = box_mesh([3, 2, 1], [0.06, 0.04, 0.02]);
    let surface = TriangleSurface::from_mesh_boundary(&mesh);
    let sdf = SignedDistance::new(&surface).unwrap();
    let (p, s) = sdf.deepest_point(&[[0.004, 0.035, 0.003]], 0.005, 1e-10);
    assert!((s - 0.01).abs() < 1e-8, "box: S = {s} at {p:?}");
    // Several starts: the best result wins; a start outside climbs in.
    let (_, s2) = sdf.deepest_point(&[[0.1, 0.1, 0.1], [0.03, 0.02, 0.01]], 0.01, 1e-10);
    assert!((s2 - 0.01).abs() < 1e-8, "{s2}");
}

/// The exact gradient is a unit vector that matches central differences of s wherever the
/// difference's stencil stays on one side of the distance's creases (checked by the two
/// one-sided differences agreeing), inside and outside; on the surface it is not defined.
#[test]
fn gradient_is_unit_and_matches_differences_off_the_creases() {
    let surface = icosphere(0.04, 2);
    let sdf = SignedDistance::new(&surface).unwrap();
    let mut rng = Rng(11);
    let step = 1e-7;
    let (mut checked, mut inside) = (0, 0);
    for _ in 0..400 {
        let q = random_point(&mut rng, 0.06);
        let (s, gradient) = sdf.value_and_gradient(q);
        assert_eq!(s, sdf.signed_distance(q));
        let g = gradient.expect("defined off the surface");
        assert!((norm(g) - 1.0).abs() < 1e-12, "|∇s| = {}", norm(g));
        let at = |d: usize, h: f64| {
            let mut p = q;
            p[d] += h;
            sdf.signed_distance(p)
        };
        let forward = [0, 1, 2].map(|d| (at(d, step) - s) / step);
        let backward = [0, 1, 2].map(|d| (s - at(d, -step)) / step);
        if (0..3).any(|d| (forward[d] - backward[d]).abs() > 1e-5) {
            continue; // a crease within the stencil
        }
        for d in 0..3 {
            assert!(
                (g[d] - 0.5 * (forward[d] + backward[d])).abs() < 1e-6,
                "q {q:?}: exact {g:?}, differences {forward:?}"
            );
        }
        checked += 1;
        inside += usize::from(s > 0.0);
    }
    assert!(
        checked > 300 && inside > 20,
        "checked {checked}, inside {inside}"
    );
    let on_surface = surface.vertices[0];
    assert_eq!(sdf.gradient(on_surface), None);
}
