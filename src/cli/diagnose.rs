//! The `diagnose` job: where a simulation and a recording of the same strike still differ,
//! which physics the model left out, and how much the fit improves with it (issue 6).
//!
//! ```text
//! mpirun -np 2 diffsound diagnose --config examples/bowl/diagnose.toml
//! mpirun -np 2 diffsound diagnose --case bench/case_003/metadata.toml --out bench/case_003/diagnosis.h5
//! diffsound diagnose --mesh bowl.msh --recording mic0.wav --recording mic1.wav --material fit.h5
//! ```
//!
//! # Stages
//!
//! 1. **Recording** (rank 0). The files are resampled, cut at the shared onset with `pre_roll`
//!    s before it (the noise floor), and `duration` s after it are kept. The microphones are
//!    split into a *fit* set and a *held-out* set (`held_out_microphones`; default every
//!    second one), so that every accepted effect must also improve the fit of microphones it
//!    never saw.
//! 2. **Modes of the recording** ([`crate::diagnose::extract`], rank 0): the fit set's modes
//!    with standard deviations, then the chirp-aware stage ([`crate::diagnose::extract::glide`]:
//!    each mode, or each cluster of poles within 0.4 %, fitted as one gliding mode
//!    f(t) = f₀(1 + g e^(−2dt)) and kept as such where the BIC prefers it, with g ± σ_g per
//!    mode for the pitch-glide rows); the held-out set's the same way, separately; the
//!    residual recording − modal resynthesis (gliding modes gliding) per band and frame, and
//!    the pre-roll's floor ([`crate::diagnose::evidence`]).
//! 3. **Material.** E, ν (ρ given) from a `fit-material` result (`material = "fit.h5"`), from
//!    the configuration, or, with neither, from the line-spectrum match of the recorded mode
//!    frequencies against a reduced basis in ν ([`crate::inverse::material::line_spectrum_start`];
//!    the catalogue refits the global frequency scale, so this only has to put every mode next
//!    to its partner).
//!
//!    **A candidate added mass** (on by default; off with `[model] loaded_mass_match = false`
//!    or `--no-loaded-mass-match`). When that match leaves a distance above 10⁻³, the loaded line
//!    match ([`crate::inverse::loaded_match`]) searches E, ν, a lumped mass and its site (a
//!    surface vertex with its 2, 4 or 7 nearest; 450 farthest-point sites with 3-vertex
//!    regions, then every size at the 24 sites around each of the 4 best distinct sites) with
//!    the mass in the model (Ritz in the basis's modes, the rigid motions and the region's
//!    attachment vectors). The attachment vectors are solved at the plain match's ν for the
//!    coarse pass and each candidate's first fine pass, then again at the ν the candidate
//!    reached, for up to three re-anchored fine passes over ν ± 0.03 at its 8 nearest sites
//!    (the plain ν can be far off: 0.354 for a true 0.188 on set2 case 012; module docs of
//!    [`crate::inverse::loaded_match`], "Re-anchoring"). Each of the 4 candidates is checked
//!    by a full solve with its mass, and the best checked one is the answer. If it at most
//!    halves the plain distance, the simulation of stage 4 carries that mass: its modes are
//!    matched to the
//!    recording by their loaded frequencies (`SimulatedMode::match_frequency_hz`), while the
//!    catalogue's baseline is each loaded mode with the mass taken out again,
//!    λ_k/(1 − q_k) with q_k = m_v Σ_{v∈R} |φ_k(v)|² its loaded modal-mass fraction at the
//!    mass, and the added-mass weight is r_k = q_k/(1 − q_k) (at μ = max r the mass term gives
//!    back the loaded frequencies). The mass must then earn its place like any effect (ΔBIC
//!    with the site charged 2 parameters, held-out gain), and beat the plain model: stages 4
//!    and 5 also run without the mass at the plain match's E and ν, and the loaded model's
//!    report stands only if the catalogue accepts the mass and it either matches recorded modes
//!    the plain model leaves unmatched or cuts the plain line distance at least 4 times
//!    (`LOADED_MATCH_DECISIVE_CUT`; otherwise the plain report stands and
//!    `loaded_line_match.rejected` says why). Why: a mass of a few per cent splits every
//!    degenerate pair of a symmetric object and pulls the plain match's ν far off, so nothing
//!    downstream matches (the blind benchmark's added-mass cases).
//! 4. **Simulated modes**: every P2 mode up to 1.15 × the highest recorded frequency in use
//!    (SLEPc), the shapes gathered on rank 0, and per mode its drive at the strike
//!    (|φ·n|; with the strike unknown, the RMS of |φ·n| over the surface vertices one can hit),
//!    its motion at the support (the surface vertices within 1 % of the height of the lowest
//!    point along `support_direction`), its near-degenerate cluster (0.5 %), and, with the
//!    microphone positions known, |acoustic transfer| to each microphone
//!    ([`crate::audio::radiation`]).
//! 5. **Catalogue** ([`crate::diagnose::catalogue::diagnose`], rank 0): matching, baseline,
//!    every effect tried, greedy ΔBIC selection with the held-out check. Then the object map:
//!    the baseline's frequency residuals regressed on each surface vertex's |φ_k|² pattern
//!    ([`crate::diagnose::evidence::localise_frequency_residuals`]); when the best region's
//!    z exceeds 2, the catalogue runs again with that region as the candidate added-mass site,
//!    charged 2 parameters for having been chosen from the data (not when the simulation
//!    carries the loaded match's mass: its site is the candidate). `<out stem>.json` records
//!    the loaded match under `material.loaded_line_match` (`used`: whether it was carried).
//!
//! # Output
//!
//! * `out` (HDF5, written atomically), `/` attrs `format` = `diffsound.diagnose`,
//!   `format_version` = 1, provenance; `/material` attrs; `/observed/{frequency_hz,
//!   frequency_sd_hz,decay_rate,decay_rate_sd}` `[K]` and `/observed/amplitudes` `[K, C]`;
//!   `/held_out/...` the same; `/simulated/{frequency_hz,drive,support_weight,mass_weight,
//!   cluster}`; `/matching/{observed,simulated_first,observed_hz,simulated_hz}`;
//!   `/residuals/{frequency_hz,z_ln_f_before,z_ln_f_after,z_ln_d_before,z_ln_d_after,
//!   z_ln_a_before,z_ln_a_after}` (amplitude: RMS over channels); `/envelopes/{times_s,
//!   band_edges_hz,noise_floor}` and `/envelopes/energy` `[B, T]`; `/effects` attrs
//!   `accepted`, `rejected` (names), `held_out_before`, `held_out_after`;
//!   `/localisation/{vertex,mu,z}` over the surface vertices.
//! * `<out stem>.json`: the whole report (the catalogue's [`CatalogueReport`] under
//!   `catalogue`; the [`Evidence`] and [`CatalogueSettings`] of its final pass under
//!   `catalogue_input`, so that `examples/catalogue_replay` can re-run it; material, channels,
//!   timings).
//! * `<out stem>_map.h5` + `.xdmf` (ParaView): the simulated modes and the node field
//!   `mass_region_z` (ζ(v) in every component) of the localisation.
//! * Plots (prefix `plots`): `_residuals.png` (standardised residuals of ln f, ln d and ln a per
//!   matched mode, baseline vs final model), `_timefreq.png` (spectrograms of the recording
//!   and of recording − modal resynthesis, fit channel 0), `_envelopes.png` (residual energy
//!   per band over time against the pre-roll floor).

use super::{fail, Progress};
use crate::assembly;
use crate::audio::chain::{DampingModel, Strike};
use crate::audio::health::ChannelHealth;
use crate::audio::radiation::{fit_multipoles, MultipoleSettings, SurfaceQuadrature};
use crate::audio::recording::{load_recording, GainPolicy, RecordingOptions};
use crate::audio::stft::StftPlan;
use crate::diagnose::catalogue::{
    self, CatalogueReport, CatalogueSettings, Evidence, ObservedMode, ResidualEnvelopes,
};
use crate::diagnose::evidence::{self, EnvelopeOptions, ObservedOptions};
use crate::diagnose::extract::{
    extract_modes, fit_glides, ExtractOptions, GlideOptions, ModalExtraction,
};
use crate::diagnose::inject;
use crate::eigen::reduced::{lame_unit, AttachmentProjections, AttachmentSolver, PoissonBasis};
use crate::eigen::{self, EigenConfig, ModeRequest};
use crate::fem::Material;
use crate::inverse::loaded_match::{
    loaded_line_candidates, loaded_modes, loaded_modes_enriched, scale_fit, Enrichment,
    LoadedMatch, LoadedMatchProblem, LoadedMatchSettings, ModesAtPoisson,
};
use crate::inverse::material::{
    line_match_targets, line_spectrum_start, LineSpectrumStart, MaterialFitSettings,
    MaterialProblem,
};
use crate::io::fit_material::read_material as read_fit_material;
use crate::io::paths::{plot_path, with_suffix};
use crate::io::plot::{
    line_plot_png, spectrogram_png, AxisScale, LineFigure, Marker, Series, SpectrogramFigure,
    SpectrogramPanel,
};
use crate::io::results::ResultsFile;
use crate::io::{write_modes, MaterialRecord, ModesFile, NodeField};
use crate::mesh::{self, ReadOptions, TetMesh};
use crate::petsc::{Petsc, PetscInt};
use clap::Args;
use mpi::environment::Universe;
use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};
use std::cell::RefCell;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::rc::Rc;
use std::time::Instant;

#[derive(Args, Debug, Clone, Default)]
#[command(allow_negative_numbers = true)]
pub struct DiagnoseArgs {
    /// TOML configuration file (see the README); flags given here override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// A benchmark case's metadata.toml (examples/diagnose_generate.rs): mesh, recordings,
    /// strike, microphones and support from there.
    #[arg(long)]
    pub case: Option<PathBuf>,
    /// Tet mesh of the object (Gmsh .msh).
    #[arg(long)]
    pub mesh: Option<PathBuf>,
    /// Length unit of the mesh (m, cm, mm, … or metres per unit).
    #[arg(long)]
    pub units: Option<String>,
    /// A WAV file of the strike (repeat for several microphones).
    #[arg(long = "recording")]
    pub recordings: Vec<PathBuf>,
    /// A fit-material HDF5 result to take E, ν and ρ from.
    #[arg(long)]
    pub material: Option<PathBuf>,
    /// Young's modulus in Pa (instead of --material).
    #[arg(long)]
    pub youngs: Option<f64>,
    /// Poisson's ratio (instead of --material).
    #[arg(long)]
    pub poisson: Option<f64>,
    /// Density in kg/m³ (default 2700).
    #[arg(long)]
    pub density: Option<f64>,
    /// Held-out microphones, 0-based, comma separated (default: every second one).
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
    /// Print progress even when stderr is not a terminal.
    #[arg(long, short)]
    pub verbose: bool,
    /// PETSc/SLEPc options, after `--`.
    #[arg(last = true, allow_hyphen_values = true)]
    pub petsc_options: Vec<String>,
}

