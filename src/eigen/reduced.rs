//! A reduced basis in Poisson's ratio: eigenvalues for any E, ρ, ν at almost no cost.
//!
//! With K = λ_L K_λ + μ K_μ and M = ρ M₁, where λ_L = Eν/((1+ν)(1−2ν)) and μ = E/(2(1+ν)),
//!
//! λ_k(E, ν, ρ) = (E/ρ) · θ_k(ν),   θ_k the eigenvalues of (a(ν) K_λ + b(ν) K_μ) x = θ M₁ x
//!
//! with a(ν) = ν/((1+ν)(1−2ν)), b(ν) = 1/(2(1+ν)) [units: θ in rad²/s² per (Pa·m³/kg)]. So E
//! and ρ only scale the spectrum, and only ν needs a basis. We solve the full problem at a few
//! sample values ν_1 … ν_p (each for n + margin modes: modes reorder as ν moves), stack the
//! eigenvectors as V (n_b = p·(n + margin) columns), and project once:
//!
//! G_λ = Vᵀ K_λ V,  G_μ = Vᵀ K_μ V,  G_M = Vᵀ M₁ V   (dense n_b × n_b, the same on every rank)
//!
//! G_M is whitened by its eigen-decomposition, dropping directions below 10⁻¹⁰ of its largest
//! eigenvalue (modes at nearby ν are nearly parallel): W = Q Λ^(−½), A_• = Wᵀ G_• W. Then for
//! any ν the Ritz values are the eigenvalues of the small symmetric matrix a(ν)A_λ + b(ν)A_μ
//! (a dense solve, ~1 ms), with exact derivatives of the reduced problem
//! dθ_k/dν = z_kᵀ (a'(ν) A_λ + b'(ν) A_μ) z_k.
//!
//! The computed modes carry a trace of the rigid-body motions (θ = 0) from the shift-invert
//! solve. Two samples at nearby ν give nearly parallel vectors, and whitening their difference
//! can leave a direction made mostly of that trace: a spurious Ritz value near 0 (seen on the
//! bowl under 2 ranks after a sample at ν = 0.176 joined one at 0.2). Ritz values below 10⁻²
//! of the lowest elastic θ met in any sample's full solve are therefore discarded; no elastic
//! mode of the body lies there.
//!
//! Ritz values are upper bounds that are exact at the samples; between them their error is
//! quadratic in the eigenvector error. [`PoissonBasis::residuals`] measures, for the Ritz pair
//! (θ, x = V W z), the relative residual ‖(aK_λ + bK_μ)x − θM₁x‖₂ / (θ ‖M₁x‖₂) with three
//! distributed mat-vecs per mode: the error estimate a fit uses to decide whether to add the
//! current ν as a new sample ([`PoissonBasis::add_sample`], one full solve). A fit reports the
//! agreement with a full solve at its optimum.
//!
//! # Attachment solves on many ranks
//!
//! The loaded line match solves thousands of attachment columns
//! ([`PoissonBasis::attachments_many`]). Through a distributed MUMPS factor each multiple-
//! right-hand-side solve pays PETSc's redistribution of the solution (a scatter built anew per
//! call, its indices sorted: about as much as the solve itself on the 37.6k-DOF tube, 2 ranks),
//! and the distributed solve waits on messages at every level of the elimination tree. While
//! the degrees of freedom times the ranks stay within [`REDUNDANT_ATTACHMENT_DOFS`], each rank
//! therefore holds the whole problem ([`AttachmentPlacement::Redundant`]): sequential copies of
//! K_λ, K_μ, M₁ and of the basis, its own sequential factor, and its share of the groups of
//! loads, solved with no communication; one gather gives every rank every group's
//! projections. The numbers are those of the distributed path up to rounding (the factor's
//! pivot order differs). On the tube, case 019 of generator 2's seed 431, 2 ranks: the 804
//! regions' enrichment took 30.4 s against 52.0 s, MatMatSolve 10.5 s against 33.3 s.

use super::{solve_modes, spectrum_scale, EigenConfig, EigenError, ModeRequest};
use crate::assembly::Assembled;
use crate::petsc::{collective, Dense, Mat, Petsc, PetscError, PetscInt, Vector};
use mpi::collective::{CommunicatorCollectives, SystemOperation};
use nalgebra::{DMatrix, DVector, SymmetricEigen};
use std::cell::OnceCell;
use std::rc::Rc;

/// Extra modes a full solve asks for, so that poorly resolved rigid-body modes it has to drop
/// (see [`PoissonBasis::full_theta`]) do not leave it short.
fn cfg_rigid_spare() -> usize {
    6
}

/// Directions of the basis whose M-norm² is below this fraction of the largest are dropped when
/// whitening (rounding level of the Gram matrices). Samples at nearby ν give nearly parallel
/// vectors whose difference is dominated by the solver's error (rigid-body traces): such a basis
/// gave spurious Ritz values on 2 ranks, at this floor and at 10⁻⁶ alike, so the fits keep their
/// samples well apart (module docs) and check the answer against a full solve.
const WHITENING_FLOOR: f64 = 1e-10;

/// a(ν) = ν/((1+ν)(1−2ν)) and b(ν) = 1/(2(1+ν)): the Lamé parameters for E = 1.
pub fn lame_unit(nu: f64) -> (f64, f64) {
    (nu / ((1.0 + nu) * (1.0 - 2.0 * nu)), 0.5 / (1.0 + nu))
}

/// a'(ν), b'(ν).
pub fn lame_unit_derivative(nu: f64) -> (f64, f64) {
    let d = (1.0 + nu) * (1.0 - 2.0 * nu);
    // d/dν [ν/d] = (d − ν d')/d², d' = (1 − 2ν) − 2(1 + ν) = −1 − 4ν.
    (
        (d - nu * (-1.0 - 4.0 * nu)) / (d * d),
        -0.5 / ((1.0 + nu) * (1.0 + nu)),
    )
}

