//! Points on the surface: where a strike lands, and how to read a nodal field there.
//!
//! A surface point is stored as the tet that owns the boundary face it lies on and its
//! barycentric coordinates (λ₀ … λ₃, Σλ = 1) with respect to that tet's corners. A nodal
//! field u (3 components per node, e.g. a mode shape) is read there with the element's own
//! shape functions: N_i = λ_i for 4-node tets; for 10-node tets (Gmsh order) the corner
//! functions λ_i(2λ_i − 1) and the edge functions 4λ_aλ_b. For curved 10-node tets the
//! coordinates come from the straight corner geometry, an approximation of the order of the
//! curvature offset of the face (sub-millimetre for the meshes we use).
//!
//! [`closest_surface_point`] projects an arbitrary position onto the nearest boundary face
//! (exact closest point on each straight triangle, by brute force over the faces: a one-off
//! cost of a few ms for 10⁵ faces).
//!
//! For an object resting on its lowest side along a direction `down`: the vertices a mallet
//! can reach ([`strike_candidates`]), the contact points with the support ([`support_nodes`]),
//! and the surface vertices nearest to a point ([`nearest_surface_vertices`],
//! [`nearest_points`]). The diagnosis uses them to drive and load its simulated modes, the
//! blind benchmark's generator to place its effects.

use super::TetMesh;
use crate::numerics::{cross, dot, sub};

/// A point on the boundary of a mesh.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfacePoint {
    /// The tet whose boundary face holds the point.
    pub tet: usize,
    /// Barycentric coordinates with respect to the tet's corners 0..4.
    pub barycentric: [f64; 4],
    /// The point [m].
    pub position: [f64; 3],
    /// Outward unit normal there (of the face; at a vertex, the area-weighted vertex normal).
    pub normal: [f64; 3],
    /// Distance from the requested position to the surface [m] (0 for a vertex).
    pub distance: f64,
}

fn unit(a: [f64; 3]) -> [f64; 3] {
    let n = dot(a, a).sqrt();
    if n > 0.0 {
        [a[0] / n, a[1] / n, a[2] / n]
    } else {
        [0.0; 3]
    }
}

