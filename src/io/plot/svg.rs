//! The vector writer: an SVG 1.1 document built with the same drawing calls
//! as the raster [`super::Canvas`] (through [`super::Draw`]).
//!
//! Why vectors: a figure in a paper is scaled by the typesetter, and lines,
//! markers and text stay sharp at any size only as vectors. User units are
//! the raster's pixels, so layout code is shared and a PNG and an SVG of one
//! figure agree.
//!
//! Text is written as glyph outlines, not as `<text>`: the document then
//! looks the same in every viewer whether or not it has DejaVu Sans, and
//! needs no font embedded (what matplotlib does by default, too). Each glyph
//! used is defined once under `<defs>` in font units and placed with `<use>`
//! and a transform, which keeps a figure with many tick labels small.
//! Clipping to the plot area uses `<clipPath>` groups, like the raster clip.

use std::collections::BTreeSet;
use std::fmt::Write as _;
use std::path::Path;

use ab_glyph::OutlineCurve;

use super::canvas::{
    cross_arms, marker_stroke, text_box, text_size, Marker, PixelRect, Rgb, TextStyle,
};
use super::font::{self, Face};
use super::PlotError;

/// An SVG document being drawn; [`Svg::write`] saves it.
#[derive(Clone, Debug)]
pub struct Svg {
    width: u32,
    height: u32,
    body: String,
    /// Clip rectangles already defined, by id number.
    clips: Vec<PixelRect>,
    /// Whether a clipped `<g>` is open in `body`.
    group_open: bool,
    /// Glyphs used, by face and glyph id (defined once under `<defs>`).
    glyphs: BTreeSet<(u8, u16)>,
}

/// A number for an attribute: at most two decimals, no trailing zeros.
fn num(v: f64) -> String {
    let mut s = format!("{:.2}", v);
    if s.contains('.') {
        while s.ends_with('0') {
            s.pop();
        }
        if s.ends_with('.') {
            s.pop();
        }
    }
    if s == "-0" {
        s = "0".into();
    }
    s
}

fn hex(c: Rgb) -> String {
    format!("#{:02x}{:02x}{:02x}", c[0], c[1], c[2])
}

fn face_code(f: Face) -> u8 {
    match f {
        Face::Regular => 0,
        Face::Bold => 1,
    }
}

fn glyph_ref(f: u8, id: u16) -> String {
    format!("g{}-{}", if f == 0 { "r" } else { "b" }, id)
}

impl Svg {
    /// A `width × height` document on a `background` rectangle.
    pub fn new(width: u32, height: u32, background: Rgb) -> Svg {
        let mut body = String::new();
        let _ = writeln!(
            body,
            r#"<rect x="0" y="0" width="{width}" height="{height}" fill="{}"/>"#,
            hex(background)
        );
        Svg {
            width,
            height,
            body,
            clips: Vec::new(),
            group_open: false,
            glyphs: BTreeSet::new(),
        }
    }

    pub fn width(&self) -> u32 {
        self.width
    }
    pub fn height(&self) -> u32 {
        self.height
    }

