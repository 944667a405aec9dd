//! Observed ↔ simulated mode matching (parent module docs, "Matching").
//!
//! Frequencies are compared as x = ln f: observed modes at their undamped frequency
//! f₀ = √(f² + (d/2π)²) (the simulation is undamped), simulated ones times a global scale s.
//!
//! 0. **Faint poles.** An observed mode whose largest amplitude over the channels is more than
//!    `faint_pole_db` (default [`DEFAULT_FAINT_POLE_DB`] = 40 dB) below that of another
//!    observed mode within the largest pair split takes no part in steps 1–3 and may not be
//!    swapped in (step 6); step 5 makes it an extra pole of the partial it sits beside.
//!    Why: a pole a hundredth of its neighbour's amplitude within a few per cent is not a
//!    partial of its own that the simulation could predict. It is what the extraction makes
//!    of the loud partial's imperfect model (a glide, a decay that is not one exponential) or
//!    of a room: a reverberant field convolves each partial with a response whose peaks and
//!    notches are a few hertz apart, and ESPRIT reports them as faint poles around it. Matched by
//!    frequency alone, two such poles 70 and 72 dB below a partial 1.4 % from its simulated
//!    cluster took the cluster as a "split pair" (generator 2, seed 19, case 020, a tube in a
//!    room: split 8 Hz at z = 15, which no held-out microphone heard), and the partial itself
//!    was left as an extra pole. A beating pair's two modes are of comparable amplitude (the
//!    beat is what makes it audible), far within 40 dB.
//! 1. **Scale.** Every pairing (i, j) proposes ln s = x_i − x_j^sim within [ln s_min, ln s_max].
//!    Each proposal is scored by the truncated quadratic Σ_i min(e_i², tol²), e_i the distance
//!    from x_i − ln s to its nearest simulated mode: a matched mode costs its squared error,
//!    an unmatched one a fixed tol². The best proposal is refined three times by the median of
//!    the e_i within tol. With a fixed scale (held-out data, matched with the fit's scale) this
//!    step is skipped.
//! 2. **One-to-one.** All (i, j) with |e_ij| ≤ tol, in increasing |e_ij|, are taken when both
//!    are still free.
//! 3. **Clusters.** A cluster (near-degenerate simulated modes sharing an id) that took two
//!    observed modes further apart than the largest pair split keeps the closer one. Then
//!    every observed mode still free may join a cluster holding exactly one observed mode as
//!    its split partner, if the two observed modes are within the largest pair split and the
//!    free mode is within tol of the cluster: a simulated single mode or degenerate cluster
//!    seen as two modes.
//! 4. **Units.** A cluster with one observed mode is one [`Role::Single`] unit standing for all
//!    its members; with two, a [`Role::SplitLower`]/[`Role::SplitUpper`] pair; with three or
//!    more (only when it has that many members), one [`Role::Member`] unit per mode.
//! 5. **Extra poles.** A real object's partial is often several poles: a degenerate pair split
//!    by the object's asymmetry, each pole beating with a faint neighbour, a decay the
//!    extraction models with two or three damped sinusoids (the bowl's partial near 1680 Hz
//!    came out as five poles within 0.5 %). An observed mode still free that lies within the
//!    largest pair split of an observed mode already matched to a cluster, and within `tol` of
//!    that cluster, is an **extra pole** of that partial: matched to the cluster (no longer
//!    "unmatched"), but without rows of its own, so it adds no evidence and takes none from the
//!    unit it sits beside. Modes further away stay unmatched, with the nearest simulated mode
//!    named in the report.
//! 6. **Which poles are the partial** ([`Matching::with_swap`], used by the selection): steps
//!    2–5 decide by frequency alone, and inside a degenerate cluster the simulated split is
//!    mesh noise, so the closest pole is not necessarily the partial's. The bowl's partial
//!    near 1680 Hz rings at 1681.2 and 1684.2 Hz (d ≈ 3.1 1/s on both, the split pair) beside
//!    faint or broad poles at 1673, 1678.7 and 1687 Hz (d = 12–43 1/s), and step 2 took
//!    1678.7 Hz because the mesh's members sit at 1678.8 and 1682.3 Hz. An extra pole may
//!    therefore take a unit's place; the selection keeps the exchange when the baseline's
//!    likelihood prefers it by more than the ΔBIC threshold (parent docs, "Selection"). The
//!    exchanges are searched with a beam of readings, not greedily, and the end kept is the
//!    one of least −2 ln L once each exchange that reached it is charged the threshold
//!    (`selection::POLE_CHOICE_BEAM`): exchanges in different clusters can have near-equal
//!    gains, and which a greedy search took first decided the bowl's lowest partial.
//! 7. **Which shape is whose** ([`Matching::with_shape_exchange`], used by the selection).
//!    Two modes of different families within a fraction of a percent of each other (an
//!    avoided crossing) mix: each is a combination of the two shapes whose proportions turn
//!    with their detuning, and a ν or a mesh a little off turns them. Their frequencies keep
//!    their order, but which of them the strike drives, and so its level and energy, can be
//!    the other one's. Generator 2's seed 83 case 009 (a tube): recorded modes at 7770.0 and
//!    7778.2 Hz, the second 2.1 times as loud on every microphone and gliding by
//!    6.3·10⁻³, matched to the mesh's 7770.6 Hz (relative drive² 1.0) and 7779.3 Hz (0.034):
//!    the glide's energy covariate was the wrong way round. Two single units within
//!    [`NEAR_CROSSING_RTOL`] may therefore exchange the shapes they carry; as in step 6, the
//!    selection keeps an exchange when the baseline's likelihood prefers it.

