//! Added mass or fluid loading.
//!
//! A mass attached to the object (a label, a glue spot, a finger, liquid in a bowl) lowers
//! the frequencies of the modes that move where it sits. For a mass-normalised mode, the
//! Rayleigh quotient with kinetic energy raised by the fraction μ·w_k gives
//!
//! Δ ln f_k = −½ ln(1 + μ · w_k),  μ ≥ 0,
//!
//! with w_k = |φ_k|² at the candidate region over its maximum over the modes
//! ([`super::SimulatedMode::mass_weight`]); μ is the added modal mass of the most affected
//! mode relative to its own. Fluid loading (the object in or filled with water, or a light
//! shell in air) adds a mass that falls with frequency, roughly as the wavelength of the
//! bending wave: Δ ln f_k = −½ ln(1 + μ_f · f_1/f_k), f_1/f_k the ratio of the lowest matched
//! simulated frequency to mode k's (the scale cancels; held-out data use the fit's f_1). Both
//! variants have one parameter; the criterion picks and the
//! report names the variant. A uniform shift is indistinguishable from the global scale s, so
//! only the differential part counts.
//!
//! Detector: the weighted regression (with intercept, the scale absorbs it) of the current
//! ln f residuals on −½ w_k (added mass) or −½ f_1/f_k (fluid); a variant goes on when its
//! slope (≈ μ) is positive with z > 1 and the differential shift it implies across the matched
//! modes is at least [`MIN_DIFFERENTIAL_SHIFT`].
//!
//! **A mass at an unknown site, read from the pairs it splits** (variant `lowered_members`).
//! A point mass m at x on a degenerate pair (φ_a, φ_b) adds the rank-one kinetic term
//! m (φ·n)(φ·n)ᵀ in the pair's basis (for a small region of vertices, nearly rank one), so the
//! member with its antinode at x drops by Δ ln f = −½ ln(1 + μ w) and the other, with its
//! node there, keeps its frequency: a mass only ever lowers (Rayleigh's quotient), and on a
//! pair it lowers one member. An asymmetry of shape, thickness or material moves both members
//! about the pair's centre instead ([`super::beating_pair`]). So when the site is not known
//! (the localisation maps read frequency residuals mode by mode and may not point at it),
//! each split pair the beating-pair screen takes for the object's own
//! ([`super::beating_pair`], `split_candidates`) gets one parameter δ_c ≥ 0: its lower member
//! sits δ_c below its upper member, and the upper member stays where the model puts it. It has
//! the free splits' parameter count; the two differ only in where the pair's centre goes (the
//! mass: δ_c/2 below the model's; the asymmetry: at it), and the likelihood of the pair-mean
//! rows decides between them, with the free splits as the default reading (parent docs,
//! "Selection", *Two readings of the same splits*). Measured on generator 2's spent seeds
//! 31–47, at each case's largest split pair that the catalogue took for a beating pair
//! (residuals against the fitted scale, in units of the pair's split): the three masses on
//! cups left the upper member within 0.04 of the model and the centre 0.33–0.51 below it; the
//! asymmetries (generator 2 splits a pair about its centre) left the centre within 0.2 in 10
//! of 14 cases, and 0.24–0.46 away in the other four (one of them, seed 37 case 006, below:
//! it reads as a mass). A mass that also moves lone modes leaves their drops to the floor.
//!
//! *One site.* The pair centres alone did not separate the two readings on cups whose band
//! holds only pairs (generator 2's seed 37 case 006 and seed 53 case 000, true split pairs
//! read as masses), so the reading needs a second signature: one point mass at one site makes
//! every drop. To first order, a mass m at vertex v turns each pair to the principal
//! directions of its members' Gram matrix G_ab = φ_a(v)·φ_b(v) (mass-normalised shapes,
//! \[1/kg\]) and lowers its split by
//!
//! δ_c = ½ m (e₁ − e₂)_c(v),  e₁ ≥ e₂ the eigenvalues of G,
//!
//! so across the clusters the drops follow one vertex's pattern x_c(v) = (e₁ − e₂)_c(v)
//! ([`SplitSites`], every surface vertex, from the workflow's mode shapes). The screen fits m
//! by least squares at each vertex and offers the reading only if the best vertex's relative
//! misfit ‖δ − ½ m x(v)‖/‖δ‖ is at most [`MAX_SITE_MISFIT`]; the report names that vertex and
//! the mass. An asymmetry splits each pair by its own Fourier content, which no one vertex's
//! pattern follows. The test can fail only with at least [`MIN_SITE_CLUSTERS`] split clusters
//! (a site has two coordinates and the mass a size): with fewer, the report says the site was
//! untested and the reading stands on the centres. Without candidate sites (evidence from
//! elsewhere than the workflow) the reading is not offered.
//!
//! *Centres need a scale.* Standing on the centres, the reading needs rows that say where the
//! centres should be. The frequency nuisances (the scale s, and Δν when the baseline has it)
//! fit any centres they outnumber or equal, and the matched modes that stand for one member
//! of a degenerate cluster place nothing: an asymmetry that splits the object's pairs splits
//! the unresolved ones too, its heard member sitting ± half an unknown split from the
//! centre, and a mass leaves it at the model or lowers it. Only modes that stand for a lone
//! simulated mode (no split reading moves them) anchor the scale. So with the site untested,
//! the split clusters' centres and those anchors must outnumber the nuisances, or the reading
//! is not offered (the free splits, claiming less, stay). Generator 2's seed 71 case 015 (a
//! cup, 2 microphones, 6 modes: two split pairs and two clusters with one member heard, no lone
//! mode, with s and Δν): the generator split every pair about its centre, the heard members
//! of the unresolved pairs were their upper members, so the scale put every upper member on
//! the model and the mass's reading beat the free splits by 12 in ΔBIC (174775.8 against
//! 174763.7).

