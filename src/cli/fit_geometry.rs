//! `diffsound fit-geometry`: a body known only as a coarse voxelisation, refined by its
//! spectrum (issue 7, task 3).
//!
//! The command line of the job in [`crate::workflow::fit_geometry`] (its module docs give the
//! inputs, the method and the files): the flags and the TOML file ([`GeometryFileConfig`])
//! merged into a [`Job`], the job run, its summary printed and its files written.

use super::resolve::{existing, path_or, set, ElasticArgs, RunArgs, SurfaceArgs};
use crate::inverse::geometry::GeometryFit;
use crate::io::config::{load_toml, GeometryFileConfig};
use crate::workflow::fit_geometry;
pub use crate::workflow::fit_geometry::{load_surface, Job};
use clap::Args;
use mpi::environment::Universe;
use std::path::PathBuf;

#[derive(Args, Debug, Clone, Default)]
#[command(allow_negative_numbers = true)]
pub struct FitGeometryArgs {
    /// TOML configuration file (keys in the module docs of src/io/config.rs); flags override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// The true surface: OBJ, or a Gmsh .msh whose boundary is used.
    #[arg(long)]
    pub surface: Option<PathBuf>,
    #[command(flatten)]
    pub scale: SurfaceArgs,
    /// Voxels per axis over the bounding box (default 16).
    #[arg(long)]
    pub voxels: Option<usize>,
    /// Fit grid: cells along the longest axis (default 20).
    #[arg(long)]
    pub cells: Option<usize>,
    /// Target grid: cells along the longest axis, at least --cells (default 32; equal: the same spacing on a shifted grid).
    #[arg(long)]
    pub target_cells: Option<usize>,
    /// Seed of the target grid's random shift (default 1).
    #[arg(long)]
    pub target_seed: Option<u64>,
    /// Eigenvalues compared (default 12).
    #[arg(long)]
    pub modes: Option<usize>,
    /// Updates of the refinement (default 30).
    #[arg(long)]
    pub steps: Option<usize>,
    /// Adam step size of the refinement with --method adam (default 5e-4).
    #[arg(long)]
    pub learning_rate: Option<f64>,
    /// Step cap: largest change of the field at a grid vertex per update, in grid cells (default 0.2).
    #[arg(long)]
    pub max_field_change: Option<f64>,
    /// Refinement update: gauss_newton (default; the minimum-norm Levenberg step, module docs of src/inverse/geometry.rs) or adam.
    #[arg(long)]
    pub method: Option<crate::inverse::geometry::RefineMethod>,
    /// Initial Levenberg damping of the Gauss–Newton step, relative to the mean diagonal of J Jᵀ (default 1e-3).
    #[arg(long)]
    pub damping: Option<f64>,
    /// Compare only the spectrum's shape: a common factor of all eigenvalues (an unknown stiffness) is profiled out of the refinement's loss.
    #[arg(long)]
    pub free_scale: bool,
    /// Keep the refined field even if, solved on the target's cell count, it matches the target worse than the pre-fitted field (by default the pre-fitted field is then the answer).
    #[arg(long)]
    pub no_target_grid_check: bool,
    /// Mesh every body from the grid samples alone, with straight P2 edges (by default the crossings and the boundary mid-edge nodes sit on the zero of the continuous field: the network's, or the true signed distance's for the target and the floor).
    #[arg(long)]
    pub straight_boundary: bool,
    /// No grid-bias correction (by default the pre-fitted field is also solved on the target's cell count and the target moved by the difference of the log-eigenvalues).
    #[arg(long)]
    pub no_bias_correction: bool,
    /// Weight of the voxel sign constraint in the refinement (default 1).
    #[arg(long)]
    pub voxel_weight: Option<f64>,
    /// Weight of the eikonal regulariser in the refinement (default 0.1).
    #[arg(long)]
    pub eikonal_weight: Option<f64>,
    /// Adam updates of the pre-fit (default 1000).
    #[arg(long)]
    pub prefit_steps: Option<usize>,
    /// Octaves of the positional encoding (default 3).
    #[arg(long)]
    pub octaves: Option<usize>,
    /// Hidden layer widths (default 32,32,32).
    #[arg(long, value_delimiter = ',')]
    pub hidden: Vec<usize>,
    /// Seed of the network's initialisation, the pre-fit's batches and the eikonal points (default 1).
    #[arg(long)]
    pub seed: Option<u64>,
    #[command(flatten)]
    pub elastic: ElasticArgs,
    /// HDF5 result (default fit_geometry.h5); the mesh goes to <stem>_mesh.h5 + .xdmf.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Before/after/true picture (default <out stem>.png).
    #[arg(long)]
    pub png: Option<PathBuf>,
    #[command(flatten)]
    pub run: RunArgs,
}

