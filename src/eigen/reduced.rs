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

use super::{solve_modes, spectrum_scale, EigenConfig, EigenError, ModeRequest};
use crate::assembly::Assembled;
use crate::petsc::{Mat, Petsc, PetscError, PetscInt, Vector};
use mpi::collective::{CommunicatorCollectives, SystemOperation};
use nalgebra::{DMatrix, DVector, SymmetricEigen};

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
    ((d - nu * (-1.0 - 4.0 * nu)) / (d * d), -0.5 / ((1.0 + nu) * (1.0 + nu)))
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
    pub fn build(petsc: &'p Petsc, assembled: &Assembled<'p>, size: f64, n_modes: usize, margin: usize, samples: &[f64], probe_dofs: Vec<PetscInt>) -> Result<Self, ReducedError> {
        if samples.is_empty() || n_modes == 0 {
            return Err(ReducedError::Invalid("a reduced basis needs at least one sample ν and one mode".into()));
        }
        if let Some(nu) = samples.iter().find(|nu| !(**nu > -0.99 && **nu < 0.499)) {
            return Err(ReducedError::Invalid(format!("sample ν = {nu} outside (−1, 0.5)")));
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
    pub fn full_theta(petsc: &'p Petsc, assembled: &Assembled<'p>, size: f64, nu: f64, n: usize) -> Result<(Vec<f64>, Vec<Vector<'p>>), ReducedError> {
        let (a, b) = lame_unit(nu);
        let mut k = assembled.k_lambda.duplicate()?;
        k.scale(a)?;
        k.axpy(b, &assembled.k_mu, crate::petsc::NonzeroPattern::Same)?;
        k.set_symmetric()?;
        let mut cfg = EigenConfig::new(ModeRequest::FirstN(n + cfg_rigid_spare()), spectrum_scale(b, 1.0, size));
        cfg.verify_count = false;
        let modes = solve_modes(petsc, &k, &assembled.mass_unit, &cfg)?;
        let (mut values, mut vectors) = (modes.eigenvalues, modes.vectors);
        // Rigid-body modes the solver resolved poorly land above the rigid threshold (seen on the
        // bowl under 2 ranks: three at 10⁻³–10⁻¹ of the first elastic θ, 221–518 Hz below 1672 Hz).
        // They are the missing ones of the expected six, well below the first elastic mode: drop
        // those under a quarter of it.
        let missing = cfg.expected_rigid.saturating_sub(modes.rigid_eigenvalues.len()).min(values.len().saturating_sub(1));
        let first_elastic = values.get(missing).copied().unwrap_or(0.0);
        let spurious = values.iter().take(missing).take_while(|v| **v < 0.25 * first_elastic).count();
        values.drain(..spurious);
        vectors.drain(..spurious);
        values.truncate(n);
        vectors.truncate(n);
        if values.len() < n {
            return Err(ReducedError::Invalid(format!("the full solve at ν = {nu} gave {} elastic modes, {n} wanted", values.len())));
        }
        Ok((values, vectors))
    }

    fn solve_and_append(&mut self, petsc: &'p Petsc, assembled: &Assembled<'p>, nu: f64) -> Result<(), ReducedError> {
        let start = std::time::Instant::now();
        let (theta, vectors) = Self::full_theta(petsc, assembled, self.size, nu, self.n_modes + self.margin)?;
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
    pub fn add_sample(&mut self, petsc: &'p Petsc, assembled: &Assembled<'p>, nu: f64) -> Result<(), ReducedError> {
        self.solve_and_append(petsc, assembled, nu)?;
        self.project(petsc, assembled)
    }

    fn project(&mut self, petsc: &'p Petsc, assembled: &Assembled<'p>) -> Result<(), ReducedError> {
        let nb = self.vectors.len();
        let local: Vec<Vec<f64>> = self.vectors.iter().map(|v| v.local_values()).collect::<Result<_, _>>()?;
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
            petsc.world().all_reduce_into(&local_gram[..], &mut global[..], SystemOperation::sum());
            let g = DMatrix::from_row_slice(nb, nb, &global);
            Ok((&g + g.transpose()) * 0.5)
        };
        let g_lambda = gram(&assembled.k_lambda, &mut work)?;
        let g_mu = gram(&assembled.k_mu, &mut work)?;
        let g_mass = gram(&assembled.mass_unit, &mut work)?;
        let eig = SymmetricEigen::new(g_mass);
        let largest = eig.eigenvalues.iter().fold(0.0_f64, |m, v| m.max(*v));
        let kept: Vec<usize> = (0..nb).filter(|&i| eig.eigenvalues[i] > WHITENING_FLOOR * largest).collect();
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
    pub fn refresh_if_needed(&mut self, petsc: &'p Petsc, assembled: &Assembled<'p>, nu: f64, tolerance: f64, min_spacing: f64) -> Result<f64, ReducedError> {
        let modes = self.solve(nu);
        let worst = self.residuals(assembled, &modes)?.into_iter().fold(0.0_f64, f64::max);
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
        let floor = if self.theta_floor.is_finite() { self.theta_floor } else { 0.0 };
        let mut order: Vec<usize> = (0..eig.eigenvalues.len()).filter(|&i| eig.eigenvalues[i] > floor).collect();
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
        ReducedModes { poisson_ratio: nu, theta, dtheta_dnu: dtheta, coefficients }
    }

    /// Mode k's values at the probe DOFs (mass-normalised for ρ = 1; divide by √ρ otherwise).
    pub fn probe(&self, modes: &ReducedModes, k: usize) -> Vec<f64> {
        let coeff = &self.whitening * &modes.coefficients[k];
        (0..self.probe_values.ncols()).map(|c| self.probe_values.column(c).dot(&coeff)).collect()
    }

    /// Every mode's values at the probe DOFs: probes × modes (mass-normalised for ρ = 1).
    pub fn probe_all(&self, modes: &ReducedModes) -> DMatrix<f64> {
        let mut z = DMatrix::zeros(self.whitening.ncols(), modes.coefficients.len());
        for (k, c) in modes.coefficients.iter().enumerate() {
            z.set_column(k, c);
        }
        self.probe_values.transpose() * (&self.whitening * z)
    }

    /// Relative residual of each Ritz pair (module docs). Collective.
    pub fn residuals(&self, assembled: &Assembled<'p>, modes: &ReducedModes) -> Result<Vec<f64>, ReducedError> {
        let (a, b) = lame_unit(modes.poisson_ratio);
        let local: Vec<Vec<f64>> = self.vectors.iter().map(|v| v.local_values()).collect::<Result<_, _>>()?;
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
