//! Distributed assembly of the mass and the Lamé-split stiffness into PETSc matrices.
//!
//! With `N_a` the (P1 or P2) shape functions and dof `3·node + component`,
//!
//! ```text
//!   M₁ = Σ_e ∫_e N_a N_b δ_kl dV                [m³]           (unit density; M = ρ·M₁ in kg)
//!   K_λ = Σ_e ∫_e (∇·N_a e_k)(∇·N_b e_l) dV     [m]
//!   K_μ = Σ_e ∫_e 2 ε(N_a e_k) : ε(N_b e_l) dV  [m]
//!   K   = λ·K_λ + μ·K_μ                         [N/m]          (λ, μ Lamé parameters in Pa)
//! ```
//!
//! Keeping K split makes ∂K/∂E = (∂λ/∂E)·K_λ + (∂μ/∂E)·K_μ (and likewise for ν) exact.
//!
//! **Parallel layout.** Every rank reads the whole mesh and computes the same RCB
//! [`partition::NodePartition`]; rank r owns the rows of its nodes (3 per node, block size 3).
//! Rank r evaluates every element that touches one of its nodes and keeps only the rows it owns,
//! so its rows are complete without any communication; elements on a partition interface are
//! evaluated by each rank they touch (a few per cent of the work on compact RCB parts).
//!
//! **Exact preallocation.** The sparsity pattern is built first: for each owned node, the sorted
//! list of nodes it shares an element with. Element blocks are then added straight into a local
//! CSR array at positions found by binary search in that list, and PETSc receives pattern and
//! values together (`MatMPIAIJSetPreallocationCSR`). Allocation errors are turned on, and
//! [`AssemblyStats::mallocs`] reports PETSc's own malloc count (0: the pattern was exact).

pub mod partition;

use crate::fem::{ElementError, ElementKernel, ElementMatrices, Material};
use crate::mesh::TetMesh;
use crate::petsc::{self, Mat, NonzeroPattern, Petsc, PetscError, PetscInt};
pub use partition::{partition_nodes, NodePartition};

#[derive(Debug, thiserror::Error)]
pub enum AssemblyError {
    #[error("element {element} (0-based, in file order): {source}")]
    Element {
        element: usize,
        source: ElementError,
    },
    #[error("{0}")]
    Petsc(#[from] PetscError),
    #[error("the mesh has {0} degrees of freedom, more than PETSc's 32-bit indices can address")]
    TooLarge(usize),
}

/// How the unknowns are laid out over the ranks.
#[derive(Clone, Debug)]
pub struct DofLayout {
    pub partition: NodePartition,
    pub rank: usize,
}

impl DofLayout {
    pub fn n_nodes(&self) -> usize {
        self.partition.new_of_old.len()
    }
    pub fn n_dofs(&self) -> usize {
        3 * self.n_nodes()
    }
    /// Owned nodes in the new (PETSc) numbering.
    pub fn owned_nodes(&self) -> std::ops::Range<usize> {
        self.partition.owned_range(self.rank)
    }
    /// Global PETSc row of component `c` of original node `node`.
    pub fn global_dof(&self, node: usize, c: usize) -> usize {
        3 * self.partition.new_of_old[node] + c
    }
    /// Reorders a full vector from PETSc order into original node order (node-major x,y,z).
    pub fn to_original_order(&self, petsc_order: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; petsc_order.len()];
        for (old, &new) in self.partition.new_of_old.iter().enumerate() {
            out[3 * old..3 * old + 3].copy_from_slice(&petsc_order[3 * new..3 * new + 3]);
        }
        out
    }
    /// Every vector gathered to rank 0 and reordered into original node order; empty on the
    /// other ranks. Collective: every rank must call it with the same vectors.
    pub fn gather_original_order(&self, vectors: &[petsc::Vector]) -> petsc::Result<Vec<Vec<f64>>> {
        let mut out = Vec::new();
        for v in vectors {
            if let Some(full) = v.gather_to_root(self.rank)? {
                out.push(self.to_original_order(&full));
            }
        }
        Ok(out)
    }
    /// Reorders a full vector from original node order into PETSc order (the inverse of
    /// [`Self::to_original_order`]); a rank's owned entries are its ownership range of it.
    pub fn to_petsc_order(&self, original_order: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; original_order.len()];
        for (old, &new) in self.partition.new_of_old.iter().enumerate() {
            out[3 * new..3 * new + 3].copy_from_slice(&original_order[3 * old..3 * old + 3]);
        }
        out
    }
}

