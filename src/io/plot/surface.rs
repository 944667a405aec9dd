//! Surface figures: shaded triangle surfaces in 3-D, optionally coloured by a
//! scalar per vertex, with marked points, in a grid of panels × views.
//!
//! # Camera
//!
//! The projection is orthographic, with z up. A [`View`] looks at the body
//! from the direction
//!
//! d = (cos e · cos a, cos e · sin a, sin e)
//!
//! (azimuth a measured in the x-y plane from +x towards +y, elevation e above
//! that plane), so azimuth 0 looks from +x with +y to the right, azimuth 90°
//! looks from +y with −x to the right, and elevation 90° looks down from +z.
//! The screen axes are right = (−sin a, cos a, 0) and up = d × right; depth is
//! the distance along d (larger is nearer the viewer). Because the projection
//! is affine, barycentric weights in the image are the barycentric weights
//! on the triangle, so depth and values interpolate linearly in screen space
//! with no perspective correction.
//!
//! All panels share one scale, in pixels per unit of the vertex coordinates:
//! the largest bounding sphere among the panels (centred on each panel's
//! bounding-box centre, radius the farthest vertex from it) spans
//! [`FILL`] of the cell width, so bodies of different size compare at their
//! true relative size and none leaves its cell in any view. Each panel is
//! centred on its own bounding-box centre.
//!
//! # Rasterising and shading
//!
//! Each cell is rasterised with a depth buffer: a pixel shows the nearest
//! triangle whose interior contains the pixel centre. Edges are not drawn.
//! Shading is Lambertian from a light near the viewer (slightly above and to
//! the left of the eye):
//!
//! shade = [`AMBIENT`] + [`DIFFUSE`] · |n · l|
//!
//! with n the unit normal at the pixel and l the unit light direction, and the
//! pixel colour is the base colour multiplied by `shade`, so a scalar's colour
//! is darkened, never replaced. The absolute value shades back faces like
//! front faces: the inside of an open or cut-away body is visible. The
//! normal at a pixel is interpolated from per-corner normals: the vertex
//! normal where it is within [`CREASE_DEG`] of the face normal, the face
//! normal otherwise, so curved surfaces look smooth and sharp edges (a rim, a
//! cube's corners) stay sharp. The vertex normal is the mean of the adjacent
//! unit face normals weighted by each triangle's angle at the vertex, which
//! does not depend on how a flat face is split into triangles (area weights
//! would tilt a cube's corner normal towards the face cut into more pieces,
//! and past the crease test).
//!
//! The base colour is the crate's [`colormap`] at (v − lo)/(hi − lo) for the
//! interpolated value v (clamped to the range), or [`PLAIN`] grey for panels
//! without values. Where a corner of the triangle has a non-finite value the
//! pixel takes the value of its nearest corner (largest barycentric weight),
//! and a non-finite value is drawn [`PLAIN`] grey: a hole in a map stays a
//! hole and does not bleed colour into its neighbours.
//!
//! # Markers
//!
//! A [`SurfaceMarker`] is a filled circle in its colour with a dark outline,
//! drawn after the surfaces. It is *visible* when, at its pixel or one of the
//! eight around it, no surface is nearer the viewer than the marker by more
//! than [`MARKER_DEPTH_TOL_PX`] pixels' worth of depth (so a marker on the
//! surface survives pixel sampling on steep faces and at the silhouette,
//! while one behind a wall thicker than that is hidden). A hidden marker is
//! drawn hollow: a ring in its colour between dark edges, with the surface
//! showing through. Visible markers are drawn over hidden ones.
//!
//! Labels sit on a light box beside their marker: to the right, else to the
//! left, else one row lower or higher, whichever first stays inside the cell
//! without covering a label placed before it (visible markers' labels are
//! placed first). Labels can still cover other markers, and overlap each
//! other when all six places around a marker are taken.

use std::path::Path;

use super::axes::{self, Look};
use super::canvas::{text_size, Canvas, HAlign, Marker, PixelRect, Rgb, VAlign};
use super::colormap::colormap;
use super::draw::{ImageFormat, RASTER_FORMATS};
use super::ticks::{linear_ticks, AxisMap, AxisScale};
use super::PlotError;
use crate::mesh::{cross, dot, norm, sub};

