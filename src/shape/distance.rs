//! How far apart two closed surfaces are: Chamfer and Hausdorff distances and the volume
//! intersection-over-union, estimated by seeded sampling (issue 7, task 3: a recovered shape
//! against the true one). Pure and serial.
//!
//! # Surface distances
//!
//! Points a ∈ P_A are drawn on surface A uniformly by area (a triangle with probability
//! ∝ its area, then a uniform point in it: with r₁, r₂ uniform in [0, 1),
//! p = (1 − √r₁) v₀ + √r₁ (1 − r₂) v₁ + √r₁ r₂ v₂), plus every vertex of A (where polyhedra keep
//! their corners, and where the maximum below usually is). d(a, B) is the exact distance from a
//! to the triangles of B ([`SignedDistance::unsigned_distance`], not to B's sampled points, so
//! the estimate has no sampling bias in the distance itself). With the same for B:
//!
//! ```text
//!   Chamfer   C = ½ ( mean_{a ∈ P_A} d(a, B) + mean_{b ∈ P_B} d(b, A) )        [length]
//!   Hausdorff H = max( max_{a ∈ P_A} d(a, B), max_{b ∈ P_B} d(b, A) )          [length]
//! ```
//!
//! The means are unbiased estimates of the area-weighted means over the continuous surfaces
//! (up to the few vertices added); H is a lower bound of the true Hausdorff distance, and equals
//! it when the farthest point is a vertex (a polyhedron's corner).
//!
//! # Volume IoU
//!
//! N points uniform in the union of the two bounding boxes, each inside A if A's generalised
//! winding number exceeds ½ ([`SignedDistance::winding_number`], robust to small defects):
//!
//! ```text
//!   IoU = #(inside A and inside B) / #(inside A or inside B)
//! ```
//!
//! a Monte-Carlo estimate with standard error ≈ √(IoU (1 − IoU) / #(A ∪ B)).
//!
//! Both use splitmix64 from the given seed, so a comparison is reproducible.

use super::sdf::SignedDistance;
use super::surface::{SurfaceError, TriangleSurface};
use crate::mesh::{cross, norm, sub};
use crate::random::SplitMix64;

/// Why two surfaces could not be compared.
#[derive(Debug, thiserror::Error)]
pub enum DistanceError {
    #[error("{0}")]
    Surface(#[from] SurfaceError),
    #[error("{0}")]
    Invalid(String),
}

/// Chamfer and Hausdorff distance between two surfaces (module docs), in their length unit.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SurfaceDistance {
    pub chamfer: f64,
    pub hausdorff: f64,
    /// mean_{a} d(a, B) and mean_{b} d(b, A).
    pub mean_a_to_b: f64,
    pub mean_b_to_a: f64,
}

/// Chamfer, Hausdorff and volume IoU of a shape against a reference.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ShapeComparison {
    pub chamfer: f64,
    pub hausdorff: f64,
    pub iou: f64,
}

/// `n` points uniform by area on `surface` (module docs).
pub fn sample_surface(surface: &TriangleSurface, n: usize, rng: &mut SplitMix64) -> Vec<[f64; 3]> {
    let mut cumulative = Vec::with_capacity(surface.n_triangles());
    let mut total = 0.0;
    for t in 0..surface.n_triangles() {
        let [a, b, c] = surface.triangle_coords(t);
        total += 0.5 * norm(cross(sub(b, a), sub(c, a)));
        cumulative.push(total);
    }
    if !(total > 0.0) {
        return Vec::new();
    }
    (0..n)
        .map(|_| {
            let target = rng.unit() * total;
            let t = cumulative
                .partition_point(|&c| c <= target)
                .min(cumulative.len() - 1);
            let [a, b, c] = surface.triangle_coords(t);
            let (r1, r2) = (rng.unit().sqrt(), rng.unit());
            [0, 1, 2].map(|d| (1.0 - r1) * a[d] + r1 * (1.0 - r2) * b[d] + r1 * r2 * c[d])
        })
        .collect()
}

/// Distances from the `samples` points on `from` (plus its vertices) to `to`: (mean, max).
fn one_way(
    from: &TriangleSurface,
    to: &SignedDistance,
    samples: usize,
    rng: &mut SplitMix64,
) -> (f64, f64) {
    let mut points = sample_surface(from, samples, rng);
    points.extend_from_slice(&from.vertices);
    let d: Vec<f64> = points.iter().map(|&p| to.unsigned_distance(p)).collect();
    (
        d.iter().sum::<f64>() / d.len() as f64,
        d.iter().copied().fold(0.0, f64::max),
    )
}

fn check_samples(samples: usize) -> Result<(), DistanceError> {
    if samples == 0 {
        return Err(DistanceError::Invalid(
            "at least one sample point is needed".into(),
        ));
    }
    Ok(())
}