#[derive(Clone, Debug, Default)]
pub struct AssemblyStats {
    pub n_dofs: usize,
    pub local_elements: usize,
    pub curved_elements: usize,
    /// Nonzeros of one matrix, summed over ranks.
    pub nonzeros: f64,
    /// Mallocs PETSc needed during assembly, summed over ranks and the three matrices.
    pub mallocs: f64,
    pub seconds: f64,
}

/// The three assembled matrices. They share one nonzero pattern.
pub struct Assembled<'p> {
    /// M₁, the mass matrix for unit density.
    pub mass_unit: Mat<'p>,
    pub k_lambda: Mat<'p>,
    pub k_mu: Mat<'p>,
    pub layout: DofLayout,
    pub stats: AssemblyStats,
}

impl<'p> Assembled<'p> {
    /// K = λK_λ + μK_μ and M = ρM₁ as new matrices, keeping the split parts.
    pub fn operators(&self, material: &Material) -> Result<(Mat<'p>, Mat<'p>), PetscError> {
        let mut k = self.k_lambda.duplicate()?;
        k.scale(material.lame_lambda())?;
        k.axpy(material.lame_mu(), &self.k_mu, NonzeroPattern::Same)?;
        let mut m = self.mass_unit.duplicate()?;
        m.scale(material.density)?;
        k.set_symmetric()?;
        m.set_symmetric()?;
        Ok((k, m))
    }
}

/// Adds `values[c]` to diagonal entry (3n + c) of every node n of `nodes` (original numbering)
/// and assembles: lumped point masses on M, point springs on K. Rank 0 inserts (each entry
/// once), every rank assembles (collective). The diagonal is in every P2 pattern.
pub fn add_nodal_diagonal(
    petsc: &Petsc,
    mat: &mut Mat<'_>,
    layout: &DofLayout,
    nodes: &[usize],
    values: [f64; 3],
) -> Result<(), PetscError> {
    if petsc.rank() == 0 {
        for &n in nodes {
            for (c, &v) in values.iter().enumerate() {
                let dof = layout.global_dof(n, c) as PetscInt;
                mat.add_values(&[dof], &[dof], &[v])?;
            }
        }
    }
    mat.assemble()
}

/// The one rank that owns element `e` for element-wise sums that must count each element once
/// (e.g. shape gradients): the owner of its first corner node.
pub fn element_owner(mesh: &TetMesh, partition: &NodePartition, e: usize) -> usize {
    partition.owner_of_new(partition.new_of_old[mesh.tet(e)[0]])
}

/// Sparsity of this rank's rows: for each owned node (new numbering), the sorted new ids of
/// every node it shares an element with; and the elements that touch an owned node.
pub struct LocalPattern {
    pub owned: std::ops::Range<usize>,
    pub neighbours: Vec<Vec<u32>>,
    pub elements: Vec<usize>,
}

pub fn local_pattern(mesh: &TetMesh, partition: &NodePartition, rank: usize) -> LocalPattern {
    let owned = partition.owned_range(rank);
    let npt = mesh.nodes_per_tet();
    let mut neighbours: Vec<Vec<u32>> = vec![Vec::new(); owned.len()];
    let mut elements = Vec::new();
    let mut new_ids = vec![0u32; npt];
    for e in 0..mesh.n_tets() {
        let mut touches = false;
        for (k, &old) in mesh.tet(e).iter().enumerate() {
            new_ids[k] = partition.new_of_old[old] as u32;
            touches |= owned.contains(&(new_ids[k] as usize));
        }
        if !touches {
            continue;
        }
        elements.push(e);
        for &a in &new_ids {
            let a = a as usize;
            if owned.contains(&a) {
                neighbours[a - owned.start].extend_from_slice(&new_ids);
            }
        }
    }
    for list in &mut neighbours {
        list.sort_unstable();
        list.dedup();
    }
    LocalPattern {
        owned,
        neighbours,
        elements,
    }
}

/// Per-row nonzero counts (diagonal block, off-diagonal block) for this rank's rows.
pub fn preallocation(
    mesh: &TetMesh,
    partition: &NodePartition,
    rank: usize,
) -> (Vec<PetscInt>, Vec<PetscInt>) {
    let pattern = local_pattern(mesh, partition, rank);
    let owned = pattern.owned;
    let mut diag = Vec::with_capacity(3 * owned.len());
    let mut offdiag = Vec::with_capacity(3 * owned.len());
    for list in &pattern.neighbours {
        let inside = list
            .iter()
            .filter(|&&b| owned.contains(&(b as usize)))
            .count();
        let outside = list.len() - inside;
        for _ in 0..3 {
            diag.push(3 * inside as PetscInt);
            offdiag.push(3 * outside as PetscInt);
        }
    }
    (diag, offdiag)
}

