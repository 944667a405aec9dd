//! Exact gradients of every mode: material parameters and node positions.
//!
//! For a mass-normalised mode (K φ = λ M φ, φᵀMφ = 1) and any parameter p,
//!
//! ```text
//!   dλ/dp = φᵀ (∂K/∂p − λ ∂M/∂p) φ            [rad²/s² per unit of p]
//! ```
//!
//! **Material.** K = λ_L(E,ν)·K_λ + μ(E,ν)·K_μ and M = ρ·M₁, so with the assembled K_λ, K_μ:
//! dλ/dE = φᵀ(∂λ_L/∂E·K_λ + ∂μ/∂E·K_μ)φ, dλ/dν likewise, dλ/dρ = −λ·φᵀM₁φ = −λ/ρ. Each needs two
//! distributed mat-vecs per mode, no new factorisation. Since λ_L and μ are both ∝ E at fixed ν,
//! dλ/dE = λ/E exactly; the tests use that as one check among the finite differences.
//!
//! **Node positions.** dλ/dx is evaluated element by element with the analytic kernel
//! [`crate::fem::SensitivityKernel`] (the derivative of exactly what assembly integrates); no
//! global ∂K/∂x is ever formed. Each rank evaluates the elements it owns in assembly
//! ([`crate::assembly::element_owner`]) after one scatter that brings it the mode values of those
//! elements' nodes (owned plus ghosts), and the per-node sums are reduced onto rank 0. The cost is
//! about one assembly per 25 modes (the kernel's batched cost).
//!
//! **(Near-)degenerate clusters.** Where modes i ∈ C have (nearly) equal eigenvalues, individual
//! derivatives are not defined: the basis inside the cluster is arbitrary and two modes may swap
//! order under a tiny perturbation. We therefore report, for every mode of a cluster, the
//! derivative of the **cluster mean** λ̄_C = (1/|C|)Σ_{i∈C} λ_i, which is (1/|C|)·Σ_i
//! φ_iᵀ(∂K − λ_i∂M)φ_i: a symmetric function of the cluster, smooth as long as the cluster stays
//! apart from its neighbours, so an optimiser never sees a gradient jump because two modes
//! swapped. Beside it, for material parameters, we give the **split derivatives**: the
//! eigenvalues of the |C|×|C| matrix D_p = Φ_Cᵀ(∂K/∂p − λ̄_C ∂M/∂p)Φ_C, which are the one-sided
//! derivatives of the individual eigenvalues of an exactly degenerate cluster. Clusters are
//! the ones found by [`super::find_clusters`] with the solve's `cluster_rtol` (default 10⁻²).
//!
//! **Chain to what is heard.** f = √λ/2π gives df/dλ = 1/(4π√λ). Under Rayleigh damping
//! (C = αM + βK) a mode decays at d = (α + βλ)/2 [1/s] and rings at ω_d = √(λ − d²) [rad/s]:
//! dd/dλ = β/2, dω_d/dλ = (1 − βd)/(2ω_d), dd/dα = ½, dd/dβ = λ/2, dω_d/dα = −d/(2ω_d),
//! dω_d/dβ = −dλ/(2ω_d). See [`damped_chain`].

use super::Modes;
use crate::assembly::{element_owner, DofLayout};
use crate::fem::{ElasticCoefficients, Material, SensitivityKernel};
use crate::mesh::TetMesh;
use crate::petsc::{Mat, Petsc, PetscError, PetscInt};

/// Derivatives of the eigenvalues with respect to E [Pa], ν and ρ [kg/m³].
#[derive(Clone, Debug, Default)]
pub struct MaterialSensitivities {
    /// dλ_i/dE [rad²/s²/Pa]; cluster-mean derivative for clustered modes.
    pub d_youngs: Vec<f64>,
    /// dλ_i/dν [rad²/s²].
    pub d_poisson: Vec<f64>,
    /// dλ_i/dρ [rad²/s²/(kg/m³)].
    pub d_density: Vec<f64>,
    /// The same derivatives for each mode on its own (undefined inside a cluster; kept for
    /// inspection and for the finite-difference tests of well separated modes).
    pub per_mode_youngs: Vec<f64>,
    pub per_mode_poisson: Vec<f64>,
    pub per_mode_density: Vec<f64>,
    /// Split derivatives of each cluster (eigenvalues of D_p, ascending).
    pub clusters: Vec<ClusterSplit>,
}

