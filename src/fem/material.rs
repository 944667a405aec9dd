//! Isotropic linear-elastic material with Rayleigh damping.
//!
//! Stiffness enters the FEM only through the Lamé parameters, and K is linear
//! in them: K = λ K_λ + μ K_μ. A sensitivity with respect to E or ν is therefore
//! dK/dp = (∂λ/∂p) K_λ + (∂μ/∂p) K_μ, with the exact partials provided here
//! ([`Material::dlame_dE`], [`Material::dlame_dnu`]); dM/dρ = M₁ (unit-density mass).
//!
//! Rayleigh damping C = α M + β K gives modal damping ratio
//! ζ(ω) = α/(2ω) + βω/2: α damps low frequencies, β high ones.

use serde::{Deserialize, Serialize};

/// Isotropic material, SI units: E in Pa, ν dimensionless, ρ in kg/m³, α in 1/s, β in s.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Material {
    pub youngs_modulus: f64,
    pub poisson_ratio: f64,
    pub density: f64,
    pub rayleigh_alpha: f64,
    pub rayleigh_beta: f64,
}

/// How close to 0.5 a Poisson ratio may come. At ν = 0.5 − 10⁻⁴ the bulk-to-shear ratio
/// λ/μ = 2ν/(1 − 2ν) is 5·10³; beyond it P2 displacement elements lock and the rigid modes stop
/// separating from the elastic ones (ν = 0.4999999 gave three "elastic" modes at 3.5–6.5 Hz with
/// residuals 1e-2, issue 41). The fits search ν ≤ 0.49.
pub const NEARLY_INCOMPRESSIBLE: f64 = 1e-4;

/// Why a [`Material`] is not physically admissible.
#[derive(thiserror::Error, Debug, Clone, PartialEq)]
pub enum MaterialError {
    #[error("Young's modulus must be positive and finite, got {0} Pa")]
    YoungsModulus(f64),
    #[error("Poisson ratio must satisfy -1 < nu < 0.5, got {0}")]
    PoissonRatio(f64),
    #[error(
        "Poisson ratio {0} is within {NEARLY_INCOMPRESSIBLE} of 0.5: displacement-based elements lock there (the bulk modulus swamps the shear \
         stiffness by {ratio:.0e}, and the solver can no longer tell the rigid modes from the elastic ones); no solid that rings is that \
         incompressible — use nu <= {limit}", ratio = (1.0 - 2.0 * .0).recip(), limit = 0.5 - NEARLY_INCOMPRESSIBLE
    )]
    NearlyIncompressible(f64),
    #[error("density must be positive and finite, got {0} kg/m^3")]
    Density(f64),
    #[error("Rayleigh damping coefficients must be finite and >= 0, got alpha = {alpha} 1/s, beta = {beta} s")]
    Rayleigh { alpha: f64, beta: f64 },
}

/// Preset table. Values are typical textbook/handbook figures for the class of
/// material, NOT measurements of any particular object; fit them (see the
/// inverse stage) for real objects. Rayleigh coefficients are chosen so the
/// damping ratio ζ(ω) = α/(2ω) + βω/2 is of the usual order in the audible band:
/// * ceramic/porcelain/glass: ζ ≈ 5e-4–1e-3 at 1 kHz (long, clear ring);
///   `ceramic` is the project's stated starting point (α = 6, β = 1e-7);
/// * metals: lower still (ζ ≈ 1e-4–3e-4 at 1 kHz; bells and bars ring for seconds);
/// * wood: ζ ≈ 1 % at 1 kHz (loss factor ~ 2 %); the isotropic model is a crude
///   stand-in for an orthotropic material;
/// * plastic (ABS-like): ζ ≈ 1.5–5 % across 1–5 kHz (dull knock).
const PRESETS: &[(&str, Material)] = &[
    ("ceramic", m(72e9, 0.19, 2700.0, 6.0, 1e-7)),
    ("porcelain", m(100e9, 0.22, 2400.0, 6.0, 1e-7)),
    ("glass", m(62e9, 0.20, 2500.0, 4.0, 8e-8)),
    ("steel", m(200e9, 0.29, 7850.0, 1.0, 3e-8)),
    ("aluminium", m(70e9, 0.33, 2700.0, 2.0, 5e-8)),
    ("aluminum", m(70e9, 0.33, 2700.0, 2.0, 5e-8)),
    ("brass", m(110e9, 0.34, 8500.0, 3.0, 5e-8)),
    ("wood", m(10e9, 0.30, 600.0, 60.0, 1.5e-6)),
    ("plastic", m(2.3e9, 0.35, 1050.0, 100.0, 3e-6)),
];