/// Merges defaults < config file < flags and validates.
pub fn resolve(args: &FitGeometryArgs) -> Result<Job, String> {
    let file: GeometryFileConfig = load_toml(&args.config).map_err(|e| e.to_string())?;
    let surface = existing(
        args.surface.clone().or(file.surface.clone()),
        "surface",
        "--surface",
    )?;
    let (unit_scale, diagonal) = args.scale.resolve(&file.units, file.diagonal)?;
    let mut s = file.geometry.clone().unwrap_or_default();
    set(&mut s.voxels, args.voxels);
    set(&mut s.cells, args.cells);
    set(&mut s.target_cells, args.target_cells);
    set(&mut s.target_seed, args.target_seed);
    set(&mut s.modes, args.modes);
    set(&mut s.refine.steps, args.steps);
    set(&mut s.refine.learning_rate, args.learning_rate);
    set(&mut s.refine.max_field_change, args.max_field_change);
    set(&mut s.refine.method, args.method);
    set(&mut s.refine.damping, args.damping);
    if args.free_scale {
        s.refine.free_scale = true;
    }
    if args.no_target_grid_check {
        s.target_grid_check = false;
    }
    if args.no_bias_correction {
        s.bias_correction = false;
    }
    if args.straight_boundary {
        s.refine.curved_boundary = false;
    }
    set(&mut s.refine.voxel_weight, args.voxel_weight);
    set(&mut s.refine.eikonal_weight, args.eikonal_weight);
    set(&mut s.prefit.steps, args.prefit_steps);
    set(&mut s.octaves, args.octaves);
    if !args.hidden.is_empty() {
        s.hidden = args.hidden.clone();
    }
    if let Some(seed) = args.seed {
        s.network_seed = seed;
        s.prefit.seed = seed;
        s.refine.seed = seed;
    }
    s.validate().map_err(|e| e.to_string())?;

    let material = args.elastic.resolve(&file.material)?;

    let out = path_or(&args.out, &file.out, "fit_geometry.h5");
    let stem = out.with_extension("");
    let mesh_out = crate::io::paths::plot_path(&stem, "_mesh.h5");
    let png = args
        .png
        .clone()
        .or(file.png.clone())
        .unwrap_or_else(|| crate::io::paths::plot_path(&stem, ".png"));
    // The figure's format from --png's extension, before any work.
    crate::io::plot::ImageFormat::for_path(&png, crate::io::plot::RASTER_FORMATS)
        .map_err(|e| e.to_string())?;
    // No output may be one of the inputs: the surface or the config file.
    let mut given: Vec<(&str, &std::path::Path)> = vec![("the surface", surface.as_path())];
    if let Some(c) = &args.config {
        given.push(("the config file", c.as_path()));
    }
    for o in [&out, &mesh_out, &mesh_out.with_extension("xdmf"), &png] {
        super::resolve::check_output(o, &given)?;
    }
    let mut petsc_options = file.solver.petsc_options.clone();
    petsc_options.extend(args.run.petsc_options.iter().cloned());
    Ok(Job {
        surface,
        unit_scale,
        diagonal,
        settings: s,
        material,
        out,
        mesh_out,
        png,
        petsc_options,
        verbose: args.run.verbose,
    })
}

pub fn run(universe: Universe, args: FitGeometryArgs) -> Result<(), String> {
    let job = resolve(&args)?;
    let (surface, sdf, warnings) = load_surface(&job.surface, job.unit_scale, job.diagonal)?;
    super::with_petsc(
        universe,
        &job.petsc_options,
        job.verbose,
        |petsc, progress| {
            let rank = petsc.rank();
            if rank == 0 {
                for w in &warnings {
                    eprintln!("warning: {}: {w}", job.surface.display());
                }
            }
            let report = fit_geometry::run(petsc, &job, &surface, &sdf, progress)?;
            if rank == 0 {
                print_summary(&report.fit);
                fit_geometry::write::write_outputs(&job, &report, &surface)?;
                println!(
                    "wrote {}, {} (+ .xdmf) and {}",
                    job.out.display(),
                    job.mesh_out.display(),
                    job.png.display()
                );
            }
            Ok::<(), fit_geometry::Error>(())
        },
    )
}

/// The before/after table on stdout.
fn print_summary(fit: &GeometryFit) {
    let mm = 1e3;
    println!(
        "fit-geometry: best step {} of {} (loss {:.4e} → {:.4e})",
        fit.refinement.best_step,
        fit.refinement.history.len() - 1,
        fit.refinement.history[0].loss,
        fit.refinement.best().loss
    );
    println!(
        "  {:<22} {:>12} {:>14} {:>8} {:>14}",
        "", "Chamfer mm", "Hausdorff mm", "IoU", "rms freq err"
    );
    println!(
        "  {:<22} {:>12.3} {:>14.3} {:>8.4} {:>14}",
        "voxels",
        mm * fit.voxel_comparison.chamfer,
        mm * fit.voxel_comparison.hausdorff,
        fit.voxel_comparison.iou,
        "-"
    );
    for (name, a) in [
        ("before (pre-fit)", &fit.before),
        ("after (refined)", &fit.after),
        ("true SDF, fit grid", &fit.floor),
    ] {
        println!(
            "  {:<22} {:>12.3} {:>14.3} {:>8.4} {:>13.3}%",
            name,
            mm * a.comparison.chamfer,
            mm * a.comparison.hausdorff,
            a.comparison.iou,
            100.0 * a.rms_frequency_error(&fit.target)
        );
    }
}
