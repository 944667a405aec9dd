//! `diffsound locate-impact`: where was the object struck, and how hard (issue 8).
//!
//! Mesh, material and recordings of one strike in; a likelihood map over the object's surface
//! out (HDF5 + XDMF for ParaView, PNG, JSON), with the top candidate positions and the strike
//! strength. The physics and the statistics are in [`crate::inverse::impact`]; this module
//! only wires them.
//!
//! # Steps
//!
//! 1. **Recording** (rank 0): the channels after the onset, at the samples' own scale
//!    (`GainPolicy::Unity`, so the strength stays in the recording's units); the poles of the
//!    recording below `fmax` by the sub-band ESPRIT + variable-projection extraction
//!    ([`crate::diagnose::extract`]).
//! 2. **Modes** (all ranks): the P2 modes of the mesh at the fitted material (a `fit-material`
//!    result, or `--youngs/--poisson/--density`) up to 1.05 × `fmax`; shapes gathered to
//!    rank 0. Modes whose scaled frequency (step 3) lies above `fmax` are dropped: the
//!    recording was not analysed there, so they are neither heard nor missed.
//! 3. **Poles per simulated mode.** The simulated modes are grouped into clusters of
//!    near-degenerate modes (frequencies within 0.5 %). After the global frequency scale
//!    s = median of f_obs/f_sim over nearest-neighbour pairs, every recorded pole within
//!    `match_tolerance` (default 3 %) of s·f_cluster is assigned to its nearest cluster.
//!    The recorded frequencies and decay rates are the "known poles" of the amplitude fit.
//!    A cluster no pole was assigned to gets its predicted pole, s·f_sim with the decay
//!    rate of the fit's damping curve (or the median recorded decay when no curve is given),
//!    so that a mode the strike did not excite (a strike on its nodal line) still counts, as
//!    an amplitude below its detection limit. Recorded poles no cluster claims stay in the
//!    amplitude fit (so that they do not leak into the others) and are then left out.
//! 4. **Amplitudes** ([`crate::inverse::impact::fit_amplitudes`]): linear least squares of
//!    every channel on the damped sinusoids of the poles, from the onset over `window`
//!    seconds (default 0.5), with σ; the measured amplitude of a cluster is its energy over
//!    its poles ([`crate::inverse::impact::cluster_amplitudes`]).
//! 5. **Forward table**: every surface vertex struck along its inward normal; drive φ_k·n,
//!    the contact force (impulse, or a half-sine of `contact_duration_s`), and the acoustic
//!    transfer of each mode ([`crate::audio::radiation`]): to the microphones when their
//!    positions are given, otherwise the **direction-averaged** transfer at
//!    `assumed_distance_m` (default 0.5 m), the documented fallback. With a transfer the
//!    pressure follows the modal displacement (Response::Displacement: the transfer holds the
//!    ρω² of the radiation condition); with `transfer = "none"` every |T| = 1 and the signal
//!    is taken as the surface acceleration.
//! 6. **Map** ([`crate::inverse::impact::likelihood_map`]): log-amplitude likelihood with the
//!    strength profiled (one gain per microphone unless `calibrated_microphones = true`: real
//!    microphones differ in gain and distance, so only the pattern over the modes at each
//!    microphone is trusted) and the model error σ_model profiled per vertex; posterior over the
//!    surface by area; top candidates by non-maximum suppression; the strength at the best
//!    vertex.
//! 7. **Evaluation** when the true strike vertex is known (`--true-vertex`, or a benchmark
//!    case's metadata): geodesic distance from the truth to the best candidate, the fraction
//!    of the surface ranked at or above the truth, and whether the best candidate lies on the
//!    truth's symmetry orbit ([`crate::inverse::impact::symmetry_orbit`]).
//!
//! # Output
//!
//! * `OUT.h5`: `/impact` (best vertex, position, strength ± σ, σ_model, terms), `/map` (per
//!   surface vertex: node, posterior, log-likelihood, cosine, area share, strength),
//!   `/top` (candidates), `/modes` (simulated frequency, cluster, pole used, measured and
//!   predicted amplitudes at the best vertex), `/evaluation` when the truth is known,
//!   `/timings`.
//! * `OUT_map.h5` + `.xdmf`: the mesh with node fields `posterior_density` (posterior / area
//!   share, normalised to a maximum of 1) and `log_likelihood_ratio` (ℓ − max ℓ), 0 and −∞
//!   clipped to −50 off the surface (ParaView: colour by either).
//! * `OUT.json`: the summary; `OUT_map.png`: the map seen from three sides, with the top
//!   candidates (and the truth, when known) marked.

use super::{fail, Progress};
use crate::assembly;
use crate::audio::chain::{DampingCurve, Strike};
use crate::audio::excitation::{ContactForce, Response};
use crate::audio::radiation::{fit_multipoles, MultipoleSettings, SurfaceQuadrature};
use crate::audio::recording::{load_recording, GainPolicy, RecordingOptions};
use crate::diagnose::evidence;
use crate::diagnose::extract::{extract_modes, ExtractOptions};
use crate::eigen::{self, EigenConfig, ModeRequest};
use crate::fem::Material;
use crate::inverse::impact::{
    self, AmplitudeFitOptions, ClusterAmplitudes, ForwardTable, ImpactMap, MapOptions, Pole,
    SurfaceGraph, Transfer,
};
use crate::io::fit_material::read_material as read_fit_material;
use crate::io::paths::with_suffix;
use crate::io::plot::{surface_png, SurfaceFigure, SurfaceMarker, SurfacePanel, View};
use crate::io::results::{read_dataset, ResultsFile};
use crate::io::{write_modes, MaterialRecord, ModesFile, NodeField};
use crate::mesh::{self, ReadOptions, TetMesh};
use crate::petsc::Petsc;
use crate::workflow::broadcast_from_root;
use clap::Args;
use mpi::environment::Universe;
use rustfft::num_complex::Complex64;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Args, Debug, Clone, Default)]
#[command(allow_negative_numbers = true)]
pub struct ImpactArgs {
    /// TOML configuration file (see the README); flags given here override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// A benchmark case's metadata.toml (examples/diagnose_generate.rs): mesh, recordings,
    /// microphone positions and the true strike (for the evaluation) from there.
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
    /// A fit-material HDF5 result to take E, ν, ρ and the damping curve from.
    #[arg(long)]
    pub material: Option<PathBuf>,
    /// Young's modulus in Pa (instead of --material).
    #[arg(long)]
    pub youngs: Option<f64>,
    /// Poisson's ratio (instead of --material).
    #[arg(long)]
    pub poisson: Option<f64>,
    /// Density in kg/m³ (with --youngs/--poisson; default 2700).
    #[arg(long)]
    pub density: Option<f64>,
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
    /// Print progress even when stderr is not a terminal.
    #[arg(long, short)]
    pub verbose: bool,
    /// PETSc/SLEPc options, after `--`.
    #[arg(last = true, allow_hyphen_values = true)]
    pub petsc_options: Vec<String>,
}

