//! Stage 5's inputs from the simulation, on rank 0: per simulated mode its drive at the strike
//! (|φ·n|, or the RMS over the surface vertices one can hit when the strike is unknown), its
//! motion along the support direction at the support, its near-degenerate cluster, |φ_k|² at
//! each surface vertex (and the motion along the support direction at those a support can
//! touch), and with the microphones known its |acoustic transfer| to each; then the object
//! map, the baseline's frequency residuals regressed on each surface vertex's |φ_k|² pattern.

use super::Job;
use crate::audio::radiation::{mode_transfers, Listeners};
use crate::diagnose::catalogue::{CatalogueReport, SitePair, SplitSites};
use crate::diagnose::evidence::{self, Motion};
use crate::eigen;
use crate::inverse::impact::cluster_members;
use crate::mesh::locate::{nearest_surface_vertices, strike_candidates, support_nodes};
use crate::mesh::TetMesh;
use crate::workflow::Progress;
use std::time::Instant;

/// Per-mode features on rank 0 from the full shapes (original node order).
pub struct Features {
    /// Simulated frequencies [Hz] (with a carried mass: the mass taken out again).
    pub frequencies_hz: Vec<f64>,
    pub clusters: Vec<usize>,
    pub drive: Vec<f64>,
    pub support_energy: Vec<f64>,
    /// |acoustic transfer| per mode to each microphone (fit ones first, then held out).
    pub transfer: Option<Vec<Vec<f64>>>,
    /// Surface vertices and |φ_k|² there: [vertex][mode].
    pub surface: Vec<usize>,
    pub surface_energy: Vec<Vec<f64>>,
    /// Surface vertices a support can touch (outward normal within 60° of the support
    /// direction) and the squared motion along that direction there: [vertex][mode].
    pub support_candidates: Vec<usize>,
    pub support_candidate_energy: Vec<Vec<f64>>,
    /// Per two-member cluster, how a unit point mass at each surface vertex splits it
    /// ([`SplitSites`]).
    pub split_sites: SplitSites,
    /// How the strike was taken (printed and in the JSON).
    pub strike_note: String,
}