/// Chamfer and Hausdorff distances between `a` and `b` from `samples` points on each (module
/// docs).
pub fn surface_distance(
    a: &TriangleSurface,
    b: &TriangleSurface,
    samples: usize,
    seed: u64,
) -> Result<SurfaceDistance, DistanceError> {
    check_samples(samples)?;
    let (sa, sb) = (SignedDistance::new(a)?, SignedDistance::new(b)?);
    Ok(distance_with(a, &sa, b, &sb, samples, seed))
}

fn distance_with(
    a: &TriangleSurface,
    sa: &SignedDistance,
    b: &TriangleSurface,
    sb: &SignedDistance,
    samples: usize,
    seed: u64,
) -> SurfaceDistance {
    let (mean_ab, max_ab) = one_way(a, sb, samples, &mut SplitMix64::stream(seed, 0));
    let (mean_ba, max_ba) = one_way(b, sa, samples, &mut SplitMix64::stream(seed, 1));
    SurfaceDistance {
        chamfer: 0.5 * (mean_ab + mean_ba),
        hausdorff: max_ab.max(max_ba),
        mean_a_to_b: mean_ab,
        mean_b_to_a: mean_ba,
    }
}

/// Volume intersection over union of the solids bounded by `a` and `b` from `samples` points
/// (module docs).
pub fn volume_iou(
    a: &TriangleSurface,
    b: &TriangleSurface,
    samples: usize,
    seed: u64,
) -> Result<f64, DistanceError> {
    check_samples(samples)?;
    let (sa, sb) = (SignedDistance::new(a)?, SignedDistance::new(b)?);
    iou_with(a, &sa, b, &sb, samples, seed)
}

fn iou_with(
    a: &TriangleSurface,
    sa: &SignedDistance,
    b: &TriangleSurface,
    sb: &SignedDistance,
    samples: usize,
    seed: u64,
) -> Result<f64, DistanceError> {
    let ((lo_a, hi_a), (lo_b, hi_b)) = (a.bounding_box(), b.bounding_box());
    let lo = [0, 1, 2].map(|d| lo_a[d].min(lo_b[d]));
    let hi = [0, 1, 2].map(|d| hi_a[d].max(hi_b[d]));
    let mut rng = SplitMix64::stream(seed, 2);
    let (mut both, mut either) = (0usize, 0usize);
    for _ in 0..samples {
        let q = [0, 1, 2].map(|d| rng.uniform(lo[d], hi[d]));
        let (ia, ib) = (sa.winding_number(q) > 0.5, sb.winding_number(q) > 0.5);
        both += usize::from(ia && ib);
        either += usize::from(ia || ib);
    }
    if either == 0 {
        return Err(DistanceError::Invalid(format!(
            "none of {samples} sample points lies inside either surface: are they closed?"
        )));
    }
    Ok(both as f64 / either as f64)
}