/// How each mode's sound reaches the microphones.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TransferChoice {
    /// Multipole transfer: to the microphone positions when given, direction-averaged otherwise.
    #[default]
    Multipole,
    /// |T| = 1 for every mode and microphone; the signal is taken as surface acceleration.
    None,
}

impl std::str::FromStr for TransferChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "multipole" => Ok(TransferChoice::Multipole),
            "none" => Ok(TransferChoice::None),
            other => Err(format!("unknown transfer {other:?}: use multipole or none")),
        }
    }
}

/// The TOML file (every key optional).
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImpactFileConfig {
    pub mesh: Option<PathBuf>,
    pub units: Option<String>,
    #[serde(default)]
    pub recordings: Vec<PathBuf>,
    /// fit-material result to read E, ν, ρ and the damping curve from.
    pub material_fit: Option<PathBuf>,
    pub youngs_modulus: Option<f64>,
    pub poisson_ratio: Option<f64>,
    pub density: Option<f64>,
    /// Metres, one per recording, in the mesh's frame.
    pub microphone_positions: Option<Vec<[f64; 3]>>,
    pub transfer: Option<TransferChoice>,
    /// Distance of the microphones for the direction-averaged transfer [m] (default 0.5).
    pub assumed_distance_m: Option<f64>,
    pub contact_duration_s: Option<f64>,
    pub max_frequency_hz: Option<f64>,
    pub window_s: Option<f64>,
    pub pre_roll_s: Option<f64>,
    pub sample_rate: Option<u32>,
    /// Relative distance of a recorded pole from s·f_sim that still matches (default 0.03).
    pub match_tolerance: Option<f64>,
    pub true_vertex: Option<usize>,
    /// The microphones share one calibrated gain (and their positions are known): one strength
    /// for all of them. Default false: one gain per microphone, profiled.
    pub calibrated_microphones: Option<bool>,
    pub out: Option<PathBuf>,
    #[serde(default)]
    pub extract: ExtractOptions,
    #[serde(default)]
    pub map: MapOptions,
    #[serde(default)]
    pub petsc_options: Vec<String>,
}

/// The parts of a benchmark case's metadata this job reads.
#[derive(Clone, Debug, Deserialize)]
struct CaseMeta {
    mesh: PathBuf,
    mesh_unit: String,
    density_kg_m3: f64,
    sample_rate_hz: u32,
    onset_time_s: f64,
    microphone_files: Vec<PathBuf>,
    microphone_positions_m: Vec<[f64; 3]>,
    strike: CaseStrike,
}

#[derive(Clone, Debug, Deserialize)]
struct CaseStrike {
    vertex: usize,
}

/// Everything resolved and checked before PETSc starts.
#[derive(Clone, Debug)]
pub struct Job {
    pub mesh: PathBuf,
    pub unit_scale: f64,
    pub recordings: Vec<PathBuf>,
    pub sample_rate: u32,
    pub pre_roll: f64,
    pub window: f64,
    pub max_frequency_hz: f64,
    pub material: Material,
    pub material_source: String,
    pub damping_curve: Option<DampingCurve>,
    pub microphones: Option<Vec<[f64; 3]>>,
    pub transfer: TransferChoice,
    pub assumed_distance_m: f64,
    pub contact_duration_s: Option<f64>,
    pub match_tolerance: f64,
    pub true_vertex: Option<usize>,
    pub extract: ExtractOptions,
    pub map: MapOptions,
    pub out: PathBuf,
    pub json: PathBuf,
    pub map_file: PathBuf,
    pub png: PathBuf,
    pub petsc_options: Vec<String>,
    pub verbose: bool,
}

/// The damping curve of a fit-material result, if it has one.
fn read_damping_curve(path: &Path) -> Option<DampingCurve> {
    let (f, _) = read_dataset(path, "/damping/curve/frequencies_hz").ok()?;
    let (d, _) = read_dataset(path, "/damping/curve/decay_rates").ok()?;
    DampingCurve::new(f, &d).ok()
}

fn read_toml<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    toml::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))
}

