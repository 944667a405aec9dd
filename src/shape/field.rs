//! Shapes as sampled fields: surfaces read and placed, their signed distance sampled on a
//! background grid, and the reference depth of a solid (issue 7).
//!
//! # Shapes, units and alignment
//!
//! Surfaces (OBJ, or the boundary of a Gmsh tet mesh, [`read_surface`]) are placed by
//! [`normalise_surface`]: the bounding box is centred on the origin and scaled uniformly to a
//! bounding-box diagonal D (the benchmarks use D = 0.1 m), so every shape has the same size and
//! frequency range and two shapes to be morphed overlap around the origin with their own
//! orientation. The signed distance s [m] ([`SignedDistance`], positive inside) is sampled on a
//! grid of cubic cells whose longest axis has N cells ([`SampledField::of_sdf`], one cell of
//! margin; for a morph, one grid over the union of both boxes).
//!
use super::spectrum::ShapeError;
use super::{BackgroundGrid, SignedDistance, TriangleSurface};
use crate::mesh;
use std::path::Path;

/// A closed triangle surface from an OBJ file, or the boundary of a Gmsh tet mesh (`.msh`),
/// with the reader's warnings.
pub fn read_surface(path: &Path) -> Result<(TriangleSurface, Vec<String>), ShapeError> {
    let is_msh = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("msh"));
    if is_msh {
        let read = mesh::read_mesh(path, &mesh::ReadOptions::default())
            .map_err(|e| ShapeError::Invalid(e.to_string()))?;
        Ok((
            TriangleSurface::from_mesh_boundary(&read.mesh),
            read.warnings,
        ))
    } else {
        let read = super::read_obj(path)?;
        Ok((read.surface, read.warnings))
    }
}

/// Centres the surface's bounding box on the origin and scales it uniformly to a bounding-box
/// diagonal of `diagonal` (module docs). Returns the scale factor applied.
pub fn normalise_surface(surface: &mut TriangleSurface, diagonal: f64) -> Result<f64, ShapeError> {
    if !(diagonal.is_finite() && diagonal > 0.0) {
        return Err(ShapeError::Invalid(format!(
            "the bounding-box diagonal must be positive, got {diagonal}"
        )));
    }
    let (lo, hi) = surface.bounding_box();
    let current = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
    if !(current.is_finite() && current > 0.0) {
        return Err(ShapeError::Invalid(
            "the surface has no extent (all its vertices coincide)".into(),
        ));
    }
    let scale = diagonal / current;
    let centre = [0, 1, 2].map(|d| 0.5 * (lo[d] + hi[d]));
    for v in &mut surface.vertices {
        for d in 0..3 {
            v[d] = (v[d] - centre[d]) * scale;
        }
    }
    Ok(scale)
}

/// A signed distance sampled at the vertices of a background grid.
#[derive(Clone, Debug)]
pub struct SampledField {
    pub grid: BackgroundGrid,
    pub values: Vec<f64>,
}

impl SampledField {
    /// Samples `sdf` on the grid of cubic cells with `cells` along the longest axis of the box
    /// [lo, hi] plus one cell of margin ([`BackgroundGrid::covering`]).
    pub fn of_sdf(
        sdf: &SignedDistance,
        lo: [f64; 3],
        hi: [f64; 3],
        cells: usize,
    ) -> Result<SampledField, ShapeError> {
        SampledField::of_sdf_shifted(sdf, lo, hi, cells, [0.0; 3])
    }

    /// [`SampledField::of_sdf`] on the grid moved by `shift` cells along the axes
    /// ([`shifted_covering`]): the same spacing, another alignment of the vertices with the
    /// surface (a replica level, module docs "Grid bias and its extrapolation").
    pub fn of_sdf_shifted(
        sdf: &SignedDistance,
        lo: [f64; 3],
        hi: [f64; 3],
        cells: usize,
        shift: [f64; 3],
    ) -> Result<SampledField, ShapeError> {
        if cells < 4 {
            return Err(ShapeError::Invalid(format!(
                "a grid needs at least 4 cells along its longest axis, got {cells}"
            )));
        }
        let grid = shifted_covering(lo, hi, cells, shift)?;
        let values = sdf.evaluate(&grid.vertex_positions());
        if !values.iter().any(|&v| v > 0.0) {
            return Err(ShapeError::Invalid(format!(
                "no vertex of the {cells}-cell grid lies inside the surface: is it closed?"
            )));
        }
        Ok(SampledField { grid, values })
    }

    /// Cell size h [m] (cubic cells).
    pub fn spacing(&self) -> f64 {
        self.grid.spacing()[0]
    }

    /// Cells along the longest axis.
    pub fn cells(&self) -> usize {
        self.grid.cells().into_iter().max().unwrap_or(0)
    }
}

/// [`BackgroundGrid::covering`] with one cell of margin, moved by `shift` cells along the axes
/// (each in [−½, ½], so the box stays inside): the same spacing, vertices that do not line up
/// with the centred grid's (a target grid of 40 cells would otherwise contain every vertex of a
/// 20-cell fit grid).
pub fn shifted_covering(
    lo: [f64; 3],
    hi: [f64; 3],
    cells: usize,
    shift: [f64; 3],
) -> Result<BackgroundGrid, ShapeError> {
    if shift.iter().any(|s| !(s.abs() <= 0.5)) {
        return Err(ShapeError::Invalid(format!(
            "grid shift {shift:?} must lie in [−½, ½] cells"
        )));
    }
    let base = BackgroundGrid::covering(lo, hi, cells, 1.0)?;
    let h = base.spacing();
    Ok(BackgroundGrid::new(
        [0, 1, 2].map(|d| base.origin()[d] + shift[d] * h[d]),
        h,
        base.cells(),
    )?)
}

/// The box [lo, hi] of the union of the bounding boxes of `surfaces`.
pub fn union_box(surfaces: &[&TriangleSurface]) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for s in surfaces {
        let (a, b) = s.bounding_box();
        for d in 0..3 {
            lo[d] = lo[d].min(a[d]);
            hi[d] = hi[d].max(b[d]);
        }
    }
    (lo, hi)
}

/// Grid cells of the sampling that seeds [`reference_depth`].
const DEPTH_SEED_CELLS: usize = 32;

/// S, the depth of the deepest point of the solid (module docs): the pattern search of
/// [`SignedDistance::deepest_point`] from the 16 deepest vertices of a 32-cell sampling, to a
/// step of 1e-7 of the bounding-box diagonal. Depends on the surface only, so the fit and any
/// target use the same S.
pub fn reference_depth(sdf: &SignedDistance, surface: &TriangleSurface) -> Result<f64, ShapeError> {
    let (lo, hi) = surface.bounding_box();
    let seed = SampledField::of_sdf(sdf, lo, hi, DEPTH_SEED_CELLS)?;
    let mut order: Vec<usize> = (0..seed.values.len())
        .filter(|&v| seed.values[v] > 0.0)
        .collect();
    order.sort_by(|&a, &b| seed.values[b].total_cmp(&seed.values[a]));
    let starts: Vec<[f64; 3]> = order
        .iter()
        .take(16)
        .map(|&v| seed.grid.vertex_position(v))
        .collect();
    let diagonal = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
    let (_, depth) = sdf.deepest_point(&starts, seed.spacing(), 1e-7 * diagonal);
    if !(depth > 0.0) {
        return Err(ShapeError::Invalid(
            "the surface encloses no inside point".into(),
        ));
    }
    Ok(depth)
}
