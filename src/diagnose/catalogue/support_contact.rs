//! The object resting on a support.
//!
//! A support (a table, a hand, a cushion) touches the object over a small region. Modes that
//! move there lose energy into it and are stiffened (or, for a soft heavy support, loaded);
//! modes with a node there are untouched. With w_k ∈ [0, 1] mode k's squared motion along the
//! support's direction at the candidate support region, Σ (φ_k·n)², over the largest mode's
//! ([`super::SimulatedMode::support_weight`]; a contact reacts along its normal, so the two
//! members of a tube's bending pair, one pressing into the support and one sliding over it,
//! differ), first-order perturbation theory gives shifts proportional to w_k:
//!
//! Δd_k = γ · w_k  \[1/s\],  γ ≥ 0 (a passive support only removes energy),
//! Δ ln f_k = κ · w_k  (κ < 0 mass loading, κ > 0 a stiffening whose law is unknown),
//! Δ ln f_k = κ_s · w_k · (f_ref / f_k)²  (κ_s ≥ 0, a spring).
//!
//! The spring's law is the perturbation of the eigenvalue: a spring of stiffness k_s at the
//! region adds k_s |φ_k|² to λ_k = ω_k² (φ mass-normalised), so Δ ln f_k = k_s |φ_k|² / (2 λ_k):
//! proportional to the weight and falling as 1/f². A heavy support's mass m_s instead takes
//! −m_s λ_k |φ_k|² from λ_k, Δ ln f_k = −m_s |φ_k|² / 2, which is the law κ · w_k with κ < 0.
//! A support that shifts only the lowest modes, by far more than the upper ones (a spring
//! that splits a bending pair by 2.5 % at 2.4 kHz and by 0.36 % at 5.9 kHz), fits neither
//! κ · w_k nor a free split per pair as well as it fits the spring. f_ref is the model's
//! reference frequency ([`super::Model::ln_f_ref`], fixed when the term is proposed), so κ_s
//! is the shift of a mode of weight 1 there.
//!
//! Three variants: damping only (γ), damping with the proportional shift (γ, κ) and damping
//! with the spring (γ, κ_s); the criterion picks. Detector: weighted regressions of the current
//! decay residuals d_obs − d_pred on w (slope γ̂, its z), of the decay-split residuals of split
//! pairs on w_u − w_l through the origin (slope γ̂_pair, its z: the two modes of a pair share
//! any damping law's misfit, so a support that damps one more than the other stands out to the
//! extraction's precision), and of the ln f residuals on w (slope κ̂, its z) and on w (f_ref/f)²
//! (slope κ̂_s, its z); the candidate goes on if γ̂ > 0 with z > 1, γ̂_pair > 0 with z > 1.5,
//! |z_κ| > 1.5 or z_κs > 1.5 (the weights must vary by 5 % of the largest matched one).
//!
//! *Within split pairs.* The decay-split rows carry a profiled floor (parent docs: a room
//! scatters the decay rates of a pair far beyond their σ). Profiled under the null, that floor
//! takes up whatever a slope would explain, and on n pairs the Wald z of the slope cannot
//! exceed about √n however precise the decays: a tube on a rail (generator 2's spent seed 281
//! case 011), its two split pairs' upper members decaying 64 % and 74 % faster (10.10 ± 0.11
//! against 6.14 ± 0.05 1/s at 2.3 kHz), gave z = 1.5, below the raised members' gate, and
//! the free splits of a beating pair took the case. So the slope's z is the signed
//! likelihood-ratio statistic with the floor profiled under both hypotheses
//! ([`super::profiled_slope_through_origin`]): two pairs that agree to their precision give a
//! large z, two that disagree in sign or size a small one.
//!
//! Signature, after the fit: the support must damp, γ > [`MIN_DAMPING_Z`] σ_γ (2). A passive contact always takes
//! energy from the modes that move at it; a frequency shift alone is not a support's signature,
//! because any small frequency misfit correlated with the support weights looks the same. Two
//! versions of this rule failed. The first accepted any frequency-only "support": on a clean
//! blind-benchmark case it was accepted at ΔBIC 6.9 with a differential shift of 10⁻⁶. The
//! second accepted one whose differential shift |κ|·(w_max − w_min) reached 5·10⁻⁴, the
//! finite-element model's own accuracy. On the blind set 3 (seed 303) that still named a
//! support with γ = 0 ± 0.05 1/s twice: next to a beating pair whose sector of denser, stiffer
//! material also moves the pair means (case 015, κ = 9.7·10⁻⁴), and next to an added mass
//! (case 028). Requiring the damping removed both false alarms and lost no support on sets 1
//! to 3. For a time the damping also had to be firmer than 3σ (*Back to 2σ* says why no
//! longer): a bounded one-parameter term pays for
//! itself under the criterion only at z² ≳ ln n + the ΔBIC threshold (≈ 8 for a hundred rows),
//! z ≈ 2.8, and a damping below that is the frequency law's passenger. Generator 2's seed 65
//! case 002 (a tube in a room, no support) named a spring support at ΔBIC 62.1 whose damping
//! was 43 ± 19 1/s (2.3σ) on decay rates the room had blurred (ln d floor 0.37), once the tube's
//! pairs were clustered about its own axis; the other supports accepted in the calibration runs
//! (generator 2's spent seeds 41–65) had γ at 3.5σ to 54σ.
//!
//! *Back to 2σ.* That argument weighed the damping alone, and the damping does not stand
//! alone: the term must also pay for itself (ΔBIC ≥ 3) and lower the held-out error (gain ≥ 2),
//! and the decay rates a room blurs are now held out of every decay test (parent docs, **A room
//! holds up the fast modes**). Regenerated and rerun, seed 65's case 002 no longer reaches the support's
//! test: the room holds all of its decays. Meanwhile 3σ rejected three true supports that had
//! passed both other gates: generator 2's seed 157 case 006 (a plate on a strip, γ = 2.98 ±
//! 1.30 1/s, ΔBIC 21.2, held-out gain 20.5), seed 191 case 018 (a tube on a rail, 5.34 ± 2.48,
//! ΔBIC 11.8, gain 7.4) and set 1's seed 101 case 014 (the bowl on its foot, 26.1 ± 11.6, ΔBIC
//! 3.3, gain 2.6). Every false support candidate that passed both gates in the 215 saved cases
//! had γ within 1σ of zero (three of them: two added masses and a room). Replayed at 2σ,
//! the three supports were found and no other verdict changed, the real bowl's included. A
//! one-sided 2σ test on a bounded damping leaves 2.3 % of noise through, and the other two
//! gates stand behind it.
//!
//! **More than one mode.** A support damps every mode that moves at it, so its signature
//! must rest on at least [`MIN_SUPPORT_MODES`] matched modes whose weight is at least
//! [`SUPPORT_MODE_SHARE`] of the largest; with one, γ is a free decay rate for that mode, the
//! damping law's own misfit there. Generator 2's seed 71 case 016 (a uniform-shift control on
//! a cup, 6 matched modes, the support weight on the lowest alone) named a spring support whose
//! 0.26 ± 0.02 1/s (11σ) was 9 % of that one mode's decay rate.
//!
//! **Raised members** (variant `raised_members`). A support under a tube presses on one member
//! of each degenerate pair (the one moving along its normal) and slides under the other, so
//! it raises and damps the first and barely touches the second. Its stiffening of that member
//! follows k_s|φ|²/(2λ) only as far as the contact is a set of normal springs at the candidate
//! region: tangential stiffness, the strip's own extent and a region that is not quite the
//! catalogue's make each pair's rise its own. Generator 2's seed 65 case 011 (a 116-vertex
//! strip, springs 0.3 k tangential) raised the pressing members of its tube's pairs by
//! 0.3–4.1 % and the others by 0.15–1.3 %, and the free splits of a beating pair took the case
//! (ΔBIC 7138) before any support law could. So when the within-pair decay regression says
//! the members with the larger support weight decay faster (γ̂_pair > 0, z > 1.5), the support
//! is also offered with one free rise δ_c ≥ 0 per split pair that the split screen takes for
//! the object's ([`super::beating_pair`], `split_candidates`): the upper member sits δ_c above
//! the lower one, which stays where the model puts it, and the damping is γ w_k as above. It
//! has one parameter more than the free splits, which it contests (parent docs, "Selection",
//! *Two readings of the same splits*): it enters only if the damping pays for it, and its
//! signature is the same damping. Splits with like decay rates stay an asymmetry's. The
//! pressing member is the upper one because the split pair's members take their support
//! weights in frequency order (the largest on the highest, `ModeTable::resolve_split_weights`).

