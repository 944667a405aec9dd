//! Curved 10-node tets whose map folds over, found before the FEM and, on request, straightened.
//!
//! A second-order Gmsh mesh places each mid-edge node on the curved geometry. On a thin curved
//! part (a slender rod, a thin shell) a tet whose edge follows the curvature while its opposite
//! corner sits close by can fold: the isoparametric map x(ξ) = Σ Nᵢ(ξ) xᵢ has a Jacobian
//! determinant det J(ξ) ≤ 0 somewhere inside, and its stiffness matrix is meaningless.
//!
//! **Detection.** det J is evaluated at the 35 points of the barycentric lattice with step 1/4
//! (corners, edge and face points and interior points; the quadratic map's det J is a cubic
//! polynomial, so a fold deep enough to matter shows on this lattice), with the P2 shape
//! functions Nᵢ = Lᵢ(2Lᵢ − 1) at the corners and 4 LᵢLⱼ on the edges ([`super::TET10_EDGES`]).
//!
//! **Straightening.** Each mid-edge node of a folded tet moves to the midpoint of its edge's
//! corners. That tet becomes affine (det J constant, the corner volume, positive for a valid
//! corner mesh); its neighbours that share the edge see that edge straightened too, which
//! lowers their curvature. The geometry loses its curvature on those edges only (a user can
//! instead let Gmsh untangle the mesh with `gmsh -optimize_ho`).
//!
//! **Every job that assembles a mesh** reads it with [`read_for_fem`]: the reader's checks, then
//! this one, refusing the file with its name, the count and the first Gmsh element tags
//! ([`MeshError::FoldedTets`]) unless asked to straighten (`--straighten-invalid`), in which case
//! the straightening is one of the read's warnings. (The shape fits read a `.msh` only for its
//! boundary triangles' corners, which a fold inside does not change, and mesh the body anew.)

use super::{MeshError, MeshRead, ReadOptions, TetMesh, TET10_EDGES};
use std::path::Path;

/// How many Gmsh element tags a message lists before an ellipsis.
const TAGS_SHOWN: usize = 5;

/// Barycentric lattice step of the detection (module docs).
const LATTICE: usize = 4;

/// det J of the 10-node tet with node coordinates `x` (Gmsh order) at barycentric `l`.
fn det_jacobian(x: &[[f64; 3]; 10], l: [f64; 4]) -> f64 {
    // dN/dL_i for every node, then dξ_k via ∂L0/∂ξ_k = −1, ∂L_k/∂ξ_k = 1.
    let mut jac = [[0.0; 3]; 3];
    let mut add = |node: usize, dl: [f64; 4]| {
        for k in 0..3 {
            let d = dl[k + 1] - dl[0];
            for a in 0..3 {
                jac[a][k] += x[node][a] * d;
            }
        }
    };
    for i in 0..4 {
        let mut dl = [0.0; 4];
        dl[i] = 4.0 * l[i] - 1.0;
        add(i, dl);
    }
    for (e, &(i, j)) in TET10_EDGES.iter().enumerate() {
        let mut dl = [0.0; 4];
        dl[i] = 4.0 * l[j];
        dl[j] = 4.0 * l[i];
        add(4 + e, dl);
    }
    jac[0][0] * (jac[1][1] * jac[2][2] - jac[1][2] * jac[2][1])
        - jac[0][1] * (jac[1][0] * jac[2][2] - jac[1][2] * jac[2][0])
        + jac[0][2] * (jac[1][0] * jac[2][1] - jac[1][1] * jac[2][0])
}

/// The smallest det J of tet `e` over the lattice (module docs).
pub fn min_det_jacobian(mesh: &TetMesh, e: usize) -> f64 {
    let t = mesh.tet(e);
    let mut x = [[0.0; 3]; 10];
    for (k, &n) in t.iter().take(10).enumerate() {
        x[k] = mesh.nodes[n];
    }
    let mut worst = f64::INFINITY;
    let n = LATTICE;
    for a in 0..=n {
        for b in 0..=n - a {
            for c in 0..=n - a - b {
                let d = n - a - b - c;
                let l = [
                    a as f64 / n as f64,
                    b as f64 / n as f64,
                    c as f64 / n as f64,
                    d as f64 / n as f64,
                ];
                worst = worst.min(det_jacobian(&x, l));
            }
        }
    }
    worst
}

/// The 10-node tets whose map folds (det J ≤ 0 on the lattice), ascending. Empty for a
/// 4-node mesh.
pub fn folded_tets(mesh: &TetMesh) -> Vec<usize> {
    if mesh.nodes_per_tet() != 10 {
        return Vec::new();
    }
    (0..mesh.n_tets())
        .filter(|&e| min_det_jacobian(mesh, e) <= 0.0)
        .collect()
}

