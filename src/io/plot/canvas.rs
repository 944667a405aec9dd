//! An RGB raster with the handful of drawing operations the figures need.
//!
//! Coordinates: pixel `(i, j)` is column `i` from the left, row `j` from the
//! top. Integer operations (rectangles, text) address whole pixels.
//! Anti-aliased operations (lines, markers) take continuous coordinates in
//! which pixel `(i, j)` covers `[i, i+1) × [j, j+1)`, so its centre is
//! `(i + 0.5, j + 0.5)`; a 1 px line along `y = j + 0.5` is exactly row `j`.
//!
//! Every operation respects the clip rectangle (the whole canvas unless
//! [`Canvas::set_clip`] narrowed it), which is how data stay inside the plot
//! frame.

use std::io::BufWriter;
use std::path::Path;

use super::font;
use super::PlotError;
use ab_glyph::Font as _;

/// 8-bit sRGB colour.
pub type Rgb = [u8; 3];

/// A half-open pixel rectangle `[x0, x1) × [y0, y1)`; empty when `x1 <= x0`
/// or `y1 <= y0`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PixelRect {
    pub x0: i32,
    pub y0: i32,
    pub x1: i32,
    pub y1: i32,
}

impl PixelRect {
    pub fn new(x0: i32, y0: i32, x1: i32, y1: i32) -> PixelRect {
        PixelRect { x0, y0, x1, y1 }
    }
    pub fn width(&self) -> i32 {
        (self.x1 - self.x0).max(0)
    }
    pub fn height(&self) -> i32 {
        (self.y1 - self.y0).max(0)
    }
    pub fn contains(&self, x: i32, y: i32) -> bool {
        x >= self.x0 && x < self.x1 && y >= self.y0 && y < self.y1
    }
    pub fn intersect(&self, o: &PixelRect) -> PixelRect {
        PixelRect {
            x0: self.x0.max(o.x0),
            y0: self.y0.max(o.y0),
            x1: self.x1.min(o.x1),
            y1: self.y1.min(o.y1),
        }
    }
    /// Grown by `d` pixels on every side (shrunk for negative `d`).
    pub fn inflate(&self, d: i32) -> PixelRect {
        PixelRect::new(self.x0 - d, self.y0 - d, self.x1 + d, self.y1 + d)
    }
}

/// Marker shapes for scatter points and the legend.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Marker {
    Circle,
    Square,
    Diamond,
    /// A diagonal cross (×).
    Cross,
    /// An upright cross (+).
    Plus,
}

/// Horizontal anchor of a text box (along the reading direction when rotated).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HAlign {
    Left,
    Center,
    Right,
}

/// Vertical anchor of a text box, measured on the cap height (descenders
/// hang below `Bottom`, so `Bottom` is the baseline).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VAlign {
    Top,
    Middle,
    Bottom,
}

/// How text is drawn by [`Canvas::text`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TextStyle {
    /// Em size in pixels (a capital is about 0.73 of it).
    pub size: f32,
    pub color: Rgb,
    pub halign: HAlign,
    pub valign: VAlign,
    /// Rotated 90° counter-clockwise (reads bottom to top, as y-axis labels do).
    pub rotated: bool,
    /// The bold face, for titles.
    pub bold: bool,
}

impl TextStyle {
    /// `size` (px per em) and `color`, anchored at the top-left corner, upright, regular.
    pub fn new(size: f32, color: Rgb) -> TextStyle {
        TextStyle {
            size,
            color,
            halign: HAlign::Left,
            valign: VAlign::Top,
            rotated: false,
            bold: false,
        }
    }
    pub fn align(mut self, halign: HAlign, valign: VAlign) -> TextStyle {
        self.halign = halign;
        self.valign = valign;
        self
    }
    pub fn rotated(mut self) -> TextStyle {
        self.rotated = true;
        self
    }
    pub fn bold(mut self) -> TextStyle {
        self.bold = true;
        self
    }
    pub(crate) fn face(&self) -> font::Face {
        if self.bold {
            font::Face::Bold
        } else {
            font::Face::Regular
        }
    }
}

/// Width (the advance, rounded up) and cap height in pixels of `text` drawn
/// upright in `style` (a rotated text box is the same with the two swapped).
/// Descenders hang below the box, round letters and accents may overshoot it
/// by a pixel.
pub fn text_size(text: &str, style: &TextStyle) -> (u32, u32) {
    let line = font::layout(text, style.size, style.face());
    (
        line.width.ceil().max(0.0) as u32,
        line.cap_height().round().max(1.0) as u32,
    )
}