use std::sync::Arc;

use super::beating_pair::{split_candidates, SplitClusters};
use super::{
    weighted_regression, weights_vary, Detection, Effect, Fit, ModeTable, ObservedMode, ParamSpec,
    Proposal, Term,
};

pub struct AddedMass;

/// Smallest differential frequency shift, max_k Δln f_k − min_k Δln f_k ≈ μ·(w_max − w_min)/2,
/// worth naming a loading: 5·10⁻⁴ (0.9 cent). Below it a "mass" only re-shapes residuals at the
/// level of the material fit's own error (the blind benchmark's clean cases gave fluid-loading
/// slopes μ_f ~ 10⁻⁴ at z ≈ 3 from a line-spectrum material that was off by 10⁻⁵–10⁻⁴ in ln f),
/// and no finite-element model of a real object is trusted to that level.
pub const MIN_DIFFERENTIAL_SHIFT: f64 = 5e-4;

#[derive(Debug)]
pub struct MassLoading {
    /// None: point mass on the mass weights. Some(ln f_1): fluid loading with reference f_1.
    pub fluid_ln_f1: Option<f64>,
}

impl MassLoading {
    fn weight(&self, ln_f_sim: f64, mass_weight: f64) -> f64 {
        match self.fluid_ln_f1 {
            None => mass_weight,
            Some(ln_f1) => (ln_f1 - ln_f_sim).exp(),
        }
    }
}

impl Term for MassLoading {
    fn effect(&self) -> &'static str {
        "added_mass"
    }
    fn variant(&self) -> &'static str {
        if self.fluid_ln_f1.is_some() {
            "fluid_loading"
        } else {
            "added_mass"
        }
    }
    fn params(&self) -> Vec<ParamSpec> {
        let name = if self.fluid_ln_f1.is_some() {
            "fluid added-mass ratio μ_f"
        } else {
            "added-mass ratio μ"
        };
        vec![ParamSpec::new(name, "1", 0.0, 10.0, 1e-2)]
    }
    fn frequency(&self, table: &ModeTable, p: &[f64], ln_f: &mut [f64]) {
        for (f, m) in ln_f.iter_mut().zip(&table.modes) {
            *f -= 0.5 * (p[0] * self.weight(m.ln_f_sim, m.mass_weight)).ln_1p();
        }
    }
}

/// Fewest split clusters on which the site test of the `lowered_members` reading can fail
/// (module docs, *One site*): a point mass has a site (two coordinates on the surface) and a
/// size, so the drops of one or two pairs fit some site whatever made them; only a third
/// tests it. Below it the reading stands on the pair centres alone, as the report says.
pub const MIN_SITE_CLUSTERS: usize = 3;

