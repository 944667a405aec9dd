//! The `diagnose` command's line: its flags, its TOML configuration ([`DiagnoseFileConfig`],
//! merged with the flags and a benchmark case's metadata by [`resolve`]) and the printed summary. The job itself, its
//! stages and its outputs are [`crate::workflow::diagnose`].
//!
//! ```text
//! mpirun -np 2 diffsound diagnose --config examples/bowl/diagnose.toml
//! mpirun -np 2 diffsound diagnose --case bench/case_003/metadata.toml --out bench/case_003/diagnosis.h5
//! diffsound diagnose --mesh bowl.msh --recording mic0.wav --recording mic1.wav --material fit.h5
//! ```

use super::resolve::{path_or, require_files, MeshArgs, RunArgs, StrikeArgs};
use crate::diagnose::catalogue;
use crate::io::config::{load_toml, DiagnoseFileConfig};
use crate::io::paths::with_suffix;
use crate::workflow::diagnose::{
    self as workflow, check_recording_window, resolve_material, split_microphones, unit_vector,
    CaseMeta, Job, Outcome, Report,
};
use clap::Args;
use mpi::environment::Universe;
use std::path::{Path, PathBuf};

#[derive(Args, Debug, Clone, Default)]
#[command(allow_negative_numbers = true)]
pub struct DiagnoseArgs {
    /// TOML configuration file (see the README); flags given here override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    #[command(flatten)]
    pub input: MeshArgs,
    #[command(flatten)]
    pub strike: StrikeArgs,
    /// Held-out microphones, 0-based, comma separated (default: every second one; with the
    /// default, the two sets exchange roles when the fit one holds too few modes).
    #[arg(long, value_delimiter = ',')]
    pub held_out: Vec<usize>,
    /// Strike this surface node (0-based).
    #[arg(long)]
    pub strike_vertex: Option<usize>,
    /// Highest frequency diagnosed, Hz (default 12000).
    #[arg(long)]
    pub fmax: Option<f64>,
    /// Seconds used after the onset (default 1).
    #[arg(long)]
    pub duration: Option<f64>,
    /// HDF5 result (default diagnosis.h5; the JSON report beside it).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Prefix of the PNG plots (default: the HDF5 path without its extension).
    #[arg(long)]
    pub plots: Option<PathBuf>,
    /// With the material unknown, also try the loaded line match (a candidate added mass in
    /// the model; the default, see the README).
    #[arg(long, conflicts_with = "no_loaded_mass_match")]
    pub loaded_mass_match: bool,
    /// With the material unknown, use the plain line match only (faster: the loaded search
    /// costs minutes per case where the plain match leaves a distance above 10⁻³).
    #[arg(long)]
    pub no_loaded_mass_match: bool,
    #[command(flatten)]
    pub run: RunArgs,
}

