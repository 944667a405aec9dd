//! The `fit-thickness` and `fit-morph` jobs (issue 7): one shape parameter from target
//! eigenvalues, through the differentiable tet representation ([`crate::inverse::shape`]).
//!
//! ```text
//! mpirun -np 2 diffsound fit-thickness --surface spot.obj --diagonal 0.1 --target modes.txt --out out/spot_t.h5
//! mpirun -np 2 diffsound fit-thickness --surface spot.obj --diagonal 0.1 --target-thickness 0.5 --target-cells 40 --out t.h5
//! mpirun -np 2 diffsound fit-morph --shape-a frog.obj --shape-b turtle.obj --diagonal 0.1 --target-weight 0.4 --target-cells 32 --out m.h5
//! ```
//!
//! # Inputs
//!
//! * **Shapes**: closed triangle surfaces, OBJ or the boundary of a Gmsh tet mesh (`.msh`), in
//!   `units` (metres per unit). Each is centred on its bounding box's centre and, with
//!   `diagonal`, scaled to that bounding-box diagonal [m] ([`normalise_surface`]); a morph's
//!   two shapes are aligned that way and share one grid over the union of their boxes.
//! * **Target**: a text file of frequencies [Hz] (or eigenvalues [rad²/s²] with
//!   `--target-units rad2`), separated by spaces, commas or newlines, `#` starting a comment;
//!   the lowest `modes` are used. Or a synthesised one: the true thickness / weight rendered on
//!   a `target_cells` grid (finer than every fit level) shifted by a random fraction of a cell
//!   drawn from `target_seed`, as the benchmark does. The fit never sees the true value; it is
//!   only written to the result for the error.
//! * **Grid levels** `cells` (coarse to fine, cells along the longest axis): the coarsest is
//!   scanned, every level refined. The answer is the finest level's (curved thickness body) or,
//!   with two or more levels, the line in the grid spacing through the finest levels' answers
//!   at the target's spacing (morph, `--straight-boundary`; `target_spacing`, default 0 for a
//!   file target, the target grid's for a synthesised one); `--extrapolate` and
//!   `--no-extrapolate` choose explicitly. `replicas` K (default 1) fits the finest level (the
//!   answer is the finest level's) or every level after the first (the answer is the line) on
//!   K grids of its spacing, moved by r/K of a cell along the diagonal; the line goes through
//!   all of them and the finest level's answer is the mean of its K grids': the grids'
//!   alignment noise averages instead of riding on one alignment per spacing
//!   (src/inverse/shape.rs, "Grid bias and its extrapolation"), at K times the cost of those
//!   levels.
//! * **Material**: a preset and overrides (E, ν, ρ are known; only the shape is fitted).
//! * **Boundary** (thickness): by default every crossing of the marched shell sits on the zero
//!   of the continuous signed distance and every boundary mid-edge node is moved onto it (a
//!   curved P2 surface, src/inverse/shape.rs "Curved boundary"); `--straight-boundary` (TOML
//!   `straight_boundary = true`) meshes from the grid samples alone, as the morph does. The
//!   synthesised target uses the same boundary as the fit. `--wall-refinement L` (TOML
//!   `[fit] wall_refinement`) halves the grid L times near the walls where its samples do not
//!   resolve the signed distance, on every level after the first and on a synthesised target
//!   (src/inverse/shape.rs "Refinement near the walls"); each halving multiplies the tets
//!   there by 8, so L = 1 on a 28-cell turtle already takes 4× the solve time and L = 2 does
//!   not fit in 24 GB.
//!
//! # Outputs
//!
//! `out` (HDF5, written atomically; `/` attrs `format` = `diffsound.fit_shape`,
//! `format_version` = 2, `task` (`thickness` | `morph`), `parameter_name`, `surfaces`,
//! `command`, `version`, `n_ranks` (i64)). Counts and indices are integers (u64 datasets, i64
//! attributes) and flags u8 (`flag` attributes as in [`crate::io::results`]); version 1 stored
//! them as f64:
//!
//! | path | contents |
//! |------|----------|
//! | `/fit` attrs | `wall_refinement`, `wall_band`, `wall_tolerance` (the grid refinement near the walls; 0 halvings: none), `parameter` (the answer), `finest_level_parameter` (the mean over the finest spacing's replicas), `extrapolated` (if any), `target_spacing` [m], `loss` (finest level), `evaluations`, `seconds`; synthesised targets add `true_parameter`, `abs_error`, `target_cells` |
//! | `/fit/levels/{cells,spacing,parameter,loss,log_stiffness_scale,evaluations,seconds,grid_tets,wall_centre}` | per level, coarse to fine (replicas of a spacing are consecutive entries with equal cells); spacing in m (of the structured grid); log_stiffness_scale the profiled ln factor with `--free-scale` (else 0); grid_tets the background tets after any refinement, wall_centre the t its inner-wall band was centred on (NaN: not refined) |
//! | `/fit/history/{level,cells,phase,parameter,loss,gradient,step,tets,p2_nodes,meshing_s,assembly_s,solve_s,gradient_s,failed}` | every evaluation (level, cells, phase, tets, p2_nodes u64: phase 0 = scan, 1 = refine; failed u8, 1 where no body could be meshed or solved, loss NaN) |
//! | `/modes/{target_frequency_hz,fitted_frequency_hz,target_eigenvalues,fitted_eigenvalues,relative_frequency_error}` | the compared modes: target vs the finest level's best fit (the model on that grid) |
//! | `/modes/answer_frequency_hz` | the body at the answer (extrapolated) parameter on the finest grid: the mesh file's modes |
//! | `/shape` attrs | `reference_depth` [m] and `curved_boundary` (1: exact crossings and curved P2 edges, 0: `--straight-boundary`) for thickness, `diagonal` [m], `finest_cells`, `tets`, `p2_nodes`, `volume` [m³] of the P2 body |
//! | `/material` attrs | `youngs_modulus` [Pa], `poisson_ratio`, `density` [kg/m³] |
//! | `/timings` attrs | `setup`, `target`, `fit`, `final_body`, `total` [s] |
//!
//! and `<out stem>_mesh.h5` + `.xdmf` (ParaView): the fitted body on the finest grid, P2, with
//! its modes ([`crate::io::write_modes`] layout). Progress on stderr per evaluation (with
//! `-v`, or on a terminal); only rank 0 writes.
//!
//! The command line ([`crate::cli::fit_shape`]) resolves flags and the TOML file into a
//! [`Job`] and reads the shapes ([`load_shapes`]) before PETSc starts; [`run`] fits and
//! returns a [`Report`], which [`write::write_outputs`] writes (rank 0).