/// Where the box of `text` lies for the anchor `(x, y)`, and the offsets
/// `(du, dv)` of the anchor inside the upright box.
pub(crate) fn text_box(x: i32, y: i32, w: i32, h: i32, style: &TextStyle) -> (PixelRect, i32, i32) {
    // Offsets of the anchor inside the upright box (u along the text,
    // v down from the cap line).
    let du = match style.halign {
        HAlign::Left => 0,
        HAlign::Center => w / 2,
        HAlign::Right => w,
    };
    let dv = match style.valign {
        VAlign::Top => 0,
        VAlign::Middle => h / 2,
        VAlign::Bottom => h,
    };
    let rect = if style.rotated {
        // Upright pixel (u, v) relative to the anchor lands on screen pixel
        // (x + v, y - u): reading upwards, glyph rows running to +x.
        PixelRect::new(x - dv, y - (w - du) + 1, x - dv + h, y + du + 1)
    } else {
        PixelRect::new(x - du, y - dv, x - du + w, y - dv + h)
    };
    (rect, du, dv)
}

/// An 8-bit RGB image with a clip rectangle.
#[derive(Clone, Debug)]
pub struct Canvas {
    width: u32,
    height: u32,
    /// Row-major RGB triples, the layout PNG wants.
    data: Vec<u8>,
    clip: PixelRect,
}

impl Canvas {
    /// A `width × height` canvas filled with `background`.
    pub fn new(width: u32, height: u32, background: Rgb) -> Canvas {
        let mut c = Canvas {
            width,
            height,
            data: vec![0; width as usize * height as usize * 3],
            clip: PixelRect::new(0, 0, width as i32, height as i32),
        };
        c.fill(background);
        c
    }

    pub fn width(&self) -> u32 {
        self.width
    }
    pub fn height(&self) -> u32 {
        self.height
    }
    /// Row-major RGB bytes, 3 per pixel.
    pub fn data(&self) -> &[u8] {
        &self.data
    }
    /// The colour at `(x, y)`; panics outside the canvas.
    pub fn pixel(&self, x: u32, y: u32) -> Rgb {
        assert!(
            x < self.width && y < self.height,
            "pixel ({x}, {y}) outside canvas"
        );
        let i = (y as usize * self.width as usize + x as usize) * 3;
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }

    /// Every pixel set to `color`, regardless of the clip rectangle.
    pub fn fill(&mut self, color: Rgb) {
        for px in self.data.chunks_exact_mut(3) {
            px.copy_from_slice(&color);
        }
    }

    /// Restricts drawing to `rect` (intersected with the canvas); `None`
    /// restores the whole canvas.
    pub fn set_clip(&mut self, rect: Option<PixelRect>) {
        let full = PixelRect::new(0, 0, self.width as i32, self.height as i32);
        self.clip = rect.map_or(full, |r| r.intersect(&full));
    }
    pub fn clip(&self) -> PixelRect {
        self.clip
    }

    /// Sets one pixel if it is inside the clip rectangle.
    pub fn put(&mut self, x: i32, y: i32, color: Rgb) {
        if self.clip.contains(x, y) {
            let i = (y as usize * self.width as usize + x as usize) * 3;
            self.data[i..i + 3].copy_from_slice(&color);
        }
    }

    /// Mixes `color` into one pixel with opacity `alpha` (0..=1), if inside
    /// the clip rectangle. Mixing is in sRGB values: not photometrically
    /// exact, but edges of thin lines come out the way people expect.
    pub fn blend(&mut self, x: i32, y: i32, color: Rgb, alpha: f32) {
        if alpha <= 0.0 || !self.clip.contains(x, y) {
            return;
        }
        let a = alpha.min(1.0);
        let i = (y as usize * self.width as usize + x as usize) * 3;
        for (d, &c) in self.data[i..i + 3].iter_mut().zip(&color) {
            let old = *d as f32;
            *d = (old + (c as f32 - old) * a).round() as u8;
        }
    }

    /// Fills the pixels of `rect` (clipped).
    pub fn fill_rect(&mut self, rect: PixelRect, color: Rgb) {
        let r = rect.intersect(&self.clip);
        for y in r.y0..r.y1 {
            for x in r.x0..r.x1 {
                self.put(x, y, color);
            }
        }
    }

