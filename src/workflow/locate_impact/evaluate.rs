//! Step 7: the map against a known strike vertex: geodesic distance from the truth to the
//! best candidate, the fraction of the surface ranked at or above the truth, and whether the
//! best candidate lies on the truth's symmetry orbit
//! ([`crate::inverse::impact::symmetry_orbit`]).

use crate::inverse::impact::{self, ForwardTable, ImpactMap, SurfaceGraph};
use serde::Serialize;

/// How the map did against a known strike vertex.
#[derive(Clone, Debug, Serialize)]
pub struct Evaluation {
    pub true_vertex: usize,
    pub best_vertex: usize,
    /// Along surface edges [m].
    pub geodesic_error_m: f64,
    /// Fraction of the surface area ranked at or above the truth.
    pub area_rank: f64,
    pub in_top_percent: bool,
    /// Vertices that no mode cluster can tell from the truth (relative tolerance 5 %).
    pub orbit_size: usize,
    pub best_on_orbit: bool,
    /// Geodesic distance from the best candidate to the nearest orbit vertex [m].
    pub orbit_error_m: f64,
}

/// Relative tolerance of the drive signatures that makes two vertices one symmetry orbit.
const ORBIT_RTOL: f64 = 0.05;

pub fn evaluate(
    true_vertex: usize,
    table: &ForwardTable,
    map: &ImpactMap,
    graph: &SurfaceGraph,
) -> Result<Evaluation, String> {
    let truth = table
        .candidates
        .iter()
        .position(|c| c.vertex == true_vertex)
        .ok_or_else(|| {
            format!("true strike vertex {true_vertex} is not a surface vertex with a normal")
        })?;
    let best = table.candidates[map.best].vertex;
    let geodesic_error_m = graph
        .distance(true_vertex, best)
        .map_err(|e| e.to_string())?;
    let signatures = impact::drive_signatures(table);
    let orbit =
        impact::symmetry_orbit(&signatures, truth, ORBIT_RTOL).map_err(|e| e.to_string())?;
    let best_on_orbit = orbit.contains(&map.best);
    let from_best = graph
        .distances_from(best, f64::INFINITY)
        .map_err(|e| e.to_string())?;
    let orbit_error_m = orbit
        .iter()
        .filter_map(|&c| graph.index_of(table.candidates[c].vertex))
        .map(|slot| from_best[slot])
        .fold(f64::INFINITY, f64::min);
    let area_rank = map.area_rank(truth);
    Ok(Evaluation {
        true_vertex,
        best_vertex: best,
        geodesic_error_m,
        area_rank,
        in_top_percent: area_rank <= 0.01,
        orbit_size: orbit.len(),
        best_on_orbit,
        orbit_error_m,
    })
}
