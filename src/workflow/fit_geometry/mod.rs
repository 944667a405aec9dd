//! The `fit-geometry` job (issue 7, task 3): a body known only as a coarse voxelisation,
//! represented by an MLP signed-distance field, pre-fitted to the voxels and refined by the
//! first N eigenvalues of a target spectrum ([`crate::inverse::geometry`]).
//!
//! ```text
//! mpirun -np 2 diffsound fit-geometry --surface spot.obj --diagonal 0.1 --voxels 16 --cells 20 \
//!        --target-cells 32 --modes 12 --steps 30 --out out/spot_geometry.h5 -v
//! ```
//!
//! # Inputs
//!
//! * **Surface**: a closed triangle surface, OBJ or the boundary of a Gmsh tet mesh (`.msh`), in
//!   `units` (metres per unit), centred on its bounding box and, with `diagonal`, scaled to that
//!   bounding-box diagonal [m]. It is the truth: voxelised (`voxels` per axis over its bounding
//!   box), rendered for the target spectrum (`target_cells`, a grid shifted by a random fraction
//!   of a cell from `target_seed`), and compared with the results. The fit itself only sees the
//!   voxels and the target eigenvalues.
//! * **Fit**: the grid (`cells` along the longest axis), `modes` N, the refinement's `steps`
//!   and update (`method`: minimum-norm Gauss–Newton with its `damping`, the default, or Adam
//!   with its `learning_rate`), the grid-bias correction (on unless `--no-bias-correction`),
//!   `free_scale` (off; the spectrum's shape only, for a body of unknown stiffness), the check
//!   on the target's cell count (on unless `--no-target-grid-check`), the body's boundary
//!   (curved unless `--straight-boundary`: every body — target, fit, bias reference, floor —
//!   has its crossings and boundary mid-edge nodes on the zero of its continuous field, the
//!   network's or the true signed distance; TOML `[geometry.refine] curved_boundary`),
//!   the weights of the voxel constraint and of the eikonal regulariser, the
//!   pre-fit's updates, the network (`octaves`, `hidden` widths) and `seed` (network
//!   initialisation, pre-fit batches and eikonal points).
//! * **Material**: a preset and overrides (E, ν, ρ are known).
//!
//! # Outputs
//!
//! `out` (HDF5, written atomically; `/` attrs `format` = `diffsound.fit_geometry`,
//! `format_version` = 2, `surface`, `command`, `version`, `n_ranks` (i64), `settings_json`).
//! Steps, counts and sizes are integers (u64 datasets, i64 attributes) and flags u8; version 1
//! stored them as f64:
//!
//! | path | contents |
//! |------|----------|
//! | `/metrics/{voxels,before,after,floor}` attrs | `chamfer`, `hausdorff` [m], `iou` against the true surface: the voxels' staircase, the pre-fitted field, the refined field (both marched on the fit grid, crossings on the field's zero with the curved boundary) and the true signed distance marched on the fit grid (the floor); the last three add `rms_frequency_error`, `eigen_loss`, `volume` [m³] |
//! | `/modes/{target,before,after,floor}_eigenvalues`, `…_frequency_hz`, `{before,after,floor}_relative_frequency_error` | the N compared modes |
//! | `/check` attrs `before_loss`, `after_loss`, `refined_kept` | with the correction and the check (default): the eigenvalue loss of the pre-fitted and the refined field on a centred grid of `target_cells` against the uncorrected target; `refined_kept` = 1 if the refined field is the answer (its loss there is lower), else the answer is the pre-fitted field |
//! | `/modes/bias_correction` | with the grid-bias correction (default): ln λ_k(fit grid) − ln λ_k(bias grid) of the pre-fitted field, added to ln λ*_k for the refinement (the errors above are against the uncorrected target) |
//! | `/refine/history/{step,loss,eigen_loss,voxel_loss,eikonal_loss,tets,p2_nodes,meshing_s,assembly_s,solve_s,gradient_s,network_s,step_scale,backtracked,failed}` | every evaluation (step 0 = the pre-fit; step_scale: the fraction of Adam's update taken after it; backtracked: the next update restarted from the best θ); attrs `best_step`, `seconds` |
//! | `/refine/mean_step` attrs | `meshing`, `assembly`, `solve`, `gradient`, `network`, `total` [s] per evaluation |
//! | `/prefit/loss` | L_pre per update; attrs `centre_accuracy`, `sign_loss`, `eikonal_loss`, `seconds` |
//! | `/network/parameters`, `/network/prefit_parameters` | θ after and before refinement (layout in [`crate::shape::neural_sdf`]); attrs `octaves`, `length` [m], `centre_x/y/z` [m], text `hidden`, `config_json` |
//! | `/voxels` attrs | `resolution`, `occupied`, `edge_x/y/z` [m] |
//! | `/material` attrs, `/timings` attrs | E, ν, ρ; `voxelise`, `prefit`, `target`, `refine`, `assess`, `final_body`, `total` [s] |
//!
//! `<out stem>_mesh.h5` + `.xdmf` (ParaView): the refined body on the fit grid, P2 (curved
//! boundary by default), with its modes ([`crate::io::write_modes`] layout). `png` (default `<out stem>.png`): the voxels,
//! the pre-fitted body, the refined body and the true surface side by side, from two views, at
//! one scale. Progress per step on stderr (with `-v`, or on a terminal); only rank 0 writes.
//!
//! The command line ([`crate::cli::fit_geometry`]) resolves flags and the TOML file into a
//! [`Job`] and reads the surface ([`load_surface`]) before PETSc starts; [`run`] fits and
//! returns a [`Report`], which [`write::write_outputs`] writes (rank 0).