#[derive(Clone, Debug)]
pub struct ClusterSplit {
    pub modes: std::ops::Range<usize>,
    pub d_youngs: Vec<f64>,
    pub d_poisson: Vec<f64>,
    pub d_density: Vec<f64>,
}

/// dλ/dE, dλ/dν, dλ/dρ for every mode, from the split stiffness K_λ, K_μ and unit mass M₁.
pub fn material_sensitivities<'p>(
    k_lambda: &Mat<'p>,
    k_mu: &Mat<'p>,
    mass_unit: &Mat<'p>,
    modes: &Modes<'p>,
    material: &Material,
) -> Result<MaterialSensitivities, PetscError> {
    let n = modes.eigenvalues.len();
    let (dl_de, dm_de) = material.dlame_dE();
    let (dl_dnu, dm_dnu) = material.dlame_dnu();
    // Gram-type matrices G_λ[i][j] = φ_iᵀK_λφ_j etc. are needed only inside clusters; the
    // diagonal is needed for all modes.
    let in_cluster = |i: usize| modes.clusters.iter().find(|r| r.contains(&i)).cloned();
    let mut w = k_lambda.create_vector()?;
    let mut diag = vec![(0.0, 0.0, 0.0); n]; // (φᵀK_λφ, φᵀK_μφ, φᵀM₁φ)
    let mut blocks: Vec<(std::ops::Range<usize>, Vec<[f64; 3]>)> = modes
        .clusters
        .iter()
        .map(|r| (r.clone(), vec![[0.0; 3]; r.len() * r.len()]))
        .collect();
    for j in 0..n {
        let phi_j = &modes.vectors[j];
        let cluster = in_cluster(j);
        for (slot, mat) in [k_lambda, k_mu, mass_unit].into_iter().enumerate() {
            mat.mult(phi_j, &mut w)?;
            let value = phi_j.dot(&w)?;
            match slot {
                0 => diag[j].0 = value,
                1 => diag[j].1 = value,
                _ => diag[j].2 = value,
            }
            if let Some(r) = &cluster {
                let (_, block) = blocks
                    .iter_mut()
                    .find(|(br, _)| br == r)
                    .expect("cluster block exists");
                for i in r.clone() {
                    let v = if i == j {
                        value
                    } else {
                        modes.vectors[i].dot(&w)?
                    };
                    block[(i - r.start) * r.len() + (j - r.start)][slot] = v;
                }
            }
        }
    }
    let per_mode_youngs: Vec<f64> = diag
        .iter()
        .map(|&(kl, km, _)| dl_de * kl + dm_de * km)
        .collect();
    let per_mode_poisson: Vec<f64> = diag
        .iter()
        .map(|&(kl, km, _)| dl_dnu * kl + dm_dnu * km)
        .collect();
    let per_mode_density: Vec<f64> = diag
        .iter()
        .zip(&modes.eigenvalues)
        .map(|(&(_, _, m1), &l)| -l * m1)
        .collect();
    let mut out = MaterialSensitivities {
        d_youngs: per_mode_youngs.clone(),
        d_poisson: per_mode_poisson.clone(),
        d_density: per_mode_density.clone(),
        per_mode_youngs,
        per_mode_poisson,
        per_mode_density,
        clusters: Vec::new(),
    };
    for (r, block) in blocks {
        let k = r.len();
        let mean_lambda = modes.eigenvalues[r.clone()].iter().sum::<f64>() / k as f64;
        for v in [&mut out.d_youngs, &mut out.d_poisson, &mut out.d_density] {
            let mean = v[r.clone()].iter().sum::<f64>() / k as f64;
            v[r.clone()].iter_mut().for_each(|x| *x = mean);
        }
        let split = |f: &dyn Fn(&[f64; 3]) -> f64| -> Vec<f64> {
            let m = nalgebra::DMatrix::from_fn(k, k, |a, b| {
                0.5 * (f(&block[a * k + b]) + f(&block[b * k + a]))
            });
            let mut e: Vec<f64> = m.symmetric_eigenvalues().iter().copied().collect();
            e.sort_by(f64::total_cmp);
            e
        };
        out.clusters.push(ClusterSplit {
            modes: r.clone(),
            d_youngs: split(&|g| dl_de * g[0] + dm_de * g[1]),
            d_poisson: split(&|g| dl_dnu * g[0] + dm_dnu * g[1]),
            d_density: split(&|g| -mean_lambda * g[2]),
        });
    }
    Ok(out)
}