const PRESET_NAMES: &[&str] = &[
    "ceramic",
    "porcelain",
    "glass",
    "steel",
    "aluminium",
    "aluminum",
    "brass",
    "wood",
    "plastic",
];

const fn m(e: f64, nu: f64, rho: f64, alpha: f64, beta: f64) -> Material {
    Material {
        youngs_modulus: e,
        poisson_ratio: nu,
        density: rho,
        rayleigh_alpha: alpha,
        rayleigh_beta: beta,
    }
}

impl Material {
    /// First Lamé parameter λ = E ν / ((1+ν)(1−2ν)), in Pa.
    pub fn lame_lambda(&self) -> f64 {
        let (e, nu) = (self.youngs_modulus, self.poisson_ratio);
        e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    }

    /// Shear modulus μ = E / (2(1+ν)), in Pa.
    pub fn lame_mu(&self) -> f64 {
        self.youngs_modulus / (2.0 * (1.0 + self.poisson_ratio))
    }

    /// (λ, μ) together.
    pub fn lame(&self) -> (f64, f64) {
        (self.lame_lambda(), self.lame_mu())
    }

    /// (∂λ/∂E, ∂μ/∂E) = (ν/((1+ν)(1−2ν)), 1/(2(1+ν))).
    #[allow(non_snake_case)]
    pub fn dlame_dE(&self) -> (f64, f64) {
        let nu = self.poisson_ratio;
        (
            nu / ((1.0 + nu) * (1.0 - 2.0 * nu)),
            1.0 / (2.0 * (1.0 + nu)),
        )
    }

    /// (∂λ/∂ν, ∂μ/∂ν) = (E(1+2ν²)/((1+ν)(1−2ν))², −E/(2(1+ν)²)).
    pub fn dlame_dnu(&self) -> (f64, f64) {
        let (e, nu) = (self.youngs_modulus, self.poisson_ratio);
        let d = (1.0 + nu) * (1.0 - 2.0 * nu);
        (
            e * (1.0 + 2.0 * nu * nu) / (d * d),
            -e / (2.0 * (1.0 + nu) * (1.0 + nu)),
        )
    }

    /// Physical admissibility: E > 0 finite, −1 < ν < 0.5, ρ > 0 finite, α, β ≥ 0 finite.
    pub fn validate(&self) -> Result<(), MaterialError> {
        let e = self.youngs_modulus;
        if !(e.is_finite() && e > 0.0) {
            return Err(MaterialError::YoungsModulus(e));
        }
        let nu = self.poisson_ratio;
        if !(nu > -1.0 && nu < 0.5) {
            return Err(MaterialError::PoissonRatio(nu));
        }
        if nu > 0.5 - NEARLY_INCOMPRESSIBLE {
            return Err(MaterialError::NearlyIncompressible(nu));
        }
        let rho = self.density;
        if !(rho.is_finite() && rho > 0.0) {
            return Err(MaterialError::Density(rho));
        }
        let (alpha, beta) = (self.rayleigh_alpha, self.rayleigh_beta);
        if !(alpha.is_finite() && beta.is_finite() && alpha >= 0.0 && beta >= 0.0) {
            return Err(MaterialError::Rayleigh { alpha, beta });
        }
        Ok(())
    }

    /// A named preset (case-insensitive, surrounding whitespace ignored); see [`Material::preset_names`].
    pub fn preset(name: &str) -> Option<Material> {
        let name = name.trim();
        PRESETS
            .iter()
            .find(|(n, _)| n.eq_ignore_ascii_case(name))
            .map(|&(_, mat)| mat)
    }

