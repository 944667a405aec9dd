use super::*;
use crate::assembly::{partition_nodes, DofLayout};
use crate::mesh::{box_mesh, lift_to_quadratic};

/// Π's rows of every rank (of `parts`), applied to the vertex values of `field`, as one vector
/// over all P2 DOFs in the assembly's (new) order; also checks the coarse layout on the way.
fn interpolate(mesh: &TetMesh, parts: usize, field: impl Fn([f64; 3]) -> [f64; 3]) -> Vec<f64> {
    let partition = partition_nodes(&mesh.nodes, parts);
    let layouts: Vec<DofLayout> = (0..parts)
        .map(|rank| DofLayout {
            partition: partition.clone(),
            rank,
        })
        .collect();
    let csr: Vec<_> = layouts.iter().map(|l| interpolation_csr(mesh, l)).collect();
    let vertices = csr[0].4;
    assert_eq!(csr.iter().map(|c| c.3).sum::<usize>(), vertices);
    // The vertex rows (one entry, weight 1) give each vertex's coarse index; the coarse indices
    // of rank r are contiguous and follow those of rank r − 1.
    let mut coarse_values = vec![f64::NAN; 3 * vertices];
    let mut first = 0;
    for (layout, (row_ptr, cols, values, local, _)) in layouts.iter().zip(&csr) {
        let mut seen = Vec::new();
        for (i, new) in layout.owned_nodes().enumerate() {
            let row = 3 * i;
            let (a, b) = (row_ptr[row] as usize, row_ptr[row + 1] as usize);
            if b - a == 1 {
                assert_eq!(values[a], 1.0);
                let j = cols[a] as usize / 3;
                seen.push(j);
                let f = field(mesh.nodes[layout.partition.old_of_new[new]]);
                coarse_values[3 * j..3 * j + 3].copy_from_slice(&f);
            }
        }
        assert_eq!(seen, (first..first + local).collect::<Vec<_>>());
        first += local;
    }
    assert!(coarse_values.iter().all(|v| v.is_finite()));
    let mut out = vec![0.0; 3 * mesh.n_nodes()];
    for (layout, (row_ptr, cols, values, _, _)) in layouts.iter().zip(&csr) {
        let start = 3 * layout.owned_nodes().start;
        for row in 0..row_ptr.len() - 1 {
            let (a, b) = (row_ptr[row] as usize, row_ptr[row + 1] as usize);
            assert!(b - a == 1 || b - a == 2, "row {row} has {} entries", b - a);
            assert!((values[a..b].iter().sum::<f64>() - 1.0).abs() < 1e-15);
            out[start + row] = (a..b)
                .map(|k| values[k] * coarse_values[cols[k] as usize])
                .sum();
        }
    }
    out
}

fn linear(x: [f64; 3]) -> [f64; 3] {
    [
        1.0 + 2.0 * x[0] - x[1] + 0.5 * x[2],
        -3.0 + x[0] + 4.0 * x[2],
        0.25 - x[0] + x[1] - 2.0 * x[2],
    ]
}

#[test]
fn interpolation_reproduces_a_linear_field_at_every_p2_node() {
    let mesh = lift_to_quadratic(&box_mesh([3, 2, 2], [1.0, 0.7, 0.5]));
    for parts in [1, 2, 3] {
        let u = interpolate(&mesh, parts, linear);
        let partition = partition_nodes(&mesh.nodes, parts);
        for (old, x) in mesh.nodes.iter().enumerate() {
            let new = partition.new_of_old[old];
            let f = linear(*x);
            for c in 0..3 {
                assert!(
                    (u[3 * new + c] - f[c]).abs() < 1e-13,
                    "{parts} parts, node {old} component {c}: {} != {}",
                    u[3 * new + c],
                    f[c]
                );
            }
        }
    }
}

#[test]
fn interpolation_averages_the_edge_ends_on_curved_tets_too() {
    // Π is the P1 interpolation in reference coordinates: a mid-edge node moved off its chord
    // still receives the mean of the edge's two vertex values, not the field at its position.
    let mut mesh = lift_to_quadratic(&box_mesh([2, 2, 2], [1.0, 1.0, 1.0]));
    let parents = edge_parents(&mesh);
    let (moved, [a, b]) = parents
        .iter()
        .enumerate()
        .find_map(|(n, p)| p.map(|p| (n, p)))
        .expect("a P2 mesh has mid-edge nodes");
    mesh.nodes[moved][0] += 0.05;
    let u = interpolate(&mesh, 2, linear);
    let partition = partition_nodes(&mesh.nodes, 2);
    let (fa, fb) = (linear(mesh.nodes[a]), linear(mesh.nodes[b]));
    let new = partition.new_of_old[moved];
    for c in 0..3 {
        assert!((u[3 * new + c] - 0.5 * (fa[c] + fb[c])).abs() < 1e-13);
    }
    // Every vertex is a coarse node and every other node has two parents.
    let vertices = parents.iter().filter(|p| p.is_none()).count();
    assert_eq!(vertices, 27);
}

#[test]
fn a_linear_mesh_has_no_mid_edge_nodes() {
    let mesh = box_mesh([1, 1, 1], [1.0, 1.0, 1.0]);
    assert!(edge_parents(&mesh).iter().all(|p| p.is_none()));
}