/// Chamfer, Hausdorff (from `surface_samples` points on each surface) and IoU (from
/// `volume_samples` points) of `shape` against `reference`.
pub fn compare_shapes(
    shape: &TriangleSurface,
    reference: &TriangleSurface,
    surface_samples: usize,
    volume_samples: usize,
    seed: u64,
) -> Result<ShapeComparison, DistanceError> {
    check_samples(surface_samples.min(volume_samples))?;
    let (sa, sb) = (SignedDistance::new(shape)?, SignedDistance::new(reference)?);
    let d = distance_with(shape, &sa, reference, &sb, surface_samples, seed);
    let iou = iou_with(shape, &sa, reference, &sb, volume_samples, seed)?;
    Ok(ShapeComparison {
        chamfer: d.chamfer,
        hausdorff: d.hausdorff,
        iou,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::icosphere;
    use std::f64::consts::PI;

    fn sphere(r: f64, centre: [f64; 3]) -> TriangleSurface {
        let (v, t) = icosphere(r, 4);
        TriangleSurface::new(
            v.into_iter()
                .map(|p| [0, 1, 2].map(|d| p[d] + centre[d]))
                .collect(),
            t,
        )
        .unwrap()
    }

    fn cuboid(h: f64) -> TriangleSurface {
        let v: Vec<[f64; 3]> = (0..8)
            .map(|k| {
                [
                    (k & 1) as f64,
                    ((k >> 1) & 1) as f64,
                    if k & 4 == 4 { h } else { 0.0 },
                ]
            })
            .collect();
        let mut t = Vec::new();
        for [p, q, r, s] in [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ] {
            t.push([p, q, r]);
            t.push([p, r, s]);
        }
        TriangleSurface::new(v, t).unwrap()
    }

    // An icosphere of 5120 faces sags inside its sphere by at most ~1e-3 r (its faces' circumradius²
    // / 2r): the analytic answers hold to that, plus the Monte-Carlo error of the IoU.

    #[test]
    fn concentric_spheres_are_their_radius_difference_apart() {
        let (a, b) = (sphere(1.0, [0.0; 3]), sphere(0.8, [0.0; 3]));
        let c = compare_shapes(&a, &b, 4000, 40_000, 1).unwrap();
        assert!((c.chamfer - 0.2).abs() < 3e-3, "Chamfer {}", c.chamfer);
        assert!(
            (c.hausdorff - 0.2).abs() < 3e-3,
            "Hausdorff {}",
            c.hausdorff
        );
        // IoU = 0.8³; standard error ≈ 0.0035.
        assert!((c.iou - 0.512).abs() < 0.015, "IoU {}", c.iou);
        let same = compare_shapes(&a, &a, 500, 5000, 2).unwrap();
        assert!(
            same.chamfer < 1e-12 && same.hausdorff < 1e-12 && same.iou == 1.0,
            "{same:?}"
        );
        // Reproducible from the seed.
        assert_eq!(
            compare_shapes(&a, &b, 300, 3000, 5).unwrap(),
            compare_shapes(&a, &b, 300, 3000, 5).unwrap()
        );
    }

    #[test]
    fn offset_spheres_match_the_lens_and_the_mean_distance() {
        let (r, d) = (1.0, 0.3);
        let (a, b) = (sphere(r, [0.0; 3]), sphere(r, [d, 0.0, 0.0]));
        let c = compare_shapes(&a, &b, 20_000, 60_000, 3).unwrap();
        // The point of A farthest from B is opposite B's centre: d away.
        assert!((c.hausdorff - d).abs() < 3e-3, "Hausdorff {}", c.hausdorff);
        // Lens volume π (4r + d)(2r − d)² / 12.
        let lens = PI * (4.0 * r + d) * (2.0 * r - d).powi(2) / 12.0;
        let ball = 4.0 / 3.0 * PI * r.powi(3);
        let iou = lens / (2.0 * ball - lens);
        assert!((c.iou - iou).abs() < 0.012, "IoU {} vs {iou}", c.iou);
        // A point at angle φ from the offset has |a − c_B| = √(r² + d² − 2rd cos φ), and cos φ is
        // uniform in [−1, 1] on the sphere: the mean of ||a − c_B| − r| by Simpson's rule.
        let n = 2000;
        let f = |u: f64| ((r * r + d * d - 2.0 * r * d * u).sqrt() - r).abs();
        let mean = (0..=n)
            .map(|i| {
                let u = -1.0 + 2.0 * i as f64 / n as f64;
                let w = if i == 0 || i == n {
                    1.0
                } else if i % 2 == 1 {
                    4.0
                } else {
                    2.0
                };
                w * f(u)
            })
            .sum::<f64>()
            * (2.0 / n as f64)
            / 3.0
            / 2.0;
        // Standard error of the sampled mean ≈ 0.1/√20000 per side.
        assert!(
            (c.chamfer - mean).abs() < 4e-3,
            "Chamfer {} vs {mean}",
            c.chamfer
        );
    }

    #[test]
    fn boxes_of_different_height() {
        let (a, b) = (cuboid(1.0), cuboid(1.2));
        let c = compare_shapes(&a, &b, 3000, 40_000, 4).unwrap();
        // B's top corners are 0.2 above A's, and nothing is farther.
        assert!(
            (c.hausdorff - 0.2).abs() < 1e-12,
            "Hausdorff {}",
            c.hausdorff
        );
        assert!((c.iou - 1.0 / 1.2).abs() < 0.01, "IoU {}", c.iou);
        // Both surfaces share four full sides' worth of area with the other: the Chamfer
        // distance is well below the Hausdorff one, and positive.
        assert!(
            c.chamfer > 0.005 && c.chamfer < 0.1,
            "Chamfer {}",
            c.chamfer
        );
        assert!(compare_shapes(&a, &b, 0, 10, 1).is_err());
        assert!(surface_distance(&a, &b, 10, 1).is_ok() && volume_iou(&a, &b, 10, 1).is_ok());
    }

    #[test]
    fn samples_are_uniform_by_area() {
        // Box of height 3 with unit base: the sides hold 12 of the 14 units of area.
        let s = cuboid(3.0);
        let points = sample_surface(&s, 14_000, &mut SplitMix64::new(9));
        let on_sides = points
            .iter()
            .filter(|p| p[2] > 1e-12 && p[2] < 3.0 - 1e-12)
            .count();
        let fraction = on_sides as f64 / points.len() as f64;
        assert!((fraction - 12.0 / 14.0).abs() < 0.01, "{fraction}");
    }
}
