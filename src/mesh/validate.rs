//! Turns a parsed file into a [`TetMesh`] the FEM can trust: drops nodes no
//! tet uses, applies the unit scale, rejects (or flips) badly oriented tets and
//! collects the warnings.

use std::path::Path;

use super::gmsh::{ignored_summary, RawMesh};
use super::{BadTet, ElementOrder, MeshError, MeshRead, ReadOptions, TetMesh};

/// How many offending tets an error or warning lists by element tag.
const LISTED_BAD_TETS: usize = 5;

/// Relative zero-volume tolerance; see the module docs of `mesh`.
pub const ZERO_VOLUME_RELATIVE_TOLERANCE: f64 = 1e-12;

pub(super) fn finish(raw: RawMesh, path: &Path, opts: &ReadOptions) -> Result<MeshRead, MeshError> {
    let mut warnings = Vec::new();
    let ignored = ignored_summary(&raw.ignored);
    if raw.connectivity.is_empty() {
        let detail = ignored
            .map(|summary| format!("; {summary}"))
            .unwrap_or_default();
        return Err(MeshError::NoTetrahedra {
            path: path.to_path_buf(),
            location: raw.end_location,
            detail,
        });
    }
    if let Some(summary) = ignored {
        warnings.push(summary);
    }

    let RawMesh {
        coords,
        order,
        mut connectivity,
        element_tags,
        ..
    } = raw;
    let (nodes, n_dropped) = drop_unused_nodes(&coords, &mut connectivity, opts.unit_scale);
    if n_dropped > 0 {
        warnings.push(format!(
            "{n_dropped} nodes are not used by any tetrahedron; they were dropped and the remaining {} nodes \
             renumbered, so the FEM never sees them",
            nodes.len()
        ));
    }
    let mut mesh = TetMesh {
        nodes,
        connectivity,
        order,
    };

    let check = check_volumes(&mesh, &element_tags);
    if !check.degenerate.is_empty() || (!check.inverted.is_empty() && !opts.fix_inverted) {
        let mut examples: Vec<BadTet> = check
            .degenerate
            .iter()
            .take(LISTED_BAD_TETS)
            .cloned()
            .collect();
        examples.extend(
            check
                .inverted
                .iter()
                .take(LISTED_BAD_TETS - examples.len())
                .cloned(),
        );
        return Err(MeshError::BadVolume {
            path: path.to_path_buf(),
            n_inverted: check.inverted.len(),
            n_degenerate: check.degenerate.len(),
            tolerance: check.tolerance,
            examples,
        });
    }
    if !check.inverted.is_empty() {
        for &e in &check.inverted_indices {
            flip_tet(&mut mesh, e);
        }
        let listed: Vec<String> = check
            .inverted
            .iter()
            .take(LISTED_BAD_TETS)
            .map(|t| t.to_string())
            .collect();
        warnings.push(format!(
            "flipped {} inverted tetrahedra (swapped corners 1 and 2, fix_inverted is set); first: {}",
            check.inverted.len(),
            listed.join(", ")
        ));
    }

    let pieces = mesh.connected_components();
    if pieces > 1 {
        warnings.push(format!(
            "the mesh has {pieces} connected pieces (tets sharing no node); each piece adds its own rigid-body modes"
        ));
    }
    Ok(MeshRead {
        mesh,
        element_tags,
        warnings,
    })
}

/// Keeps only nodes referenced by `connectivity`, in their original order,
/// rewrites `connectivity` to the compact indices and scales the coordinates.
/// Returns the kept nodes and how many were dropped.
fn drop_unused_nodes(
    coords: &[[f64; 3]],
    connectivity: &mut [usize],
    scale: f64,
) -> (Vec<[f64; 3]>, usize) {
    let mut new_index = vec![usize::MAX; coords.len()];
    for &n in connectivity.iter() {
        new_index[n] = 0;
    }
    let mut nodes = Vec::with_capacity(coords.len());
    for (old, slot) in new_index.iter_mut().enumerate() {
        if *slot == 0 {
            *slot = nodes.len();
            let [x, y, z] = coords[old];
            nodes.push([x * scale, y * scale, z * scale]);
        }
    }
    for n in connectivity.iter_mut() {
        *n = new_index[*n];
    }
    let dropped = coords.len() - nodes.len();
    (nodes, dropped)
}