/// Fraction of the cell width spanned by the diameter of the largest
/// bounding sphere (the rest is a margin for markers near the silhouette).
pub(crate) const FILL: f64 = 0.92;
/// Share of the light that reaches every pixel regardless of orientation;
/// with [`DIFFUSE`] it sums to 1, so a face looking at the light shows its
/// base colour unchanged.
pub(crate) const AMBIENT: f64 = 0.42;
/// Share of the light that follows Lambert's cosine law.
pub(crate) const DIFFUSE: f64 = 1.0 - AMBIENT;
/// Corner normals farther than this from the face normal are replaced by it
/// (degrees): the crease angle that separates smooth from sharp edges.
pub(crate) const CREASE_DEG: f64 = 40.0;
/// Base colour of surfaces without values and of non-finite values: a
/// neutral light grey, unlike any colour of the map.
pub(crate) const PLAIN: Rgb = [205, 205, 205];
/// How much nearer (in pixels of depth at the figure's scale) a surface may
/// be than a marker before it hides the marker.
pub(crate) const MARKER_DEPTH_TOL_PX: f64 = 3.0;

/// Gap between cells, horizontally and vertically.
const CELL_GAP: i32 = 12;
/// Frame colour around each cell: light, so it separates cells without
/// competing with the surfaces.
const CELL_FRAME: Rgb = [200, 200, 200];
const COLORBAR_W: i32 = 20;
const COLORBAR_GAP: i32 = 24;
/// Diameter of a marker's coloured disc, and the width of its dark outline.
const MARKER_SIZE: f64 = 12.0;
const MARKER_OUTLINE: f64 = 1.5;
/// Refuse figures beyond this many pixels (as the spectrograms do).
const MAX_PIXELS: i64 = 100_000_000;

/// One body: a triangle surface, optionally a scalar per vertex, and points
/// to mark on it.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfacePanel {
    /// Shown above the panel's column (may be empty).
    pub title: String,
    /// Vertex positions, in any length unit (the same for all panels of a
    /// figure, since they share one scale).
    pub vertices: Vec<[f64; 3]>,
    /// Three 0-based vertex indices per triangle. Counter-clockwise seen from
    /// outside is expected (it makes the smooth normals agree), but back
    /// faces are drawn too, so an inconsistent orientation only loses some
    /// smoothness.
    pub triangles: Vec<[usize; 3]>,
    /// One value per vertex, coloured on the figure's shared scale;
    /// `None` draws the surface in plain grey.
    pub values: Option<Vec<f64>>,
    pub markers: Vec<SurfaceMarker>,
}

impl SurfacePanel {
    /// A plain grey surface without markers.
    pub fn new(
        title: impl Into<String>,
        vertices: Vec<[f64; 3]>,
        triangles: Vec<[usize; 3]>,
    ) -> SurfacePanel {
        SurfacePanel {
            title: title.into(),
            vertices,
            triangles,
            values: None,
            markers: Vec::new(),
        }
    }
    pub fn with_values(mut self, values: Vec<f64>) -> SurfacePanel {
        self.values = Some(values);
        self
    }
    pub fn with_marker(mut self, marker: SurfaceMarker) -> SurfacePanel {
        self.markers.push(marker);
        self
    }
}

/// A point drawn over a surface (see the module docs for visible and hidden
/// markers).
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceMarker {
    /// In the units of the panel's vertices; normally a point on the surface.
    pub position: [f64; 3],
    /// Drawn beside the marker (may be empty).
    pub label: String,
    /// Fill colour, e.g. from [`super::PALETTE`].
    pub color: Rgb,
}

impl SurfaceMarker {
    pub fn new(position: [f64; 3], label: impl Into<String>, color: Rgb) -> SurfaceMarker {
        SurfaceMarker {
            position,
            label: label.into(),
            color,
        }
    }
}

/// A direction to look from (see the module docs for the angles).
#[derive(Clone, Debug, PartialEq)]
pub struct View {
    pub azimuth_deg: f64,
    pub elevation_deg: f64,
    /// Shown left of the view's row (may be empty).
    pub label: String,
}

impl View {
    /// A view labelled with its angles, e.g. "az 30°, el 20°".
    pub fn new(azimuth_deg: f64, elevation_deg: f64) -> View {
        View {
            azimuth_deg,
            elevation_deg,
            label: format!("az {azimuth_deg}°, el {elevation_deg}°"),
        }
    }
    pub fn labelled(azimuth_deg: f64, elevation_deg: f64, label: impl Into<String>) -> View {
        View {
            azimuth_deg,
            elevation_deg,
            label: label.into(),
        }
    }
}

/// A grid of surfaces, see [`surface_png`]: one column per panel, one row per
/// view.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceFigure {
    /// Shown centred above everything (may be empty).
    pub title: String,
    pub panels: Vec<SurfacePanel>,
    pub views: Vec<View>,
    /// Label of the colour bar, e.g. "log-likelihood"; the bar is drawn only
    /// when some panel has values.
    pub value_label: String,
    /// Bottom and top of the colour scale; default: the smallest and largest
    /// finite value of all panels. Values outside it take the end colours.
    pub value_range: Option<(f64, f64)>,
    /// Side of each square cell in pixels; the figure adds margins, labels
    /// and the colour bar.
    pub panel_size: u32,
    /// Size of text, margins and markers (1 = 15 px per em labels), like a
    /// DPI setting; the cells keep their pixel size.
    pub scale: f64,
}

