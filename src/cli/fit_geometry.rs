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
//! `format_version` = 1, `surface`, `command`, `version`, `n_ranks`, `settings_json`):
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
//! | `/network/parameters`, `/network/prefit_parameters` | θ after and before refinement (layout in [`crate::inverse::neural_sdf`]); attrs `octaves`, `length` [m], `centre_x/y/z` [m], text `hidden`, `config_json` |
//! | `/voxels` attrs | `resolution`, `occupied`, `edge_x/y/z` [m] |
//! | `/material` attrs, `/timings` attrs | E, ν, ρ; `voxelise`, `prefit`, `target`, `refine`, `assess`, `final_body`, `total` [s] |
//!
//! `<out stem>_mesh.h5` + `.xdmf` (ParaView): the refined body on the fit grid, P2 (curved
//! boundary by default), with its modes ([`crate::io::write_modes`] layout). `png` (default `<out stem>.png`): the voxels,
//! the pre-fitted body, the refined body and the true surface side by side, from two views, at
//! one scale. Progress per step on stderr (with `-v`, or on a terminal); only rank 0 writes.

use super::fail;
use super::fit_shape::{MaterialConfig, SolverConfig};
use crate::fem::Material;
use crate::inverse::geometry::{fit_geometry, GeometryFit, GeometryProgress, GeometrySettings};
use crate::inverse::shape::{curved_field_modes, normalise_surface, read_surface, shape_modes};
use crate::io::plot::{surface_png, SurfaceFigure, SurfacePanel, View};
use crate::io::results::ResultsFile;
use crate::io::{write_modes, MaterialRecord, ModesFile};
use crate::mesh::{self, MarchingOptions, SignedDistance, TriangleSurface};
use crate::petsc::Petsc;
use clap::Args;
use mpi::environment::Universe;
use serde::Deserialize;
use std::path::{Path, PathBuf};

#[derive(Args, Debug, Clone, Default)]
#[command(allow_negative_numbers = true)]
pub struct FitGeometryArgs {
    /// TOML configuration file (keys in the module docs of src/cli/fit_geometry.rs); flags override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// The true surface: OBJ, or a Gmsh .msh whose boundary is used.
    #[arg(long)]
    pub surface: Option<PathBuf>,
    /// Length unit of the surface file: m, cm, mm, um, in, ft, or metres per unit (default m).
    #[arg(long)]
    pub units: Option<String>,
    /// Scale the surface to this bounding-box diagonal in metres (default: keep its size).
    #[arg(long)]
    pub diagonal: Option<f64>,
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
    /// Material preset (default ceramic); --youngs Pa, --poisson, --density kg/m³ override it.
    #[arg(long)]
    pub material: Option<String>,
    #[arg(long)]
    pub youngs: Option<f64>,
    #[arg(long)]
    pub poisson: Option<f64>,
    #[arg(long)]
    pub density: Option<f64>,
    /// HDF5 result (default fit_geometry.h5); the mesh goes to <stem>_mesh.h5 + .xdmf.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Before/after/true picture (default <out stem>.png).
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Print progress even when stderr is not a terminal.
    #[arg(long, short)]
    pub verbose: bool,
    /// PETSc/SLEPc options, after `--`.
    #[arg(last = true, allow_hyphen_values = true)]
    pub petsc_options: Vec<String>,
}

