//! The `locate-impact` job: where was the object struck, and how hard (issue 8).
//!
//! Mesh, material and recordings of one strike in ([`Job`]); a likelihood map over the
//! object's surface out ([`Report`], written by [`write`] as HDF5 + XDMF for ParaView, PNG,
//! JSON), with the top candidate positions and the strike strength. The physics and the
//! statistics are in [`crate::inverse::impact`]; this module only wires them.
//!
//! Submodules: [`measure`] (the recording, its poles and their match to the simulated modes),
//! [`transfer`] (the acoustic transfer of step 5), [`evaluate`] (step 7), [`write`] (the
//! files).
//!
//! # Steps
//!
//! 1. **Recording** (rank 0): the channels after the onset, at the samples' own scale
//!    (`GainPolicy::Unity`, so the strength stays in the recording's units); the poles of the
//!    recording below `fmax` by the sub-band ESPRIT + variable-projection extraction
//!    ([`crate::analysis::extract`]).
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
//! * `OUT.h5` (`format` = `diffsound.locate_impact`, `format_version` = 2, written by
//!   [`write::write_hdf5`]; types as in [`crate::io::results`]):
//!
//!   | path | contents |
//!   |------|----------|
//!   | `/` attrs | `mesh`, `recordings` (string array), `n_ranks` (i64), `command`, `version` |
//!   | `/material` attrs | `youngs_modulus` [Pa], `poisson_ratio`, `density` [kg/m³], `source` (`fit_file` or `given`), `source_path` (the fit-material result, with `fit_file`) |
//!   | `/impact` attrs | `best_vertex`, `terms`, `terms_below_limit` (i64), `strength`, `strength_sd`, `strength_units`, `sigma_model_at_best`, `frequency_scale`, `transfer` |
//!   | `/impact/best_position` `[3]` | m |
//!   | `/map/vertex` (u64 node index), `/map/{posterior,log_likelihood,cosine,area_share,log_strength,sigma_model}` | per surface vertex |
//!   | `/top/vertex` (u64), `/top/position` `[T, 3]`, `/top/{neighbourhood_mass,log_likelihood,strength}` | the candidates |
//!   | `/modes/simulated_hz`, `/modes/cluster` (u64) | per simulated mode |
//!   | `/poles/{frequency_hz,decay_rate}`, `/poles/cluster` (i64, −1: none) | per recorded pole |
//!   | `/clusters/{measured_amplitude,measured_sd,predicted_at_best}` `[K, C]`, `/clusters/heard` (u8 flag) | per cluster (and microphone) |
//!   | `/evaluation` attrs | when the truth is known: `true_vertex`, `orbit_size` (i64), `best_on_orbit` (u8 flag), `geodesic_error_m`, `area_rank`, `orbit_error_m` |
//!   | `/timings` attrs | seconds per stage |
//!
//!   Version 1 stored every index, count and flag as f64, `recordings` joined by ", " and
//!   `source` as one sentence.
//! * `OUT_map.h5` + `.xdmf`: the mesh with scalar node fields `posterior_density` (posterior / area
//!   share, normalised to a maximum of 1) and `log_likelihood_ratio` (ℓ − max ℓ), 0 and −∞
//!   clipped to −50 off the surface (ParaView: colour by either).
//! * `OUT.json`: the summary; `OUT_map.png`: the map seen from three sides, with the top
//!   candidates (and the truth, when known) marked.

pub mod evaluate;
pub mod job;
pub mod measure;
pub mod transfer;
pub mod write;

pub use evaluate::Evaluation;
pub use measure::{Measured, PoleAssignment};

use crate::analysis::extract::ExtractOptions;
use crate::assembly::{self, AssemblyError};
use crate::audio::chain::{DampingCurve, Strike};
use crate::audio::excitation::{ContactForce, Response};
use crate::diagnose::evidence;
use crate::eigen::{self, EigenConfig, ModeRequest};
use crate::fem::Material;
use crate::inverse::impact::{
    self, AmplitudeFitOptions, ClusterAmplitudes, ForwardTable, ImpactMap, MapOptions,
    SurfaceGraph, Transfer,
};
use crate::mesh::{MeshError, ReadOptions, TetMesh};
use crate::petsc::Petsc;
use crate::workflow::model_mesh;
use crate::workflow::{broadcast_from_root, Progress};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::time::Instant;
use transfer::TransferValues;

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