/// Largest relative misfit ‖δ − δ̂(v)‖/‖δ‖ of the pairs' drops at the best candidate site for
/// the `lowered_members` reading to be offered (module docs, *One site*). Calibrated on
/// generator 2's spent seeds (diagnose_benchmarks.md, "2026-12-03 (seventh)"): two masses on
/// cups over three split clusters fitted their best sites to 0.005, six true split pairs on
/// cups over three or four clusters to 0.058–0.183 at best.
pub const MAX_SITE_MISFIT: f64 = 0.02;

/// Candidate sites of a point mass, and how a unit mass at each splits each degenerate pair
/// of the model (first order): for mass-normalised shapes, a mass m at vertex v turns the
/// pair to the principal directions of its members' Gram matrix G_ab = φ_a(v)·φ_b(v) and
/// lowers each member by Δ ln f = −½ m e, e an eigenvalue of G; the pair's split grows by
/// ½ m (e₁ − e₂).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SplitSites {
    /// Mesh node of each candidate site (the surface vertices).
    pub vertices: Vec<usize>,
    /// One per two-member simulated cluster.
    pub pairs: Vec<SitePair>,
}

/// One pair's row of [`SplitSites`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SitePair {
    /// The simulated cluster.
    pub cluster: usize,
    /// e₁ − e₂ at each site \[1/kg\] (≥ 0).
    pub split_per_kg: Vec<f64>,
}

/// The candidate site that best explains a set of pair drops ([`SplitSites::fit`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SiteFit {
    /// Mesh node.
    pub vertex: usize,
    /// The point mass's first-order estimate \[kg\].
    pub mass_kg: f64,
    /// ‖δ − δ̂‖/‖δ‖.
    pub misfit: f64,
}

impl SplitSites {
    pub(super) fn validate(&self) -> Result<(), super::CatalogueError> {
        let bad = |m: String| Err(super::CatalogueError::InvalidSplitSites(m));
        for p in &self.pairs {
            if p.split_per_kg.len() != self.vertices.len() {
                return bad(format!(
                    "cluster {} has {} values for {} sites",
                    p.cluster,
                    p.split_per_kg.len(),
                    self.vertices.len()
                ));
            }
            if let Some(v) = p
                .split_per_kg
                .iter()
                .find(|v| !(**v >= 0.0 && v.is_finite()))
            {
                return bad(format!(
                    "cluster {}: a split per kg of {v}; must be ≥ 0 and finite",
                    p.cluster
                ));
            }
        }
        Ok(())
    }

    /// The site whose first-order splits ½ m x_c(v) fit `drops` (cluster, δ_c ln f) best in
    /// least squares over m > 0; `Ok(None)` when no site fits a positive mass, `Err(cluster)`
    /// for a cluster with no row.
    pub fn fit(&self, drops: &[(usize, f64)]) -> Result<Option<SiteFit>, usize> {
        let rows: Vec<&[f64]> = drops
            .iter()
            .map(|&(c, _)| {
                self.pairs
                    .iter()
                    .find(|p| p.cluster == c)
                    .map(|p| p.split_per_kg.as_slice())
                    .ok_or(c)
            })
            .collect::<Result<_, _>>()?;
        let norm2: f64 = drops.iter().map(|d| d.1 * d.1).sum();
        if !(norm2 > 0.0) {
            return Ok(None);
        }
        let mut best: Option<SiteFit> = None;
        for (i, &vertex) in self.vertices.iter().enumerate() {
            let (mut sxx, mut sxy) = (0.0, 0.0);
            for (row, d) in rows.iter().zip(drops) {
                sxx += row[i] * row[i];
                sxy += row[i] * d.1;
            }
            if !(sxx > 0.0 && sxy > 0.0) {
                continue;
            }
            let misfit = ((norm2 - sxy * sxy / sxx).max(0.0) / norm2).sqrt();
            if best.is_none_or(|b| misfit < b.misfit) {
                best = Some(SiteFit {
                    vertex,
                    mass_kg: 2.0 * sxy / sxx,
                    misfit,
                });
            }
        }
        Ok(best)
    }
}

/// The variant name of a mass's lowered members ([`LoweredMembers`]).
pub(super) const LOWERED_MEMBERS_VARIANT: &str = "lowered_members";