/// Ritz values at one ν.
#[derive(Clone, Debug)]
pub struct ReducedModes {
    pub poisson_ratio: f64,
    /// θ_k ascending, for E/ρ = 1 [rad²/s² per Pa·m³/kg].
    pub theta: Vec<f64>,
    /// dθ_k/dν.
    pub dtheta_dnu: Vec<f64>,
    /// z_k in whitened coordinates (for shapes and residuals).
    coefficients: Vec<DVector<f64>>,
}

impl ReducedModes {
    /// λ_k = (E/ρ) θ_k [rad²/s²].
    pub fn eigenvalues(&self, youngs: f64, density: f64) -> Vec<f64> {
        self.theta.iter().map(|t| youngs / density * t).collect()
    }

    /// The modes' whitened coordinates z_k as columns (reduced dimension × modes): with
    /// [`AttachmentProjections`] they give the coupling Φᵀ K A = Zᵀ C.
    pub fn coefficient_matrix(&self) -> DMatrix<f64> {
        let rows = self.coefficients.first().map_or(0, |z| z.len());
        let mut z = DMatrix::zeros(rows, self.coefficients.len());
        for (k, c) in self.coefficients.iter().enumerate() {
            z.set_column(k, c);
        }
        z
    }
}

/// Static (attachment) responses to loads, A = P (a K_λ + b K_μ + σ M₁)⁻¹ F at one ν, with
/// the rigid-body motions P projected out and each column M₁-normalised, projected for a Ritz
/// enrichment of the basis (see [`crate::inverse::loaded_match`]): the modal truncation of a
/// concentrated mass misses the local flexibility under it, which these vectors carry.
#[derive(Clone, Debug)]
pub struct AttachmentProjections {
    /// C_• = Wᵀ Vᵀ K_• A (reduced dimension × attachments), for K_λ, K_μ and M₁.
    pub cross_lambda: DMatrix<f64>,
    pub cross_mu: DMatrix<f64>,
    pub cross_mass: DMatrix<f64>,
    /// Aᵀ K_• A (attachments × attachments).
    pub self_lambda: DMatrix<f64>,
    pub self_mu: DMatrix<f64>,
    pub self_mass: DMatrix<f64>,
    /// Values at the basis's probe DOFs (probes × attachments).
    pub probe_values: DMatrix<f64>,
}

/// Per group of a chunk: the cross projections C_• and the own Gram blocks Aᵀ K_• A.
type Projected = (Vec<DMatrix<f64>>, Vec<DMatrix<f64>>);

/// Where [`PoissonBasis::attachment_solver_placed`] puts the attachment problem (module docs,
/// "Attachment solves on many ranks").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AttachmentPlacement {
    /// Redundant on more than one rank while the ranks' copies together stay within
    /// [`REDUNDANT_ATTACHMENT_DOFS`] (degrees of freedom × ranks), else distributed.
    Auto,
    /// One factor over every rank; every rank takes part in every solve.
    Distributed,
    /// The whole problem on every rank, the groups of loads shared out.
    Redundant,
}

/// The most degrees of freedom times ranks for which [`AttachmentPlacement::Auto`] copies the
/// attachment problem to every rank (150k DOF on 2 ranks, 75k on 4): each rank then holds a
/// sequential factor and three sparse matrices of the whole system, so the copies' memory grows
/// with the ranks.
pub const REDUNDANT_ATTACHMENT_DOFS: usize = 300_000;

/// The whole attachment problem on this rank: K_λ, K_μ and M₁ as sequential copies, and every
/// row of every basis vector (global numbering).
struct SequentialOperators<'p> {
    k_lambda: Mat<'p>,
    k_mu: Mat<'p>,
    mass: Mat<'p>,
    basis: Vec<Vec<f64>>,
}

/// K_λ, K_μ and M₁ as the placement holds them: this rank's sequential copies, or the
/// distributed matrices.
fn placed_operators<'a, 'p>(
    sequential: Option<&'a SequentialOperators<'p>>,
    assembled: &'a Assembled<'p>,
) -> (&'a Mat<'p>, &'a Mat<'p>, &'a Mat<'p>) {
    match sequential {
        Some(s) => (&s.k_lambda, &s.k_mu, &s.mass),
        None => (&assembled.k_lambda, &assembled.k_mu, &assembled.mass_unit),
    }
}

/// The factored operator a(ν)K_λ + b(ν)K_μ + σM₁ and the M₁-orthonormal rigid-body motions,
/// for [`PoissonBasis::attachments`].
pub struct AttachmentSolver<'p> {
    solver: crate::petsc::MumpsCholesky<'p>,
    /// The rigid motions: distributed, or whole on this rank when `sequential` is set.
    rigid: Vec<Vector<'p>>,
    /// M₁ times each rigid motion.
    rigid_mass: Vec<Vector<'p>>,
    /// This rank's entries of every basis vector (the projections are local dot products
    /// summed in one reduction); empty when `sequential` is set.
    local_basis: Vec<Vec<f64>>,
    /// Set when each rank holds the whole problem ([`AttachmentPlacement::Redundant`]).
    sequential: Option<Rc<SequentialOperators<'p>>>,
}

/// The basis, its projections, and the probe values of its vectors.
pub struct PoissonBasis<'p> {
    vectors: Vec<Vector<'p>>,
    samples: Vec<f64>,
    n_modes: usize,
    margin: usize,
    /// V W: maps whitened coordinates to coefficients of `vectors`.
    whitening: DMatrix<f64>,
    a_lambda: DMatrix<f64>,
    a_mu: DMatrix<f64>,
    probe_dofs: Vec<PetscInt>,
    /// Values of every basis vector at `probe_dofs` (n_b rows × probes), on every rank.
    probe_values: DMatrix<f64>,
    size: f64,
    /// Ritz values below this are discarded (module docs): 10⁻² × the lowest elastic θ of any
    /// sample's full solve.
    theta_floor: f64,
    /// Full solves done.
    pub full_solves: usize,
    pub full_solve_seconds: f64,
    /// The sequential copies of a redundant attachment solver, made once (reset when the basis
    /// changes).
    sequential: OnceCell<Rc<SequentialOperators<'p>>>,
}