    /// Draws the outline of `rect`, `thickness` pixels wide, inside it.
    pub fn stroke_rect(&mut self, rect: PixelRect, color: Rgb, thickness: i32) {
        let t = thickness.max(1);
        let PixelRect { x0, y0, x1, y1 } = rect;
        self.fill_rect(PixelRect::new(x0, y0, x1, y0 + t), color);
        self.fill_rect(PixelRect::new(x0, y1 - t, x1, y1), color);
        self.fill_rect(PixelRect::new(x0, y0, x0 + t, y1), color);
        self.fill_rect(PixelRect::new(x1 - t, y0, x1, y1), color);
    }

    /// An anti-aliased line from `(x0, y0)` to `(x1, y1)` (continuous
    /// coordinates), `width` pixels wide with round ends.
    pub fn line(&mut self, x0: f64, y0: f64, x1: f64, y1: f64, color: Rgb, width: f64) {
        self.polyline(&[(x0, y0), (x1, y1)], color, width);
    }

    /// Anti-aliased connected segments through `points`, `width` pixels wide,
    /// with round joins. A non-finite point ends one run and starts the next
    /// (a gap), so callers can pass data with holes.
    ///
    /// Coverage is accumulated per pixel as the maximum over segments before
    /// blending once; blending each segment separately would darken the
    /// anti-aliased fringe wherever segments meet.
    pub fn polyline(&mut self, points: &[(f64, f64)], color: Rgb, width: f64) {
        let r = (width.max(0.5)) / 2.0;
        let pad = r + 2.0;
        // Bounding box of the finite points, limited to the clip rectangle.
        let clip = self.clip;
        let (mut bx0, mut by0, mut bx1, mut by1) = (
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        );
        for &(x, y) in points
            .iter()
            .filter(|(x, y)| x.is_finite() && y.is_finite())
        {
            bx0 = bx0.min(x);
            by0 = by0.min(y);
            bx1 = bx1.max(x);
            by1 = by1.max(y);
        }
        if !(bx0 <= bx1 && by0 <= by1) {
            return;
        }
        let bx0 = (bx0 - pad).floor().max(clip.x0 as f64) as i32;
        let by0 = (by0 - pad).floor().max(clip.y0 as f64) as i32;
        let bx1 = ((bx1 + pad).ceil().min(clip.x1 as f64) as i32).max(bx0);
        let by1 = ((by1 + pad).ceil().min(clip.y1 as f64) as i32).max(by0);
        let mask_rect = PixelRect::new(bx0, by0, bx1, by1);
        if mask_rect.width() == 0 || mask_rect.height() == 0 {
            return;
        }
        let mut mask = Coverage::new(mask_rect);
        let mut prev: Option<(f64, f64)> = None;
        for &p in points {
            if !(p.0.is_finite() && p.1.is_finite()) {
                prev = None;
                continue;
            }
            let a = prev.unwrap_or(p);
            mask.capsule(a, p, r);
            prev = Some(p);
        }
        mask.blend_into(self, color);
    }

    /// A filled, anti-aliased marker of overall size `size` pixels centred
    /// at `(x, y)` (continuous coordinates).
    pub fn marker(&mut self, x: f64, y: f64, marker: Marker, size: f64, color: Rgb) {
        self.any_marker(x, y, marker, size, color, false);
    }

    /// The outline of a marker (the inside left as it was), so a second
    /// series at the same points stays visible; crosses are strokes anyway
    /// and draw as [`Canvas::marker`] does.
    pub fn hollow_marker(&mut self, x: f64, y: f64, marker: Marker, size: f64, color: Rgb) {
        self.any_marker(x, y, marker, size, color, true);
    }