/// The TOML file (every key optional; flags override).
///
/// ```toml
/// surface = "spot.obj"
/// units = "m"
/// diagonal = 0.1
/// out = "out/spot_geometry.h5"
/// png = "out/spot_geometry.png"
/// [geometry]                # GeometrySettings: voxels, cells, target_cells, target_seed,
/// voxels = 16               # bias_correction, target_grid_check, modes, cluster_rtol, octaves, hidden, network_seed,
/// [geometry.refine]         # surface_samples, volume_samples, metric_seed; [geometry.prefit]
/// steps = 30                # PrefitSettings; [geometry.refine] RefineSettings
/// method = "gauss_newton"   # (steps, method = "adam" | "gauss_newton", damping, free_scale, curved_boundary, learning_rate, …)
/// [material]
/// preset = "ceramic"
/// [solver]
/// petsc_options = []
/// ```
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GeometryFileConfig {
    pub surface: Option<PathBuf>,
    pub units: Option<String>,
    pub diagonal: Option<f64>,
    pub out: Option<PathBuf>,
    pub png: Option<PathBuf>,
    pub geometry: Option<GeometrySettings>,
    #[serde(default)]
    pub material: MaterialConfig,
    #[serde(default)]
    pub solver: SolverConfig,
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

/// Merges defaults < config file < flags and validates.
pub fn resolve(args: &FitGeometryArgs) -> Result<Job, String> {
    let file = match &args.config {
        Some(p) => {
            let text = std::fs::read_to_string(p).map_err(|e| format!("{}: {e}", p.display()))?;
            toml::from_str::<GeometryFileConfig>(&text)
                .map_err(|e| format!("{}: {e}", p.display()))?
        }
        None => GeometryFileConfig::default(),
    };
    let surface = args
        .surface
        .clone()
        .or(file.surface.clone())
        .ok_or("no surface given: use --surface FILE")?;
    if !surface.is_file() {
        return Err(format!("surface {} does not exist", surface.display()));
    }
    let units = args
        .units
        .clone()
        .or(file.units.clone())
        .unwrap_or_else(|| "m".into());
    let unit_scale = mesh::parse_unit(&units).map_err(|e| e.to_string())?;
    let diagonal = args.diagonal.or(file.diagonal);
    if let Some(d) = diagonal {
        if !(d.is_finite() && d > 0.0) {
            return Err(format!(
                "--diagonal must be a positive length in metres, got {d}"
            ));
        }
    }
    let mut s = file.geometry.clone().unwrap_or_default();
    if let Some(v) = args.voxels {
        s.voxels = v;
    }
    if let Some(v) = args.cells {
        s.cells = v;
    }
    if let Some(v) = args.target_cells {
        s.target_cells = v;
    }
    if let Some(v) = args.target_seed {
        s.target_seed = v;
    }
    if let Some(v) = args.modes {
        s.modes = v;
    }
    if let Some(v) = args.steps {
        s.refine.steps = v;
    }
    if let Some(v) = args.learning_rate {
        s.refine.learning_rate = v;
    }
    if let Some(v) = args.max_field_change {
        s.refine.max_field_change = v;
    }
    if let Some(v) = args.method {
        s.refine.method = v;
    }
    if let Some(v) = args.damping {
        s.refine.damping = v;
    }
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
    if let Some(v) = args.voxel_weight {
        s.refine.voxel_weight = v;
    }
    if let Some(v) = args.eikonal_weight {
        s.refine.eikonal_weight = v;
    }
    if let Some(v) = args.prefit_steps {
        s.prefit.steps = v;
    }
    if let Some(v) = args.octaves {
        s.octaves = v;
    }
    if !args.hidden.is_empty() {
        s.hidden = args.hidden.clone();
    }
    if let Some(seed) = args.seed {
        s.network_seed = seed;
        s.prefit.seed = seed;
        s.refine.seed = seed;
    }
    s.validate().map_err(|e| e.to_string())?;

    let flags = super::config::MaterialConfig {
        preset: args.material.clone(),
        youngs_modulus: args.youngs,
        poisson_ratio: args.poisson,
        density: args.density,
        ..Default::default()
    };
    let material = file.material.resolve(&flags)?;

    let out = args
        .out
        .clone()
        .or(file.out.clone())
        .unwrap_or_else(|| PathBuf::from("fit_geometry.h5"));
    super::resolve::check_output(&out, &[])?;
    let stem = out.with_extension("");
    let mesh_out = crate::io::paths::plot_path(&stem, "_mesh.h5");
    let png = args
        .png
        .clone()
        .or(file.png.clone())
        .unwrap_or_else(|| crate::io::paths::plot_path(&stem, ".png"));
    super::resolve::check_output(&png, &[])?;
    let mut petsc_options = file.solver.petsc_options.clone();
    petsc_options.extend(args.petsc_options.iter().cloned());
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
        verbose: args.verbose,
    })
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

