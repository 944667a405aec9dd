//! `diffsound fit-thickness` and `diffsound fit-morph`: one shape parameter from target
//! eigenvalues (issue 7).
//!
//! The command line of the jobs in [`crate::workflow::fit_shape`] (its module docs give the
//! inputs, the method and the files): the flags and the TOML file ([`ShapeFileConfig`])
//! merged into a [`Job`], the job run, its summary printed and its files written.

use super::resolve::{existing, path_or, set, ElasticArgs, RunArgs, SurfaceArgs};
use crate::inverse::shape::ShapeFitSettings;
use crate::io::config::{load_toml, ShapeFileConfig};
use crate::workflow::fit_shape::{self, Report};
pub use crate::workflow::fit_shape::{parse_target, Job, TargetChoice, TargetSource, Task};
use clap::Args;
use mpi::environment::Universe;
use std::path::PathBuf;

/// Flags shared by both commands.
#[derive(Args, Debug, Clone, Default)]
#[command(allow_negative_numbers = true)]
pub struct ShapeArgs {
    /// TOML configuration file (keys in the module docs of src/io/config.rs); flags override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    #[command(flatten)]
    pub scale: SurfaceArgs,
    /// Grid levels, coarse to fine: cells along the longest axis (default 20,28).
    #[arg(long, value_delimiter = ',')]
    pub cells: Vec<usize>,
    /// Grids per replicated level, each moved by r/K of a cell along the diagonal (1–4, default
    /// 1): the finest level when the answer is the finest level's (curved thickness; the answer
    /// is then their mean), else every level after the first (the line goes through all).
    #[arg(long)]
    pub replicas: Option<usize>,
    /// Modes compared (default 8).
    #[arg(long)]
    pub modes: Option<usize>,
    /// Target frequencies (Hz) or eigenvalues (with --target-units rad2) in a text file.
    #[arg(long)]
    pub target: Option<PathBuf>,
    /// Units of the target file: hz (default) or rad2 (eigenvalues in rad²/s²).
    #[arg(long)]
    pub target_units: Option<String>,
    /// Grid cells of a synthesised target (default 40; finer than every fit level).
    #[arg(long)]
    pub target_cells: Option<usize>,
    /// Seed of the synthesised target's random grid shift (default 1).
    #[arg(long)]
    pub target_seed: Option<u64>,
    /// The target's grid spacing in metres for the extrapolation (default: 0 for a file
    /// target, the target grid's for a synthesised one).
    #[arg(long)]
    pub target_spacing: Option<f64>,
    /// Answer with the finest level instead of the extrapolation to the target spacing.
    #[arg(long)]
    pub no_extrapolate: bool,
    /// Answer with the extrapolation (the default for fit-morph and a straight-boundary
    /// thickness fit; a curved-boundary thickness fit answers with its finest level).
    #[arg(long)]
    pub extrapolate: bool,
    /// Profile a stiffness factor common to every mode out of the loss (the spectrum's shape,
    /// not its level, decides; see "Free stiffness scale" in src/inverse/shape.rs).
    #[arg(long)]
    pub free_scale: bool,
    /// Evaluations of the scan on the coarsest level (default 9 for thickness, 6 for morph).
    #[arg(long)]
    pub scan_points: Option<usize>,
    /// Most refinement evaluations per level (default 8).
    #[arg(long)]
    pub max_refinements: Option<usize>,
    #[command(flatten)]
    pub elastic: ElasticArgs,
    /// HDF5 result (default fit_thickness.h5 / fit_morph.h5); the mesh goes to <stem>_mesh.h5 + .xdmf.
    #[arg(long)]
    pub out: Option<PathBuf>,
    #[command(flatten)]
    pub run: RunArgs,
}

#[derive(Args, Debug, Clone, Default)]
#[command(allow_negative_numbers = true)]
pub struct FitThicknessArgs {
    /// The solid's surface: OBJ, or a Gmsh .msh whose boundary is used.
    #[arg(long)]
    pub surface: Option<PathBuf>,
    /// Synthesise the target from this relative thickness (instead of --target).
    #[arg(long)]
    pub target_thickness: Option<f64>,
    /// Lowest and highest thickness searched, lo,hi (default 0.1,0.95).
    #[arg(long, value_delimiter = ',')]
    pub bounds: Vec<f64>,
    /// Mesh the shell from the grid samples alone (linear crossings, straight P2 edges) instead
    /// of exact crossings and a curved boundary on the continuous signed distance (see "Curved
    /// boundary" in src/inverse/shape.rs).
    #[arg(long)]
    pub straight_boundary: bool,
    /// Halve the grid this many times (0–3, default 0) near the outer wall and the inner walls
    /// around each level's start, where the samples do not resolve the signed distance, on
    /// every level after the first and on a synthesised target (around its true thickness);
    /// see "Refinement near the walls" in src/inverse/shape.rs.
    #[arg(long)]
    pub wall_refinement: Option<usize>,
    /// The thickness half-range ±w around a level's start whose inner walls are refined
    /// (default 0.05).
    #[arg(long)]
    pub wall_band: Option<f64>,
    /// Refine only where an edge midpoint's signed distance misses the corners' mean by more
    /// than this fraction of the tet's longest edge (default 0.05; 0: the whole bands).
    #[arg(long)]
    pub wall_tolerance: Option<f64>,
    #[command(flatten)]
    pub common: ShapeArgs,
}