/// What [`node_gradients`] reports for modes inside a (near-)degenerate cluster.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ClusterTreatment {
    /// Every mode of a cluster gets the gradient of the cluster mean (smooth; for optimisers).
    Mean,
    /// Each mode's own gradient (not smooth inside a cluster; for inspection and tests).
    PerMode,
}

/// dλ_i/dx for every mode and node, on rank 0 (`None` elsewhere): `[mode][3·node + d]` in the
/// original node order [rad²/(s²·m)]. Collective over all ranks.
pub fn node_gradients<'p>(
    petsc: &'p Petsc,
    mesh: &TetMesh,
    layout: &DofLayout,
    modes: &Modes<'p>,
    material: &Material,
    clusters: ClusterTreatment,
) -> Result<Option<Vec<Vec<f64>>>, SensitivityError> {
    let rank = petsc.rank();
    let npt = mesh.nodes_per_tet();
    let m = modes.eigenvalues.len();
    let owned: Vec<usize> = (0..mesh.n_tets())
        .filter(|&e| element_owner(mesh, &layout.partition, e) == rank)
        .collect();
    // Global dofs this rank needs: every dof of every owned element, sorted and unique.
    let mut needed: Vec<PetscInt> = owned
        .iter()
        .flat_map(|&e| {
            mesh.tet(e).iter().flat_map(|&node| {
                (0..3).map(move |c| (3 * layout.partition.new_of_old[node] + c) as PetscInt)
            })
        })
        .collect();
    needed.sort_unstable();
    needed.dedup();
    let mut values = Vec::with_capacity(m);
    for v in &modes.vectors {
        values.push(v.gather_indices(&needed)?);
    }
    let kernel = SensitivityKernel::try_new(npt, false).map_err(|e| SensitivityError::Element {
        element: 0,
        message: e.to_string(),
    })?;
    let coef = ElasticCoefficients::from_material(material);
    let mut local = vec![0.0; m * 3 * mesh.n_nodes()];
    let mut coords = vec![[0.0; 3]; npt];
    let mut phi_e = vec![0.0; m * 3 * npt];
    let mut grad = vec![[0.0; 3]; m * npt];
    let mut pos = vec![0usize; npt];
    // An element that fails on one rank must stop every rank before the reduction below.
    let mut element_loop = || -> Result<(), SensitivityError> {
        for &e in &owned {
            let tet = mesh.tet(e);
            for (a, &node) in tet.iter().enumerate() {
                coords[a] = mesh.nodes[node];
                let g = (3 * layout.partition.new_of_old[node]) as PetscInt;
                pos[a] = needed
                    .binary_search(&g)
                    .expect("owned element dofs were gathered");
            }
            for k in 0..m {
                for a in 0..npt {
                    for c in 0..3 {
                        phi_e[k * 3 * npt + 3 * a + c] = values[k][pos[a] + c];
                    }
                }
            }
            kernel
                .gradients_into(&coords, &phi_e, &modes.eigenvalues, coef, &mut grad, None)
                .map_err(|err| SensitivityError::Element {
                    element: e,
                    message: err.to_string(),
                })?;
            for k in 0..m {
                for (a, &node) in tet.iter().enumerate() {
                    for c in 0..3 {
                        local[k * 3 * mesh.n_nodes() + 3 * node + c] += grad[k * npt + a][c];
                    }
                }
            }
        }
        Ok(())
    };
    let outcome = element_loop();
    crate::petsc::collective::agree(petsc, outcome.map_err(|e| e.to_string()))
        .map_err(SensitivityError::Collective)?;
    let reduced = {
        use mpi::collective::{Root, SystemOperation};
        use mpi::topology::Communicator;
        let root = petsc.world().process_at_rank(0);
        if rank == 0 {
            let mut sum = vec![0.0; local.len()];
            root.reduce_into_root(&local[..], &mut sum[..], SystemOperation::sum());
            Some(sum)
        } else {
            root.reduce_into(&local[..], SystemOperation::sum());
            None
        }
    };
    Ok(reduced.map(|sum| {
        let len = 3 * mesh.n_nodes();
        let mut per_mode: Vec<Vec<f64>> = sum.chunks_exact(len).map(<[f64]>::to_vec).collect();
        let averaged: &[std::ops::Range<usize>] = if clusters == ClusterTreatment::Mean {
            &modes.clusters
        } else {
            &[]
        };
        for r in averaged {
            let mut mean = vec![0.0; len];
            for k in r.clone() {
                mean.iter_mut()
                    .zip(&per_mode[k])
                    .for_each(|(a, b)| *a += b / r.len() as f64);
            }
            for k in r.clone() {
                per_mode[k].clone_from(&mean);
            }
        }
        per_mode
    }))
}