/// Merges defaults < case metadata < config file < flags and validates.
pub fn resolve(args: &DiagnoseArgs) -> Result<Job, String> {
    let file: DiagnoseFileConfig = load_toml(&args.config).map_err(|e| e.to_string())?;
    let case = args
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
    let mesh_from_case = case.as_ref().map(|c| c.mesh.clone());
    let units_from_case = case.as_ref().map(|c| c.mesh_unit.clone());
    let crate::cli::resolve::MeshChoice {
        mesh, unit_scale, ..
    } = args.input.resolve_existing(
        &file.mesh.clone().or(mesh_from_case),
        &file.units.clone().or(units_from_case),
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
        Vec::new()
    };
    if recordings.is_empty() {
        return Err("no recordings given: use --recording FILE (repeatable), `recordings = [...]` in the config file, or --case".into());
    }
    require_files(&recordings, "recording")?;
    let n_mics = recordings.len();
    let held_chosen_by_default = args.held_out.is_empty() && file.held_out_microphones.is_none();
    let held_channels: Vec<usize> = if !args.held_out.is_empty() {
        args.held_out.clone()
    } else {
        file.held_out_microphones
            .clone()
            .unwrap_or_else(|| (1..n_mics).step_by(2).collect())
    };
    let (fit_channels, held_channels) =
        split_microphones(n_mics, held_channels, file.catalogue.require_held_out)?;
    let sample_rate = file
        .recording
        .sample_rate
        .or(case.as_ref().map(|c| c.sample_rate_hz))
        .unwrap_or(48_000);
    let duration = args
        .duration
        .or(file.recording.duration)
        .or(case.as_ref().map(|c| c.duration_after_onset_s))
        .unwrap_or(1.0);
    let pre_roll = file
        .recording
        .pre_roll
        .or(case.as_ref().map(|c| (c.onset_time_s - 0.02).max(0.0)))
        .unwrap_or(0.2);
    let max_frequency_hz = args
        .fmax
        .or(file.recording.max_frequency_hz)
        .unwrap_or(12_000.0);
    check_recording_window(sample_rate, duration, pre_roll, max_frequency_hz)?;
    let density = args
        .strike
        .density
        .or(file.model.density)
        .or(case.as_ref().map(|c| c.density_kg_m3))
        .unwrap_or(2700.0);
    let (material, material_source, density) = resolve_material(
        args.strike.material.clone().or(file.material_fit.clone()),
        (
            args.strike.youngs.or(file.model.youngs_modulus),
            args.strike.poisson.or(file.model.poisson_ratio),
        ),
        density,
    )
    .map_err(|e| e.to_string())?;
    let strike_vertex = args
        .strike_vertex
        .or(file.model.strike_vertex)
        .or(case.as_ref().map(|c| c.strike.vertex));
    let strike_direction = match file
        .model
        .strike_direction
        .or(case.as_ref().map(|c| c.strike.direction))
    {
        Some(d) => Some(unit_vector(d, "the strike direction")?),
        None => None,
    };
    let support_direction = unit_vector(
        file.model
            .support_direction
            .or(case.as_ref().map(|c| c.support_direction))
            .unwrap_or([0.0, 0.0, -1.0]),
        "the support direction",
    )?;
    let microphones = file
        .model
        .microphone_positions
        .clone()
        .or(case.as_ref().map(|c| c.microphone_positions_m.clone()));
    if let Some(m) = &microphones {
        if m.len() != n_mics {
            return Err(format!(
                "{} microphone positions for {n_mics} recordings",
                m.len()
            ));
        }
    }
    file.catalogue.validate().map_err(|e| e.to_string())?;
    let out = path_or(&args.out, &file.out, "diagnosis.h5");
    let plots = args
        .plots
        .clone()
        .or(file.plots.clone())
        .unwrap_or_else(|| out.with_extension(""));
    let given = crate::cli::resolve::inputs(&mesh, &recordings);
    crate::cli::resolve::check_output(&out, &given)?;
    crate::cli::resolve::check_output(&plots, &given)?;
    let mut petsc_options = file.solver.petsc_options.clone();
    petsc_options.extend(args.run.petsc_options.iter().cloned());
    Ok(Job {
        json: out.with_extension("json"),
        map: with_suffix(&out, "_map.h5"),
        mesh,
        unit_scale,
        straighten_invalid: args.input.straighten_invalid
            || file.straighten_invalid.unwrap_or(false),
        recordings,
        held_chosen_by_default,
        fit_channels,
        held_channels,
        channel_health: Vec::new(),
        sample_rate,
        duration,
        pre_roll,
        max_frequency_hz,
        density,
        material,
        material_source,
        loaded_mass_match: !args.no_loaded_mass_match
            && (args.loaded_mass_match || file.model.loaded_mass_match.unwrap_or(true)),
        strike_vertex,
        strike_direction,
        support_direction,
        microphones,
        observed: file.observed.clone(),
        extract: file.extract.clone(),
        glide: file.glide.clone(),
        envelopes: file.envelopes.clone(),
        catalogue: file.catalogue.clone(),
        out,
        plots,
        petsc_options,
        verbose: args.run.verbose,
    })
}

pub fn run(universe: Universe, args: DiagnoseArgs) -> Result<(), String> {
    let job = resolve(&args)?;
    super::with_petsc(
        universe,
        &job.petsc_options,
        job.verbose,
        |petsc, progress| match workflow::run(petsc, &job, progress)? {
            Some(Outcome::Diagnosed(report)) => {
                print_report(&report);
                write_outputs(&report)
            }
            Some(Outcome::Refused(refusal)) => {
                // Not an error: the recordings were read and say too little; the report
                // says so (module docs of the workflow, "Too few modes").
                eprintln!("warning: no diagnosis: {}", refusal.reason);
                println!(
                    "diagnose: nothing tested: {} ({} modes on the fit microphones, {} held out)",
                    refusal.reason,
                    refusal.measured.fit.len(),
                    refusal.measured.held_out.len()
                );
                workflow::write_refusal_json(&refusal)?;
                println!(
                    "wrote {} (no HDF5 result, map or plots: there is no model to put in them)",
                    refusal.job.json.display()
                );
                Ok(())
            }
            None => Ok(()),
        },
    )
}

/// Writes the report's files (rank 0), naming each as it is written.
fn write_outputs(report: &Report) -> Result<(), workflow::Error> {
    let job = &report.job;
    workflow::write_json(report)?;
    println!("wrote {}", job.json.display());
    workflow::write_hdf5(report)?;
    println!("wrote {}", job.out.display());
    workflow::write_map(report)?;
    println!(
        "wrote {} and its .xdmf sidecar (ParaView: colour by mass_region_z)",
        job.map.display()
    );
    workflow::write_plots(report)?;
    println!(
        "wrote {}_{{residuals,timefreq,envelopes}}.png",
        job.plots.display()
    );
    Ok(())
}

fn fmt_param(p: &catalogue::FittedParam) -> String {
    match p.sigma {
        Some(s) => format!("{} = {:.4e} ± {:.2e} {}", p.name, p.value, s, p.unit),
        None => format!("{} = {:.4e} (undetermined) {}", p.name, p.value, p.unit),
    }
}