/// Merges defaults < case metadata < config file < flags and validates.
pub fn resolve(args: &ImpactArgs) -> Result<Job, String> {
    let file: ImpactFileConfig = match &args.config {
        Some(p) => read_toml(p)?,
        None => ImpactFileConfig::default(),
    };
    let case: Option<CaseMeta> = args.case.as_deref().map(read_toml).transpose()?;
    let case_dir = args
        .case
        .as_ref()
        .and_then(|p| p.parent())
        .map(Path::to_path_buf)
        .unwrap_or_default();
    let super::resolve::MeshChoice {
        mesh, unit_scale, ..
    } = super::resolve::resolve_mesh(
        &args.mesh,
        &file.mesh.clone().or(case.as_ref().map(|c| c.mesh.clone())),
        &args.units,
        &file
            .units
            .clone()
            .or(case.as_ref().map(|c| c.mesh_unit.clone())),
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
        return Err("no recordings given: use --recording FILE (repeatable), `recordings = [...]` in the config file, or --case".into());
    };
    if let Some(r) = recordings.iter().find(|r| !r.is_file()) {
        return Err(format!("recording {} does not exist", r.display()));
    }
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
    let material_path = args.material.clone().or(file.material_fit.clone());
    let given = (
        args.youngs.or(file.youngs_modulus),
        args.poisson.or(file.poisson_ratio),
    );
    let (material, material_source, damping_curve) = match (material_path, given) {
        (Some(p), (None, None)) => {
            let (e, nu, rho) = read_fit_material(&p)?;
            let curve = read_damping_curve(&p);
            (Material { youngs_modulus: e, poisson_ratio: nu, density: rho, rayleigh_alpha: 0.0, rayleigh_beta: 0.0 }, format!("fit-material result {}", p.display()), curve)
        }
        (Some(_), _) => return Err("give the material either as a fit-material result (--material) or as --youngs/--poisson, not both".into()),
        (None, (Some(e), Some(nu))) => {
            let density = args.density.or(file.density).or(case.as_ref().map(|c| c.density_kg_m3)).unwrap_or(2700.0);
            (Material { youngs_modulus: e, poisson_ratio: nu, density, rayleigh_alpha: 0.0, rayleigh_beta: 0.0 }, "given".to_string(), None)
        }
        (None, (None, None)) => return Err("the material is needed: --material FIT.h5 (a fit-material result) or --youngs and --poisson".into()),
        (None, _) => return Err("--youngs and --poisson go together".into()),
    };
    material.validate().map_err(|e| format!("material: {e}"))?;
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
    if let Some(k) = args.top {
        map.top_k = k;
    }
    // Microphones are uncalibrated unless the file says otherwise (module docs, step 6).
    map.free_microphone_gains = !file.calibrated_microphones.unwrap_or(false);
    let out = args
        .out
        .clone()
        .or(file.out.clone())
        .unwrap_or_else(|| PathBuf::from("impact.h5"));
    super::resolve::check_output(&out, &super::resolve::inputs(&mesh, &recordings))?;
    let mut petsc_options = file.petsc_options.clone();
    petsc_options.extend(args.petsc_options.iter().cloned());
    Ok(Job {
        json: out.with_extension("json"),
        map_file: with_suffix(&out, "_map.h5"),
        png: with_suffix(&out, "_map.png"),
        mesh,
        unit_scale,
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
        verbose: args.verbose,
    })
}

pub fn run(universe: Universe, args: ImpactArgs) -> Result<(), String> {
    let job = resolve(&args)?;
    let petsc =
        Petsc::initialize(universe, "diffsound", &job.petsc_options).map_err(|e| e.to_string())?;
    let (rank, size) = (petsc.rank(), petsc.size());
    match compute(&petsc, &job) {
        Ok(()) => Ok(()),
        Err(message) => fail(rank, size, &message),
    }
}

/// What rank 0 read from the recording.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct Measured {
    /// The healthy channels' names, and their indices among the recordings.
    names: Vec<String>,
    kept: Vec<usize>,
    onset_s: f64,
    /// Channels from the onset on, recording units.
    channels: Vec<Vec<f64>>,
    sample_rate: f64,
    /// Recorded poles below fmax: (f [Hz], d [1/s], SNR [dB]).
    poles: Vec<(f64, f64, f64)>,
    seconds: f64,
}

fn measure(job: &Job, progress: &Progress) -> Result<Measured, String> {
    let t = Instant::now();
    let options = RecordingOptions {
        target_rate: Some(job.sample_rate),
        pre_roll_s: job.pre_roll,
        duration_s: Some(job.pre_roll + job.window),
        gain: GainPolicy::Unity,
        band_max_hz: Some(job.max_frequency_hz),
        ..Default::default()
    };
    let rec = load_recording(&job.recordings, &options).map_err(|e| e.to_string())?;
    let fs = f64::from(rec.sample_rate);
    let onset =
        (((rec.onset_s - rec.start_s) * fs).round().max(0.0) as usize).min(rec.channels[0].len());
    // Channel health: a dead, noise-only or misaligned microphone would move the map; it is
    // left out with a warning naming its file.
    let health = crate::audio::health::assess(
        &rec.names,
        &rec.channels,
        onset,
        fs,
        &rec.channel_onsets_s,
        rec.onset_s,
    );
    for h in health.iter().filter(|h| !h.is_healthy()) {
        eprintln!("{}", h.left_out_warning("the map"));
    }
    let kept = crate::audio::health::healthy_channels(&health).map_err(|e| e.to_string())?;
    let channels: Vec<Vec<f64>> = kept
        .iter()
        .map(|&c| rec.channels[c][onset..].to_vec())
        .collect();
    let names: Vec<String> = kept.iter().map(|&c| rec.names[c].clone()).collect();
    if (channels[0].len() as f64) < 0.02 * fs {
        return Err(format!(
            "only {:.3} s of recording after the onset at {:.3} s",
            channels[0].len() as f64 / fs,
            rec.onset_s
        ));
    }
    let ex =
        extract_modes(&channels, fs, &job.extract).map_err(|e| format!("mode extraction: {e}"))?;
    let poles: Vec<(f64, f64, f64)> = ex
        .modes
        .iter()
        .filter(|m| m.frequency_hz <= job.max_frequency_hz && m.decay_rate >= 0.0)
        .map(|m| (m.frequency_hz, m.decay_rate, m.snr_db))
        .collect();
    progress.say(format!("{} channel(s) at {} Hz, onset at {:.4} s, {:.3} s fitted; {} recorded poles below {:.0} Hz", channels.len(), rec.sample_rate, rec.onset_s, channels[0].len() as f64 / fs, poles.len(), job.max_frequency_hz));
    Ok(Measured {
        names,
        kept,
        onset_s: rec.onset_s,
        channels,
        sample_rate: fs,
        poles,
        seconds: t.elapsed().as_secs_f64(),
    })
}

/// Near-degenerate simulated modes share a cluster (relative frequency tolerance).
const CLUSTER_RTOL: f64 = 0.005;

/// The poles of the amplitude fit and what they stand for (module docs, step 3).
struct PoleAssignment {
    /// Global frequency scale s = f_obs / f_sim.
    scale: f64,
    /// Poles of the amplitude fit: one per recorded pole, then one per unclaimed cluster.
    poles: Vec<Pole>,
    /// Cluster id of each pole (a simulated cluster index), or None for an unclaimed pole.
    pole_cluster: Vec<Option<usize>>,
    /// Per simulated cluster: whether a recorded pole was assigned to it.
    observed: Vec<bool>,
}