use crate::numerics::median;
use std::collections::BTreeMap;

use super::{CatalogueSettings, Role, SimulatedMode};

/// Two simulated modes of different clusters within this of each other in ln f may carry
/// each other's shapes (module docs, step 7): the width of a near-degenerate cluster.
pub const NEAR_CROSSING_RTOL: f64 = 0.005;

/// Default of [`CatalogueSettings::faint_pole_db`] (module docs, step 0).
pub const DEFAULT_FAINT_POLE_DB: f64 = 40.0;

/// Step 0 of the module docs: which observed modes are faint poles. `ln_level[i]`: ln of mode
/// i's largest amplitude over the channels (−∞ when it has none); an empty slice marks none.
pub fn faint_poles(
    observed_ln_f: &[f64],
    ln_level: &[f64],
    settings: &CatalogueSettings,
) -> Vec<bool> {
    if ln_level.len() != observed_ln_f.len() || !settings.faint_pole_db.is_finite() {
        return vec![false; observed_ln_f.len()];
    }
    let margin = settings.faint_pole_db / 20.0 * std::f64::consts::LN_10;
    (0..observed_ln_f.len())
        .map(|i| {
            (0..observed_ln_f.len()).any(|j| {
                j != i
                    && (observed_ln_f[i] - observed_ln_f[j]).abs() <= settings.max_pair_split
                    && ln_level[j] - ln_level[i] > margin
            })
        })
        .collect()
}

/// One matched observed mode and what in the simulation it stands for.
#[derive(Clone, Debug, PartialEq)]
pub struct Unit {
    /// Index into the observed list.
    pub observed: usize,
    pub role: Role,
    pub cluster: usize,
    /// Position of this observed mode among the cluster's observed modes, by frequency.
    pub slot: usize,
    /// Simulated modes whose drive, support and mass weights and transfer it carries.
    pub represents: Vec<usize>,
    /// Simulated modes whose (drive²-weighted) ln f it is predicted at.
    pub frequency_from: Vec<usize>,
    /// Factor on the combined drive √Σ drive² of `represents`: 1, or 1/√2 for each mode of a
    /// split pair (the pair shares the cluster's excitation).
    pub drive_factor: f64,
}

