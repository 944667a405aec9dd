//! The job's inputs that the command line resolves alike for any front end: a benchmark
//! case's metadata, and the material from a fit-material result or given E and ν.

use crate::audio::chain::DampingCurve;
use crate::fem::Material;
use crate::io::fit_material;
use crate::workflow::material::{self, MaterialInputError, MaterialSource};
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// The parts of a benchmark case's metadata this job reads.
#[derive(Clone, Debug, Deserialize)]
pub struct CaseMeta {
    pub mesh: PathBuf,
    pub mesh_unit: String,
    pub density_kg_m3: f64,
    pub sample_rate_hz: u32,
    pub onset_time_s: f64,
    pub microphone_files: Vec<PathBuf>,
    pub microphone_positions_m: Vec<[f64; 3]>,
    pub strike: CaseStrike,
}

#[derive(Clone, Debug, Deserialize)]
pub struct CaseStrike {
    pub vertex: usize,
}

/// The damping curve of a fit-material result, if it has a valid one.
pub fn read_damping_curve(path: &Path) -> Option<DampingCurve> {
    let (f, d) = fit_material::read_damping_curve(path).ok()?;
    DampingCurve::new(f, &d).ok()
}

impl CaseMeta {
    /// Reads a case's `metadata.toml`.
    pub fn read(path: &Path) -> Result<CaseMeta, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        toml::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))
    }
}

/// The material, its source for the report, and the damping curve when a fit-material result
/// gives one: from the result at `material_path`, or from `given` (E, ν) with `density()`;
/// validated ([`crate::workflow::material::resolve`]).
pub fn resolve_material(
    material_path: Option<PathBuf>,
    given: (Option<f64>, Option<f64>),
    density: impl FnOnce() -> f64,
) -> Result<(Material, MaterialSource, Option<DampingCurve>), MaterialInputError> {
    let resolved = material::resolve(material_path, given, density, false)?;
    let curve = resolved.source.path().and_then(read_damping_curve);
    let Some(m) = resolved.material() else {
        return Err(MaterialInputError::Missing);
    };
    Ok((m, resolved.source, curve))
}