/// A mass at an unknown site, from the pairs it splits (module docs, `lowered_members`): the
/// lower member of each listed cluster's pair sits δ_c below the upper one, which stays where
/// the model puts it.
#[derive(Debug)]
pub struct LoweredMembers {
    pub splits: SplitClusters,
}

impl Term for LoweredMembers {
    fn effect(&self) -> &'static str {
        "added_mass"
    }
    fn variant(&self) -> &'static str {
        LOWERED_MEMBERS_VARIANT
    }
    fn params(&self) -> Vec<ParamSpec> {
        self.splits.params(|c, f| {
            format!("lower member's drop δ/f below the upper of cluster {c} ({f:.1} Hz)")
        })
    }
    /// As the free splits: only a held-out table that resolves one of these clusters into a
    /// pair can test it.
    fn held_out_can_test(&self, held: &ModeTable) -> bool {
        self.splits.held_out_can_test(held)
    }
    fn sets_splits(&self) -> bool {
        true
    }
    fn frequency(&self, table: &ModeTable, p: &[f64], ln_f: &mut [f64]) {
        for pair in &table.pairs {
            if let Some(i) = self.splits.index(pair.cluster) {
                ln_f[pair.lower] = ln_f[pair.upper] - p[i];
            }
        }
    }
    /// The free splits of an asymmetry read the same split rows.
    fn contests(&self) -> Option<&'static str> {
        Some("beating_pair")
    }
}

impl Effect for AddedMass {
    fn name(&self) -> &'static str {
        "added_mass"
    }
    fn signature(&self) -> &'static str {
        "frequencies low where the candidate mass sits (or, fluid loading, increasingly toward low modes)"
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

impl AddedMass {
    fn screen(
        &self,
        table: &ModeTable,
        held_poles: Option<&[ObservedMode]>,
        current: &Fit,
    ) -> Detection {
        if table.modes.len() < 4 {
            return Detection::NotEnoughData(format!(
                "{} matched modes; at least 4 needed",
                table.modes.len()
            ));
        }
        let res = current.mode_residuals(table);
        let ln_f1 = table
            .modes
            .iter()
            .map(|m| m.ln_f_sim)
            .fold(f64::INFINITY, f64::min);
        let mut details = Vec::new();
        let mut proposals = Vec::new();
        let mut statistic = f64::NEG_INFINITY;
        let mass_weights_vary = weights_vary(table.modes.iter().map(|m| m.mass_weight));
        for fluid in [None, Some(ln_f1)] {
            let term = MassLoading { fluid_ln_f1: fluid };
            if fluid.is_none() && !mass_weights_vary {
                details.push("mass weights do not vary".to_string());
                continue;
            }
            let points: Vec<(f64, f64, f64)> = table
                .modes
                .iter()
                .zip(&res.ln_f)
                .map(|(m, &(r, v))| (-0.5 * term.weight(m.ln_f_sim, m.mass_weight), r, 1.0 / v))
                .collect();
            let (mu, z) = weighted_regression(&points);
            let (lo, hi) = points
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
                    (a.min(p.0), b.max(p.0))
                });
            let differential_shift = mu * (hi - lo);
            details.push(format!(
                "{}: slope μ ≈ {mu:.3e} (z = {z:.1}), differential shift {:.2} ‰",
                term.variant(),
                1e3 * differential_shift
            ));
            statistic = statistic.max(z);
            if mu > 0.0 && z > 1.0 && differential_shift >= MIN_DIFFERENTIAL_SHIFT {
                proposals.push(Proposal {
                    term: Arc::new(term),
                    init: vec![mu.clamp(1e-4, 10.0)],
                });
            }
        }
        match split_candidates(table, held_poles, current) {
            Ok(found) => match one_site(table, &found.splits.clusters, &found.init, current) {
                Ok(site) => {
                    details.push(format!(
                        "{LOWERED_MEMBERS_VARIANT}: {}; {site}",
                        found.listed.join("; ")
                    ));
                    statistic = statistic.max(found.worst);
                    proposals.push(Proposal {
                        term: Arc::new(LoweredMembers {
                            splits: found.splits,
                        }),
                        init: found.init,
                    });
                }
                Err(why) => details.push(format!("{LOWERED_MEMBERS_VARIANT}: {why}")),
            },
            Err(Detection::Nothing { detail, .. }) | Err(Detection::NotEnoughData(detail)) => {
                details.push(format!("{LOWERED_MEMBERS_VARIANT}: {detail}"))
            }
            Err(Detection::Found { .. }) => {}
        }
        let detail = details.join("; ");
        if proposals.is_empty() {
            return Detection::Nothing { statistic, detail };
        }
        Detection::Found {
            statistic,
            detail,
            proposals,
        }
    }
}