pub mod job;
pub mod write;

pub use job::{parse_target, replicate_every_level, Job, TargetChoice, TargetSource, Task};

use crate::inverse::shape::{
    fit_shape, replica_levels, replica_shift, FitEvaluation, SearchPhase, ShapeFamily, ShapeFit,
    ShapeLevel, SpectrumTarget,
};
use crate::petsc::Petsc;
use crate::random::SplitMix64;
use crate::shape::{
    self, normalise_surface, read_surface, reference_depth, shifted_covering, union_box,
    MarchingOptions, ShapeModes, SignedDistance, TriangleSurface,
};
use crate::workflow::Progress;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

/// What stops a shape fit. The messages are the command's (`error: …`).
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Reading or placing a shape's surface (before PETSc starts).
    #[error("{0}")]
    Shape(String),
    /// The grids, the target, the fit or the fitted body (meshing, solving).
    #[error("{0}")]
    Fit(String),
    /// Writing the result files.
    #[error("{0}")]
    Output(String),
}

/// A shape ready to sample: its name, placed surface and signed distance.
pub struct Shape {
    pub path: PathBuf,
    pub surface: TriangleSurface,
    pub sdf: Arc<SignedDistance>,
    /// The reader's warnings (dropped degenerate triangles, ignored element types, …).
    pub warnings: Vec<String>,
}

fn load_shape(path: &Path, job: &Job) -> Result<Shape, String> {
    let (mut surface, warnings) =
        read_surface(path).map_err(|e| format!("{}: {e}", path.display()))?;
    for v in &mut surface.vertices {
        for x in v.iter_mut() {
            *x *= job.unit_scale;
        }
    }
    let (lo, hi) = surface.bounding_box();
    let size = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
    normalise_surface(&mut surface, job.diagonal.unwrap_or(size))
        .map_err(|e| format!("{}: {e}", path.display()))?;
    let sdf = SignedDistance::new(&surface).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(Shape {
        path: path.to_path_buf(),
        surface,
        sdf: Arc::new(sdf),
        warnings,
    })
}

