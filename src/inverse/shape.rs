//! Shape from sound: the spectrum of the body an implicit field encloses, its exact gradient
//! with respect to the field, and the thickness fit built on it (issue 7).
//!
//! # The chain
//!
//! A field s_i on the vertices of a background tet grid ([`BackgroundGrid`], positive inside)
//! is meshed by marching tetrahedra ([`crate::mesh::march`]); the P1 mesh is lifted to P2
//! ([`lift_to_quadratic`]); M, K_λ, K_μ are assembled and the first `n` elastic modes solved
//! (shift-invert Krylov–Schur, as everywhere else). For each mode
//!
//! ```text
//!   dλ_k/ds_i = Σ_v (dλ_k/dx_v) · (dx_v/ds_i)
//! ```
//!
//! where dλ_k/dx_v [rad²/(s²·m)] is the node-position sensitivity of the P2 mesh
//! ([`node_gradients`], cluster means for near-degenerate modes) carried back to the P1 corners
//! (mid-edge nodes are edge midpoints, [`linear_node_gradient`]) and dx_v/ds_i is the marching
//! Jacobian (a crossing x = x_a + t (x_b − x_a), t = s_a/(s_a − s_b), moves with s_a and s_b
//! only; [`crate::mesh::MarchedMesh::vjp`]). Grid vertices that are mesh corners do not move
//! with s. The topology (which tets exist) is piecewise constant in s, so the gradient is that of
//! the current mesh; it is exact between topology changes.
//!
//! # Thickness
//!
//! A hollow body of relative thickness t is the set 0 < s ≤ t·max(s) of the solid's field s
//! ([`crate::mesh::shell`], g = min(s, t·max s − s)). With the target eigenvalues λ*_k, the fit
//! minimises the squared log-eigenvalue misfit
//!
//! ```text
//!   L(t) = Σ_k (ln λ_k(t) − ln λ*_k)²,    r_k = ln λ_k − ln λ*_k,    J_k = dλ_k/dt / λ_k
//! ```
//!
//! by Gauss–Newton on the one parameter, Δt = −Σ J_k r_k / Σ J_k², with the step halved while L
//! does not fall and t kept in the bounds. Eigenvalues are compared in ascending order; a
//! degenerate pair enters as its two members, whose gradient is the cluster mean. E, ν and ρ are
//! known here (the material fit is a separate problem).

use crate::assembly;
use crate::eigen::sensitivity::{node_gradients, ClusterTreatment};
use crate::eigen::{self, EigenConfig, ModeRequest};
use crate::fem::Material;
use crate::mesh::{self, lift_to_quadratic, linear_node_gradient, BackgroundGrid, MarchingOptions, MarchingReport};
use crate::petsc::Petsc;