/// The result of [`match_modes`].
#[derive(Clone, Debug, PartialEq)]
pub struct Matching {
    /// ln s, the global frequency scale.
    pub ln_scale: f64,
    pub units: Vec<Unit>,
    pub unmatched_observed: Vec<usize>,
    pub unmatched_simulated: Vec<usize>,
    /// Extra poles of matched partials (step 5): (observed mode, the unit's observed mode it
    /// sits beside, cluster).
    pub extra_poles: Vec<(usize, usize, usize)>,
    /// Per observed mode: a faint pole (step 0).
    pub faint: Vec<bool>,
}

/// Signed distance x − v from `x` to the nearest value v of the ascending, non-empty `sorted`.
fn offset_from_nearest(sorted: &[f64], x: f64) -> f64 {
    crate::numerics::nearest_sorted(sorted, x).map_or(f64::INFINITY, |j| x - sorted[j])
}

impl Matching {
    /// This matching with the extra pole `extra` in the place of the unit whose observed mode
    /// is `replaced` (step 6 of the module docs); `replaced` becomes an extra pole beside it.
    /// Roles and the members a split pair's modes sit at are re-sorted by frequency. None when
    /// `extra` is not an extra pole of that unit's cluster, or when a split pair would then be
    /// split by more than the largest pair split.
    pub fn with_swap(
        &self,
        observed_ln_f: &[f64],
        simulated: &[SimulatedMode],
        replaced: usize,
        extra: usize,
        settings: &CatalogueSettings,
    ) -> Option<Matching> {
        if self.faint.get(extra).copied().unwrap_or(false) {
            return None;
        }
        let unit = self.units.iter().position(|u| u.observed == replaced)?;
        let cluster = self.units[unit].cluster;
        let extra_at = self
            .extra_poles
            .iter()
            .position(|&(i, _, c)| i == extra && c == cluster)?;
        let mut m = self.clone();
        m.units[unit].observed = extra;
        m.extra_poles[extra_at] = (replaced, extra, cluster);
        let mut idx: Vec<usize> = (0..m.units.len())
            .filter(|&k| m.units[k].cluster == cluster)
            .collect();
        if idx.len() == 2 && m.units[idx[0]].role != Role::Member {
            idx.sort_by(|&a, &b| {
                observed_ln_f[m.units[a].observed].total_cmp(&observed_ln_f[m.units[b].observed])
            });
            let (lo, hi) = (m.units[idx[0]].observed, m.units[idx[1]].observed);
            let old_split = {
                let o: Vec<f64> = self
                    .units
                    .iter()
                    .filter(|u| u.cluster == cluster)
                    .map(|u| observed_ln_f[u.observed])
                    .collect();
                (o[0] - o[1]).abs()
            };
            let split = observed_ln_f[hi] - observed_ln_f[lo];
            if split > settings.max_pair_split.max(old_split) {
                return None;
            }
            let mut at: Vec<Vec<usize>> = idx
                .iter()
                .map(|&k| m.units[k].frequency_from.clone())
                .collect();
            let key = |v: &Vec<usize>| v.first().map_or(f64::NAN, |&j| simulated[j].match_ln_f());
            at.sort_by(|a, b| key(a).total_cmp(&key(b)));
            for (slot, (&k, from)) in idx.iter().zip(at).enumerate() {
                let u = &mut m.units[k];
                u.slot = slot;
                u.role = if slot == 0 {
                    Role::SplitLower
                } else {
                    Role::SplitUpper
                };
                u.frequency_from = from;
            }
        }
        m.units.sort_by_key(|u| u.observed);
        Some(m)
    }

