//! The `modes` job: the vibration modes of a free elastic body, from a tet mesh to HDF5/XDMF
//! (and optionally a WAV of one strike).
//!
//! Mesh → P2 (or P1) elements → assembly of the mass M and the stiffness K = λ_L K_λ + μ K_μ
//! (Lamé parameters of the material) → SLEPc for the generalised eigenproblem K φ = λ M φ with
//! mass-normalised φ (φᵀ M φ = 1). The six near-zero eigenvalues of the rigid-body motions are
//! removed; each elastic eigenvalue λ [rad²/s²] is a frequency f = √λ / 2π [Hz]. The solver's
//! default shift is σ = −10⁻²·μ/(ρL²) with L the bounding-box diagonal [m], and an inertia check
//! (Sylvester's law on K − τM) proves that no mode below the last one was missed.
//!
//! On request the job also computes the exact derivatives dλ/dE, dλ/dν, dλ/dρ of every eigenvalue
//! (cluster means inside near-degenerate clusters) and dλ/dx at every node.
//!
//! [`run`] is collective over all ranks; [`write_outputs`] and [`write_timings_json`] run on
//! rank 0, where the mode shapes are gathered.

mod write;

pub use write::{inertia_line, probe_line, write_outputs, write_timings_json};

use crate::assembly::{self, AssemblyError, AssemblyStats};
use crate::eigen::sensitivity::{self, ClusterTreatment, MaterialSensitivities, SensitivityError};
use crate::eigen::{
    self, EigenConfig, EigenError, IterativePreconditioner, ModeRequest, SolverPath,
};
use crate::fem::Material;
use crate::io::IoError;
use crate::mesh::{MeshError, ReadOptions, TetMesh};
use crate::petsc::{Petsc, PetscError};
use crate::workflow::model_mesh;
use crate::workflow::Progress;
use std::path::PathBuf;
use std::time::Instant;

/// Everything the job needs, resolved from defaults, the config file and the flags.
#[derive(Clone, Debug)]
pub struct Job {
    pub mesh: PathBuf,
    pub unit_scale: f64,
    pub units: String,
    pub order: u32,
    pub fix_inverted: bool,
    pub straighten_invalid: bool,
    pub material: Material,
    pub material_name: String,
    pub request: ModeRequest,
    pub tolerance: f64,
    /// The iterative path's tolerance when the user gave one (else its own default).
    pub iterative_tolerance: Option<f64>,
    pub solver_path: SolverPath,
    /// The iterative path's preconditioner.
    pub iterative_preconditioner: IterativePreconditioner,
    pub verify_count: bool,
    pub cluster_rtol: Option<f64>,
    pub shift: Option<f64>,
    pub out: PathBuf,
    pub wav: Option<PathBuf>,
    pub strike_vertex: Option<usize>,
    pub duration: f64,
    pub sample_rate: u32,
    pub timings_json: Option<PathBuf>,
    pub sensitivities: bool,
    pub node_gradients: bool,
    pub petsc_options: Vec<String>,
}

