//! What a figure draws with, whatever it is written to: the raster
//! [`Canvas`] (PNG) or the vector [`Svg`] document.
//!
//! Line plots and the shared axes code are written once against [`Draw`], so
//! a PNG and an SVG of the same figure have the same layout pixel for pixel
//! (SVG user units are the PNG's pixels); only the rendering differs. The
//! spectrogram and surface figures are rasters by nature and use the
//! [`Canvas`] directly.
//!
//! The output format follows the file name's extension ([`ImageFormat`]);
//! an extension a figure cannot be written as is refused up front with
//! [`PlotError::UnsupportedFormat`], so `--out x.pdf` never writes PNG bytes
//! into a file named `.pdf`.

use std::path::Path;

use super::canvas::{Canvas, Marker, PixelRect, Rgb, TextStyle};
use super::svg::Svg;
use super::PlotError;

/// The file formats the figures are written in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageFormat {
    Png,
    Svg,
}

impl ImageFormat {
    /// The extension (lower case, without the dot).
    pub fn extension(self) -> &'static str {
        match self {
            ImageFormat::Png => "png",
            ImageFormat::Svg => "svg",
        }
    }

    /// The format `path`'s extension names (case-insensitive), if it is one
    /// of `supported`; otherwise [`PlotError::UnsupportedFormat`] naming the
    /// path and the extensions that would do.
    pub fn for_path(path: &Path, supported: &[ImageFormat]) -> Result<ImageFormat, PlotError> {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase());
        supported
            .iter()
            .copied()
            .find(|f| ext.as_deref() == Some(f.extension()))
            .ok_or_else(|| PlotError::UnsupportedFormat {
                path: path.to_path_buf(),
                extension: ext.unwrap_or_default(),
                supported: supported
                    .iter()
                    .map(|f| format!(".{}", f.extension()))
                    .collect::<Vec<_>>()
                    .join(", "),
            })
    }
}

/// The formats a line plot is written in.
pub const LINE_PLOT_FORMATS: &[ImageFormat] = &[ImageFormat::Png, ImageFormat::Svg];
/// The formats spectrograms and surface figures are written in (rasters).
pub const RASTER_FORMATS: &[ImageFormat] = &[ImageFormat::Png];

/// Drawing operations in pixel coordinates (see [`Canvas`] for the
/// conventions: integer rectangles address whole pixels, lines and markers
/// take continuous coordinates in which pixel `i` covers `[i, i+1)`).
pub trait Draw {
    /// Restricts drawing to `rect`; `None` restores the whole image.
    fn set_clip(&mut self, rect: Option<PixelRect>);
    fn fill_rect(&mut self, rect: PixelRect, color: Rgb);
    /// The outline of `rect`, `thickness` pixels wide, inside it.
    fn stroke_rect(&mut self, rect: PixelRect, color: Rgb, thickness: i32) {
        let t = thickness.max(1);
        let PixelRect { x0, y0, x1, y1 } = rect;
        self.fill_rect(PixelRect::new(x0, y0, x1, y0 + t), color);
        self.fill_rect(PixelRect::new(x0, y1 - t, x1, y1), color);
        self.fill_rect(PixelRect::new(x0, y0, x0 + t, y1), color);
        self.fill_rect(PixelRect::new(x1 - t, y0, x1, y1), color);
    }
    /// Connected segments with round joins and caps; a non-finite point is a gap.
    fn polyline(&mut self, points: &[(f64, f64)], color: Rgb, width: f64);
    /// As [`Draw::polyline`], dashed: on, off, … lengths in pixels.
    fn dashed_polyline(&mut self, points: &[(f64, f64)], color: Rgb, width: f64, dash: &[f64]);
    fn line(&mut self, x0: f64, y0: f64, x1: f64, y1: f64, color: Rgb, width: f64) {
        self.polyline(&[(x0, y0), (x1, y1)], color, width);
    }
    /// A filled marker of overall size `size` centred at `(x, y)`.
    fn marker(&mut self, x: f64, y: f64, marker: Marker, size: f64, color: Rgb);
    /// The outline of a marker, its inside left as it was.
    fn hollow_marker(&mut self, x: f64, y: f64, marker: Marker, size: f64, color: Rgb);
    /// `text` anchored at `(x, y)`; returns its box (cap height).
    fn text(&mut self, x: i32, y: i32, text: &str, style: &TextStyle) -> PixelRect;
}

impl Draw for Canvas {
    fn set_clip(&mut self, rect: Option<PixelRect>) {
        Canvas::set_clip(self, rect)
    }
    fn fill_rect(&mut self, rect: PixelRect, color: Rgb) {
        Canvas::fill_rect(self, rect, color)
    }
    fn stroke_rect(&mut self, rect: PixelRect, color: Rgb, thickness: i32) {
        Canvas::stroke_rect(self, rect, color, thickness)
    }
    fn polyline(&mut self, points: &[(f64, f64)], color: Rgb, width: f64) {
        Canvas::polyline(self, points, color, width)
    }
    fn dashed_polyline(&mut self, points: &[(f64, f64)], color: Rgb, width: f64, dash: &[f64]) {
        Canvas::dashed_polyline(self, points, color, width, dash)
    }
    fn line(&mut self, x0: f64, y0: f64, x1: f64, y1: f64, color: Rgb, width: f64) {
        Canvas::line(self, x0, y0, x1, y1, color, width)
    }
    fn marker(&mut self, x: f64, y: f64, marker: Marker, size: f64, color: Rgb) {
        Canvas::marker(self, x, y, marker, size, color)
    }
    fn hollow_marker(&mut self, x: f64, y: f64, marker: Marker, size: f64, color: Rgb) {
        Canvas::hollow_marker(self, x, y, marker, size, color)
    }
    fn text(&mut self, x: i32, y: i32, text: &str, style: &TextStyle) -> PixelRect {
        Canvas::text(self, x, y, text, style)
    }
}

impl Draw for Svg {
    fn set_clip(&mut self, rect: Option<PixelRect>) {
        Svg::set_clip(self, rect)
    }
    fn fill_rect(&mut self, rect: PixelRect, color: Rgb) {
        Svg::fill_rect(self, rect, color)
    }
    fn polyline(&mut self, points: &[(f64, f64)], color: Rgb, width: f64) {
        Svg::polyline(self, points, color, width, &[])
    }
    fn dashed_polyline(&mut self, points: &[(f64, f64)], color: Rgb, width: f64, dash: &[f64]) {
        Svg::polyline(self, points, color, width, dash)
    }
    fn marker(&mut self, x: f64, y: f64, marker: Marker, size: f64, color: Rgb) {
        Svg::marker(self, x, y, marker, size, color, false)
    }
    fn hollow_marker(&mut self, x: f64, y: f64, marker: Marker, size: f64, color: Rgb) {
        Svg::marker(self, x, y, marker, size, color, true)
    }
    fn text(&mut self, x: i32, y: i32, text: &str, style: &TextStyle) -> PixelRect {
        Svg::text(self, x, y, text, style)
    }
}