#[derive(Debug, thiserror::Error)]
pub enum SensitivityError {
    #[error("{0}")]
    Petsc(#[from] PetscError),
    #[error("element {element}: {message}")]
    Element { element: usize, message: String },
    /// A failure on some rank, shared by every rank ([`crate::petsc::collective::agree`]).
    #[error("{0}")]
    Collective(String),
}

/// Derivatives of what is heard with respect to λ and the Rayleigh coefficients, for one mode.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DampedChain {
    /// Undamped frequency f [Hz] and df/dλ.
    pub frequency_hz: f64,
    pub dfreq_dlambda: f64,
    /// Damped angular frequency ω_d [rad/s] and its derivatives.
    pub omega_d: f64,
    pub domega_d_dlambda: f64,
    pub domega_d_dalpha: f64,
    pub domega_d_dbeta: f64,
    /// Decay rate d [1/s] and its derivatives.
    pub decay: f64,
    pub ddecay_dlambda: f64,
    pub ddecay_dalpha: f64,
    pub ddecay_dbeta: f64,
}

/// The chain from λ (and α, β) to frequency, damped frequency and decay rate. `None` when the
/// mode is overdamped (d ≥ √λ) and does not ring.
pub fn damped_chain(lambda: f64, alpha: f64, beta: f64) -> Option<DampedChain> {
    if !(lambda > 0.0) {
        return None;
    }
    let omega = lambda.sqrt();
    let decay = 0.5 * (alpha + beta * lambda);
    let wd2 = lambda - decay * decay;
    if !(wd2 > 0.0) {
        return None;
    }
    let omega_d = wd2.sqrt();
    Some(DampedChain {
        frequency_hz: omega / (2.0 * std::f64::consts::PI),
        dfreq_dlambda: 1.0 / (4.0 * std::f64::consts::PI * omega),
        omega_d,
        domega_d_dlambda: (1.0 - beta * decay) / (2.0 * omega_d),
        domega_d_dalpha: -decay / (2.0 * omega_d),
        domega_d_dbeta: -decay * lambda / (2.0 * omega_d),
        decay,
        ddecay_dlambda: 0.5 * beta,
        ddecay_dalpha: 0.5,
        ddecay_dbeta: 0.5 * lambda,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn damped_chain_matches_finite_differences() {
        let (l, a, b) = (4.0e8, 6.0, 1e-7);
        let c = damped_chain(l, a, b).unwrap();
        let f = |l: f64, a: f64, b: f64| damped_chain(l, a, b).unwrap();
        let rel = |x: f64, y: f64| (x - y).abs() / y.abs().max(1e-300);
        let h = 1e-6;
        let fd =
            |g: &dyn Fn(f64) -> f64, x: f64| (g(x * (1.0 + h)) - g(x * (1.0 - h))) / (2.0 * x * h);
        // ω_d barely moves with α or β (relative 1e-13 at h = 1e-6), so those use a larger step.
        let h_damp = 1e-3;
        let fd_damp = |g: &dyn Fn(f64) -> f64, x: f64| {
            (g(x * (1.0 + h_damp)) - g(x * (1.0 - h_damp))) / (2.0 * x * h_damp)
        };
        assert!(rel(fd(&|x| f(x, a, b).frequency_hz, l), c.dfreq_dlambda) < 1e-7);
        assert!(rel(fd(&|x| f(x, a, b).omega_d, l), c.domega_d_dlambda) < 1e-7);
        assert!(rel(fd_damp(&|x| f(l, x, b).omega_d, a), c.domega_d_dalpha) < 1e-5);
        assert!(rel(fd_damp(&|x| f(l, a, x).omega_d, b), c.domega_d_dbeta) < 1e-5);
        assert!(rel(fd(&|x| f(x, a, b).decay, l), c.ddecay_dlambda) < 1e-7);
        assert!(rel(fd(&|x| f(l, x, b).decay, a), c.ddecay_dalpha) < 1e-7);
        assert!(rel(fd(&|x| f(l, a, x).decay, b), c.ddecay_dbeta) < 1e-7);
        assert!(damped_chain(1.0, 10.0, 0.0).is_none(), "overdamped");
        assert!(damped_chain(0.0, 1.0, 0.0).is_none());
    }
}
