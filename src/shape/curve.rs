//! Curved boundaries for P2 meshes of implicit bodies: every mid-edge node of a boundary edge
//! is moved from the straight edge's midpoint onto the zero of the continuous field f that the
//! body was marched from (f > 0 inside).
//!
//! # Why
//!
//! A marched body with straight P2 edges is a polyhedron whose corners lie on the surface
//! (with exact crossings) or near it: its volume and stiffness carry an O(h²) geometric error
//! from the chords, which on the shape tasks dominates the finite-element error of P2 itself
//! (the shape module's docs, "Grid bias"). With the mid-edge nodes of the boundary on f = 0
//! the isoparametric P2 surface interpolates the true surface at six points per face, and the
//! geometric error falls to O(h³).
//!
//! # The move
//!
//! From the midpoint p₀ the node moves along the unit direction n = D f/|D f| at p₀ (D: central
//! differences with a step of 1e-3 of the edge length, which vary continuously with p₀ even
//! across a crease of f): x = p₀ + u n with f(x) = 0, found by
//! safeguarded secant iteration on u, |u| at most `max_fraction` of the edge length. A node
//! whose root is not found there keeps its midpoint.
//!
//! # Validity
//!
//! A curved tet must keep det J > 0 everywhere: det J is a cubic in the reference coordinates,
//! checked on the 35 points of the order-4 barycentric lattice of every tet touching a moved
//! node against `min_jacobian_ratio` × the straight tet's det J. Every moved node of a tet that
//! fails goes back to its midpoint, and the check repeats until no tet fails.
//!
//! # Derivative with respect to a parameter of f
//!
//! If f depends on a parameter p, a node on f(x; p) = 0 that moves along the fixed direction n
//! has dx/dp = −(∂f/∂p) / (∇f·n) · n; [`CurvedNode::slope`] is ∇f·n at the root [1/m ×
//! units of f], so the caller only needs ∂f/∂p there; ∇f at the root is the field's exact
//! gradient where the caller has one ([`FieldGradient`]), else central differences. The
//! direction n = D f(p₀)/|D f(p₀)| (D the central difference of step δ) turns when f changes
//! shape near p₀ or p₀ moves where f is not linear: with x = p₀ + u n,
//! a node gradient G contributes u·T·dn, T = G − (G·n/∇f·n) ∇f, and dn = (I − n nᵀ) dD/|D|,
//! so the node also carries weights ±b_d/(2δ), b = u (I − n nᵀ) T/|D|, at p₀ ± δ e_d
//! ([`CurvedNode::origin`], `offset`, `origin_gradient_norm`, `difference_step`). A change
//! of f that only moves the surface along itself (a thickness's inner wall: ∂f/∂p is the
//! same at all six points) gives that term no weight.

use crate::fem::element::{affine_jacobian, det3, jacobian};
use crate::fem::p2_grad_ref;
use crate::mesh::{ElementOrder, TetMesh, TET10_EDGES};
use std::collections::HashMap;

/// The gradient of f where it is known in closed form (None where it is not defined there,
/// e.g. on a signed distance's surface): used instead of central differences, which blend
/// the two sides of a crease of f (a signed distance's, [`super::SignedDistance::gradient`]).
pub type FieldGradient<'a> = &'a dyn Fn([f64; 3]) -> Option<[f64; 3]>;

/// One mid-edge node moved onto f = 0.
#[derive(Clone, Copy, Debug)]
pub struct CurvedNode {
    /// Node index in the P2 mesh.
    pub node: usize,
    /// Its position on f = 0 [m].
    pub position: [f64; 3],
    /// The unit direction it moved along.
    pub direction: [f64; 3],
    /// ∇f·direction at the root [units of f per m].
    pub slope: f64,
    /// ∇f at the root [units of f per m] (central differences).
    pub gradient: [f64; 3],
    /// The midpoint p₀ it moved from [m], and how far: position = p₀ + offset · direction.
    pub origin: [f64; 3],
    pub offset: f64,
    /// |D f(p₀)| [units of f per m], the central-difference gradient at p₀ whose direction is
    /// `direction`, and that difference's step [m] (the direction turns with f: the module docs).
    pub origin_gradient_norm: f64,
    pub difference_step: f64,
}

/// What [`curve_boundary`] did.
#[derive(Clone, Copy, Debug, Default)]
pub struct CurvingReport {
    /// Mid-edge nodes of boundary edges.
    pub boundary_edges: usize,
    /// Moved onto f = 0 and kept.
    pub moved: usize,
    /// No root within the allowed distance: left at the midpoint.
    pub no_root: usize,
    /// Moved back to the midpoint because a tet around them would have folded.
    pub reverted: usize,
}