/// Matches recorded poles to clusters of simulated modes (module docs, step 3).
fn assign_poles(
    measured: &Measured,
    sim_hz: &[f64],
    cluster_of: &[usize],
    decay_of: impl Fn(f64) -> f64,
    tolerance: f64,
) -> Result<PoleAssignment, String> {
    let n_clusters = cluster_of.iter().max().map_or(0, |m| m + 1);
    // Cluster centres in the simulation.
    let mut centre = vec![(0.0, 0usize); n_clusters];
    for (k, &c) in cluster_of.iter().enumerate() {
        centre[c].0 += sim_hz[k].ln();
        centre[c].1 += 1;
    }
    let centre: Vec<f64> = centre.iter().map(|(s, n)| (s / *n as f64).exp()).collect();
    // Global scale: median ratio of each recorded pole to its nearest simulated cluster.
    let mut ratios: Vec<f64> = measured
        .poles
        .iter()
        .filter_map(|p| {
            centre
                .iter()
                .map(|c| (p.0 / c).ln())
                .min_by(|a, b| a.abs().total_cmp(&b.abs()))
        })
        .collect();
    if ratios.is_empty() {
        return Err("no recorded pole to match against the simulated modes".into());
    }
    ratios.sort_by(f64::total_cmp);
    let ln_scale = ratios[ratios.len() / 2];
    let mut poles = Vec::new();
    let mut pole_cluster = Vec::new();
    let mut observed = vec![false; n_clusters];
    for &(f, d, _) in &measured.poles {
        let nearest = (0..n_clusters)
            .map(|c| (c, (f.ln() - ln_scale - centre[c].ln()).abs()))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        poles.push(Pole {
            frequency_hz: f,
            decay_rate: d,
        });
        match nearest {
            Some((c, dist)) if dist <= tolerance => {
                observed[c] = true;
                pole_cluster.push(Some(c));
            }
            _ => pole_cluster.push(None),
        }
    }
    let nyquist = 0.5 * measured.sample_rate;
    for c in 0..n_clusters {
        if !observed[c] {
            let f = ln_scale.exp() * centre[c];
            if f >= 0.95 * nyquist {
                return Err(format!("simulated mode at {f:.0} Hz is too close to the recording's Nyquist frequency ({nyquist:.0} Hz); lower max_frequency_hz"));
            }
            poles.push(Pole {
                frequency_hz: f,
                decay_rate: decay_of(f),
            });
            pole_cluster.push(Some(c));
        }
    }
    Ok(PoleAssignment {
        scale: ln_scale.exp(),
        poles,
        pole_cluster,
        observed,
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
    if let Some(v) = job.true_vertex {
        if v >= mesh_model.n_nodes() {
            return Err(format!(
                "true strike vertex {v} does not exist ({} nodes)",
                mesh_model.n_nodes()
            ));
        }
    }

    // 1: the recording (rank 0), shared so that every rank stops together on an error.
    let local = (rank == 0).then(|| measure(job, &progress));
    let measured: Measured = broadcast_from_root(petsc, local)??;
    // The microphone positions of the channels kept.
    let adjusted = Job {
        microphones: job
            .microphones
            .as_ref()
            .map(|m| measured.kept.iter().map(|&c| m[c]).collect()),
        ..job.clone()
    };
    let job = &adjusted;
    if measured.poles.len() < 3 {
        return Err(format!(
            "only {} poles found in the recording below {} Hz; the map needs at least 3",
            measured.poles.len(),
            job.max_frequency_hz
        ));
    }

    // 2: the modes at the fitted material.
    let t_solve = Instant::now();
    let assembled = assembly::assemble(petsc, &mesh_model).map_err(|e| e.to_string())?;
    let (lo, hi) = mesh_model.bounding_box();
    let diagonal = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
    let material = &job.material;
    let (k, m) = assembled.operators(material).map_err(|e| e.to_string())?;
    // Up to the band's top (a little beyond, for a recording a few % sharp of the model);
    // modes that land above it after the frequency scale are dropped below.
    let f_top = 1.05 * job.max_frequency_hz;
    let cfg = EigenConfig::new(
        ModeRequest::UpTo { f_max_hz: f_top },
        eigen::spectrum_scale(material.lame_mu(), material.density, diagonal),
    );
    let modes = eigen::solve_modes(petsc, &k, &m, &cfg).map_err(|e| e.to_string())?;
    let mut shapes = assembled
        .layout
        .gather_original_order(&modes.vectors)
        .map_err(|e| e.to_string())?;
    let solve_seconds = t_solve.elapsed().as_secs_f64();
    progress.say(format!(
        "{} simulated modes up to {:.0} Hz at E = {:.4e} Pa, ν = {:.4}, ρ = {} in {:.1} s",
        modes.eigenvalues.len(),
        f_top,
        material.youngs_modulus,
        material.poisson_ratio,
        material.density,
        solve_seconds
    ));
    for w in &modes.warnings {
        if rank == 0 {
            eprintln!("warning: {w}");
        }
    }
    if rank != 0 {
        return Ok(());
    }
    if shapes.is_empty() {
        return Err(format!("no elastic mode below {f_top:.0} Hz"));
    }

    // 3: poles per simulated cluster, for the modes whose scaled frequency lies in the band (a
    // mode above it is neither heard nor missed: the recording was not analysed there).
    let median_decay = {
        let mut d: Vec<f64> = measured.poles.iter().map(|p| p.1).collect();
        d.sort_by(f64::total_cmp);
        d[d.len() / 2]
    };
    let decay_of = |f: f64| {
        job.damping_curve
            .as_ref()
            .map_or(median_decay, |c| c.decay(f))
    };
    let all_hz: Vec<f64> = modes
        .eigenvalues
        .iter()
        .map(|&l| eigen::frequency_hz(l))
        .collect();
    let first = assign_poles(
        &measured,
        &all_hz,
        &evidence::cluster_ids(&all_hz, CLUSTER_RTOL),
        decay_of,
        job.match_tolerance,
    )?;
    let in_band = all_hz
        .iter()
        .take_while(|&&f| first.scale * f <= job.max_frequency_hz)
        .count();
    if in_band == 0 {
        return Err(format!(
            "no simulated mode below {} Hz",
            job.max_frequency_hz
        ));
    }
    let eigenvalues = modes.eigenvalues[..in_band].to_vec();
    shapes.truncate(in_band);
    let sim_hz = all_hz[..in_band].to_vec();
    let cluster_of = evidence::cluster_ids(&sim_hz, CLUSTER_RTOL);
    let assignment = assign_poles(
        &measured,
        &sim_hz,
        &cluster_of,
        decay_of,
        job.match_tolerance,
    )?;
    let n_observed = assignment.observed.iter().filter(|o| **o).count();
    progress.say(format!("frequency scale {:.5}; {} of {} simulated clusters matched by a recorded pole, {} recorded poles unclaimed", assignment.scale, n_observed, assignment.observed.len(), assignment.pole_cluster.iter().filter(|c| c.is_none()).count()));

    // 4: amplitudes with the poles known.
    let t_amp = Instant::now();
    let fit = impact::fit_amplitudes(
        &measured.channels,
        measured.sample_rate,
        0.0,
        &assignment.poles,
        &AmplitudeFitOptions {
            window_s: Some(job.window),
            ..Default::default()
        },
    )
    .map_err(|e| format!("amplitude fit: {e}"))?;
    // Unclaimed poles get ids past the clusters, then are dropped.
    let n_clusters = assignment.observed.len();
    let ids: Vec<usize> = assignment
        .pole_cluster
        .iter()
        .enumerate()
        .map(|(i, c)| c.unwrap_or(n_clusters + i))
        .collect();
    let all =
        impact::cluster_amplitudes(&fit, &ids).map_err(|e| format!("cluster amplitudes: {e}"))?;
    let measured_clusters = keep_simulated_clusters(all, &ids, &cluster_of)?;
    let amplitude_seconds = t_amp.elapsed().as_secs_f64();
    if !fit.not_separable.is_empty() {
        progress.say(format!(
            "{} pole(s) not separable in the amplitude fit (their clusters count with infinite σ)",
            fit.not_separable.len()
        ));
    }

    // 5: the forward table.
    let t_table = Instant::now();
    let candidates = impact::surface_candidates(&mesh_model);
    let decay_rates: Vec<f64> = (0..sim_hz.len())
        .map(|k| {
            cluster_decay(&assignment, &fit, cluster_of[k]).unwrap_or_else(|| decay_of(sim_hz[k]))
        })
        .collect();
    let n_mics = measured.channels.len();
    let (transfer_values, transfer_note) =
        transfers(job, &mesh_model, &eigenvalues, &shapes, n_mics, &progress)?;
    let transfer = match &transfer_values {
        TransferValues::None => Transfer::None {
            microphones: n_mics,
        },
        TransferValues::Complex(t) => Transfer::Directional(t),
    };
    let response = if matches!(transfer_values, TransferValues::None) {
        Response::Acceleration
    } else {
        Response::Displacement
    };
    let force = job
        .contact_duration_s
        .map_or(ContactForce::Impulse, |duration_s| ContactForce::HalfSine {
            duration_s,
        });
    let strike = Strike { force, response };
    let table = impact::forward_amplitudes(
        &shapes,
        &eigenvalues,
        &decay_rates,
        &strike,
        &candidates,
        &transfer,
        &cluster_of,
    )
    .map_err(|e| format!("forward amplitudes: {e}"))?;
    let table_seconds = t_table.elapsed().as_secs_f64();

    // 6: the map.
    let t_map = Instant::now();
    let graph = SurfaceGraph::from_mesh(&mesh_model).map_err(|e| format!("surface graph: {e}"))?;
    let map = impact::likelihood_map(&measured_clusters, &table, &graph, &job.map)
        .map_err(|e| format!("likelihood map: {e}"))?;
    let map_seconds = t_map.elapsed().as_secs_f64();
    let best = &table.candidates[map.best];
    progress.say(format!("map over {} surface vertices from {} cluster × microphone terms ({} below the detection limit) in {:.2} s; best vertex {} (strength {:.3e} ± {:.1e})", candidates.len(), map.terms, map.terms_below_limit, map_seconds, best.vertex, map.strength, map.strength_sd));

    // 7: evaluation against a known strike.
    let evaluation = match job.true_vertex {
        Some(v) => Some(evaluate(v, &table, &map, &graph)?),
        None => None,
    };

    let timings = [
        ("recording", measured.seconds),
        ("modes", solve_seconds),
        ("amplitudes", amplitude_seconds),
        ("transfer_and_table", table_seconds),
        ("map", map_seconds),
        ("total", total.elapsed().as_secs_f64()),
    ];
    print_summary(
        job,
        &mesh_model,
        &assignment,
        &table,
        &map,
        evaluation.as_ref(),
        &transfer_note,
    );
    let report = Report {
        job,
        measured: &measured,
        assignment: &assignment,
        sim_hz: &sim_hz,
        cluster_of: &cluster_of,
        fit_clusters: &measured_clusters,
        table: &table,
        map: &map,
        mesh: &mesh_model,
        evaluation: evaluation.as_ref(),
        transfer_note: &transfer_note,
        timings: &timings,
        n_ranks: petsc.size(),
    };
    write_hdf5(&report)?;
    write_json(&report)?;
    write_map(&report, &eigenvalues, &shapes, &modes.rigid_eigenvalues)?;
    write_png(&report)?;
    Ok(())
}

/// The cluster amplitudes of the simulated clusters only, relabelled with the simulated modes
/// each cluster stands for (`cluster_of`), so that they line up with the forward table. Every
/// simulated cluster has a pole (recorded or predicted), so the ids are 0..n_clusters in order.
fn keep_simulated_clusters(
    all: ClusterAmplitudes,
    ids: &[usize],
    cluster_of: &[usize],
) -> Result<ClusterAmplitudes, String> {
    let n_clusters = cluster_of.iter().max().map_or(0, |m| m + 1);
    let keep: Vec<bool> = all
        .clusters
        .iter()
        .map(|members| ids[members[0]] < n_clusters)
        .collect();
    let kept_ids: Vec<usize> = all
        .clusters
        .iter()
        .map(|members| ids[members[0]])
        .filter(|&c| c < n_clusters)
        .collect();
    if kept_ids != (0..n_clusters).collect::<Vec<_>>() {
        return Err(format!(
            "internal: clusters {kept_ids:?} have poles, expected every one of 0..{n_clusters}"
        ));
    }
    let pick = |v: Vec<Vec<f64>>| {
        v.into_iter()
            .zip(&keep)
            .filter(|(_, k)| **k)
            .map(|(x, _)| x)
            .collect::<Vec<_>>()
    };
    let below = all
        .below_limit
        .into_iter()
        .zip(&keep)
        .filter(|(_, k)| **k)
        .map(|(x, _)| x)
        .collect();
    Ok(ClusterAmplitudes {
        clusters: impact::cluster_members(cluster_of),
        amplitude: pick(all.amplitude),
        sd: pick(all.sd),
        detection_limit: pick(all.detection_limit),
        below_limit: below,
    })
}

/// The decay rate of the (first) pole assigned to a cluster.
fn cluster_decay(
    assignment: &PoleAssignment,
    fit: &impact::AmplitudeFit,
    cluster: usize,
) -> Option<f64> {
    assignment
        .pole_cluster
        .iter()
        .position(|c| *c == Some(cluster))
        .map(|i| fit.poles[i].decay_rate)
}

enum TransferValues {
    None,
    Complex(Vec<Vec<Complex64>>),
}

/// The acoustic transfer of every mode to every microphone (module docs, step 5).
fn transfers(
    job: &Job,
    mesh: &TetMesh,
    eigenvalues: &[f64],
    shapes: &[Vec<f64>],
    n_mics: usize,
    progress: &Progress,
) -> Result<(TransferValues, String), String> {
    if job.transfer == TransferChoice::None {
        return Ok((
            TransferValues::None,
            "none: |T| = 1, signal taken as surface acceleration".into(),
        ));
    }
    let t = Instant::now();
    let quadrature = SurfaceQuadrature::new(mesh).map_err(|e| format!("radiation: {e}"))?;
    let mut out = Vec::with_capacity(shapes.len());
    let mut worst_residual = 0.0f64;
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
        worst_residual = worst_residual.max(fit.residual);
        let row = match &job.microphones {
            Some(mics) => {
                let nearest = mics
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
                fit.transfer(mics).map_err(|e| e.to_string())?
            }
            None => fit
                .transfer_unknown_positions(
                    n_mics,
                    job.assumed_distance_m.max(1.01 * fit.source_radius),
                )
                .map_err(|e| e.to_string())?,
        };
        out.push(row);
    }
    let note = match &job.microphones {
        Some(_) => format!("multipole transfer to the given microphone positions (largest boundary residual ε = {worst_residual:.2})"),
        None => format!("microphone positions unknown: direction-averaged multipole transfer at {} m (largest boundary residual ε = {worst_residual:.2}); right on average over directions, not for any one microphone", job.assumed_distance_m),
    };
    progress.say(format!(
        "acoustic transfer of {} modes in {:.1} s: {note}",
        shapes.len(),
        t.elapsed().as_secs_f64()
    ));
    Ok((TransferValues::Complex(out), note))
}

/// How the map did against a known strike vertex.
#[derive(Clone, Debug, Serialize)]
struct Evaluation {
    true_vertex: usize,
    best_vertex: usize,
    /// Along surface edges [m].
    geodesic_error_m: f64,
    /// Fraction of the surface area ranked at or above the truth.
    area_rank: f64,
    in_top_percent: bool,
    /// Vertices that no mode cluster can tell from the truth (relative tolerance 5 %).
    orbit_size: usize,
    best_on_orbit: bool,
    /// Geodesic distance from the best candidate to the nearest orbit vertex [m].
    orbit_error_m: f64,
}

/// Relative tolerance of the drive signatures that makes two vertices one symmetry orbit.
const ORBIT_RTOL: f64 = 0.05;

fn evaluate(
    true_vertex: usize,
    table: &ForwardTable,
    map: &ImpactMap,
    graph: &SurfaceGraph,
) -> Result<Evaluation, String> {
    let truth = table
        .candidates
        .iter()
        .position(|c| c.vertex == true_vertex)
        .ok_or_else(|| {
            format!("true strike vertex {true_vertex} is not a surface vertex with a normal")
        })?;
    let best = table.candidates[map.best].vertex;
    let geodesic_error_m = graph
        .distance(true_vertex, best)
        .map_err(|e| e.to_string())?;
    let signatures = impact::drive_signatures(table);
    let orbit =
        impact::symmetry_orbit(&signatures, truth, ORBIT_RTOL).map_err(|e| e.to_string())?;
    let best_on_orbit = orbit.contains(&map.best);
    let from_best = graph
        .distances_from(best, f64::INFINITY)
        .map_err(|e| e.to_string())?;
    let orbit_error_m = orbit
        .iter()
        .filter_map(|&c| graph.index_of(table.candidates[c].vertex))
        .map(|slot| from_best[slot])
        .fold(f64::INFINITY, f64::min);
    let area_rank = map.area_rank(truth);
    Ok(Evaluation {
        true_vertex,
        best_vertex: best,
        geodesic_error_m,
        area_rank,
        in_top_percent: area_rank <= 0.01,
        orbit_size: orbit.len(),
        best_on_orbit,
        orbit_error_m,
    })
}

fn print_summary(
    job: &Job,
    mesh: &TetMesh,
    assignment: &PoleAssignment,
    table: &ForwardTable,
    map: &ImpactMap,
    evaluation: Option<&Evaluation>,
    transfer_note: &str,
) {
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

struct Report<'a> {
    job: &'a Job,
    measured: &'a Measured,
    assignment: &'a PoleAssignment,
    sim_hz: &'a [f64],
    cluster_of: &'a [usize],
    fit_clusters: &'a ClusterAmplitudes,
    table: &'a ForwardTable,
    map: &'a ImpactMap,
    mesh: &'a TetMesh,
    evaluation: Option<&'a Evaluation>,
    transfer_note: &'a str,
    timings: &'a [(&'a str, f64)],
    n_ranks: usize,
}