#[derive(Args, Debug, Clone, Default)]
#[command(allow_negative_numbers = true)]
pub struct FitMorphArgs {
    /// Shape A (weight c): OBJ or .msh.
    #[arg(long)]
    pub shape_a: Option<PathBuf>,
    /// Shape B (weight 1 − c): OBJ or .msh.
    #[arg(long)]
    pub shape_b: Option<PathBuf>,
    /// Synthesise the target from this weight c ∈ [0, 1] (instead of --target).
    #[arg(long)]
    pub target_weight: Option<f64>,
    #[command(flatten)]
    pub common: ShapeArgs,
}

/// Merges defaults < config file < flags and validates, for either command.
fn resolve(
    task: Task,
    synthetic_value: Option<f64>,
    bounds: Option<(f64, f64)>,
    wall: (Option<usize>, Option<f64>, Option<f64>),
    common: &ShapeArgs,
    file: &ShapeFileConfig,
) -> Result<Job, String> {
    let (unit_scale, diagonal) = common.scale.resolve(&file.units, file.diagonal)?;
    let cells = if common.cells.is_empty() {
        file.cells.clone().unwrap_or_else(|| vec![20, 28])
    } else {
        common.cells.clone()
    };
    let replicas = common.replicas.or(file.replicas).unwrap_or(1);
    fit_shape::job::check_levels(&cells, replicas)?;
    let mut settings = file.fit.clone().unwrap_or_else(|| match task {
        Task::Thickness { .. } => ShapeFitSettings::default(),
        Task::Morph { .. } => ShapeFitSettings::morph(),
    });
    set(&mut settings.modes, common.modes);
    set(&mut settings.bounds, bounds);
    set(&mut settings.scan_points, common.scan_points);
    set(&mut settings.max_refinements, common.max_refinements);
    if common.no_extrapolate && common.extrapolate {
        return Err("--extrapolate and --no-extrapolate exclude each other".into());
    }
    if common.no_extrapolate {
        settings.extrapolate = Some(false);
    }
    if common.extrapolate {
        settings.extrapolate = Some(true);
    }
    if common.free_scale {
        settings.free_scale = true;
    }
    set(&mut settings.wall_refinement, wall.0);
    set(&mut settings.wall_band, wall.1);
    set(&mut settings.wall_tolerance, wall.2);
    fit_shape::job::finish_settings(&task, &mut settings, replicas)?;

    let choice = TargetChoice {
        file: common.target.clone().or(file.target.file.clone()),
        units: (common.target_units.clone().or(file.target.units.clone()))
            .unwrap_or_else(|| "hz".into()),
        synthetic: synthetic_value,
        cells: common.target_cells.or(file.target.cells).unwrap_or(40),
        seed: common.target_seed.or(file.target.seed).unwrap_or(1),
        spacing: common.target_spacing.or(file.target.spacing),
    };
    let target = choice.resolve(&task, &settings, *cells.last().expect("non-empty"))?;

    let material = common.elastic.resolve(&file.material)?;

    let out = path_or(&common.out, &file.out, &format!("fit_{}.h5", task.name()));
    let mesh_out = crate::io::paths::plot_path(&out.with_extension(""), "_mesh.h5");
    // No output may be one of the inputs: a shape, the target file or the config file.
    let mut given: Vec<(&str, &std::path::Path)> = match &task {
        Task::Thickness { surface, .. } => vec![("the surface", surface.as_path())],
        Task::Morph { a, b } => vec![("shape A", a.as_path()), ("shape B", b.as_path())],
    };
    if let TargetSource::Given { path, .. } = &target {
        given.push(("the target", path.as_path()));
    }
    if let Some(c) = &common.config {
        given.push(("the config file", c.as_path()));
    }
    for o in [&out, &mesh_out, &mesh_out.with_extension("xdmf")] {
        super::resolve::check_output(o, &given)?;
    }
    let mut petsc_options = file.solver.petsc_options.clone();
    petsc_options.extend(common.run.petsc_options.iter().cloned());
    Ok(Job {
        task,
        unit_scale,
        diagonal,
        cells,
        replicas,
        target,
        material,
        settings,
        out,
        mesh_out,
        petsc_options,
        verbose: common.run.verbose,
    })
}