pub(super) fn features(
    job: &Job,
    mesh: &TetMesh,
    eigenvalues: &[f64],
    shapes: &[Vec<f64>],
    progress: &Progress,
) -> Result<Features, String> {
    let along =
        |shape: &[f64], v: usize, n: [f64; 3]| (0..3).map(|c| shape[3 * v + c] * n[c]).sum::<f64>();
    let normals: std::collections::HashMap<usize, [f64; 3]> =
        mesh.vertex_normals().into_iter().collect();
    let (drive, strike_note) = match job.strike_vertex {
        Some(v) => {
            let n = match job.strike_direction {
                Some(d) => d,
                None => normals.get(&v).map(|n| n.map(|c| -c)).ok_or_else(|| {
                    format!("strike vertex {v} is not a surface vertex of the mesh")
                })?,
            };
            (
                shapes.iter().map(|s| along(s, v, n).abs()).collect(),
                format!("vertex {v}"),
            )
        }
        None => {
            // Unknown strike: the RMS drive over the vertices one can hit.
            let candidates = strike_candidates(mesh, job.support_direction, 0.05);
            if candidates.is_empty() {
                return Err("no surface vertex can be struck (all face the support)".into());
            }
            let d = shapes
                .iter()
                .map(|s| {
                    (candidates
                        .iter()
                        .map(|&(v, n)| along(s, v, n).powi(2))
                        .sum::<f64>()
                        / candidates.len() as f64)
                        .sqrt()
                })
                .collect();
            (
                d,
                format!("unknown: RMS over {} surface vertices", candidates.len()),
            )
        }
    };
    let support = support_nodes(mesh, job.support_direction, 0.01, 3);
    let frequencies_hz: Vec<f64> = eigenvalues
        .iter()
        .map(|&l| eigen::frequency_hz(l))
        .collect();
    // The profiles are taken about the body's own axis through its centroid
    // ([`evidence::symmetry_axis`]). A mesh of no volume, which reading it refuses, would fall
    // back to the support direction through the bounding box's centre.
    let (centre, axis) = match mesh.volume_moments() {
        Some((centre, moments)) => (centre, evidence::symmetry_axis(moments)),
        None => {
            let (lo, hi) = mesh.bounding_box();
            (
                std::array::from_fn(|r| 0.5 * (lo[r] + hi[r])),
                job.support_direction,
            )
        }
    };
    let profiles: Vec<Vec<f64>> = shapes
        .iter()
        .map(|s| evidence::axial_profile(s, &mesh.nodes, centre, axis, PROFILE_BINS))
        .collect();
    let clusters = evidence::symmetric_cluster_ids(
        &frequencies_hz,
        &profiles,
        CLUSTER_RTOL,
        CLUSTER_PROFILE_DISTANCE,
    );
    // A support feels the motion along its direction, a mass all of it (evidence module docs).
    let pressing = Motion::Along(job.support_direction);
    let support_energy = evidence::cluster_region_energies(
        shapes,
        &frequencies_hz,
        &clusters,
        &support,
        pressing,
        false,
    );
    let surface = mesh.surface_vertices();
    let region_energies = |v: usize, motion: Motion, lowers: bool| {
        evidence::cluster_region_energies(shapes, &frequencies_hz, &clusters, &[v], motion, lowers)
    };
    let surface_energy: Vec<Vec<f64>> = surface
        .iter()
        .map(|&v| region_energies(v, Motion::Full, true))
        .collect();
    let positions: Vec<[f64; 3]> = surface.iter().map(|&v| mesh.nodes[v]).collect();
    let split_sites = split_sites(
        &surface,
        &positions,
        &surface_energy,
        &frequencies_hz,
        &clusters,
        MAX_SPLIT_SITES,
    );
    let norm = job
        .support_direction
        .iter()
        .map(|c| c * c)
        .sum::<f64>()
        .sqrt();
    let support_candidates: Vec<usize> = surface
        .iter()
        .copied()
        .filter(|v| {
            normals.get(v).is_some_and(|n| {
                (0..3).map(|c| n[c] * job.support_direction[c]).sum::<f64>() > SUPPORT_FACING * norm
            })
        })
        .collect();
    let support_candidate_energy = support_candidates
        .iter()
        .map(|&v| region_energies(v, pressing, false))
        .collect();
    let transfer = match &job.microphones {
        None => None,
        Some(mics) => {
            let t = Instant::now();
            let order: Vec<usize> = job
                .fit_channels
                .iter()
                .chain(&job.held_channels)
                .copied()
                .collect();
            let positions: Vec<[f64; 3]> = order.iter().map(|&c| mics[c]).collect();
            let out: Vec<Vec<f64>> =
                mode_transfers(mesh, eigenvalues, shapes, Listeners::At(&positions))
                    .map_err(|e| format!("radiation: {e}"))?
                    .values
                    .iter()
                    .map(|row| row.iter().map(|p| p.norm()).collect())
                    .collect();
            progress.say(format!(
                "acoustic transfer of {} modes to {} microphones in {:.1} s",
                shapes.len(),
                positions.len(),
                t.elapsed().as_secs_f64()
            ));
            Some(out)
        }
    };
    Ok(Features {
        frequencies_hz,
        clusters,
        drive,
        support_energy,
        transfer,
        surface,
        surface_energy,
        support_candidates,
        support_candidate_energy,
        split_sites,
        strike_note,
    })
}

/// Most candidate sites of a point mass in the evidence ([`SplitSites`]); above it the surface
/// vertices are thinned by farthest-point sampling. The sites go into the report's JSON
/// (`catalogue_input`), one value per site and pair: the real bowl's 3,007 surface vertices
/// and 4 pairs took 263 kB of its 578 kB, and a 100k-vertex surface with 30 pairs would take
/// 60 MB. A mass's split pattern varies smoothly over the surface (the loaded match's coarse
/// pass samples 450 sites); no mesh of the benchmarks or the bowl reaches the cap.
const MAX_SPLIT_SITES: usize = 4000;

