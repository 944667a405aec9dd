//! The job's inputs that the command line resolves alike for any front end: a benchmark
//! case's metadata, and the material from a fit-material result or given E and ν.

use crate::audio::chain::DampingCurve;
use crate::fem::Material;
use crate::io::fit_material::read_material as read_fit_material;
use crate::io::results::read_dataset;
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

/// The damping curve of a fit-material result, if it has one.
pub fn read_damping_curve(path: &Path) -> Option<DampingCurve> {
    let (f, _) = read_dataset(path, "/damping/curve/frequencies_hz").ok()?;
    let (d, _) = read_dataset(path, "/damping/curve/decay_rates").ok()?;
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
/// validated.
pub fn resolve_material(
    material_path: Option<PathBuf>,
    given: (Option<f64>, Option<f64>),
    density: impl FnOnce() -> f64,
) -> Result<(Material, super::MaterialSource, Option<DampingCurve>), String> {
    let (material, material_source, damping_curve) = match (material_path, given) {
        (Some(p), (None, None)) => {
            let (e, nu, rho) = read_fit_material(&p).map_err(|e| e.to_string())?;
            let curve = read_damping_curve(&p);
            (Material { youngs_modulus: e, poisson_ratio: nu, density: rho, rayleigh_alpha: 0.0, rayleigh_beta: 0.0 }, super::MaterialSource::FitFile(p.clone()), curve)
        }
        (Some(_), _) => return Err("give the material either as a fit-material result (--material) or as --youngs/--poisson, not both".into()),
        (None, (Some(e), Some(nu))) => {
            let density = density();
            (Material { youngs_modulus: e, poisson_ratio: nu, density, rayleigh_alpha: 0.0, rayleigh_beta: 0.0 }, super::MaterialSource::Given, None)
        }
        (None, (None, None)) => return Err("the material is needed: --material FIT.h5 (a fit-material result) or --youngs and --poisson".into()),
        (None, _) => return Err("--youngs and --poisson go together".into()),
    };
    material.validate().map_err(|e| format!("material: {e}"))?;
    Ok((material, material_source, damping_curve))
}