impl SurfaceFigure {
    /// Defaults: one view from azimuth 30°, elevation 25°; automatic value
    /// range; 360 px cells.
    pub fn new(title: impl Into<String>, panels: Vec<SurfacePanel>) -> SurfaceFigure {
        SurfaceFigure {
            title: title.into(),
            panels,
            views: vec![View::new(30.0, 25.0)],
            value_label: String::new(),
            value_range: None,
            panel_size: 360,
            scale: 1.0,
        }
    }
}

/// Orthographic camera of one cell: world point → canvas pixel and depth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Camera {
    pub right: [f64; 3],
    pub up: [f64; 3],
    /// Unit vector from the body towards the viewer.
    pub toward: [f64; 3],
    /// World point drawn at `origin`.
    pub centre: [f64; 3],
    /// Pixels per world unit.
    pub scale: f64,
    /// Canvas coordinates (continuous) of `centre`.
    pub origin: (f64, f64),
}

impl Camera {
    pub(crate) fn new(view: &View, centre: [f64; 3], scale: f64, origin: (f64, f64)) -> Camera {
        let (a, e) = (
            view.azimuth_deg.to_radians(),
            view.elevation_deg.to_radians(),
        );
        let toward = [e.cos() * a.cos(), e.cos() * a.sin(), e.sin()];
        let right = [-a.sin(), a.cos(), 0.0];
        let up = cross(toward, right);
        Camera {
            right,
            up,
            toward,
            centre,
            scale,
            origin,
        }
    }

    /// Canvas position `(x, y)` (continuous, y down) and depth (world units,
    /// larger is nearer) of world point `p`.
    pub(crate) fn project(&self, p: [f64; 3]) -> [f64; 3] {
        let q = sub(p, self.centre);
        [
            self.origin.0 + self.scale * dot(q, self.right),
            self.origin.1 - self.scale * dot(q, self.up),
            dot(q, self.toward),
        ]
    }

    /// Unit direction towards the light: from the eye, tilted up and to the
    /// left so that relief reads as lit from the top left.
    pub(crate) fn light(&self) -> [f64; 3] {
        let l = [0, 1, 2].map(|k| self.toward[k] + 0.45 * self.up[k] - 0.3 * self.right[k]);
        let n = norm(l);
        l.map(|c| c / n)
    }
}

/// `AMBIENT + DIFFUSE · |n · l|` for unit vectors `n` and `l`.
pub(crate) fn shade(n: [f64; 3], l: [f64; 3]) -> f64 {
    AMBIENT + DIFFUSE * dot(n, l).abs().min(1.0)
}

/// `color` darkened by `shade` (0..=1).
pub(crate) fn shaded(color: Rgb, shade: f64) -> Rgb {
    color.map(|c| (c as f64 * shade).round().clamp(0.0, 255.0) as u8)
}

/// A cell being rasterised: depth and colour per pixel of `rect` (canvas
/// coordinates); `None` where no triangle covers the pixel.
pub(crate) struct DepthImage {
    pub rect: PixelRect,
    pub depth: Vec<f64>,
    pub color: Vec<Option<Rgb>>,
}

impl DepthImage {
    pub(crate) fn new(rect: PixelRect) -> DepthImage {
        let n = rect.width() as usize * rect.height() as usize;
        DepthImage {
            rect,
            depth: vec![f64::NEG_INFINITY; n],
            color: vec![None; n],
        }
    }

    fn index(&self, x: i32, y: i32) -> Option<usize> {
        self.rect.contains(x, y).then(|| {
            (y - self.rect.y0) as usize * self.rect.width() as usize + (x - self.rect.x0) as usize
        })
    }

    /// Depth of the surface at pixel `(x, y)` (canvas coordinates); `-inf`
    /// where there is none or outside the cell.
    pub(crate) fn depth_at(&self, x: i32, y: i32) -> f64 {
        self.index(x, y)
            .map_or(f64::NEG_INFINITY, |i| self.depth[i])
    }

