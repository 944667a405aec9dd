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
//! `format_version` = 1, `task` (`thickness` | `morph`), `parameter_name`, `surfaces`,
//! `command`, `version`, `n_ranks`):
//!
//! | path | contents |
//! |------|----------|
//! | `/fit` attrs | `wall_refinement`, `wall_band`, `wall_tolerance` (the grid refinement near the walls; 0 halvings: none), `parameter` (the answer), `finest_level_parameter` (the mean over the finest spacing's replicas), `extrapolated` (if any), `target_spacing` [m], `loss` (finest level), `evaluations`, `seconds`; synthesised targets add `true_parameter`, `abs_error`, `target_cells` |
//! | `/fit/levels/{cells,spacing,parameter,loss,log_stiffness_scale,evaluations,seconds,grid_tets,wall_centre}` | per level, coarse to fine (replicas of a spacing are consecutive entries with equal cells); spacing in m (of the structured grid); log_stiffness_scale the profiled ln factor with `--free-scale` (else 0); grid_tets the background tets after any refinement, wall_centre the t its inner-wall band was centred on (NaN: not refined) |
//! | `/fit/history/{level,cells,phase,parameter,loss,gradient,step,tets,p2_nodes,meshing_s,assembly_s,solve_s,gradient_s,failed}` | every evaluation (phase 0 = scan, 1 = refine; failed 1 where no body could be meshed or solved, loss NaN) |
//! | `/modes/{target_frequency_hz,fitted_frequency_hz,target_eigenvalues,fitted_eigenvalues,relative_frequency_error}` | the compared modes: target vs the finest level's best fit (the model on that grid) |
//! | `/modes/answer_frequency_hz` | the body at the answer (extrapolated) parameter on the finest grid: the mesh file's modes |
//! | `/shape` attrs | `reference_depth` [m] and `curved_boundary` (1: exact crossings and curved P2 edges, 0: `--straight-boundary`) for thickness, `diagonal` [m], `finest_cells`, `tets`, `p2_nodes`, `volume` [m³] of the P2 body |
//! | `/material` attrs | `youngs_modulus` [Pa], `poisson_ratio`, `density` [kg/m³] |
//! | `/timings` attrs | `setup`, `target`, `fit`, `final_body`, `total` [s] |
//!
//! and `<out stem>_mesh.h5` + `.xdmf` (ParaView): the fitted body on the finest grid, P2, with
//! its modes ([`crate::io::write_modes`] layout). Progress on stderr per evaluation (with
//! `-v`, or on a terminal); only rank 0 writes.

