//! `diffsound locate-impact`: where was the object struck, and how hard (issue 8).
//!
//! The command line of the job in [`crate::workflow::locate_impact`] (its module docs give the
//! steps, the equations and the files): the flags, the TOML file ([`ImpactFileConfig`]) and a
//! benchmark case's metadata merged into a [`Job`], the job run, and its summary printed.

use super::resolve::{path_or, require_files, set, MeshArgs, RunArgs, StrikeArgs};
use crate::io::config::{load_toml, ImpactFileConfig};
use crate::io::paths::with_suffix;
use crate::workflow::locate_impact::job::{resolve_material, CaseMeta};
use crate::workflow::locate_impact::{self, Report};
pub use crate::workflow::locate_impact::{Job, TransferChoice};
pub use crate::workflow::material::MaterialSource;
use clap::Args;
use mpi::environment::Universe;
use std::path::{Path, PathBuf};

#[derive(Args, Debug, Clone, Default)]
#[command(allow_negative_numbers = true)]
pub struct ImpactArgs {
    /// TOML configuration file (see the README); flags given here override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    #[command(flatten)]
    pub input: MeshArgs,
    #[command(flatten)]
    pub strike: StrikeArgs,
    /// Highest frequency used, Hz (default 12000).
    #[arg(long)]
    pub fmax: Option<f64>,
    /// Seconds after the onset fitted for the amplitudes (default 0.5).
    #[arg(long)]
    pub window: Option<f64>,
    /// Contact duration of a half-sine force in s (default: an impulse).
    #[arg(long)]
    pub contact_duration: Option<f64>,
    /// The true strike vertex, when known: the map is then evaluated against it.
    #[arg(long)]
    pub true_vertex: Option<usize>,
    /// Number of top candidates reported (default 5).
    #[arg(long)]
    pub top: Option<usize>,
    /// Acoustic transfer: `multipole` (default; to the microphone positions when the config
    /// gives them, direction-averaged otherwise) or `none` (|T| = 1, signal = acceleration).
    #[arg(long)]
    pub transfer: Option<TransferChoice>,
    /// HDF5 result (default impact.h5; JSON, map and PNG beside it).
    #[arg(long)]
    pub out: Option<PathBuf>,
    #[command(flatten)]
    pub run: RunArgs,
}

/// Merges defaults < case metadata < config file < flags and validates.
pub fn resolve(args: &ImpactArgs) -> Result<Job, String> {
    let file: ImpactFileConfig = load_toml(&args.config).map_err(|e| e.to_string())?;
    let case: Option<CaseMeta> = args
        .strike
        .case
        .as_deref()
        .map(CaseMeta::read)
        .transpose()?;
    let case_dir = args
        .strike
        .case
        .as_ref()
        .and_then(|p| p.parent())
        .map(Path::to_path_buf)
        .unwrap_or_default();
    let super::resolve::MeshChoice {
        mesh, unit_scale, ..
    } = args.input.resolve_existing(
        &file.mesh.clone().or(case.as_ref().map(|c| c.mesh.clone())),
        &file
            .units
            .clone()
            .or(case.as_ref().map(|c| c.mesh_unit.clone())),
        Some(2),
    )?;
    let recordings: Vec<PathBuf> = if !args.strike.recordings.is_empty() {
        args.strike.recordings.clone()
    } else if !file.recordings.is_empty() {
        file.recordings.clone()
    } else if let Some(c) = &case {
        c.microphone_files
            .iter()
            .map(|f| case_dir.join(f))
            .collect()
    } else {
        return Err("no recordings given: use --recording FILE (repeatable), `recordings = [...]` in the config file, or --case".into());
    };
    require_files(&recordings, "recording")?;
    let sample_rate = file
        .sample_rate
        .or(case.as_ref().map(|c| c.sample_rate_hz))
        .unwrap_or(48_000);
    if !(8_000..=192_000).contains(&sample_rate) {
        return Err(format!(
            "the sample rate must lie in 8000..=192000 Hz, got {sample_rate}"
        ));
    }
    let pre_roll = file
        .pre_roll_s
        .or(case.as_ref().map(|c| (c.onset_time_s - 0.02).max(0.0)))
        .unwrap_or(0.2);
    if !(0.0..=10.0).contains(&pre_roll) {
        return Err(format!(
            "the pre-roll must lie in [0, 10] s, got {pre_roll}"
        ));
    }
    let window = args.window.or(file.window_s).unwrap_or(0.5);
    if !(0.02..=30.0).contains(&window) {
        return Err(format!(
            "the amplitude window must lie in [0.02, 30] s, got {window}"
        ));
    }
    let max_frequency_hz = args.fmax.or(file.max_frequency_hz).unwrap_or(12_000.0);
    if !(max_frequency_hz > 100.0 && max_frequency_hz < 0.5 * f64::from(sample_rate)) {
        return Err(format!(
            "--fmax must lie in (100 Hz, Nyquist {} Hz), got {max_frequency_hz}",
            0.5 * f64::from(sample_rate)
        ));
    }
    let (material, material_source, damping_curve) = resolve_material(
        args.strike.material.clone().or(file.material_fit.clone()),
        (
            args.strike.youngs.or(file.youngs_modulus),
            args.strike.poisson.or(file.poisson_ratio),
        ),
        || {
            args.strike
                .density
                .or(file.density)
                .or(case.as_ref().map(|c| c.density_kg_m3))
                .unwrap_or(2700.0)
        },
    )
    .map_err(|e| e.to_string())?;
    let microphones = file
        .microphone_positions
        .clone()
        .or(case.as_ref().map(|c| c.microphone_positions_m.clone()));
    if let Some(m) = &microphones {
        if m.len() != recordings.len() {
            return Err(format!(
                "{} microphone positions for {} recordings",
                m.len(),
                recordings.len()
            ));
        }
        if m.iter().flatten().any(|x| !x.is_finite()) {
            return Err("microphone positions must be finite".into());
        }
    }
    let assumed_distance_m = file.assumed_distance_m.unwrap_or(0.5);
    if !(assumed_distance_m.is_finite() && assumed_distance_m > 0.0) {
        return Err(format!(
            "assumed_distance_m must be positive, got {assumed_distance_m}"
        ));
    }
    let contact_duration_s = args.contact_duration.or(file.contact_duration_s);
    if let Some(t) = contact_duration_s {
        if !(t.is_finite() && t > 0.0 && t < 0.05) {
            return Err(format!(
                "the contact duration must lie in (0, 0.05) s, got {t}"
            ));
        }
    }
    let match_tolerance = file.match_tolerance.unwrap_or(0.03);
    if !(match_tolerance > 0.0 && match_tolerance < 0.5) {
        return Err(format!(
            "match_tolerance must lie in (0, 0.5), got {match_tolerance}"
        ));
    }
    let mut map = file.map.clone();
    set(&mut map.top_k, args.top);
    // Microphones are uncalibrated unless the file says otherwise (module docs, step 6).
    map.free_microphone_gains = !file.calibrated_microphones.unwrap_or(false);
    let out = path_or(&args.out, &file.out, "impact.h5");
    super::resolve::check_output(&out, &super::resolve::inputs(&mesh, &recordings))?;
    let mut petsc_options = file.petsc_options.clone();
    petsc_options.extend(args.run.petsc_options.iter().cloned());
    Ok(Job {
        json: out.with_extension("json"),
        map_file: with_suffix(&out, "_map.h5"),
        png: with_suffix(&out, "_map.png"),
        mesh,
        unit_scale,
        straighten_invalid: args.input.straighten_invalid
            || file.straighten_invalid.unwrap_or(false),
        recordings,
        sample_rate,
        pre_roll,
        window,
        max_frequency_hz,
        material,
        material_source,
        damping_curve,
        microphones,
        transfer: args.transfer.or(file.transfer).unwrap_or_default(),
        assumed_distance_m,
        contact_duration_s,
        match_tolerance,
        true_vertex: args
            .true_vertex
            .or(file.true_vertex)
            .or(case.as_ref().map(|c| c.strike.vertex)),
        extract: file.extract.clone(),
        map,
        out,
        petsc_options,
        command: std::env::args().collect::<Vec<_>>().join(" "),
    })
}