    /// Names accepted by [`Material::preset`] (`aluminum` is an alias of `aluminium`).
    pub fn preset_names() -> &'static [&'static str] {
        PRESET_NAMES
    }

    /// Modal damping ratio ζ(ω) = α/(2ω) + βω/2 of Rayleigh damping at angular frequency ω (rad/s).
    pub fn damping_ratio(&self, omega: f64) -> f64 {
        self.rayleigh_alpha / (2.0 * omega) + self.rayleigh_beta * omega / 2.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_validate_and_lookup() {
        assert_eq!(PRESET_NAMES.len(), PRESETS.len());
        for (name, p) in PRESET_NAMES.iter().zip(PRESETS) {
            assert_eq!(*name, p.0);
        }
        for name in Material::preset_names() {
            let mat = Material::preset(name).unwrap();
            mat.validate().unwrap();
            assert_eq!(Material::preset(&name.to_uppercase()), Some(mat));
        }
        let c = Material::preset(" Ceramic").unwrap();
        assert_eq!(c, m(72e9, 0.19, 2700.0, 6.0, 1e-7));
        assert_eq!(Material::preset("aluminum"), Material::preset("ALUMINIUM"));
        assert!(Material::preset("unobtainium").is_none());
    }

    #[test]
    fn validate_rejects_bad_values() {
        let ok = Material::preset("steel").unwrap();
        let bad = [
            Material {
                youngs_modulus: 0.0,
                ..ok
            },
            Material {
                youngs_modulus: f64::INFINITY,
                ..ok
            },
            Material {
                youngs_modulus: f64::NAN,
                ..ok
            },
            Material {
                poisson_ratio: 0.5,
                ..ok
            },
            Material {
                poisson_ratio: -1.0,
                ..ok
            },
            Material {
                poisson_ratio: 0.4999999,
                ..ok
            },
            Material {
                poisson_ratio: f64::NAN,
                ..ok
            },
            Material { density: 0.0, ..ok },
            Material {
                rayleigh_alpha: -1.0,
                ..ok
            },
            Material {
                rayleigh_beta: f64::NAN,
                ..ok
            },
        ];
        for b in bad {
            assert!(b.validate().is_err(), "{b:?} accepted");
        }
        assert!(Material {
            poisson_ratio: -0.5,
            ..ok
        }
        .validate()
        .is_ok());
    }

    #[test]
    fn lame_formulas() {
        // E = 2.5, ν = 0.25: λ = 2.5·0.25/(1.25·0.5) = 1, μ = 2.5/2.5 = 1.
        let mat = m(2.5, 0.25, 1.0, 0.0, 0.0);
        assert!((mat.lame_lambda() - 1.0).abs() < 1e-15);
        assert!((mat.lame_mu() - 1.0).abs() < 1e-15);
        // Consistency: E = μ(3λ+2μ)/(λ+μ), ν = λ/(2(λ+μ)).
        let c = Material::preset("ceramic").unwrap();
        let (l, mu) = c.lame();
        assert!(((mu * (3.0 * l + 2.0 * mu) / (l + mu)) / c.youngs_modulus - 1.0).abs() < 1e-14);
        assert!((l / (2.0 * (l + mu)) - c.poisson_ratio).abs() < 1e-14);
    }

    #[test]
    fn derivatives_match_finite_differences() {
        for name in Material::preset_names() {
            let mat = Material::preset(name).unwrap();
            let he = mat.youngs_modulus * 1e-6;
            let p = Material {
                youngs_modulus: mat.youngs_modulus + he,
                ..mat
            };
            let q = Material {
                youngs_modulus: mat.youngs_modulus - he,
                ..mat
            };
            let (dl, dm) = mat.dlame_dE();
            let fdl = (p.lame_lambda() - q.lame_lambda()) / (2.0 * he);
            let fdm = (p.lame_mu() - q.lame_mu()) / (2.0 * he);
            assert!((dl - fdl).abs() <= 1e-7 * dl.abs() && (dm - fdm).abs() <= 1e-7 * dm.abs());

            let hn = 1e-6;
            let p = Material {
                poisson_ratio: mat.poisson_ratio + hn,
                ..mat
            };
            let q = Material {
                poisson_ratio: mat.poisson_ratio - hn,
                ..mat
            };
            let (dl, dm) = mat.dlame_dnu();
            let fdl = (p.lame_lambda() - q.lame_lambda()) / (2.0 * hn);
            let fdm = (p.lame_mu() - q.lame_mu()) / (2.0 * hn);
            assert!(
                (dl - fdl).abs() <= 1e-6 * dl.abs(),
                "{name}: dλ/dν {dl} vs {fdl}"
            );
            assert!(
                (dm - fdm).abs() <= 1e-6 * dm.abs(),
                "{name}: dμ/dν {dm} vs {fdm}"
            );
        }
    }
}