/// This rank's rows of the three matrices in CSR form (shared pattern, three value arrays).
pub struct LocalCsr {
    pub row_ptr: Vec<PetscInt>,
    pub cols: Vec<PetscInt>,
    pub mass: Vec<f64>,
    pub k_lambda: Vec<f64>,
    pub k_mu: Vec<f64>,
    pub elements_evaluated: usize,
    pub curved_elements: usize,
}

/// Evaluates the element kernels of every element touching an owned node and sums the owned
/// rows into CSR arrays. Pure and serial: no PETSc, no MPI (tested directly).
pub fn assemble_local_csr(
    mesh: &TetMesh,
    partition: &NodePartition,
    rank: usize,
) -> Result<LocalCsr, AssemblyError> {
    let LocalPattern {
        owned,
        neighbours,
        elements,
    } = local_pattern(mesh, partition, rank);
    // Row 3a+c of owned node a holds the columns 3b+d of its neighbours b, in sorted order.
    let mut node_base = Vec::with_capacity(owned.len() + 1);
    let mut acc = 0usize;
    for list in &neighbours {
        node_base.push(acc);
        acc += 9 * list.len();
    }
    node_base.push(acc);
    let nnz = acc;
    petsc::to_petsc_int(nnz).map_err(|_| AssemblyError::TooLarge(nnz))?;
    let mut row_ptr = Vec::with_capacity(3 * owned.len() + 1);
    let mut cols: Vec<PetscInt> = Vec::with_capacity(nnz);
    for list in &neighbours {
        for _ in 0..3 {
            row_ptr.push(cols.len() as PetscInt);
            for &b in list {
                let b = 3 * b as PetscInt;
                cols.extend_from_slice(&[b, b + 1, b + 2]);
            }
        }
    }
    row_ptr.push(cols.len() as PetscInt);
    let mut mass = vec![0.0; nnz];
    let mut k_lambda = vec![0.0; nnz];
    let mut k_mu = vec![0.0; nnz];

    let npt = mesh.nodes_per_tet();
    let n = 3 * npt;
    // One kernel serves straight and curved elements alike: it switches to the higher-degree
    // rule for elements whose mid-edge nodes are off the chord midpoints.
    let kernel = ElementKernel::try_new(npt, false)
        .map_err(|source| AssemblyError::Element { element: 0, source })?;
    let mut em = ElementMatrices::zeros(npt);
    let mut coords = vec![[0.0; 3]; npt];
    let mut new_ids = vec![0u32; npt];
    let mut curved_elements = 0;
    for &e in &elements {
        let tet = mesh.tet(e);
        for (k, &node) in tet.iter().enumerate() {
            coords[k] = mesh.nodes[node];
            new_ids[k] = partition.new_of_old[node] as u32;
        }
        if npt == 10 && crate::fem::is_curved(&coords) {
            curved_elements += 1;
        }
        kernel
            .matrices_into(&coords, &mut em)
            .map_err(|source| AssemblyError::Element { element: e, source })?;
        for a in 0..npt {
            let node_a = new_ids[a] as usize;
            if !owned.contains(&node_a) {
                continue;
            }
            let local_a = node_a - owned.start;
            let list = &neighbours[local_a];
            let row_len = 3 * list.len();
            for (b, id) in new_ids.iter().enumerate().take(npt) {
                let j = list
                    .binary_search(id)
                    .expect("pattern contains every element neighbour");
                for c in 0..3 {
                    let dst = node_base[local_a] + c * row_len + 3 * j;
                    let src = (3 * a + c) * n + 3 * b;
                    for d in 0..3 {
                        mass[dst + d] += em.mass[src + d];
                        k_lambda[dst + d] += em.k_lambda[src + d];
                        k_mu[dst + d] += em.k_mu[src + d];
                    }
                }
            }
        }
    }
    Ok(LocalCsr {
        row_ptr,
        cols,
        mass,
        k_lambda,
        k_mu,
        elements_evaluated: elements.len(),
        curved_elements,
    })
}

/// Assembles M₁, K_λ and K_μ for `mesh` (P1 or P2, as given) over all ranks of `petsc`.
pub fn assemble<'p>(petsc: &'p Petsc, mesh: &TetMesh) -> Result<Assembled<'p>, AssemblyError> {
    let start = std::time::Instant::now();
    let (layout, mut csr) = local_csr(petsc, mesh)?;
    // Each value array is released as soon as PETSc holds its copy: the peak is the pattern,
    // three value arrays and one PETSc matrix, not three of each.
    let mass = matrix_from(petsc, &layout, &mut csr, |c| &mut c.mass)?;
    let k_lambda = matrix_from(petsc, &layout, &mut csr, |c| &mut c.k_lambda)?;
    let k_mu = matrix_from(petsc, &layout, &mut csr, |c| &mut c.k_mu)?;
    let stats = finish(&layout, &csr, &[&mass, &k_lambda, &k_mu], start)?;
    drop(csr);
    release_freed_heap();
    Ok(Assembled {
        mass_unit: mass,
        k_lambda,
        k_mu,
        layout,
        stats,
    })
}