use super::fail;
use crate::fem::Material;
use crate::inverse::shape::{
    answers_with_line, fit_shape, normalise_surface, read_surface, reference_depth, replica_levels,
    replica_line_levels, replica_shift, shifted_covering, union_box, FitEvaluation, SearchPhase,
    ShapeFamily, ShapeFit, ShapeFitSettings, ShapeLevel, SpectrumTarget,
};
use crate::io::results::ResultsFile;
use crate::io::{write_modes, MaterialRecord, ModesFile};
use crate::mesh::{self, MarchingOptions, SignedDistance, TriangleSurface};
use crate::petsc::Petsc;
use crate::random::SplitMix64;
use clap::Args;
use mpi::environment::Universe;
use serde::Deserialize;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Flags shared by both commands.
#[derive(Args, Debug, Clone, Default)]
#[command(allow_negative_numbers = true)]
pub struct ShapeArgs {
    /// TOML configuration file (keys in the module docs of src/cli/fit_shape.rs); flags override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Length unit of the surface files: m, cm, mm, um, in, ft, or metres per unit (default m).
    #[arg(long)]
    pub units: Option<String>,
    /// Scale every shape to this bounding-box diagonal in metres (default: keep its size).
    #[arg(long)]
    pub diagonal: Option<f64>,
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
    /// Material preset (default ceramic); --youngs Pa, --poisson, --density kg/m³ override it.
    #[arg(long)]
    pub material: Option<String>,
    #[arg(long)]
    pub youngs: Option<f64>,
    #[arg(long)]
    pub poisson: Option<f64>,
    #[arg(long)]
    pub density: Option<f64>,
    /// HDF5 result (default fit_thickness.h5 / fit_morph.h5); the mesh goes to <stem>_mesh.h5 + .xdmf.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print progress even when stderr is not a terminal.
    #[arg(long, short)]
    pub verbose: bool,
    /// PETSc/SLEPc options, after `--`.
    #[arg(last = true, allow_hyphen_values = true)]
    pub petsc_options: Vec<String>,
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

/// The TOML file (every key optional; flags override).
///
/// ```toml
/// surface = "spot.obj"          # fit-thickness; fit-morph takes shape_a and shape_b
/// units = "m"
/// diagonal = 0.1
/// cells = [20, 28]
/// replicas = 1                  # grids per replicated level (1–4): the finest, or all but the first for the line
/// straight_boundary = false      # fit-thickness: true meshes from the grid samples alone
/// out = "out/spot_thickness.h5"
/// [target]
/// file = "modes.txt"            # or: thickness = 0.5 (fit-morph: weight = 0.4), cells = 40, seed = 1
/// units = "hz"
/// spacing = 0.0
/// [material]
/// preset = "ceramic"            # youngs_modulus, poisson_ratio, density
/// [fit]                         # ShapeFitSettings: modes, bounds, scan_points, max_refinements,
/// modes = 8                     # tolerance, refine_window, cluster_rtol, extrapolate, free_scale,
/// wall_refinement = 0           # wall_band, wall_tolerance (fit-thickness, curved boundary)
/// [solver]
/// petsc_options = []
/// ```
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShapeFileConfig {
    pub surface: Option<PathBuf>,
    pub shape_a: Option<PathBuf>,
    pub shape_b: Option<PathBuf>,
    pub units: Option<String>,
    pub diagonal: Option<f64>,
    pub cells: Option<Vec<usize>>,
    pub replicas: Option<usize>,
    /// fit-thickness: true for the straight boundary (`--straight-boundary`).
    pub straight_boundary: Option<bool>,
    pub out: Option<PathBuf>,
    #[serde(default)]
    pub target: TargetConfig,
    #[serde(default)]
    pub material: MaterialConfig,
    pub fit: Option<ShapeFitSettings>,
    #[serde(default)]
    pub solver: SolverConfig,
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetConfig {
    pub file: Option<PathBuf>,
    pub units: Option<String>,
    pub thickness: Option<f64>,
    pub weight: Option<f64>,
    pub cells: Option<usize>,
    pub seed: Option<u64>,
    pub spacing: Option<f64>,
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialConfig {
    pub preset: Option<String>,
    pub youngs_modulus: Option<f64>,
    pub poisson_ratio: Option<f64>,
    pub density: Option<f64>,
}

impl MaterialConfig {
    /// The preset with the flags' and then the file's E, ν, ρ, validated: the shared
    /// resolution of [`super::config::MaterialConfig::resolve`] (shape fits take no damping).
    pub fn resolve(&self, flags: &super::config::MaterialConfig) -> Result<Material, String> {
        let shared = super::config::MaterialConfig {
            preset: self.preset.clone(),
            youngs_modulus: self.youngs_modulus,
            poisson_ratio: self.poisson_ratio,
            density: self.density,
            ..Default::default()
        };
        shared.resolve(flags).map(|(material, _)| material)
    }
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SolverConfig {
    #[serde(default)]
    pub petsc_options: Vec<String>,
}

/// Whether replicas go on every level after the first (the answer is the line through the
/// levels) or on the finest alone (the answer is the finest spacing's mean: the curved
/// thickness body unless told `--extrapolate`).
fn replicate_every_level(task: &Task, settings: &ShapeFitSettings) -> bool {
    answers_with_line(
        settings.extrapolate,
        matches!(task, Task::Thickness { curved: true, .. }),
    )
}

/// Which parameter is fitted, and of what.
#[derive(Clone, Debug)]
pub enum Task {
    /// `curved`: exact crossings and a curved boundary on the continuous signed distance.
    Thickness {
        surface: PathBuf,
        curved: bool,
    },
    Morph {
        a: PathBuf,
        b: PathBuf,
    },
}

/// Where the target spectrum comes from.
#[derive(Clone, Debug)]
pub enum TargetSource {
    /// λ* [rad²/s²] from a file, and the spacing the extrapolation aims at.
    Given {
        path: PathBuf,
        eigenvalues: Vec<f64>,
        spacing: f64,
    },
    /// The true parameter on a shifted grid of `cells`.
    Synthetic {
        value: f64,
        cells: usize,
        seed: u64,
        spacing: Option<f64>,
    },
}

/// Everything resolved and checked before PETSc starts.
#[derive(Clone, Debug)]
pub struct Job {
    pub task: Task,
    pub unit_scale: f64,
    pub diagonal: Option<f64>,
    pub cells: Vec<usize>,
    /// Grids per replicated level ([`crate::inverse::shape::replica_levels`], [`crate::inverse::shape::replica_shift`]).
    pub replicas: usize,
    pub target: TargetSource,
    pub material: Material,
    pub settings: ShapeFitSettings,
    pub out: PathBuf,
    pub mesh_out: PathBuf,
    pub petsc_options: Vec<String>,
    pub verbose: bool,
}

impl Task {
    fn name(&self) -> &'static str {
        match self {
            Task::Thickness { .. } => "thickness",
            Task::Morph { .. } => "morph",
        }
    }

    /// The fitted parameter's name, as [`ShapeFamily::parameter_name`] says it.
    fn parameter_name(&self) -> &'static str {
        match self {
            Task::Thickness { .. } => "thickness",
            Task::Morph { .. } => "morph weight c",
        }
    }
}

/// Reads frequencies or eigenvalues: numbers separated by whitespace or commas, `#` comments.
pub fn parse_target(text: &str, path: &Path, hertz: bool) -> Result<Vec<f64>, String> {
    let mut values = Vec::new();
    for (line_no, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("");
        for token in line
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|t| !t.is_empty())
        {
            let v: f64 = token.parse().map_err(|_| {
                format!(
                    "{}: line {}: {token:?} is not a number",
                    path.display(),
                    line_no + 1
                )
            })?;
            if !(v.is_finite() && v > 0.0) {
                return Err(format!(
                    "{}: line {}: target values must be positive, got {v}",
                    path.display(),
                    line_no + 1
                ));
            }
            values.push(if hertz {
                (2.0 * std::f64::consts::PI * v).powi(2)
            } else {
                v
            });
        }
    }
    if values.is_empty() {
        return Err(format!("{}: no target values in the file", path.display()));
    }
    values.sort_by(f64::total_cmp);
    Ok(values)
}

fn load_config(path: &Option<PathBuf>) -> Result<ShapeFileConfig, String> {
    match path {
        Some(p) => {
            let text = std::fs::read_to_string(p).map_err(|e| format!("{}: {e}", p.display()))?;
            toml::from_str::<ShapeFileConfig>(&text).map_err(|e| format!("{}: {e}", p.display()))
        }
        None => Ok(ShapeFileConfig::default()),
    }
}

fn existing(path: Option<PathBuf>, what: &str, flag: &str) -> Result<PathBuf, String> {
    let p = path.ok_or_else(|| format!("no {what} given: use {flag} FILE"))?;
    if !p.is_file() {
        return Err(format!("{what} {} does not exist", p.display()));
    }
    Ok(p)
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
    let units = common
        .units
        .clone()
        .or(file.units.clone())
        .unwrap_or_else(|| "m".into());
    let unit_scale = mesh::parse_unit(&units).map_err(|e| e.to_string())?;
    let diagonal = common.diagonal.or(file.diagonal);
    if let Some(d) = diagonal {
        if !(d.is_finite() && d > 0.0) {
            return Err(format!(
                "--diagonal must be a positive length in metres, got {d}"
            ));
        }
    }
    let cells = if common.cells.is_empty() {
        file.cells.clone().unwrap_or_else(|| vec![20, 28])
    } else {
        common.cells.clone()
    };
    if cells.is_empty() || cells.iter().any(|&c| !(4..=200).contains(&c)) {
        return Err(format!(
            "--cells must be one or more grid sizes in 4..=200, got {cells:?}"
        ));
    }
    if cells.windows(2).any(|w| w[0] >= w[1]) {
        return Err(format!(
            "--cells must increase from coarse to fine, got {cells:?}"
        ));
    }
    let replicas = common.replicas.or(file.replicas).unwrap_or(1);
    if !(1..=4).contains(&replicas) {
        return Err(format!("--replicas must lie in 1..=4, got {replicas}"));
    }
    let mut settings = file.fit.clone().unwrap_or_else(|| match task {
        Task::Thickness { .. } => ShapeFitSettings::default(),
        Task::Morph { .. } => ShapeFitSettings::morph(),
    });
    if let Some(m) = common.modes {
        settings.modes = m;
    }
    if let Some(b) = bounds {
        settings.bounds = b;
    }
    if let Some(n) = common.scan_points {
        settings.scan_points = n;
    }
    if let Some(n) = common.max_refinements {
        settings.max_refinements = n;
    }
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
    if let Some(n) = wall.0 {
        settings.wall_refinement = n;
    }
    if let Some(w) = wall.1 {
        settings.wall_band = w;
    }
    if let Some(e) = wall.2 {
        settings.wall_tolerance = e;
    }
    if settings.wall_refinement > 0 && !matches!(task, Task::Thickness { curved: true, .. }) {
        return Err("wall refinement needs the curved thickness body (not fit-morph, not --straight-boundary)".into());
    }
    settings.validate().map_err(|e| e.to_string())?;
    // The line goes through the same number of spacings, each with all its replicas.
    settings.extrapolation_levels = replica_line_levels(
        settings.extrapolation_levels,
        replicas,
        replicate_every_level(&task, &settings),
    );
    let (lo, hi) = settings.bounds;
    match task {
        Task::Thickness { .. } if !(lo > 0.0 && hi <= 1.0) => {
            return Err(format!("thickness bounds ({lo}, {hi}) must lie in (0, 1]"))
        }
        Task::Morph { .. } if !(lo >= 0.0 && hi <= 1.0) => {
            return Err(format!(
                "morph weight bounds ({lo}, {hi}) must lie in [0, 1]"
            ))
        }
        _ => {}
    }

    let target_file = common.target.clone().or(file.target.file.clone());
    let spacing = common.target_spacing.or(file.target.spacing);
    if let Some(h) = spacing {
        if !(h.is_finite() && h >= 0.0) {
            return Err(format!("--target-spacing must be ≥ 0 metres, got {h}"));
        }
    }
    let target = match (target_file, synthetic_value) {
        (Some(_), Some(_)) => return Err("give either a target file or a true value to synthesise a target from, not both".into()),
        (None, None) => return Err(format!("no target: use --target FILE (frequencies in Hz) or --target-{} VALUE with --target-cells N", if matches!(task, Task::Thickness { .. }) { "thickness" } else { "weight" })),
        (Some(path), None) => {
            let target_units = common.target_units.clone().or(file.target.units.clone()).unwrap_or_else(|| "hz".into());
            let hertz = match target_units.to_ascii_lowercase().as_str() {
                "hz" => true,
                "rad2" => false,
                other => return Err(format!("--target-units must be hz or rad2, got {other:?}")),
            };
            let text = std::fs::read_to_string(&path).map_err(|e| format!("target file {}: {e}", path.display()))?;
            let eigenvalues = parse_target(&text, &path, hertz)?;
            if eigenvalues.len() < settings.modes {
                return Err(format!("{}: {} target values for {} compared modes (lower --modes or give more)", path.display(), eigenvalues.len(), settings.modes));
            }
            TargetSource::Given { path, eigenvalues: eigenvalues[..settings.modes].to_vec(), spacing: spacing.unwrap_or(0.0) }
        }
        (None, Some(value)) => {
            if !(value >= lo && value <= hi) {
                return Err(format!("the true {} {value} lies outside the bounds [{lo}, {hi}]", task.name()));
            }
            let target_cells = common.target_cells.or(file.target.cells).unwrap_or(40);
            let finest = *cells.last().expect("non-empty");
            if target_cells <= finest || target_cells > 200 {
                return Err(format!("--target-cells must exceed the finest fit level ({finest}) and be at most 200, got {target_cells}"));
            }
            TargetSource::Synthetic { value, cells: target_cells, seed: common.target_seed.or(file.target.seed).unwrap_or(1), spacing }
        }
    };

    let flags = super::config::MaterialConfig {
        preset: common.material.clone(),
        youngs_modulus: common.youngs,
        poisson_ratio: common.poisson,
        density: common.density,
        ..Default::default()
    };
    let material = file.material.resolve(&flags)?;

    let out = common
        .out
        .clone()
        .or(file.out.clone())
        .unwrap_or_else(|| PathBuf::from(format!("fit_{}.h5", task.name())));
    super::resolve::check_output(&out, &[])?;
    let mesh_out = crate::io::paths::plot_path(&out.with_extension(""), "_mesh.h5");
    let mut petsc_options = file.solver.petsc_options.clone();
    petsc_options.extend(common.petsc_options.iter().cloned());
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
        verbose: common.verbose,
    })
}

