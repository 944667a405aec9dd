//! The `modes` command: its flags, their merging with the TOML configuration file
//! ([`FileConfig`]), and the printed summary. The job itself is [`crate::workflow::modes`].

use super::resolve::{check_output, inputs, MeshArgs, MeshChoice, RunArgs};
use crate::eigen::{IterativePreconditioner, ModeRequest, SolverPath};
use crate::io::config::{load_toml, ConfigError, FileConfig, MaterialConfig};
use crate::petsc::Petsc;
use crate::workflow::modes::{self as workflow, inertia_line, probe_line, Job, Report};
use clap::Args;
use mpi::environment::Universe;
use std::path::{Path, PathBuf};

#[derive(Args, Debug, Clone, Default)]
// Negative numbers are values (so `--fmax -5` meets our own range check, not a parser hint).
#[command(allow_negative_numbers = true)]
pub struct ModesArgs {
    /// TOML configuration file (see the README); flags given here override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    #[command(flatten)]
    pub input: MeshArgs,
    /// Element order: 2 (quadratic, default) or 1 (linear baseline).
    #[arg(long)]
    pub order: Option<u32>,
    /// Flip inverted tets instead of rejecting the mesh.
    #[arg(long)]
    pub fix_inverted: bool,
    /// Material preset (ceramic, glass, steel, aluminium, wood, plastic, …); default ceramic.
    #[arg(long)]
    pub material: Option<String>,
    /// Young's modulus E in Pa (overrides the preset).
    #[arg(long)]
    pub youngs: Option<f64>,
    /// Poisson's ratio ν (overrides the preset).
    #[arg(long)]
    pub poisson: Option<f64>,
    /// Density ρ in kg/m³ (overrides the preset).
    #[arg(long)]
    pub density: Option<f64>,
    /// Rayleigh mass damping α in 1/s (overrides the preset).
    #[arg(long)]
    pub alpha: Option<f64>,
    /// Rayleigh stiffness damping β in s (overrides the preset).
    #[arg(long)]
    pub beta: Option<f64>,
    /// Compute the first N elastic modes (default 20).
    #[arg(long, conflicts_with = "fmax")]
    pub modes: Option<usize>,
    /// Compute every elastic mode up to this frequency in Hz (spectrum slicing).
    #[arg(long)]
    pub fmax: Option<f64>,
    /// Relative eigen-solver tolerance (default 1e-10).
    #[arg(long)]
    pub tol: Option<f64>,
    /// Shift σ in rad²/s² (default −10⁻²·μ/(ρL²)).
    #[arg(long, allow_hyphen_values = true)]
    pub shift: Option<f64>,
    /// Solver path: auto (default: direct, iterative above 600k DOF), direct (MUMPS shift-invert
    /// with the inertia proof) or iterative (generalised Davidson + multigrid, no factor)
    #[arg(long)]
    pub solver: Option<SolverPath>,
    /// The iterative path's preconditioner: auto (default: pmg on a P2 mesh, gamg on a P1 one),
    /// gamg (algebraic multigrid on the operator), pmg (two-level P2 → P1 multigrid, the P1 level
    /// solved by CG with GAMG to 10⁻²) or pmg-mumps (the P1 level solved by a MUMPS factor)
    #[arg(long)]
    pub preconditioner: Option<IterativePreconditioner>,
    /// Skip the inertia check that proves no mode was missed.
    #[arg(long)]
    pub no_verify: bool,
    /// HDF5 output (default: <mesh stem>_modes.h5 in the current directory).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Render a strike at a surface vertex to this WAV file.
    #[arg(long)]
    pub wav: Option<PathBuf>,
    /// Surface node (0-based, in file order after unused nodes are dropped) to strike.
    #[arg(long)]
    pub strike_vertex: Option<usize>,
    /// Length of the rendered strike in s (default 2).
    #[arg(long)]
    pub duration: Option<f64>,
    /// Sample rate of the rendered strike in Hz (default 48000).
    #[arg(long)]
    pub sample_rate: Option<u32>,
    /// Also compute exact eigenvalue derivatives with respect to E, ν and ρ (written to HDF5).
    #[arg(long)]
    pub sensitivities: bool,
    /// Also compute dλ/dx at every node for every mode (HDF5 + ParaView fields); implies
    /// --sensitivities.
    #[arg(long)]
    pub node_gradients: bool,
    /// Write assembly/solve timings, memory and eigenvalues as JSON (for benchmarks).
    #[arg(long)]
    pub timings_json: Option<PathBuf>,
    #[command(flatten)]
    pub run: RunArgs,
}

