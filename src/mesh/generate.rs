//! Structured meshes for tests and quick experiments.

use super::{ElementOrder, TetMesh};

/// Unit-cube corner offsets visited by each of the 6 Kuhn tets: a monotone
/// path from (0,0,0) to (1,1,1) that steps along the axes in the order of a
/// permutation. Odd permutations would give negative volume, so their middle
/// two corners are swapped to keep every tet positively oriented.
pub(crate) const KUHN_TETS: [[[usize; 3]; 4]; 6] = {
    const fn path(first: usize, second: usize, third: usize, odd: bool) -> [[usize; 3]; 4] {
        let mut v1 = [0; 3];
        v1[first] = 1;
        let mut v2 = v1;
        v2[second] = 1;
        let mut v3 = v2;
        v3[third] = 1;
        if odd {
            [[0; 3], v2, v1, v3]
        } else {
            [[0; 3], v1, v2, v3]
        }
    }
    [
        path(0, 1, 2, false),
        path(1, 2, 0, false),
        path(2, 0, 1, false),
        path(0, 2, 1, true),
        path(1, 0, 2, true),
        path(2, 1, 0, true),
    ]
};

/// Structured linear mesh of the box `[0, size[0]] x [0, size[1]] x
/// [0, size[2]]` with `n[i]` cells along axis `i`, each cell split into the 6
/// tets of the Kuhn (Freudenthal) subdivision along its (0,0,0)-(1,1,1)
/// diagonal. Every cell is split the same way, so neighbouring cells' faces
/// match. All tets are positively oriented. Node `(i, j, k)` has index
/// `i + (n[0]+1) * (j + (n[1]+1) * k)`. If any `n[i]` is 0 the mesh is empty.
pub fn box_mesh(n: [usize; 3], size: [f64; 3]) -> TetMesh {
    if n.contains(&0) {
        return TetMesh {
            nodes: Vec::new(),
            connectivity: Vec::new(),
            order: ElementOrder::Linear,
        };
    }
    let [nx, ny, nz] = n;
    let node_index = |i: usize, j: usize, k: usize| i + (nx + 1) * (j + (ny + 1) * k);
    let mut nodes = Vec::with_capacity((nx + 1) * (ny + 1) * (nz + 1));
    for k in 0..=nz {
        for j in 0..=ny {
            for i in 0..=nx {
                nodes.push([
                    size[0] * i as f64 / nx as f64,
                    size[1] * j as f64 / ny as f64,
                    size[2] * k as f64 / nz as f64,
                ]);
            }
        }
    }
    let mut connectivity = Vec::with_capacity(24 * nx * ny * nz);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                for tet in KUHN_TETS {
                    for [di, dj, dk] in tet {
                        connectivity.push(node_index(i + di, j + dj, k + dk));
                    }
                }
            }
        }
    }
    TetMesh {
        nodes,
        connectivity,
        order: ElementOrder::Linear,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_mesh_counts_volume_orientation() {
        let m = box_mesh([3, 2, 4], [0.3, 0.2, 0.8]);
        assert_eq!(m.n_nodes(), 4 * 3 * 5);
        assert_eq!(m.n_tets(), 6 * 3 * 2 * 4);
        assert!((m.volume() - 0.3 * 0.2 * 0.8).abs() < 1e-14);
        let cell_volume = 0.1 * 0.1 * 0.2;
        for e in 0..m.n_tets() {
            assert!(
                (m.corner_volume(e) - cell_volume / 6.0).abs() < 1e-15,
                "tet {e}"
            );
        }
        assert_eq!(m.connected_components(), 1);
    }

    #[test]
    fn box_mesh_faces_match_between_cells() {
        // With matching faces the boundary is exactly the box surface:
        // 2 triangles per boundary cell face.
        let n = [3, 2, 4];
        let m = box_mesh(n, [1.0, 1.0, 1.0]);
        let expected = 2 * 2 * (n[0] * n[1] + n[1] * n[2] + n[0] * n[2]);
        assert_eq!(m.boundary_faces().len(), expected);
    }

    #[test]
    fn empty_box() {
        let m = box_mesh([0, 2, 2], [1.0, 1.0, 1.0]);
        assert_eq!((m.n_nodes(), m.n_tets()), (0, 0));
        assert_eq!(m.connected_components(), 0);
    }
}
