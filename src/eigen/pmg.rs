//! The coarse space of the iterative path's p-multigrid: the P1 field on the mesh's vertices,
//! interpolated into the P2 space.
//!
//! **Why.** GAMG on the P2 operator spends ~18 fine-level matrix products per V-cycle (its
//! first coarsening of a P2 stencil of ~85 nonzeros per row is expensive and weak), and GD still
//! needs ~3,300 of those V-cycles for 20 modes. A P2 element space holds the P1 space on the same
//! vertices exactly, so the natural first coarse level is geometric, not algebraic: the P1 field,
//! with about an eighth of the unknowns (a tet mesh has ~6–7 edges per vertex, so P2 has ~7–8×
//! the nodes of P1) and the same smooth content the lowest eigenvectors are made of.
//!
//! **The interpolation Π.** With v(a) the coarse unknowns at vertex a (3 components, block size
//! 3), the P2 nodal values are
//!
//! ```text
//!   u(n) = v(n)                     n a vertex (a corner of some tet)
//!   u(n) = ½ (v(a) + v(b))          n the mid-edge node of the edge (a, b)
//! ```
//!
//! which is the P1 function v evaluated at the P2 nodes of the reference element, so Π maps the
//! isoparametric P1 space into the P2 one exactly, curved tets included (their mid-edge node is
//! not at the chord midpoint, but in reference coordinates it is). Π reproduces translations
//! exactly, and rotations exactly on straight tets.
//!
//! **Layout.** The rows are the P2 DOFs in the assembly's layout (rank r owns the rows of its
//! nodes). A vertex's coarse DOFs belong to the rank that owns its P2 node, and are numbered in
//! the P2 order of those nodes, so each rank's coarse rows are contiguous and every rank computes
//! the same numbering from the whole mesh without communication. The coarse operator is the
//! Galerkin product A_c = Πᵀ P Π of the fine preconditioning matrix P = K − σM (positive definite
//! since Π has full column rank), formed by PETSc (`MatPtAP`).

use crate::assembly::DofLayout;
use crate::mesh::{ElementOrder, TetMesh, TET10_EDGES};
use crate::petsc::{Mat, Petsc, PetscError, PetscInt, Vector};

/// The P1 → P2 interpolation Π and the rigid motions on the coarse space (the near-null space a
/// coarse algebraic multigrid needs).
pub struct TwoLevel<'p> {
    pub interpolation: Mat<'p>,
    pub coarse_rigid: Vec<Vector<'p>>,
    /// Global number of coarse DOFs (3 per vertex).
    pub coarse_dofs: usize,
}

/// For each node (original numbering): `None` for a vertex, or the two vertices of the edge it is
/// the midpoint of. `None` everywhere on a P1 mesh.
pub fn edge_parents(mesh: &TetMesh) -> Vec<Option<[usize; 2]>> {
    let mut parents = vec![None; mesh.n_nodes()];
    if mesh.order != ElementOrder::Quadratic {
        return parents;
    }
    for e in 0..mesh.n_tets() {
        let t = mesh.tet(e);
        for (k, &(a, b)) in TET10_EDGES.iter().enumerate() {
            parents[t[4 + k]].get_or_insert([t[a], t[b]]);
        }
    }
    parents
}

/// The coarse index of every vertex, in the P2 (new) numbering: `coarse[new]` is `Some(i)` for a
/// vertex, numbered in increasing `new` order (so each rank's coarse indices are contiguous).
fn coarse_numbering(
    layout: &DofLayout,
    parents: &[Option<[usize; 2]>],
) -> (Vec<Option<usize>>, Vec<usize>) {
    let n = layout.n_nodes();
    let mut coarse = vec![None; n];
    let mut offsets = vec![0usize];
    let mut next = 0;
    for r in 0..layout.partition.n_parts() {
        for new in layout.partition.owned_range(r) {
            if parents[layout.partition.old_of_new[new]].is_none() {
                coarse[new] = Some(next);
                next += 1;
            }
        }
        offsets.push(next);
    }
    (coarse, offsets)
}