pub(super) struct VolumeCheck {
    /// `1e-12 * D^3` for bounding-box diagonal `D`.
    pub tolerance: f64,
    pub inverted: Vec<BadTet>,
    pub inverted_indices: Vec<usize>,
    pub degenerate: Vec<BadTet>,
}

/// Classifies every tet by its corner volume (rule in the `mesh` module docs).
pub(super) fn check_volumes(mesh: &TetMesh, element_tags: &[u64]) -> VolumeCheck {
    let (lo, hi) = mesh.bounding_box();
    let diagonal = super::norm(super::sub(hi, lo));
    let tolerance = ZERO_VOLUME_RELATIVE_TOLERANCE * diagonal.powi(3);
    let mut check = VolumeCheck {
        tolerance,
        inverted: Vec::new(),
        inverted_indices: Vec::new(),
        degenerate: Vec::new(),
    };
    for e in 0..mesh.n_tets() {
        let volume = mesh.corner_volume(e);
        let bad = BadTet {
            element_tag: element_tags.get(e).copied().unwrap_or(e as u64),
            volume,
        };
        if volume.abs() <= tolerance {
            check.degenerate.push(bad);
        } else if volume < 0.0 {
            check.inverted.push(bad);
            check.inverted_indices.push(e);
        }
    }
    check
}

/// Reverses the orientation of tet `e` by swapping corners 1 and 2. For a
/// 10-node tet the mid-edge nodes follow their edges: (0,1)<->(0,2) is
/// 4<->6, (1,3)<->(2,3) is 9<->8, while (1,2) and (0,3) map to themselves.
pub(super) fn flip_tet(mesh: &mut TetMesh, e: usize) {
    let npt = mesh.nodes_per_tet();
    let t = &mut mesh.connectivity[e * npt..(e + 1) * npt];
    t.swap(1, 2);
    if mesh.order == ElementOrder::Quadratic {
        t.swap(4, 6);
        t.swap(8, 9);
    }
}

#[cfg(test)]
mod tests {
    use super::super::{box_mesh, lift_to_quadratic, TET10_EDGES};
    use super::*;

    #[test]
    fn flip_keeps_mid_nodes_on_their_edges() {
        let mut mesh = lift_to_quadratic(&box_mesh([1, 1, 1], [1.0, 1.0, 1.0]));
        let before = mesh.corner_volume(0);
        flip_tet(&mut mesh, 0);
        assert!((mesh.corner_volume(0) + before).abs() < 1e-15);
        let coords = mesh.tet_coords(0);
        for (k, &(a, b)) in TET10_EDGES.iter().enumerate() {
            let midpoint: [f64; 3] = std::array::from_fn(|d| 0.5 * (coords[a][d] + coords[b][d]));
            assert_eq!(coords[4 + k], midpoint);
        }
    }

    #[test]
    fn drops_unused_nodes_keeping_order() {
        let coords = [[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [3.0, 0.0, 0.0]];
        let mut connectivity = vec![3, 1];
        let (nodes, dropped) = drop_unused_nodes(&coords, &mut connectivity, 2.0);
        assert_eq!(dropped, 2);
        assert_eq!(nodes, vec![[2.0, 0.0, 0.0], [6.0, 0.0, 0.0]]);
        assert_eq!(connectivity, vec![1, 0]);
    }

    #[test]
    fn volume_check_classifies() {
        let mut mesh = box_mesh([1, 1, 1], [1.0, 1.0, 1.0]);
        flip_tet(&mut mesh, 2);
        // A seventh tet whose corners all lie in the plane z = 0.
        mesh.nodes.push([0.5, 0.5, 0.0]);
        let flat = mesh.nodes.len() - 1;
        mesh.connectivity.extend([0, 1, 3, flat]);
        let tags: Vec<u64> = (1..=mesh.n_tets() as u64).collect();
        let check = check_volumes(&mesh, &tags);
        assert_eq!(check.inverted_indices, vec![2]);
        assert_eq!(check.inverted[0].element_tag, 3);
        assert_eq!(check.degenerate.len(), 1);
        assert_eq!(check.degenerate[0].element_tag, 7);
    }
}