/// The TOML file (every key optional).
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DiagnoseFileConfig {
    pub mesh: Option<PathBuf>,
    pub units: Option<String>,
    #[serde(default)]
    pub recordings: Vec<PathBuf>,
    /// fit-material result to read E, ν, ρ from.
    pub material_fit: Option<PathBuf>,
    pub held_out_microphones: Option<Vec<usize>>,
    pub out: Option<PathBuf>,
    pub plots: Option<PathBuf>,
    #[serde(default)]
    pub recording: RecordingSection,
    #[serde(default)]
    pub model: ModelSection,
    #[serde(default)]
    pub observed: ObservedOptions,
    #[serde(default)]
    pub extract: ExtractOptions,
    /// The chirp-aware stage after the extraction.
    #[serde(default)]
    pub glide: GlideOptions,
    #[serde(default)]
    pub envelopes: EnvelopeOptions,
    #[serde(default)]
    pub catalogue: CatalogueSettings,
    #[serde(default)]
    pub solver: SolverSection,
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordingSection {
    pub sample_rate: Option<u32>,
    pub duration: Option<f64>,
    pub pre_roll: Option<f64>,
    pub max_frequency_hz: Option<f64>,
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelSection {
    pub density: Option<f64>,
    pub youngs_modulus: Option<f64>,
    pub poisson_ratio: Option<f64>,
    pub strike_vertex: Option<usize>,
    /// Into the surface; default: the inward normal at the vertex.
    pub strike_direction: Option<[f64; 3]>,
    /// Direction from the object to its support (default [0, 0, −1]).
    pub support_direction: Option<[f64; 3]>,
    /// Metres, one per recording, in the mesh's frame.
    pub microphone_positions: Option<Vec<[f64; 3]>>,
    /// With the material unknown, also try the loaded line match (a candidate added mass in the
    /// model, module docs, stage 3). Default true: on all three blind-benchmark seeds it scores
    /// higher than the plain match alone, with no false alarm on a clean case (README, diagnose).
    pub loaded_mass_match: Option<bool>,
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SolverSection {
    #[serde(default)]
    pub petsc_options: Vec<String>,
}

/// A benchmark case's metadata (written by `examples/diagnose_generate.rs`).
#[derive(Clone, Debug, Deserialize)]
struct CaseMeta {
    mesh: PathBuf,
    mesh_unit: String,
    density_kg_m3: f64,
    sample_rate_hz: u32,
    onset_time_s: f64,
    duration_after_onset_s: f64,
    microphone_files: Vec<PathBuf>,
    microphone_positions_m: Vec<[f64; 3]>,
    support_direction: [f64; 3],
    strike: CaseStrike,
}

#[derive(Clone, Debug, Deserialize)]
struct CaseStrike {
    vertex: usize,
    direction: [f64; 3],
}

/// Where E and ν come from.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MaterialSource {
    FitFile(PathBuf),
    Given,
    LineSpectrum,
}

/// Everything resolved and checked before PETSc starts.
#[derive(Clone, Debug)]
pub struct Job {
    pub mesh: PathBuf,
    pub unit_scale: f64,
    pub recordings: Vec<PathBuf>,
    pub fit_channels: Vec<usize>,
    pub held_channels: Vec<usize>,
    /// Each recording's health, measured at the start of the job (empty before).
    pub channel_health: Vec<ChannelHealth>,
    pub sample_rate: u32,
    pub duration: f64,
    pub pre_roll: f64,
    pub max_frequency_hz: f64,
    pub density: f64,
    pub material: Option<(f64, f64)>,
    pub material_source: MaterialSource,
    /// `[model] loaded_mass_match` or `--loaded-mass-match`.
    pub loaded_mass_match: bool,
    pub strike_vertex: Option<usize>,
    pub strike_direction: Option<[f64; 3]>,
    pub support_direction: [f64; 3],
    pub microphones: Option<Vec<[f64; 3]>>,
    pub observed: ObservedOptions,
    pub extract: ExtractOptions,
    pub glide: GlideOptions,
    pub envelopes: EnvelopeOptions,
    pub catalogue: CatalogueSettings,
    pub out: PathBuf,
    pub json: PathBuf,
    pub map: PathBuf,
    pub plots: PathBuf,
    pub petsc_options: Vec<String>,
    pub verbose: bool,
}

fn unit_vector(v: [f64; 3], what: &str) -> Result<[f64; 3], String> {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if !(n.is_finite() && n > 0.0) {
        return Err(format!(
            "{what} must be a non-zero finite vector, got {v:?}"
        ));
    }
    Ok(v.map(|c| c / n))
}

/// Merges defaults < case metadata < config file < flags and validates.
pub fn resolve(args: &DiagnoseArgs) -> Result<Job, String> {
    let file = match &args.config {
        Some(p) => {
            let text = std::fs::read_to_string(p).map_err(|e| format!("{}: {e}", p.display()))?;
            toml::from_str::<DiagnoseFileConfig>(&text)
                .map_err(|e| format!("{}: {e}", p.display()))?
        }
        None => DiagnoseFileConfig::default(),
    };
    let case: Option<CaseMeta> = match &args.case {
        Some(p) => {
            let text = std::fs::read_to_string(p).map_err(|e| format!("{}: {e}", p.display()))?;
            Some(toml::from_str::<CaseMeta>(&text).map_err(|e| format!("{}: {e}", p.display()))?)
        }
        None => None,
    };
    let case_dir = args
        .case
        .as_ref()
        .and_then(|p| p.parent())
        .map(Path::to_path_buf)
        .unwrap_or_default();
    let mesh_from_case = case.as_ref().map(|c| c.mesh.clone());
    let units_from_case = case.as_ref().map(|c| c.mesh_unit.clone());
    let super::resolve::MeshChoice {
        mesh, unit_scale, ..
    } = super::resolve::resolve_mesh(
        &args.mesh,
        &file.mesh.clone().or(mesh_from_case),
        &args.units,
        &file.units.clone().or(units_from_case),
        Some(2),
    )?;
    if !mesh.is_file() {
        return Err(format!("mesh {} does not exist", mesh.display()));
    }
    let recordings: Vec<PathBuf> = if !args.recordings.is_empty() {
        args.recordings.clone()
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
    for r in &recordings {
        if !r.is_file() {
            return Err(format!("recording {} does not exist", r.display()));
        }
    }
    let n_mics = recordings.len();
    let held_channels: Vec<usize> = if !args.held_out.is_empty() {
        args.held_out.clone()
    } else {
        file.held_out_microphones
            .clone()
            .unwrap_or_else(|| (1..n_mics).step_by(2).collect())
    };
    if let Some(&bad) = held_channels.iter().find(|&&c| c >= n_mics) {
        return Err(format!(
            "held-out microphone {bad} does not exist ({n_mics} recordings, 0-based)"
        ));
    }
    let mut sorted = held_channels.clone();
    sorted.sort_unstable();
    sorted.dedup();
    if sorted.len() != held_channels.len() {
        return Err(format!("held-out microphones {held_channels:?} repeat"));
    }
    let fit_channels: Vec<usize> = (0..n_mics).filter(|c| !sorted.contains(c)).collect();
    if fit_channels.is_empty() {
        return Err("every microphone is held out; keep at least one for the fit".into());
    }
    if sorted.is_empty() && file.catalogue.require_held_out {
        return Err("no held-out microphone: diagnosis needs at least 2 recordings (one held out), or `[catalogue] require_held_out = false` to accept effects on ΔBIC alone".into());
    }
    let sample_rate = file
        .recording
        .sample_rate
        .or(case.as_ref().map(|c| c.sample_rate_hz))
        .unwrap_or(48_000);
    if !(8_000..=192_000).contains(&sample_rate) {
        return Err(format!(
            "the sample rate must lie in 8000..=192000 Hz, got {sample_rate}"
        ));
    }
    let duration = args
        .duration
        .or(file.recording.duration)
        .or(case.as_ref().map(|c| c.duration_after_onset_s))
        .unwrap_or(1.0);
    if !(0.1..=30.0).contains(&duration) {
        return Err(format!(
            "the duration must lie in [0.1, 30] s, got {duration}"
        ));
    }
    let pre_roll = file
        .recording
        .pre_roll
        .or(case.as_ref().map(|c| (c.onset_time_s - 0.02).max(0.0)))
        .unwrap_or(0.2);
    if !(0.0..=10.0).contains(&pre_roll) {
        return Err(format!(
            "the pre-roll must lie in [0, 10] s, got {pre_roll}"
        ));
    }
    let max_frequency_hz = args
        .fmax
        .or(file.recording.max_frequency_hz)
        .unwrap_or(12_000.0);
    if !(max_frequency_hz > 100.0 && max_frequency_hz < 0.5 * f64::from(sample_rate)) {
        return Err(format!(
            "--fmax must lie in (100 Hz, Nyquist {} Hz), got {max_frequency_hz}",
            0.5 * f64::from(sample_rate)
        ));
    }
    let mut density = args
        .density
        .or(file.model.density)
        .or(case.as_ref().map(|c| c.density_kg_m3))
        .unwrap_or(2700.0);
    let material_path = args.material.clone().or(file.material_fit.clone());
    let given = (
        args.youngs.or(file.model.youngs_modulus),
        args.poisson.or(file.model.poisson_ratio),
    );
    let (material, material_source) = match (material_path, given) {
        (Some(p), (None, None)) => {
            let (e, nu, rho) = read_fit_material(&p)?;
            density = rho;
            (Some((e, nu)), MaterialSource::FitFile(p))
        }
        (Some(_), _) => return Err("give the material either as a fit-material result (--material) or as --youngs/--poisson, not both".into()),
        (None, (Some(e), Some(nu))) => (Some((e, nu)), MaterialSource::Given),
        (None, (None, None)) => (None, MaterialSource::LineSpectrum),
        (None, _) => return Err("--youngs and --poisson go together".into()),
    };
    if !(density.is_finite() && density > 0.0) {
        return Err(format!("the density must be positive, got {density}"));
    }
    if let Some((e, nu)) = material {
        Material {
            youngs_modulus: e,
            poisson_ratio: nu,
            density,
            rayleigh_alpha: 0.0,
            rayleigh_beta: 0.0,
        }
        .validate()
        .map_err(|e| format!("material: {e}"))?;
    }
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
    let out = args
        .out
        .clone()
        .or(file.out.clone())
        .unwrap_or_else(|| PathBuf::from("diagnosis.h5"));
    let plots = args
        .plots
        .clone()
        .or(file.plots.clone())
        .unwrap_or_else(|| out.with_extension(""));
    let given = super::resolve::inputs(&mesh, &recordings);
    super::resolve::check_output(&out, &given)?;
    super::resolve::check_output(&plots, &given)?;
    let mut petsc_options = file.solver.petsc_options.clone();
    petsc_options.extend(args.petsc_options.iter().cloned());
    Ok(Job {
        json: out.with_extension("json"),
        map: with_suffix(&out, "_map.h5"),
        mesh,
        unit_scale,
        recordings,
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
        verbose: args.verbose,
    })
}

pub fn run(universe: Universe, args: DiagnoseArgs) -> Result<(), String> {
    let job = resolve(&args)?;
    let petsc =
        Petsc::initialize(universe, "diffsound", &job.petsc_options).map_err(|e| e.to_string())?;
    let (rank, size) = (petsc.rank(), petsc.size());
    match compute(&petsc, &job) {
        Ok(()) => Ok(()),
        Err(message) => fail(rank, size, &message),
    }
}

/// What rank 0 measured in the recording.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct Measured {
    names: Vec<String>,
    onset_s: f64,
    fit: Vec<ObservedMode>,
    held_out: Vec<ObservedMode>,
    envelopes: Option<ResidualEnvelopes>,
    extraction_fit: ModalExtraction,
    extraction_held: Option<ModalExtraction>,
    /// Fit channel 0 after the onset and its residual (for the plots).
    plot_signal: Vec<f64>,
    plot_residual: Vec<f64>,
    seconds: f64,
}

fn pick(channels: &[Vec<f64>], which: &[usize]) -> Vec<Vec<f64>> {
    which.iter().map(|&c| channels[c].clone()).collect()
}

/// Every channel's health, then the fit and the held-out microphones kept.
type ChannelChoice = (Vec<ChannelHealth>, Vec<usize>, Vec<usize>);

/// The recording's channel health ([`crate::audio::health`]) and the fit and held-out
/// microphones that remain: unhealthy ones dropped; an emptied held-out set takes a healthy fit
/// microphone when at least two remain (and an emptied fit set a held-out one). Rank 0.
fn healthy_channels(job: &Job) -> Result<ChannelChoice, String> {
    let options = RecordingOptions {
        target_rate: Some(job.sample_rate),
        pre_roll_s: job.pre_roll,
        duration_s: Some(job.pre_roll + job.duration),
        gain: GainPolicy::Unity,
        band_max_hz: Some(job.max_frequency_hz),
        ..Default::default()
    };
    let rec = load_recording(&job.recordings, &options).map_err(|e| e.to_string())?;
    let fs = f64::from(rec.sample_rate);
    let onset =
        (((rec.onset_s - rec.start_s) * fs).round().max(0.0) as usize).min(rec.channels[0].len());
    let health = crate::audio::health::assess(
        &rec.names,
        &rec.channels,
        onset,
        fs,
        &rec.channel_onsets_s,
        rec.onset_s,
    );
    let healthy = crate::audio::health::healthy_channels(&health).map_err(|e| e.to_string())?;
    let ok = |c: &usize| healthy.contains(c);
    let mut fit: Vec<usize> = job.fit_channels.iter().copied().filter(ok).collect();
    let mut held: Vec<usize> = job.held_channels.iter().copied().filter(ok).collect();
    if fit.is_empty() && held.len() >= 2 {
        fit.push(held.remove(0));
    }
    if held.is_empty() && !job.held_channels.is_empty() && fit.len() >= 2 {
        held.push(fit.pop().expect("two or more"));
    }
    if fit.is_empty() {
        // A lone healthy held-out channel cannot be fitted and checked at once.
        let verdicts = health
            .iter()
            .map(|h| format!("{}: {}", h.name, h.verdict.word()))
            .collect::<Vec<_>>()
            .join("; ");
        return Err(crate::audio::health::NoHealthyChannel { verdicts }.to_string());
    }
    Ok((health, fit, held))
}

fn measure(job: &Job, progress: &Progress) -> Result<Measured, String> {
    let t = Instant::now();
    let options = RecordingOptions {
        target_rate: Some(job.sample_rate),
        pre_roll_s: job.pre_roll,
        duration_s: Some(job.pre_roll + job.duration),
        gain: GainPolicy::CommonPeak(0.5),
        band_max_hz: Some(job.max_frequency_hz),
        ..Default::default()
    };
    let rec = load_recording(&job.recordings, &options).map_err(|e| e.to_string())?;
    let fs = f64::from(rec.sample_rate);
    let onset =
        (((rec.onset_s - rec.start_s) * fs).round().max(0.0) as usize).min(rec.channels[0].len());
    let (pre, post): (Vec<Vec<f64>>, Vec<Vec<f64>>) = rec
        .channels
        .iter()
        .map(|c| (c[..onset].to_vec(), c[onset..].to_vec()))
        .unzip();
    let n = post[0].len();
    if (n as f64) < 0.1 * fs {
        return Err(format!(
            "only {:.3} s of recording after the onset at {:.3} s",
            n as f64 / fs,
            rec.onset_s
        ));
    }
    progress.say(format!("{} channel(s) at {} Hz, onset at {:.4} s, {:.3} s pre-roll, {:.3} s after; fit microphones {:?}, held out {:?}", rec.channels.len(), rec.sample_rate, rec.onset_s, onset as f64 / fs, n as f64 / fs, job.fit_channels, job.held_channels));
    // Extraction, then the chirp-aware stage: a gliding mode comes out as one mode with its
    // glide instead of a cluster of constant poles (which would read as a split pair).
    let extract = |channels: &[Vec<f64>], what: &str| -> Result<ModalExtraction, String> {
        let t = Instant::now();
        let ex = extract_modes(channels, fs, &job.extract)
            .map_err(|e| format!("mode extraction ({what}): {e}"))?;
        let stage = fit_glides(channels, &ex, &job.glide)
            .map_err(|e| format!("glide stage ({what}): {e}"))?;
        let selected: Vec<_> = stage.decisions.iter().filter(|d| d.selected).collect();
        let merged: usize = selected.iter().map(|d| d.poles_hz.len()).sum();
        let gliding: usize = selected.iter().map(|d| d.f0_hz.len()).sum();
        progress.say(format!("extraction ({what}): {} modes, {} after the glide stage ({} groups tried, {} gliding modes from {} poles) in {:.1} s", ex.modes.len(), stage.extraction.modes.len(), stage.decisions.len(), gliding, merged, t.elapsed().as_secs_f64()));
        for d in &selected {
            let round = |v: &[f64]| {
                v.iter()
                    .map(|f| (f * 100.0).round() / 100.0)
                    .collect::<Vec<_>>()
            };
            let glides: Vec<String> = d
                .glide
                .iter()
                .zip(&d.glide_sd)
                .map(|(g, s)| format!("{g:.3e} ± {s:.1e}"))
                .collect();
            progress.say(format!(
                "    glide: poles {:?} Hz → f₀ = {:?} Hz, d = {:?} 1/s, g = [{}] (ΔBIC {:.1})",
                round(&d.poles_hz),
                round(&d.f0_hz),
                round(&d.decay_rate),
                glides.join(", "),
                d.delta_bic
            ));
        }
        Ok(stage.extraction)
    };
    let fit_post = pick(&post, &job.fit_channels);
    let full = extract(&fit_post, "fit microphones")?;
    let in_band = |mut modes: Vec<ObservedMode>| {
        modes.retain(|m| m.frequency_hz <= job.max_frequency_hz);
        modes
    };
    let fit = in_band(evidence::observed_modes(&full, None, None, &job.observed));
    let (held_out, extraction_held) = if job.held_channels.is_empty() {
        (Vec::new(), None)
    } else {
        let held = extract(&pick(&post, &job.held_channels), "held-out microphones")?;
        (
            in_band(evidence::observed_modes(&held, None, None, &job.observed)),
            Some(held),
        )
    };
    let envelopes = match evidence::residual_envelopes(
        &fit_post,
        &pick(&pre, &job.fit_channels),
        &full,
        &job.envelopes,
    ) {
        Ok(e) => Some(e),
        Err(e) => {
            progress.say(format!("no residual envelopes: {e}"));
            None
        }
    };
    let model0 = full.render_channel(0, n);
    let plot_residual = fit_post[0]
        .iter()
        .zip(&model0)
        .map(|(a, b)| a - b)
        .collect();
    Ok(Measured {
        names: rec.names,
        onset_s: rec.onset_s,
        fit,
        held_out,
        envelopes,
        extraction_fit: full,
        extraction_held,
        plot_signal: fit_post[0].clone(),
        plot_residual,
        seconds: t.elapsed().as_secs_f64(),
    })
}

/// Per-mode features on rank 0 from the full shapes (original node order).
struct Features {
    frequencies_hz: Vec<f64>,
    clusters: Vec<usize>,
    drive: Vec<f64>,
    support_energy: Vec<f64>,
    transfer: Option<Vec<Vec<f64>>>,
    /// Surface vertices and |φ_k|² there: [vertex][mode].
    surface: Vec<usize>,
    surface_energy: Vec<Vec<f64>>,
    strike_note: String,
}

fn features(
    job: &Job,
    mesh: &TetMesh,
    eigenvalues: &[f64],
    shapes: &[Vec<f64>],
    progress: &Progress,
) -> Result<Features, String> {
    let along =
        |shape: &[f64], v: usize, n: [f64; 3]| (0..3).map(|c| shape[3 * v + c] * n[c]).sum::<f64>();
    let normals: std::collections::HashMap<usize, [f64; 3]> =
        mesh.vertex_normals().into_iter().collect();
    let (drive, strike_note) = match job.strike_vertex {
        Some(v) => {
            let n = match job.strike_direction {
                Some(d) => d,
                None => normals.get(&v).map(|n| n.map(|c| -c)).ok_or_else(|| {
                    format!("strike vertex {v} is not a surface vertex of the mesh")
                })?,
            };
            (
                shapes.iter().map(|s| along(s, v, n).abs()).collect(),
                format!("vertex {v}"),
            )
        }
        None => {
            // Unknown strike: the RMS drive over the vertices one can hit.
            let candidates = inject::strike_candidates(mesh, job.support_direction, 0.05);
            if candidates.is_empty() {
                return Err("no surface vertex can be struck (all face the support)".into());
            }
            let d = shapes
                .iter()
                .map(|s| {
                    (candidates
                        .iter()
                        .map(|&(v, n)| along(s, v, n).powi(2))
                        .sum::<f64>()
                        / candidates.len() as f64)
                        .sqrt()
                })
                .collect();
            (
                d,
                format!("unknown: RMS over {} surface vertices", candidates.len()),
            )
        }
    };
    let support = inject::support_nodes(mesh, job.support_direction, 0.01, 3);
    let frequencies_hz: Vec<f64> = eigenvalues
        .iter()
        .map(|&l| eigen::frequency_hz(l))
        .collect();
    let (lo, hi) = mesh.bounding_box();
    let centre = [
        0.5 * (lo[0] + hi[0]),
        0.5 * (lo[1] + hi[1]),
        0.5 * (lo[2] + hi[2]),
    ];
    let profiles: Vec<Vec<f64>> = shapes
        .iter()
        .map(|s| {
            evidence::axial_profile(s, &mesh.nodes, centre, job.support_direction, PROFILE_BINS)
        })
        .collect();
    let clusters = evidence::symmetric_cluster_ids(
        &frequencies_hz,
        &profiles,
        CLUSTER_RTOL,
        CLUSTER_PROFILE_DISTANCE,
    );
    let support_energy =
        evidence::cluster_region_energies(shapes, &frequencies_hz, &clusters, &support, false);
    let surface = mesh.surface_vertices();
    let surface_energy = surface
        .iter()
        .map(|&v| evidence::cluster_region_energies(shapes, &frequencies_hz, &clusters, &[v], true))
        .collect();
    let transfer = match &job.microphones {
        None => None,
        Some(mics) => {
            let t = Instant::now();
            let quadrature = SurfaceQuadrature::new(mesh).map_err(|e| format!("radiation: {e}"))?;
            let order: Vec<usize> = job
                .fit_channels
                .iter()
                .chain(&job.held_channels)
                .copied()
                .collect();
            let positions: Vec<[f64; 3]> = order.iter().map(|&c| mics[c]).collect();
            let mut out = Vec::new();
            for (shape, &lambda) in shapes.iter().zip(eigenvalues) {
                let un = quadrature
                    .normal_displacement(shape)
                    .map_err(|e| format!("radiation: {e}"))?;
                let fit = fit_multipoles(
                    quadrature.samples(),
                    &un,
                    lambda.sqrt(),
                    &MultipoleSettings::default(),
                )
                .map_err(|e| format!("radiation: {e}"))?;
                let nearest = positions
                    .iter()
                    .map(|x| {
                        (0..3)
                            .map(|d| (x[d] - fit.centre[d]).powi(2))
                            .sum::<f64>()
                            .sqrt()
                    })
                    .fold(f64::INFINITY, f64::min);
                if nearest <= fit.source_radius {
                    return Err(format!("a microphone {nearest:.3} m from the radiation fit's centre lies inside its source sphere ({:.3} m); the transfer there is not defined", fit.source_radius));
                }
                out.push(
                    fit.transfer(&positions)
                        .map_err(|e| e.to_string())?
                        .iter()
                        .map(|p| p.norm())
                        .collect(),
                );
            }
            progress.say(format!(
                "acoustic transfer of {} modes to {} microphones in {:.1} s",
                shapes.len(),
                positions.len(),
                t.elapsed().as_secs_f64()
            ));
            Some(out)
        }
    };
    Ok(Features {
        frequencies_hz,
        clusters,
        drive,
        support_energy,
        transfer,
        surface,
        surface_energy,
        strike_note,
    })
}

/// The localisation and, when it points somewhere, the second catalogue run.
struct Localised {
    map: Vec<(f64, f64)>,
    best: Option<(usize, f64)>,
    region: Vec<usize>,
}

/// Near-degenerate clusters: neighbouring simulated frequencies within 0.5 % whose motion has
/// the same axial profile about the support axis through the bounding-box centre.
const CLUSTER_RTOL: f64 = 0.005;

/// Axial profiles ([`evidence::axial_profile`]) of the members of a symmetry-degenerate
/// cluster: 8 × 8 cells, L1 distance at most 0.2 (of 2).
const PROFILE_BINS: usize = 8;
const CLUSTER_PROFILE_DISTANCE: f64 = 0.2;

/// Nodes of the candidate added-mass region around the best vertex.
const MASS_REGION_VERTICES: usize = 5;
/// ζ above which the best region is offered to the catalogue.
const MASS_REGION_Z: f64 = 2.0;

fn localise(report: &CatalogueReport, feats: &Features, mesh: &TetMesh) -> Localised {
    let residuals: Vec<(Vec<usize>, f64)> = report
        .residuals
        .iter()
        .filter(|r| r.before.ln_frequency.is_finite())
        .map(|r| (r.simulated.clone(), r.before.ln_frequency))
        .collect();
    let map = evidence::localise_frequency_residuals(&feats.surface_energy, &residuals);
    let best = map
        .iter()
        .enumerate()
        .filter(|(_, m)| m.1.is_finite())
        .max_by(|a, b| a.1 .1.total_cmp(&b.1 .1))
        .map(|(i, m)| (feats.surface[i], m.1));
    let region = match best {
        Some((v, z)) if z > MASS_REGION_Z => {
            inject::nearest_surface_vertices(mesh, v, MASS_REGION_VERTICES)
        }
        _ => Vec::new(),
    };
    Localised { map, best, region }
}

/// The loaded line match ([`crate::inverse::loaded_match`]) runs only when the plain match
/// leaves a distance above this (ln f): below it every line already has its partner.
const LOADED_MATCH_MIN_DISTANCE: f64 = 1e-3;
/// The simulation carries the loaded match's mass only when it at most halves the plain
/// distance.
const LOADED_MATCH_RATIO: f64 = 0.5;
/// A carried mass that the catalogue accepts stands without matching a recorded mode the
/// plain model leaves unmatched when it cuts the plain line distance at least this many times
/// (`compute`, stages 4 and 5). On the three blind-benchmark seeds (90 cases) the cases with a
/// mass that entered the search cut it 4.1–27.9 times (one 2.4, set2 case 012, which the
/// unmatched-mode test keeps), the cases without one at most 2.1 times.
const LOADED_MATCH_DECISIVE_CUT: f64 = 4.0;
/// Whether the loaded model's report stands against the plain model's (`compute`, stages 4 and
/// 5): the catalogue accepted the carried mass (`accepted`), and it either leaves fewer recorded
/// modes unmatched (`with` against `without`) or cut the plain line distance `cut` times, at
/// least [`LOADED_MATCH_DECISIVE_CUT`]. Err: why not, for the report.
fn loaded_model_verdict(
    accepted: bool,
    with: usize,
    without: usize,
    cut: f64,
) -> Result<(), String> {
    if !accepted {
        return Err("the catalogue rejected the carried mass".to_string());
    }
    if with < without || cut >= LOADED_MATCH_DECISIVE_CUT {
        return Ok(());
    }
    Err(format!("the carried mass matches no recorded mode the plain model leaves unmatched ({with} unmatched with it, {without} without) and cuts the line distance only {cut:.1} times (< {LOADED_MATCH_DECISIVE_CUT})"))
}

/// Candidate mass sites of the loaded match's coarse pass (farthest-point samples of the
/// surface vertices), and the sites around its best one tried in the fine pass.
const LOADED_MATCH_COARSE_SITES: usize = 450;
/// The coarse pass's step in ν (the fine passes refine by 0.001 over ± 0.01).
const LOADED_MATCH_COARSE_POISSON_STEP: f64 = 0.02;
const LOADED_MATCH_FINE_SITES: usize = 24;

/// Krylov blocks of attachment vectors per candidate region (three vectors each): on set2
/// case 012 (9.6 % on three vertices, true ν and E) one block left frequency errors up to 1.8 %
/// against the full solve at 9.5–10 kHz, two blocks 1.2 %, three 1.2 % (no gain: the rest is
/// the band's modes).
const ATTACHMENT_BLOCKS: usize = 2;
/// Sizes (surface vertices) of the loaded match's candidate regions around each site: the
/// coarse pass uses the first, the fine passes all. The mass's spread matters: on set2 case
/// 012 (9.6 % on three vertices) the truth's centre scored 8.6·10⁻⁴ with its three vertices
/// and 1.7·10⁻² with five.
const LOADED_MATCH_REGION_SIZES: [usize; 3] = [3, 5, 8];
/// Seconds between the loaded match's progress lines.
const LOADED_MATCH_PROGRESS_SECONDS: f64 = 30.0;
/// Candidate sites of the loaded match checked by a full solve each.
const LOADED_MATCH_CANDIDATES: usize = 4;

/// The loaded line match's answer, as the job uses and reports it.
#[derive(Clone, Debug, Serialize)]
struct LoadedMass {
    matched: LoadedMatch,
    mass_fraction: f64,
    /// Centre vertex and the region's vertices (mesh nodes).
    centre: usize,
    region: Vec<usize>,
    plain_distance: f64,
    /// Whether the simulation carried it (distance at most [`LOADED_MATCH_RATIO`] of the plain)
    /// in the final model.
    used: bool,
    /// Why a carried mass was dropped again, the report then being the plain model's (see
    /// `compute`, stages 4 and 5).
    rejected: Option<String>,
    /// The answer's distance by the Ritz model (`matched.distance` is the full solve's).
    ritz_distance: f64,
    /// The answer's loaded frequencies by the enriched Ritz model [Hz], ascending.
    ritz_hz: Vec<f64>,
    /// Largest |f_Ritz/f_full − 1| over those frequencies against the full solve with the mass
    /// (when the simulation carried it).
    ritz_check: Option<f64>,
    enrichment: EnrichmentStats,
}

/// The attachment enrichment of the loaded match: regions enriched (counted once per anchor ν),
/// failures (those fell back to the modes alone), and the factorisations (one per anchor) and
/// their time.
#[derive(Clone, Debug, Serialize)]
struct EnrichmentStats {
    regions: usize,
    failures: usize,
    factorisations: usize,
    factor_seconds: f64,
    /// Seconds spent forming the regions' attachment vectors (solves and projections).
    seconds: f64,
}

/// `n` farthest-point samples of `points`, from the first.
fn farthest_points(points: &[[f64; 3]], n: usize) -> Vec<usize> {
    let d2 = |a: [f64; 3], b: [f64; 3]| (0..3).map(|d| (a[d] - b[d]).powi(2)).sum::<f64>();
    let mut chosen = vec![0];
    let mut nearest: Vec<f64> = points.iter().map(|x| d2(*x, points[0])).collect();
    while chosen.len() < n.min(points.len()) {
        let (next, _) =
            nearest.iter().enumerate().fold(
                (0, -1.0),
                |best, (j, &d)| if d > best.1 { (j, d) } else { best },
            );
        chosen.push(next);
        for (j, x) in points.iter().enumerate() {
            nearest[j] = nearest[j].min(d2(*x, points[next]));
        }
    }
    chosen
}

/// The loaded line match on the basis whose probes are the strike DOFs (`strike_dofs` of them,
/// weighted by `problem.direction_weights`) followed by the three DOFs of each vertex of
/// `surface`. Candidate regions: each surface vertex with its nearest surface vertices
/// ([`LOADED_MATCH_REGION_SIZES`] in all). Each region's Ritz problem is enriched by its
/// [`ATTACHMENT_BLOCKS`] blocks of three attachment vectors
/// ([`crate::inverse::loaded_match::Enrichment`]), solved with a Cholesky factorisation at the
/// anchor ν the search asks for (the plain match's ν first, then each candidate's own); a
/// region whose enrichment fails falls back to the modes alone (counted in the report). The [`LOADED_MATCH_CANDIDATES`] best sites are each checked by a full solve.
/// Collective: every rank runs the same search.
#[allow(clippy::too_many_arguments)]
fn loaded_match<'p>(
    petsc: &'p Petsc,
    assembled: &assembly::Assembled<'p>,
    basis: &PoissonBasis<'p>,
    mesh: &TetMesh,
    surface: &[usize],
    strike_petsc_dofs: &[PetscInt],
    problem: &MaterialProblem,
    start: &LineSpectrumStart,
    settings: &MaterialFitSettings,
    density: f64,
    progress: &Progress,
) -> Result<LoadedMass, String> {
    let strike_dofs = strike_petsc_dofs.len();
    let points: Vec<[f64; 3]> = surface.iter().map(|&v| mesh.nodes[v]).collect();
    // Region r = (vertex r / k, the nearest LOADED_MATCH_REGION_SIZES[r % k] vertices).
    let sizes = LOADED_MATCH_REGION_SIZES.len();
    let regions: Vec<Vec<usize>> = points
        .iter()
        .flat_map(|&c| LOADED_MATCH_REGION_SIZES.iter().map(move |&n| (c, n)))
        .map(|(c, n)| inject::nearest_points(&points, c, n))
        .collect();
    let coarse: Vec<usize> = farthest_points(&points, LOADED_MATCH_COARSE_SITES)
        .into_iter()
        .map(|v| v * sizes)
        .collect();
    let neighbours = |r: usize| {
        inject::nearest_points(&points, points[r / sizes], LOADED_MATCH_FINE_SITES)
            .into_iter()
            .flat_map(|v| (0..sizes).map(move |s| v * sizes + s))
            .collect::<Vec<usize>>()
    };
    let (target, ceiling) = line_match_targets(problem)?;
    let volume = mesh.volume();
    let weights = &problem.direction_weights;
    // Drive at the strike of column j of probe values (strike DOFs first), weighted as the
    // plain match weights them.
    let strike_drive = |probes: &DMatrix<f64>, j: usize| -> f64 {
        (0..strike_dofs).map(|d| probes[(d, j)] * weights[d]).sum()
    };
    // The attachment vectors: static responses at the plain ν, the shift a tenth of the lowest
    // elastic θ (it only makes the free body's operator definite).
    let t = Instant::now();
    let lowest = basis
        .solve(start.poisson)
        .theta
        .first()
        .copied()
        .ok_or("the reduced basis has no modes")?;
    let attach_nu = std::env::var("DS_ATTACH_NU")
        .ok()
        .and_then(|v| v.parse::<f64>().ok())
        .unwrap_or(start.poisson);
    let solver = basis
        .attachment_solver(petsc, assembled, &mesh.nodes, attach_nu, 0.1 * lowest)
        .map_err(|e| format!("attachment solver: {e}"))?;
    let factor_seconds = t.elapsed().as_secs_f64();
    let rigid_all = basis
        .rigid_probe_values(&solver)
        .map_err(|e| format!("rigid motions: {e}"))?;
    let rigid = rigid_all.rows(strike_dofs, 3 * surface.len()).into_owned();
    let rigid_strike: Vec<f64> = (0..rigid_all.ncols())
        .map(|j| strike_drive(&rigid_all, j))
        .collect();
    let modes_at = |nu: f64| {
        let modes = basis.solve(nu);
        let all = basis.probe_all(&modes);
        let strike = (0..modes.theta.len())
            .map(|k| strike_drive(&all, k))
            .collect();
        ModesAtPoisson {
            theta: modes.theta.clone(),
            strike,
            values: all.rows(strike_dofs, 3 * surface.len()).into_owned(),
            lame: lame_unit(nu),
            coefficients: modes.coefficient_matrix(),
            rigid: rigid.clone(),
            rigid_strike: rigid_strike.clone(),
        }
    };
    // Enrichments by (region, anchor ν); the solver of the latest anchor other than the plain
    // one is kept (a re-anchored fine round asks for one anchor many times, then moves on).
    type EnrichmentCache = HashMap<(usize, u64), Option<Rc<Enrichment>>>;
    let cache: RefCell<EnrichmentCache> = RefCell::new(HashMap::new());
    let anchored: RefCell<Option<(u64, AttachmentSolver)>> = RefCell::new(None);
    let failures = std::cell::Cell::new(0usize);
    let enrich_seconds = std::cell::Cell::new(0.0f64);
    let factorisations = std::cell::Cell::new(1usize);
    let factor_total = std::cell::Cell::new(factor_seconds);
    let last_report = std::cell::Cell::new(Instant::now());
    let reanchor_regions = LoadedMatchSettings::default().reanchor_regions;
    let enrich = |r: usize, anchor: f64| -> Option<Rc<Enrichment>> {
        let key = (r, anchor.to_bits());
        if let Some(hit) = cache.borrow().get(&key) {
            return hit.clone();
        }
        let started = Instant::now();
        let plain = anchor.to_bits() == start.poisson.to_bits();
        if !plain && anchored.borrow().as_ref().map(|(bits, _)| *bits) != Some(anchor.to_bits()) {
            // Drop the previous anchor's factors before making the next ones.
            *anchored.borrow_mut() = None;
            let t = Instant::now();
            match basis.attachment_solver(petsc, assembled, &mesh.nodes, anchor, 0.1 * lowest) {
                Ok(made) => *anchored.borrow_mut() = Some((anchor.to_bits(), made)),
                Err(_) => {
                    failures.set(failures.get() + 1);
                    cache.borrow_mut().insert(key, None);
                    return None;
                }
            }
            factorisations.set(factorisations.get() + 1);
            factor_total.set(factor_total.get() + t.elapsed().as_secs_f64());
        }
        let loads = |r: usize| -> Vec<Vec<(PetscInt, f64)>> {
            (0..3)
                .map(|c| {
                    regions[r]
                        .iter()
                        .map(|&i| (assembled.layout.global_dof(surface[i], c) as PetscInt, 1.0))
                        .collect()
                })
                .collect()
        };
        // One batch: this region and those the search asks for next at this anchor (the whole
        // coarse pass at the plain ν; otherwise every size at the sites around this one), through
        // one multiple-right-hand-side solve (`PoissonBasis::attachments_many`).
        let upcoming: Vec<usize> = if plain && coarse.contains(&r) {
            coarse.clone()
        } else if plain {
            neighbours(r)
        } else {
            // A re-anchored pass asks for the first `reanchor_regions` around its site only.
            neighbours(r).into_iter().take(reanchor_regions).collect()
        };
        let mut batch = vec![r];
        {
            let cached = cache.borrow();
            for u in upcoming {
                if !batch.contains(&u) && !cached.contains_key(&(u, anchor.to_bits())) {
                    batch.push(u);
                }
            }
        }
        let held = anchored.borrow();
        let use_solver = if plain {
            &solver
        } else {
            &held.as_ref().expect("factored above").1
        };
        let enrichment = |r: usize, projections: AttachmentProjections| {
            let p = &projections.probe_values;
            let na = p.ncols();
            let region_values = DMatrix::from_fn(3 * regions[r].len(), na, |row, j| {
                p[(strike_dofs + 3 * regions[r][row / 3] + row % 3, j)]
            });
            let strike = (0..na).map(|j| strike_drive(p, j)).collect();
            Rc::new(Enrichment {
                projections,
                region_values,
                strike,
            })
        };
        let groups: Vec<_> = batch.iter().map(|&r| loads(r)).collect();
        let made: Vec<Option<Rc<Enrichment>>> = match basis.attachments_many(
            petsc,
            assembled,
            use_solver,
            &groups,
            ATTACHMENT_BLOCKS,
        ) {
            Ok(list) => batch
                .iter()
                .zip(list)
                .map(|(&r, p)| Some(enrichment(r, p)))
                .collect(),
            // One bad region must not cost the batch: each alone, a failure falling back to
            // the modes alone.
            Err(_) => batch
                .iter()
                .map(|&r| {
                    match basis.attachments(
                        petsc,
                        assembled,
                        use_solver,
                        &loads(r),
                        ATTACHMENT_BLOCKS,
                    ) {
                        Ok(p) => Some(enrichment(r, p)),
                        Err(_) => {
                            failures.set(failures.get() + 1);
                            None
                        }
                    }
                })
                .collect(),
        };
        drop(held);
        {
            let mut cached = cache.borrow_mut();
            for (&u, e) in batch.iter().zip(&made) {
                cached.insert((u, anchor.to_bits()), e.clone());
            }
        }
        let made = made[0].clone();
        enrich_seconds.set(enrich_seconds.get() + started.elapsed().as_secs_f64());
        // The search is silent otherwise for minutes: report it about every 30 s.
        if last_report.get().elapsed().as_secs_f64() >= LOADED_MATCH_PROGRESS_SECONDS {
            last_report.set(Instant::now());
            progress.say(format!("  loaded line match: {} regions enriched so far (attachments at ν = {anchor:.3}), {:.0} s", cache.borrow().len(), t.elapsed().as_secs_f64()));
        }
        made
    };
    let search = LoadedMatchProblem {
        target_ln_f: &target,
        ceiling_ln_f: ceiling,
        density,
        volume,
        regions: &regions,
        coarse: &coarse,
        neighbours: &neighbours,
        plain_youngs: start.youngs,
        enrichment: Some(&enrich),
        anchor_poisson: start.poisson,
    };
    let match_settings = LoadedMatchSettings {
        poisson_bounds: settings.poisson_bounds,
        cap: settings.line_match_cap,
        coarse_poisson_step: LOADED_MATCH_COARSE_POISSON_STEP,
        ..Default::default()
    };
    let candidates =
        loaded_line_candidates(&search, &modes_at, &match_settings, LOADED_MATCH_CANDIDATES)?;
    // Each candidate checked by a full solve with its mass: the answer is the best verified
    // one, and its distance is the verified one.
    let top_hz = target
        .iter()
        .copied()
        .fold(f64::NEG_INFINITY, f64::max)
        .exp();
    let (lo, hi) = mesh.bounding_box();
    let diagonal = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
    let mut verified: Vec<(f64, f64, LoadedMatch)> = Vec::with_capacity(candidates.len());
    for cand in candidates {
        let material = Material {
            youngs_modulus: cand.youngs,
            poisson_ratio: cand.poisson,
            density,
            rayleigh_alpha: 0.0,
            rayleigh_beta: 0.0,
        };
        let (k, mut m) = assembled.operators(&material).map_err(|e| e.to_string())?;
        let nodes: Vec<usize> = regions[cand.region].iter().map(|&i| surface[i]).collect();
        assembly::add_nodal_diagonal(
            petsc,
            &mut m,
            &assembled.layout,
            &nodes,
            [cand.mass_kg / nodes.len() as f64; 3],
        )
        .map_err(|e| e.to_string())?;
        m.set_symmetric().map_err(|e| e.to_string())?;
        let cfg = EigenConfig::new(
            ModeRequest::UpTo {
                f_max_hz: 1.15 * top_hz,
            },
            eigen::spectrum_scale(material.lame_mu(), density, diagonal),
        );
        let full = eigen::solve_modes(petsc, &k, &m, &cfg).map_err(|e| e.to_string())?;
        let mut loaded = Vec::with_capacity(full.eigenvalues.len());
        for (lambda, v) in full.eigenvalues.iter().zip(&full.vectors) {
            let at_strike = v
                .gather_indices(strike_petsc_dofs)
                .map_err(|e| e.to_string())?;
            let drive: f64 = at_strike.iter().zip(weights).map(|(x, w)| x * w).sum();
            loaded.push((lambda * density / cand.youngs, drive * drive));
        }
        let (distance, youngs) = scale_fit(
            &target,
            ceiling,
            &loaded,
            density,
            cand.youngs,
            0.02,
            &match_settings,
        );
        progress.say(format!(
            "  loaded candidate: ν = {:.4} (attachments at ν = {:.3}), {:.2} % of the body at surface vertex {}: Ritz distance {:.2e}, full solve {:.2e} (E = {:.4e} Pa)",
            cand.poisson,
            cand.anchor_poisson,
            100.0 * cand.mass_kg / (density * volume),
            surface[regions[cand.region][0]],
            cand.distance,
            distance,
            youngs
        ));
        verified.push((distance, youngs, cand));
    }
    let (verified_distance, verified_youngs, found) = verified
        .into_iter()
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .ok_or("the loaded line match found no candidate")?;
    let ritz_distance = found.distance;
    let found = LoadedMatch {
        youngs: verified_youngs,
        distance: verified_distance,
        ..found
    };
    // The answer's loaded frequencies by the enriched Ritz model, for the check against the
    // full solve that carries the mass.
    let modes = modes_at(found.poisson);
    let alpha = found.mass_kg / density / regions[found.region].len() as f64;
    let loaded = match enrich(found.region, found.anchor_poisson) {
        Some(extra) => {
            loaded_modes_enriched(&modes, &regions[found.region], &extra, alpha).unwrap_or_default()
        }
        None => loaded_modes(&modes, &regions[found.region], alpha),
    };
    let ritz_hz = loaded
        .iter()
        .map(|(theta, _)| (found.youngs / density * theta).sqrt() / (2.0 * std::f64::consts::PI))
        .collect();
    let region: Vec<usize> = regions[found.region].iter().map(|&i| surface[i]).collect();
    let enrichment = EnrichmentStats {
        regions: cache.borrow().len(),
        failures: failures.get(),
        factorisations: factorisations.get(),
        factor_seconds: factor_total.get(),
        seconds: enrich_seconds.get(),
    };
    Ok(LoadedMass {
        mass_fraction: found.mass_kg / (density * volume),
        centre: surface[regions[found.region][0]],
        region,
        plain_distance: start.distance,
        used: false,
        rejected: None,
        matched: found,
        ritz_distance,
        ritz_hz,
        ritz_check: None,
        enrichment,
    })
}

fn compute(petsc: &Petsc, job: &Job) -> Result<(), String> {
    let total = Instant::now();
    let rank = petsc.rank();
    let progress = super::stderr_progress(rank, job.verbose);
    let read = mesh::read_mesh(
        &job.mesh,
        &ReadOptions {
            unit_scale: job.unit_scale,
            fix_inverted: false,
        },
    )
    .map_err(|e| e.to_string())?;
    let mesh_model: TetMesh = mesh::lift_to_quadratic(&read.mesh);
    drop(read);
    if let Some(v) = job.strike_vertex {
        if v >= mesh_model.n_nodes() {
            return Err(format!(
                "strike vertex {v} does not exist ({} nodes)",
                mesh_model.n_nodes()
            ));
        }
    }

    // 0: channel health (rank 0, shared): a dead, noise-only or misaligned microphone is left
    // out with a warning naming its file, never used as evidence.
    let local = (rank == 0).then(|| healthy_channels(job));
    let (health, fit_channels, held_channels): ChannelChoice =
        crate::workflow::broadcast_from_root(petsc, local)??;
    if rank == 0 {
        for h in health.iter().filter(|h| !h.is_healthy()) {
            eprintln!("{}", h.left_out_warning("the diagnosis"));
        }
        if held_channels.is_empty() && !job.held_channels.is_empty() {
            eprintln!("warning: no held-out microphone carries the strike: no effect can be confirmed on held-out evidence");
        } else if held_channels != job.held_channels || fit_channels != job.fit_channels {
            eprintln!("note: microphones used: fit {fit_channels:?}, held out {held_channels:?} (asked: fit {:?}, held out {:?})", job.fit_channels, job.held_channels);
        }
    }
    let adjusted = Job {
        fit_channels,
        held_channels,
        channel_health: health,
        ..job.clone()
    };
    let job = &adjusted;

    // 1–2: the recording (rank 0), shared so that every rank stops together on an error.
    let local = (rank == 0).then(|| measure(job, &progress));
    let measured: Measured = crate::workflow::broadcast_from_root(petsc, local)??;
    if measured.fit.len() < 4 {
        return Err(format!(
            "only {} modes found in the recording below {} Hz; the diagnosis needs at least 4",
            measured.fit.len(),
            job.max_frequency_hz
        ));
    }
    let top_observed = measured
        .fit
        .iter()
        .map(|m| m.frequency_hz)
        .fold(0.0_f64, f64::max);

    // 3: the material.
    let t_material = Instant::now();
    let assembled = assembly::assemble(petsc, &mesh_model).map_err(|e| e.to_string())?;
    let (lo, hi) = mesh_model.bounding_box();
    let diagonal = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
    let mut line_start = None;
    let mut loaded: Option<LoadedMass> = None;
    let (youngs, poisson) = match job.material {
        Some(m) => m,
        None => {
            let point = match job.strike_vertex {
                Some(v) => mesh_model
                    .surface_point_at_vertex(v)
                    .ok_or_else(|| format!("strike vertex {v} is not a surface corner node"))?,
                None => mesh_model
                    .default_strike_point()
                    .ok_or("the mesh has no surface")?,
            };
            let normal = job
                .strike_direction
                .map(|d| d.map(|c| -c))
                .unwrap_or(point.normal);
            let (mut dofs, w) =
                super::fit_material::probe_along(&mesh_model, &point, normal, &assembled.layout);
            // The basis also carries every surface vertex's values, for the loaded match.
            let strike_dofs = dofs.len();
            let surface = if job.loaded_mass_match {
                mesh_model.surface_vertices()
            } else {
                Vec::new()
            };
            dofs.extend(
                surface
                    .iter()
                    .flat_map(|&v| (0..3).map(move |c| (v, c)))
                    .map(|(v, c)| assembled.layout.global_dof(v, c) as PetscInt),
            );
            // Enough modes to cover the recorded band; spurious weak poles (a reverberant tail) must
            // not inflate the solves, so the count is capped.
            let n_modes = (measured.fit.len() + 8).min(48);
            let samples = [0.1, 0.25, 0.4];
            progress.say(format!("material unknown: reduced basis in ν ({n_modes} modes at ν = {samples:?}) for the line-spectrum match"));
            let strike_petsc_dofs: Vec<PetscInt> = dofs[..strike_dofs].to_vec();
            let basis =
                PoissonBasis::build(petsc, &assembled, diagonal, n_modes, 8, &samples, dofs)
                    .map_err(|e| e.to_string())?;
            let problem = MaterialProblem {
                targets: &[],
                sample_rate: f64::from(job.sample_rate),
                density: job.density,
                damping: DampingModel::Rayleigh {
                    alpha: 0.0,
                    beta: 0.0,
                },
                strike: Strike::default(),
                direction_weights: w,
                max_frequency_hz: Some(job.max_frequency_hz),
                target_modes_hz: measured.fit.iter().map(|m| m.frequency_hz).collect(),
            };
            let settings = MaterialFitSettings {
                youngs_search_factor: 8.0,
                ..Default::default()
            };
            let start = line_spectrum_start(&basis, &problem, (7.2e10, 0.25), &settings)?;
            progress.say(format!(
                "line-spectrum match: E = {:.4e} Pa, ν = {:.4} (distance {:.2e})",
                start.youngs, start.poisson, start.distance
            ));
            line_start = Some(start);
            if job.loaded_mass_match && start.distance > LOADED_MATCH_MIN_DISTANCE {
                let t = Instant::now();
                let found = loaded_match(
                    petsc,
                    &assembled,
                    &basis,
                    &mesh_model,
                    &surface,
                    &strike_petsc_dofs,
                    &problem,
                    &start,
                    &settings,
                    job.density,
                    &progress,
                )?;
                let used = found.matched.distance < LOADED_MATCH_RATIO * start.distance;
                progress.say(format!(
                    "loaded line match: E = {:.4e} Pa, ν = {:.4}, {:.2} g ({:.2} % of the body) at surface vertex {} (distance {:.2e} against {:.2e} without; {}) in {:.1} s ({} regions enriched in {:.1} s, {} failed, {} factorisations in {:.1} s)",
                    found.matched.youngs,
                    found.matched.poisson,
                    1e3 * found.matched.mass_kg,
                    100.0 * found.mass_fraction,
                    found.centre,
                    found.matched.distance,
                    start.distance,
                    if used { "the simulation carries this mass, the catalogue tests it" } else { "not used" },
                    t.elapsed().as_secs_f64(),
                    found.enrichment.regions,
                    found.enrichment.seconds,
                    found.enrichment.failures,
                    found.enrichment.factorisations,
                    found.enrichment.factor_seconds
                ));
                loaded = Some(LoadedMass { used, ..found });
            }
            match &loaded {
                Some(l) if l.used => (l.matched.youngs, l.matched.poisson),
                _ => (start.youngs, start.poisson),
            }
        }
    };
    let material_seconds = t_material.elapsed().as_secs_f64();

    // 4 and 5, twice when stage 3 carries a mass: with it, then without it at the plain
    // match's E and ν. The carried mass has only halved the line distance, and a mass the body
    // does not carry still splits pairs in the model that the recording does not split, which
    // other effects then "explain": set2 case 024 of the blind benchmark, a clean case, carried
    // 0.40 % and the catalogue accepted it and a beating pair (ΔBIC 4256 and 874) against the
    // loaded model's own unloaded baseline, the circular test the mass was meant to pass. A
    // loaded line match exists to put every line next to a partner, so the loaded model is kept
    // only if it matches recorded modes that the plain model leaves unmatched, and the catalogue
    // accepts the mass; otherwise the plain model's report stands and the JSON says why
    // (`material.loaded_line_match.rejected`). On set2 the four mass cases left 3–5 recorded
    // modes unmatched without the mass and none with it; cases 007 and 024 (no mass) left none
    // either way. A mass whose splits are small enough for the plain model to match every line
    // leaves none unmatched either way too (set3 case 028: 2.0 % of the body's mass, the plain
    // distance 3.9·10⁻³, the loaded 1.4·10⁻⁴, and without the mass the catalogue named the
    // splits a beating pair), so a decisive cut of the line distance
    // ([`LOADED_MATCH_DECISIVE_CUT`]) stands in for an unmatched mode; set2 case 024 cut it 2.1
    // times.
    let plain_material = (youngs, poisson);
    let passes: Vec<bool> = if loaded.as_ref().is_some_and(|l| l.used) {
        vec![true, false]
    } else {
        vec![false]
    };
    let mut results = Vec::with_capacity(passes.len());
    let mut solve_seconds_sum = 0.0;
    for &with_mass in &passes {
        let carried = loaded.clone().filter(|l| l.used && with_mass);
        let (youngs, poisson) = match (&carried, line_start) {
            (Some(l), _) => (l.matched.youngs, l.matched.poisson),
            (None, Some(plain)) if passes.len() == 2 => (plain.youngs, plain.poisson),
            _ => plain_material,
        };
        // 4: the simulated modes up to above the highest recorded frequency.
        let t_solve = Instant::now();
        let material = Material {
            youngs_modulus: youngs,
            poisson_ratio: poisson,
            density: job.density,
            rayleigh_alpha: 0.0,
            rayleigh_beta: 0.0,
        };
        let (k, mut m) = assembled.operators(&material).map_err(|e| e.to_string())?;
        if let Some(l) = &carried {
            // The candidate mass, lumped evenly on the region's vertices.
            let per_vertex = l.matched.mass_kg / l.region.len() as f64;
            assembly::add_nodal_diagonal(
                petsc,
                &mut m,
                &assembled.layout,
                &l.region,
                [per_vertex; 3],
            )
            .map_err(|e| e.to_string())?;
            m.set_symmetric().map_err(|e| e.to_string())?;
        }
        let cfg = EigenConfig::new(
            ModeRequest::UpTo {
                f_max_hz: 1.15 * top_observed.max(1.0),
            },
            eigen::spectrum_scale(material.lame_mu(), job.density, diagonal),
        );
        let modes = eigen::solve_modes(petsc, &k, &m, &cfg).map_err(|e| e.to_string())?;
        let shapes = assembled
            .layout
            .gather_original_order(&modes.vectors)
            .map_err(|e| e.to_string())?;
        let solve_seconds = t_solve.elapsed().as_secs_f64();
        solve_seconds_sum += solve_seconds;
        if let (Some(l), Some(record)) = (&carried, loaded.as_mut()) {
            // How well the loaded Ritz model predicted the full solve with the mass.
            let full: Vec<f64> = modes
                .eigenvalues
                .iter()
                .map(|&lambda| eigen::frequency_hz(lambda))
                .collect();
            let worst = l
                .ritz_hz
                .iter()
                .zip(&full)
                .map(|(r, f)| (r / f - 1.0).abs())
                .fold(0.0_f64, f64::max);
            record.ritz_check = Some(worst);
            progress.say(format!("loaded Ritz model against the full solve with the mass: largest frequency error {:.2} % over {} modes", 100.0 * worst, l.ritz_hz.len().min(full.len())));
        }
        progress.say(format!(
            "{} simulated modes up to {:.0} Hz at E = {:.4e} Pa, ν = {:.4} in {:.1} s",
            modes.eigenvalues.len(),
            1.15 * top_observed,
            youngs,
            poisson,
            solve_seconds
        ));
        for w in &modes.warnings {
            if rank == 0 {
                eprintln!("warning: {w}");
            }
        }

        // 5: features, catalogue, localisation (rank 0).
        let outcome: Option<Result<_, String>> = (rank == 0).then(|| {
            (|| {
                let t_diag = Instant::now();
                // With a carried mass: each mode's loaded modal-mass fraction at the mass q_k, its
                // eigenvalue with the mass taken out again (Rayleigh quotient of the loaded shape without
                // the mass, λ/(1 − q_k)), and the added-mass weight r_k = q_k/(1 − q_k) (module docs).
                let unloading = carried.as_ref().map(|l| {
                    let per_vertex = l.matched.mass_kg / l.region.len() as f64;
                    shapes.iter().map(|s| (per_vertex * evidence::region_energy(s, &l.region)).min(0.95)).collect::<Vec<f64>>()
                });
                let eigenvalues: Vec<f64> = match &unloading {
                    Some(q) => modes.eigenvalues.iter().zip(q).map(|(l, q)| l / (1.0 - q)).collect(),
                    None => modes.eigenvalues.clone(),
                };
                let feats = features(job, &mesh_model, &eigenvalues, &shapes, &progress)?;
                let mass_weights: Option<Vec<f64>> = unloading.as_ref().map(|q| q.iter().map(|q| q / (1.0 - q)).collect());
                let mut simulated = evidence::simulated_modes(&feats.frequencies_hz, &feats.drive, &feats.support_energy, mass_weights.as_deref(), feats.transfer.as_deref(), &feats.clusters).map_err(|e| e.to_string())?;
                if unloading.is_some() {
                    for (sim, &lambda) in simulated.iter_mut().zip(&modes.eigenvalues) {
                        sim.match_frequency_hz = Some(eigen::frequency_hz(lambda));
                    }
                }
                let mut evidence = Evidence { fit: measured.fit.clone(), held_out: (!measured.held_out.is_empty()).then(|| measured.held_out.clone()), simulated, residual_envelopes: measured.envelopes.clone() };
                let mut first_settings = job.catalogue.clone();
                if carried.is_some() {
                    // The site was chosen from the same data: a 2-D location.
                    first_settings.mass_region_search_params = 2;
                }
                let first = catalogue::diagnose(&evidence, &first_settings).map_err(|e| format!("catalogue: {e}"))?;
                let localised = localise(&first, &feats, &mesh_model);
                let mut final_settings = first_settings.clone();
                let report = if localised.region.is_empty() || carried.is_some() {
                    first
                } else {
                    let mass_energy = evidence::cluster_region_energies(&shapes, &feats.frequencies_hz, &feats.clusters, &localised.region, true);
                    evidence.simulated = evidence::simulated_modes(&feats.frequencies_hz, &feats.drive, &feats.support_energy, Some(&mass_energy), feats.transfer.as_deref(), &feats.clusters).map_err(|e| e.to_string())?;
                    final_settings.mass_region_search_params = 2;
                    progress.say(format!("frequency residuals point at surface vertex {} (z = {:.1}); catalogue again with it as the candidate added-mass region", localised.best.map_or(0, |b| b.0), localised.best.map_or(0.0, |b| b.1)));
                    catalogue::diagnose(&evidence, &final_settings).map_err(|e| format!("catalogue: {e}"))?
                };
                let diagnose_seconds = t_diag.elapsed().as_secs_f64();
                Ok((report, localised, feats, evidence, final_settings, diagnose_seconds))
            })()
        });
        // Rank 0 keeps each pass's outcome (an error too: every rank must still take part in
        // the next pass's solve) with what writing it needs.
        if let Some(outcome) = outcome {
            results.push((
                outcome,
                youngs,
                poisson,
                modes.eigenvalues.clone(),
                modes.rigid_eigenvalues.clone(),
                shapes,
            ));
        }
    }
    if rank != 0 {
        return Ok(());
    }
    let unmatched = |r: &CatalogueReport| r.matching.unmatched_observed.len();
    let mut results = results.into_iter();
    let first = results.next().ok_or("no simulated model")?;
    let chosen = match results.next() {
        None => first,
        Some(plain) => {
            let (first_report, plain_report) = (
                first.0.as_ref().map_err(|e| e.clone())?,
                plain.0.as_ref().map_err(|e| e.clone())?,
            );
            let accepted = first_report
                .0
                .accepted
                .iter()
                .any(|a| a.name == "added_mass");
            let (with, without) = (unmatched(&first_report.0), unmatched(&plain_report.0));
            let cut = loaded
                .as_ref()
                .map_or(1.0, |l| l.plain_distance / l.matched.distance);
            let verdict = loaded_model_verdict(accepted, with, without, cut);
            let keep = verdict.is_ok();
            let why = verdict.err().unwrap_or_default();
            if keep {
                progress.say(format!("the carried mass stands: accepted by the catalogue, {with} recorded modes unmatched with it against {without} without, line distance cut {cut:.1} times"));
                first
            } else {
                progress.say(format!(
                    "{why}: the report is the plain model's (E = {:.4e} Pa, ν = {:.4})",
                    plain.1, plain.2
                ));
                if let Some(record) = loaded.as_mut() {
                    record.used = false;
                    record.rejected = Some(why);
                }
                plain
            }
        }
    };
    let (outcome, youngs, poisson, eigenvalues, rigid_eigenvalues, shapes) = chosen;
    let (report, localised, feats, evidence, final_settings, diagnose_seconds) = outcome?;
    let solve_seconds = solve_seconds_sum;
    print_report(job, &measured, &report, youngs, poisson, &feats, &localised);
    let timings = [
        ("measure", measured.seconds),
        ("material", material_seconds),
        ("solve", solve_seconds),
        ("catalogue", diagnose_seconds),
        ("total", total.elapsed().as_secs_f64()),
    ];
    write_json(
        job,
        &measured,
        &report,
        youngs,
        poisson,
        line_start,
        loaded.as_ref(),
        &feats,
        &localised,
        &timings,
        (&evidence, &final_settings),
    )?;
    write_hdf5(
        job,
        petsc.size(),
        &measured,
        &evidence,
        &report,
        youngs,
        poisson,
        &localised,
        &feats,
        &timings,
    )?;
    write_map(
        job,
        &mesh_model,
        &eigenvalues,
        &shapes,
        &rigid_eigenvalues,
        youngs,
        poisson,
        &feats,
        &localised,
    )?;
    write_plots(job, &measured, &report)?;
    Ok(())
}

fn fmt_param(p: &catalogue::FittedParam) -> String {
    match p.sigma {
        Some(s) => format!("{} = {:.4e} ± {:.2e} {}", p.name, p.value, s, p.unit),
        None => format!("{} = {:.4e} (undetermined) {}", p.name, p.value, p.unit),
    }
}

fn print_report(
    job: &Job,
    measured: &Measured,
    report: &CatalogueReport,
    youngs: f64,
    poisson: f64,
    feats: &Features,
    localised: &Localised,
) {
    println!(
        "diagnose: E = {youngs:.5e} Pa, ν = {poisson:.4}, ρ = {} kg/m³ ({:?}); strike {}",
        job.density, job.material_source, feats.strike_note
    );
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
        println!("  rejected {}: {:?}{extra}: {}", r.name, r.reason, r.detail);
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
                "      {:.2} Hz {:?}{}: {}",
                u.frequency_hz,
                u.quantity,
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

#[allow(clippy::too_many_arguments)]
fn write_json(
    job: &Job,
    measured: &Measured,
    report: &CatalogueReport,
    youngs: f64,
    poisson: f64,
    line_start: Option<LineSpectrumStart>,
    loaded: Option<&LoadedMass>,
    feats: &Features,
    localised: &Localised,
    timings: &[(&str, f64)],
    catalogue_input: (&Evidence, &CatalogueSettings),
) -> Result<(), String> {
    let value = serde_json::json!({
        "format": "diffsound.diagnose",
        "format_version": 1,
        "command": std::env::args().collect::<Vec<_>>().join(" "),
        "version": env!("CARGO_PKG_VERSION"),
        "mesh": job.mesh.display().to_string(),
        "recordings": job.recordings.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
        "fit_microphones": job.fit_channels,
        "held_out_microphones": job.held_channels,
        // Every recording's health and verdict; the unhealthy ones were left out.
        "channel_health": job.channel_health,
        "onset_s": measured.onset_s,
        // The pitch-glide rows are the chirp fit's g per mode (relative offset at the onset),
        // not an early-minus-late frequency difference: the scorer compares accordingly.
        "glide_observable": "offset_at_onset",
        "material": {"youngs_modulus": youngs, "poisson_ratio": poisson, "density": job.density, "source": job.material_source, "line_spectrum_start": line_start, "loaded_line_match": loaded},
        "strike": feats.strike_note,
        "observed": {"fit": measured.fit, "held_out": measured.held_out},
        "localisation": {"best_vertex": localised.best.map(|b| b.0), "best_z": localised.best.map(|b| b.1), "offered_region": localised.region},
        "catalogue": report,
        // The effects these recordings could not test, and why (a subset of the rejections).
        "untested": report.untested().iter().map(|r| serde_json::json!({"name": r.name, "reason": r.reason, "detail": r.detail})).collect::<Vec<_>>(),
        // What the final catalogue pass saw, so that it can be replayed without the audio,
        // the mesh or the solver (examples/catalogue_replay).
        "catalogue_input": {"evidence": catalogue_input.0, "settings": catalogue_input.1},
        "timings_s": timings.iter().map(|(k, v)| (k.to_string(), *v)).collect::<std::collections::BTreeMap<_, _>>(),
    });
    let text = serde_json::to_string_pretty(&value).map_err(|e| e.to_string())?;
    crate::io::write_atomically(&job.json, |tmp| {
        std::fs::write(tmp, &text).map_err(|source| crate::io::IoError::Fs {
            path: tmp.to_path_buf(),
            context: "writing the JSON report".into(),
            source,
        })
    })
    .map_err(|e| e.to_string())?;
    println!("wrote {}", job.json.display());
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn write_hdf5(
    job: &Job,
    n_ranks: usize,
    measured: &Measured,
    evidence: &Evidence,
    report: &CatalogueReport,
    youngs: f64,
    poisson: f64,
    localised: &Localised,
    feats: &Features,
    timings: &[(&str, f64)],
) -> Result<(), String> {
    let mut file = ResultsFile::new("diffsound.diagnose", 1);
    file.text("/", "mesh", &job.mesh.display().to_string())
        .text(
            "/",
            "recordings",
            &job.recordings
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", "),
        )
        .text("/", "fit_microphones", &format!("{:?}", job.fit_channels))
        .text(
            "/",
            "held_out_microphones",
            &format!("{:?}", job.held_channels),
        )
        .number("/", "n_ranks", n_ranks as f64)
        .text(
            "/",
            "command",
            &std::env::args().collect::<Vec<_>>().join(" "),
        )
        .text("/", "version", env!("CARGO_PKG_VERSION"))
        .number("/material", "youngs_modulus", youngs)
        .number("/material", "poisson_ratio", poisson)
        .number("/material", "density", job.density)
        .text("/material", "source", &format!("{:?}", job.material_source));
    if !job.channel_health.is_empty() {
        // Per recording: its SNR, whether it was used (fit or held out), and the verdict.
        let used = |c: usize| job.fit_channels.contains(&c) || job.held_channels.contains(&c);
        file.column(
            "/channels/snr_db",
            job.channel_health.iter().map(|h| h.snr_db).collect(),
            "dB",
        )
        .column(
            "/channels/used",
            (0..job.channel_health.len())
                .map(|c| if used(c) { 1.0 } else { 0.0 })
                .collect(),
            "1",
        )
        .text(
            "/channels",
            "verdicts",
            &job.channel_health
                .iter()
                .map(|h| format!("{}: {}", h.name, h.verdict.word()))
                .collect::<Vec<_>>()
                .join("; "),
        );
    }
    for (group, modes) in [
        ("/observed", &measured.fit),
        ("/held_out", &measured.held_out),
    ] {
        if modes.is_empty() {
            continue;
        }
        let c = modes[0].amplitudes.len();
        file.column(
            &format!("{group}/frequency_hz"),
            modes.iter().map(|m| m.frequency_hz).collect(),
            "Hz",
        )
        .column(
            &format!("{group}/frequency_sd_hz"),
            modes.iter().map(|m| m.sigma_frequency_hz).collect(),
            "Hz",
        )
        .column(
            &format!("{group}/decay_rate"),
            modes.iter().map(|m| m.decay_rate).collect(),
            "1/s",
        )
        .column(
            &format!("{group}/decay_rate_sd"),
            modes.iter().map(|m| m.sigma_decay_rate).collect(),
            "1/s",
        )
        .dataset(
            &format!("{group}/amplitudes"),
            &[modes.len(), c],
            modes.iter().flat_map(|m| m.amplitudes.clone()).collect(),
            "full scale",
        );
    }
    let s = &evidence.simulated;
    file.column(
        "/simulated/frequency_hz",
        s.iter().map(|m| m.frequency_hz).collect(),
        "Hz",
    )
    .column(
        "/simulated/drive",
        s.iter().map(|m| m.drive).collect(),
        "kg^-1/2",
    )
    .column(
        "/simulated/support_weight",
        s.iter().map(|m| m.support_weight).collect(),
        "1",
    )
    .column(
        "/simulated/mass_weight",
        s.iter().map(|m| m.mass_weight).collect(),
        "1",
    )
    .column(
        "/simulated/cluster",
        s.iter().map(|m| m.cluster as f64).collect(),
        "",
    );
    let pairs = &report.matching.pairs;
    if !pairs.is_empty() {
        file.column(
            "/matching/observed",
            pairs.iter().map(|p| p.observed as f64).collect(),
            "",
        )
        .column(
            "/matching/simulated_first",
            pairs
                .iter()
                .map(|p| p.simulated.first().map_or(-1.0, |&k| k as f64))
                .collect(),
            "",
        )
        .column(
            "/matching/observed_hz",
            pairs.iter().map(|p| p.observed_hz).collect(),
            "Hz",
        )
        .column(
            "/matching/simulated_hz",
            pairs.iter().map(|p| p.simulated_hz).collect(),
            "Hz",
        );
    }
    let rows = &report.residuals;
    if !rows.is_empty() {
        let rms_a = |z: &catalogue::ZScores| {
            let v: Vec<f64> = z.ln_amplitude.iter().flatten().copied().collect();
            if v.is_empty() {
                f64::NAN
            } else {
                (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
            }
        };
        file.column(
            "/residuals/frequency_hz",
            rows.iter().map(|r| r.frequency_hz).collect(),
            "Hz",
        )
        .column(
            "/residuals/z_ln_f_before",
            rows.iter().map(|r| r.before.ln_frequency).collect(),
            "1",
        )
        .column(
            "/residuals/z_ln_f_after",
            rows.iter().map(|r| r.after.ln_frequency).collect(),
            "1",
        )
        .column(
            "/residuals/z_ln_d_before",
            rows.iter()
                .map(|r| r.before.ln_decay.unwrap_or(f64::NAN))
                .collect(),
            "1",
        )
        .column(
            "/residuals/z_ln_d_after",
            rows.iter()
                .map(|r| r.after.ln_decay.unwrap_or(f64::NAN))
                .collect(),
            "1",
        )
        .column(
            "/residuals/z_ln_a_before",
            rows.iter().map(|r| rms_a(&r.before)).collect(),
            "1",
        )
        .column(
            "/residuals/z_ln_a_after",
            rows.iter().map(|r| rms_a(&r.after)).collect(),
            "1",
        );
    }
    if let Some(env) = &measured.envelopes {
        file.column("/envelopes/times_s", env.times_s.clone(), "s")
            .column("/envelopes/band_edges_hz", env.band_edges_hz.clone(), "Hz")
            .column(
                "/envelopes/noise_floor",
                env.noise_floor_estimate.clone(),
                "full scale^2",
            )
            .dataset(
                "/envelopes/energy",
                &[env.energy.len(), env.times_s.len()],
                env.energy.iter().flatten().copied().collect(),
                "full scale^2",
            );
    }
    file.text(
        "/effects",
        "accepted",
        &report
            .accepted
            .iter()
            .map(|a| format!("{} ({})", a.name, a.variant))
            .collect::<Vec<_>>()
            .join(", "),
    )
    .text(
        "/effects",
        "rejected",
        &report
            .rejected
            .iter()
            .map(|r| format!("{}: {:?}", r.name, r.reason))
            .collect::<Vec<_>>()
            .join(", "),
    )
    .number(
        "/effects",
        "held_out_before",
        report.baseline.held_out_error.unwrap_or(f64::NAN),
    )
    .number(
        "/effects",
        "held_out_after",
        report.final_model.held_out_error.unwrap_or(f64::NAN),
    )
    .number("/effects", "bic_baseline", report.baseline.bic)
    .number("/effects", "bic_final", report.final_model.bic);
    file.column(
        "/localisation/vertex",
        feats.surface.iter().map(|&v| v as f64).collect(),
        "",
    )
    .column(
        "/localisation/mu",
        localised.map.iter().map(|m| m.0).collect(),
        "1",
    )
    .column(
        "/localisation/z",
        localised.map.iter().map(|m| m.1).collect(),
        "1",
    );
    for (k, v) in timings {
        file.number("/timings", k, *v);
    }
    file.write(&job.out).map_err(|e| e.to_string())?;
    println!("wrote {}", job.out.display());
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn write_map(
    job: &Job,
    mesh: &TetMesh,
    eigenvalues: &[f64],
    shapes: &[Vec<f64>],
    rigid: &[f64],
    youngs: f64,
    poisson: f64,
    feats: &Features,
    localised: &Localised,
) -> Result<(), String> {
    let mut field = vec![0.0; 3 * mesh.n_nodes()];
    for (&v, m) in feats.surface.iter().zip(&localised.map) {
        field[3 * v..3 * v + 3].fill(m.1);
    }
    let residual_norms = vec![f64::NAN; eigenvalues.len()];
    let file = ModesFile {
        nodes: &mesh.nodes,
        connectivity: &mesh.connectivity,
        nodes_per_tet: mesh.nodes_per_tet(),
        material: MaterialRecord { name: "diagnosis".into(), youngs_modulus: youngs, poisson_ratio: poisson, density: job.density, rayleigh_alpha: 0.0, rayleigh_beta: 0.0 },
        eigenvalues,
        frequencies_hz: &feats.frequencies_hz,
        mode_shapes: shapes,
        residual_norms: &residual_norms,
        rigid_eigenvalues: rigid,
        solver: Vec::new(),
        n_ranks: 1,
        element_order: 2,
        timings: Vec::new(),
        provenance: vec![("command".into(), std::env::args().collect::<Vec<_>>().join(" "))],
        extra_datasets: Vec::new(),
        node_fields: vec![NodeField { name: "mass_region_z".into(), data: &field, units: "1 (z of the added-mass regression at this surface vertex; all three components equal)".into() }],
    };
    write_modes(&job.map, &file).map_err(|e| e.to_string())?;
    println!(
        "wrote {} and its .xdmf sidecar (ParaView: colour by mass_region_z)",
        job.map.display()
    );
    Ok(())
}

fn write_plots(job: &Job, measured: &Measured, report: &CatalogueReport) -> Result<(), String> {
    let fs = f64::from(job.sample_rate);
    // Standardised residuals per matched mode, baseline vs final.
    let rows = &report.residuals;
    let f: Vec<f64> = rows.iter().map(|r| r.frequency_hz).collect();
    let mut series = Vec::new();
    let pick =
        |g: &dyn Fn(&catalogue::ZScores) -> Option<f64>, after: bool| -> (Vec<f64>, Vec<f64>) {
            rows.iter()
                .filter_map(|r| {
                    g(if after { &r.after } else { &r.before })
                        .filter(|v| v.is_finite())
                        .map(|v| (r.frequency_hz, v))
                })
                .unzip()
        };
    let quantities: [(&str, Box<dyn Fn(&catalogue::ZScores) -> Option<f64>>); 3] = [
        (
            "ln f",
            Box::new(|z: &catalogue::ZScores| Some(z.ln_frequency)),
        ),
        ("ln d", Box::new(|z: &catalogue::ZScores| z.ln_decay)),
        (
            "ln a (RMS over mics)",
            Box::new(|z: &catalogue::ZScores| {
                let v: Vec<f64> = z.ln_amplitude.iter().flatten().copied().collect();
                (!v.is_empty())
                    .then(|| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt())
            }),
        ),
    ];
    let markers = [
        (Marker::Cross, Marker::Circle),
        (Marker::Plus, Marker::Square),
        (Marker::Cross, Marker::Diamond),
    ];
    for ((name, g), (mb, ma)) in quantities.iter().zip(markers) {
        let (xb, yb) = pick(g.as_ref(), false);
        let (xa, ya) = pick(g.as_ref(), true);
        series.push(Series::markers(format!("{name} baseline"), xb, yb, mb));
        series.push(Series::markers(format!("{name} final"), xa, ya, ma));
    }
    if !f.is_empty() {
        let accepted: Vec<String> = report.accepted.iter().map(|a| a.name.clone()).collect();
        let mut fig = LineFigure::new(
            format!(
                "standardised residuals per mode: baseline vs final ({})",
                if accepted.is_empty() {
                    "no effect accepted".into()
                } else {
                    accepted.join(", ")
                }
            ),
            "observed frequency [Hz]",
            "z (residual / sigma incl. model floor)",
        );
        fig.x_scale = AxisScale::Log;
        fig.series = series;
        line_plot_png(&plot_path(&job.plots, "_residuals.png"), &fig).map_err(|e| e.to_string())?;
    }
    // Time–frequency: the recording and what the modes leave.
    let plan = StftPlan::new(2048, 256).map_err(|e| e.to_string())?;
    let signals: [(&str, &[f64]); 2] = [
        ("recording (fit mic 0)", &measured.plot_signal),
        ("recording - modal resynthesis", &measured.plot_residual),
    ];
    let specs: Vec<_> = signals.iter().map(|(_, s)| plan.forward(s)).collect();
    let peak = specs[0].magnitude.iter().fold(0.0_f64, |m, &v| m.max(v));
    let dbs: Vec<Vec<f64>> = specs
        .iter()
        .map(|s| s.decibels(peak.max(1e-300), -140.0))
        .collect();
    let panels: Vec<SpectrogramPanel> = signals
        .iter()
        .zip(&specs)
        .zip(&dbs)
        .map(|(((title, _), s), db)| SpectrogramPanel {
            title: title.to_string(),
            db,
            n_frames: s.n_frames,
            n_bins: s.n_bins,
            time_step_s: plan.hop() as f64 / fs,
            time_offset_s: 0.0,
            freq_step_hz: fs / plan.n_fft() as f64,
        })
        .collect();
    let mut figure = SpectrogramFigure::new("where the modes do not explain the recording", panels);
    figure.max_freq_hz = Some((1.1 * job.max_frequency_hz).min(fs / 2.0));
    figure.db_max = Some(0.0);
    figure.db_min = Some(-120.0);
    spectrogram_png(&plot_path(&job.plots, "_timefreq.png"), &figure).map_err(|e| e.to_string())?;
    // Residual energy per band over time against the pre-roll floor.
    if let Some(env) = &measured.envelopes {
        let mut fig = LineFigure::new(
            "residual energy per band (lines) vs pre-roll noise floor (flat)",
            "time after the strike [s]",
            "energy [full scale^2]",
        );
        fig.y_scale = AxisScale::Log;
        for (b, band) in env.energy.iter().enumerate() {
            let label = format!(
                "{:.0}-{:.0} Hz",
                env.band_edges_hz[b],
                env.band_edges_hz[b + 1]
            );
            fig.series.push(Series::line(
                label.clone(),
                env.times_s.clone(),
                band.iter().map(|e| e.max(1e-300)).collect(),
            ));
            if env.noise_floor_estimate[b] > 0.0 {
                fig.series.push(Series::line(
                    format!("floor {label}"),
                    vec![env.times_s[0], *env.times_s.last().unwrap_or(&1.0)],
                    vec![env.noise_floor_estimate[b]; 2],
                ));
            }
        }
        line_plot_png(&plot_path(&job.plots, "_envelopes.png"), &fig).map_err(|e| e.to_string())?;
    }
    println!(
        "wrote {}_{{residuals,timefreq,envelopes}}.png",
        job.plots.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The blind benchmark's cases: seed 303 case 028 (a 2.0 % mass whose splits the plain model
    /// matched, line distance cut 27.9 times) stands; seed 202 case 024 (clean, cut 2.1 times,
    /// nothing unmatched either way) does not; a mass the catalogue rejects never does.
    #[test]
    fn a_loaded_model_stands_on_an_unmatched_mode_or_a_decisive_cut() {
        assert_eq!(loaded_model_verdict(true, 0, 0, 27.9), Ok(()));
        assert_eq!(loaded_model_verdict(true, 0, 4, 2.4), Ok(()));
        let clean = loaded_model_verdict(true, 0, 0, 2.1).unwrap_err();
        assert!(clean.contains("2.1 times"), "{clean}");
        assert!(loaded_model_verdict(false, 0, 5, 30.0)
            .unwrap_err()
            .contains("rejected"));
        assert!(loaded_model_verdict(true, 1, 1, f64::NAN).is_err());
    }
}