/// This rank's rows of Π in CSR form, with global coarse column indices (module docs). Pure:
/// no PETSc (tested directly). Returns (row_ptr, cols, values, local coarse vertices, global
/// coarse vertices).
pub fn interpolation_csr(
    mesh: &TetMesh,
    layout: &DofLayout,
) -> (Vec<PetscInt>, Vec<PetscInt>, Vec<f64>, usize, usize) {
    let parents = edge_parents(mesh);
    let (coarse, offsets) = coarse_numbering(layout, &parents);
    let owned = layout.owned_nodes();
    let mut row_ptr = Vec::with_capacity(3 * owned.len() + 1);
    let mut cols = Vec::with_capacity(6 * owned.len());
    let mut values = Vec::with_capacity(6 * owned.len());
    row_ptr.push(0);
    for new in owned {
        let old = layout.partition.old_of_new[new];
        let entries: Vec<(usize, f64)> = match parents[old] {
            None => vec![(coarse[new].expect("a vertex has a coarse index"), 1.0)],
            Some([a, b]) => {
                let (ca, cb) = (
                    coarse[layout.partition.new_of_old[a]].expect("an edge ends at vertices"),
                    coarse[layout.partition.new_of_old[b]].expect("an edge ends at vertices"),
                );
                let (lo, hi) = (ca.min(cb), ca.max(cb));
                vec![(lo, 0.5), (hi, 0.5)]
            }
        };
        for c in 0..3 {
            for &(j, w) in &entries {
                cols.push((3 * j + c) as PetscInt);
                values.push(w);
            }
            row_ptr.push(cols.len() as PetscInt);
        }
    }
    let rank = layout.rank;
    (
        row_ptr,
        cols,
        values,
        offsets[rank + 1] - offsets[rank],
        *offsets.last().expect("one offset per rank and a start"),
    )
}

/// Builds Π (distributed like `like`'s rows) and the coarse rigid motions, evaluated at the
/// vertices with the same centroid and scale as [`super::rigid_body_vectors`].
pub fn two_level<'p>(
    petsc: &'p Petsc,
    mesh: &TetMesh,
    layout: &DofLayout,
) -> Result<TwoLevel<'p>, PetscError> {
    if mesh.order != ElementOrder::Quadratic {
        return Err(PetscError::other(
            "the p-multigrid preconditioner needs a P2 (10-node) mesh",
        ));
    }
    let (row_ptr, cols, values, local_vertices, vertices) = interpolation_csr(mesh, layout);
    let interpolation = Mat::from_csr_rectangular(
        petsc,
        (3 * layout.owned_nodes().len(), layout.n_dofs()),
        (3 * local_vertices, 3 * vertices),
        3,
        &row_ptr,
        &cols,
        &values,
    )?;
    // The vertices this rank owns, in coarse order (= increasing new index).
    let parents = edge_parents(mesh);
    let points: Vec<[f64; 3]> = layout
        .owned_nodes()
        .map(|new| layout.partition.old_of_new[new])
        .filter(|&old| parents[old].is_none())
        .map(|old| mesh.nodes[old])
        .collect();
    let frame = super::RigidFrame::of(&mesh.nodes);
    let (coarse_vector, _) = interpolation.create_vectors()?;
    let mut coarse_rigid = Vec::with_capacity(6);
    for motion in 0..6 {
        let local: Vec<f64> = points
            .iter()
            .flat_map(|&x| frame.motion(motion, x))
            .collect();
        let mut v = coarse_vector.duplicate()?;
        v.set_local_values(&local)?;
        coarse_rigid.push(v);
    }
    Ok(TwoLevel {
        interpolation,
        coarse_rigid,
        coarse_dofs: 3 * vertices,
    })
}

#[cfg(test)]
mod tests;