fn write_hdf5(r: &Report) -> Result<(), String> {
    let (job, map, table) = (r.job, r.map, r.table);
    let best = table.candidates[map.best].vertex;
    let mut file = ResultsFile::new("diffsound.locate_impact", 1);
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
        .number("/", "n_ranks", r.n_ranks as f64)
        .text(
            "/",
            "command",
            &std::env::args().collect::<Vec<_>>().join(" "),
        )
        .text("/", "version", env!("CARGO_PKG_VERSION"))
        .number("/material", "youngs_modulus", job.material.youngs_modulus)
        .number("/material", "poisson_ratio", job.material.poisson_ratio)
        .number("/material", "density", job.material.density)
        .text("/material", "source", &job.material_source)
        .number("/impact", "best_vertex", best as f64)
        .number("/impact", "strength", map.strength)
        .number("/impact", "strength_sd", map.strength_sd)
        .text(
            "/impact",
            "strength_units",
            "recording units per N·s of impulse",
        )
        .number("/impact", "sigma_model_at_best", map.sigma_model[map.best])
        .number("/impact", "terms", map.terms as f64)
        .number("/impact", "terms_below_limit", map.terms_below_limit as f64)
        .number("/impact", "frequency_scale", r.assignment.scale)
        .text("/impact", "transfer", r.transfer_note)
        .dataset(
            "/impact/best_position",
            &[3],
            r.mesh.nodes[best].to_vec(),
            "m",
        );
    let vertices: Vec<f64> = table.candidates.iter().map(|c| c.vertex as f64).collect();
    file.column("/map/vertex", vertices, "")
        .column("/map/posterior", map.posterior.clone(), "1")
        .column("/map/log_likelihood", map.log_likelihood.clone(), "1")
        .column("/map/cosine", map.cosine.clone(), "1")
        .column("/map/area_share", map.area_share.clone(), "1")
        .column(
            "/map/log_strength",
            map.log_strength.clone(),
            "ln(recording units per N·s)",
        )
        .column("/map/sigma_model", map.sigma_model.clone(), "ln amplitude");
    file.column(
        "/top/vertex",
        map.top.iter().map(|t| t.vertex as f64).collect(),
        "",
    )
    .dataset(
        "/top/position",
        &[map.top.len(), 3],
        map.top.iter().flat_map(|t| t.position).collect(),
        "m",
    )
    .column(
        "/top/neighbourhood_mass",
        map.top.iter().map(|t| t.neighbourhood_mass).collect(),
        "1",
    )
    .column(
        "/top/log_likelihood",
        map.top.iter().map(|t| t.log_likelihood).collect(),
        "1",
    )
    .column(
        "/top/strength",
        map.top.iter().map(|t| t.strength).collect(),
        "recording units per N·s",
    );
    file.column("/modes/simulated_hz", r.sim_hz.to_vec(), "Hz")
        .column(
            "/modes/cluster",
            r.cluster_of.iter().map(|&c| c as f64).collect(),
            "",
        );
    file.column(
        "/poles/frequency_hz",
        r.assignment.poles.iter().map(|p| p.frequency_hz).collect(),
        "Hz",
    )
    .column(
        "/poles/decay_rate",
        r.assignment.poles.iter().map(|p| p.decay_rate).collect(),
        "1/s",
    )
    .column(
        "/poles/cluster",
        r.assignment
            .pole_cluster
            .iter()
            .map(|c| c.map_or(-1.0, |c| c as f64))
            .collect(),
        "",
    );
    let (nc, nm) = (table.clusters.len(), table.microphones);
    let flat = |v: &Vec<Vec<f64>>| v.iter().flatten().copied().collect::<Vec<f64>>();
    let predicted: Vec<f64> = (0..nc)
        .flat_map(|c| (0..nm).map(move |m| (c, m)))
        .map(|(c, m)| table.amplitude(map.best, c, m) * map.strength)
        .collect();
    file.dataset(
        "/clusters/measured_amplitude",
        &[nc, nm],
        flat(&r.fit_clusters.amplitude),
        "recording units",
    )
    .dataset(
        "/clusters/measured_sd",
        &[nc, nm],
        flat(&r.fit_clusters.sd),
        "recording units",
    )
    .dataset(
        "/clusters/predicted_at_best",
        &[nc, nm],
        predicted,
        "recording units",
    )
    .column(
        "/clusters/heard",
        r.assignment
            .observed
            .iter()
            .map(|&o| if o { 1.0 } else { 0.0 })
            .collect(),
        "",
    );
    if let Some(e) = r.evaluation {
        file.number("/evaluation", "true_vertex", e.true_vertex as f64)
            .number("/evaluation", "geodesic_error_m", e.geodesic_error_m)
            .number("/evaluation", "area_rank", e.area_rank)
            .number("/evaluation", "orbit_size", e.orbit_size as f64)
            .number(
                "/evaluation",
                "best_on_orbit",
                if e.best_on_orbit { 1.0 } else { 0.0 },
            )
            .number("/evaluation", "orbit_error_m", e.orbit_error_m);
    }
    for (k, v) in r.timings {
        file.number("/timings", k, *v);
    }
    file.write(&job.out).map_err(|e| e.to_string())?;
    println!("wrote {}", job.out.display());
    Ok(())
}

