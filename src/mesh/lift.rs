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
}
