//! Figures for people to look at and for papers: spectrograms (recording
//! against rendering, several microphones), line/scatter plots (damping
//! curves, decay rates, loss histories, frequency errors) and shaded 3-D
//! surfaces (a scalar map over an object, shapes side by side).
//!
//! Self-contained: the raster ([`Canvas`]), the vector writer ([`Svg`]),
//! tick placement and the colour map are all here; the `png` crate encodes,
//! and `ab_glyph` rasterises the embedded DejaVu Sans (see `font.rs` for why
//! a bundled outline font: smooth text with α, ν, λ, Δ, σ, ² on any
//! machine). Every file is written through
//! [`crate::io::atomic::replace_atomically`], so a reader sees the old
//! figure or the complete new one, and a failed or refused write leaves
//! nothing behind. Invalid input (mismatched lengths, no valid data,
//! non-finite steps, …) is a [`PlotError::InvalidInput`] naming the file,
//! never a panic; a file name whose extension is not a format the figure is
//! written in is a [`PlotError::UnsupportedFormat`] naming the path and the
//! extensions that would do, checked before anything is drawn
//! ([`ImageFormat::for_path`], which commands also call before their work).
//!
//! # Entry points
//!
//! - [`spectrogram_png`] with a [`SpectrogramFigure`]: panels side by side,
//!   each a [`SpectrogramPanel`] of dB magnitudes, row-major
//!   `[n_frames][n_bins]`; frame `i` is centred at
//!   `time_offset_s + i·time_step_s` (s), bin `j` at `j·freq_step_hz` (Hz),
//!   and each cell spans half a step either side of its centre. All panels
//!   share the time axis (the union of their extents; area a panel has no
//!   data for is light grey), the frequency axis (0 Hz to `max_freq_hz`,
//!   default the highest bin centre; labelled in kHz from 2 kHz up), and
//!   one colour scale (default top = the loudest finite value of all
//!   panels, bottom = top − 80 dB) shown as a bar labelled "dB".
//!   `panel_width`/`panel_height` size each image; margins are added. PNG.
//! - [`line_plot`] with a [`LineFigure`]: [`Series`] drawn as lines,
//!   markers, both, or stems, on linear or log axes ([`AxisScale`]); colours
//!   from [`PALETTE`] in order, then the same colours dashed or hollow
//!   (unless set); the legend lists the series that have something drawn,
//!   in a corner of the plot that holds no data or else outside it. A point
//!   that is not finite (or not > 0 on a log axis) is skipped and breaks a
//!   line. `width`/`height` are the whole image (default 1600 × 1000 at
//!   scale 1.6). Written as PNG or SVG by the path's extension.
//! - [`surface_png`] with a [`SurfaceFigure`]: triangle surfaces
//!   ([`SurfacePanel`]: vertices, triangles, optionally one value per vertex,
//!   and [`SurfaceMarker`]s) in a grid, one column per panel and one row per
//!   [`View`] (azimuth and elevation in degrees, z up), orthographic with a
//!   depth buffer and Lambert shading from a light near the viewer; back
//!   faces are drawn too. All panels share one scale (the largest bounding
//!   sphere fits its cell), each centred on its own bounding box. Values are
//!   coloured on one shared scale (default: the finite min..max of all
//!   panels; non-finite values grey) shown as a bar labelled `value_label`;
//!   a panel without values is plain grey. Markers are filled circles with a
//!   dark outline and a label, hollow when the surface hides them.
//!   `panel_size` is the side of each square cell; margins are added. PNG.
//! - [`Canvas`] (and [`Svg`], both behind [`Draw`]) for anything else:
//!   fill, rectangles, anti-aliased lines (solid or dashed) and markers
//!   (filled or hollow), text (aligned, optionally rotated 90°), a clip
//!   rectangle, and [`Canvas::write_png`] / [`Svg::write`].
//!
//! Every figure has a `scale` that sizes text, lines, markers, ticks and
//! margins together, like a DPI setting (1 = 15 px per em labels, 2 px
//! lines); the image and panel sizes stay in pixels.
//!
//! # Conventions
//!
//! Pixel `(i, j)` is column `i` from the left, row `j` from the top; in the
//! continuous coordinates of lines and [`AxisMap`], pixel `i` covers
//! `[i, i+1)`; SVG user units are these pixels. A plot area is a
//! [`PixelRect`] that holds only data; its frame lies just outside it and
//! ticks point outwards from the frame, so neither hides data. [`AxisMap`]
//! sends the axis limits to the outer edges of the plot area: `to_px(lo)` is
//! the left (bottom) edge, `to_px(hi)` the right (top) edge.
//!
//! Linear ticks are multiples of 1, 2 or 5 × 10^k ([`nice_ticks`]); log
//! axes tick every decade with minor ticks at 2..9 ([`log_ticks`]). Labels
//! are compact: `0, 500, 1k, 1.5k`; `0.001`; `10⁻⁷` and `2.5·10⁻⁷` when the
//! axis is below 1e-3 or above 1e12 ([`format_ticks`]).
//!
//! Text is DejaVu Sans, anti-aliased, near-black on white, aligned on its
//! cap height ([`text_size`]); titles use the bold face. In an SVG the
//! glyphs are outlines, so the file shows the same everywhere.