use std::sync::Arc;

use super::beating_pair::{split_candidates, SplitClusters};
use super::{
    profiled_slope_through_origin, weight_range, weighted_regression, weights_vary, Detection,
    Effect, Fit, ModeTable, ObservedMode, ParamSpec, Proposal, Quantity, Term,
};

pub struct SupportContact;

/// How the support shifts the frequencies (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrequencyLaw {
    /// Damping only.
    None,
    /// Δ ln f = κ w.
    Proportional,
    /// Δ ln f = κ_s w (f_ref/f)², κ_s ≥ 0.
    Spring,
}

#[derive(Debug)]
pub struct SupportTerm {
    pub law: FrequencyLaw,
    /// ln f_ref (Hz) of the spring law.
    pub ln_f_ref: f64,
}

impl SupportTerm {
    /// The frequency covariate of mode `m` under the term's law: w, or w (f_ref/f)².
    fn shift_weight(&self, m: &super::ModeEntry) -> f64 {
        frequency_covariate(self.law, self.ln_f_ref, m)
    }
}

/// w for [`FrequencyLaw::Proportional`], w (f_ref/f_sim)² for [`FrequencyLaw::Spring`], 0
/// without a shift.
fn frequency_covariate(law: FrequencyLaw, ln_f_ref: f64, m: &super::ModeEntry) -> f64 {
    match law {
        FrequencyLaw::None => 0.0,
        FrequencyLaw::Proportional => m.support_weight,
        FrequencyLaw::Spring => m.support_weight * (2.0 * (ln_f_ref - m.ln_f_sim)).exp(),
    }
}