    fn any_marker(&mut self, x: f64, y: f64, marker: Marker, size: f64, color: Rgb, hollow: bool) {
        if !(x.is_finite() && y.is_finite()) {
            return;
        }
        let h = size.max(1.0) / 2.0;
        let rect = PixelRect::new(
            (x - h - 2.0).floor() as i32,
            (y - h - 2.0).floor() as i32,
            (x + h + 2.0).ceil() as i32,
            (y + h + 2.0).ceil() as i32,
        )
        .intersect(&self.clip);
        if rect.width() == 0 || rect.height() == 0 {
            return;
        }
        let mut mask = Coverage::new(rect);
        // A hollow marker is the band of the filled shape's signed distance
        // between -stroke and 0: the outline drawn just inside the edge.
        let stroke = marker_stroke(size);
        let ring = |sd: f64| {
            if hollow {
                (sd + stroke / 2.0).abs() - stroke / 2.0
            } else {
                sd
            }
        };
        match marker {
            Marker::Circle => mask.shape(|px, py| ring((px - x).hypot(py - y) - h)),
            Marker::Square => {
                // Squares and diamonds look larger than circles of the same
                // width; shrink them so mixed markers read as one size.
                let s = h * 0.85;
                mask.shape(|px, py| ring((px - x).abs().max((py - y).abs()) - s))
            }
            Marker::Diamond => {
                let s = h * 1.1;
                mask.shape(|px, py| {
                    ring(((px - x).abs() + (py - y).abs() - s) / std::f64::consts::SQRT_2)
                })
            }
            Marker::Cross | Marker::Plus => {
                let w = (size / 4.0).clamp(1.0, 3.0) / 2.0;
                for (a, b) in cross_arms(x, y, marker, size) {
                    mask.capsule(a, b, w);
                }
            }
        }
        mask.blend_into(self, color);
    }

    /// Like [`Canvas::polyline`], broken into dashes: `dash` holds the
    /// lengths in pixels of on, off, on, off, … along the line (empty: solid).
    pub fn dashed_polyline(&mut self, points: &[(f64, f64)], color: Rgb, width: f64, dash: &[f64]) {
        self.polyline(&dash_points(points, dash), color, width);
    }

    /// Draws `text` anchored at pixel `(x, y)` as `style` says, and returns
    /// the pixel box it occupies (cap height; descenders hang below it).
    /// Glyphs are anti-aliased: coverage is accumulated upright, then blended
    /// in (turned a quarter for rotated text), so only ink is drawn and the
    /// background shows between strokes.
    pub fn text(&mut self, x: i32, y: i32, text: &str, style: &TextStyle) -> PixelRect {
        let line = font::layout(text, style.size, style.face());
        let (w, h) = text_size(text, style);
        let (w, h) = (w as i32, h as i32);
        let (rect, du, dv) = text_box(x, y, w, h, style);
        // Upright coverage buffer, anchor-relative: u from -du - pad, v from
        // the ascender above the cap line to the descender below the baseline.
        let pad = 2 + (style.size / 8.0).ceil() as i32;
        let up = (line.ascent() - line.cap_height()).ceil().max(0.0) as i32 + pad;
        let down = line.descent().ceil() as i32 + pad;
        let (u0, v0) = (-du - pad, -dv - up);
        let (bw, bh) = (w + 2 * pad, h + up + down);
        if bw <= 0 || bh <= 0 || line.glyphs.is_empty() {
            return rect;
        }
        let mut cov = vec![0.0f32; bw as usize * bh as usize];
        let px_scale = style.size * font::face(line.face).font.height_unscaled()
            / font::face(line.face).units_per_em;
        let baseline = (h - dv - v0) as f32; // baseline row in buffer coordinates
        let ff = &font::face(line.face).font;
        for g in &line.glyphs {
            let glyph = g.id.with_scale_and_position(
                px_scale,
                ab_glyph::point((-du - u0) as f32 + g.x, baseline),
            );
            let Some(outlined) = ff.outline_glyph(glyph) else {
                continue;
            };
            let b = outlined.px_bounds();
            let (gx, gy) = (b.min.x as i32, b.min.y as i32);
            outlined.draw(|px, py, c| {
                let (bx, by) = (gx + px as i32, gy + py as i32);
                if bx >= 0 && by >= 0 && bx < bw && by < bh {
                    let i = by as usize * bw as usize + bx as usize;
                    cov[i] = (cov[i] + c).min(1.0);
                }
            });
        }
        for by in 0..bh {
            for bx in 0..bw {
                let c = cov[by as usize * bw as usize + bx as usize];
                if c <= 0.0 {
                    continue;
                }
                let (u, v) = (u0 + bx, v0 + by);
                let (sx, sy) = if style.rotated {
                    (x + v, y - u)
                } else {
                    (x + u, y + v)
                };
                self.blend(sx, sy, style.color, c);
            }
        }
        rect
    }