    /// This matching with the single units of observed modes `a` and `b` exchanging the
    /// simulated shapes they carry (drive, weights, transfer: [`Unit::represents`]) while
    /// each keeps its frequency (step 7 of the module docs). None unless both are
    /// [`Role::Single`] units of different clusters predicted within [`NEAR_CROSSING_RTOL`]
    /// of each other.
    pub fn with_shape_exchange(
        &self,
        simulated: &[SimulatedMode],
        a: usize,
        b: usize,
    ) -> Option<Matching> {
        let ua = self.units.iter().position(|u| u.observed == a)?;
        let ub = self.units.iter().position(|u| u.observed == b)?;
        let (x, y) = (&self.units[ua], &self.units[ub]);
        if x.role != Role::Single || y.role != Role::Single || x.cluster == y.cluster {
            return None;
        }
        let ln_f = |u: &Unit| u.frequency_from.first().map(|&j| simulated[j].match_ln_f());
        if (ln_f(x)? - ln_f(y)?).abs() > NEAR_CROSSING_RTOL {
            return None;
        }
        let mut m = self.clone();
        let (represents, factor) = (x.represents.clone(), x.drive_factor);
        m.units[ua].represents = y.represents.clone();
        m.units[ua].drive_factor = y.drive_factor;
        m.units[ub].represents = represents;
        m.units[ub].drive_factor = factor;
        Some(m)
    }
}

/// Step 1 of the module docs.
fn search_scale(observed: &[f64], sim_sorted: &[f64], settings: &CatalogueSettings) -> f64 {
    let tol = settings.match_tolerance;
    let (lo, hi) = (settings.min_scale.ln(), settings.max_scale.ln());
    let cost = |ln_s: f64| -> f64 {
        observed
            .iter()
            .map(|&x| {
                let e = offset_from_nearest(sim_sorted, x - ln_s);
                (e * e).min(tol * tol)
            })
            .sum()
    };
    let mut best = (f64::INFINITY, 0.0f64.clamp(lo, hi));
    let mut consider = |ln_s: f64| {
        let c = cost(ln_s);
        if c < best.0 || (c == best.0 && ln_s.abs() < best.1.abs()) {
            best = (c, ln_s);
        }
    };
    consider(0.0f64.clamp(lo, hi));
    for &x in observed {
        for &y in sim_sorted {
            let ln_s = x - y;
            if ln_s >= lo && ln_s <= hi {
                consider(ln_s);
            }
        }
    }
    let mut ln_s = best.1;
    for _ in 0..3 {
        let within: Vec<f64> = observed
            .iter()
            .map(|&x| offset_from_nearest(sim_sorted, x - ln_s))
            .filter(|e| e.abs() <= tol)
            .collect();
        let Some(m) = median(&within) else {
            break;
        };
        ln_s += m;
    }
    ln_s
}