    /// Rasterises one triangle: screen corners `s` (x, y, depth), per-corner
    /// unit normals `normals` and values `values` (NaN where there are none).
    /// `base` turns an interpolated value into the unshaded colour. A pixel
    /// is covered when its centre lies inside the triangle or on its edges
    /// (a 1e-9 slack in the barycentric weights closes cracks between
    /// neighbours from rounding), and written when nearer than what it holds.
    pub(crate) fn triangle(
        &mut self,
        s: [[f64; 3]; 3],
        normals: [[f64; 3]; 3],
        values: [f64; 3],
        light: [f64; 3],
        base: &dyn Fn(f64) -> Rgb,
    ) {
        let [a, b, c] = s;
        let area2 = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
        // Edge-on triangles cover no pixel centre (and would divide by zero).
        if !(area2.abs() > 1e-12) {
            return;
        }
        // Pixels whose centres (x + 0.5, y + 0.5) fall in the bounding box.
        let r = self.rect;
        let (xs, ys) = ([a[0], b[0], c[0]], [a[1], b[1], c[1]]);
        let lo =
            |v: [f64; 3], min: i32| (v[0].min(v[1]).min(v[2]) - 0.5).ceil().max(min as f64) as i32;
        let hi =
            |v: [f64; 3], max: i32| (v[0].max(v[1]).max(v[2]) - 0.5).floor().min(max as f64) as i32;
        let (x0, x1) = (lo(xs, r.x0), hi(xs, r.x1 - 1));
        let (y0, y1) = (lo(ys, r.y0), hi(ys, r.y1 - 1));
        let all_finite = values.iter().all(|v| v.is_finite());
        const SLACK: f64 = -1e-9;
        for y in y0..=y1 {
            let py = y as f64 + 0.5;
            for x in x0..=x1 {
                let px = x as f64 + 0.5;
                // Barycentric weights from the signed sub-areas.
                let w0 = ((b[0] - px) * (c[1] - py) - (b[1] - py) * (c[0] - px)) / area2;
                let w1 = ((c[0] - px) * (a[1] - py) - (c[1] - py) * (a[0] - px)) / area2;
                let w2 = 1.0 - w0 - w1;
                if w0 < SLACK || w1 < SLACK || w2 < SLACK {
                    continue;
                }
                let z = w0 * a[2] + w1 * b[2] + w2 * c[2];
                let i = (y - r.y0) as usize * r.width() as usize + (x - r.x0) as usize;
                if !(z > self.depth[i]) {
                    continue;
                }
                let w = [w0, w1, w2];
                let v = if all_finite {
                    w0 * values[0] + w1 * values[1] + w2 * values[2]
                } else {
                    let k = (0..3).fold(0, |k, j| if w[j] > w[k] { j } else { k });
                    values[k]
                };
                let n =
                    [0, 1, 2].map(|k| w0 * normals[0][k] + w1 * normals[1][k] + w2 * normals[2][k]);
                let len = norm(n);
                // The corner normals all lie within CREASE_DEG of the face
                // normal (see corner_normals), so their blend cannot vanish
                // on a face with area; the guard is for one without.
                let s = if len > 1e-12 {
                    shade(n.map(|c| c / len), light)
                } else {
                    1.0
                };
                self.depth[i] = z;
                self.color[i] = Some(shaded(base(v), s));
            }
        }
    }
}

/// Per triangle, per corner, the unit normal to shade with: the vertex normal
/// where it is within [`CREASE_DEG`] of the face normal, else the face normal
/// (see the module docs). A degenerate triangle gets zero normals.
pub(crate) fn corner_normals(
    vertices: &[[f64; 3]],
    triangles: &[[usize; 3]],
) -> Vec<[[f64; 3]; 3]> {
    let face: Vec<[f64; 3]> = triangles
        .iter()
        .map(|t| {
            cross(
                sub(vertices[t[1]], vertices[t[0]]),
                sub(vertices[t[2]], vertices[t[0]]),
            )
        })
        .collect();
    let unit = |a: [f64; 3]| {
        let n = norm(a);
        if n > 0.0 {
            a.map(|c| c / n)
        } else {
            [0.0; 3]
        }
    };
    // Angle-weighted vertex normals.
    let mut vertex = vec![[0.0; 3]; vertices.len()];
    for (t, f) in triangles.iter().zip(&face) {
        let f = unit(*f);
        for j in 0..3 {
            let p = vertices[t[j]];
            let (e1, e2) = (
                unit(sub(vertices[t[(j + 1) % 3]], p)),
                unit(sub(vertices[t[(j + 2) % 3]], p)),
            );
            let angle = dot(e1, e2).clamp(-1.0, 1.0).acos();
            for k in 0..3 {
                vertex[t[j]][k] += angle * f[k];
            }
        }
    }
    let vertex: Vec<[f64; 3]> = vertex.into_iter().map(unit).collect();
    let cos_crease = CREASE_DEG.to_radians().cos();
    triangles
        .iter()
        .zip(&face)
        .map(|(t, f)| {
            let f = unit(*f);
            t.map(|v| {
                if dot(vertex[v], f) >= cos_crease {
                    vertex[v]
                } else {
                    f
                }
            })
        })
        .collect()
}