/// The human summary on stdout (rank 0).
fn print_report(r: &Report) {
    let (job, measured, report, feats, localised) =
        (&r.job, &r.measured, &r.catalogue, &r.features, &r.localised);
    let (youngs, poisson) = (r.youngs, r.poisson);
    println!(
        "diagnose: E = {youngs:.5e} Pa, ν = {poisson:.4}, ρ = {} kg/m³ ({}); strike {}",
        job.density, job.material_source, feats.strike_note
    );
    if let Some(s) = r.line_start.filter(|s| s.poisson_at_edge()) {
        println!(
            "  warning: the line-spectrum match put ν at {:.4}, an end of the range it searched ([{}, {}]): the recorded lines do not fix the material, and every verdict below rests on it; give the material (--material with a fit-material result, or the configuration)",
            s.poisson, s.poisson_range.0, s.poisson_range.1
        );
    }
    println!(
        "  recording: {} modes on {} fit microphones, {} on {} held-out, below {} Hz",
        measured.fit.len(),
        job.fit_channels.len(),
        measured.held_out.len(),
        job.held_channels.len(),
        job.max_frequency_hz
    );
    println!(
        "  matching: scale {:.5}, {} pairs, {} extra poles of matched partials, {} observed and {} simulated modes unmatched",
        report.matching.scale,
        report.matching.pairs.len(),
        report.matching.extra_poles.len(),
        report.matching.unmatched_observed.len(),
        report.matching.unmatched_simulated.len()
    );
    for p in &report.matching.extra_poles {
        println!(
            "      extra pole {:.2} Hz of the partial at {:.2} Hz (simulated cluster {})",
            p.observed_hz, p.beside_hz, p.cluster
        );
    }
    if let Some(r) = &report.matching.room_held {
        println!(
            "  room: {} fit and {} held-out modes decay at least as fast as the room ({:.1} 1/s, ln(10³)/(T60 + 2σ)); only their frequencies count",
            r.frequencies_hz.len(),
            r.held_out_modes,
            r.room_decay_rate
        );
    }
    let ho = |v: Option<f64>| v.map_or("n/a".to_string(), |v| format!("{v:.3}"));
    let gain = |g: Option<f64>| g.map_or(String::new(), |g| format!(" (Σz² gain {g:.1})"));
    println!(
        "  held-out error (RMS standardised residual): baseline {} → final {}",
        ho(report.baseline.held_out_error),
        ho(report.final_model.held_out_error)
    );
    println!(
        "  floors (baseline → final): ln f {:.2e} → {:.2e}, ln d {:.3} → {:.3}, ln a {:.3} → {:.3}",
        report.baseline.floors.ln_frequency,
        report.final_model.floors.ln_frequency,
        report.baseline.floors.ln_decay,
        report.final_model.floors.ln_decay,
        report.baseline.floors.ln_amplitude,
        report.final_model.floors.ln_amplitude
    );
    if report.accepted.is_empty() {
        println!("  accepted effects: none");
    }
    for a in &report.accepted {
        println!(
            "  ACCEPTED {} ({}): ΔBIC {:.1}, held-out {} → {}{}",
            a.name,
            a.variant,
            a.delta_bic,
            ho(a.held_out_before),
            ho(a.held_out_after),
            gain(a.held_out_gain)
        );
        println!("      evidence: {}", a.detector);
        for p in &a.params {
            println!("      {}", fmt_param(p));
        }
    }
    for r in &report.rejected {
        let extra = match (r.delta_bic, r.held_out_before, r.held_out_after) {
            (Some(d), Some(b), Some(a)) => format!(
                " (ΔBIC {d:.1}, held-out {b:.3} → {a:.3}{})",
                gain(r.held_out_gain)
            ),
            (Some(d), _, _) => format!(" (ΔBIC {d:.1})"),
            _ => String::new(),
        };
        println!("  rejected {}: {}{extra}: {}", r.name, r.reason, r.detail);
    }
    let untested = report.untested();
    if !untested.is_empty() {
        println!(
            "  could not be tested with these recordings ({}): {}",
            untested.len(),
            untested
                .iter()
                .map(|r| format!("{} ({})", r.name, r.detail))
                .collect::<Vec<_>>()
                .join("; ")
        );
    }
    if !report.unexplained.is_empty() {
        println!("  unexplained ({}):", report.unexplained.len());
        for u in report.unexplained.iter().take(12) {
            println!(
                "      {:.2} Hz{}{}: {}",
                u.frequency_hz,
                u.quantity.map_or(String::new(), |q| format!(", {q}")),
                u.z.map_or(String::new(), |z| format!(" z = {z:.1}")),
                u.reason
            );
        }
        if report.unexplained.len() > 12 {
            println!(
                "      … {} more in the report",
                report.unexplained.len() - 12
            );
        }
    }
    if let Some((v, z)) = localised.best {
        println!("  localisation: frequency residuals best explained by mass at surface vertex {v} (z = {z:.1}{})", if localised.region.is_empty() { ", below the offer threshold" } else { "" });
    }
}