impl Term for SupportTerm {
    fn effect(&self) -> &'static str {
        "support_contact"
    }
    fn variant(&self) -> &'static str {
        match self.law {
            FrequencyLaw::None => "damping_only",
            FrequencyLaw::Proportional => "damping_and_frequency",
            FrequencyLaw::Spring => "damping_and_spring",
        }
    }
    fn params(&self) -> Vec<ParamSpec> {
        let mut p = vec![damping_spec()];
        match self.law {
            FrequencyLaw::None => {}
            FrequencyLaw::Proportional => p.push(ParamSpec::new(
                "support frequency shift κ",
                "1",
                -0.5,
                0.5,
                1e-2,
            )),
            FrequencyLaw::Spring => p.push(ParamSpec::new(
                "support spring shift κ_s at f_ref",
                "1",
                0.0,
                0.5,
                1e-2,
            )),
        }
        p
    }
    fn frequency(&self, table: &ModeTable, p: &[f64], ln_f: &mut [f64]) {
        if self.law != FrequencyLaw::None {
            for (f, m) in ln_f.iter_mut().zip(&table.modes) {
                *f += p[1] * self.shift_weight(m);
            }
        }
    }
    fn damping(&self, table: &ModeTable, p: &[f64], _ln_f: &[f64], decay: &mut [f64]) {
        add_support_damping(table, p[0], decay);
    }
    fn signature_missing(&self, table: &ModeTable, p: &[f64], sigma: &[f64]) -> Option<String> {
        let shift = if self.law == FrequencyLaw::None {
            0.0
        } else {
            let (lo, hi) = weight_range(table.modes.iter().map(|m| self.shift_weight(m)));
            p[1].abs() * (hi - lo)
        };
        does_not_damp(
            p[0],
            sigma[0],
            &format!("differential frequency shift {shift:.1e}"),
        )
    }
}

/// Share of the largest support weight above which a matched mode counts as moving at the
/// support (module docs, *More than one mode*).
pub const SUPPORT_MODE_SHARE: f64 = 0.1;

/// Fewest matched modes with a decay rate that must move at the support (module docs, *More
/// than one mode*).
pub const MIN_SUPPORT_MODES: usize = 2;

/// How many standard deviations the fitted support damping γ must clear (module docs,
/// "Signature").
pub const MIN_DAMPING_Z: f64 = 2.0;

/// The support damping γ \[1/s\] that every variant carries first.
fn damping_spec() -> ParamSpec {
    ParamSpec::new("support damping γ", "1/s", 0.0, 1e4, 1.0)
}

/// Δd_k = γ w_k \[1/s\] on every matched mode (module docs).
fn add_support_damping(table: &ModeTable, gamma: f64, decay: &mut [f64]) {
    for (d, m) in decay.iter_mut().zip(&table.modes) {
        *d += gamma * m.support_weight;
    }
}