/// Everything resolved and checked before PETSc starts.
#[derive(Clone, Debug)]
pub struct Job {
    pub mesh: PathBuf,
    pub unit_scale: f64,
    /// Straighten folded curved tets instead of refusing the mesh ([`crate::mesh::read_for_fem`]).
    pub straighten_invalid: bool,
    pub recordings: Vec<PathBuf>,
    pub sample_rate: u32,
    pub pre_roll: f64,
    pub window: f64,
    pub max_frequency_hz: f64,
    pub material: Material,
    pub material_source: crate::workflow::material::MaterialSource,
    pub damping_curve: Option<DampingCurve>,
    /// Metres, one per recording, in the mesh's frame.
    pub microphones: Option<Vec<[f64; 3]>>,
    pub transfer: TransferChoice,
    /// Distance of the microphones for the direction-averaged transfer [m].
    pub assumed_distance_m: f64,
    pub contact_duration_s: Option<f64>,
    /// Relative distance of a recorded pole from s·f_sim that still matches.
    pub match_tolerance: f64,
    pub true_vertex: Option<usize>,
    pub extract: ExtractOptions,
    pub map: MapOptions,
    pub out: PathBuf,
    pub json: PathBuf,
    pub map_file: PathBuf,
    pub png: PathBuf,
    pub petsc_options: Vec<String>,
    /// The command line, recorded in the output files.
    pub command: String,
}

/// Why the job stopped. The messages are the command's error messages.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Mesh(#[from] MeshError),
    #[error("true strike vertex {vertex} does not exist ({nodes} nodes)")]
    NoSuchVertex { vertex: usize, nodes: usize },
    /// Reading the recording on rank 0 (step 1), or sharing it with the other ranks.
    #[error("{0}")]
    Recording(String),
    #[error("only {found} poles found in the recording below {max_frequency_hz} Hz; the map needs at least 3")]
    TooFewPoles { found: usize, max_frequency_hz: f64 },
    #[error(transparent)]
    Assembly(#[from] AssemblyError),
    /// PETSc/SLEPc (operators, eigen-solve, gathering the shapes).
    #[error("{0}")]
    Solver(String),
    /// Steps 3 to 7: matching the poles, the amplitudes, the transfer, the map, the evaluation.
    #[error("{0}")]
    Map(String),
    /// Writing the output files.
    #[error("{0}")]
    Output(String),
}

/// What the job found (rank 0 only).
pub struct Report {
    /// The recording as rank 0 read it (step 1).
    pub measured: Measured,
    /// The quadratic mesh the modes and the map live on.
    pub mesh: TetMesh,
    /// λ [rad²/s²] of the simulated modes in the band, their shapes (gathered, original node
    /// order) and the rigid-body eigenvalues.
    pub eigenvalues: Vec<f64>,
    pub shapes: Vec<Vec<f64>>,
    pub rigid_eigenvalues: Vec<f64>,
    /// Frequency [Hz] and near-degenerate cluster of each simulated mode in the band.
    pub sim_hz: Vec<f64>,
    pub cluster_of: Vec<usize>,
    /// The poles of the amplitude fit (step 3).
    pub assignment: PoleAssignment,
    /// Measured amplitude of each simulated cluster at each microphone (step 4).
    pub fit_clusters: ClusterAmplitudes,
    /// Predicted amplitudes per candidate vertex (step 5).
    pub table: ForwardTable,
    /// The likelihood map (step 6).
    pub map: ImpactMap,
    /// Against the known strike vertex (step 7).
    pub evaluation: Option<Evaluation>,
    /// Which acoustic transfer was used, in words.
    pub transfer_note: String,
    /// Seconds per stage.
    pub timings: Vec<(&'static str, f64)>,
    pub n_ranks: usize,
}

/// Near-degenerate simulated modes share a cluster (relative frequency tolerance).
const CLUSTER_RTOL: f64 = 0.005;

/// Runs the job on every rank (module docs, steps 1–7). Rank 0 returns the [`Report`]; the other
/// ranks take part in the collective steps (the recording's broadcast, assembly, eigen-solve)
/// and return `None`.
pub fn run(petsc: &Petsc, job: &Job, progress: &Progress) -> Result<Option<Report>, Error> {
    let total = Instant::now();
    let rank = petsc.rank();
    let (mesh_model, _) = model_mesh(
        petsc,
        &job.mesh,
        &ReadOptions {
            unit_scale: job.unit_scale,
            fix_inverted: false,
        },
        job.straighten_invalid,
        2,
    )?;
    if let Some(v) = job.true_vertex {
        if v >= mesh_model.n_nodes() {
            return Err(Error::NoSuchVertex {
                vertex: v,
                nodes: mesh_model.n_nodes(),
            });
        }
    }

    // 1: the recording (rank 0), shared so that every rank stops together on an error.
    let local = (rank == 0).then(|| measure::measure(job, progress));
    let measured: Measured = broadcast_from_root(petsc, local)
        .map_err(Error::Recording)?
        .map_err(Error::Recording)?;
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
        return Err(Error::TooFewPoles {
            found: measured.poles.len(),
            max_frequency_hz: job.max_frequency_hz,
        });
    }