pub fn resolve_thickness(args: &FitThicknessArgs) -> Result<Job, String> {
    let file = load_toml::<ShapeFileConfig>(&args.common.config).map_err(|e| e.to_string())?;
    if file.shape_a.is_some() || file.shape_b.is_some() || file.target.weight.is_some() {
        return Err(
            "shape_a, shape_b and target.weight are fit-morph keys, not fit-thickness ones".into(),
        );
    }
    let surface = existing(
        args.surface.clone().or(file.surface.clone()),
        "surface",
        "--surface",
    )?;
    let bounds = match args.bounds.as_slice() {
        [] => None,
        [lo, hi] => Some((*lo, *hi)),
        other => return Err(format!("--bounds takes lo,hi, got {other:?}")),
    };
    let curved = !(args.straight_boundary || file.straight_boundary.unwrap_or(false));
    resolve(
        Task::Thickness { surface, curved },
        args.target_thickness.or(file.target.thickness),
        bounds,
        (args.wall_refinement, args.wall_band, args.wall_tolerance),
        &args.common,
        &file,
    )
}

pub fn resolve_morph(args: &FitMorphArgs) -> Result<Job, String> {
    let file = load_toml::<ShapeFileConfig>(&args.common.config).map_err(|e| e.to_string())?;
    if file.surface.is_some() || file.target.thickness.is_some() || file.straight_boundary.is_some()
    {
        return Err("surface, straight_boundary and target.thickness are fit-thickness keys, not fit-morph ones".into());
    }
    let a = existing(
        args.shape_a.clone().or(file.shape_a.clone()),
        "shape A",
        "--shape-a",
    )?;
    let b = existing(
        args.shape_b.clone().or(file.shape_b.clone()),
        "shape B",
        "--shape-b",
    )?;
    resolve(
        Task::Morph { a, b },
        args.target_weight.or(file.target.weight),
        None,
        (None, None, None),
        &args.common,
        &file,
    )
}

pub fn run_thickness(universe: Universe, args: FitThicknessArgs) -> Result<(), String> {
    let job = resolve_thickness(&args)?;
    run(universe, job)
}

pub fn run_morph(universe: Universe, args: FitMorphArgs) -> Result<(), String> {
    let job = resolve_morph(&args)?;
    run(universe, job)
}

fn run(universe: Universe, job: Job) -> Result<(), String> {
    // The shapes are read before PETSc starts: a bad file ends the job with its message.
    let shapes = fit_shape::load_shapes(&job).map_err(|e| e.to_string())?;
    super::with_petsc(
        universe,
        &job.petsc_options,
        job.verbose,
        |petsc, progress| {
            let rank = petsc.rank();
            if rank == 0 {
                for shape in &shapes {
                    for w in &shape.warnings {
                        eprintln!("warning: {}: {w}", shape.path.display());
                    }
                }
            }
            let report = fit_shape::run(petsc, &job, shapes, progress)?;
            if rank == 0 {
                print_summary(&job, &report);
                fit_shape::write::write_outputs(&job, &report)?;
                println!(
                    "wrote {} and {} (+ .xdmf)",
                    job.out.display(),
                    job.mesh_out.display()
                );
            }
            Ok::<(), fit_shape::Error>(())
        },
    )
}

/// The answer, each level's, the extrapolation and the compared modes, on stdout.
fn print_summary(job: &Job, report: &Report) {
    let Report {
        fit,
        target,
        fitted,
        target_spacing,
        truth,
        body,
        ..
    } = report;
    let (target_spacing, truth) = (*target_spacing, *truth);
    let parameter_name = job.task.parameter_name();
    let answer = &body.eigenvalues[..job.settings.modes];
    let hz = |v: &[f64]| {
        v.iter()
            .map(|&l| crate::eigen::frequency_hz(l))
            .collect::<Vec<f64>>()
    };
    let (target_hz, fitted_hz, answer_hz) = (hz(&target.eigenvalues), hz(fitted), hz(answer));
    println!(
        "fit-{}: {parameter_name} = {:.5}{}",
        job.task.name(),
        fit.parameter,
        match truth {
            Some((v, _)) => format!(" (true {v}, error {:+.5})", fit.parameter - v),
            None => String::new(),
        }
    );
    for l in &fit.levels {
        let refined = l
            .wall_centre
            .map(|p0| {
                format!(
                    ", grid refined near the walls around {p0:.4} ({} background tets)",
                    l.grid_tets
                )
            })
            .unwrap_or_default();
        println!("  level {:>3} cells (h = {:.3} mm): {parameter_name} {:.5}, loss {:.3e}, {} evaluations, {:.1} s{refined}", l.cells, 1e3 * l.spacing, l.parameter, l.loss, l.evaluations, l.seconds);
    }
    if let Some(e) = fit.extrapolated {
        println!(
            "  extrapolated to the target spacing {:.3} mm: {e:.5}{}",
            1e3 * target_spacing,
            if fit.extrapolation_used {
                ""
            } else {
                " (not used: the answer is the finest level's)"
            }
        );
    }
    println!(
        "  {:>4} {:>12} {:>18} {:>9} {:>18}",
        "mode", "target Hz", "finest-level fit", "error", "answer, finest grid"
    );
    for k in 0..target_hz.len() {
        println!(
            "  {k:>4} {:>12.2} {:>18.2} {:>8.3}% {:>18.2}",
            target_hz[k],
            fitted_hz[k],
            100.0 * (fitted_hz[k] / target_hz[k] - 1.0),
            answer_hz[k]
        );
    }
}