/// Reads and places the task's shapes (before PETSc starts: a bad file ends the job with its
/// message).
pub fn load_shapes(job: &Job) -> Result<Vec<Shape>, Error> {
    match &job.task {
        Task::Thickness { surface, .. } => load_shape(surface, job)
            .map(|s| vec![s])
            .map_err(Error::Shape),
        Task::Morph { a, b } => Ok(vec![
            load_shape(a, job).map_err(Error::Shape)?,
            load_shape(b, job).map_err(Error::Shape)?,
        ]),
    }
}

/// The family of the task on one grid.
fn family_on(job: &Job, shapes: &[Shape], grid: &shape::BackgroundGrid, depth: f64) -> ShapeFamily {
    let positions = grid.vertex_positions();
    match job.task {
        Task::Thickness { curved, .. } => ShapeFamily::Thickness {
            solid: shapes[0].sdf.evaluate(&positions),
            depth,
            surface: curved.then(|| Arc::clone(&shapes[0].sdf)),
        },
        Task::Morph { .. } => ShapeFamily::Morph {
            a: shapes[0].sdf.evaluate(&positions),
            b: shapes[1].sdf.evaluate(&positions),
        },
    }
}

/// Fits the task's parameter on every rank (module docs), then solves the body at the answer on
/// the finest grid. The shapes are [`load_shapes`]'s.
pub fn run(
    petsc: &Petsc,
    job: &Job,
    shapes: Vec<Shape>,
    progress: &Progress,
) -> Result<Report, Error> {
    compute(petsc, job, shapes, progress).map_err(Error::Fit)
}