/// The layout of this rank's rows and their local CSR arrays (the shared start of
/// [`assemble`] and [`assemble_operators`]).
fn local_csr(petsc: &Petsc, mesh: &TetMesh) -> Result<(DofLayout, LocalCsr), AssemblyError> {
    let n_dofs = 3 * mesh.n_nodes();
    petsc::to_petsc_int(n_dofs).map_err(|_| AssemblyError::TooLarge(n_dofs))?;
    let rank = petsc.rank();
    let partition = partition_nodes(&mesh.nodes, petsc.size());
    let csr = assemble_local_csr(mesh, &partition, rank)?;
    Ok((DofLayout { partition, rank }, csr))
}

/// A PETSc matrix on `csr`'s pattern with the value array `pick` chooses, which is taken out of
/// `csr` and freed once PETSc holds its copy.
fn matrix_from<'p>(
    petsc: &'p Petsc,
    layout: &DofLayout,
    csr: &mut LocalCsr,
    pick: fn(&mut LocalCsr) -> &mut Vec<f64>,
) -> Result<Mat<'p>, PetscError> {
    let values = std::mem::take(pick(csr));
    Mat::from_csr(petsc, layout.n_dofs(), 3, &csr.row_ptr, &csr.cols, &values)
}

/// The statistics of an assembly that made `mats` from `csr`, begun at `start`.
fn finish(
    layout: &DofLayout,
    csr: &LocalCsr,
    mats: &[&Mat<'_>],
    start: std::time::Instant,
) -> Result<AssemblyStats, PetscError> {
    let mut nonzeros = 0.0;
    let mut mallocs = 0.0;
    for (i, m) in mats.iter().enumerate() {
        let (nz, mal) = m.global_info()?;
        if i == 0 {
            nonzeros = nz;
        }
        mallocs += mal;
    }
    Ok(AssemblyStats {
        n_dofs: layout.n_dofs(),
        local_elements: csr.elements_evaluated,
        curved_elements: csr.curved_elements,
        nonzeros,
        mallocs,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// K = λK_λ + μK_μ and M = ρM₁ for `material` only, without the split parts (a forward run that
/// asks for no sensitivities): K is combined in the local CSR arrays, so at no time do more than
/// the pattern, two value arrays and one PETSc matrix coexist. Same values as
/// [`Assembled::operators`] up to rounding.
pub fn assemble_operators<'p>(
    petsc: &'p Petsc,
    mesh: &TetMesh,
    material: &Material,
) -> Result<(Mat<'p>, Mat<'p>, DofLayout, AssemblyStats), AssemblyError> {
    let start = std::time::Instant::now();
    let (layout, mut csr) = local_csr(petsc, mesh)?;
    let (lambda, mu, rho) = (material.lame_lambda(), material.lame_mu(), material.density);
    let k_mu = std::mem::take(&mut csr.k_mu);
    for (k, kmu) in csr.k_lambda.iter_mut().zip(&k_mu) {
        *k = lambda * *k + mu * kmu;
    }
    drop(k_mu);
    csr.mass.iter_mut().for_each(|v| *v *= rho);
    let mut m = matrix_from(petsc, &layout, &mut csr, |c| &mut c.mass)?;
    let mut k = matrix_from(petsc, &layout, &mut csr, |c| &mut c.k_lambda)?;
    k.set_symmetric()?;
    m.set_symmetric()?;
    let stats = finish(&layout, &csr, &[&m, &k], start)?;
    drop(csr);
    release_freed_heap();
    Ok((k, m, layout, stats))
}

/// Hands the heap memory freed by assembly (the pattern lists, the element work arrays, the
/// mesh's P2 lifting) back to the operating system. glibc keeps freed small blocks in its heap,
/// and the millions of per-node lists of a large mesh leave gigabytes there that the solve would
/// otherwise never see returned (measured at 3M DOF: 13.2 GB summed RSS after assembly, where the
/// two matrices take 6.2 GB).
fn release_freed_heap() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only returns free pages to the kernel; it touches no live allocation.
    unsafe {
        libc::malloc_trim(0);
    }
}