/// What can stop the job. Every message is the one the underlying stage wrote.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// The strike point of the WAV: no surface, or the node asked for is not on it.
    #[error("{0}")]
    Strike(String),
    #[error(transparent)]
    Assembly(#[from] AssemblyError),
    #[error(transparent)]
    Petsc(#[from] PetscError),
    #[error(transparent)]
    Eigen(#[from] EigenError),
    #[error(transparent)]
    Sensitivity(#[from] SensitivityError),
    #[error(transparent)]
    Io(#[from] IoError),
    #[error(transparent)]
    Audio(#[from] crate::audio::AudioError),
}

/// Seconds and memory of the stages beyond those the assembly and the solver keep themselves.
#[derive(Clone, Debug)]
pub struct Timings {
    /// When the job began (the outputs' "total" is measured from here when each is written).
    pub started: Instant,
    /// Forming K and M from the assembled parts.
    pub operator_seconds: f64,
    pub material_seconds: f64,
    pub node_gradient_seconds: f64,
    /// Material and node sensitivities together.
    pub sensitivity_seconds: f64,
    /// Peak resident memory summed over the ranks [bytes].
    pub peak_rss_sum: f64,
    /// The same at the end of each stage ("assembly", "preconditioner_setup" on the iterative
    /// path, "solve"), each rank's peak so far, summed [bytes].
    pub peak_rss_after: Vec<(String, f64)>,
}

impl Timings {
    pub fn total_seconds(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }
}

/// The job's results. The mode shapes are gathered on rank 0 only (empty elsewhere).
pub struct Report<'p> {
    /// The mesh the modes live on (lifted to P2 or reduced to P1), in metres.
    pub mesh: TetMesh,
    pub stats: AssemblyStats,
    pub modes: eigen::Modes<'p>,
    /// Mode shapes in original node order, `[mode][3·node + d]`, with the entry of largest
    /// magnitude positive (rank 0).
    pub shapes: Vec<Vec<f64>>,
    /// f = √λ / 2π [Hz] per elastic mode.
    pub frequencies: Vec<f64>,
    pub material_sensitivities: Option<MaterialSensitivities>,
    /// dλ/dx per mode, `[mode][3·node + d]` [rad²/(s²·m)] (rank 0).
    pub node_gradients: Option<Vec<Vec<f64>>>,
    /// The strike node and its outward unit normal, when a WAV is asked for.
    pub strike: Option<(usize, [f64; 3])>,
    pub timings: Timings,
    pub n_ranks: usize,
    /// PETSc's and SLEPc's version strings.
    pub versions: (String, String),
}

/// Computes the modes (and sensitivities) on every rank. Warnings go to stderr on rank 0 as they
/// arise, so that they precede any later error.
pub fn run<'p>(petsc: &'p Petsc, job: &Job, progress: &Progress) -> Result<Report<'p>, Error> {
    let started = Instant::now();
    let rank = petsc.rank();

    progress.say(format!("reading {}", job.mesh.display()));
    // Curved 10-node tets that fold over are refused with the file and Gmsh tags named, or
    // straightened on request (`mesh::straighten`), before any assembly.
    let (mesh, input_order) = model_mesh(
        petsc,
        &job.mesh,
        &ReadOptions {
            unit_scale: job.unit_scale,
            fix_inverted: job.fix_inverted,
        },
        job.straighten_invalid,
        job.order,
    )?;
    // Check the strike point now, not after a long solve.
    let strike_point = match &job.wav {
        Some(_) => Some(strike(&mesh, job.strike_vertex).map_err(Error::Strike)?),
        None => None,
    };
    let (lo, hi) = mesh.bounding_box();
    let diagonal =
        ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2) + (hi[2] - lo[2]).powi(2)).sqrt();
    progress.say(format!(
        "mesh: {} tets, {} nodes (P{}, from {}-node input), {} DOF on {} rank(s)",
        mesh.n_tets(),
        mesh.n_nodes(),
        job.order,
        input_order,
        3 * mesh.n_nodes(),
        petsc.size()
    ));

    // Sensitivities need the split K_λ, K_μ and M₁; a forward-only run assembles K and M
    // directly and never holds the split parts (a third less memory at the peak).
    let t_ops = Instant::now();
    let (k, m, layout, split, stats) = if job.sensitivities {
        let assembled = assembly::assemble(petsc, &mesh)?;
        let (k, m) = assembled.operators(&job.material)?;
        let layout = assembled.layout.clone();
        let stats = assembled.stats.clone();
        (k, m, layout, Some(assembled), stats)
    } else {
        let (k, m, layout, stats) = assembly::assemble_operators(petsc, &mesh, &job.material)?;
        (k, m, layout, None, stats)
    };
    progress.say(format!(
        "assembled {} in {:.2} s ({:.0} nonzeros each, {} mallocs)",
        if split.is_some() {
            "M, K_λ, K_μ"
        } else {
            "M, K"
        },
        stats.seconds,
        stats.nonzeros,
        stats.mallocs
    ));
    let operator_seconds = t_ops.elapsed().as_secs_f64() - stats.seconds;
    let rss_assembly = petsc.peak_rss_bytes();

    let scale = eigen::spectrum_scale(job.material.lame_mu(), job.material.density, diagonal);
    let mut cfg = EigenConfig::new(job.request, scale);
    cfg.tolerance = job.tolerance;
    cfg.verify_count = job.verify_count;
    cfg.shift = job.shift;
    if let Some(r) = job.cluster_rtol {
        cfg.cluster_rtol = r;
    }
    progress.say(match job.request {
        ModeRequest::FirstN(n) => format!(
            "solving for the first {n} elastic modes (shift {:.3e} rad²/s²)",
            cfg.effective_shift()
        ),
        ModeRequest::UpTo { f_max_hz } => {
            format!("solving for every mode up to {f_max_hz} Hz (spectrum slicing)")
        }
    });
    cfg.path = job.solver_path;
    if let Some(t) = job.iterative_tolerance {
        cfg.iterative_tolerance = t;
    }
    cfg.iterative_preconditioner = job.iterative_preconditioner;
    // The rigid motions are what the iterative path deflates and gives its multigrid; the
    // direct path finds them as eigenpairs and proves the count with them.
    let rigid = match (
        job.solver_path.resolve(layout.n_dofs(), job.request),
        job.request,
    ) {
        (SolverPath::Iterative, ModeRequest::FirstN(_)) => {
            eigen::rigid_body_vectors(&k, &layout, &mesh.nodes)?
        }
        _ => Vec::new(),
    };
    // The p-multigrid's P1 → P2 interpolation, only when the iterative path will use it: asked
    // for, or chosen by `auto` on a P2 mesh (a P1 mesh has no coarser P1 space; GAMG instead).
    let wants_coarse_space = match job.iterative_preconditioner {
        IterativePreconditioner::PMultigrid(_) => true,
        IterativePreconditioner::Auto => mesh.order == crate::mesh::ElementOrder::Quadratic,
        IterativePreconditioner::Gamg => false,
    };
    let two_level = if wants_coarse_space && !rigid.is_empty() {
        Some(eigen::pmg::two_level(petsc, &mesh, &layout)?)
    } else {
        None
    };
    let modes =
        eigen::solve_modes_two_level(petsc, &k, &m, &cfg, &rigid, two_level.as_ref(), &|line| {
            progress.say(line)
        })?;
    drop(two_level);
    drop(rigid);
    let rss_solve = petsc.peak_rss_bytes();
    if rank == 0 {
        for w in &modes.warnings {
            eprintln!("warning: {w}");
        }
    }
    progress.say(format!(
        "{} elastic modes in {:.2} s",
        modes.eigenvalues.len(),
        modes.solve_seconds
    ));

    let t_sens = Instant::now();
    let material_sensitivities = match &split {
        Some(a) => Some(sensitivity::material_sensitivities(
            &a.k_lambda,
            &a.k_mu,
            &a.mass_unit,
            &modes,
            &job.material,
        )?),
        None => None,
    };
    let material_seconds = t_sens.elapsed().as_secs_f64();
    let t_nodes = Instant::now();
    let node_gradients = if job.node_gradients {
        sensitivity::node_gradients(
            petsc,
            &mesh,
            &layout,
            &modes,
            &job.material,
            ClusterTreatment::Mean,
        )?
    } else {
        None
    };
    let node_gradient_seconds = t_nodes.elapsed().as_secs_f64();
    let sensitivity_seconds = t_sens.elapsed().as_secs_f64();
    if material_sensitivities.is_some() {
        progress.say(format!("sensitivities in {sensitivity_seconds:.2} s (material {material_seconds:.2} s, node positions {node_gradient_seconds:.2} s)"));
    }

    // Gather every mode to rank 0 in original node order, with a deterministic sign: the entry
    // of largest magnitude is made positive, so runs on any number of ranks agree.
    let mut shapes = layout.gather_original_order(&modes.vectors)?;
    for s in &mut shapes {
        let (imax, _) = s.iter().enumerate().fold((0, 0.0f64), |(bi, bv), (i, &x)| {
            if x.abs() > bv + 1e-12 * bv {
                (i, x.abs())
            } else {
                (bi, bv)
            }
        });
        if s[imax] < 0.0 {
            s.iter_mut().for_each(|x| *x = -*x);
        }
    }
    let frequencies: Vec<f64> = modes
        .eigenvalues
        .iter()
        .map(|&l| eigen::frequency_hz(l))
        .collect();
    let rss_setup = modes.preconditioner_setup.map(|s| s.peak_rss_bytes);
    let local = [
        rss_assembly,
        rss_setup.unwrap_or(0.0),
        rss_solve,
        petsc.peak_rss_bytes(),
    ];
    let summed: [f64; 4] = {
        use mpi::collective::{CommunicatorCollectives, SystemOperation};
        let mut sum = [0.0; 4];
        petsc
            .world()
            .all_reduce_into(&local[..], &mut sum[..], SystemOperation::sum());
        sum
    };
    let peak_rss_sum = summed[3];
    let mut peak_rss_after = vec![("assembly".to_string(), summed[0])];
    if rss_setup.is_some() {
        peak_rss_after.push(("preconditioner_setup".to_string(), summed[1]));
    }
    peak_rss_after.push(("solve".to_string(), summed[2]));

    Ok(Report {
        mesh,
        stats,
        modes,
        shapes,
        frequencies,
        material_sensitivities,
        node_gradients,
        strike: strike_point,
        timings: Timings {
            started,
            operator_seconds,
            material_seconds,
            node_gradient_seconds,
            sensitivity_seconds,
            peak_rss_sum,
            peak_rss_after,
        },
        n_ranks: petsc.size(),
        versions: petsc.versions(),
    })
}

/// The strike point: the given node (must be on the surface) or, by default, the surface vertex
/// farthest from the bounding-box centre (a rim or corner, where most modes move). Returns the
/// node and its outward unit normal, the strike direction.
fn strike(mesh: &TetMesh, requested: Option<usize>) -> Result<(usize, [f64; 3]), String> {
    let vertex = match requested {
        Some(v) => v,
        None => mesh
            .default_strike_vertex()
            .ok_or("the mesh has no surface vertices to strike")?,
    };
    let point = mesh.surface_point_at_vertex(vertex).ok_or_else(|| {
        format!(
            "strike vertex {vertex} is not a surface vertex of the mesh ({} nodes)",
            mesh.n_nodes()
        )
    })?;
    Ok((vertex, point.normal))
}