fn write_json(r: &Report) -> Result<(), String> {
    let (job, map, table) = (r.job, r.map, r.table);
    let value = serde_json::json!({
        "format": "diffsound.locate_impact",
        "format_version": 1,
        "command": std::env::args().collect::<Vec<_>>().join(" "),
        "version": env!("CARGO_PKG_VERSION"),
        "mesh": job.mesh.display().to_string(),
        "recordings": job.recordings.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
        "onset_s": r.measured.onset_s,
        "material": {"youngs_modulus": job.material.youngs_modulus, "poisson_ratio": job.material.poisson_ratio, "density": job.material.density, "source": job.material_source},
        "transfer": r.transfer_note,
        "frequency_scale": r.assignment.scale,
        "clusters": table.clusters.len(),
        "clusters_heard": r.assignment.observed.iter().filter(|o| **o).count(),
        "best_vertex": table.candidates[map.best].vertex,
        "best_position_m": r.mesh.nodes[table.candidates[map.best].vertex],
        "strength": map.strength,
        "strength_sd": map.strength_sd,
        "strength_units": "recording units per N·s of impulse",
        "sigma_model_at_best": map.sigma_model[map.best],
        "top": map.top,
        "evaluation": r.evaluation,
        "timings_s": r.timings.iter().map(|(k, v)| (k.to_string(), *v)).collect::<std::collections::BTreeMap<_, _>>(),
    });
    let text = serde_json::to_string_pretty(&value).map_err(|e| e.to_string())?;
    crate::io::write_atomically(&job.json, |tmp| {
        std::fs::write(tmp, &text).map_err(|source| crate::io::IoError::Fs {
            path: tmp.to_path_buf(),
            context: "writing the JSON summary".into(),
            source,
        })
    })
    .map_err(|e| e.to_string())?;
    println!("wrote {}", job.json.display());
    Ok(())
}