/// Matches observed modes (`observed_ln_f`: ln of the undamped observed frequencies) to the
/// simulated modes (module docs). `ln_level`: ln of each observed mode's largest amplitude over
/// the channels, for step 0 (an empty slice: no mode is faint). `fixed_ln_scale` skips the
/// scale search.
pub fn match_modes(
    observed_ln_f: &[f64],
    ln_level: &[f64],
    simulated: &[SimulatedMode],
    fixed_ln_scale: Option<f64>,
    settings: &CatalogueSettings,
) -> Matching {
    let sim_ln_f: Vec<f64> = simulated.iter().map(SimulatedMode::match_ln_f).collect();
    let mut sim_sorted = sim_ln_f.clone();
    sim_sorted.sort_by(f64::total_cmp);
    let faint = faint_poles(observed_ln_f, ln_level, settings);
    let partials: Vec<f64> = observed_ln_f
        .iter()
        .zip(&faint)
        .filter(|(_, &f)| !f)
        .map(|(&x, _)| x)
        .collect();
    let ln_scale = if partials.is_empty() || simulated.is_empty() {
        fixed_ln_scale.unwrap_or(0.0)
    } else {
        fixed_ln_scale.unwrap_or_else(|| search_scale(&partials, &sim_sorted, settings))
    };
    let tol = settings.match_tolerance;
    let distance = |i: usize, j: usize| observed_ln_f[i] - ln_scale - sim_ln_f[j];

    // Step 2: greedy one-to-one by distance.
    let mut edges: Vec<(f64, usize, usize)> = Vec::new();
    for i in (0..observed_ln_f.len()).filter(|&i| !faint[i]) {
        for j in 0..simulated.len() {
            let e = distance(i, j).abs();
            if e <= tol {
                edges.push((e, i, j));
            }
        }
    }
    edges.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut sim_of_obs: Vec<Option<usize>> = vec![None; observed_ln_f.len()];
    let mut obs_of_sim: Vec<Option<usize>> = vec![None; simulated.len()];
    for &(_, i, j) in &edges {
        if sim_of_obs[i].is_none() && obs_of_sim[j].is_none() {
            sim_of_obs[i] = Some(j);
            obs_of_sim[j] = Some(i);
        }
    }

    // Step 3: clusters.
    let mut members: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for (j, m) in simulated.iter().enumerate() {
        members.entry(m.cluster).or_default().push(j);
    }
    for list in members.values_mut() {
        list.sort_by(|&a, &b| sim_ln_f[a].total_cmp(&sim_ln_f[b]));
    }
    let observed_in = |cluster: &[usize], obs_of_sim: &[Option<usize>]| -> Vec<usize> {
        cluster.iter().filter_map(|&j| obs_of_sim[j]).collect()
    };
    for list in members.values() {
        let obs = observed_in(list, &obs_of_sim);
        // A loaded simulation (match frequencies) may split the cluster itself; the observed
        // split is then judged against the split of the two members they matched.
        let allowance = match obs.as_slice() {
            &[a, b] => match (sim_of_obs[a], sim_of_obs[b]) {
                (Some(ja), Some(jb))
                    if simulated[ja].match_frequency_hz.is_some()
                        && simulated[jb].match_frequency_hz.is_some() =>
                {
                    (sim_ln_f[ja] - sim_ln_f[jb]).abs()
                }
                _ => 0.0,
            },
            _ => 0.0,
        };
        if obs.len() == 2
            && (observed_ln_f[obs[0]] - observed_ln_f[obs[1]]).abs()
                > settings.max_pair_split + allowance
        {
            let err = |i: usize| distance(i, sim_of_obs[i].unwrap_or(0)).abs();
            let drop = if err(obs[0]) > err(obs[1]) {
                obs[0]
            } else {
                obs[1]
            };
            if let Some(j) = sim_of_obs[drop].take() {
                obs_of_sim[j] = None;
            }
        }
    }
    // Split partners: (observed, cluster) joined in step 3.
    let mut partner_of_cluster: BTreeMap<usize, usize> = BTreeMap::new();
    let mut free: Vec<usize> = (0..observed_ln_f.len())
        .filter(|&i| sim_of_obs[i].is_none() && !faint[i])
        .collect();
    free.sort_by(|&a, &b| {
        let da = offset_from_nearest(&sim_sorted, observed_ln_f[a] - ln_scale).abs();
        let db = offset_from_nearest(&sim_sorted, observed_ln_f[b] - ln_scale).abs();
        da.total_cmp(&db)
    });
    for &i in &free {
        let mut best: Option<(f64, usize)> = None;
        for (&cluster, list) in &members {
            if partner_of_cluster.contains_key(&cluster) {
                continue;
            }
            let obs = observed_in(list, &obs_of_sim);
            if obs.len() != 1 {
                continue;
            }
            let split = (observed_ln_f[i] - observed_ln_f[obs[0]]).abs();
            let near = list
                .iter()
                .map(|&j| distance(i, j).abs())
                .fold(f64::INFINITY, f64::min);
            if split <= settings.max_pair_split && near <= tol && best.is_none_or(|b| split < b.0) {
                best = Some((split, cluster));
            }
        }
        if let Some((_, cluster)) = best {
            partner_of_cluster.insert(cluster, i);
        }
    }

    // Step 4: units.
    let mut units = Vec::new();
    let mut unmatched_simulated = Vec::new();
    for (&cluster, list) in &members {
        let mut obs = observed_in(list, &obs_of_sim);
        if let Some(&i) = partner_of_cluster.get(&cluster) {
            obs.push(i);
        }
        obs.sort_by(|&a, &b| observed_ln_f[a].total_cmp(&observed_ln_f[b]));
        match obs.len() {
            0 => unmatched_simulated.extend(list.iter().copied()),
            1 => units.push(Unit {
                observed: obs[0],
                role: Role::Single,
                cluster,
                slot: 0,
                represents: list.clone(),
                frequency_from: list.clone(),
                drive_factor: 1.0,
            }),
            2 => {
                // Each mode of the pair sits at "its" member: for a one-member cluster both at
                // that mode; otherwise the lower observed at the lower of the members matched
                // (or, for a split partner, of the free members), the upper at the upper.
                let mut own: Vec<usize> = list
                    .iter()
                    .copied()
                    .filter(|&j| obs_of_sim[j].is_some())
                    .collect();
                for &j in list {
                    if own.len() < 2 && !own.contains(&j) {
                        own.push(j);
                    }
                }
                own.sort_by(|&a, &b| sim_ln_f[a].total_cmp(&sim_ln_f[b]));
                for (slot, &i) in obs.iter().enumerate() {
                    let j = own[slot.min(own.len() - 1)];
                    units.push(Unit {
                        observed: i,
                        role: if slot == 0 {
                            Role::SplitLower
                        } else {
                            Role::SplitUpper
                        },
                        cluster,
                        slot,
                        represents: list.clone(),
                        frequency_from: vec![j],
                        drive_factor: std::f64::consts::FRAC_1_SQRT_2,
                    });
                }
            }
            _ => {
                for (slot, &i) in obs.iter().enumerate() {
                    let j = sim_of_obs[i]
                        .expect("three observed modes in a cluster are all pass-1 matches");
                    units.push(Unit {
                        observed: i,
                        role: Role::Member,
                        cluster,
                        slot,
                        represents: vec![j],
                        frequency_from: vec![j],
                        drive_factor: 1.0,
                    });
                }
                unmatched_simulated
                    .extend(list.iter().copied().filter(|&j| obs_of_sim[j].is_none()));
            }
        }
    }
    units.sort_by_key(|u| u.observed);
    let mut matched: Vec<bool> = {
        let mut m = vec![false; observed_ln_f.len()];
        for u in &units {
            m[u.observed] = true;
        }
        m
    };
    // Step 5: extra poles of matched partials.
    let mut extra_poles = Vec::new();
    for i in 0..observed_ln_f.len() {
        if matched[i] {
            continue;
        }
        let beside = units
            .iter()
            .filter(|u| {
                (observed_ln_f[i] - observed_ln_f[u.observed]).abs() <= settings.max_pair_split
            })
            .filter(|u| {
                members[&u.cluster]
                    .iter()
                    .any(|&j| distance(i, j).abs() <= tol)
            })
            .min_by(|a, b| {
                (observed_ln_f[i] - observed_ln_f[a.observed])
                    .abs()
                    .total_cmp(&(observed_ln_f[i] - observed_ln_f[b.observed]).abs())
            });
        if let Some(u) = beside {
            extra_poles.push((i, u.observed, u.cluster));
        }
    }
    for &(i, _, _) in &extra_poles {
        matched[i] = true;
    }
    let unmatched_observed = (0..observed_ln_f.len()).filter(|&i| !matched[i]).collect();
    unmatched_simulated.sort_unstable();
    Matching {
        ln_scale,
        units,
        unmatched_observed,
        unmatched_simulated,
        extra_poles,
        faint,
    }
}