pub fn run(universe: Universe, args: FitGeometryArgs) -> Result<(), String> {
    let job = resolve(&args)?;
    let (surface, sdf, warnings) = load_surface(&job.surface, job.unit_scale, job.diagonal)?;
    let petsc =
        Petsc::initialize(universe, "diffsound", &job.petsc_options).map_err(|e| e.to_string())?;
    let (rank, size) = (petsc.rank(), petsc.size());
    if rank == 0 {
        for w in &warnings {
            eprintln!("warning: {}: {w}", job.surface.display());
        }
    }
    match compute(&petsc, &job, &surface, &sdf) {
        Ok(()) => Ok(()),
        Err(message) => fail(rank, size, &message),
    }
}

fn compute(
    petsc: &Petsc,
    job: &Job,
    truth: &TriangleSurface,
    sdf: &SignedDistance,
) -> Result<(), String> {
    let total = std::time::Instant::now();
    let rank = petsc.rank();
    let progress = super::stderr_progress(rank, job.verbose);
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
    let clock = std::time::Instant::now();
    let net = crate::inverse::neural_sdf::NeuralSdf::from_parameters(
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
    if rank == 0 {
        print_summary(&fit);
        write_results(
            job,
            &fit,
            &body,
            final_seconds,
            total.elapsed().as_secs_f64(),
            petsc.size(),
        )?;
        render_comparison(&job.png, &fit, truth, &format!("{}: {}^3 voxels -> pre-fit (before) -> refined by {} eigenvalues (after); C = Chamfer distance", job.surface.file_name().map_or(String::new(), |n| n.to_string_lossy().to_string()), job.settings.voxels, job.settings.modes))?;
        println!(
            "wrote {}, {} (+ .xdmf) and {}",
            job.out.display(),
            job.mesh_out.display(),
            job.png.display()
        );
    }
    Ok(())
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

/// The voxels, the pre-fitted and refined bodies and the true surface side by side (two views,
/// one scale), in millimetres.
pub fn render_comparison(
    path: &Path,
    fit: &GeometryFit,
    truth: &TriangleSurface,
    title: &str,
) -> Result<(), String> {
    let mm = |s: &TriangleSurface| {
        s.vertices
            .iter()
            .map(|v| v.map(|x| 1e3 * x))
            .collect::<Vec<_>>()
    };
    let voxels = fit.voxels.boundary_surface();
    // The plot font is ASCII: "16^3", not "16³". Titles stay short enough for one cell.
    let label = |name: &str, a: &crate::inverse::geometry::Assessed| {
        format!(
            "{name}: C {:.2} mm, IoU {:.3}",
            1e3 * a.comparison.chamfer,
            a.comparison.iou
        )
    };
    let panels = vec![
        SurfacePanel::new(
            format!(
                "{n}^3 voxels: C {:.2} mm",
                1e3 * fit.voxel_comparison.chamfer,
                n = fit.voxels.resolution
            ),
            mm(&voxels),
            voxels.triangles.clone(),
        ),
        SurfacePanel::new(
            label("before", &fit.before),
            mm(&fit.before.surface),
            fit.before.surface.triangles.clone(),
        ),
        SurfacePanel::new(
            label("after", &fit.after),
            mm(&fit.after.surface),
            fit.after.surface.triangles.clone(),
        ),
        SurfacePanel::new("true", mm(truth), truth.triangles.clone()),
    ];
    let mut fig = SurfaceFigure::new(title, panels);
    fig.views = vec![
        View::new(30.0, 25.0),
        View::new(210.0, 20.0),
        View::labelled(0.0, 89.0, "top"),
    ];
    fig.panel_size = 340;
    surface_png(path, &fig).map_err(|e| e.to_string())
}

fn write_results(
    job: &Job,
    fit: &GeometryFit,
    body: &crate::inverse::shape::ShapeModes,
    final_seconds: f64,
    total: f64,
    n_ranks: usize,
) -> Result<(), String> {
    let hz = |v: &[f64]| {
        v.iter()
            .map(|&l| crate::eigen::frequency_hz(l))
            .collect::<Vec<f64>>()
    };
    let mut file = ResultsFile::new("diffsound.fit_geometry", 1);
    file.text("/", "surface", &job.surface.display().to_string())
        .text(
            "/",
            "command",
            &std::env::args().collect::<Vec<_>>().join(" "),
        )
        .text("/", "version", env!("CARGO_PKG_VERSION"))
        .text(
            "/",
            "settings_json",
            &serde_json::to_string(&job.settings).map_err(|e| e.to_string())?,
        )
        .number("/", "n_ranks", n_ranks as f64);
    let c = &fit.voxel_comparison;
    file.number("/metrics/voxels", "chamfer", c.chamfer)
        .number("/metrics/voxels", "hausdorff", c.hausdorff)
        .number("/metrics/voxels", "iou", c.iou);
    let loss_of = |a: &crate::inverse::geometry::Assessed| {
        crate::inverse::geometry::eigenvalue_loss(&a.eigenvalues, &fit.target)
            .map(|(l, _)| l)
            .unwrap_or(f64::NAN)
    };
    for (name, a) in [
        ("before", &fit.before),
        ("after", &fit.after),
        ("floor", &fit.floor),
    ] {
        let g = format!("/metrics/{name}");
        file.number(&g, "chamfer", a.comparison.chamfer)
            .number(&g, "hausdorff", a.comparison.hausdorff)
            .number(&g, "iou", a.comparison.iou)
            .number(
                &g,
                "rms_frequency_error",
                a.rms_frequency_error(&fit.target),
            )
            .number(&g, "eigen_loss", loss_of(a))
            .number(&g, "volume", a.volume);
        file.column(
            &format!("/modes/{name}_eigenvalues"),
            a.eigenvalues.clone(),
            "rad^2/s^2",
        )
        .column(
            &format!("/modes/{name}_frequency_hz"),
            hz(&a.eigenvalues),
            "Hz",
        )
        .column(
            &format!("/modes/{name}_relative_frequency_error"),
            a.eigenvalues
                .iter()
                .zip(&fit.target.eigenvalues)
                .map(|(l, t)| (l / t).sqrt() - 1.0)
                .collect(),
            "1",
        );
    }
    if !fit.bias_correction.is_empty() {
        file.column("/modes/bias_correction", fit.bias_correction.clone(), "1");
    }
    if let Some(c) = &fit.check {
        file.number("/check", "before_loss", c.before_loss)
            .number("/check", "after_loss", c.after_loss)
            .number(
                "/check",
                "refined_kept",
                f64::from(u8::from(c.refined_kept)),
            );
    }
    file.column(
        "/modes/target_eigenvalues",
        fit.target.eigenvalues.clone(),
        "rad^2/s^2",
    )
    .column(
        "/modes/target_frequency_hz",
        hz(&fit.target.eigenvalues),
        "Hz",
    )
    .number("/modes", "target_spacing", fit.target_spacing);
    let h = &fit.refinement.history;
    let col = |f: &dyn Fn(&crate::inverse::geometry::RefineStep) -> f64| {
        h.iter().map(f).collect::<Vec<f64>>()
    };
    file.column("/refine/history/step", col(&|s| s.step as f64), "")
        .column("/refine/history/loss", col(&|s| s.loss), "1")
        .column("/refine/history/eigen_loss", col(&|s| s.eigen_loss), "1")
        .column("/refine/history/voxel_loss", col(&|s| s.voxel_loss), "1")
        .column(
            "/refine/history/eikonal_loss",
            col(&|s| s.eikonal_loss),
            "1",
        )
        .column("/refine/history/tets", col(&|s| s.tets as f64), "")
        .column("/refine/history/p2_nodes", col(&|s| s.p2_nodes as f64), "")
        .column(
            "/refine/history/meshing_s",
            col(&|s| s.timings.meshing),
            "s",
        )
        .column(
            "/refine/history/assembly_s",
            col(&|s| s.timings.assembly),
            "s",
        )
        .column("/refine/history/solve_s", col(&|s| s.timings.solve), "s")
        .column(
            "/refine/history/gradient_s",
            col(&|s| s.timings.gradient),
            "s",
        )
        .column(
            "/refine/history/network_s",
            col(&|s| s.network_seconds),
            "s",
        )
        .column("/refine/history/step_scale", col(&|s| s.step_scale), "1")
        .column(
            "/refine/history/backtracked",
            col(&|s| f64::from(u8::from(s.backtracked))),
            "",
        )
        .column(
            "/refine/history/failed",
            col(&|s| f64::from(u8::from(s.failure.is_some()))),
            "",
        )
        .number("/refine", "best_step", fit.refinement.best_step as f64)
        .number("/refine", "seconds", fit.refinement.seconds);
    let (mean, network) = fit.refinement.mean_timings();
    file.number("/refine/mean_step", "meshing", mean.meshing)
        .number("/refine/mean_step", "assembly", mean.assembly)
        .number("/refine/mean_step", "solve", mean.solve)
        .number("/refine/mean_step", "gradient", mean.gradient)
        .number("/refine/mean_step", "network", network)
        .number("/refine/mean_step", "total", mean.total() + network);
    file.column("/prefit/loss", fit.prefit.loss.clone(), "1")
        .number("/prefit", "centre_accuracy", fit.prefit.centre_accuracy)
        .number("/prefit", "sign_loss", fit.prefit.sign_loss)
        .number("/prefit", "eikonal_loss", fit.prefit.eikonal_loss)
        .number("/prefit", "seconds", fit.prefit.seconds);
    let n = &fit.network;
    file.column(
        "/network/parameters",
        fit.refinement.best_parameters.clone(),
        "1",
    )
    .column(
        "/network/prefit_parameters",
        fit.prefit_parameters.clone(),
        "1",
    )
    .number("/network", "octaves", n.octaves as f64)
    .number("/network", "length", n.length)
    .number("/network", "centre_x", n.centre[0])
    .number("/network", "centre_y", n.centre[1])
    .number("/network", "centre_z", n.centre[2])
    .text(
        "/network",
        "hidden",
        &n.hidden
            .iter()
            .map(|w| w.to_string())
            .collect::<Vec<_>>()
            .join(","),
    )
    .text(
        "/network",
        "config_json",
        &serde_json::to_string(n).map_err(|e| e.to_string())?,
    );
    let v = &fit.voxels;
    file.number("/voxels", "resolution", v.resolution as f64)
        .number("/voxels", "occupied", v.occupied() as f64)
        .number("/voxels", "edge_x", v.size[0])
        .number("/voxels", "edge_y", v.size[1])
        .number("/voxels", "edge_z", v.size[2]);
    file.number("/material", "youngs_modulus", job.material.youngs_modulus)
        .number("/material", "poisson_ratio", job.material.poisson_ratio)
        .number("/material", "density", job.material.density);
    let t = &fit.timings;
    for (k, value) in [
        ("voxelise", t.voxelise),
        ("prefit", t.prefit),
        ("target", t.target),
        ("refine", t.refine),
        ("assess", t.assess),
        ("final_body", final_seconds),
        ("total", total),
    ] {
        file.number("/timings", k, value);
    }
    file.write(&job.out).map_err(|e| e.to_string())?;

    let frequencies = hz(&body.eigenvalues);
    let mesh_file = ModesFile {
        nodes: &body.mesh.nodes,
        connectivity: &body.mesh.connectivity,
        nodes_per_tet: body.mesh.nodes_per_tet(),
        material: MaterialRecord {
            name: "refined geometry (MLP SDF)".into(),
            youngs_modulus: job.material.youngs_modulus,
            poisson_ratio: job.material.poisson_ratio,
            density: job.material.density,
            rayleigh_alpha: job.material.rayleigh_alpha,
            rayleigh_beta: job.material.rayleigh_beta,
        },
        eigenvalues: &body.eigenvalues,
        frequencies_hz: &frequencies,
        mode_shapes: &body.shapes,
        residual_norms: &body.residuals,
        rigid_eigenvalues: &body.rigid_eigenvalues,
        solver: Vec::new(),
        n_ranks,
        element_order: 2,
        timings: Vec::new(),
        provenance: vec![
            (
                "command".into(),
                std::env::args().collect::<Vec<_>>().join(" "),
            ),
            ("fit".into(), job.out.display().to_string()),
        ],
        extra_datasets: Vec::new(),
        node_fields: Vec::new(),
    };
    write_modes(&job.mesh_out, &mesh_file).map_err(|e| e.to_string())
}
