//! The `fit-material` command: damping, Young's modulus and Poisson's ratio from recordings of
//! one strike. The job itself is [`crate::workflow::fit_material`] (stages, equations and
//! outputs); the result file's layout is in [`crate::io::fit_material`]. Here: the flags, the
//! TOML configuration ([`FitFileConfig`]) merged under them, and the summary printed on stdout.
//!
//! ```text
//! mpirun -np 2 diffsound fit-material --config examples/bowl/fit.toml
//! diffsound fit-material --mesh bowl.msh --recording mic0.wav --recording mic1.wav --out fit.h5
//! ```

use super::resolve::{path_or, require_files, set, MeshArgs, RunArgs};
use crate::io::config::{load_toml, FitFileConfig};
use crate::workflow::fit_material::{self as workflow, Job, Report, MAX_MATCH_ERROR};
use clap::Args;
use mpi::environment::Universe;
use std::path::PathBuf;

#[derive(Args, Debug, Clone, Default)]
#[command(allow_negative_numbers = true)]
pub struct FitMaterialArgs {
    /// TOML configuration file (see the README); flags given here override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    #[command(flatten)]
    pub input: MeshArgs,
    /// Element order of the model: 2 (default) or 1.
    #[arg(long)]
    pub order: Option<u32>,
    /// A WAV file of the strike (repeat for several microphones; multichannel files count as
    /// several).
    #[arg(long = "recording")]
    pub recordings: Vec<PathBuf>,
    /// Analysis sample rate in Hz (default 48000).
    #[arg(long)]
    pub sample_rate: Option<u32>,
    /// Seconds of each recording used after the onset (default 1).
    #[arg(long)]
    pub duration: Option<f64>,
    /// Density ρ in kg/m³ (default 2700); the fit finds E/ρ, reported as E at this ρ.
    #[arg(long)]
    pub density: Option<f64>,
    /// Starting Young's modulus in Pa (default 7.2e10).
    #[arg(long)]
    pub youngs: Option<f64>,
    /// Starting Poisson's ratio (default 0.25).
    #[arg(long)]
    pub poisson: Option<f64>,
    /// Hold ν at its starting value.
    #[arg(long)]
    pub fix_poisson: bool,
    /// Simulated modes in the fit (default 32).
    #[arg(long)]
    pub modes: Option<usize>,
    /// Upper end of the band the material fit compares, Hz (default 8000).
    #[arg(long)]
    pub fmax: Option<f64>,
    /// Strike this surface node (0-based) in the model; default: farthest from the centre.
    #[arg(long, conflicts_with = "strike_position")]
    pub strike_vertex: Option<usize>,
    /// Strike the surface point nearest x,y,z (metres).
    #[arg(long, value_parser = super::render::parse_vec3)]
    pub strike_position: Option<[f64; 3]>,
    /// Most fit steps (default 600).
    #[arg(long)]
    pub max_steps: Option<usize>,
    /// HDF5 result (default fit_material.h5).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Prefix of the PNG plots (default: the HDF5 path without its extension).
    #[arg(long)]
    pub plots: Option<PathBuf>,
    #[command(flatten)]
    pub run: RunArgs,
}