/// Where everything landed; the tests project points through the cameras.
#[derive(Clone, Debug)]
// Only the tests read the fields; rendering just fills them in.
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) struct SurfaceLayout {
    /// `cells[view][panel]`: the cell's pixels and its camera.
    pub cells: Vec<Vec<(PixelRect, Camera)>>,
    /// Pixels per world unit, shared by all cells.
    pub scale: f64,
    /// The colour bar and its value axis, when some panel has values.
    pub colorbar: Option<(PixelRect, AxisMap)>,
    /// Per cell (same indexing as `cells`), per marker: drawn as visible?
    pub marker_visible: Vec<Vec<Vec<bool>>>,
}

/// Renders `fig` and writes it to `path` as a PNG, atomically. Nothing is
/// written if the figure is invalid (see [`PlotError::InvalidInput`]).
pub fn surface_png(path: &Path, fig: &SurfaceFigure) -> Result<(), PlotError> {
    ImageFormat::for_path(path, RASTER_FORMATS)?;
    let (canvas, _) = render_surface(path, fig)?;
    canvas.write_png(path)
}

/// "panel 2 ('after')" or "panel 2".
fn panel_name(k: usize, p: &SurfacePanel) -> String {
    if p.title.is_empty() {
        format!("panel {k}")
    } else {
        format!("panel {k} ('{}')", p.title)
    }
}

/// Checks `fig`; returns the colour-scale range, if some panel has values.
fn validate(path: &Path, fig: &SurfaceFigure) -> Result<Option<(f64, f64)>, PlotError> {
    let bad = |reason: String| PlotError::InvalidInput {
        path: path.to_path_buf(),
        reason,
    };
    if fig.panels.is_empty() {
        return Err(bad("surface figure has no panels".into()));
    }
    if fig.views.is_empty() {
        return Err(bad("surface figure has no views".into()));
    }
    if !(32..=4096).contains(&fig.panel_size) {
        return Err(bad(format!(
            "panel size {} px is outside 32..=4096",
            fig.panel_size
        )));
    }
    for (k, v) in fig.views.iter().enumerate() {
        if !(v.azimuth_deg.is_finite() && v.elevation_deg.is_finite()) {
            return Err(bad(format!(
                "view {k}: azimuth {}° / elevation {}° must be finite",
                v.azimuth_deg, v.elevation_deg
            )));
        }
    }
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut any_values = false;
    for (k, p) in fig.panels.iter().enumerate() {
        let name = panel_name(k, p);
        let n = p.vertices.len();
        if p.triangles.is_empty() {
            return Err(bad(format!("{name} has no triangles")));
        }
        if let Some((i, v)) = p
            .vertices
            .iter()
            .enumerate()
            .find(|(_, v)| v.iter().any(|c| !c.is_finite()))
        {
            return Err(bad(format!("{name}: vertex {i} at {v:?} is not finite")));
        }
        for (t, tri) in p.triangles.iter().enumerate() {
            if let Some(&v) = tri.iter().find(|&&v| v >= n) {
                return Err(bad(format!(
                    "{name}: triangle {t} uses vertex {v}, but the panel has {n} vertices"
                )));
            }
        }
        if let Some(values) = &p.values {
            if values.len() != n {
                return Err(bad(format!(
                    "{name}: {} values for {n} vertices",
                    values.len()
                )));
            }
            any_values = true;
            for &v in values.iter().filter(|v| v.is_finite()) {
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
        for (m, mk) in p.markers.iter().enumerate() {
            if mk.position.iter().any(|c| !c.is_finite()) {
                return Err(bad(format!(
                    "{name}: marker {m} ('{}') at {:?} is not finite",
                    mk.label, mk.position
                )));
            }
        }
    }
    if !any_values {
        return Ok(None);
    }
    let (lo, hi) = match fig.value_range {
        Some(r) => r,
        None if lo <= hi => {
            if lo < hi {
                (lo, hi)
            } else {
                // One value everywhere: centre it on the scale.
                let d = if lo == 0.0 { 1.0 } else { 0.1 * lo.abs() };
                (lo - d, hi + d)
            }
        }
        None => {
            return Err(bad(
                "no finite value in any panel (and no value_range given)".into(),
            ))
        }
    };
    if !(lo.is_finite() && hi.is_finite() && (hi - lo).is_finite() && lo < hi) {
        return Err(bad(format!(
            "value range {lo} .. {hi} must be finite and increasing"
        )));
    }
    Ok(Some((lo, hi)))
}

/// Bounding-box centre of `vertices` and the distance from it to the
/// farthest vertex.
fn bounding_sphere(vertices: &[[f64; 3]]) -> ([f64; 3], f64) {
    let (lo, hi) = crate::mesh::bounding_box_of(vertices);
    let c = [0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k]));
    let r = vertices
        .iter()
        .map(|&v| norm(sub(v, c)))
        .fold(0.0, f64::max);
    (c, r)
}