    pub fn set_clip(&mut self, rect: Option<PixelRect>) {
        if self.group_open {
            self.body.push_str("</g>\n");
            self.group_open = false;
        }
        let full = PixelRect::new(0, 0, self.width as i32, self.height as i32);
        let Some(r) = rect.map(|r| r.intersect(&full)) else {
            return;
        };
        if r == full {
            return;
        }
        let id = match self.clips.iter().position(|c| *c == r) {
            Some(i) => i,
            None => {
                self.clips.push(r);
                self.clips.len() - 1
            }
        };
        let _ = writeln!(self.body, r#"<g clip-path="url(#clip{id})">"#);
        self.group_open = true;
    }

    pub fn fill_rect(&mut self, rect: PixelRect, color: Rgb) {
        if rect.width() == 0 || rect.height() == 0 {
            return;
        }
        let _ = writeln!(
            self.body,
            r#"<rect x="{}" y="{}" width="{}" height="{}" fill="{}" shape-rendering="crispEdges"/>"#,
            rect.x0,
            rect.y0,
            rect.width(),
            rect.height(),
            hex(color)
        );
    }

    /// Connected segments, round joins and caps; a non-finite point starts a
    /// new run. `dash`: on, off, … lengths (empty: solid).
    pub fn polyline(&mut self, points: &[(f64, f64)], color: Rgb, width: f64, dash: &[f64]) {
        let mut d = String::new();
        let mut pen_down = false;
        for &(x, y) in points {
            if !(x.is_finite() && y.is_finite()) {
                pen_down = false;
                continue;
            }
            let _ = write!(
                d,
                "{}{} {} ",
                if pen_down { "L" } else { "M" },
                num(x),
                num(y)
            );
            pen_down = true;
        }
        if d.is_empty() {
            return;
        }
        let dash_attr = if dash.is_empty() {
            String::new()
        } else {
            format!(
                r#" stroke-dasharray="{}""#,
                dash.iter().map(|&v| num(v)).collect::<Vec<_>>().join(",")
            )
        };
        let _ = writeln!(
            self.body,
            r#"<path d="{}" fill="none" stroke="{}" stroke-width="{}" stroke-linejoin="round" stroke-linecap="round"{dash_attr}/>"#,
            d.trim_end(),
            hex(color),
            num(width.max(0.5))
        );
    }

    /// The same marker shapes and sizes as the raster's.
    pub fn marker(&mut self, x: f64, y: f64, marker: Marker, size: f64, color: Rgb, hollow: bool) {
        if !(x.is_finite() && y.is_finite()) {
            return;
        }
        let h = size.max(1.0) / 2.0;
        let sw = marker_stroke(size);
        // A hollow outline is drawn just inside the filled shape's edge.
        let inset = if hollow { sw / 2.0 } else { 0.0 };
        let paint = if hollow {
            format!(
                r#"fill="none" stroke="{}" stroke-width="{}""#,
                hex(color),
                num(sw)
            )
        } else {
            format!(r#"fill="{}""#, hex(color))
        };
        let shape = match marker {
            Marker::Circle => format!(
                r#"<circle cx="{}" cy="{}" r="{}" {paint}/>"#,
                num(x),
                num(y),
                num(h - inset)
            ),
            Marker::Square => {
                let s = h * 0.85 - inset;
                format!(
                    r#"<rect x="{}" y="{}" width="{}" height="{}" {paint}/>"#,
                    num(x - s),
                    num(y - s),
                    num(2.0 * s),
                    num(2.0 * s)
                )
            }
            Marker::Diamond => {
                let s = h * 1.1 - inset * std::f64::consts::SQRT_2;
                format!(
                    r#"<path d="M{} {} L{} {} L{} {} L{} {} Z" {paint}/>"#,
                    num(x),
                    num(y - s),
                    num(x + s),
                    num(y),
                    num(x),
                    num(y + s),
                    num(x - s),
                    num(y)
                )
            }
            Marker::Cross | Marker::Plus => {
                let w = (size / 4.0).clamp(1.0, 3.0);
                let d: String = cross_arms(x, y, marker, size)
                    .iter()
                    .map(|(a, b)| format!("M{} {} L{} {} ", num(a.0), num(a.1), num(b.0), num(b.1)))
                    .collect();
                format!(
                    r#"<path d="{}" fill="none" stroke="{}" stroke-width="{}" stroke-linecap="round"/>"#,
                    d.trim_end(),
                    hex(color),
                    num(w)
                )
            }
        };
        self.body.push_str(&shape);
        self.body.push('\n');
    }

    /// `text` as glyph outlines, placed exactly as [`super::Canvas::text`]
    /// places it; returns the same box.
    pub fn text(&mut self, x: i32, y: i32, text: &str, style: &TextStyle) -> PixelRect {
        let line = font::layout(text, style.size, style.face());
        let (w, h) = text_size(text, style);
        let (rect, du, dv) = text_box(x, y, w as i32, h as i32, style);
        let f = face_code(line.face);
        let s = line.scale() as f64;
        let mut uses = String::new();
        for g in &line.glyphs {
            if line.outline(g.id).is_none() {
                continue; // a space
            }
            self.glyphs.insert((f, g.id.0));
            // Glyph origin in upright coordinates relative to the anchor.
            let (u, v) = (-(du as f64) + g.x as f64, (h as i32 - dv) as f64);
            let transform = if style.rotated {
                // Upright (u, v) lands at (x + v, y + 1 - u), turned a quarter
                // counter-clockwise (see `text_box`).
                format!(
                    "translate({} {}) rotate(-90) scale({} {})",
                    num(x as f64 + v),
                    num(y as f64 + 1.0 - u),
                    s,
                    -s
                )
            } else {
                format!(
                    "translate({} {}) scale({} {})",
                    num(x as f64 + u),
                    num(y as f64 + v),
                    s,
                    -s
                )
            };
            let _ = writeln!(
                uses,
                r##"<use xlink:href="#{}" transform="{transform}"/>"##,
                glyph_ref(f, g.id.0)
            );
        }
        if !uses.is_empty() {
            let _ = write!(self.body, "<g fill=\"{}\">\n{uses}</g>\n", hex(style.color));
        }
        rect
    }

    /// The whole document.
    pub fn finish(&self) -> String {
        let mut out = String::new();
        let _ = writeln!(out, r#"<?xml version="1.0" encoding="UTF-8"?>"#);
        let _ = writeln!(
            out,
            r#"<svg xmlns="http://www.w3.org/2000/svg" xmlns:xlink="http://www.w3.org/1999/xlink" version="1.1" width="{w}" height="{h}" viewBox="0 0 {w} {h}">"#,
            w = self.width,
            h = self.height
        );
        out.push_str("<defs>\n");
        for (i, r) in self.clips.iter().enumerate() {
            let _ = writeln!(
                out,
                r#"<clipPath id="clip{i}"><rect x="{}" y="{}" width="{}" height="{}"/></clipPath>"#,
                r.x0,
                r.y0,
                r.width(),
                r.height()
            );
        }
        for &(f, id) in &self.glyphs {
            let face = font::face(if f == 0 { Face::Regular } else { Face::Bold });
            let Some(outline) = ab_glyph::Font::outline(&face.font, ab_glyph::GlyphId(id)) else {
                continue;
            };
            let _ = writeln!(
                out,
                r#"<path id="{}" d="{}"/>"#,
                glyph_ref(f, id),
                outline_path(&outline.curves)
            );
        }
        out.push_str("</defs>\n");
        out.push_str(&self.body);
        if self.group_open {
            out.push_str("</g>\n");
        }
        out.push_str("</svg>\n");
        out
    }

    /// Writes the document to `path`, atomically (see [`crate::io::atomic`]).
    pub fn write(&self, path: &Path) -> Result<(), PlotError> {
        let doc = self.finish();
        crate::io::atomic::replace_atomically(path, |tmp| {
            std::fs::write(tmp, doc.as_bytes()).map_err(|source| PlotError::Fs {
                path: tmp.to_path_buf(),
                context: "writing SVG".into(),
                source,
            })
        })
    }
}

/// SVG path data of a glyph outline in font units: a curve whose start is
/// not where the previous one ended begins a new contour.
fn outline_path(curves: &[OutlineCurve]) -> String {
    let mut d = String::new();
    let mut at: Option<ab_glyph::Point> = None;
    let p = |q: ab_glyph::Point| format!("{} {}", q.x, q.y);
    for c in curves {
        let (start, end) = match c {
            OutlineCurve::Line(a, b) => (*a, *b),
            OutlineCurve::Quad(a, _, b) => (*a, *b),
            OutlineCurve::Cubic(a, _, _, b) => (*a, *b),
        };
        if at != Some(start) {
            if at.is_some() {
                d.push('Z');
            }
            let _ = write!(d, "M{}", p(start));
        }
        let _ = match c {
            OutlineCurve::Line(_, b) => write!(d, "L{}", p(*b)),
            OutlineCurve::Quad(_, c1, b) => write!(d, "Q{} {}", p(*c1), p(*b)),
            OutlineCurve::Cubic(_, c1, c2, b) => write!(d, "C{} {} {}", p(*c1), p(*c2), p(*b)),
        };
        at = Some(end);
    }
    if at.is_some() {
        d.push('Z');
    }
    d
}