/// The support's signature (module docs): it damps, γ > [`MIN_DAMPING_Z`] σ_γ; otherwise why not.
fn does_not_damp(gamma: f64, sigma: f64, shift: &str) -> Option<String> {
    (gamma <= MIN_DAMPING_Z * sigma).then(|| {
        format!("the support does not damp (γ = {gamma:.3} ± {sigma:.3} 1/s; {shift}, which alone is not a support)")
    })
}

/// The variant name of a support's raised members ([`RaisedMembers`]).
pub(super) const RAISED_MEMBERS_VARIANT: &str = "raised_members";

/// A support that stiffens the member pressing into it by a law not known (module docs,
/// *Raised members*): its damping γ w_k, and per listed cluster the upper member of the pair
/// δ_c above the lower one, which stays where the model puts it.
#[derive(Debug)]
pub struct RaisedMembers {
    pub splits: SplitClusters,
}

impl Term for RaisedMembers {
    fn effect(&self) -> &'static str {
        "support_contact"
    }
    fn variant(&self) -> &'static str {
        RAISED_MEMBERS_VARIANT
    }
    fn params(&self) -> Vec<ParamSpec> {
        let mut p = vec![damping_spec()];
        p.extend(self.splits.params(|c, f| {
            format!("upper member's rise δ/f above the lower of cluster {c} ({f:.1} Hz)")
        }));
        p
    }
    fn sets_splits(&self) -> bool {
        true
    }
    fn frequency(&self, table: &ModeTable, p: &[f64], ln_f: &mut [f64]) {
        for pair in &table.pairs {
            if let Some(i) = self.splits.index(pair.cluster) {
                ln_f[pair.upper] = ln_f[pair.lower] + p[1 + i];
            }
        }
    }
    fn damping(&self, table: &ModeTable, p: &[f64], _ln_f: &[f64], decay: &mut [f64]) {
        add_support_damping(table, p[0], decay);
    }
    fn signature_missing(&self, _table: &ModeTable, p: &[f64], sigma: &[f64]) -> Option<String> {
        does_not_damp(p[0], sigma[0], "the raised members alone")
    }
    /// The free splits of an asymmetry read the same split rows.
    fn contests(&self) -> Option<&'static str> {
        Some("beating_pair")
    }
}

impl Effect for SupportContact {
    fn name(&self) -> &'static str {
        "support_contact"
    }
    fn signature(&self) -> &'static str {
        "modes that move at the support decay faster (and shift) in proportion to their energy there"
    }
    fn detect(&self, table: &ModeTable, current: &Fit) -> Detection {
        self.screen(table, None, current)
    }
    fn detect_with_held_out(
        &self,
        table: &ModeTable,
        held_poles: Option<&[ObservedMode]>,
        current: &Fit,
    ) -> Detection {
        self.screen(table, held_poles, current)
    }
}