/// The surface vertices (at `positions`) as candidate sites of a point mass ([`SplitSites`]),
/// at most `max_sites` of them (farthest-point samples): for each two-member cluster, e₁ − e₂
/// at each vertex, read off the vertex energies that [`evidence::cluster_region_energies`]
/// turned to the vertex's principal directions (the larger eigenvalue on the lower member,
/// since a mass lowers).
fn split_sites(
    surface: &[usize],
    positions: &[[f64; 3]],
    surface_energy: &[Vec<f64>],
    frequencies_hz: &[f64],
    clusters: &[usize],
    max_sites: usize,
) -> SplitSites {
    let kept: Vec<usize> = if surface.len() > max_sites {
        super::loaded_match::farthest_points(positions, max_sites)
    } else {
        (0..surface.len()).collect()
    };
    let pairs = cluster_members(clusters)
        .into_iter()
        .filter(|ks| ks.len() == 2)
        .map(|mut ks| {
            let cluster = clusters[ks[0]];
            ks.sort_by(|&a, &b| frequencies_hz[a].total_cmp(&frequencies_hz[b]));
            SitePair {
                cluster,
                split_per_kg: kept
                    .iter()
                    .map(|&i| (surface_energy[i][ks[0]] - surface_energy[i][ks[1]]).max(0.0))
                    .collect(),
            }
        })
        .collect();
    SplitSites {
        vertices: kept.iter().map(|&i| surface[i]).collect(),
        pairs,
    }
}

/// The localisation and, when it points somewhere, the second catalogue run.
pub struct Localised {
    /// (μ, z) of the regression at each of [`Features::surface`].
    pub map: Vec<(f64, f64)>,
    /// The best surface vertex and its z.
    pub best: Option<(usize, f64)>,
    /// The region offered to the catalogue (empty when z is at most [`MASS_REGION_Z`]).
    pub region: Vec<usize>,
    /// The support's best candidate vertex (facing the support) and its z, from the
    /// baseline's decay residuals ([`evidence::localise_decay_residuals`]).
    pub support_best: Option<(usize, f64)>,
    /// The support region offered to the catalogue instead of the lowest band (empty when z is
    /// at most [`SUPPORT_REGION_Z`] or the band's own z is as large).
    pub support_region: Vec<usize>,
}

/// Near-degenerate clusters: neighbouring simulated frequencies within 0.5 % whose motion has
/// the same axial profile about the body's symmetry axis through its centroid
/// ([`evidence::symmetry_axis`]).
const CLUSTER_RTOL: f64 = 0.005;

/// Axial profiles ([`evidence::axial_profile`]) of the members of a symmetry-degenerate
/// cluster: 8 × 8 cells, L1 distance at most 0.2 (of 2).
const PROFILE_BINS: usize = 8;
const CLUSTER_PROFILE_DISTANCE: f64 = 0.2;

/// Nodes of the candidate added-mass region around the best vertex.
const MASS_REGION_VERTICES: usize = 5;
/// ζ above which the best region is offered to the catalogue.
const MASS_REGION_Z: f64 = 2.0;

/// Nodes of the candidate support region around the best vertex, and the ζ above which it is
/// offered: the same as the mass's (a contact region is no better known than a mass's).
const SUPPORT_REGION_VERTICES: usize = MASS_REGION_VERTICES;
const SUPPORT_REGION_Z: f64 = MASS_REGION_Z;
/// A support can touch the surface vertices whose outward normal is within 60° of the support
/// direction (n·down > ½), the complement of the strike candidates' rule.
const SUPPORT_FACING: f64 = 0.5;