/// Renders the figure into a canvas (used by [`surface_png`] and the tests,
/// which project points through the returned cameras).
pub(crate) fn render_surface(
    path: &Path,
    fig: &SurfaceFigure,
) -> Result<(Canvas, SurfaceLayout), PlotError> {
    let range = validate(path, fig)?;
    let spheres: Vec<([f64; 3], f64)> = fig
        .panels
        .iter()
        .map(|p| bounding_sphere(&p.vertices))
        .collect();
    let r_max = spheres.iter().map(|s| s.1).fold(0.0, f64::max);
    if !(r_max > 0.0 && r_max.is_finite()) {
        return Err(PlotError::InvalidInput {
            path: path.to_path_buf(),
            reason: format!("every panel has zero (or unrepresentable) extent (radius {r_max})"),
        });
    }
    let ps = fig.panel_size as i32;
    let scale = FILL * 0.5 * ps as f64 / r_max;
    // The cells alone must fit the pixel budget, checked in i64 before the
    // layout below does its arithmetic in i32.
    let cells_px = (fig.panels.len() as i64)
        .saturating_mul(fig.views.len() as i64)
        .saturating_mul(ps as i64 * ps as i64);
    if cells_px > MAX_PIXELS {
        return Err(PlotError::InvalidInput {
            path: path.to_path_buf(),
            reason: format!(
                "{} panels x {} views of {ps} px would exceed {MAX_PIXELS} pixels; use fewer or smaller panels",
                fig.panels.len(),
                fig.views.len()
            ),
        });
    }

    // Layout, top to bottom: title, panel titles, rows of cells. Left to
    // right: rotated view labels, columns of cells, colour bar, its tick
    // labels and its rotated label.
    let n_cols = fig.panels.len() as i32;
    let n_rows = fig.views.len() as i32;
    let look = Look::new(fig.scale);
    let (text_h, margin) = (look.text_h(), look.margin());
    let title_h = if fig.title.is_empty() {
        0
    } else {
        look.title_h() + look.px(16.0)
    };
    let col_title_h = if fig.panels.iter().any(|p| !p.title.is_empty()) {
        text_h + look.px(14.0)
    } else {
        0
    };
    let row_label_w = if fig.views.iter().any(|v| !v.label.is_empty()) {
        text_h + look.descent() + look.px(12.0)
    } else {
        0
    };
    let grid_x0 = margin + row_label_w;
    let grid_y0 = margin + title_h + col_title_h;
    let grid_x1 = grid_x0 + n_cols * ps + (n_cols - 1) * CELL_GAP;
    let grid_y1 = grid_y0 + n_rows * ps + (n_rows - 1) * CELL_GAP;
    let bar = range.map(|(lo, hi)| {
        let cb = PixelRect::new(
            grid_x1 + COLORBAR_GAP,
            grid_y0,
            grid_x1 + COLORBAR_GAP + COLORBAR_W,
            grid_y1,
        );
        let map = AxisMap {
            scale: AxisScale::Linear,
            lo,
            hi,
            px_lo: cb.y1 as f64,
            px_hi: cb.y0 as f64,
        };
        let ticks = linear_ticks(lo, hi, axes::tick_budget(cb.height(), look.px(48.0)));
        (cb, map, ticks)
    });
    let mut width = grid_x1 + margin;
    if let Some((cb, _, ticks)) = &bar {
        let label_w = if fig.value_label.is_empty() {
            0
        } else {
            look.label_gap() + look.px(6.0) + text_h + look.descent()
        };
        width = cb.x1
            + look.rule()
            + look.tick()
            + look.label_gap()
            + look.max_label_w(ticks)
            + label_w
            + margin;
    }
    // The title may be wider than the grid.
    width = width.max(2 * margin + text_size(&fig.title, &look.title_style()).0 as i32);
    let height = grid_y1 + margin;
    if width as i64 * height as i64 > MAX_PIXELS {
        return Err(PlotError::InvalidInput {
            path: path.to_path_buf(),
            reason: format!("figure would be {width}x{height} px; use fewer or smaller panels"),
        });
    }

    let mut c = Canvas::new(width as u32, height as u32, axes::BACKGROUND);
    let (lo, hi) = range.unwrap_or((0.0, 1.0));
    let value_color = |v: f64| {
        if v.is_finite() {
            colormap((v - lo) / (hi - lo))
        } else {
            PLAIN
        }
    };
    let plain_color = |_: f64| PLAIN;
    let normals: Vec<Vec<[[f64; 3]; 3]>> = fig
        .panels
        .iter()
        .map(|p| corner_normals(&p.vertices, &p.triangles))
        .collect();

    let mut layout = SurfaceLayout {
        cells: Vec::new(),
        scale,
        colorbar: bar.as_ref().map(|(r, m, _)| (*r, *m)),
        marker_visible: Vec::new(),
    };
    for (row, view) in fig.views.iter().enumerate() {
        let y0 = grid_y0 + row as i32 * (ps + CELL_GAP);
        let mut cells = Vec::new();
        let mut visible_row = Vec::new();
        for (col, p) in fig.panels.iter().enumerate() {
            let x0 = grid_x0 + col as i32 * (ps + CELL_GAP);
            let rect = PixelRect::new(x0, y0, x0 + ps, y0 + ps);
            let origin = (x0 as f64 + 0.5 * ps as f64, y0 as f64 + 0.5 * ps as f64);
            let cam = Camera::new(view, spheres[col].0, scale, origin);
            let light = cam.light();
            let mut img = DepthImage::new(rect);
            let screen: Vec<[f64; 3]> = p.vertices.iter().map(|&v| cam.project(v)).collect();
            let base: &dyn Fn(f64) -> Rgb = if p.values.is_some() {
                &value_color
            } else {
                &plain_color
            };
            for (t, tri) in p.triangles.iter().enumerate() {
                let vals = match &p.values {
                    Some(v) => tri.map(|i| v[i]),
                    None => [f64::NAN; 3],
                };
                img.triangle(tri.map(|i| screen[i]), normals[col][t], vals, light, base);
            }
            blit(&mut c, &img);
            c.stroke_rect(rect.inflate(1), CELL_FRAME, 1);
            visible_row.push(draw_markers(&mut c, &look, &img, &cam, &p.markers));
            cells.push((rect, cam));
        }
        if !view.label.is_empty() {
            c.text(
                margin,
                y0 + ps / 2,
                &view.label,
                &look.style().align(HAlign::Center, VAlign::Top).rotated(),
            );
        }
        layout.cells.push(cells);
        layout.marker_visible.push(visible_row);
    }
    for (col, p) in fig.panels.iter().enumerate() {
        if !p.title.is_empty() {
            let x = grid_x0 + col as i32 * (ps + CELL_GAP) + ps / 2;
            c.text(
                x,
                grid_y0 - look.px(10.0),
                &p.title,
                &look.style().align(HAlign::Center, VAlign::Bottom).bold(),
            );
        }
    }

    // Colour bar: one row per pixel, coloured by the value at its centre
    // (unshaded: the bar is the key, the surfaces are darkened by light).
    if let Some((cb, map, ticks)) = &bar {
        for y in cb.y0..cb.y1 {
            let col = value_color(map.from_px(y as f64 + 0.5));
            c.fill_rect(PixelRect::new(cb.x0, y, cb.x1, y + 1), col);
        }
        axes::frame(&mut c, &look, *cb);
        let rule = look.rule();
        axes::y_axis_at(&mut c, &look, cb.x1 + rule - 1, map, ticks, true, false);
        if !fig.value_label.is_empty() {
            let x = cb.x1
                + rule
                + look.tick()
                + look.label_gap()
                + look.max_label_w(ticks)
                + look.label_gap()
                + look.px(6.0);
            c.text(
                x,
                (cb.y0 + cb.y1) / 2,
                &fig.value_label,
                &look.style().align(HAlign::Center, VAlign::Top).rotated(),
            );
        }
    }
    if !fig.title.is_empty() {
        c.text(
            width / 2,
            margin,
            &fig.title,
            &look.title_style().align(HAlign::Center, VAlign::Top),
        );
    }
    Ok((c, layout))
}