/// Moves every mid-edge node of the tets `tets` to its edge's midpoint (module docs); returns
/// how many nodes moved.
pub fn straighten(mesh: &mut TetMesh, tets: &[usize]) -> usize {
    let mut moved = std::collections::BTreeSet::new();
    for &e in tets {
        let t: Vec<usize> = mesh.tet(e).to_vec();
        for (k, &(i, j)) in TET10_EDGES.iter().enumerate() {
            let (a, b) = (mesh.nodes[t[i]], mesh.nodes[t[j]]);
            let mid = [
                0.5 * (a[0] + b[0]),
                0.5 * (a[1] + b[1]),
                0.5 * (a[2] + b[2]),
            ];
            if mesh.nodes[t[4 + k]] != mid {
                mesh.nodes[t[4 + k]] = mid;
                moved.insert(t[4 + k]);
            }
        }
    }
    moved.len()
}

/// Reads the tet mesh a job assembles: [`super::read_mesh`], then the fold check of the module
/// docs. Folded curved tets are an error naming the file, their count and first Gmsh element
/// tags, or with `straighten_invalid` are straightened, which is reported as the first of the
/// read's warnings.
pub fn read_for_fem(
    path: &Path,
    opts: &ReadOptions,
    straighten_invalid: bool,
) -> Result<MeshRead, MeshError> {
    let mut read = super::read_mesh(path, opts)?;
    let folded = folded_tets(&read.mesh);
    if folded.is_empty() {
        return Ok(read);
    }
    let mut tags: Vec<String> = folded
        .iter()
        .take(TAGS_SHOWN)
        .map(|&e| {
            read.element_tags
                .get(e)
                .map_or(format!("#{e}"), |t| t.to_string())
        })
        .collect();
    if folded.len() > TAGS_SHOWN {
        tags.push("…".into());
    }
    let tags = tags.join(", ");
    if !straighten_invalid {
        return Err(MeshError::FoldedTets {
            path: path.to_path_buf(),
            count: folded.len(),
            tags,
        });
    }
    let moved = straighten(&mut read.mesh, &folded);
    read.warnings.insert(
        0,
        format!(
            "straightened {} folded curved tetrahedra ({moved} mid-edge nodes moved to their edge midpoints; Gmsh element tags {tags})",
            folded.len()
        ),
    );
    Ok(read)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::ElementOrder;

    /// The unit tet with straight mid-edge nodes, then mid-edge node `bend` pushed by `by`.
    fn tet10(bend: usize, by: [f64; 3]) -> TetMesh {
        let corners = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
        ];
        let mut nodes: Vec<[f64; 3]> = corners.to_vec();
        for &(i, j) in TET10_EDGES.iter() {
            nodes.push([
                0.5 * (corners[i][0] + corners[j][0]),
                0.5 * (corners[i][1] + corners[j][1]),
                0.5 * (corners[i][2] + corners[j][2]),
            ]);
        }
        for a in 0..3 {
            nodes[4 + bend][a] += by[a];
        }
        TetMesh {
            nodes,
            connectivity: (0..10).collect(),
            order: ElementOrder::Quadratic,
        }
    }

    #[test]
    fn a_straight_tet_has_its_volume_jacobian_everywhere() {
        let m = tet10(0, [0.0; 3]);
        assert!((min_det_jacobian(&m, 0) - 1.0).abs() < 1e-12);
        assert!(folded_tets(&m).is_empty());
    }

    #[test]
    fn a_mid_edge_node_pushed_across_the_tet_folds_it_and_straightening_unfolds_it() {
        // Edge (0,1)'s mid node pushed far along +y: the map folds near corner 0 or 1.
        let mut m = tet10(0, [0.0, 0.9, 0.9]);
        assert!(min_det_jacobian(&m, 0) <= 0.0);
        assert_eq!(folded_tets(&m), vec![0]);
        // A mild curvature does not fold.
        assert!(folded_tets(&tet10(0, [0.0, 0.1, 0.0])).is_empty());
        assert_eq!(straighten(&mut m, &[0]), 1);
        assert!((min_det_jacobian(&m, 0) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn read_for_fem_refuses_a_folded_file_by_tag_or_straightens_it_with_a_warning() {
        let path =
            std::env::temp_dir().join(format!("diffsound_folded_{}.msh", std::process::id()));
        std::fs::write(
            &path,
            "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n10\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 0.5 0.9 0.9\n6 0.5 0.5 0\n7 0 0.5 0\n8 0 0 0.5\n9 0 0.5 0.5\n10 0.5 0 0.5\n$EndNodes\n$Elements\n1\n4287 11 2 0 1 1 2 3 4 5 6 7 8 9 10\n$EndElements\n",
        )
        .unwrap();
        let e = read_for_fem(&path, &ReadOptions::default(), false).unwrap_err();
        let text = e.to_string();
        assert!(
            matches!(e, MeshError::FoldedTets { count: 1, .. })
                && text.contains("Gmsh element tags 4287")
                && text.contains(&path.display().to_string()),
            "{text}"
        );
        let read = read_for_fem(&path, &ReadOptions::default(), true).unwrap();
        assert!(folded_tets(&read.mesh).is_empty());
        assert!(
            read.warnings[0].starts_with("straightened 1 folded curved tetrahedra (1 mid-edge"),
            "{:?}",
            read.warnings
        );
        let _ = std::fs::remove_file(&path);
    }
}