/// Merges defaults < config file < flags and validates.
pub fn resolve(args: &FitMaterialArgs) -> Result<Job, String> {
    let file: FitFileConfig = load_toml(&args.config).map_err(|e| e.to_string())?;
    let super::resolve::MeshChoice {
        mesh,
        unit_scale,
        order,
        ..
    } = args
        .input
        .resolve(&file.mesh, &file.units, args.order.or(file.order))?;
    let recordings = if args.recordings.is_empty() {
        file.recordings.clone()
    } else {
        args.recordings.clone()
    };
    if recordings.is_empty() {
        return Err("no recordings given: use --recording FILE (repeatable) or `recordings = [...]` in the config file".into());
    }
    require_files(&recordings, "recording")?;
    let sample_rate = args
        .sample_rate
        .or(file.recording.sample_rate)
        .unwrap_or(48_000);
    if !(8_000..=192_000).contains(&sample_rate) {
        return Err(format!(
            "the sample rate must lie in 8000..=192000 Hz, got {sample_rate}"
        ));
    }
    let duration = args.duration.or(file.recording.duration).unwrap_or(1.0);
    if !(0.05..=30.0).contains(&duration) {
        return Err(format!(
            "the duration must lie in [0.05, 30] s, got {duration}"
        ));
    }
    let density = args.density.or(file.material.density).unwrap_or(2700.0);
    if !(density.is_finite() && density > 0.0) {
        return Err(format!("the density must be positive, got {density}"));
    }
    let start_youngs = args
        .youngs
        .or(file.material.youngs_modulus)
        .unwrap_or(7.2e10);
    if !(start_youngs.is_finite() && start_youngs > 0.0) {
        return Err(format!(
            "the starting Young's modulus must be positive, got {start_youngs}"
        ));
    }
    let mut fit = file.fit.clone();
    if args.fix_poisson {
        fit.learn_poisson = false;
    }
    set(&mut fit.max_steps, args.max_steps);
    let start_poisson = args.poisson.or(file.material.poisson_ratio).unwrap_or(0.25);
    let (lo, hi) = fit.poisson_bounds;
    if !(lo >= -0.99 && lo < hi && hi < 0.5) {
        return Err(format!(
            "poisson_bounds must satisfy −0.99 ≤ lo < hi < 0.5, got ({lo}, {hi})"
        ));
    }
    // The starts tried beside the line-spectrum start step ν by this much
    // (`inverse::material::fit_material`, *Several starts*).
    if fit.start_probes > 0
        && !(fit.start_probe_spacing.is_finite() && fit.start_probe_spacing > 0.0)
    {
        return Err(format!(
            "[fit] start_probe_spacing must be a positive step in ν, got {}",
            fit.start_probe_spacing
        ));
    }
    if !(start_poisson >= lo && start_poisson <= hi) {
        return Err(format!(
            "the starting Poisson's ratio {start_poisson} lies outside the bounds [{lo}, {hi}]"
        ));
    }
    let n_modes = args.modes.or(file.material.modes).unwrap_or(32);
    if !(1..=500).contains(&n_modes) {
        return Err(format!("--modes must lie in 1..=500, got {n_modes}"));
    }
    let max_frequency_hz = args
        .fmax
        .or(file.material.max_frequency_hz)
        .unwrap_or(8000.0);
    if !(max_frequency_hz > 0.0 && 1.1 * max_frequency_hz < 0.5 * f64::from(sample_rate)) {
        return Err(format!("--fmax must be positive and 1.1 × fmax below the Nyquist frequency {} Hz, got {max_frequency_hz}", 0.5 * f64::from(sample_rate)));
    }
    let basis_samples = file
        .material
        .basis_samples
        .clone()
        .unwrap_or_else(|| vec![0.05, 0.15, 0.25, 0.35, 0.45]);
    if basis_samples.is_empty() || basis_samples.iter().any(|nu| !(*nu > -0.99 && *nu < 0.499)) {
        return Err(format!(
            "basis_samples must be one or more ν in (−0.99, 0.499), got {basis_samples:?}"
        ));
    }
    let out = path_or(&args.out, &file.out, "fit_material.h5");
    let plots = args
        .plots
        .clone()
        .or(file.plots.clone())
        .unwrap_or_else(|| out.with_extension(""));
    let given = super::resolve::inputs(&mesh, &recordings);
    super::resolve::check_output(&out, &given)?;
    super::resolve::check_output(&plots, &given)?;
    let mut petsc_options = file.solver.petsc_options.clone();
    petsc_options.extend(args.run.petsc_options.iter().cloned());
    Ok(Job {
        mesh,
        unit_scale,
        straighten_invalid: args.input.straighten_invalid
            || file.straighten_invalid.unwrap_or(false),
        order,
        recordings,
        sample_rate,
        duration,
        density,
        start_youngs,
        start_poisson,
        n_modes,
        max_frequency_hz,
        basis_samples,
        basis_margin: file.material.basis_margin.unwrap_or(8),
        strike_vertex: args.strike_vertex.or(file.material.strike_vertex),
        strike_position: args.strike_position.or(file.material.strike_position),
        damping: file.damping.clone(),
        fit,
        out,
        plots,
        petsc_options,
        verbose: args.run.verbose,
    })
}