#[derive(Debug, thiserror::Error)]
pub enum ReducedError {
    #[error("{0}")]
    Eigen(#[from] EigenError),
    #[error("{0}")]
    Petsc(#[from] PetscError),
    #[error("{0}")]
    Invalid(String),
}

impl<'p> PoissonBasis<'p> {
    /// Solves at each ν in `samples` for `n_modes + margin` modes and projects. `size` [m] is
    /// the body's size for the solver's spectrum scale; `probe_dofs` are PETSc indices whose
    /// values of each mode [`Self::probe`] returns (e.g. the DOFs of the strike element).
    pub fn build(
        petsc: &'p Petsc,
        assembled: &Assembled<'p>,
        size: f64,
        n_modes: usize,
        margin: usize,
        samples: &[f64],
        probe_dofs: Vec<PetscInt>,
    ) -> Result<Self, ReducedError> {
        if samples.is_empty() || n_modes == 0 {
            return Err(ReducedError::Invalid(
                "a reduced basis needs at least one sample ν and one mode".into(),
            ));
        }
        if let Some(nu) = samples.iter().find(|nu| !(**nu > -0.99 && **nu < 0.499)) {
            return Err(ReducedError::Invalid(format!(
                "sample ν = {nu} outside (−1, 0.5)"
            )));
        }
        let mut basis = PoissonBasis {
            vectors: Vec::new(),
            samples: Vec::new(),
            n_modes,
            margin,
            whitening: DMatrix::zeros(0, 0),
            a_lambda: DMatrix::zeros(0, 0),
            a_mu: DMatrix::zeros(0, 0),
            probe_dofs,
            probe_values: DMatrix::zeros(0, 0),
            size,
            theta_floor: f64::INFINITY,
            full_solves: 0,
            full_solve_seconds: 0.0,
            sequential: OnceCell::new(),
        };
        for &nu in samples {
            basis.solve_and_append(petsc, assembled, nu)?;
        }
        basis.project(petsc, assembled)?;
        Ok(basis)
    }

    pub fn samples(&self) -> &[f64] {
        &self.samples
    }

    /// Columns of the basis before whitening, and the reduced dimension after it.
    pub fn dimensions(&self) -> (usize, usize) {
        (self.vectors.len(), self.whitening.ncols())
    }

    /// Full eigenvalues (E = ρ = 1) at ν by SLEPc, for checks; ascending, first `n`.
    pub fn full_theta(
        petsc: &'p Petsc,
        assembled: &Assembled<'p>,
        size: f64,
        nu: f64,
        n: usize,
    ) -> Result<(Vec<f64>, Vec<Vector<'p>>), ReducedError> {
        let (a, b) = lame_unit(nu);
        let mut k = assembled.k_lambda.duplicate()?;
        k.scale(a)?;
        k.axpy(b, &assembled.k_mu, crate::petsc::NonzeroPattern::Same)?;
        k.set_symmetric()?;
        let mut cfg = EigenConfig::new(
            ModeRequest::FirstN(n + cfg_rigid_spare()),
            spectrum_scale(b, 1.0, size),
        );
        cfg.verify_count = false;
        let modes = solve_modes(petsc, &k, &assembled.mass_unit, &cfg)?;
        let (mut values, mut vectors) = (modes.eigenvalues, modes.vectors);
        // Rigid-body modes the solver resolved poorly land above the rigid threshold (seen on the
        // bowl under 2 ranks: three at 10⁻³–10⁻¹ of the first elastic θ, 221–518 Hz below 1672 Hz).
        // They are the missing ones of the expected six, well below the first elastic mode: drop
        // those under a quarter of it.
        let missing = cfg
            .expected_rigid
            .saturating_sub(modes.rigid_eigenvalues.len())
            .min(values.len().saturating_sub(1));
        let first_elastic = values.get(missing).copied().unwrap_or(0.0);
        let spurious = values
            .iter()
            .take(missing)
            .take_while(|v| **v < 0.25 * first_elastic)
            .count();
        values.drain(..spurious);
        vectors.drain(..spurious);
        values.truncate(n);
        vectors.truncate(n);
        if values.len() < n {
            return Err(ReducedError::Invalid(format!(
                "the full solve at ν = {nu} gave {} elastic modes, {n} wanted",
                values.len()
            )));
        }
        Ok((values, vectors))
    }

    fn solve_and_append(
        &mut self,
        petsc: &'p Petsc,
        assembled: &Assembled<'p>,
        nu: f64,
    ) -> Result<(), ReducedError> {
        let start = std::time::Instant::now();
        let (theta, vectors) =
            Self::full_theta(petsc, assembled, self.size, nu, self.n_modes + self.margin)?;
        if let Some(first) = theta.iter().copied().filter(|t| *t > 0.0).reduce(f64::min) {
            self.theta_floor = self.theta_floor.min(1e-2 * first);
        }
        self.full_solves += 1;
        self.full_solve_seconds += start.elapsed().as_secs_f64();
        self.vectors.extend(vectors);
        self.samples.push(nu);
        Ok(())
    }

    /// Adds the modes at ν (one full solve) and re-projects.
    pub fn add_sample(
        &mut self,
        petsc: &'p Petsc,
        assembled: &Assembled<'p>,
        nu: f64,
    ) -> Result<(), ReducedError> {
        self.solve_and_append(petsc, assembled, nu)?;
        self.project(petsc, assembled)
    }

    fn project(&mut self, petsc: &'p Petsc, assembled: &Assembled<'p>) -> Result<(), ReducedError> {
        self.sequential = OnceCell::new();
        let nb = self.vectors.len();
        let local: Vec<Vec<f64>> = self
            .vectors
            .iter()
            .map(|v| v.local_values())
            .collect::<Result<_, _>>()?;
        let mut work = self.vectors[0].duplicate()?;
        let gram = |mat: &Mat<'p>, work: &mut Vector<'p>| -> Result<DMatrix<f64>, ReducedError> {
            let mut local_gram = vec![0.0; nb * nb];
            for j in 0..nb {
                mat.mult(&self.vectors[j], work)?;
                let aj = work.local_values()?;
                for i in 0..nb {
                    local_gram[i * nb + j] = local[i].iter().zip(&aj).map(|(x, y)| x * y).sum();
                }
            }
            let mut global = vec![0.0; nb * nb];
            petsc
                .world()
                .all_reduce_into(&local_gram[..], &mut global[..], SystemOperation::sum());
            let g = DMatrix::from_row_slice(nb, nb, &global);
            Ok((&g + g.transpose()) * 0.5)
        };
        let g_lambda = gram(&assembled.k_lambda, &mut work)?;
        let g_mu = gram(&assembled.k_mu, &mut work)?;
        let g_mass = gram(&assembled.mass_unit, &mut work)?;
        let eig = SymmetricEigen::new(g_mass);
        let largest = eig.eigenvalues.iter().fold(0.0_f64, |m, v| m.max(*v));
        let kept: Vec<usize> = (0..nb)
            .filter(|&i| eig.eigenvalues[i] > WHITENING_FLOOR * largest)
            .collect();
        let mut w = DMatrix::zeros(nb, kept.len());
        for (c, &i) in kept.iter().enumerate() {
            let scale = 1.0 / eig.eigenvalues[i].sqrt();
            for r in 0..nb {
                w[(r, c)] = eig.eigenvectors[(r, i)] * scale;
            }
        }
        self.a_lambda = w.transpose() * &g_lambda * &w;
        self.a_mu = w.transpose() * &g_mu * &w;
        self.whitening = w;
        // Probe values: each rank asks for all probe DOFs of every vector.
        let mut probe = DMatrix::zeros(nb, self.probe_dofs.len());
        for (i, v) in self.vectors.iter().enumerate() {
            let vals = v.gather_indices(&self.probe_dofs)?;
            for (c, x) in vals.into_iter().enumerate() {
                probe[(i, c)] = x;
            }
        }
        self.probe_values = probe;
        Ok(())
    }

    /// The fits' error check at ν: the largest Ritz residual of the first `n_modes` pairs; if it
    /// exceeds `tolerance` and no sample lies within `min_spacing` of ν, ν is added as a sample
    /// (one full solve). The spacing rule stops a refresh loop where a sample would not help: the
    /// residual measure is pessimistic (a residual of 2·10⁻³ went with eigenvalue errors of
    /// 2·10⁻⁸ against a full solve), and on some meshes it stays above the tolerance right at a
    /// sample. Collective. Returns the largest residual before any refresh.
    pub fn refresh_if_needed(
        &mut self,
        petsc: &'p Petsc,
        assembled: &Assembled<'p>,
        nu: f64,
        tolerance: f64,
        min_spacing: f64,
    ) -> Result<f64, ReducedError> {
        let modes = self.solve(nu);
        let worst = self
            .residuals(assembled, &modes)?
            .into_iter()
            .fold(0.0_f64, f64::max);
        if worst > tolerance && self.samples.iter().all(|s| (s - nu).abs() >= min_spacing) {
            self.add_sample(petsc, assembled, nu)?;
        }
        Ok(worst)
    }

    /// The first `n_modes` Ritz values at ν and their ν-derivatives.
    pub fn solve(&self, nu: f64) -> ReducedModes {
        let (a, b) = lame_unit(nu);
        let (da, db) = lame_unit_derivative(nu);
        let matrix = &self.a_lambda * a + &self.a_mu * b;
        let eig = SymmetricEigen::new((&matrix + matrix.transpose()) * 0.5);
        let floor = if self.theta_floor.is_finite() {
            self.theta_floor
        } else {
            0.0
        };
        let mut order: Vec<usize> = (0..eig.eigenvalues.len())
            .filter(|&i| eig.eigenvalues[i] > floor)
            .collect();
        order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
        let dmatrix = &self.a_lambda * da + &self.a_mu * db;
        let n = self.n_modes.min(order.len());
        let mut theta = Vec::with_capacity(n);
        let mut dtheta = Vec::with_capacity(n);
        let mut coefficients = Vec::with_capacity(n);
        for &i in &order[..n] {
            let z = eig.eigenvectors.column(i).into_owned();
            theta.push(eig.eigenvalues[i]);
            dtheta.push(z.dot(&(&dmatrix * &z)));
            coefficients.push(z);
        }
        ReducedModes {
            poisson_ratio: nu,
            theta,
            dtheta_dnu: dtheta,
            coefficients,
        }
    }

    /// Mode k's values at the probe DOFs (mass-normalised for ρ = 1; divide by √ρ otherwise).
    pub fn probe(&self, modes: &ReducedModes, k: usize) -> Vec<f64> {
        let coeff = &self.whitening * &modes.coefficients[k];
        (0..self.probe_values.ncols())
            .map(|c| self.probe_values.column(c).dot(&coeff))
            .collect()
    }

    /// Every mode's values at the probe DOFs: probes × modes (mass-normalised for ρ = 1).
    pub fn probe_all(&self, modes: &ReducedModes) -> DMatrix<f64> {
        let mut z = DMatrix::zeros(self.whitening.ncols(), modes.coefficients.len());
        for (k, c) in modes.coefficients.iter().enumerate() {
            z.set_column(k, c);
        }
        self.probe_values.transpose() * (&self.whitening * z)
    }

    /// Factors a(ν)K_λ + b(ν)K_μ + σM₁ (σ > 0 makes the free body's operator definite) and
    /// builds the six rigid-body motions of `nodes` (original order), M₁-orthonormalised.
    /// Collective.
    pub fn attachment_solver(
        &self,
        petsc: &'p Petsc,
        assembled: &Assembled<'p>,
        nodes: &[[f64; 3]],
        nu: f64,
        shift: f64,
    ) -> Result<AttachmentSolver<'p>, ReducedError> {
        self.attachment_solver_placed(
            petsc,
            assembled,
            nodes,
            nu,
            shift,
            AttachmentPlacement::Auto,
        )
    }

    /// The sequential copies of K_λ, K_μ, M₁ and of the basis on this rank, made at the first
    /// call. Collective.
    fn sequential_operators(
        &self,
        assembled: &Assembled<'p>,
    ) -> Result<Rc<SequentialOperators<'p>>, ReducedError> {
        if let Some(made) = self.sequential.get() {
            return Ok(made.clone());
        }
        let n = assembled.mass_unit.global_rows()?;
        let every_row: Vec<PetscInt> = (0..n as PetscInt).collect();
        let basis = self
            .vectors
            .iter()
            .map(|v| v.gather_indices(&every_row))
            .collect::<Result<Vec<_>, _>>()?;
        let made = Rc::new(SequentialOperators {
            k_lambda: assembled.k_lambda.sequential_copy()?,
            k_mu: assembled.k_mu.sequential_copy()?,
            mass: assembled.mass_unit.sequential_copy()?,
            basis,
        });
        let _ = self.sequential.set(made.clone());
        Ok(made)
    }