/// Closest point of triangle (a, b, c) to p, as weights (wa, wb, wc) summing to 1. Region
/// tests on the triangle's Voronoi regions (vertices, edges, interior).
pub(crate) fn closest_on_triangle(p: [f64; 3], a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> [f64; 3] {
    let (ab, ac, ap) = (sub(b, a), sub(c, a), sub(p, a));
    let (d1, d2) = (dot(ab, ap), dot(ac, ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return [1.0, 0.0, 0.0];
    }
    let bp = sub(p, b);
    let (d3, d4) = (dot(ab, bp), dot(ac, bp));
    if d3 >= 0.0 && d4 <= d3 {
        return [0.0, 1.0, 0.0];
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return [1.0 - v, v, 0.0];
    }
    let cp = sub(p, c);
    let (d5, d6) = (dot(ab, cp), dot(ac, cp));
    if d6 >= 0.0 && d5 <= d6 {
        return [0.0, 0.0, 1.0];
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return [1.0 - w, 0.0, w];
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return [0.0, 1.0 - w, w];
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    [1.0 - v - w, v, w]
}

impl TetMesh {
    /// The tet owning each boundary face, with the face's corners (outward order) and the
    /// local corner indices they have in that tet.
    fn boundary_faces_with_owner(&self) -> Vec<(usize, [usize; 3])> {
        let faces = self.boundary_faces();
        let mut key_to_face: std::collections::HashMap<[usize; 3], usize> =
            std::collections::HashMap::with_capacity(faces.len());
        for (i, f) in faces.iter().enumerate() {
            let mut k = *f;
            k.sort_unstable();
            key_to_face.insert(k, i);
        }
        let mut owner = vec![usize::MAX; faces.len()];
        for e in 0..self.n_tets() {
            let t = self.tet(e);
            for skip in 0..4 {
                let mut k: Vec<usize> = (0..4).filter(|&i| i != skip).map(|i| t[i]).collect();
                k.sort_unstable();
                if let Some(&i) = key_to_face.get(&[k[0], k[1], k[2]]) {
                    owner[i] = e;
                }
            }
        }
        owner.into_iter().zip(faces).collect()
    }

    /// The surface point nearest to `position` [m]. `None` if the mesh has no boundary.
    pub fn closest_surface_point(&self, position: [f64; 3]) -> Option<SurfacePoint> {
        let mut best: Option<(f64, usize, [usize; 3], [f64; 3])> = None;
        let faces = self.boundary_faces_with_owner();
        for &(tet, face) in &faces {
            let [a, b, c] = face.map(|n| self.nodes[n]);
            let w = closest_on_triangle(position, a, b, c);
            let q = [0, 1, 2].map(|d| w[0] * a[d] + w[1] * b[d] + w[2] * c[d]);
            let d2 = dot(sub(q, position), sub(q, position));
            if best.is_none_or(|(bd, ..)| d2 < bd) {
                best = Some((d2, tet, face, w));
            }
        }
        let (d2, tet, face, w) = best?;
        let corners = &self.tet(tet)[..4];
        let mut barycentric = [0.0; 4];
        for (node, weight) in face.iter().zip(w) {
            if let Some(i) = corners.iter().position(|c| c == node) {
                barycentric[i] = weight;
            }
        }
        let [a, b, c] = face.map(|n| self.nodes[n]);
        let position_on = [0, 1, 2].map(|d| w[0] * a[d] + w[1] * b[d] + w[2] * c[d]);
        Some(SurfacePoint {
            tet,
            barycentric,
            position: position_on,
            normal: unit(cross(sub(b, a), sub(c, a))),
            distance: d2.sqrt(),
        })
    }

    /// The surface point at corner node `vertex`, with the vertex normal. `None` if the node
    /// is not on the surface.
    pub fn surface_point_at_vertex(&self, vertex: usize) -> Option<SurfacePoint> {
        let normals = self.vertex_normals();
        let &(_, normal) = normals.iter().find(|(v, _)| *v == vertex)?;
        let npt = self.nodes_per_tet();
        let (tet, local) = self
            .connectivity
            .chunks_exact(npt)
            .enumerate()
            .find_map(|(e, t)| t[..4].iter().position(|&n| n == vertex).map(|i| (e, i)))?;
        let mut barycentric = [0.0; 4];
        barycentric[local] = 1.0;
        Some(SurfacePoint {
            tet,
            barycentric,
            position: self.nodes[vertex],
            normal,
            distance: 0.0,
        })
    }

    /// The default strike vertex: the surface vertex farthest from the bounding-box centre (a
    /// rim or a corner, where most modes move); the lowest index among equals.
    pub fn default_strike_vertex(&self) -> Option<usize> {
        let (lo, hi) = self.bounding_box();
        let centre = [
            0.5 * (lo[0] + hi[0]),
            0.5 * (lo[1] + hi[1]),
            0.5 * (lo[2] + hi[2]),
        ];
        let dist2 = |n: usize| dot(sub(self.nodes[n], centre), sub(self.nodes[n], centre));
        let vertices = self.surface_vertices();
        let first = *vertices.first()?;
        Some(vertices.into_iter().fold(first, |best, cand| {
            if dist2(cand) > dist2(best) + 1e-30 {
                cand
            } else {
                best
            }
        }))
    }

    /// The surface point at [`Self::default_strike_vertex`].
    pub fn default_strike_point(&self) -> Option<SurfacePoint> {
        self.surface_point_at_vertex(self.default_strike_vertex()?)
    }

    /// Shape-function weights of the tet's nodes at barycentric coordinates `l` (module docs).
    pub fn shape_weights(&self, l: [f64; 4]) -> Vec<f64> {
        match self.nodes_per_tet() {
            4 => l.to_vec(),
            _ => {
                let mut n = vec![0.0; 10];
                for i in 0..4 {
                    n[i] = l[i] * (2.0 * l[i] - 1.0);
                }
                // Gmsh tet10 edge order: (0,1) (1,2) (0,2) (0,3) (2,3) (1,3).
                for (e, (i, j)) in [(0, 1), (1, 2), (0, 2), (0, 3), (2, 3), (1, 3)]
                    .into_iter()
                    .enumerate()
                {
                    n[4 + e] = 4.0 * l[i] * l[j];
                }
                n
            }
        }
    }

    /// The 3-vector of nodal field `field` (3 values per node) at `point`.
    pub fn interpolate_vector(&self, field: &[f64], point: &SurfacePoint) -> [f64; 3] {
        let weights = self.shape_weights(point.barycentric);
        let mut out = [0.0; 3];
        for (&node, w) in self.tet(point.tet).iter().zip(weights) {
            for d in 0..3 {
                out[d] += w * field[3 * node + d];
            }
        }
        out
    }
}

// ---------------------------------------------------------------------------------------------
// Strike, support and neighbourhoods on an object resting on its lowest side
// ---------------------------------------------------------------------------------------------

/// `a` scaled to unit length (`a` must be non-zero: these take a validated direction).
fn direction(a: [f64; 3]) -> [f64; 3] {
    let n = dot(a, a).sqrt();
    [a[0] / n, a[1] / n, a[2] / n]
}

/// Heights of the corner nodes above the lowest one along −`down` [m], and the body's extent.
fn heights(mesh: &TetMesh, down: [f64; 3]) -> (Vec<f64>, f64) {
    let up = direction(down).map(|c| -c);
    let h: Vec<f64> = mesh.nodes.iter().map(|x| dot(*x, up)).collect();
    let lo = h.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = h.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    (h.into_iter().map(|v| v - lo).collect(), hi - lo)
}

/// Surface vertices a mallet can reach on an object resting on its lowest side: outward
/// normal not pointing more than 60° downwards (n·down < 0.5) and higher than
/// `clearance`·(extent) above the lowest point. (vertex, outward unit normal).
pub fn strike_candidates(mesh: &TetMesh, down: [f64; 3], clearance: f64) -> Vec<(usize, [f64; 3])> {
    let (h, extent) = heights(mesh, down);
    let down = direction(down);
    mesh.vertex_normals()
        .into_iter()
        .filter(|&(v, n)| dot(n, down) < 0.5 && h[v] > clearance * extent)
        .collect()
}

/// The contact points of an object resting on a support below it: the surface vertices within
/// `band`·(extent) of the lowest point along `down`, at least `min_nodes` (the lowest ones).
pub fn support_nodes(mesh: &TetMesh, down: [f64; 3], band: f64, min_nodes: usize) -> Vec<usize> {
    let (h, extent) = heights(mesh, down);
    let mut surface = mesh.surface_vertices();
    surface.sort_by(|&a, &b| h[a].total_cmp(&h[b]).then(a.cmp(&b)));
    let within = surface
        .iter()
        .take_while(|&&v| h[v] <= band * extent)
        .count();
    surface.truncate(within.max(min_nodes).min(surface.len()));
    surface.sort_unstable();
    surface
}

/// The `n` surface vertices nearest to vertex `centre` (itself included), sorted.
pub fn nearest_surface_vertices(mesh: &TetMesh, centre: usize, n: usize) -> Vec<usize> {
    let surface = mesh.surface_vertices();
    let points: Vec<[f64; 3]> = surface.iter().map(|&v| mesh.nodes[v]).collect();
    // `surface` is ascending, so ties at equal distance go to the lower node, as before.
    let mut near: Vec<usize> = nearest_points(&points, mesh.nodes[centre], n)
        .into_iter()
        .map(|i| surface[i])
        .collect();
    near.sort_unstable();
    near
}

/// Indices of the `n` of `points` nearest to `centre`, nearest first (ties: lower index).
pub fn nearest_points(points: &[[f64; 3]], centre: [f64; 3], n: usize) -> Vec<usize> {
    let d2 = |x: &[f64; 3]| {
        (x[0] - centre[0]).powi(2) + (x[1] - centre[1]).powi(2) + (x[2] - centre[2]).powi(2)
    };
    let mut order: Vec<(f64, usize)> = points.iter().map(d2).zip(0..).collect();
    let n = n.min(order.len());
    let by_distance = |a: &(f64, usize), b: &(f64, usize)| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1));
    if n < order.len() {
        order.select_nth_unstable_by(n, by_distance);
        order.truncate(n);
    }
    order.sort_by(by_distance);
    order.into_iter().map(|p| p.1).collect()
}

#[cfg(test)]
mod tests {
    use crate::mesh::{box_mesh, lift_to_quadratic};

    #[test]
    fn closest_point_on_a_box_face_and_exact_interpolation_of_quadratic_fields() {
        let m = lift_to_quadratic(&box_mesh([3, 3, 3], [1.0, 2.0, 3.0]));
        // Outside the +x face, level with its interior.
        let p = m.closest_surface_point([1.4, 0.7, 1.1]).unwrap();
        assert!(
            (p.position[0] - 1.0).abs() < 1e-12
                && (p.position[1] - 0.7).abs() < 1e-12
                && (p.position[2] - 1.1).abs() < 1e-12,
            "{p:?}"
        );
        assert!((p.distance - 0.4).abs() < 1e-12);
        assert!((p.normal[0] - 1.0).abs() < 1e-12, "normal {:?}", p.normal);
        // A quadratic field is reproduced exactly by P2 interpolation.
        let field: Vec<f64> = m
            .nodes
            .iter()
            .flat_map(|x| [x[0] * x[1], x[2] * x[2], 1.0 + x[0] - 2.0 * x[1] * x[2]])
            .collect();
        let v = m.interpolate_vector(&field, &p);
        let x = p.position;
        let exact = [x[0] * x[1], x[2] * x[2], 1.0 + x[0] - 2.0 * x[1] * x[2]];
        for d in 0..3 {
            assert!(
                (v[d] - exact[d]).abs() < 1e-12,
                "component {d}: {} vs {}",
                v[d],
                exact[d]
            );
        }
        // A point inside the body projects to the nearest face.
        let inner = m.closest_surface_point([0.1, 1.0, 1.5]).unwrap();
        assert!(inner.position[0].abs() < 1e-12 && (inner.distance - 0.1).abs() < 1e-12);
    }

    #[test]
    fn support_strike_and_neighbourhood_on_a_box() {
        use super::{nearest_surface_vertices, strike_candidates, support_nodes};
        let mesh = box_mesh([4, 3, 2], [0.4, 0.3, 0.1]);
        let down = [0.0, 0.0, -1.0];
        let bottom = support_nodes(&mesh, down, 0.01, 3);
        assert_eq!(bottom.len(), 5 * 4);
        assert!(bottom.iter().all(|&v| mesh.nodes[v][2] == 0.0));
        let strike = strike_candidates(&mesh, down, 0.05);
        assert!(
            !strike.is_empty()
                && strike
                    .iter()
                    .all(|&(v, n)| mesh.nodes[v][2] > 0.004 && n[2] > -0.5)
        );
        let corner = mesh
            .nodes
            .iter()
            .position(|x| *x == [0.4, 0.3, 0.1])
            .unwrap();
        let near = nearest_surface_vertices(&mesh, corner, 4);
        assert!(near.contains(&corner) && near.len() == 4);
    }

    #[test]
    fn vertex_points_and_the_default_strike() {
        let m = box_mesh([2, 2, 2], [1.0, 1.0, 1.0]);
        let corner = m.nodes.iter().position(|x| *x == [1.0, 1.0, 1.0]).unwrap();
        let p = m.surface_point_at_vertex(corner).unwrap();
        assert_eq!(p.position, [1.0, 1.0, 1.0]);
        let field: Vec<f64> = (0..3 * m.n_nodes()).map(|i| i as f64).collect();
        assert_eq!(
            m.interpolate_vector(&field, &p),
            [
                3.0 * corner as f64,
                3.0 * corner as f64 + 1.0,
                3.0 * corner as f64 + 2.0
            ]
        );
        let centre = m.nodes.iter().position(|x| *x == [0.5, 0.5, 0.5]).unwrap();
        assert!(m.surface_point_at_vertex(centre).is_none(), "interior node");
        let s = m.default_strike_point().unwrap();
        assert!(
            (s.position.iter().map(|c| (c - 0.5).powi(2)).sum::<f64>() - 0.75).abs() < 1e-12,
            "a corner"
        );
    }
}