pub fn run(universe: Universe, args: FitMaterialArgs) -> Result<(), String> {
    let job = resolve(&args)?;
    super::with_petsc(
        universe,
        &job.petsc_options,
        job.verbose,
        |petsc, progress| {
            let report = workflow::run(petsc, &job, progress)?;
            if petsc.rank() == 0 {
                print_summary(&job, &report);
                write_outputs(&job, &report)?;
            }
            Ok::<(), workflow::Error>(())
        },
    )
}

/// Rank 0: the HDF5 result, then the plots, each announced on stdout when written.
fn write_outputs(job: &Job, report: &Report) -> Result<(), workflow::Error> {
    workflow::write_result(job, report)?;
    println!("wrote {}", job.out.display());
    let written = workflow::write_plots(job, report)?;
    if written.frequencies {
        println!(
            "wrote {}_{{spectrogram,damping,loss,frequencies}}.png",
            job.plots.display()
        );
    } else {
        eprintln!("warning: no recorded mode has a simulated partner within {:.0} %; {}_frequencies.png not written", 100.0 * MAX_MATCH_ERROR, job.plots.display());
        println!(
            "wrote {}_{{spectrogram,damping,loss}}.png",
            job.plots.display()
        );
    }
    Ok(())
}

/// The human summary on stdout: the material, the damping, the errors and the matched modes.
fn print_summary(job: &Job, report: &Report) {
    let fit = &report.fit;
    let damping = &report.stage.damping;
    let (error_start, error_fit) = (report.error_start, report.error_fit);
    let max_difference = report.max_difference;
    println!(
        "fit-material: E = {:.6e} Pa (ρ = {} kg/m³, E/ρ = {:.6e} m²/s²), ν = {:.5}",
        fit.youngs,
        job.density,
        fit.youngs / job.density,
        fit.poisson
    );
    println!(
        "  damping: {} real modes, Rayleigh α = {:.4} 1/s, β = {:.4e} s; curve knots at {} Hz",
        damping.modes.iter().filter(|m| m.kept()).count(),
        damping.rayleigh.alpha,
        damping.rayleigh.beta,
        crate::workflow::short_list(
            &damping
                .curve
                .frequencies_hz
                .iter()
                .map(|f| format!("{f:.0}"))
                .collect::<Vec<_>>(),
            12
        )
    );
    println!("  spectrogram error vs target: start {error_start:.4}, fit {error_fit:.4}");
    if let (Some(l), Some(check)) = (fit.line_start, report.line_start_check) {
        let (err, n) = (check.mean_abs_error, check.matched);
        println!("  line-spectrum start: E = {:.5e} Pa, ν = {:.4} (distance {:.2e}); {n} lines matched there, mean |relative frequency error| {:.3} %", l.youngs, l.poisson, l.distance, 100.0 * err);
    }
    println!("  reduced basis vs full solve at the fit: max relative eigenvalue difference {max_difference:.2e}");
    println!(
        "  {} recorded modes below {} Hz matched; mean |relative frequency error| {:.3} %",
        report.matches.len(),
        job.max_frequency_hz,
        100.0 * report.mean_abs_error
    );
    println!(
        "  {:>10} {:>10} {:>9} {:>8}",
        "recorded", "simulated", "error", "d [1/s]"
    );
    for m in &report.matches {
        let r = &damping.modes[report.in_band[m.recorded]];
        println!(
            "  {:>10.2} {:>10.2} {:>8.3}% {:>8.2}",
            r.frequency_hz,
            report.sim_hz[m.simulated],
            100.0 * m.relative_error,
            r.decay_rate
        );
    }
}