/// Posterior density (normalised to a maximum of 1) and log-likelihood ratio per mesh node.
fn node_fields(r: &Report) -> (Vec<f64>, Vec<f64>) {
    let (map, table) = (r.map, r.table);
    let n = r.mesh.n_nodes();
    let density: Vec<f64> = map
        .posterior
        .iter()
        .zip(&map.area_share)
        .map(|(p, a)| if *a > 0.0 { p / a } else { 0.0 })
        .collect();
    let top_density = density.iter().cloned().fold(0.0, f64::max);
    let top_ll = map.log_likelihood[map.best];
    let mut dens = vec![0.0; n];
    let mut ratio = vec![LOG_RATIO_FLOOR; n];
    for (i, c) in table.candidates.iter().enumerate() {
        dens[c.vertex] = if top_density > 0.0 {
            density[i] / top_density
        } else {
            0.0
        };
        ratio[c.vertex] = (map.log_likelihood[i] - top_ll).max(LOG_RATIO_FLOOR);
    }
    (dens, ratio)
}

/// Log-likelihood ratios below this are drawn at it (e^−50: no support).
const LOG_RATIO_FLOOR: f64 = -50.0;

fn write_map(
    r: &Report,
    eigenvalues: &[f64],
    shapes: &[Vec<f64>],
    rigid: &[f64],
) -> Result<(), String> {
    let (dens, ratio) = node_fields(r);
    let triple = |v: &[f64]| v.iter().flat_map(|&x| [x, x, x]).collect::<Vec<f64>>();
    let (dens3, ratio3) = (triple(&dens), triple(&ratio));
    let residual_norms = vec![f64::NAN; eigenvalues.len()];
    let m = &r.job.material;
    let file = ModesFile {
        nodes: &r.mesh.nodes,
        connectivity: &r.mesh.connectivity,
        nodes_per_tet: r.mesh.nodes_per_tet(),
        material: MaterialRecord { name: "locate-impact".into(), youngs_modulus: m.youngs_modulus, poisson_ratio: m.poisson_ratio, density: m.density, rayleigh_alpha: 0.0, rayleigh_beta: 0.0 },
        eigenvalues,
        frequencies_hz: r.sim_hz,
        mode_shapes: shapes,
        residual_norms: &residual_norms,
        rigid_eigenvalues: rigid,
        solver: Vec::new(),
        n_ranks: 1,
        element_order: 2,
        timings: Vec::new(),
        provenance: vec![("command".into(), std::env::args().collect::<Vec<_>>().join(" "))],
        extra_datasets: Vec::new(),
        node_fields: vec![
            NodeField { name: "posterior_density".into(), data: &dens3, units: "1 (posterior per unit area over its maximum; all three components equal; 0 off the surface)".into() },
            NodeField { name: "log_likelihood_ratio".into(), data: &ratio3, units: "1 (ℓ − max ℓ, floored at −50; all three components equal)".into() },
        ],
    };
    write_modes(&r.job.map_file, &file).map_err(|e| e.to_string())?;
    println!("wrote {} and its .xdmf sidecar (ParaView: colour by posterior_density or log_likelihood_ratio)", r.job.map_file.display());
    Ok(())
}