/// Merges defaults < config file < command-line flags and validates the result.
pub fn resolve(args: &ModesArgs) -> Result<Job, String> {
    let file: FileConfig = load_toml(&args.config).map_err(|e| match e {
        ConfigError::Read { .. } => format!("cannot read config file {e}"),
        e => format!("config file {e}"),
    })?;
    let MeshChoice {
        mesh,
        units,
        unit_scale,
        order,
    } = args
        .input
        .resolve(&file.mesh, &file.units, args.order.or(file.order))?;
    let flags = MaterialConfig {
        preset: args.material.clone(),
        youngs_modulus: args.youngs,
        poisson_ratio: args.poisson,
        density: args.density,
        rayleigh_alpha: args.alpha,
        rayleigh_beta: args.beta,
    };
    let (material, material_name) = file.material.resolve(&flags).map_err(|e| e.to_string())?;

    let fmax = args.fmax.or(if args.modes.is_some() {
        None
    } else {
        file.solver.fmax
    });
    let request = match (
        args.modes.or(if args.fmax.is_some() {
            None
        } else {
            file.solver.modes
        }),
        fmax,
    ) {
        (Some(_), Some(_)) => {
            return Err("give either a number of modes or a frequency limit, not both".into())
        }
        (Some(0), None) => return Err("the number of modes must be at least 1".into()),
        (Some(n), None) => ModeRequest::FirstN(n),
        (None, Some(f)) if f.is_finite() && f > 0.0 => ModeRequest::UpTo { f_max_hz: f },
        (None, Some(f)) => {
            return Err(format!(
                "the frequency limit must be a positive number of Hz, got {f}"
            ))
        }
        (None, None) => ModeRequest::FirstN(20),
    };
    let given_tolerance = args.tol.or(file.solver.tolerance);
    let tolerance = given_tolerance.unwrap_or(1e-10);
    let solver_path = match (args.solver, file.solver.path.as_deref()) {
        (Some(p), _) => p,
        (None, Some(word)) => word.parse().map_err(|e| {
            format!(
                "{}: [solver] path: {e}",
                args.config
                    .as_deref()
                    .unwrap_or(Path::new("config"))
                    .display()
            )
        })?,
        (None, None) => SolverPath::Auto,
    };
    let iterative_preconditioner =
        match (args.preconditioner, file.solver.preconditioner.as_deref()) {
            (Some(p), _) => p,
            (None, Some(word)) => word.parse().map_err(|e| {
                format!(
                    "{}: [solver] preconditioner: {e}",
                    args.config
                        .as_deref()
                        .unwrap_or(Path::new("config"))
                        .display()
                )
            })?,
            (None, None) => IterativePreconditioner::default(),
        };
    if !(tolerance > 0.0 && tolerance < 1.0) {
        return Err(format!(
            "the solver tolerance must lie in (0, 1), got {tolerance}"
        ));
    }
    let duration = args.duration.or(file.output.duration).unwrap_or(2.0);
    if !(duration > 0.0 && duration <= 600.0) {
        return Err(format!(
            "the strike duration must lie in (0, 600] s, got {duration}"
        ));
    }
    let sample_rate = args
        .sample_rate
        .or(file.output.sample_rate)
        .unwrap_or(48_000);
    if !(8_000..=384_000).contains(&sample_rate) {
        return Err(format!(
            "the sample rate must lie in 8000..=384000 Hz, got {sample_rate}"
        ));
    }
    let out = args
        .out
        .clone()
        .or(file.output.h5.clone())
        .unwrap_or_else(|| {
            let stem = mesh
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "mesh".into());
            PathBuf::from(format!("{stem}_modes.h5"))
        });
    let mut petsc_options = file.solver.petsc_options.clone();
    petsc_options.extend(args.run.petsc_options.iter().cloned());
    Ok(Job {
        mesh,
        unit_scale,
        units,
        order,
        fix_inverted: args.fix_inverted || file.fix_inverted.unwrap_or(false),
        straighten_invalid: args.input.straighten_invalid
            || file.straighten_invalid.unwrap_or(false),
        material,
        material_name,
        request,
        tolerance,
        iterative_tolerance: given_tolerance,
        solver_path,
        iterative_preconditioner,
        verify_count: !args.no_verify && file.solver.verify_count.unwrap_or(true),
        cluster_rtol: file.solver.cluster_rtol,
        shift: args.shift.or(file.solver.shift),
        out,
        wav: args.wav.clone().or(file.output.wav.clone()),
        strike_vertex: args.strike_vertex.or(file.output.strike_vertex),
        duration,
        sample_rate,
        timings_json: args
            .timings_json
            .clone()
            .or(file.output.timings_json.clone()),
        sensitivities: args.sensitivities
            || args.node_gradients
            || file.output.sensitivities.unwrap_or(false)
            || file.output.node_gradients.unwrap_or(false),
        node_gradients: args.node_gradients || file.output.node_gradients.unwrap_or(false),
        petsc_options,
    })
}