pub fn run(universe: Universe, args: ImpactArgs) -> Result<(), String> {
    let job = resolve(&args)?;
    super::with_petsc(
        universe,
        &job.petsc_options,
        args.run.verbose,
        |petsc, progress| match locate_impact::run(petsc, &job, progress)? {
            Some(report) => print_and_write(&job, &report),
            None => Ok(()),
        },
    )
}

/// Rank 0: the summary on stdout, then each file with a line saying it was written.
fn print_and_write(job: &Job, report: &Report) -> Result<(), locate_impact::Error> {
    print_summary(job, report);
    locate_impact::write::write_hdf5(job, report)?;
    println!("wrote {}", job.out.display());
    locate_impact::write::write_json(job, report)?;
    println!("wrote {}", job.json.display());
    locate_impact::write::write_map(job, report)?;
    println!("wrote {} and its .xdmf sidecar (ParaView: colour by posterior_density or log_likelihood_ratio)", job.map_file.display());
    locate_impact::write::write_png(job, report)?;
    println!("wrote {}", job.png.display());
    Ok(())
}

/// The human summary on stdout: the counts, the transfer, the strength, the top candidates and
/// the evaluation.
fn print_summary(job: &Job, report: &Report) {
    let (mesh, assignment, table, map) =
        (&report.mesh, &report.assignment, &report.table, &report.map);
    let (evaluation, transfer_note) = (report.evaluation.as_ref(), &report.transfer_note);
    let pos = |v: usize| mesh.nodes[v];
    println!("locate-impact: {} surface vertices, {} clusters ({} heard), {} microphones; E = {:.4e} Pa, ν = {:.4}, ρ = {} ({})", table.candidates.len(), table.clusters.len(), assignment.observed.iter().filter(|o| **o).count(), table.microphones, job.material.youngs_modulus, job.material.poisson_ratio, job.material.density, job.material_source);
    println!("  transfer: {transfer_note}");
    println!("  strength at the best vertex: {:.4e} ± {:.2e} (recording units per N·s of impulse; absolute only with calibrated microphones and known positions)", map.strength, map.strength_sd);
    println!(
        "  top candidates (posterior mass within {:.1} mm):",
        1e3 * map.neighbourhood_m
    );
    for (i, t) in map.top.iter().enumerate() {
        let p = pos(t.vertex);
        println!(
            "    {}. vertex {:>6} at ({:+.4}, {:+.4}, {:+.4}) m: mass {:.3}, ℓ = {:.2}",
            i + 1,
            t.vertex,
            p[0],
            p[1],
            p[2],
            t.neighbourhood_mass,
            t.log_likelihood
        );
    }
    if let Some(e) = evaluation {
        println!("  truth: vertex {}; best candidate {:.1} mm away along the surface; {:.2} % of the surface ranks at or above the truth ({}); symmetry orbit of {} vertices, best candidate {} ({:.1} mm from it)", e.true_vertex, 1e3 * e.geodesic_error_m, 100.0 * e.area_rank, if e.in_top_percent { "in the top 1 %" } else { "not in the top 1 %" }, e.orbit_size, if e.best_on_orbit { "on it" } else { "off it" }, 1e3 * e.orbit_error_m);
    }
}