impl SupportContact {
    fn screen(
        &self,
        table: &ModeTable,
        held_poles: Option<&[ObservedMode]>,
        current: &Fit,
    ) -> Detection {
        if !weights_vary(table.modes.iter().map(|m| m.support_weight)) {
            return Detection::NotEnoughData(
                "support weights do not vary between the matched modes".into(),
            );
        }
        let res = current.mode_residuals(table);
        // Decay residuals in 1/s: d_obs − d_pred, variance d² (σ_lnd² + τ_d²).
        let damping: Vec<(f64, f64, f64)> = table
            .modes
            .iter()
            .enumerate()
            .filter_map(|(k, m)| {
                m.ln_d.map(|(ln_d, _)| {
                    let (_, v) = res.ln_d[k].expect("present with ln_d");
                    let d = ln_d.exp();
                    (
                        m.support_weight,
                        d - current.prediction.decay[k],
                        1.0 / (d * d * v),
                    )
                })
            })
            .collect();
        if damping.len() < 4 {
            return Detection::NotEnoughData(format!(
                "{} modes with a decay rate; at least 4 needed",
                damping.len()
            ));
        }
        // A support damps every mode that moves at it (module docs, *More than one mode*).
        let (_, w_max) = weight_range(damping.iter().map(|p| p.0));
        let moving = damping
            .iter()
            .filter(|p| p.0 >= SUPPORT_MODE_SHARE * w_max)
            .count();
        if moving < MIN_SUPPORT_MODES {
            return Detection::NotEnoughData(format!(
                "{moving} matched mode(s) with a decay rate move at the support (weight ≥ {SUPPORT_MODE_SHARE} of the largest); at least {MIN_SUPPORT_MODES} needed, or the damping is one mode's own misfit of the law"
            ));
        }
        // The ln f residuals against each frequency law's covariate.
        let ln_f_ref = current.model.ln_f_ref;
        let ln_f_regression = |law: FrequencyLaw| {
            let rows: Vec<(f64, f64, f64)> = table
                .modes
                .iter()
                .zip(&res.ln_f)
                .map(|(m, &(r, v))| (frequency_covariate(law, ln_f_ref, m), r, 1.0 / v))
                .collect();
            weighted_regression(&rows)
        };
        let (gamma, z_gamma) = weighted_regression(&damping);
        let (kappa, z_kappa) = ln_f_regression(FrequencyLaw::Proportional);
        let (kappa_s, z_spring) = ln_f_regression(FrequencyLaw::Spring);
        // Within split pairs: the decay split's residual in 1/s, d̄ (r_u − r_l) at the pair's
        // mean decay d̄, against w_u − w_l, through the origin (a damping law gives the two
        // modes of a pair the same residual, so no intercept is left). Each row with its
        // variance less the profiled decay-split floor, which the test profiles itself under
        // both hypotheses (module docs, *Within split pairs*).
        let split_floor = Quantity::DecaySplit
            .floor_index()
            .map_or(0.0, |q| current.tau2[q]);
        let within: Vec<(f64, f64, f64)> = current
            .decay_split_residuals(table)
            .into_iter()
            .filter_map(|(pair, r, v)| {
                let (l, u) = (&table.modes[pair.lower], &table.modes[pair.upper]);
                let d = 0.5 * (l.ln_d?.0.exp() + u.ln_d?.0.exp());
                Some((
                    u.support_weight - l.support_weight,
                    d * r,
                    d * d * (v - split_floor).max(0.0),
                ))
            })
            .collect();
        let (gamma_pair, z_pair) = profiled_slope_through_origin(&within).unwrap_or((0.0, 0.0));
        let detail = format!(
            "decay residual vs support weight: slope {gamma:.3} 1/s (z = {z_gamma:.1}); within split pairs: slope {gamma_pair:.3} 1/s (z = {z_pair:.1}); ln f: slope {kappa:.2e} (z = {z_kappa:.1}); ln f on w (f_ref/f)²: slope {kappa_s:.2e} (z = {z_spring:.1})"
        );
        let statistic = z_gamma.max(z_pair).max(z_kappa.abs()).max(z_spring);
        let damps = (gamma > 0.0 && z_gamma > 1.0) || (gamma_pair > 0.0 && z_pair > 1.5);
        // Split pairs whose upper member decays faster are what a support pressing on one
        // member of each pair makes (module docs, *Raised members*).
        let raised = if gamma_pair > 0.0 && z_pair > 1.5 {
            split_candidates(table, held_poles, current).ok()
        } else {
            None
        };
        let detail = match &raised {
            Some(found) => format!(
                "{detail}; {RAISED_MEMBERS_VARIANT}: {}",
                found.listed.join("; ")
            ),
            None => detail,
        };
        if !damps && z_kappa.abs() <= 1.5 && z_spring <= 1.5 {
            return Detection::Nothing { statistic, detail };
        }
        let g0 = if z_pair > z_gamma { gamma_pair } else { gamma }.max(0.0);
        let raised = raised.map(|found| Proposal {
            init: std::iter::once(g0).chain(found.init).collect(),
            term: Arc::new(RaisedMembers {
                splits: found.splits,
            }),
        });
        Detection::Found {
            statistic,
            detail,
            proposals: raised
                .into_iter()
                .chain([
                    Proposal {
                        term: Arc::new(SupportTerm {
                            law: FrequencyLaw::None,
                            ln_f_ref,
                        }),
                        init: vec![g0],
                    },
                    Proposal {
                        term: Arc::new(SupportTerm {
                            law: FrequencyLaw::Proportional,
                            ln_f_ref,
                        }),
                        init: vec![g0, kappa.clamp(-0.5, 0.5)],
                    },
                    Proposal {
                        term: Arc::new(SupportTerm {
                            law: FrequencyLaw::Spring,
                            ln_f_ref,
                        }),
                        init: vec![g0, kappa_s.clamp(0.0, 0.5)],
                    },
                ])
                .collect(),
        }
    }
}