    /// Writes the canvas to `path` as an 8-bit RGB PNG, atomically (see
    /// [`crate::io::atomic`]): on error nothing is left at `path` or beside it.
    pub fn write_png(&self, path: &Path) -> Result<(), PlotError> {
        crate::io::atomic::replace_atomically(path, |tmp| {
            let file = std::fs::File::create(tmp).map_err(|source| PlotError::Fs {
                path: tmp.to_path_buf(),
                context: "creating temporary file".into(),
                source,
            })?;
            let png_err = |source| PlotError::Png {
                path: path.to_path_buf(),
                source,
            };
            let mut enc = png::Encoder::new(BufWriter::new(file), self.width, self.height);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            let mut writer = enc.write_header().map_err(png_err)?;
            writer.write_image_data(&self.data).map_err(png_err)?;
            // `finish` writes the end chunk and flushes the BufWriter with
            // error reporting (a plain drop would swallow a failed flush).
            writer.finish().map_err(png_err)
        })
    }
}

/// Stroke width of a hollow marker of overall size `size`.
pub(crate) fn marker_stroke(size: f64) -> f64 {
    (size / 6.0).clamp(1.5, 3.0)
}

/// The two strokes of a cross (×) or plus (+) marker of size `size` at `(x, y)`.
pub(crate) fn cross_arms(
    x: f64,
    y: f64,
    marker: Marker,
    size: f64,
) -> [((f64, f64), (f64, f64)); 2] {
    let h = size.max(1.0) / 2.0;
    if marker == Marker::Cross {
        let d = h * 0.8;
        [
            ((x - d, y - d), (x + d, y + d)),
            ((x - d, y + d), (x + d, y - d)),
        ]
    } else {
        [((x - h, y), (x + h, y)), ((x, y - h), (x, y + h))]
    }
}

/// `points` cut into dashes: the pieces drawn, separated by a non-finite
/// point (the gap [`Canvas::polyline`] understands). `dash` alternates on and
/// off lengths in pixels; the pattern runs on across vertices and across a
/// gap in the data. An empty or non-positive pattern returns the points as
/// they are.
pub(crate) fn dash_points(points: &[(f64, f64)], dash: &[f64]) -> Vec<(f64, f64)> {
    if dash.is_empty() || dash.iter().any(|d| !(d.is_finite() && *d > 0.0)) {
        return points.to_vec();
    }
    let gap = (f64::NAN, f64::NAN);
    let mut out = Vec::new();
    let (mut k, mut left) = (0usize, dash[0]);
    let mut prev: Option<(f64, f64)> = None;
    for &p in points {
        if !(p.0.is_finite() && p.1.is_finite()) {
            prev = None;
            out.push(gap);
            continue;
        }
        let Some(a) = prev else {
            if k % 2 == 0 {
                out.push(p);
            }
            prev = Some(p);
            continue;
        };
        let len = (p.0 - a.0).hypot(p.1 - a.1);
        let mut t = 0.0;
        while len - t > 1e-9 {
            let step = left.min(len - t);
            t += step;
            left -= step;
            let q = (a.0 + (p.0 - a.0) * t / len, a.1 + (p.1 - a.1) * t / len);
            if k % 2 == 0 {
                out.push(q);
            }
            if left <= 1e-9 {
                k = (k + 1) % dash.len();
                left = dash[k];
                if k % 2 == 0 {
                    out.push(q);
                } else {
                    out.push(gap);
                }
            }
        }
        prev = Some(p);
    }
    out
}

/// Per-pixel coverage (0..=1) over a rectangle, combined by maximum and
/// blended into the canvas in one go.
struct Coverage {
    rect: PixelRect,
    cov: Vec<f32>,
}

impl Coverage {
    fn new(rect: PixelRect) -> Coverage {
        Coverage {
            rect,
            cov: vec![0.0; rect.width() as usize * rect.height() as usize],
        }
    }

    fn add(&mut self, x: i32, y: i32, c: f64) {
        if self.rect.contains(x, y) && c > 0.0 {
            let i = (y - self.rect.y0) as usize * self.rect.width() as usize
                + (x - self.rect.x0) as usize;
            let c = c.min(1.0) as f32;
            if c > self.cov[i] {
                self.cov[i] = c;
            }
        }
    }

