//! Where a job's material comes from, decided once for every job: a fit-material result
//! (`--material FIT.h5`, which also carries ρ and the damping curve), E and ν given on the command
//! line (`--youngs`, `--poisson`; ρ from `--density`), or neither, which only the diagnosis
//! accepts: its line-spectrum match then finds E and ν from the recording.

use crate::fem::{Material, MaterialError};
use crate::io::fit_material::read_material;
use crate::io::IoError;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Where E and ν come from.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MaterialSource {
    /// A fit-material result (`--material FIT.h5`).
    FitFile(PathBuf),
    /// `--youngs` and `--poisson`.
    Given,
    /// Neither: the diagnosis's line-spectrum match.
    LineSpectrum,
}

impl MaterialSource {
    /// The word stored in the HDF5 results (`/material` attr `source`).
    pub fn kind(&self) -> &'static str {
        match self {
            MaterialSource::FitFile(_) => "fit_file",
            MaterialSource::Given => "given",
            MaterialSource::LineSpectrum => "line_spectrum",
        }
    }

    /// The fit-material result, if that is the source.
    pub fn path(&self) -> Option<&Path> {
        match self {
            MaterialSource::FitFile(p) => Some(p),
            _ => None,
        }
    }
}

impl std::fmt::Display for MaterialSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            MaterialSource::FitFile(p) => write!(f, "fitted in {}", p.display()),
            MaterialSource::Given => f.write_str("given"),
            MaterialSource::LineSpectrum => f.write_str("matched to the recorded line spectrum"),
        }
    }
}

/// Why the material given to a job was refused.
#[derive(Debug, thiserror::Error)]
pub enum MaterialInputError {
    #[error("give the material either as a fit-material result (--material) or as --youngs/--poisson, not both")]
    Both,
    #[error("--youngs and --poisson go together")]
    HalfPair,
    #[error("the material is needed: --material FIT.h5 (a fit-material result) or --youngs and --poisson")]
    Missing,
    #[error(transparent)]
    Read(#[from] IoError),
    #[error("the density must be positive, got {0}")]
    Density(f64),
    #[error("material: {0}")]
    Invalid(#[from] MaterialError),
}

/// The material as the job will use it.
#[derive(Clone, Debug, PartialEq)]
pub struct ResolvedMaterial {
    /// (E [Pa], ν), or none when the line-spectrum match is to find them.
    pub elastic: Option<(f64, f64)>,
    /// ρ [kg/m³]: the fit-material result's, else the one given.
    pub density: f64,
    pub source: MaterialSource,
}

/// Resolves and checks the material: from the fit-material result at `material_path` (whose ρ
/// replaces `density`), or from `given` = (E, ν) with `density`, not both. `density` is asked
/// for only when it is used. Neither is [`MaterialSource::LineSpectrum`] when
/// `line_spectrum_allowed`, else [`MaterialInputError::Missing`].
pub fn resolve(
    material_path: Option<PathBuf>,
    given: (Option<f64>, Option<f64>),
    density: impl FnOnce() -> f64,
    line_spectrum_allowed: bool,
) -> Result<ResolvedMaterial, MaterialInputError> {
    let resolved = match (material_path, given) {
        (Some(p), (None, None)) => {
            let (e, nu, rho) = read_material(&p)?;
            ResolvedMaterial {
                elastic: Some((e, nu)),
                density: rho,
                source: MaterialSource::FitFile(p),
            }
        }
        (Some(_), _) => return Err(MaterialInputError::Both),
        (None, (Some(e), Some(nu))) => ResolvedMaterial {
            elastic: Some((e, nu)),
            density: density(),
            source: MaterialSource::Given,
        },
        (None, (None, None)) if line_spectrum_allowed => ResolvedMaterial {
            elastic: None,
            density: density(),
            source: MaterialSource::LineSpectrum,
        },
        (None, (None, None)) => return Err(MaterialInputError::Missing),
        (None, _) => return Err(MaterialInputError::HalfPair),
    };
    if !(resolved.density.is_finite() && resolved.density > 0.0) {
        return Err(MaterialInputError::Density(resolved.density));
    }
    if let Some(material) = resolved.material() {
        material.validate()?;
    }
    Ok(resolved)
}

impl ResolvedMaterial {
    /// The FE material (no Rayleigh damping), when E and ν are known.
    pub fn material(&self) -> Option<Material> {
        self.elastic.map(|(e, nu)| Material {
            youngs_modulus: e,
            poisson_ratio: nu,
            density: self.density,
            rayleigh_alpha: 0.0,
            rayleigh_beta: 0.0,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_combination_resolves_or_is_refused_by_name() {
        let given = resolve(None, (Some(7e10), Some(0.3)), || 2700.0, false).unwrap();
        assert_eq!(given.source, MaterialSource::Given);
        assert_eq!(given.material().unwrap().density, 2700.0);
        let matched = resolve(None, (None, None), || 2400.0, true).unwrap();
        assert_eq!(matched.source, MaterialSource::LineSpectrum);
        assert!(matched.material().is_none());
        assert!(matches!(
            resolve(None, (None, None), || 2400.0, false),
            Err(MaterialInputError::Missing)
        ));
        assert!(matches!(
            resolve(None, (Some(7e10), None), || 2400.0, true),
            Err(MaterialInputError::HalfPair)
        ));
        assert!(matches!(
            resolve(Some("x.h5".into()), (Some(7e10), Some(0.3)), || 1.0, true),
            Err(MaterialInputError::Both)
        ));
        assert!(matches!(
            resolve(None, (Some(7e10), Some(0.3)), || -1.0, false),
            Err(MaterialInputError::Density(_))
        ));
        assert!(matches!(
            resolve(None, (Some(7e10), Some(0.6)), || 2700.0, false),
            Err(MaterialInputError::Invalid(_))
        ));
        assert!(matches!(
            resolve(
                Some("/nonexistent/fit.h5".into()),
                (None, None),
                || 1.0,
                false
            ),
            Err(MaterialInputError::Read(_))
        ));
    }
}