/// Curves the boundary of a P2 mesh onto f = 0 (module docs). Returns the curved mesh, the
/// kept moves and a report. A linear mesh is returned unchanged.
pub fn curve_boundary(
    quadratic: &TetMesh,
    f: &dyn Fn([f64; 3]) -> f64,
    gradient: Option<FieldGradient>,
    max_fraction: f64,
    min_jacobian_ratio: f64,
) -> (TetMesh, Vec<CurvedNode>, CurvingReport) {
    let mut report = CurvingReport::default();
    if quadratic.order != ElementOrder::Quadratic {
        return (quadratic.clone(), Vec::new(), report);
    }
    // Mid-edge node of every corner pair, from the connectivity.
    let mut mid_of: HashMap<(usize, usize), usize> = HashMap::with_capacity(2 * quadratic.n_tets());
    for e in 0..quadratic.n_tets() {
        let t = quadratic.tet(e);
        for (k, &(a, b)) in TET10_EDGES.iter().enumerate() {
            let key = if t[a] < t[b] {
                (t[a], t[b])
            } else {
                (t[b], t[a])
            };
            mid_of.insert(key, t[4 + k]);
        }
    }
    let mut boundary: Vec<(usize, usize, usize)> = Vec::new();
    for face in quadratic.boundary_faces() {
        for (a, b) in [(face[0], face[1]), (face[1], face[2]), (face[2], face[0])] {
            let key = if a < b { (a, b) } else { (b, a) };
            boundary.push((mid_of[&key], key.0, key.1));
        }
    }
    boundary.sort_unstable();
    boundary.dedup();
    report.boundary_edges = boundary.len();

    let mut out = quadratic.clone();
    let mut moved: Vec<CurvedNode> = Vec::with_capacity(boundary.len());
    for &(node, a, b) in &boundary {
        let (pa, pb) = (quadratic.nodes[a], quadratic.nodes[b]);
        let length = (0..3).map(|d| (pb[d] - pa[d]).powi(2)).sum::<f64>().sqrt();
        let p0 = quadratic.nodes[node];
        if let Some(c) = project(p0, length, f, gradient, max_fraction) {
            out.nodes[node] = c.position;
            moved.push(CurvedNode { node, ..c });
        } else {
            report.no_root += 1;
        }
    }

    // Tets around moved nodes, checked until none folds.
    let mut is_moved = vec![false; out.nodes.len()];
    for c in &moved {
        is_moved[c.node] = true;
    }
    let lattice = lattice_gradients();
    for _ in 0..20 {
        let mut revert = Vec::new();
        for e in 0..out.n_tets() {
            let t = out.tet(e);
            if !t[4..].iter().any(|&n| is_moved[n]) {
                continue;
            }
            let coords: Vec<[f64; 3]> = t.iter().map(|&n| out.nodes[n]).collect();
            if !keeps_orientation(&coords, &lattice, min_jacobian_ratio) {
                revert.extend(t[4..].iter().copied().filter(|&n| is_moved[n]));
            }
        }
        if revert.is_empty() {
            break;
        }
        for n in revert {
            if is_moved[n] {
                is_moved[n] = false;
                out.nodes[n] = quadratic.nodes[n];
                report.reverted += 1;
            }
        }
    }
    moved.retain(|c| is_moved[c.node]);
    report.moved = moved.len();
    (out, moved, report)
}

/// The root of f along ∇f from p0 (module docs), or None.
fn project(
    p0: [f64; 3],
    length: f64,
    f: &dyn Fn([f64; 3]) -> f64,
    exact_gradient: Option<FieldGradient>,
    max_fraction: f64,
) -> Option<CurvedNode> {
    let step = 1e-3 * length;
    let at = |p: [f64; 3], d: usize, s: f64| {
        let mut q = p;
        q[d] += s;
        f(q)
    };
    let difference =
        |p: [f64; 3]| [0, 1, 2].map(|d| (at(p, d, step) - at(p, d, -step)) / (2.0 * step));
    // The direction is the central difference even where the exact gradient is known: it
    // varies continuously with p₀ across a crease of f, where the exact one jumps.
    let grad = difference(p0);
    let norm = grad.iter().map(|g| g * g).sum::<f64>().sqrt();
    if !(norm.is_finite() && norm > 0.0) {
        return None;
    }
    let n = grad.map(|g| g / norm);
    let along = |u: f64| f([0, 1, 2].map(|d| p0[d] + u * n[d]));
    let limit = max_fraction * length;
    // Secant from u = 0 with the gradient's estimate, kept inside [−limit, limit].
    let (mut u0, mut f0) = (0.0, along(0.0));
    if f0 == 0.0 {
        return None;
    }
    let mut u1 = (-f0 / norm).clamp(-limit, limit);
    let mut f1 = along(u1);
    for _ in 0..30 {
        if f1 == 0.0 || (u1 - u0).abs() <= 1e-10 * length {
            break;
        }
        let u2 = if f1 != f0 {
            u1 - f1 * (u1 - u0) / (f1 - f0)
        } else {
            break;
        };
        if !u2.is_finite() || u2.abs() > limit {
            return None;
        }
        (u0, f0) = (u1, f1);
        u1 = u2;
        f1 = along(u1);
    }
    if !(f1.abs() <= 1e-9 * length.max(f0.abs())) && (u1 - u0).abs() > 1e-8 * length {
        return None;
    }
    let position = [0, 1, 2].map(|d| p0[d] + u1 * n[d]);
    let gradient = exact_gradient
        .and_then(|g| g(position))
        .unwrap_or_else(|| difference(position));
    let slope = match exact_gradient {
        Some(_) => (0..3).map(|d| gradient[d] * n[d]).sum::<f64>(),
        None => (along(u1 + step) - along(u1 - step)) / (2.0 * step),
    };
    if !(slope.is_finite() && slope != 0.0) {
        return None;
    }
    Some(CurvedNode {
        node: usize::MAX,
        position,
        direction: n,
        slope,
        gradient,
        origin: p0,
        offset: u1,
        origin_gradient_norm: norm,
        difference_step: step,
    })
}