    /// Coverage of a shape given by a signed distance (negative inside, in
    /// pixels): a pixel centre half a pixel inside is fully covered, half a
    /// pixel outside not at all, linear in between.
    fn shape(&mut self, sd: impl Fn(f64, f64) -> f64) {
        let r = self.rect;
        for y in r.y0..r.y1 {
            for x in r.x0..r.x1 {
                self.add(x, y, 0.5 - sd(x as f64 + 0.5, y as f64 + 0.5));
            }
        }
    }

    /// The stadium of radius `r` around segment `a`–`b`. Only a band of
    /// pixels along the segment is visited (not its bounding box), and the
    /// segment is first cut to the mask, so long diagonals and far-off
    /// endpoints stay cheap.
    fn capsule(&mut self, a: (f64, f64), b: (f64, f64), r: f64) {
        let m = r + 2.0;
        let lim = (
            self.rect.x0 as f64 - m,
            self.rect.y0 as f64 - m,
            self.rect.x1 as f64 + m,
            self.rect.y1 as f64 + m,
        );
        let Some((a, b)) = clip_segment(a, b, lim) else {
            return;
        };
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let len2 = dx * dx + dy * dy;
        let dist = |px: f64, py: f64| -> f64 {
            let t = if len2 > 0.0 {
                (((px - a.0) * dx + (py - a.1) * dy) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            (px - (a.0 + t * dx)).hypot(py - (a.1 + t * dy))
        };
        // Across the band, |slope| <= 1 so the perpendicular radius r spans
        // at most r·√2 along the minor axis; +1.5 covers the fringe.
        let half = r * std::f64::consts::SQRT_2 + 1.5;
        let x_major = dx.abs() >= dy.abs();
        let (lo, hi) = if x_major {
            (a.0.min(b.0) - r - 1.0, a.0.max(b.0) + r + 1.0)
        } else {
            (a.1.min(b.1) - r - 1.0, a.1.max(b.1) + r + 1.0)
        };
        let (rlo, rhi) = if x_major {
            (self.rect.x0, self.rect.x1)
        } else {
            (self.rect.y0, self.rect.y1)
        };
        let i0 = (lo.floor() as i32).max(rlo);
        let i1 = (hi.ceil() as i32).min(rhi);
        for i in i0..i1 {
            let c = i as f64 + 0.5;
            // Minor-axis position of the segment at this major coordinate,
            // held at the endpoint beyond the segment (covers the round cap).
            let minor = if x_major {
                if dx == 0.0 {
                    a.1
                } else {
                    a.1 + ((c - a.0) / dx).clamp(0.0, 1.0) * dy
                }
            } else if dy == 0.0 {
                a.0
            } else {
                a.0 + ((c - a.1) / dy).clamp(0.0, 1.0) * dx
            };
            let j0 = (minor - half).floor() as i32;
            let j1 = (minor + half).ceil() as i32;
            for j in j0..=j1 {
                let (x, y) = if x_major { (i, j) } else { (j, i) };
                let d = dist(x as f64 + 0.5, y as f64 + 0.5);
                self.add(x, y, r + 0.5 - d);
            }
        }
    }

    fn blend_into(&self, canvas: &mut Canvas, color: Rgb) {
        let w = self.rect.width() as usize;
        for (i, &c) in self.cov.iter().enumerate() {
            if c > 0.0 {
                let x = self.rect.x0 + (i % w) as i32;
                let y = self.rect.y0 + (i / w) as i32;
                canvas.blend(x, y, color, c);
            }
        }
    }
}

/// Liang–Barsky: the part of segment `a`–`b` inside the box
/// `(xmin, ymin, xmax, ymax)`, or `None` if it misses it.
fn clip_segment(
    a: (f64, f64),
    b: (f64, f64),
    (xmin, ymin, xmax, ymax): (f64, f64, f64, f64),
) -> Option<((f64, f64), (f64, f64))> {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let mut t0 = 0.0f64;
    let mut t1 = 1.0f64;
    for (p, q) in [
        (-dx, a.0 - xmin),
        (dx, xmax - a.0),
        (-dy, a.1 - ymin),
        (dy, ymax - a.1),
    ] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let t = q / p;
            if p < 0.0 {
                t0 = t0.max(t);
            } else {
                t1 = t1.min(t);
            }
        }
    }
    if t0 > t1 || !t0.is_finite() || !t1.is_finite() {
        return None;
    }
    Some((
        (a.0 + t0 * dx, a.1 + t0 * dy),
        (a.0 + t1 * dx, a.1 + t1 * dy),
    ))
}
