//! The diagnosis's job: everything resolved and checked before PETSc starts, and the checks
//! that read or validate input data (a benchmark case's metadata, a fit-material result, the
//! choice of held-out microphones, directions).

use crate::analysis::extract::{ExtractOptions, GlideOptions};
use crate::audio::health::ChannelHealth;
use crate::diagnose::catalogue::CatalogueSettings;
use crate::diagnose::evidence::{EnvelopeOptions, ObservedOptions};
pub use crate::workflow::material::MaterialSource;
use crate::workflow::material::{self, MaterialInputError};
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// Everything resolved and checked before PETSc starts.
#[derive(Clone, Debug)]
pub struct Job {
    pub mesh: PathBuf,
    pub unit_scale: f64,
    /// Straighten folded curved tets instead of refusing the mesh ([`crate::mesh::read_for_fem`]).
    pub straighten_invalid: bool,
    pub recordings: Vec<PathBuf>,
    pub fit_channels: Vec<usize>,
    pub held_channels: Vec<usize>,
    /// The held-out microphones are the default choice (every second one), not the user's:
    /// the diagnosis may then exchange the roles when the fit microphones hold too few modes
    /// (module docs of [`super`], "Too few modes").
    pub held_chosen_by_default: bool,
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

/// A benchmark case's metadata (written by `examples/diagnose_generate.rs`).
#[derive(Clone, Debug, Deserialize)]
pub struct CaseMeta {
    pub mesh: PathBuf,
    pub mesh_unit: String,
    pub density_kg_m3: f64,
    pub sample_rate_hz: u32,
    pub onset_time_s: f64,
    pub duration_after_onset_s: f64,
    pub microphone_files: Vec<PathBuf>,
    pub microphone_positions_m: Vec<[f64; 3]>,
    pub support_direction: [f64; 3],
    pub strike: CaseStrike,
}

#[derive(Clone, Debug, Deserialize)]
pub struct CaseStrike {
    pub vertex: usize,
    pub direction: [f64; 3],
}

impl CaseMeta {
    /// Reads a case's `metadata.toml`.
    pub fn read(p: &Path) -> Result<CaseMeta, String> {
        let text = std::fs::read_to_string(p).map_err(|e| format!("{}: {e}", p.display()))?;
        toml::from_str::<CaseMeta>(&text).map_err(|e| format!("{}: {e}", p.display()))
    }
}

/// `v` scaled to unit length; `what` names it in the error when it is zero or not finite.
pub fn unit_vector(v: [f64; 3], what: &str) -> Result<[f64; 3], String> {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if !(n.is_finite() && n > 0.0) {
        return Err(format!(
            "{what} must be a non-zero finite vector, got {v:?}"
        ));
    }
    Ok(v.map(|c| c / n))
}

/// The fit and the held-out microphones of `n_mics` recordings, given the held-out ones
/// (0-based): each must exist and appear once, at least one must remain for the fit, and with
/// `require_held_out` at least one must be held out.
pub fn split_microphones(
    n_mics: usize,
    held_channels: Vec<usize>,
    require_held_out: bool,
) -> Result<(Vec<usize>, Vec<usize>), String> {
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
    if sorted.is_empty() && require_held_out {
        return Err("no held-out microphone: diagnosis needs at least 2 recordings (one held out), or `[catalogue] require_held_out = false` to accept effects on ΔBIC alone".into());
    }
    Ok((fit_channels, held_channels))
}

/// (E, ν) if known [Pa, 1], where the material comes from, and the density [kg/m³].
pub type MaterialChoice = (Option<(f64, f64)>, MaterialSource, f64);

/// E and ν (or none: the line-spectrum match finds them), where they come from, and the density:
/// from a fit-material result at `material_path` (its density replaces `density`) or given as
/// (E, ν), not both; checked for a valid material ([`crate::workflow::material::resolve`]).
pub fn resolve_material(
    material_path: Option<PathBuf>,
    given: (Option<f64>, Option<f64>),
    density: f64,
) -> Result<MaterialChoice, MaterialInputError> {
    let r = material::resolve(material_path, given, || density, true)?;
    Ok((r.elastic, r.source, r.density))
}

/// Checks the recording window: the sample rate [Hz], the seconds kept after the onset and
/// before it, and the highest frequency diagnosed [Hz] (above 100 Hz, below Nyquist).
pub fn check_recording_window(
    sample_rate: u32,
    duration: f64,
    pre_roll: f64,
    max_frequency_hz: f64,
) -> Result<(), String> {
    if !(8_000..=192_000).contains(&sample_rate) {
        return Err(format!(
            "the sample rate must lie in 8000..=192000 Hz, got {sample_rate}"
        ));
    }
    if !(0.1..=30.0).contains(&duration) {
        return Err(format!(
            "the duration must lie in [0.1, 30] s, got {duration}"
        ));
    }
    if !(0.0..=10.0).contains(&pre_roll) {
        return Err(format!(
            "the pre-roll must lie in [0, 10] s, got {pre_roll}"
        ));
    }
    if !(max_frequency_hz > 100.0 && max_frequency_hz < 0.5 * f64::from(sample_rate)) {
        return Err(format!(
            "--fmax must lie in (100 Hz, Nyquist {} Hz), got {max_frequency_hz}",
            0.5 * f64::from(sample_rate)
        ));
    }
    Ok(())
}
