//! Conversions between 4-node and 10-node tet meshes.

use std::collections::HashMap;

use super::{ElementOrder, TetMesh, TET10_EDGES};

/// Linear -> quadratic: adds one node at the midpoint of every edge, shared by
/// all tets around that edge, and appends it to each tet in Gmsh order
/// ([`TET10_EDGES`]). Edges are identified by their sorted pair of node
/// indices, never by coordinates, so coincident but unconnected nodes stay
/// apart. The original nodes keep their indices; new nodes follow in order of
/// first appearance. A quadratic mesh is returned unchanged.
pub fn lift_to_quadratic(m: &TetMesh) -> TetMesh {
    if m.order == ElementOrder::Quadratic {
        return m.clone();
    }
    let n_tets = m.n_tets();
    // A tet mesh has roughly 7/6 edges per tet on the inside.
    let mut edge_node: HashMap<(usize, usize), usize> =
        HashMap::with_capacity(n_tets + n_tets / 4 + 16);
    let mut nodes = m.nodes.clone();
    let mut connectivity = Vec::with_capacity(10 * n_tets);
    for e in 0..n_tets {
        let corners = m.tet(e);
        connectivity.extend_from_slice(corners);
        for (a, b) in TET10_EDGES {
            let (i, j) = (corners[a], corners[b]);
            let key = if i < j { (i, j) } else { (j, i) };
            let mid = *edge_node.entry(key).or_insert_with(|| {
                let (p, q) = (m.nodes[i], m.nodes[j]);
                nodes.push([
                    0.5 * (p[0] + q[0]),
                    0.5 * (p[1] + q[1]),
                    0.5 * (p[2] + q[2]),
                ]);
                nodes.len() - 1
            });
            connectivity.push(mid);
        }
    }
    TetMesh {
        nodes,
        connectivity,
        order: ElementOrder::Quadratic,
    }
}

/// Quadratic -> linear: keeps the 4 corners of each tet and only the nodes
/// that are a corner of some tet, renumbered compactly in their original
/// relative order. A linear mesh is returned unchanged.
pub fn to_linear(m: &TetMesh) -> TetMesh {
    if m.order == ElementOrder::Linear {
        return m.clone();
    }
    let mut new_index = vec![usize::MAX; m.n_nodes()];
    for e in 0..m.n_tets() {
        for &n in &m.tet(e)[..4] {
            new_index[n] = 0;
        }
    }
    let mut nodes = Vec::new();
    for (old, slot) in new_index.iter_mut().enumerate() {
        if *slot == 0 {
            *slot = nodes.len();
            nodes.push(m.nodes[old]);
        }
    }
    let connectivity = (0..m.n_tets())
        .flat_map(|e| {
            m.tet(e)[..4]
                .iter()
                .map(|&n| new_index[n])
                .collect::<Vec<_>>()
        })
        .collect();
    TetMesh {
        nodes,
        connectivity,
        order: ElementOrder::Linear,
    }
}

/// A linear mesh and a quadratic mesh that are not a mesh and its lift.
#[derive(thiserror::Error, Debug, Clone, PartialEq)]
pub enum LiftError {
    #[error("expected a linear mesh and a quadratic one, got {linear:?} and {quadratic:?}")]
    Order {
        linear: ElementOrder,
        quadratic: ElementOrder,
    },
    #[error("the quadratic mesh is not the lift of the linear one: {message}")]
    Mismatch { message: String },
    #[error("the gradient has {found} entries, expected 3 per quadratic node ({expected})")]
    GradientLength { expected: usize, found: usize },
}