fn write_png(r: &Report) -> Result<(), String> {
    let (_, ratio) = node_fields(r);
    let triangles = r.mesh.boundary_faces();
    let mut values = vec![f64::NAN; r.mesh.n_nodes()];
    for c in &r.table.candidates {
        // ℓ − max ℓ on a readable scale: 0 (best) down to −20.
        values[c.vertex] = ratio[c.vertex].max(-20.0);
    }
    let colours = [[214, 39, 40], [255, 127, 14], [255, 187, 120]];
    let mut panel = SurfacePanel::new(
        "log-likelihood ratio l - max l",
        r.mesh.nodes.clone(),
        triangles.clone(),
    )
    .with_values(values);
    for (i, t) in r.map.top.iter().take(3).enumerate() {
        panel = panel.with_marker(SurfaceMarker::new(
            r.mesh.nodes[t.vertex],
            format!("{}", i + 1),
            colours[i],
        ));
    }
    if let Some(e) = r.evaluation {
        panel = panel.with_marker(SurfaceMarker::new(
            r.mesh.nodes[e.true_vertex],
            "true",
            [255, 255, 255],
        ));
    }
    let mut fig = SurfaceFigure::new(
        format!(
            "Where was it struck? {} (best vertex {})",
            r.job
                .mesh
                .file_name()
                .map_or(String::new(), |n| n.to_string_lossy().to_string()),
            r.table.candidates[r.map.best].vertex
        ),
        vec![panel],
    );
    fig.views = vec![
        View::new(30.0, 35.0),
        View::new(210.0, 35.0),
        View::labelled(0.0, 89.0, "top"),
        View::labelled(0.0, -89.0, "below"),
    ];
    fig.value_label = "l - max l".into();
    fig.value_range = Some((-20.0, 0.0));
    surface_png(&r.job.png, &fig).map_err(|e| e.to_string())?;
    println!("wrote {}", r.job.png.display());
    Ok(())
}
