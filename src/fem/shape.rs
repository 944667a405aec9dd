//! Lagrange shape functions on the reference tetrahedron, Gmsh node order.
//!
//! Barycentric coordinates: L0 = 1 − ξ − η − ζ, L1 = ξ, L2 = η, L3 = ζ.
//! P1: N_i = L_i (corners 0..3).
//! P2 (tet10): corners N_i = L_i (2 L_i − 1); mid-edge nodes N = 4 L_i L_j with
//! the Gmsh edge order 4:(0,1) 5:(1,2) 6:(0,2) 7:(0,3) 8:(2,3) 9:(1,3).

/// Corner pair of each P2 mid-edge node, in Gmsh order (node 4 + index).
pub const P2_EDGES: [(usize, usize); 6] = [(0, 1), (1, 2), (0, 2), (0, 3), (2, 3), (1, 3)];

/// Reference coordinates of the P1 corners.
pub const P1_NODES: [[f64; 3]; 4] = [
    [0.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, 0.0, 1.0],
];

/// Reference coordinates of the 10 P2 nodes (Gmsh order).
pub const P2_NODES: [[f64; 3]; 10] = [
    [0.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, 0.0, 1.0],
    [0.5, 0.0, 0.0],
    [0.5, 0.5, 0.0],
    [0.0, 0.5, 0.0],
    [0.0, 0.0, 0.5],
    [0.0, 0.5, 0.5],
    [0.5, 0.0, 0.5],
];

/// Gradients of the barycentric coordinates L0..L3 with respect to (ξ,η,ζ).
const GRAD_L: [[f64; 3]; 4] = [
    [-1.0, -1.0, -1.0],
    [1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, 0.0, 1.0],
];

#[inline]
fn barycentric(xi: [f64; 3]) -> [f64; 4] {
    [1.0 - xi[0] - xi[1] - xi[2], xi[0], xi[1], xi[2]]
}

/// P1 shape function values at reference point `xi`.
#[inline]
pub fn p1_shape(xi: [f64; 3]) -> [f64; 4] {
    barycentric(xi)
}

/// P1 reference gradients (constant), `[node][d/dξ, d/dη, d/dζ]`.
#[inline]
pub fn p1_grad_ref() -> [[f64; 3]; 4] {
    GRAD_L
}

/// P2 shape function values at reference point `xi` (Gmsh tet10 order).
#[inline]
pub fn p2_shape(xi: [f64; 3]) -> [f64; 10] {
    let l = barycentric(xi);
    let mut n = [0.0; 10];
    for i in 0..4 {
        n[i] = l[i] * (2.0 * l[i] - 1.0);
    }
    for (e, &(i, j)) in P2_EDGES.iter().enumerate() {
        n[4 + e] = 4.0 * l[i] * l[j];
    }
    n
}

/// P2 reference gradients at `xi`, `[node][d/dξ, d/dη, d/dζ]`.
#[inline]
pub fn p2_grad_ref(xi: [f64; 3]) -> [[f64; 3]; 10] {
    let l = barycentric(xi);
    let mut g = [[0.0; 3]; 10];
    for i in 0..4 {
        let f = 4.0 * l[i] - 1.0;
        for d in 0..3 {
            g[i][d] = f * GRAD_L[i][d];
        }
    }
    for (e, &(i, j)) in P2_EDGES.iter().enumerate() {
        for d in 0..3 {
            g[4 + e][d] = 4.0 * (l[j] * GRAD_L[i][d] + l[i] * GRAD_L[j][d]);
        }
    }
    g
}

/// Shape values for a tet with `nodes` nodes (4 or 10) written into `out[..nodes]`.
/// Returns false for an unsupported node count.
pub(crate) fn shape_into(nodes: usize, xi: [f64; 3], out: &mut [f64]) -> bool {
    match nodes {
        4 => out[..4].copy_from_slice(&p1_shape(xi)),
        10 => out[..10].copy_from_slice(&p2_shape(xi)),
        _ => return false,
    }
    true
}

/// Reference gradients for a tet with `nodes` nodes (4 or 10) into `out[..nodes]`.
pub(crate) fn grad_into(nodes: usize, xi: [f64; 3], out: &mut [[f64; 3]]) -> bool {
    match nodes {
        4 => out[..4].copy_from_slice(&p1_grad_ref()),
        10 => out[..10].copy_from_slice(&p2_grad_ref(xi)),
        _ => return false,
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_points() -> Vec<[f64; 3]> {
        let mut pts = vec![
            [0.1, 0.2, 0.3],
            [0.25, 0.25, 0.25],
            [0.7, 0.1, 0.05],
            [0.0, 0.0, 0.0],
            [0.3, 0.0, 0.6],
        ];
        pts.extend(P2_NODES);
        pts
    }

    #[test]
    fn partition_of_unity_and_zero_gradient_sum() {
        for xi in sample_points() {
            let s1: f64 = p1_shape(xi).iter().sum();
            let s2: f64 = p2_shape(xi).iter().sum();
            assert!((s1 - 1.0).abs() < 1e-14 && (s2 - 1.0).abs() < 1e-14);
            for d in 0..3 {
                let g1: f64 = p1_grad_ref().iter().map(|g| g[d]).sum();
                let g2: f64 = p2_grad_ref(xi).iter().map(|g| g[d]).sum();
                assert!(g1.abs() < 1e-14 && g2.abs() < 1e-13);
            }
        }
    }

    #[test]
    fn kronecker_delta_at_nodes() {
        for (a, &x) in P2_NODES.iter().enumerate() {
            let n = p2_shape(x);
            for (b, &v) in n.iter().enumerate() {
                assert!(
                    (v - if a == b { 1.0 } else { 0.0 }).abs() < 1e-15,
                    "N_{b}(node {a}) = {v}"
                );
            }
        }
        for (a, &x) in P1_NODES.iter().enumerate() {
            let n = p1_shape(x);
            for (b, &v) in n.iter().enumerate() {
                assert!((v - if a == b { 1.0 } else { 0.0 }).abs() < 1e-15);
            }
        }
    }

    #[test]
    fn mid_nodes_are_edge_midpoints() {
        for (e, &(i, j)) in P2_EDGES.iter().enumerate() {
            let mid: Vec<f64> = (0..3)
                .map(|d| 0.5 * (P2_NODES[i][d] + P2_NODES[j][d]))
                .collect();
            assert_eq!(P2_NODES[4 + e].to_vec(), mid);
        }
    }

    #[test]
    fn gradients_match_finite_differences() {
        let h = 1e-6;
        for xi in sample_points() {
            let g = p2_grad_ref(xi);
            let g1 = p1_grad_ref();
            for d in 0..3 {
                let mut xp = xi;
                let mut xm = xi;
                xp[d] += h;
                xm[d] -= h;
                let (np, nm) = (p2_shape(xp), p2_shape(xm));
                let (n1p, n1m) = (p1_shape(xp), p1_shape(xm));
                for a in 0..10 {
                    let fd = (np[a] - nm[a]) / (2.0 * h);
                    assert!(
                        (fd - g[a][d]).abs() < 1e-8,
                        "node {a} dir {d}: fd {fd} vs {}",
                        g[a][d]
                    );
                }
                for a in 0..4 {
                    assert!(((n1p[a] - n1m[a]) / (2.0 * h) - g1[a][d]).abs() < 1e-8);
                }
            }
        }
    }
}