pub fn resolve_thickness(args: &FitThicknessArgs) -> Result<Job, String> {
    let file = load_config(&args.common.config)?;
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
    let file = load_config(&args.common.config)?;
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
    let shapes = load_shapes(&job)?;
    let petsc =
        Petsc::initialize(universe, "diffsound", &job.petsc_options).map_err(|e| e.to_string())?;
    let (rank, size) = (petsc.rank(), petsc.size());
    match compute(&petsc, &job, shapes) {
        Ok(()) => Ok(()),
        Err(message) => fail(rank, size, &message),
    }
}

/// A shape ready to sample: its name, placed surface and signed distance.
struct Shape {
    path: PathBuf,
    surface: TriangleSurface,
    sdf: Arc<SignedDistance>,
    /// The reader's warnings (dropped degenerate triangles, ignored element types, …).
    warnings: Vec<String>,
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

fn load_shapes(job: &Job) -> Result<Vec<Shape>, String> {
    match &job.task {
        Task::Thickness { surface, .. } => Ok(vec![load_shape(surface, job)?]),
        Task::Morph { a, b } => Ok(vec![load_shape(a, job)?, load_shape(b, job)?]),
    }
}

/// The family of the task on one grid.
fn family_on(job: &Job, shapes: &[Shape], grid: &mesh::BackgroundGrid, depth: f64) -> ShapeFamily {
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

fn compute(petsc: &Petsc, job: &Job, shapes: Vec<Shape>) -> Result<(), String> {
    let total = std::time::Instant::now();
    let rank = petsc.rank();
    let progress = super::stderr_progress(rank, job.verbose);
    if rank == 0 {
        for shape in &shapes {
            for w in &shape.warnings {
                eprintln!("warning: {}: {w}", shape.path.display());
            }
        }
    }
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
    let clock = std::time::Instant::now();
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
    let clock = std::time::Instant::now();
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
    let clock = std::time::Instant::now();
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

    if rank == 0 {
        let fitted = &fit.levels.last().expect("at least one level").eigenvalues;
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
        write_results(
            job,
            &shapes,
            &fit,
            &target,
            fitted,
            depth,
            target_spacing,
            truth,
            &body,
            [
                setup_seconds,
                target_seconds,
                fit_seconds,
                final_seconds,
                total.elapsed().as_secs_f64(),
            ],
            petsc.size(),
        )?;
        println!(
            "wrote {} and {} (+ .xdmf)",
            job.out.display(),
            job.mesh_out.display()
        );
    }
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn write_results(
    job: &Job,
    shapes: &[Shape],
    fit: &ShapeFit,
    target: &SpectrumTarget,
    fitted: &[f64],
    depth: f64,
    target_spacing: f64,
    truth: Option<(f64, usize)>,
    body: &crate::inverse::shape::ShapeModes,
    [setup, target_s, fit_s, final_s, total]: [f64; 5],
    n_ranks: usize,
) -> Result<(), String> {
    let hz = |v: &[f64]| {
        v.iter()
            .map(|&l| crate::eigen::frequency_hz(l))
            .collect::<Vec<f64>>()
    };
    let mut file = ResultsFile::new("diffsound.fit_shape", 1);
    file.text("/", "task", job.task.name())
        .text("/", "parameter_name", job.task.parameter_name())
        .text(
            "/",
            "surfaces",
            &shapes
                .iter()
                .map(|s| s.path.display().to_string())
                .collect::<Vec<_>>()
                .join(", "),
        )
        .text(
            "/",
            "command",
            &std::env::args().collect::<Vec<_>>().join(" "),
        )
        .text("/", "version", env!("CARGO_PKG_VERSION"))
        .number("/", "n_ranks", n_ranks as f64);
    let finest = fit.levels.last().expect("at least one level");
    file.number("/fit", "parameter", fit.parameter)
        .number("/fit", "finest_level_parameter", fit.finest_parameter())
        .number("/fit", "target_spacing", target_spacing)
        .number("/fit", "loss", finest.loss)
        .number("/fit", "evaluations", fit.history.len() as f64)
        .number("/fit", "seconds", fit.seconds);
    if let Some(e) = fit.extrapolated {
        file.number("/fit", "extrapolated", e);
    }
    if let Some((value, cells)) = truth {
        file.number("/fit", "true_parameter", value)
            .number("/fit", "abs_error", (fit.parameter - value).abs())
            .number("/fit", "target_cells", cells as f64);
    }
    let l = &fit.levels;
    file.column(
        "/fit/levels/cells",
        l.iter().map(|l| l.cells as f64).collect(),
        "",
    )
    .column(
        "/fit/levels/spacing",
        l.iter().map(|l| l.spacing).collect(),
        "m",
    )
    .column(
        "/fit/levels/parameter",
        l.iter().map(|l| l.parameter).collect(),
        "1",
    )
    .column("/fit/levels/loss", l.iter().map(|l| l.loss).collect(), "1")
    .column(
        "/fit/levels/log_stiffness_scale",
        l.iter().map(|l| l.log_scale).collect(),
        "1",
    )
    .column(
        "/fit/levels/evaluations",
        l.iter().map(|l| l.evaluations as f64).collect(),
        "",
    )
    .column(
        "/fit/levels/seconds",
        l.iter().map(|l| l.seconds).collect(),
        "s",
    )
    .column(
        "/fit/levels/grid_tets",
        l.iter().map(|l| l.grid_tets as f64).collect(),
        "",
    )
    .column(
        "/fit/levels/wall_centre",
        l.iter()
            .map(|l| l.wall_centre.unwrap_or(f64::NAN))
            .collect(),
        "1",
    );
    file.number(
        "/fit",
        "wall_refinement",
        job.settings.wall_refinement as f64,
    )
    .number("/fit", "wall_band", job.settings.wall_band)
    .number("/fit", "wall_tolerance", job.settings.wall_tolerance);
    let h = &fit.history;
    file.column(
        "/fit/history/level",
        h.iter().map(|e| e.level as f64).collect(),
        "",
    )
    .column(
        "/fit/history/cells",
        h.iter().map(|e| e.cells as f64).collect(),
        "",
    )
    .column(
        "/fit/history/phase",
        h.iter()
            .map(|e| {
                if e.phase == SearchPhase::Scan {
                    0.0
                } else {
                    1.0
                }
            })
            .collect(),
        "",
    )
    .column(
        "/fit/history/parameter",
        h.iter().map(|e| e.parameter).collect(),
        "1",
    )
    .column("/fit/history/loss", h.iter().map(|e| e.loss).collect(), "1")
    .column(
        "/fit/history/gradient",
        h.iter().map(|e| e.gradient).collect(),
        "1",
    )
    .column("/fit/history/step", h.iter().map(|e| e.step).collect(), "1")
    .column(
        "/fit/history/tets",
        h.iter().map(|e| e.tets as f64).collect(),
        "",
    )
    .column(
        "/fit/history/p2_nodes",
        h.iter().map(|e| e.p2_nodes as f64).collect(),
        "",
    )
    .column(
        "/fit/history/meshing_s",
        h.iter().map(|e| e.timings.meshing).collect(),
        "s",
    )
    .column(
        "/fit/history/assembly_s",
        h.iter().map(|e| e.timings.assembly).collect(),
        "s",
    )
    .column(
        "/fit/history/solve_s",
        h.iter().map(|e| e.timings.solve).collect(),
        "s",
    )
    .column(
        "/fit/history/gradient_s",
        h.iter().map(|e| e.timings.gradient).collect(),
        "s",
    )
    .column(
        "/fit/history/failed",
        h.iter()
            .map(|e| f64::from(u8::from(e.failure.is_some())))
            .collect(),
        "",
    );
    let (target_hz, fitted_hz) = (hz(&target.eigenvalues), hz(fitted));
    file.column(
        "/modes/target_eigenvalues",
        target.eigenvalues.clone(),
        "rad^2/s^2",
    )
    .column("/modes/fitted_eigenvalues", fitted.to_vec(), "rad^2/s^2")
    .column(
        "/modes/relative_frequency_error",
        fitted_hz
            .iter()
            .zip(&target_hz)
            .map(|(f, t)| f / t - 1.0)
            .collect(),
        "1",
    )
    .column("/modes/target_frequency_hz", target_hz, "Hz")
    .column("/modes/fitted_frequency_hz", fitted_hz, "Hz")
    .column(
        "/modes/answer_frequency_hz",
        hz(&body.eigenvalues[..fitted.len()]),
        "Hz",
    );
    // ∫ det J over the P2 elements: the curved boundary's volume, not its chords' (det J is a
    // cubic, so the degree-4 rule is exact).
    let rule = crate::fem::tet_rule(4);
    let volume = (0..body.mesh.n_tets())
        .map(|e| crate::fem::element_volume(&body.mesh.tet_coords(e), &rule))
        .sum::<Result<f64, _>>()
        .map_err(|e| format!("the fitted body's volume: {e}"))?;
    let (lo, hi) = union_box(&shapes.iter().map(|s| &s.surface).collect::<Vec<_>>());
    file.number(
        "/shape",
        "diagonal",
        (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt(),
    )
    .number("/shape", "finest_cells", finest.cells as f64)
    .number("/shape", "tets", body.mesh.n_tets() as f64)
    .number("/shape", "p2_nodes", body.mesh.n_nodes() as f64)
    .number("/shape", "volume", volume);
    if let Task::Thickness { curved, .. } = job.task {
        file.number("/shape", "reference_depth", depth).number(
            "/shape",
            "curved_boundary",
            f64::from(u8::from(curved)),
        );
    }
    file.number("/material", "youngs_modulus", job.material.youngs_modulus)
        .number("/material", "poisson_ratio", job.material.poisson_ratio)
        .number("/material", "density", job.material.density);
    for (k, v) in [
        ("setup", setup),
        ("target", target_s),
        ("fit", fit_s),
        ("final_body", final_s),
        ("total", total),
    ] {
        file.number("/timings", k, v);
    }
    file.write(&job.out).map_err(|e| e.to_string())?;

    let frequencies = hz(&body.eigenvalues);
    let mesh_file = ModesFile {
        nodes: &body.mesh.nodes,
        connectivity: &body.mesh.connectivity,
        nodes_per_tet: body.mesh.nodes_per_tet(),
        material: MaterialRecord {
            name: format!("fitted {} = {:.5}", job.task.name(), fit.parameter),
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn target_files_parse_hertz_and_eigenvalues_with_comments() {
        let p = Path::new("t.txt");
        let v = parse_target("# modes\n200, 100\n300 # last\n", p, true).unwrap();
        let w = |f: f64| (2.0 * std::f64::consts::PI * f).powi(2);
        assert_eq!(v, vec![w(100.0), w(200.0), w(300.0)]);
        assert_eq!(parse_target("4e6 1e6", p, false).unwrap(), vec![1e6, 4e6]);
        for (bad, what) in [
            ("1 x 2", "not a number"),
            ("-5", "positive"),
            ("# nothing", "no target values"),
        ] {
            let e = parse_target(bad, p, true).unwrap_err();
            assert!(e.contains(what) && e.contains("t.txt"), "{bad}: {e}");
        }
    }
}