fn compute(
    petsc: &Petsc,
    job: &Job,
    shapes: Vec<Shape>,
    progress: &Progress,
) -> Result<Report, String> {
    let total = Instant::now();
    let options = MarchingOptions::default();
    let (lo, hi) = union_box(&shapes.iter().map(|s| &s.surface).collect::<Vec<_>>());
    let depth = match job.task {
        Task::Thickness { .. } => reference_depth(&shapes[0].sdf, &shapes[0].surface)
            .map_err(|e| format!("{}: {e}", shapes[0].path.display()))?,
        Task::Morph { .. } => f64::NAN,
    };
    let parameter_name = job.task.parameter_name();
    if matches!(job.task, Task::Thickness { .. }) {
        progress.say(format!(
            "{}: reference depth S = {:.4} mm (deepest point of the solid)",
            shapes[0].path.display(),
            1e3 * depth
        ));
    }
    let mut levels = Vec::new();
    for (cells, r) in replica_levels(
        &job.cells,
        job.replicas,
        replicate_every_level(&job.task, &job.settings),
    ) {
        let grid = shifted_covering(lo, hi, cells, replica_shift(r, job.replicas))
            .map_err(|e| e.to_string())?;
        levels.push(ShapeLevel {
            family: family_on(job, &shapes, &grid, depth),
            grid,
        });
    }
    let setup_seconds = total.elapsed().as_secs_f64();

    // The target.
    let clock = Instant::now();
    let (target_eigenvalues, target_spacing, truth) = match &job.target {
        TargetSource::Given {
            eigenvalues,
            spacing,
            ..
        } => (eigenvalues.clone(), *spacing, None),
        TargetSource::Synthetic {
            value,
            cells,
            seed,
            spacing,
        } => {
            let mut rng = SplitMix64::new(*seed);
            let shift = [0; 3].map(|_| rng.uniform(-0.5, 0.5));
            let grid = shifted_covering(lo, hi, *cells, shift).map_err(|e| e.to_string())?;
            progress.say(format!("synthesising the target: {parameter_name} {value} on a {cells}-cell grid shifted by {:.2?} cells", shift));
            let plain = ShapeLevel {
                family: family_on(job, &shapes, &grid, depth),
                grid,
            };
            // The target is refined at its own inner wall as the fit levels are at theirs.
            let target_level = plain
                .near_wall(
                    *value,
                    job.settings.wall_band,
                    job.settings.wall_refinement,
                    job.settings.wall_tolerance,
                )
                .map_err(|e| format!("the synthesised target: {e}"))?
                .unwrap_or(plain);
            if target_level.grid.is_refined() {
                progress.say(format!(
                    "target grid refined {} times near its walls: {} background tets",
                    job.settings.wall_refinement,
                    target_level.grid.n_tets()
                ));
            }
            let (grid, family) = (&target_level.grid, &target_level.family);
            let (spectrum, _) = family
                .spectrum(
                    petsc,
                    grid,
                    *value,
                    &options,
                    &job.material,
                    job.settings.modes,
                    false,
                )
                .map_err(|e| format!("the synthesised target: {e}"))?;
            (
                spectrum.eigenvalues,
                spacing.unwrap_or(grid.spacing()[0]),
                Some((*value, *cells)),
            )
        }
    };
    let target = SpectrumTarget::new(target_eigenvalues, job.settings.cluster_rtol)
        .map_err(|e| e.to_string())?;
    let target_seconds = clock.elapsed().as_secs_f64();
    progress.say(format!(
        "target: {} modes, {:.1} … {:.1} Hz, {} group(s)",
        target.len(),
        crate::eigen::frequency_hz(target.eigenvalues[0]),
        crate::eigen::frequency_hz(*target.eigenvalues.last().expect("non-empty")),
        target.groups.len()
    ));

    // The fit.
    let clock = Instant::now();
    let fit = fit_shape(petsc, &levels, &target, &options, &job.material, &job.settings, Some(target_spacing), |e: &FitEvaluation| {
        let phase = if e.phase == SearchPhase::Scan { "scan" } else { "refine" };
        match &e.failure {
            None => progress.say(format!("level {} ({} cells) {phase}: {parameter_name} {:.5}, loss {:.4e}, dL/dp {:+.3e}, {} tets; mesh {:.2} s, assembly {:.2} s, solve {:.2} s, gradient {:.2} s", e.level, e.cells, e.parameter, e.loss, e.gradient, e.tets, e.timings.meshing, e.timings.assembly, e.timings.solve, e.timings.gradient)),
            Some(f) => progress.say(format!("level {} ({} cells) {phase}: {parameter_name} {:.5}: no body ({f})", e.level, e.cells, e.parameter)),
        }
    })
    .map_err(|e| e.to_string())?;
    let fit_seconds = clock.elapsed().as_secs_f64();

    // The fitted body on the finest grid, with its modes, for the mesh file and the comparison.
    let clock = Instant::now();
    let finest = levels.last().expect("at least one level");
    // Refined as the finest level was during the fit (around that level's start).
    let finest_refined = match fit.levels.last().and_then(|l| l.wall_centre) {
        Some(p0) => finest
            .near_wall(
                p0,
                job.settings.wall_band,
                job.settings.wall_refinement,
                job.settings.wall_tolerance,
            )
            .map_err(|e| format!("the fitted body: {e}"))?,
        None => None,
    };
    let finest = finest_refined.as_ref().unwrap_or(finest);
    let body = finest
        .family
        .modes(
            petsc,
            &finest.grid,
            fit.parameter,
            &options,
            &job.material,
            job.settings.modes,
        )
        .map_err(|e| format!("the fitted body: {e}"))?;
    let final_seconds = clock.elapsed().as_secs_f64();

    Ok(Report {
        depth,
        target_spacing,
        truth,
        fitted: fit
            .levels
            .last()
            .expect("at least one level")
            .eigenvalues
            .clone(),
        fit,
        target,
        body,
        timings: Timings {
            setup: setup_seconds,
            target: target_seconds,
            fit: fit_seconds,
            final_body: final_seconds,
            total: total.elapsed().as_secs_f64(),
        },
        n_ranks: petsc.size(),
        shapes,
    })
}

/// The fit, the target it matched and the body at the answer.
pub struct Report {
    /// The shapes, as [`load_shapes`] placed them.
    pub shapes: Vec<Shape>,
    pub fit: ShapeFit,
    pub target: SpectrumTarget,
    /// λ [rad²/s²] of the finest level's best fit (the model on that grid).
    pub fitted: Vec<f64>,
    /// The thickness's reference depth S [m] (NaN for a morph).
    pub depth: f64,
    /// The spacing [m] the extrapolation aims at.
    pub target_spacing: f64,
    /// A synthesised target's true value and grid cells.
    pub truth: Option<(f64, usize)>,
    /// The body at the answer on the finest grid, with its modes.
    pub body: ShapeModes,
    pub timings: Timings,
    pub n_ranks: usize,
}

/// Seconds per stage of [`run`].
#[derive(Clone, Copy, Debug)]
pub struct Timings {
    pub setup: f64,
    pub target: f64,
    pub fit: f64,
    pub final_body: f64,
    pub total: f64,
}