mod axes;
mod canvas;
mod colormap;
mod draw;
mod font;
mod line;
mod spectrogram;
mod surface;
mod svg;
mod ticks;

use std::path::{Path, PathBuf};

pub use canvas::{text_size, Canvas, HAlign, Marker, PixelRect, Rgb, TextStyle, VAlign};
pub use colormap::colormap;
pub use draw::{Draw, ImageFormat, LINE_PLOT_FORMATS, RASTER_FORMATS};
pub use line::{
    line_plot, line_plot_png, Dash, LegendPlacement, LineFigure, Series, SeriesStyle, PALETTE,
};
pub use spectrogram::{spectrogram_png, Resampling, SpectrogramFigure, SpectrogramPanel};
pub use surface::{surface_png, SurfaceFigure, SurfaceMarker, SurfacePanel, View};
pub use svg::Svg;
pub use ticks::{
    axis_ticks, format_log_ticks, format_ticks, linear_ticks, log_ticks, nice_ticks, AxisMap,
    AxisScale, Tick,
};

/// Errors of the plotting functions; each names the file concerned.
#[derive(thiserror::Error, Debug)]
pub enum PlotError {
    /// A filesystem operation failed (the temporary file is removed).
    #[error("{path}: {context}: {source}")]
    Fs {
        path: PathBuf,
        context: String,
        #[source]
        source: std::io::Error,
    },
    /// The PNG encoder failed.
    #[error("{path}: encoding PNG: {source}")]
    Png {
        path: PathBuf,
        #[source]
        source: png::EncodingError,
    },
    /// The file name's extension is not a format this figure is written
    /// in; nothing was drawn or written.
    #[error("{path}: {}", unsupported(extension, supported))]
    UnsupportedFormat {
        path: PathBuf,
        /// The extension found (lower case, empty if none).
        extension: String,
        /// The extensions that would do, e.g. ".png, .svg".
        supported: String,
    },
    /// The figure description is inconsistent; nothing was written.
    #[error("{path}: refusing to plot: {reason}")]
    InvalidInput { path: PathBuf, reason: String },
    /// Writing failed for a cause found by [`crate::io::atomic::replace_atomically`] (disk
    /// full, quota, file size limit, …); nothing was written at `path`.
    #[error("cannot write {path}: {reason}")]
    WriteFailed { path: PathBuf, reason: String },
}

/// `v` in scientific notation as a reader writes it: `7.2·10¹⁰`, `-1.5·10⁻⁸`
/// (`digits` after the point), or plainly for 0 and non-finite values.
pub fn scientific(v: f64, digits: usize) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let e = v.abs().log10().floor() as i32;
    let mut m = v / 10f64.powi(e);
    let mut e = e;
    // Rounding the mantissa can carry it to 10.
    if format!("{:.*}", digits, m.abs()).starts_with("10") {
        m /= 10.0;
        e += 1;
    }
    if e == 0 {
        return format!("{:.*}", digits, m);
    }
    format!("{:.*}·10{}", digits, m, ticks::superscript(e))
}

fn unsupported(extension: &str, supported: &str) -> String {
    if extension.is_empty() {
        format!("a figure file needs an extension; use {supported}")
    } else {
        format!("cannot write a figure as '.{extension}'; use {supported}")
    }
}

impl crate::io::atomic::AtomicWriteError for PlotError {
    fn fs(path: &Path, context: String, source: std::io::Error) -> Self {
        PlotError::Fs {
            path: path.to_path_buf(),
            context,
            source,
        }
    }
    fn no_file_name(path: &Path) -> Self {
        PlotError::InvalidInput {
            path: path.to_path_buf(),
            reason: "path has no file name".into(),
        }
    }
    fn write_failed(path: &Path, reason: String) -> Self {
        PlotError::WriteFailed {
            path: path.to_path_buf(),
            reason,
        }
    }
    fn os_error(&self) -> Option<std::io::Error> {
        let io = match self {
            PlotError::Fs { source, .. } => source,
            PlotError::Png {
                source: png::EncodingError::IoError(source),
                ..
            } => source,
            _ => return None,
        };
        io.raw_os_error().map(std::io::Error::from_raw_os_error)
    }
}

#[cfg(test)]
mod tests;