/// Runs the job on every rank. Input errors found before PETSc starts are returned; errors
/// after that end the job through [`fail`] so that no rank waits forever in a collective call.
pub fn run(universe: Universe, args: ModesArgs) -> Result<(), String> {
    let job = resolve(&args)?;
    let given = inputs(&job.mesh, &[]);
    check_output(&job.out, &given)?;
    if let Some(w) = &job.wav {
        check_output(w, &given)?;
    }
    if let Some(t) = &job.timings_json {
        check_output(t, &given)?;
    }
    super::with_petsc(
        universe,
        &job.petsc_options,
        args.run.verbose,
        |petsc, progress| {
            let rank = petsc.rank();
            // Fault injection for the tests: a panic on one rank must end the whole job, not hang it.
            if std::env::var("DIFFSOUND_TEST_PANIC_ON_RANK")
                .ok()
                .and_then(|v| v.parse::<usize>().ok())
                == Some(rank)
            {
                panic!("injected panic (DIFFSOUND_TEST_PANIC_ON_RANK={rank})");
            }
            compute(petsc, &job, progress)
        },
    )
}

/// The job, then on rank 0 its files and the summary (printed before the timings JSON is
/// written, as the files' "total" times are measured when each is written).
fn compute(petsc: &Petsc, job: &Job, progress: &super::Progress) -> Result<(), workflow::Error> {
    let report = workflow::run(petsc, job, progress)?;
    if petsc.rank() == 0 {
        workflow::write_outputs(job, &report, progress)?;
        print_summary(job, &report);
        if let Some(path) = &job.timings_json {
            workflow::write_timings_json(path, &report)?;
        }
    }
    Ok(())
}

fn print_summary(job: &Job, report: &Report<'_>) {
    let (mesh, stats, modes, freqs) = (
        &report.mesh,
        &report.stats,
        &report.modes,
        &report.frequencies,
    );
    let sens = report.material_sensitivities.as_ref();
    let (total, ranks) = (report.timings.total_seconds(), report.n_ranks);
    println!(
        "diffsound modes: {} ({} tets, {} DOF, P{}, {} rank(s))",
        job.mesh.display(),
        mesh.n_tets(),
        stats.n_dofs,
        job.order,
        ranks
    );
    println!(
        "material: {} E = {:.4e} Pa, ν = {}, ρ = {} kg/m³",
        job.material_name,
        job.material.youngs_modulus,
        job.material.poisson_ratio,
        job.material.density
    );
    println!(
        "rigid modes removed: {}  |  elastic modes: {}",
        modes.rigid_eigenvalues.len(),
        modes.eigenvalues.len()
    );
    if let Some(c) = &modes.inertia_check {
        println!("inertia check: {}", inertia_line(c));
    }
    if let Some(c) = &modes.probe_check {
        println!("completeness probe: {}", probe_line(c));
    }
    let sens_header = if sens.is_some() {
        format!(" {:>14} {:>12}", "df/dE [Hz/GPa]", "df/dν [Hz]")
    } else {
        String::new()
    };
    println!(
        "{:>5} {:>14} {:>18} {:>10}{}",
        "mode", "freq [Hz]", "λ [rad²/s²]", "residual", sens_header
    );
    for (i, (&l, &f)) in modes.eigenvalues.iter().zip(freqs).enumerate() {
        let tag = if modes.clusters.iter().any(|r| r.contains(&i)) {
            " *"
        } else {
            ""
        };
        let sens_cols = sens.map_or(String::new(), |s| {
            let dfdl = 1.0 / (4.0 * std::f64::consts::PI * l.sqrt());
            format!(
                " {:>14.4} {:>12.2}",
                s.d_youngs[i] * dfdl * 1e9,
                s.d_poisson[i] * dfdl
            )
        });
        println!(
            "{:>5} {:>14.4} {:>18.10e} {:>10.2e}{}{}",
            i, f, l, modes.residuals[i], sens_cols, tag
        );
    }
    if !modes.clusters.is_empty() {
        println!(
            "(* near-degenerate cluster: relative eigenvalue gap <= {:e})",
            modes.cluster_rtol
        );
    }
    println!(
        "time: assembly {:.2} s, solve {:.2} s, total {:.2} s; output {}",
        stats.seconds,
        modes.solve_seconds,
        total,
        job.out.display()
    );
}