pub(super) fn localise(report: &CatalogueReport, feats: &Features, mesh: &TetMesh) -> Localised {
    let residuals: Vec<(Vec<usize>, f64)> = report
        .residuals
        .iter()
        .filter(|r| r.before.ln_frequency.is_finite())
        .map(|r| (r.simulated.clone(), r.before.ln_frequency))
        .collect();
    let map = evidence::localise_frequency_residuals(&feats.surface_energy, &residuals);
    let best = map
        .iter()
        .enumerate()
        .filter(|(_, m)| m.1.is_finite())
        .max_by(|a, b| a.1 .1.total_cmp(&b.1 .1))
        .map(|(i, m)| (feats.surface[i], m.1));
    let region = match best {
        Some((v, z)) if z > MASS_REGION_Z => {
            nearest_surface_vertices(mesh, v, MASS_REGION_VERTICES)
        }
        _ => Vec::new(),
    };
    let (support_best, support_region) = localise_support(report, feats, mesh);
    Localised {
        map,
        best,
        region,
        support_best,
        support_region,
    }
}

/// Where the support is, from the baseline's decay residuals (module docs of
/// [`evidence`], "Where on the object"): the best downward-facing vertex, and its region when
/// its z exceeds [`SUPPORT_REGION_Z`] and the default band's weights' own z.
fn localise_support(
    report: &CatalogueReport,
    feats: &Features,
    mesh: &TetMesh,
) -> (Option<(usize, f64)>, Vec<usize>) {
    let residuals: Vec<(Vec<usize>, f64)> = report
        .residuals
        .iter()
        .filter_map(|r| {
            let z = r.before.ln_decay?;
            z.is_finite().then(|| (r.simulated.clone(), z))
        })
        .collect();
    let map = evidence::localise_decay_residuals(&feats.support_candidate_energy, &residuals);
    let best = map
        .iter()
        .zip(&feats.support_candidates)
        .filter(|(m, _)| m.1.is_finite())
        .max_by(|a, b| a.0 .1.total_cmp(&b.0 .1))
        .map(|(m, &v)| (v, m.1));
    // The default band's own z on the same residuals: the localised region replaces it only
    // when it explains the decays better.
    let band =
        evidence::localise_decay_residuals(std::slice::from_ref(&feats.support_energy), &residuals)
            [0]
        .1;
    let region = match best {
        Some((v, z)) if z > SUPPORT_REGION_Z && !(band >= z) => {
            nearest_surface_vertices(mesh, v, SUPPORT_REGION_VERTICES)
        }
        _ => Vec::new(),
    };
    (best, region)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each two-member cluster gets e₁ − e₂ per site (lower member's energy minus the upper's,
    /// whatever order the modes come in); lone modes and triples get no row; above the cap the
    /// sites are thinned to spread-out vertices, rows and vertices kept together.
    #[test]
    fn split_sites_pair_rows_and_thinning() {
        // Modes: a pair {0, 1} listed upper first, a lone mode 2.
        let frequencies_hz = [101.0, 100.0, 300.0];
        let clusters = [0, 0, 1];
        let surface = [10, 11, 12, 13, 14];
        let positions: Vec<[f64; 3]> = (0..5).map(|i| [i as f64, 0.0, 0.0]).collect();
        // At site i the lower member (mode 1) has 1 + i, the upper (mode 0) 0.5.
        let energy: Vec<Vec<f64>> = (0..5).map(|i| vec![0.5, 1.0 + i as f64, 2.0]).collect();
        let all = split_sites(
            &surface,
            &positions,
            &energy,
            &frequencies_hz,
            &clusters,
            10,
        );
        assert_eq!(all.vertices, surface.to_vec());
        assert_eq!(all.pairs.len(), 1);
        assert_eq!(all.pairs[0].cluster, 0);
        assert_eq!(all.pairs[0].split_per_kg, vec![0.5, 1.5, 2.5, 3.5, 4.5]);
        let thin = split_sites(&surface, &positions, &energy, &frequencies_hz, &clusters, 3);
        // The first vertex, then the farthest (the other end), then the middle.
        assert_eq!(thin.vertices, vec![10, 14, 12]);
        assert_eq!(thin.pairs[0].split_per_kg, vec![0.5, 4.5, 2.5]);
    }
}