/// Reference gradients of the ten P2 shape functions on the order-4 barycentric lattice.
fn lattice_gradients() -> Vec<[[f64; 3]; 10]> {
    let mut out = Vec::with_capacity(35);
    for i in 0..=4 {
        for j in 0..=4 - i {
            for k in 0..=4 - i - j {
                out.push(p2_grad_ref([
                    i as f64 / 4.0,
                    j as f64 / 4.0,
                    k as f64 / 4.0,
                ]));
            }
        }
    }
    out
}

/// det J ≥ ratio × the straight tet's det J at every lattice point.
fn keeps_orientation(coords: &[[f64; 3]], lattice: &[[[f64; 3]; 10]], ratio: f64) -> bool {
    let straight = det3(&affine_jacobian(coords));
    let sign = straight.signum();
    lattice
        .iter()
        .all(|g| sign * det3(&jacobian(coords, g)) >= ratio * straight.abs())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::lift_to_quadratic;
    use crate::shape::{march, BackgroundGrid, MarchingOptions};

    fn ball(radius: f64) -> impl Fn([f64; 3]) -> f64 {
        move |p: [f64; 3]| radius - (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()
    }

    #[test]
    fn curved_ball_has_the_exact_volume_to_third_order_and_its_mid_nodes_on_the_sphere() {
        let radius = 0.05;
        let f = ball(radius);
        let mut errors = Vec::new();
        for n in [8, 12] {
            let grid = BackgroundGrid::covering([-radius; 3], [radius; 3], n, 1.0).unwrap();
            let values: Vec<f64> = grid.vertex_positions().iter().map(|&p| f(p)).collect();
            let marched = march(&grid, &values, None, &MarchingOptions::default()).unwrap();
            let (exact_linear, _, _) =
                crate::shape::spectrum::refine_crossings(&marched, &grid, &f, None, 0.01);
            let straight = lift_to_quadratic(&exact_linear);
            let (curved, moved, report) = curve_boundary(&straight, &f, None, 0.5, 0.05);
            assert!(report.moved > 0 && report.moved == moved.len());
            for c in &moved {
                assert!(
                    f(curved.nodes[c.node]).abs() < 1e-9,
                    "a moved node is off the sphere"
                );
            }
            let rule = crate::fem::tet_rule(8);
            let volume = |m: &TetMesh| {
                (0..m.n_tets())
                    .map(|e| crate::fem::element_volume(&m.tet_coords(e), &rule).unwrap())
                    .sum::<f64>()
            };
            let exact = 4.0 / 3.0 * std::f64::consts::PI * radius.powi(3);
            let (vs, vc) = (
                volume(&straight) / exact - 1.0,
                volume(&curved) / exact - 1.0,
            );
            assert!(
                vc.abs() < 0.25 * vs.abs(),
                "curving should cut the volume error: straight {vs:.3e}, curved {vc:.3e}"
            );
            errors.push(vc.abs());
        }
        // Halving-ish h (8 → 12 cells) cuts the curved error by more than (12/8)² = 2.25.
        assert!(
            errors[1] < errors[0] / 2.25,
            "curved volume errors {errors:?}"
        );
    }

    #[test]
    fn a_node_whose_move_would_fold_a_tet_goes_back_to_its_midpoint() {
        // One tet with a boundary face; a field whose zero is far beyond the allowed fold.
        let mesh = lift_to_quadratic(&TetMesh {
            nodes: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 1.0],
            ],
            connectivity: vec![0, 1, 2, 3],
            order: ElementOrder::Linear,
        });
        // f = 0.3 − z + x·(1 − x)·4·0.45: the x-edge's midpoint moves by +0.45 in z (nearly to
        // the top corner): the tet would fold.
        let f = |p: [f64; 3]| -p[2] + 1.8 * p[0] * (1.0 - p[0]) * (1.0 - p[1]);
        let (curved, moved, report) = curve_boundary(&mesh, &f, None, 0.6, 0.05);
        assert!(report.reverted > 0);
        for c in &moved {
            assert!(
                keeps_orientation(&curved.tet_coords(0), &lattice_gradients(), 0.05),
                "{c:?}"
            );
        }
        assert!(keeps_orientation(
            &curved.tet_coords(0),
            &lattice_gradients(),
            0.05
        ));
    }
}