/// Why a shape evaluation or fit failed.
#[derive(Debug, thiserror::Error)]
pub enum ShapeError {
    #[error("meshing: {0}")]
    Marching(#[from] mesh::MarchingError),
    #[error("the field encloses no body (every value ≤ 0)")]
    Empty,
    #[error("{0}")]
    Solver(String),
    #[error("{0}")]
    Invalid(String),
}

/// Seconds spent in each part of one evaluation.
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct StepTimings {
    pub meshing: f64,
    pub assembly: f64,
    pub solve: f64,
    pub gradient: f64,
}

impl StepTimings {
    pub fn total(&self) -> f64 {
        self.meshing + self.assembly + self.solve + self.gradient
    }
}

/// The spectrum of the body inside a field, and optionally its gradient.
#[derive(Clone, Debug)]
pub struct ShapeSpectrum {
    /// First `n` elastic eigenvalues, ascending [rad²/s²].
    pub eigenvalues: Vec<f64>,
    /// dλ_k/ds_i per mode k and grid vertex i [rad²/s² per unit of s]; on every rank.
    pub gradient: Option<Vec<Vec<f64>>>,
    /// Near-degenerate clusters among the first `n` modes (index ranges): their members carry
    /// the cluster-mean gradient.
    pub clusters: Vec<std::ops::Range<usize>>,
    pub report: MarchingReport,
    pub tets: usize,
    pub p2_nodes: usize,
    pub timings: StepTimings,
}

/// Meshes the field, solves the first `n_modes` elastic modes, and (if asked) their gradients
/// with respect to the field values. Collective: every rank passes the same field.
pub fn shape_spectrum(petsc: &Petsc, grid: &BackgroundGrid, values: &[f64], options: &MarchingOptions, material: &Material, n_modes: usize, with_gradient: bool) -> Result<ShapeSpectrum, ShapeError> {
    if values.iter().all(|v| *v <= 0.0) {
        return Err(ShapeError::Empty);
    }
    let mut timings = StepTimings::default();
    let t = std::time::Instant::now();
    let marched = mesh::march(grid, values, None, options)?;
    let linear = &marched.mesh;
    let quadratic = lift_to_quadratic(linear);
    timings.meshing = t.elapsed().as_secs_f64();

    let t = std::time::Instant::now();
    let assembled = assembly::assemble(petsc, &quadratic).map_err(|e| ShapeError::Solver(e.to_string()))?;
    let (k, m) = assembled.operators(material).map_err(|e| ShapeError::Solver(e.to_string()))?;
    timings.assembly = t.elapsed().as_secs_f64();

    let t = std::time::Instant::now();
    let (lo, hi) = quadratic.bounding_box();
    let diagonal = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
    let mut cfg = EigenConfig::new(ModeRequest::FirstN(n_modes), eigen::spectrum_scale(material.lame_mu(), material.density, diagonal));
    // The count is proven by the solver's own cluster completion; the inertia check would cost a
    // second factorisation per step.
    cfg.verify_count = false;
    let modes = eigen::solve_modes(petsc, &k, &m, &cfg).map_err(|e| ShapeError::Solver(e.to_string()))?;
    if modes.eigenvalues.len() < n_modes {
        return Err(ShapeError::Solver(format!("the solve gave {} elastic modes, {n_modes} wanted", modes.eigenvalues.len())));
    }
    timings.solve = t.elapsed().as_secs_f64();
    let eigenvalues: Vec<f64> = modes.eigenvalues[..n_modes].to_vec();

    let gradient = if with_gradient {
        let t = std::time::Instant::now();
        let per_node = node_gradients(petsc, &quadratic, &assembled.layout, &modes, material, ClusterTreatment::Mean).map_err(|e| ShapeError::Solver(e.to_string()))?;
        // Rank 0 holds the node gradients: carry them to the field there, then share.
        let n_grid = grid.n_vertices();
        let mut flat = vec![0.0; n_modes * n_grid];
        if let Some(per_node) = per_node {
            for (k, g) in per_node.iter().take(n_modes).enumerate() {
                let corners = linear_node_gradient(linear, &quadratic, g).map_err(|e| ShapeError::Solver(e.to_string()))?;
                let back = marched.vjp(&corners)?;
                flat[k * n_grid..(k + 1) * n_grid].copy_from_slice(&back.values);
            }
        }
        {
            use mpi::traits::{Communicator, Root};
            petsc.world().process_at_rank(0).broadcast_into(&mut flat[..]);
        }
        timings.gradient = t.elapsed().as_secs_f64();
        Some(flat.chunks(n_grid).map(<[f64]>::to_vec).collect())
    } else {
        None
    };
    let clusters = modes.clusters.iter().filter(|r| r.start < n_modes).map(|r| r.start..r.end.min(n_modes)).collect();
    Ok(ShapeSpectrum { eigenvalues, gradient, clusters, report: marched.report.clone(), tets: linear.n_tets(), p2_nodes: quadratic.n_nodes(), timings })
}

/// Settings of [`fit_thickness`].
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ThicknessFitSettings {
    /// Gauss–Newton iterations at most (default 12).
    pub max_iterations: usize,
    /// Stop when |Δt| falls below this (default 1e-5).
    pub step_tolerance: f64,
    /// t is kept in [lo, hi] (default [0.05, 0.98]).
    pub bounds: (f64, f64),
    /// Modes compared (default 8).
    pub modes: usize,
}

impl Default for ThicknessFitSettings {
    fn default() -> Self {
        ThicknessFitSettings { max_iterations: 12, step_tolerance: 1e-5, bounds: (0.05, 0.98), modes: 8 }
    }
}

/// One Gauss–Newton iteration.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ThicknessStep {
    pub iteration: usize,
    pub thickness: f64,
    pub loss: f64,
    /// dL/dt.
    pub gradient: f64,
    pub tets: usize,
    pub timings: StepTimings,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ThicknessFit {
    pub thickness: f64,
    pub loss: f64,
    pub eigenvalues: Vec<f64>,
    pub history: Vec<ThicknessStep>,
    /// Evaluations, including rejected (halved) steps.
    pub evaluations: usize,
    pub seconds: f64,
}

/// The loss, its t-derivative and the Gauss–Newton step at thickness t (module docs).
fn thickness_point(petsc: &Petsc, grid: &BackgroundGrid, solid: &[f64], t: f64, targets: &[f64], options: &MarchingOptions, material: &Material) -> Result<(f64, f64, f64, ShapeSpectrum), ShapeError> {
    let shell = mesh::shell(solid, t)?;
    let spectrum = shape_spectrum(petsc, grid, &shell.values, options, material, targets.len(), true)?;
    let gradient = spectrum.gradient.as_ref().expect("asked for the gradient");
    let (mut loss, mut d_loss, mut jtj, mut jtr) = (0.0, 0.0, 0.0, 0.0);
    for (k, (&lambda, &target)) in spectrum.eigenvalues.iter().zip(targets).enumerate() {
        let r = (lambda / target).ln();
        // dλ_k/dt through the shell field: the shell's own VJP with dL/dg = dλ_k/ds.
        let d_lambda_dt = shell.vjp(&gradient[k])?.thickness;
        let j = d_lambda_dt / lambda;
        loss += r * r;
        d_loss += 2.0 * r * j;
        jtj += j * j;
        jtr += j * r;
    }
    let step = if jtj > 0.0 { -jtr / jtj } else { 0.0 };
    Ok((loss, d_loss, step, spectrum))
}

/// Fits the relative thickness t of the hollow version of the solid field `solid` to the target
/// eigenvalues (module docs). `on_step` sees every accepted iteration. Collective.
pub fn fit_thickness(petsc: &Petsc, grid: &BackgroundGrid, solid: &[f64], targets: &[f64], start: f64, options: &MarchingOptions, material: &Material, settings: &ThicknessFitSettings, mut on_step: impl FnMut(&ThicknessStep)) -> Result<ThicknessFit, ShapeError> {
    let (lo, hi) = settings.bounds;
    if !(0.0 < lo && lo < hi && hi <= 1.0) || !(lo..=hi).contains(&start) {
        return Err(ShapeError::Invalid(format!("thickness start {start} outside the bounds [{lo}, {hi}] (0 < lo < hi ≤ 1)")));
    }
    if targets.is_empty() || targets.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
        return Err(ShapeError::Invalid("the target eigenvalues must be positive numbers".into()));
    }
    let clock = std::time::Instant::now();
    let mut t = start;
    let (mut loss, mut grad, mut step, mut spectrum) = thickness_point(petsc, grid, solid, t, targets, options, material)?;
    let mut evaluations = 1;
    let mut history = Vec::new();
    let record = |iteration: usize, t: f64, loss: f64, grad: f64, s: &ShapeSpectrum| ThicknessStep { iteration, thickness: t, loss, gradient: grad, tets: s.tets, timings: s.timings };
    history.push(record(0, t, loss, grad, &spectrum));
    on_step(&history[0]);
    for iteration in 1..=settings.max_iterations {
        let mut scale = 1.0;
        let mut accepted = false;
        while scale > 1.0 / 64.0 {
            let candidate = (t + scale * step).clamp(lo, hi);
            if (candidate - t).abs() < settings.step_tolerance {
                break;
            }
            let (l, g, s, sp) = thickness_point(petsc, grid, solid, candidate, targets, options, material)?;
            evaluations += 1;
            if l < loss {
                (t, loss, grad, step, spectrum) = (candidate, l, g, s, sp);
                accepted = true;
                break;
            }
            scale *= 0.5;
        }
        if !accepted {
            break;
        }
        history.push(record(iteration, t, loss, grad, &spectrum));
        on_step(history.last().expect("pushed"));
        if step.abs() < settings.step_tolerance {
            break;
        }
    }
    Ok(ThicknessFit { thickness: t, loss, eigenvalues: spectrum.eigenvalues, history, evaluations, seconds: clock.elapsed().as_secs_f64() })
}