    /// [`Self::attachment_solver`] with the placement chosen (module docs, "Attachment solves on
    /// many ranks"). Collective.
    pub fn attachment_solver_placed(
        &self,
        petsc: &'p Petsc,
        assembled: &Assembled<'p>,
        nodes: &[[f64; 3]],
        nu: f64,
        shift: f64,
        placement: AttachmentPlacement,
    ) -> Result<AttachmentSolver<'p>, ReducedError> {
        if !(shift > 0.0) || nodes.len() != assembled.layout.n_nodes() {
            return Err(ReducedError::Invalid(format!(
                "attachment solver: shift {shift} must be positive and {} nodes given for {}",
                nodes.len(),
                assembled.layout.n_nodes()
            )));
        }
        let n_global = assembled.mass_unit.global_rows()?;
        let redundant = match placement {
            AttachmentPlacement::Auto => {
                petsc.size() > 1 && n_global * petsc.size() <= REDUNDANT_ATTACHMENT_DOFS
            }
            AttachmentPlacement::Distributed => false,
            AttachmentPlacement::Redundant => true,
        };
        if !redundant {
            return self.place_attachment_solver(petsc, assembled, nodes, nu, shift, false);
        }
        // Every rank's copy agreed on (a rank whose own factor failed must not leave the others
        // in a collective); where the copies fail, Auto falls back to the distributed factor.
        let made = self
            .place_attachment_solver(petsc, assembled, nodes, nu, shift, true)
            .map_err(|e| e.to_string());
        match collective::agree(petsc, made) {
            Ok(solver) => Ok(solver),
            Err(_) if placement == AttachmentPlacement::Auto => {
                self.place_attachment_solver(petsc, assembled, nodes, nu, shift, false)
            }
            Err(message) => Err(ReducedError::Invalid(format!(
                "redundant attachment solver: {message}"
            ))),
        }
    }

    fn place_attachment_solver(
        &self,
        petsc: &'p Petsc,
        assembled: &Assembled<'p>,
        nodes: &[[f64; 3]],
        nu: f64,
        shift: f64,
        redundant: bool,
    ) -> Result<AttachmentSolver<'p>, ReducedError> {
        let sequential = if redundant {
            Some(self.sequential_operators(assembled)?)
        } else {
            None
        };
        let (k_lambda, k_mu, mass) = placed_operators(sequential.as_deref(), assembled);
        let (a, b) = lame_unit(nu);
        let mut operator = k_lambda.duplicate()?;
        operator.scale(a)?;
        operator.axpy(b, k_mu, crate::petsc::NonzeroPattern::Same)?;
        operator.axpy(shift, mass, crate::petsc::NonzeroPattern::Subset)?;
        operator.set_symmetric()?;
        let solver = crate::petsc::MumpsCholesky::factor(
            petsc,
            &operator,
            crate::petsc::FactorUse::Solve,
            "attachment operator a(ν)K_λ + b(ν)K_μ + σM₁",
        )
        .map_err(PetscError::from)?;
        let n = nodes.len();
        let centre = nodes.iter().fold([0.0; 3], |acc, x| {
            [
                acc[0] + x[0] / n as f64,
                acc[1] + x[1] / n as f64,
                acc[2] + x[2] / n as f64,
            ]
        });
        let mut rigid: Vec<Vector<'p>> = Vec::with_capacity(6);
        let mut rigid_mass: Vec<Vector<'p>> = Vec::with_capacity(6);
        let template = mass.create_vector()?;
        let (lo, hi) = template.ownership_range()?;
        for motion in 0..6 {
            let mut full = vec![0.0; 3 * n];
            for (i, x) in nodes.iter().enumerate() {
                let r = [x[0] - centre[0], x[1] - centre[1], x[2] - centre[2]];
                let u = match motion {
                    0 => [1.0, 0.0, 0.0],
                    1 => [0.0, 1.0, 0.0],
                    2 => [0.0, 0.0, 1.0],
                    // e_d × r
                    3 => [0.0, -r[2], r[1]],
                    4 => [r[2], 0.0, -r[0]],
                    _ => [-r[1], r[0], 0.0],
                };
                full[3 * i..3 * i + 3].copy_from_slice(&u);
            }
            // This rank's rows of it in PETSc order: every row when the problem is whole here.
            let mut v = template.duplicate()?;
            v.set_local_values(&assembled.layout.to_petsc_order(&full)[lo..hi])?;
            // Modified Gram–Schmidt in the M₁ inner product.
            for (q, mq) in rigid.iter().zip(&rigid_mass) {
                let c = v.dot(mq)?;
                v.axpy(-c, q)?;
            }
            let mut mv = v.duplicate()?;
            mass.mult(&v, &mut mv)?;
            let scale = 1.0 / v.dot(&mv)?.sqrt();
            v.scale(scale)?;
            mv.scale(scale)?;
            rigid.push(v);
            rigid_mass.push(mv);
        }
        let local_basis = if sequential.is_some() {
            Vec::new()
        } else {
            self.vectors
                .iter()
                .map(|v| v.local_values())
                .collect::<Result<_, _>>()?
        };
        Ok(AttachmentSolver {
            solver,
            rigid,
            rigid_mass,
            local_basis,
            sequential,
        })
    }

    /// The six rigid-body motions (M₁-orthonormal, ρ = 1) at the probe DOFs (probes × 6).
    /// Collective.
    pub fn rigid_probe_values(
        &self,
        solver: &AttachmentSolver<'p>,
    ) -> Result<DMatrix<f64>, ReducedError> {
        let mut out = DMatrix::zeros(self.probe_dofs.len(), solver.rigid.len());
        for (j, q) in solver.rigid.iter().enumerate() {
            let values = if solver.sequential.is_some() {
                // Whole on this rank.
                let all = q.local_values()?;
                self.probe_dofs.iter().map(|&d| all[d as usize]).collect()
            } else {
                q.gather_indices(&self.probe_dofs)?
            };
            for (c, x) in values.into_iter().enumerate() {
                out[(c, j)] = x;
            }
        }
        Ok(out)
    }

    /// The attachment vectors of `loads` (each a list of (PETSc DOF, value); a rank uses the
    /// entries it owns) and their projections. With `blocks` > 1, each further block is the
    /// next Krylov term (K + σM₁)⁻¹ M₁ x of the previous one (the inertia of the static
    /// response), treated the same way. Collective: every rank passes the same loads.
    pub fn attachments(
        &self,
        petsc: &'p Petsc,
        assembled: &Assembled<'p>,
        solver: &AttachmentSolver<'p>,
        loads: &[Vec<(PetscInt, f64)>],
        blocks: usize,
    ) -> Result<AttachmentProjections, ReducedError> {
        let mut one = self.attachments_many(
            petsc,
            assembled,
            solver,
            std::slice::from_ref(&loads.to_vec()),
            blocks,
        )?;
        Ok(one.pop().expect("one group in, one out"))
    }

    /// [`Self::attachments`] for many groups of loads at once (one group: one region's loads),
    /// the same numbers as one group at a time. Every right-hand side of a chunk of groups
    /// goes through one multiple-right-hand-side solve, one sparse × dense product per
    /// operator and one reduction: on the 53k-DOF bowl a group of 3 loads and 2 blocks cost
    /// 0.3 s alone (0.18 s in six single solves, 0.09 s in 18 products and their dot
    /// products). Collective: every rank passes the same groups.
    pub fn attachments_many(
        &self,
        petsc: &'p Petsc,
        assembled: &Assembled<'p>,
        solver: &AttachmentSolver<'p>,
        groups: &[Vec<Vec<(PetscInt, f64)>>],
        blocks: usize,
    ) -> Result<Vec<AttachmentProjections>, ReducedError> {
        if solver.sequential.is_some() && petsc.size() > 1 {
            return self.attachments_shared(petsc, assembled, solver, groups, blocks);
        }
        self.attachments_chunked(petsc, assembled, solver, groups, blocks)
    }

    /// The redundant placement's sharing (module docs, "Attachment solves on many ranks"): each
    /// rank solves a contiguous share of the groups, balanced by columns, on its own copy of the
    /// problem; the outcome is agreed on and one gather gives every rank every group's
    /// projections, in order. Collective.
    fn attachments_shared(
        &self,
        petsc: &'p Petsc,
        assembled: &Assembled<'p>,
        solver: &AttachmentSolver<'p>,
        groups: &[Vec<Vec<(PetscInt, f64)>>],
        blocks: usize,
    ) -> Result<Vec<AttachmentProjections>, ReducedError> {
        let (rank, size) = (petsc.rank(), petsc.size());
        let blocks = blocks.max(1);
        let nr = self.whitening.ncols();
        let n_probe = self.probe_dofs.len();
        let length = |g: &Vec<Vec<(PetscInt, f64)>>| {
            let na = g.len() * blocks;
            3 * nr * na + 3 * na * na + n_probe * na
        };
        // Share p holds groups[starts[p]..starts[p + 1]]: the first group whose columns reach
        // p/size of the total starts it.
        let total: usize = groups.iter().map(|g| g.len()).sum();
        let mut starts = vec![0usize; size + 1];
        let mut columns = 0;
        let mut p = 1;
        for (i, g) in groups.iter().enumerate() {
            while p < size && columns * size >= p * total {
                starts[p] = i;
                p += 1;
            }
            columns += g.len();
        }
        while p <= size {
            starts[p] = groups.len();
            p += 1;
        }
        let mine = &groups[starts[rank]..starts[rank + 1]];
        let local = self
            .attachments_chunked(petsc, assembled, solver, mine, blocks)
            .map(|list| {
                let mut flat = Vec::with_capacity(mine.iter().map(length).sum());
                for q in &list {
                    for m in [
                        &q.cross_lambda,
                        &q.cross_mu,
                        &q.cross_mass,
                        &q.self_lambda,
                        &q.self_mu,
                        &q.self_mass,
                        &q.probe_values,
                    ] {
                        flat.extend_from_slice(m.as_slice());
                    }
                }
                flat
            })
            .map_err(|e| e.to_string());
        let local = collective::agree(petsc, local).map_err(ReducedError::Invalid)?;
        let counts: Vec<usize> = (0..size)
            .map(|p| groups[starts[p]..starts[p + 1]].iter().map(length).sum())
            .collect();
        let all = collective::all_gather_varcount(petsc, &local, &counts);
        let mut out = Vec::with_capacity(groups.len());
        let mut at = 0;
        for g in groups {
            let na = g.len() * blocks;
            let mut take = |rows: usize| {
                let m = DMatrix::from_column_slice(rows, na, &all[at..at + rows * na]);
                at += rows * na;
                m
            };
            out.push(AttachmentProjections {
                cross_lambda: take(nr),
                cross_mu: take(nr),
                cross_mass: take(nr),
                self_lambda: take(na),
                self_mu: take(na),
                self_mass: take(na),
                probe_values: take(n_probe),
            });
        }
        Ok(out)
    }

    /// The groups chunk by chunk, on this rank's solver as it is placed.
    fn attachments_chunked(
        &self,
        petsc: &'p Petsc,
        assembled: &Assembled<'p>,
        solver: &AttachmentSolver<'p>,
        groups: &[Vec<Vec<(PetscInt, f64)>>],
        blocks: usize,
    ) -> Result<Vec<AttachmentProjections>, ReducedError> {
        // Columns per chunk: bounds the dense blocks (local rows × columns × blocks) and the
        // probe values reduced at once; the factor blocks its solve by as many.
        const CHUNK_COLUMNS: usize = crate::petsc::factor::SOLVE_RHS_BLOCK;
        let mut out = Vec::with_capacity(groups.len());
        let mut start = 0;
        while start < groups.len() {
            let mut end = start;
            let mut columns = 0;
            while end < groups.len()
                && (end == start || columns + groups[end].len() <= CHUNK_COLUMNS)
            {
                columns += groups[end].len();
                end += 1;
            }
            out.extend(self.attachments_chunk(
                petsc,
                assembled,
                solver,
                &groups[start..end],
                blocks,
            )?);
            start = end;
        }
        Ok(out)
    }

    fn attachments_chunk(
        &self,
        petsc: &'p Petsc,
        assembled: &Assembled<'p>,
        solver: &AttachmentSolver<'p>,
        groups: &[Vec<Vec<(PetscInt, f64)>>],
        blocks: usize,
    ) -> Result<Vec<AttachmentProjections>, ReducedError> {
        let blocks = blocks.max(1);
        let sequential = solver.sequential.as_deref();
        let n_global = assembled.mass_unit.global_rows()?;
        // Whole on this rank, or this rank's rows.
        let (lo, hi) = match sequential {
            Some(_) => (0, n_global),
            None => self.vectors[0].ownership_range()?,
        };
        let n_local = hi - lo;
        let (k_lambda, k_mu, mass) = placed_operators(sequential, assembled);
        let basis_rows: &[Vec<f64>] = match sequential {
            Some(s) => &s.basis,
            None => &solver.local_basis,
        };
        let dense = |cols: usize| match sequential {
            Some(_) => Dense::zeros_sequential(petsc, n_global, cols),
            None => Dense::zeros(petsc, n_local, n_global, cols),
        };
        let n_rhs: usize = groups.iter().map(|g| g.len()).sum();
        if groups.iter().any(|g| g.is_empty()) {
            return Err(ReducedError::Invalid(
                "a group of attachment loads is empty".into(),
            ));
        }
        let world = petsc.world();
        // The sums over ranks of the distributed placement; a rank holding the whole problem has
        // nothing to add.
        let sum = |local: &[f64]| -> Vec<f64> {
            if sequential.is_some() {
                return local.to_vec();
            }
            let mut global = vec![0.0; local.len()];
            world.all_reduce_into(local, &mut global[..], SystemOperation::sum());
            global
        };
        let rigid: Vec<Vec<f64>> = solver
            .rigid
            .iter()
            .map(|v| v.local_values())
            .collect::<Result<_, _>>()?;
        let rigid_mass: Vec<Vec<f64>> = solver
            .rigid_mass
            .iter()
            .map(|v| v.local_values())
            .collect::<Result<_, _>>()?;
        let dot = |x: &[f64], y: &[f64]| x.iter().zip(y).map(|(a, b)| a * b).sum::<f64>();
        let mut rhs = dense(n_rhs)?;
        rhs.with_local(|x| {
            for (col, load) in groups.iter().flatten().enumerate() {
                for &(dof, value) in load {
                    let dof = dof as usize;
                    if (lo..hi).contains(&dof) {
                        x[col * n_local + dof - lo] += value;
                    }
                }
            }
        })?;
        // Block b's normalised columns (dense, for the products) per block.
        let mut solved: Vec<Dense<'p>> = Vec::with_capacity(blocks);
        let mut mass_products: Vec<Vec<f64>> = Vec::with_capacity(blocks);
        for block in 0..blocks {
            let mut x = dense(n_rhs)?;
            solver.solver.solve_many(&rhs, &mut x)?;
            // The free body's response holds rigid motion at 1/σ: project it out (twice, for
            // rounding), then normalise.
            for _ in 0..2 {
                let local = x.with_local(|xs| {
                    let mut c = vec![0.0; n_rhs * rigid.len()];
                    for j in 0..n_rhs {
                        for (r, mq) in rigid_mass.iter().enumerate() {
                            c[j * rigid.len() + r] = dot(&xs[j * n_local..(j + 1) * n_local], mq);
                        }
                    }
                    c
                })?;
                let c = sum(&local);
                x.with_local(|xs| {
                    for j in 0..n_rhs {
                        let col = &mut xs[j * n_local..(j + 1) * n_local];
                        for (r, q) in rigid.iter().enumerate() {
                            let cr = c[j * rigid.len() + r];
                            col.iter_mut().zip(q).for_each(|(o, v)| *o -= cr * v);
                        }
                    }
                })?;
            }
            let mut mx = Dense::product(mass, &x)?;
            let mx_local = mx.local_values()?;
            let local_norms = x.with_local(|xs| {
                (0..n_rhs)
                    .map(|j| {
                        dot(
                            &xs[j * n_local..(j + 1) * n_local],
                            &mx_local[j * n_local..(j + 1) * n_local],
                        )
                    })
                    .collect::<Vec<f64>>()
            })?;
            let norms: Vec<f64> = sum(&local_norms).into_iter().map(f64::sqrt).collect();
            if norms.iter().any(|n| !(*n > 0.0 && n.is_finite())) {
                return Err(ReducedError::Invalid(
                    "an attachment vector vanished (a load on no DOF?)".into(),
                ));
            }
            let scale = |xs: &mut [f64]| {
                for (j, n) in norms.iter().enumerate() {
                    xs[j * n_local..(j + 1) * n_local]
                        .iter_mut()
                        .for_each(|v| *v /= n);
                }
            };
            x.with_local(scale)?;
            // M x of the normalised columns: the mass projection's product, and the next
            // block's right-hand sides.
            mx.with_local(scale)?;
            mass_products.push(mx.local_values()?);
            if block + 1 < blocks {
                rhs = mx;
            }
            solved.push(x);
        }
        // Group g's columns, block-major as one group at a time makes them: (block, column of
        // the chunk) per attachment.
        let mut offsets = Vec::with_capacity(groups.len());
        let mut next = 0;
        for g in groups {
            offsets.push(next);
            next += g.len();
        }
        let member_lists: Vec<Vec<(usize, usize)>> = (0..groups.len())
            .map(|g| {
                let (first, len) = (offsets[g], groups[g].len());
                (0..blocks)
                    .flat_map(|b| (0..len).map(move |i| (b, first + i)))
                    .collect()
            })
            .collect();
        let members = |g: usize| -> &[(usize, usize)] { &member_lists[g] };
        let values: Vec<Vec<f64>> = solved
            .iter_mut()
            .map(|d| d.local_values())
            .collect::<Result<_, _>>()?;
        let column = |b: usize, j: usize| &values[b][j * n_local..(j + 1) * n_local];
        let nb = self.vectors.len();
        let basis = DMatrix::from_fn(n_local, nb, |r, i| basis_rows[i][r]);
        let basis_t = basis.transpose();
        let self_len: usize = (0..groups.len()).map(|g| members(g).len().pow(2)).sum();
        // K_• x of every column (the mass's are the M x already formed above).
        let products_of = |mat: &Mat<'p>| -> Result<Vec<Vec<f64>>, ReducedError> {
            Ok(solved
                .iter()
                .map(|x| Dense::product(mat, x).and_then(|mut w| w.local_values()))
                .collect::<Result<_, _>>()?)
        };
        let project = |products: &[Vec<f64>]| -> Result<Projected, ReducedError> {
            // Local sums, then one reduction: the basis rows of every column, then each group's
            // own Gram block.
            let mut local = Vec::with_capacity(nb * n_rhs * blocks + self_len);
            for w in products {
                let w = DMatrix::from_column_slice(n_local, n_rhs, w);
                local.extend_from_slice((&basis_t * w).as_slice());
            }
            for g in 0..groups.len() {
                let m = members(g);
                for &(bj, j) in m {
                    let wj = &products[bj][j * n_local..(j + 1) * n_local];
                    for &(bi, i) in m {
                        local.push(dot(column(bi, i), wj));
                    }
                }
            }
            let global = sum(&local);
            let mut cross = Vec::with_capacity(groups.len());
            let mut own = Vec::with_capacity(groups.len());
            let mut at = nb * n_rhs * blocks;
            for g in 0..groups.len() {
                let m = members(g);
                let c = DMatrix::from_fn(nb, m.len(), |i, k| {
                    let (b, j) = m[k];
                    global[b * nb * n_rhs + j * nb + i]
                });
                cross.push(self.whitening.transpose() * c);
                let o = DMatrix::from_column_slice(
                    m.len(),
                    m.len(),
                    &global[at..at + m.len() * m.len()],
                );
                at += m.len() * m.len();
                own.push((&o + o.transpose()) * 0.5);
            }
            Ok((cross, own))
        };
        let (cross_lambda, self_lambda) = project(&products_of(k_lambda)?)?;
        let (cross_mu, self_mu) = project(&products_of(k_mu)?)?;
        let (cross_mass, self_mass) = project(&mass_products)?;
        // Probe values: each rank fills the probe DOFs it owns, then one reduction.
        let n_probe = self.probe_dofs.len();
        let mut local = vec![0.0; n_probe * n_rhs * blocks];
        for (p, &dof) in self.probe_dofs.iter().enumerate() {
            let dof = dof as usize;
            if (lo..hi).contains(&dof) {
                for b in 0..blocks {
                    for j in 0..n_rhs {
                        local[(b * n_rhs + j) * n_probe + p] = values[b][j * n_local + dof - lo];
                    }
                }
            }
        }
        let probes = sum(&local);
        let mut out = Vec::with_capacity(groups.len());
        for (g, ((((cl, sl), (cm, sm)), cmass), smass)) in cross_lambda
            .into_iter()
            .zip(self_lambda)
            .zip(cross_mu.into_iter().zip(self_mu))
            .zip(cross_mass)
            .zip(self_mass)
            .enumerate()
        {
            let m = members(g);
            let probe_values = DMatrix::from_fn(n_probe, m.len(), |p, k| {
                let (b, j) = m[k];
                probes[(b * n_rhs + j) * n_probe + p]
            });
            out.push(AttachmentProjections {
                cross_lambda: cl,
                cross_mu: cm,
                cross_mass: cmass,
                self_lambda: sl,
                self_mu: sm,
                self_mass: smass,
                probe_values,
            });
        }
        Ok(out)
    }

    /// Relative residual of each Ritz pair (module docs). Collective.
    pub fn residuals(
        &self,
        assembled: &Assembled<'p>,
        modes: &ReducedModes,
    ) -> Result<Vec<f64>, ReducedError> {
        let (a, b) = lame_unit(modes.poisson_ratio);
        let local: Vec<Vec<f64>> = self
            .vectors
            .iter()
            .map(|v| v.local_values())
            .collect::<Result<_, _>>()?;
        let n_local = local.first().map_or(0, |v| v.len());
        let mut x = self.vectors[0].duplicate()?;
        let mut kl = x.duplicate()?;
        let mut km = x.duplicate()?;
        let mut mx = x.duplicate()?;
        let mut out = Vec::with_capacity(modes.theta.len());
        for (k, z) in modes.coefficients.iter().enumerate() {
            let coeff = &self.whitening * z;
            let mut values = vec![0.0; n_local];
            for (c, v) in coeff.iter().zip(&local) {
                values.iter_mut().zip(v).for_each(|(o, x)| *o += c * x);
            }
            x.set_local_values(&values)?;
            assembled.k_lambda.mult(&x, &mut kl)?;
            assembled.k_mu.mult(&x, &mut km)?;
            assembled.mass_unit.mult(&x, &mut mx)?;
            let mx_norm = mx.norm2()?;
            kl.scale(a)?;
            kl.axpy(b, &km)?;
            kl.axpy(-modes.theta[k], &mx)?;
            out.push(kl.norm2()? / (modes.theta[k].abs() * mx_norm));
        }
        Ok(out)
    }
}