pub mod write;

use crate::fem::Material;
use crate::inverse::geometry::{fit_geometry, GeometryFit, GeometryProgress, GeometrySettings};
use crate::petsc::Petsc;
use crate::shape::{
    curved_field_modes, normalise_surface, read_surface, shape_modes, MarchingOptions, ShapeModes,
    SignedDistance, TriangleSurface,
};
use crate::workflow::Progress;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What stops a geometry fit. The messages are the command's (`error: …`).
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The fit ([`fit_geometry`]) or the refined body's modes.
    #[error("{0}")]
    Fit(String),
    /// Writing the result files or the picture.
    #[error("{0}")]
    Output(String),
}

/// Everything resolved and checked before PETSc starts.
#[derive(Clone, Debug)]
pub struct Job {
    pub surface: PathBuf,
    pub unit_scale: f64,
    pub diagonal: Option<f64>,
    pub settings: GeometrySettings,
    pub material: Material,
    pub out: PathBuf,
    pub mesh_out: PathBuf,
    pub png: PathBuf,
    pub petsc_options: Vec<String>,
    pub verbose: bool,
}

/// Reads and places the surface (before PETSc starts: a bad file ends the job with its message).
pub fn load_surface(
    path: &Path,
    unit_scale: f64,
    diagonal: Option<f64>,
) -> Result<(TriangleSurface, SignedDistance, Vec<String>), String> {
    let (mut surface, warnings) =
        read_surface(path).map_err(|e| format!("{}: {e}", path.display()))?;
    for v in &mut surface.vertices {
        for x in v.iter_mut() {
            *x *= unit_scale;
        }
    }
    let (lo, hi) = surface.bounding_box();
    let size = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
    normalise_surface(&mut surface, diagonal.unwrap_or(size))
        .map_err(|e| format!("{}: {e}", path.display()))?;
    if (0..3).any(|d| !(hi[d] > lo[d])) {
        return Err(format!(
            "{}: the surface is flat (no extent along some axis)",
            path.display()
        ));
    }
    let sdf = SignedDistance::new(&surface).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok((surface, sdf, warnings))
}

/// Fits the network to the voxels of `truth` and refines it by the target spectrum on every
/// rank (module docs), then solves the refined body with its modes for the mesh file. `truth`
/// and `sdf` are [`load_surface`]'s.
pub fn run(
    petsc: &Petsc,
    job: &Job,
    truth: &TriangleSurface,
    sdf: &SignedDistance,
    progress: &Progress,
) -> Result<Report, Error> {
    compute(petsc, job, truth, sdf, progress).map_err(Error::Fit)
}

fn compute(
    petsc: &Petsc,
    job: &Job,
    truth: &TriangleSurface,
    sdf: &SignedDistance,
    progress: &Progress,
) -> Result<Report, String> {
    let total = Instant::now();
    let fit = fit_geometry(
        petsc,
        truth,
        sdf,
        &job.material,
        &job.settings,
        |p| match p {
            GeometryProgress::Message(m) => progress.say(m),
            GeometryProgress::Step(s) => progress.say(step_line(s)),
        },
    )
    .map_err(|e| format!("{}: {e}", job.surface.display()))?;
    // The refined body with its modes, for ParaView.
    let clock = Instant::now();
    let net = crate::shape::neural_sdf::NeuralSdf::from_parameters(
        fit.network.clone(),
        fit.refinement.best_parameters.clone(),
    )
    .map_err(|e| e.to_string())?;
    let values = net.values(&fit.grid.vertex_positions());
    let body = if job.settings.refine.curved_boundary {
        curved_field_modes(
            petsc,
            &fit.grid,
            &values,
            &|x| net.value(x),
            &MarchingOptions::default(),
            &job.material,
            job.settings.modes,
        )
    } else {
        shape_modes(
            petsc,
            &fit.grid,
            &values,
            &MarchingOptions::default(),
            &job.material,
            job.settings.modes,
        )
    }
    .map_err(|e| format!("the refined body: {e}"))?;
    let final_seconds = clock.elapsed().as_secs_f64();
    Ok(Report {
        fit,
        body,
        final_seconds,
        total_seconds: total.elapsed().as_secs_f64(),
        n_ranks: petsc.size(),
    })
}

/// The fit and the refined body.
pub struct Report {
    pub fit: GeometryFit,
    /// The refined body on the fit grid, P2, with its modes.
    pub body: ShapeModes,
    /// Seconds of the refined body's solve, and of the whole job.
    pub final_seconds: f64,
    pub total_seconds: f64,
    pub n_ranks: usize,
}

/// One progress line per refinement evaluation.
pub fn step_line(s: &crate::inverse::geometry::RefineStep) -> String {
    match &s.failure {
        None => format!(
            "step {:>3}: loss {:.4e} (eigen {:.4e}, voxel {:.3e}, eikonal {:.3e}), {} tets; mesh {:.2} s, assembly {:.2} s, solve {:.2} s, gradient {:.2} s, network {:.2} s{}",
            s.step, s.loss, s.eigen_loss, s.voxel_loss, s.eikonal_loss, s.tets, s.timings.meshing, s.timings.assembly, s.timings.solve, s.timings.gradient, s.network_seconds,
            if s.backtracked { "; worse than the best: back to it, half the step" } else { "" }
        ),
        Some(f) => format!("step {:>3}: no body ({f}); back to the best step", s.step),
    }
}