/// Copies the covered pixels of `img` into the canvas.
fn blit(c: &mut Canvas, img: &DepthImage) {
    let r = img.rect;
    for (i, col) in img.color.iter().enumerate() {
        if let Some(col) = col {
            let x = r.x0 + (i % r.width() as usize) as i32;
            let y = r.y0 + (i / r.width() as usize) as i32;
            c.put(x, y, *col);
        }
    }
}

/// Is a marker at canvas position `(x, y)` with depth `z` in front of the
/// surface (see the module docs)?
fn marker_visible(img: &DepthImage, x: f64, y: f64, z: f64, tol: f64) -> bool {
    let (i, j) = (x.floor() as i32, y.floor() as i32);
    // Some pixel within one of the marker's must hold nothing nearer than
    // `tol` in front of it (empty pixels hold -inf).
    (-1..=1).any(|dy| (-1..=1).any(|dx| img.depth_at(i + dx, j + dy) <= z + tol))
}

/// Draws the markers of one cell, clipped to it: hidden ones first (hollow),
/// then visible ones, then all labels. A marker whose centre projects outside
/// the cell (not on its panel's body) is left out, label and all. Returns
/// which were drawn as visible.
fn draw_markers(
    c: &mut Canvas,
    look: &Look,
    img: &DepthImage,
    cam: &Camera,
    markers: &[SurfaceMarker],
) -> Vec<bool> {
    let tol = MARKER_DEPTH_TOL_PX / cam.scale;
    let placed: Vec<([f64; 3], bool)> = markers
        .iter()
        .map(|m| {
            let s = cam.project(m.position);
            (s, marker_visible(img, s[0], s[1], s[2], tol))
        })
        .collect();
    let cell = img.rect;
    let in_cell = |s: [f64; 3]| {
        s[0] >= cell.x0 as f64
            && s[0] < cell.x1 as f64
            && s[1] >= cell.y0 as f64
            && s[1] < cell.y1 as f64
    };
    let drawn: Vec<usize> = (0..markers.len())
        .filter(|&k| in_cell(placed[k].0))
        .collect();
    let hidden = drawn.iter().copied().filter(|&k| !placed[k].1);
    let visible = drawn.iter().copied().filter(|&k| placed[k].1);
    c.set_clip(Some(cell));
    let r = MARKER_SIZE / 2.0;
    for (m, s) in hidden.clone().map(|k| (&markers[k], placed[k].0)) {
        // A closed ring on the disc's rim: dark, with the colour inside it.
        let ring: Vec<(f64, f64)> = (0..=48)
            .map(|k| {
                let a = k as f64 / 48.0 * std::f64::consts::TAU;
                (s[0] + (r - 0.5) * a.cos(), s[1] + (r - 0.5) * a.sin())
            })
            .collect();
        c.polyline(&ring, axes::INK, 2.0 + 2.0 * MARKER_OUTLINE);
        c.polyline(&ring, m.color, 2.0);
    }
    for (m, s) in visible.clone().map(|k| (&markers[k], placed[k].0)) {
        c.marker(
            s[0],
            s[1],
            Marker::Circle,
            MARKER_SIZE + 2.0 * MARKER_OUTLINE,
            axes::INK,
        );
        c.marker(s[0], s[1], Marker::Circle, MARKER_SIZE, m.color);
    }
    // Labels, visible markers' first so they get the best places: each takes
    // the first of right, left, then those one row lower or higher, that
    // stays inside the cell and clear of the labels placed so far (the first
    // that stays inside if none is clear), so nearby candidates stay legible.
    let inside =
        |b: &PixelRect| b.x0 >= cell.x0 && b.x1 <= cell.x1 && b.y0 >= cell.y0 && b.y1 <= cell.y1;
    let mut taken: Vec<PixelRect> = Vec::new();
    for k in visible.chain(hidden) {
        let (m, s) = (&markers[k], placed[k].0);
        if m.label.is_empty() {
            continue;
        }
        let (w, h) = text_size(&m.label, &look.style());
        let (w, h) = (w as i32, h as i32);
        let gap = (r + MARKER_OUTLINE + 4.0) as i32;
        let (x, y) = (s[0].floor() as i32, s[1].floor() as i32);
        let desc = look.descent();
        let row = h + desc + 6;
        let places = [0, row, -row]
            .into_iter()
            .flat_map(|dy| [(x + gap, y - h / 2 + dy), (x - gap - w, y - h / 2 + dy)]);
        // A light box behind the text keeps it legible on dark map colours
        // (with room below for the descenders).
        let boxed =
            |(tx, ty): (i32, i32)| PixelRect::new(tx - 3, ty - 3, tx + w + 3, ty + h + desc + 2);
        let clear = |b: &PixelRect| {
            taken.iter().all(|t| {
                let i = t.intersect(b);
                i.width() == 0 || i.height() == 0
            })
        };
        let (tx, ty) = places
            .clone()
            .find(|&p| inside(&boxed(p)) && clear(&boxed(p)))
            .or_else(|| places.clone().find(|&p| inside(&boxed(p))))
            .unwrap_or((x + gap, y - h / 2));
        let bx = boxed((tx, ty));
        taken.push(bx);
        let bx = bx.intersect(&cell);
        for py in bx.y0..bx.y1 {
            for px in bx.x0..bx.x1 {
                c.blend(px, py, axes::BACKGROUND, 0.8);
            }
        }
        c.text(tx, ty, &m.label, &look.style());
    }
    c.set_clip(None);
    (0..markers.len())
        .map(|k| placed[k].1 && in_cell(placed[k].0))
        .collect()
}

#[cfg(test)]
mod tests;