/// Whether the pair centres can tell a mass's lowered members from an asymmetry's centred
/// splits (module docs, *Centres need a scale*): the `split_clusters` centres and the `anchors`
/// (matched modes that stand for one simulated mode, which no split reading moves) must
/// outnumber the frequency nuisances that fit any centres (the scale, and Δν when the
/// baseline has it).
pub(super) fn pair_centres_placeable(
    split_clusters: usize,
    anchors: usize,
    nuisances: usize,
) -> bool {
    split_clusters + anchors > nuisances
}

/// The second signature of the `lowered_members` reading (module docs, *One site*): the
/// observed splits of the split clusters must fit one candidate site of [`SplitSites`] to
/// [`MAX_SITE_MISFIT`] when there are at least [`MIN_SITE_CLUSTERS`] of them (fewer cannot
/// fail the test). Ok: what the report says of the site; Err: why the reading is not offered.
fn one_site(
    table: &ModeTable,
    clusters: &[usize],
    observed: &[f64],
    current: &Fit,
) -> Result<String, String> {
    let Some(sites) = table.split_sites.as_deref() else {
        return Err("no candidate sites to test a point mass on".to_string());
    };
    if clusters.len() < MIN_SITE_CLUSTERS {
        // Untested, the reading stands on the pair centres alone, and those need rows that
        // place them (module docs, *Centres need a scale*).
        let anchors = table
            .modes
            .iter()
            .filter(|m| m.simulated.len() == 1 && !clusters.contains(&m.key.cluster))
            .count();
        let poisson = current
            .model
            .terms
            .iter()
            .any(|t| t.effect() == super::poisson_shift::POISSON_EFFECT);
        let nuisances = 1 + usize::from(poisson);
        if !pair_centres_placeable(clusters.len(), anchors, nuisances) {
            return Err(format!(
                "site untested ({} split cluster(s)) and nothing places the pair centres: {} centre(s) and {anchors} lone mode(s) against {nuisances} frequency nuisance(s) (the scale{}), which fit any centres; an asymmetry's splits and a mass's cannot be told apart",
                clusters.len(),
                clusters.len(),
                if poisson { " and Δν" } else { "" }
            ));
        }
        return Ok(format!(
            "site untested: {} split cluster(s), and a point mass fits the drops of fewer than {MIN_SITE_CLUSTERS} at some site whatever made them",
            clusters.len()
        ));
    }
    // The observed splits themselves, as the reading models them (the lower member sits δ_c
    // below the upper, whatever split the mesh gives the pair): a mesh that splits a pair by
    // a discretisation error comparable to the mass's split does not add to it (seed 47 case
    // 013: a cup pair split 5.5·10⁻⁴ by the mesh, 7.3·10⁻⁴ observed, 7.1·10⁻⁴ predicted by
    // the best site alone).
    let drops: Vec<(usize, f64)> = clusters
        .iter()
        .copied()
        .zip(observed.iter().copied())
        .collect();
    match sites.fit(&drops) {
        Ok(Some(fit)) if fit.misfit <= MAX_SITE_MISFIT => Ok(format!(
            "the drops fit one site, vertex {} (misfit {:.3}, a point mass of about {:.3e} kg)",
            fit.vertex, fit.misfit, fit.mass_kg
        )),
        Ok(Some(fit)) => Err(format!(
            "the drops of {} clusters fit no single site (best vertex {}, misfit {:.3} > {MAX_SITE_MISFIT}): not one point mass",
            drops.len(),
            fit.vertex,
            fit.misfit
        )),
        Ok(None) => Err("no candidate site gives these clusters a positive mass".to_string()),
        Err(c) => Err(format!(
            "cluster {c} has no candidate-site row (not a two-member cluster of the model), so one site cannot be tested"
        )),
    }
}
