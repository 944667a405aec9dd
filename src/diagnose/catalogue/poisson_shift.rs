//! The Poisson ratio's error, a nuisance of the baseline.
//!
//! The simulated modes come at a Poisson ratio ν that is itself an estimate (a `fit-material`
//! result, a value the user gave, or the line-spectrum match): an error Δν moves each mode by
//! its own sensitivity, bending modes little and breathing or torsional ones more. That is a
//! pattern of frequency residuals over the modes that no missing physics made, and a mass
//! placed freely on the surface (or a support's stiffening) can imitate it on a handful of
//! modes. So when the simulation reports each mode's sensitivity, the baseline profiles Δν
//! like the frequency scale:
//!
//! ln f_k += S_k Δν,  S_k = ∂ln f_k/∂ν = ½ (∂λ_k/∂ν)/λ_k \[1\]
//!
//! with E and ρ held (the scale s absorbs any change of E/ρ), λ_k = ω_k² \[rad²/s²\], and
//! ∂λ_k/∂ν = φ_kᵀ (∂K/∂ν) φ_k from the mass-normalised shapes
//! ([`crate::eigen::sensitivity::material_sensitivities`]; a cluster's modes carry its mean).
//! The correction is linear in Δν, bounded to ±[`MAX_POISSON_SHIFT`]: a larger error of ν is
//! a wrong material, not a nuisance, and the line match would not have put every mode next to
//! its partner. Off with `[catalogue] poisson_nuisance = false`; evidence without the
//! sensitivities (older reports, hand-made evidence) leaves it out.

use std::sync::Arc;

use super::{ModeTable, ParamSpec, Term};

/// The term's effect name ([`Term::effect`]), by which other screens find it in a model.
pub const POISSON_EFFECT: &str = "poisson_ratio";

/// Largest |Δν| the nuisance may take [1].
pub const MAX_POISSON_SHIFT: f64 = 0.1;

/// The baseline's Δν term (module docs). Every mode of the table it acts on has its
/// sensitivity ([`super::ModeEntry::ln_f_per_poisson`]); a mode without one is left alone.
#[derive(Debug)]
pub struct PoissonShift;

impl Term for PoissonShift {
    fn effect(&self) -> &'static str {
        POISSON_EFFECT
    }
    fn variant(&self) -> &'static str {
        "baseline_nuisance"
    }
    fn params(&self) -> Vec<ParamSpec> {
        vec![ParamSpec::new(
            "Poisson ratio error Δν",
            "1",
            -MAX_POISSON_SHIFT,
            MAX_POISSON_SHIFT,
            0.01,
        )]
    }
    fn frequency(&self, table: &ModeTable, p: &[f64], ln_f: &mut [f64]) {
        for (f, m) in ln_f.iter_mut().zip(&table.modes) {
            if let Some(s) = m.ln_f_per_poisson {
                *f += s * p[0];
            }
        }
    }
}

/// The term when every mode of `table` has its sensitivity, None otherwise (module docs). The
/// baseline's start puts Δν at 0.
pub fn poisson_shift(table: &ModeTable) -> Option<Arc<dyn Term>> {
    (!table.modes.is_empty() && table.modes.iter().all(|m| m.ln_f_per_poisson.is_some()))
        .then(|| Arc::new(PoissonShift) as Arc<dyn Term>)
}