/// Chain rule through [`lift_to_quadratic`]: from dL/dx at the nodes of
/// `quadratic` = `lift_to_quadratic(linear)` (3 per node, dof = 3·node + d) to
/// dL/dx at the nodes of `linear`. Corners keep their own rows; every
/// mid-edge node sits at x_m = (x_a + x_b)/2, so half of its row goes to each
/// corner of its edge. Corners must be the same nodes in both meshes, as
/// `lift_to_quadratic` leaves them.
pub fn linear_node_gradient(
    linear: &TetMesh,
    quadratic: &TetMesh,
    d_quadratic: &[f64],
) -> Result<Vec<f64>, LiftError> {
    if linear.order != ElementOrder::Linear || quadratic.order != ElementOrder::Quadratic {
        return Err(LiftError::Order {
            linear: linear.order,
            quadratic: quadratic.order,
        });
    }
    if d_quadratic.len() != 3 * quadratic.n_nodes() {
        return Err(LiftError::GradientLength {
            expected: 3 * quadratic.n_nodes(),
            found: d_quadratic.len(),
        });
    }
    if linear.n_tets() != quadratic.n_tets() {
        return Err(LiftError::Mismatch {
            message: format!(
                "{} linear and {} quadratic tets",
                linear.n_tets(),
                quadratic.n_tets()
            ),
        });
    }
    let mut out = vec![0.0; 3 * linear.n_nodes()];
    // Each quadratic node contributes once: as a corner or as a mid-edge node.
    let mut seen = vec![false; quadratic.n_nodes()];
    for e in 0..quadratic.n_tets() {
        let (q, l) = (quadratic.tet(e), linear.tet(e));
        if q[..4] != *l {
            return Err(LiftError::Mismatch {
                message: format!(
                    "tet {e} has corners {:?} in the quadratic mesh and {l:?} in the linear one",
                    &q[..4]
                ),
            });
        }
        for &c in l {
            if !seen[c] {
                seen[c] = true;
                for d in 0..3 {
                    out[3 * c + d] += d_quadratic[3 * c + d];
                }
            }
        }
        for (k, &(a, b)) in TET10_EDGES.iter().enumerate() {
            let m = q[4 + k];
            if m < linear.n_nodes() {
                return Err(LiftError::Mismatch {
                    message: format!("mid-edge node {m} of tet {e} has the index of a linear node"),
                });
            }
            if !seen[m] {
                seen[m] = true;
                for d in 0..3 {
                    let half = 0.5 * d_quadratic[3 * m + d];
                    out[3 * l[a] + d] += half;
                    out[3 * l[b] + d] += half;
                }
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::super::box_mesh;
    use super::*;

    fn unique_edges(m: &TetMesh) -> usize {
        let mut edges: Vec<(usize, usize)> = (0..m.n_tets())
            .flat_map(|e| {
                let t = m.tet(e);
                TET10_EDGES.map(|(a, b)| (t[a].min(t[b]), t[a].max(t[b])))
            })
            .collect();
        edges.sort_unstable();
        edges.dedup();
        edges.len()
    }

    #[test]
    fn lift_adds_one_node_per_edge_at_its_midpoint() {
        let linear = box_mesh([2, 3, 1], [1.0, 2.0, 0.5]);
        let quadratic = lift_to_quadratic(&linear);
        assert_eq!(quadratic.order, ElementOrder::Quadratic);
        assert_eq!(
            quadratic.n_nodes(),
            linear.n_nodes() + unique_edges(&linear)
        );
        assert_eq!(quadratic.n_tets(), linear.n_tets());
        for e in 0..quadratic.n_tets() {
            let x = quadratic.tet_coords(e);
            assert_eq!(&quadratic.tet(e)[..4], linear.tet(e));
            for (k, &(a, b)) in TET10_EDGES.iter().enumerate() {
                let midpoint: [f64; 3] = std::array::from_fn(|d| 0.5 * (x[a][d] + x[b][d]));
                assert_eq!(x[4 + k], midpoint);
            }
        }
        assert!((quadratic.volume() - linear.volume()).abs() < 1e-14);
        assert_eq!(to_linear(&quadratic), linear);
    }

    #[test]
    fn lift_is_topological_not_geometric() {
        // Two tets touching along a geometric edge but with distinct node
        // copies must not share a mid-edge node.
        let mut m = box_mesh([1, 1, 1], [1.0, 1.0, 1.0]);
        let copy_start = m.n_nodes();
        m.nodes.extend(m.nodes.clone());
        let second: Vec<usize> = m.tet(0).iter().map(|&n| n + copy_start).collect();
        m.connectivity.extend(second);
        let q = lift_to_quadratic(&m);
        let last = q.n_tets() - 1;
        let shared = q.tet(last)[4..]
            .iter()
            .filter(|n| q.tet(0)[4..].contains(n))
            .count();
        assert_eq!(shared, 0);
    }

    #[test]
    fn orders_are_idempotent() {
        let linear = box_mesh([1, 1, 1], [1.0, 1.0, 1.0]);
        assert_eq!(to_linear(&linear), linear);
        let quadratic = lift_to_quadratic(&linear);
        assert_eq!(lift_to_quadratic(&quadratic), quadratic);
    }

    #[test]
    fn linear_node_gradient_matches_finite_differences() {
        // L(x) = Σ_n w_n·x_n + Σ_n |x_n|² over the lifted nodes, as a function of the corners.
        let mut linear = box_mesh([2, 1, 1], [1.0, 0.5, 0.5]);
        for (i, x) in linear.nodes.iter_mut().enumerate() {
            x[0] += 0.03 * (i as f64).sin();
            x[2] += 0.02 * (i as f64).cos();
        }
        let loss = |m: &TetMesh| -> f64 {
            let q = lift_to_quadratic(m);
            q.nodes
                .iter()
                .enumerate()
                .map(|(n, x)| {
                    (n as f64 + 1.0).sqrt() * (x[0] - 2.0 * x[1] + x[2])
                        + x[0] * x[0]
                        + x[1] * x[1] * x[2]
                })
                .sum()
        };
        let quadratic = lift_to_quadratic(&linear);
        let d_quadratic: Vec<f64> = quadratic
            .nodes
            .iter()
            .enumerate()
            .flat_map(|(n, x)| {
                let w = (n as f64 + 1.0).sqrt();
                [
                    w + 2.0 * x[0],
                    -2.0 * w + 2.0 * x[1] * x[2],
                    w + x[1] * x[1],
                ]
            })
            .collect();
        let g = linear_node_gradient(&linear, &quadratic, &d_quadratic).unwrap();
        let eps = 1e-6;
        for n in 0..linear.n_nodes() {
            for d in 0..3 {
                let mut plus = linear.clone();
                plus.nodes[n][d] += eps;
                let mut minus = linear.clone();
                minus.nodes[n][d] -= eps;
                let fd = (loss(&plus) - loss(&minus)) / (2.0 * eps);
                assert!(
                    (fd - g[3 * n + d]).abs() < 1e-7 * (1.0 + fd.abs()),
                    "node {n} dim {d}: {fd} vs {}",
                    g[3 * n + d]
                );
            }
        }
        assert!(matches!(
            linear_node_gradient(&quadratic, &quadratic, &d_quadratic),
            Err(LiftError::Order { .. })
        ));
        assert!(matches!(
            linear_node_gradient(&linear, &quadratic, &d_quadratic[1..]),
            Err(LiftError::GradientLength { .. })
        ));
        let other = lift_to_quadratic(&box_mesh([1, 2, 1], [1.0, 0.5, 0.5]));
        let d_other = vec![0.0; 3 * other.n_nodes()];
        assert!(matches!(
            linear_node_gradient(&linear, &other, &d_other),
            Err(LiftError::Mismatch { .. })
        ));
    }
}