    // 2: the modes at the fitted material.
    let t_solve = Instant::now();
    let assembled = assembly::assemble(petsc, &mesh_model)?;
    let (lo, hi) = mesh_model.bounding_box();
    let diagonal = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
    let material = &job.material;
    let (k, m) = assembled
        .operators(material)
        .map_err(|e| Error::Solver(e.to_string()))?;
    // Up to the band's top (a little beyond, for a recording a few % sharp of the model);
    // modes that land above it after the frequency scale are dropped below.
    let f_top = 1.05 * job.max_frequency_hz;
    let cfg = EigenConfig::new(
        ModeRequest::UpTo { f_max_hz: f_top },
        eigen::spectrum_scale(material.lame_mu(), material.density, diagonal),
    );
    let modes =
        eigen::solve_modes(petsc, &k, &m, &cfg).map_err(|e| Error::Solver(e.to_string()))?;
    let mut shapes = assembled
        .layout
        .gather_original_order(&modes.vectors)
        .map_err(|e| Error::Solver(e.to_string()))?;
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
    // Warnings go to stderr whether or not progress is shown, as the command always did.
    for w in &modes.warnings {
        if rank == 0 {
            eprintln!("warning: {w}");
        }
    }
    if rank != 0 {
        return Ok(None);
    }
    if shapes.is_empty() {
        return Err(Error::Map(format!("no elastic mode below {f_top:.0} Hz")));
    }

    // 3: poles per simulated cluster, for the modes whose scaled frequency lies in the band (a
    // mode above it is neither heard nor missed: the recording was not analysed there).
    let median_decay = {
        let mut d: Vec<f64> = measured.poles.iter().map(|p| p.decay_rate).collect();
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
    let first = measure::assign_poles(
        &measured,
        &all_hz,
        &evidence::cluster_ids(&all_hz, CLUSTER_RTOL),
        decay_of,
        job.match_tolerance,
    )
    .map_err(Error::Map)?;
    let in_band = all_hz
        .iter()
        .take_while(|&&f| first.scale * f <= job.max_frequency_hz)
        .count();
    if in_band == 0 {
        return Err(Error::Map(format!(
            "no simulated mode below {} Hz",
            job.max_frequency_hz
        )));
    }
    let eigenvalues = modes.eigenvalues[..in_band].to_vec();
    shapes.truncate(in_band);
    let sim_hz = all_hz[..in_band].to_vec();
    let cluster_of = evidence::cluster_ids(&sim_hz, CLUSTER_RTOL);
    let assignment = measure::assign_poles(
        &measured,
        &sim_hz,
        &cluster_of,
        decay_of,
        job.match_tolerance,
    )
    .map_err(Error::Map)?;
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
    .map_err(|e| Error::Map(format!("amplitude fit: {e}")))?;
    // Unclaimed poles get ids past the clusters, then are dropped.
    let n_clusters = assignment.observed.len();
    let ids: Vec<usize> = assignment
        .pole_cluster
        .iter()
        .enumerate()
        .map(|(i, c)| c.unwrap_or(n_clusters + i))
        .collect();
    let all = impact::cluster_amplitudes(&fit, &ids)
        .map_err(|e| Error::Map(format!("cluster amplitudes: {e}")))?;
    let measured_clusters =
        measure::keep_simulated_clusters(all, &ids, &cluster_of).map_err(Error::Map)?;
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
            measure::cluster_decay(&assignment, &fit, cluster_of[k])
                .unwrap_or_else(|| decay_of(sim_hz[k]))
        })
        .collect();
    let n_mics = measured.channels.len();
    let (transfer_values, transfer_note) =
        transfer::transfers(job, &mesh_model, &eigenvalues, &shapes, n_mics, progress)
            .map_err(Error::Map)?;
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
    .map_err(|e| Error::Map(format!("forward amplitudes: {e}")))?;
    let table_seconds = t_table.elapsed().as_secs_f64();

    // 6: the map.
    let t_map = Instant::now();
    let graph = SurfaceGraph::from_mesh(&mesh_model)
        .map_err(|e| Error::Map(format!("surface graph: {e}")))?;
    let map = impact::likelihood_map(&measured_clusters, &table, &graph, &job.map)
        .map_err(|e| Error::Map(format!("likelihood map: {e}")))?;
    let map_seconds = t_map.elapsed().as_secs_f64();
    let best = &table.candidates[map.best];
    progress.say(format!("map over {} surface vertices from {} cluster × microphone terms ({} below the detection limit) in {:.2} s; best vertex {} (strength {:.3e} ± {:.1e})", candidates.len(), map.terms, map.terms_below_limit, map_seconds, best.vertex, map.strength, map.strength_sd));

    // 7: evaluation against a known strike.
    let evaluation = match job.true_vertex {
        Some(v) => Some(evaluate::evaluate(v, &table, &map, &graph).map_err(Error::Map)?),
        None => None,
    };

    let timings = vec![
        ("recording", measured.seconds),
        ("modes", solve_seconds),
        ("amplitudes", amplitude_seconds),
        ("transfer_and_table", table_seconds),
        ("map", map_seconds),
        ("total", total.elapsed().as_secs_f64()),
    ];
    Ok(Some(Report {
        measured,
        mesh: mesh_model,
        eigenvalues,
        shapes,
        rigid_eigenvalues: modes.rigid_eigenvalues.clone(),
        sim_hz,
        cluster_of,
        assignment,
        fit_clusters: measured_clusters,
        table,
        map,
        evaluation,
        transfer_note,
        timings,
        n_ranks: petsc.size(),
    }))
}
