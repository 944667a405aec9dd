//! Line and scatter figures on linear or log axes, with a legend; written
//! as PNG or SVG (by the file's extension) from one layout.
//!
//! Series are told apart by colour first; past the eight colours of
//! [`PALETTE`] the next eight repeat them dashed (lines) or hollow
//! (markers), then dotted, so a figure of 12 or 20 series has no two alike.
//! The legend never covers data: it goes to the emptiest corner of the plot
//! area only if that corner holds no data, else outside, right of the plot.
//! A series with no point to draw (empty, or nothing valid on a log axis)
//! stays out of the legend, so the legend lists only what is drawn.

use std::path::Path;

use super::axes::{self, Look};
use super::canvas::{text_size, Canvas, HAlign, Marker, PixelRect, Rgb, VAlign};
use super::draw::{Draw, ImageFormat, LINE_PLOT_FORMATS};
use super::svg::Svg;
use super::ticks::{axis_ticks, AxisMap, AxisScale, Tick};
use super::PlotError;

/// Series colours, in order of use: eight hues chosen for this module to
/// stay distinct from each other on white (and, for the first four, under
/// the common red-green colour-vision deficiencies, which differ them in
/// lightness as well as hue).
pub const PALETTE: [Rgb; 8] = [
    [31, 92, 184],  // blue
    [222, 102, 18], // orange
    [36, 150, 84],  // green
    [190, 45, 120], // magenta
    [120, 78, 190], // violet
    [20, 160, 170], // teal
    [185, 150, 20], // ochre
    [96, 96, 96],   // grey
];

/// How a series is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SeriesStyle {
    /// Straight segments between consecutive valid points; an invalid point
    /// (non-finite, or ≤ 0 on a log axis) leaves a gap.
    Line,
    Markers(Marker),
    LineMarkers(Marker),
    /// A vertical stem from y = 0 (from the bottom of a log axis) to each
    /// point, topped with a marker: bar-like, for per-mode errors.
    Stems(Marker),
}

/// The stroke pattern of a line (and of stems).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dash {
    Solid,
    Dashed,
    Dotted,
    DashDot,
}

impl Dash {
    /// On, off, … lengths in pixels for a line `width` pixels wide (round
    /// caps add half a width at each end of a dash, so the gaps are wider).
    pub(crate) fn pattern(self, width: f64) -> Vec<f64> {
        let w = width.max(1.0);
        match self {
            Dash::Solid => Vec::new(),
            Dash::Dashed => vec![4.0 * w, 3.0 * w],
            Dash::Dotted => vec![0.01 * w, 2.5 * w],
            Dash::DashDot => vec![4.0 * w, 2.5 * w, 0.01 * w, 2.5 * w],
        }
    }
}

/// One data series. `x` and `y` must have the same length.
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    /// Legend text; an empty label keeps the series out of the legend.
    pub label: String,
    pub x: Vec<f64>,
    pub y: Vec<f64>,
    pub style: SeriesStyle,
    /// Default: [`PALETTE`] by the series' position in the figure.
    pub color: Option<Rgb>,
    /// Line pattern; default: solid for the first eight series, then dashed,
    /// dotted, dash-dot for each further eight (see the module docs); solid
    /// when `color` is set.
    pub dash: Option<Dash>,
    /// Markers drawn as outlines; default: filled for the first eight
    /// series, hollow for the next eight, and so on alternately; filled when
    /// `color` is set.
    pub hollow: Option<bool>,
}

impl Series {
    pub fn new(label: impl Into<String>, x: Vec<f64>, y: Vec<f64>, style: SeriesStyle) -> Series {
        Series {
            label: label.into(),
            x,
            y,
            style,
            color: None,
            dash: None,
            hollow: None,
        }
    }
    pub fn line(label: impl Into<String>, x: Vec<f64>, y: Vec<f64>) -> Series {
        Series::new(label, x, y, SeriesStyle::Line)
    }
    pub fn markers(label: impl Into<String>, x: Vec<f64>, y: Vec<f64>, marker: Marker) -> Series {
        Series::new(label, x, y, SeriesStyle::Markers(marker))
    }
    pub fn with_color(mut self, color: Rgb) -> Series {
        self.color = Some(color);
        self
    }
    pub fn with_dash(mut self, dash: Dash) -> Series {
        self.dash = Some(dash);
        self
    }
    /// Markers drawn as outlines (`true`) or filled (`false`).
    pub fn with_hollow(mut self, hollow: bool) -> Series {
        self.hollow = Some(hollow);
        self
    }
    /// Colour, dash and fill of the series at position `k` of a figure. A series whose colour
    /// is set is solid and filled unless told otherwise: whoever chose its colour chose its look.
    pub(crate) fn look(&self, k: usize) -> (Rgb, Dash, bool) {
        let n = PALETTE.len();
        let round = if self.color.is_some() { 0 } else { k / n };
        let dash = [Dash::Solid, Dash::Dashed, Dash::Dotted, Dash::DashDot][round % 4];
        (
            self.color.unwrap_or(PALETTE[k % n]),
            self.dash.unwrap_or(dash),
            self.hollow.unwrap_or(round % 2 == 1),
        )
    }
}

/// Where the legend goes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LegendPlacement {
    /// A corner of the plot area that covers no data (tried in the order
    /// top right, top left, bottom right, bottom left), else [`Self::Outside`].
    #[default]
    Auto,
    /// Right of the plot area, which narrows to make room.
    Outside,
    TopLeft,
    TopRight,
    BottomLeft,
    BottomRight,
    Hidden,
}

/// A line/scatter figure, see [`line_plot_png`].
#[derive(Clone, Debug, PartialEq)]
pub struct LineFigure {
    pub title: String,
    /// Axis labels with units, e.g. "frequency (Hz)".
    pub x_label: String,
    pub y_label: String,
    pub x_scale: AxisScale,
    pub y_scale: AxisScale,
    /// Axis limits `(lo, hi)`; default: the valid data padded by 4 % of the
    /// span (of the log span on a log axis). With `x_range` given, the
    /// default y limits fit the points inside it.
    pub x_range: Option<(f64, f64)>,
    pub y_range: Option<(f64, f64)>,
    pub series: Vec<Series>,
    pub legend: LegendPlacement,
    /// Whole image size in pixels (SVG user units).
    pub width: u32,
    pub height: u32,
    /// Size of text, lines, markers, ticks and margins, like a DPI setting
    /// (1 = 15 px per em labels and 2 px lines).
    pub scale: f64,
}

impl LineFigure {
    /// Linear axes, automatic limits, legend placed automatically,
    /// 1600 × 1000 px at scale 1.6 (the proportions of a 1000 × 625 figure,
    /// sharp when a paper shrinks it to a column).
    pub fn new(
        title: impl Into<String>,
        x_label: impl Into<String>,
        y_label: impl Into<String>,
    ) -> LineFigure {
        LineFigure {
            title: title.into(),
            x_label: x_label.into(),
            y_label: y_label.into(),
            x_scale: AxisScale::Linear,
            y_scale: AxisScale::Linear,
            x_range: None,
            y_range: None,
            series: Vec::new(),
            legend: LegendPlacement::Auto,
            width: 1600,
            height: 1000,
            scale: 1.6,
        }
    }
}

/// Line width and marker size at scale 1, in pixels.
const LINE_WIDTH: f64 = 2.0;
const MARKER_SIZE: f64 = 9.0;

/// Where everything landed (read by the tests; the writers draw from it).
#[derive(Clone, Debug)]
// Only the tests read some of the fields.
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) struct LineLayout {
    pub plot: PixelRect,
    pub x: AxisMap,
    pub y: AxisMap,
    pub x_ticks: Vec<Tick>,
    pub y_ticks: Vec<Tick>,
    /// The legend box, if there is one.
    pub legend: Option<PixelRect>,
    /// Whether the legend sits outside the plot area.
    pub legend_outside: bool,
    /// Indices of the series listed in the legend, in order.
    pub legend_entries: Vec<usize>,
}

/// Renders `fig` and writes it to `path` as a PNG or an SVG, by the path's
/// extension (`.png`, `.svg`; any other is [`PlotError::UnsupportedFormat`]),
/// atomically. Nothing is written if the figure is invalid (see
/// [`PlotError::InvalidInput`]).
pub fn line_plot(path: &Path, fig: &LineFigure) -> Result<(), PlotError> {
    match ImageFormat::for_path(path, LINE_PLOT_FORMATS)? {
        ImageFormat::Png => render_line_plot(path, fig)?.0.write_png(path),
        ImageFormat::Svg => render_line_plot_svg(path, fig)?.0.write(path),
    }
}

/// [`line_plot`] for a path that must end in `.png`.
pub fn line_plot_png(path: &Path, fig: &LineFigure) -> Result<(), PlotError> {
    ImageFormat::for_path(path, &[ImageFormat::Png])?;
    line_plot(path, fig)
}

fn valid(scale: AxisScale, v: f64) -> bool {
    v.is_finite() && (scale == AxisScale::Linear || v > 0.0)
}

/// Axis limits from the user's range or the data `(min, max)`.
fn axis_range(
    path: &Path,
    which: &str,
    scale: AxisScale,
    user: Option<(f64, f64)>,
    data: (f64, f64),
) -> Result<(f64, f64), PlotError> {
    if let Some((lo, hi)) = user {
        if !(lo.is_finite() && hi.is_finite() && lo < hi) || (scale == AxisScale::Log && lo <= 0.0)
        {
            return Err(PlotError::InvalidInput {
                path: path.to_path_buf(),
                reason: format!(
                    "{which} range ({lo}, {hi}) must be finite and increasing{}",
                    if scale == AxisScale::Log {
                        ", and positive on a log axis"
                    } else {
                        ""
                    }
                ),
            });
        }
        return Ok((lo, hi));
    }
    let (lo, hi) = data;
    Ok(match scale {
        AxisScale::Linear => {
            if hi > lo {
                let pad = 0.04 * (hi - lo);
                (lo - pad, hi + pad)
            } else {
                let d = if lo == 0.0 { 1.0 } else { 0.1 * lo.abs() };
                (lo - d, hi + d)
            }
        }
        AxisScale::Log => {
            let (a, b) = (lo.log10(), hi.log10());
            let pad = if b > a { 0.04 * (b - a) } else { 0.3 };
            (10f64.powf(a - pad), 10f64.powf(b + pad))
        }
    })
}

/// ((x_lo, x_hi), (y_lo, y_hi)) in data units.
type Limits = ((f64, f64), (f64, f64));

/// The plot area, the two axis maps and the ticks of x and y.
type Frame = (PixelRect, AxisMap, AxisMap, Vec<Tick>, Vec<Tick>);

/// The data limits of both axes, checked.
fn data_limits(path: &Path, fig: &LineFigure) -> Result<Limits, PlotError> {
    let bad = |reason: String| PlotError::InvalidInput {
        path: path.to_path_buf(),
        reason,
    };
    if fig.series.is_empty() {
        return Err(bad("line plot has no series".into()));
    }
    if fig.width < 200 || fig.height < 150 || fig.width > 8192 || fig.height > 8192 {
        return Err(bad(format!(
            "image size {}x{} px is outside 200x150 ..= 8192x8192",
            fig.width, fig.height
        )));
    }
    if !(fig.scale.is_finite() && fig.scale > 0.0 && fig.scale <= 16.0) {
        return Err(bad(format!("scale {} is outside (0, 16]", fig.scale)));
    }
    let (mut xmin, mut xmax, mut ymin, mut ymax) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    let mut stems = false;
    for (k, s) in fig.series.iter().enumerate() {
        if s.x.len() != s.y.len() {
            return Err(bad(format!(
                "series {k} ('{}') has {} x values but {} y values",
                s.label,
                s.x.len(),
                s.y.len()
            )));
        }
        stems |= matches!(s.style, SeriesStyle::Stems(_));
        for (&x, &y) in s.x.iter().zip(&s.y) {
            if valid(fig.x_scale, x) && valid(fig.y_scale, y) {
                xmin = xmin.min(x);
                xmax = xmax.max(x);
                ymin = ymin.min(y);
                ymax = ymax.max(y);
            }
        }
    }
    if xmin > xmax {
        let log = if fig.x_scale == AxisScale::Log || fig.y_scale == AxisScale::Log {
            " (a log axis also needs values > 0)"
        } else {
            ""
        };
        return Err(bad(format!(
            "no series has a single valid (finite) point{log}"
        )));
    }
    // Stems start at zero, so zero belongs in view.
    if stems && fig.y_scale == AxisScale::Linear {
        ymin = ymin.min(0.0);
        ymax = ymax.max(0.0);
    }
    let (x_lo, x_hi) = axis_range(path, "x", fig.x_scale, fig.x_range, (xmin, xmax))?;
    // With x limits given, fit y to the points that are in view (if any).
    if fig.x_range.is_some() {
        let (mut a, mut b) = (f64::INFINITY, f64::NEG_INFINITY);
        for s in &fig.series {
            for (&x, &y) in s.x.iter().zip(&s.y) {
                if valid(fig.x_scale, x) && valid(fig.y_scale, y) && x >= x_lo && x <= x_hi {
                    a = a.min(y);
                    b = b.max(y);
                }
            }
        }
        if a <= b {
            (ymin, ymax) = (a, b);
            if stems && fig.y_scale == AxisScale::Linear {
                ymin = ymin.min(0.0);
                ymax = ymax.max(0.0);
            }
        }
    }
    let (y_lo, y_hi) = axis_range(path, "y", fig.y_scale, fig.y_range, (ymin, ymax))?;
    // Padding can overflow data near ±f64::MAX, and a span wider than f64
    // cannot be mapped to pixels.
    for (which, lo, hi) in [("x", x_lo, x_hi), ("y", y_lo, y_hi)] {
        if !(lo.is_finite() && hi.is_finite() && (hi - lo).is_finite() && lo < hi) {
            return Err(bad(format!(
                "{which} axis {lo} .. {hi} is not representable"
            )));
        }
    }
    Ok(((x_lo, x_hi), (y_lo, y_hi)))
}

/// Legend metrics at a look: sample width, row height, padding.
struct LegendMetrics {
    pad: i32,
    sample_w: i32,
    row: i32,
    inset: i32,
}

impl LegendMetrics {
    fn new(look: &Look) -> LegendMetrics {
        LegendMetrics {
            pad: look.px(10.0),
            sample_w: look.px(40.0),
            row: look.text_h() + look.px(11.0),
            inset: look.px(10.0),
        }
    }
    /// Width and height of the box for `labels`.
    fn size(&self, look: &Look, labels: &[&str]) -> (i32, i32) {
        let text_w = labels.iter().map(|l| look.text_w(l)).max().unwrap_or(0);
        (
            self.pad * 2 + self.sample_w + self.pad + text_w,
            self.pad * 2 + self.row * labels.len() as i32 - (self.row - look.text_h()),
        )
    }
}

/// The series that appear in the legend: labelled, with a point to draw.
fn legend_entries(fig: &LineFigure) -> Vec<usize> {
    fig.series
        .iter()
        .enumerate()
        .filter(|(_, s)| {
            !s.label.is_empty()
                && s.x
                    .iter()
                    .zip(&s.y)
                    .any(|(&x, &y)| valid(fig.x_scale, x) && valid(fig.y_scale, y))
        })
        .map(|(k, _)| k)
        .collect()
}

/// A series' valid points in pixels (non-finite where a point is invalid).
fn screen_points(fig: &LineFigure, s: &Series, xm: &AxisMap, ym: &AxisMap) -> Vec<(f64, f64)> {
    s.x.iter()
        .zip(&s.y)
        .map(|(&x, &y)| {
            if valid(fig.x_scale, x) && valid(fig.y_scale, y) {
                (xm.to_px(x), ym.to_px(y))
            } else {
                (f64::NAN, f64::NAN)
            }
        })
        .collect()
}

/// Where the data are drawn, as samples in pixels: the points, and samples
/// every few pixels along lines and stems, so a line crossing a corner
/// counts even with no point there.
fn data_samples(fig: &LineFigure, xm: &AxisMap, ym: &AxisMap, base_y: f64) -> Vec<(f64, f64)> {
    let mut out = Vec::new();
    let along = |a: (f64, f64), b: (f64, f64), out: &mut Vec<(f64, f64)>| {
        let n = ((b.0 - a.0).hypot(b.1 - a.1) / 6.0).ceil().min(500.0) as usize;
        for i in 0..n {
            let t = i as f64 / n as f64;
            out.push((a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1)));
        }
    };
    for s in &fig.series {
        let pts = screen_points(fig, s, xm, ym);
        match s.style {
            SeriesStyle::Line | SeriesStyle::LineMarkers(_) => {
                for win in pts.windows(2) {
                    if win[0].0.is_finite() && win[1].0.is_finite() {
                        along(win[0], win[1], &mut out);
                    }
                }
            }
            SeriesStyle::Stems(_) => {
                for &p in pts.iter().filter(|p| p.0.is_finite()) {
                    along((p.0, base_y), p, &mut out);
                }
            }
            SeriesStyle::Markers(_) => {}
        }
        out.extend(pts.iter().filter(|p| p.0.is_finite()));
    }
    out
}

/// The plot area and axes for a figure whose right part (`reserve_right`
/// pixels) is kept for an outside legend.
fn frame_layout(
    path: &Path,
    fig: &LineFigure,
    look: &Look,
    limits: ((f64, f64), (f64, f64)),
    reserve_right: i32,
) -> Result<Frame, PlotError> {
    let ((x_lo, x_hi), (y_lo, y_hi)) = limits;
    let (w, h) = (fig.width as i32, fig.height as i32);
    let text_line = look.text_h() + look.descent();
    // Vertical layout first: the y ticks (and so the left margin) depend
    // only on the plot height.
    let title_h = if fig.title.is_empty() {
        0
    } else {
        look.title_h() + look.px(16.0)
    };
    // Half a label of headroom so the top y tick label is not cut.
    let plot_y0 = look.margin() + title_h + look.text_h() / 2 + look.px(2.0);
    let x_label_h = if fig.x_label.is_empty() {
        0
    } else {
        text_line + look.px(8.0)
    };
    let plot_y1 =
        h - look.margin() - x_label_h - text_line - look.label_gap() - look.tick() - look.rule();
    let y_ticks = axis_ticks(
        fig.y_scale,
        y_lo,
        y_hi,
        axes::tick_budget(plot_y1 - plot_y0, look.px(56.0)),
    );
    let y_label_w = if fig.y_label.is_empty() {
        0
    } else {
        text_line + look.px(10.0)
    };
    let plot_x0 = look.margin()
        + y_label_w
        + look.max_label_w(&y_ticks)
        + look.label_gap()
        + look.tick()
        + look.rule();
    // Room for half of a tick label centred on the right edge.
    let plot_x1 = w - look.margin() - reserve_right - look.px(24.0);
    if plot_x1 - plot_x0 < 40 || plot_y1 - plot_y0 < 40 {
        return Err(PlotError::InvalidInput {
            path: path.to_path_buf(),
            reason: format!(
                "image size {}x{} px leaves no room for the plot",
                fig.width, fig.height
            ),
        });
    }
    let plot = PixelRect::new(plot_x0, plot_y0, plot_x1, plot_y1);
    let x_ticks = axis_ticks(
        fig.x_scale,
        x_lo,
        x_hi,
        axes::tick_budget(plot.width(), look.px(100.0)),
    );
    let xm = AxisMap {
        scale: fig.x_scale,
        lo: x_lo,
        hi: x_hi,
        px_lo: plot.x0 as f64,
        px_hi: plot.x1 as f64,
    };
    let ym = AxisMap {
        scale: fig.y_scale,
        lo: y_lo,
        hi: y_hi,
        px_lo: plot.y1 as f64,
        px_hi: plot.y0 as f64,
    };
    Ok((plot, xm, ym, x_ticks, y_ticks))
}

/// Stem base: y = 0 on a linear axis, the bottom edge on a log axis.
fn stem_base(fig: &LineFigure, plot: PixelRect, ym: &AxisMap) -> f64 {
    match fig.y_scale {
        AxisScale::Linear => ym.to_px(0.0),
        AxisScale::Log => plot.y1 as f64,
    }
}

/// The whole layout: limits, plot area, ticks and the legend's place.
fn layout(path: &Path, fig: &LineFigure) -> Result<LineLayout, PlotError> {
    let limits = data_limits(path, fig)?;
    let look = Look::new(fig.scale);
    let entries = if fig.legend == LegendPlacement::Hidden {
        Vec::new()
    } else {
        legend_entries(fig)
    };
    let lm = LegendMetrics::new(&look);
    let labels: Vec<&str> = entries
        .iter()
        .map(|&k| fig.series[k].label.as_str())
        .collect();
    let (bw, bh) = lm.size(&look, &labels);
    let inside = |plot: PixelRect, p: LegendPlacement| {
        let x0 = match p {
            LegendPlacement::TopLeft | LegendPlacement::BottomLeft => plot.x0 + lm.inset,
            _ => plot.x1 - lm.inset - bw,
        };
        let y0 = match p {
            LegendPlacement::TopLeft | LegendPlacement::TopRight => plot.y0 + lm.inset,
            _ => plot.y1 - lm.inset - bh,
        };
        PixelRect::new(x0, y0, x0 + bw, y0 + bh)
    };
    let finish =
        |(plot, x, y, x_ticks, y_ticks): (PixelRect, AxisMap, AxisMap, Vec<Tick>, Vec<Tick>),
         legend: Option<PixelRect>,
         outside: bool| LineLayout {
            plot,
            x,
            y,
            x_ticks,
            y_ticks,
            legend,
            legend_outside: outside,
            legend_entries: entries.clone(),
        };
    let outside = |look: &Look| -> Result<LineLayout, PlotError> {
        let f = frame_layout(path, fig, look, limits, bw + look.px(16.0))?;
        let x0 = fig.width as i32 - look.margin() - bw;
        let r = PixelRect::new(x0, f.0.y0, x0 + bw, f.0.y0 + bh);
        Ok(finish(f, Some(r), true))
    };
    if entries.is_empty() {
        let f = frame_layout(path, fig, &look, limits, 0)?;
        return Ok(finish(f, None, false));
    }
    match fig.legend {
        LegendPlacement::Outside => outside(&look),
        LegendPlacement::Auto => {
            let f = frame_layout(path, fig, &look, limits, 0)?;
            let base = stem_base(fig, f.0, &f.2);
            let data = data_samples(fig, &f.1, &f.2, base);
            let covered = |r: PixelRect| {
                let r = r.inflate(look.px(4.0));
                data.iter()
                    .filter(|p| r.contains(p.0.floor() as i32, p.1.floor() as i32))
                    .count()
            };
            let free = [
                LegendPlacement::TopRight,
                LegendPlacement::TopLeft,
                LegendPlacement::BottomRight,
                LegendPlacement::BottomLeft,
            ]
            .into_iter()
            .map(|p| inside(f.0, p))
            .find(|&r| covered(r) == 0 && f.0.intersect(&r) == r);
            match free {
                Some(r) => Ok(finish(f, Some(r), false)),
                None => outside(&look),
            }
        }
        LegendPlacement::Hidden => unreachable!("no entries when hidden"),
        p => {
            let f = frame_layout(path, fig, &look, limits, 0)?;
            let r = inside(f.0, p);
            Ok(finish(f, Some(r), false))
        }
    }
}

/// Renders `fig` into a canvas (used by [`line_plot`] and the tests).
pub(crate) fn render_line_plot(
    path: &Path,
    fig: &LineFigure,
) -> Result<(Canvas, LineLayout), PlotError> {
    let layout = layout(path, fig)?;
    let mut c = Canvas::new(fig.width, fig.height, axes::BACKGROUND);
    draw(&mut c, fig, &layout);
    Ok((c, layout))
}

/// Renders `fig` into an SVG document with the same layout as the PNG.
pub(crate) fn render_line_plot_svg(
    path: &Path,
    fig: &LineFigure,
) -> Result<(Svg, LineLayout), PlotError> {
    let layout = layout(path, fig)?;
    let mut d = Svg::new(fig.width, fig.height, axes::BACKGROUND);
    draw(&mut d, fig, &layout);
    Ok((d, layout))
}

/// One series' line or stems and markers.
#[allow(clippy::too_many_arguments)]
fn draw_series<D: Draw>(
    c: &mut D,
    style: SeriesStyle,
    pts: &[(f64, f64)],
    base_y: f64,
    color: Rgb,
    dash: Dash,
    hollow: bool,
    look: &Look,
) {
    let lw = LINE_WIDTH * look.scale;
    let ms = MARKER_SIZE * look.scale;
    let pattern = dash.pattern(lw);
    match style {
        SeriesStyle::Line | SeriesStyle::LineMarkers(_) => {
            c.dashed_polyline(pts, color, lw, &pattern)
        }
        SeriesStyle::Stems(_) => {
            for &(x, y) in pts.iter().filter(|p| p.0.is_finite()) {
                c.dashed_polyline(&[(x, base_y), (x, y)], color, lw, &pattern);
            }
        }
        SeriesStyle::Markers(_) => {}
    }
    if let SeriesStyle::Markers(m) | SeriesStyle::LineMarkers(m) | SeriesStyle::Stems(m) = style {
        for &(x, y) in pts {
            if hollow {
                c.hollow_marker(x, y, m, ms, color);
            } else {
                c.marker(x, y, m, ms, color);
            }
        }
    }
}

fn draw<D: Draw>(c: &mut D, fig: &LineFigure, l: &LineLayout) {
    let look = Look::new(fig.scale);
    let plot = l.plot;
    axes::grid(c, plot, &l.x, &l.x_ticks, &l.y, &l.y_ticks);
    let stems = fig
        .series
        .iter()
        .any(|s| matches!(s.style, SeriesStyle::Stems(_)));
    // Data, clipped to the plot area; a linear axis with stems gets a
    // baseline at y = 0.
    let base_y = stem_base(fig, plot, &l.y);
    c.set_clip(Some(plot));
    if stems && fig.y_scale == AxisScale::Linear {
        c.line(
            plot.x0 as f64,
            base_y,
            plot.x1 as f64,
            base_y,
            axes::INK,
            look.scale,
        );
    }
    for (k, s) in fig.series.iter().enumerate() {
        let (color, dash, hollow) = s.look(k);
        let pts = screen_points(fig, s, &l.x, &l.y);
        draw_series(c, s.style, &pts, base_y, color, dash, hollow, &look);
    }
    c.set_clip(None);

    axes::frame(c, &look, plot);
    let w = fig.width as i32;
    let below = axes::x_axis(c, &look, plot, &l.x, &l.x_ticks, true, (0, w));
    axes::y_axis(c, &look, plot, &l.y, &l.y_ticks, true);
    if !fig.x_label.is_empty() {
        c.text(
            (plot.x0 + plot.x1) / 2,
            below + look.px(8.0),
            &fig.x_label,
            &look.style().align(HAlign::Center, VAlign::Top),
        );
    }
    if !fig.y_label.is_empty() {
        c.text(
            look.margin(),
            (plot.y0 + plot.y1) / 2,
            &fig.y_label,
            &look.style().align(HAlign::Center, VAlign::Top).rotated(),
        );
    }
    if !fig.title.is_empty() {
        // Centred on the plot area, or on the image if it is too wide for that.
        let style = look.title_style_within(&fig.title, w);
        let tw = text_size(&fig.title, &style).0 as i32;
        let mid = (plot.x0 + plot.x1) / 2;
        let x = if mid - tw / 2 >= look.margin() && mid + tw / 2 <= w - look.margin() {
            mid
        } else {
            w / 2
        };
        c.text(
            x,
            look.margin(),
            &fig.title,
            &style.align(HAlign::Center, VAlign::Top),
        );
    }
    if let Some(r) = l.legend {
        draw_legend(c, fig, l, r, &look);
    }
}

/// Draws the legend box `r` with one row per entry.
fn draw_legend<D: Draw>(c: &mut D, fig: &LineFigure, l: &LineLayout, r: PixelRect, look: &Look) {
    let lm = LegendMetrics::new(look);
    c.set_clip(None);
    c.fill_rect(r, axes::BACKGROUND);
    c.stroke_rect(r, [170, 170, 170], look.rule());
    let lw = LINE_WIDTH * look.scale;
    let ms = MARKER_SIZE * look.scale;
    for (row, &k) in l.legend_entries.iter().enumerate() {
        let s = &fig.series[k];
        let (color, dash, hollow) = s.look(k);
        let cy = r.y0 + lm.pad + row as i32 * lm.row + look.text_h() / 2;
        let (sx0, sx1) = ((r.x0 + lm.pad) as f64, (r.x0 + lm.pad + lm.sample_w) as f64);
        let y = cy as f64 + 0.5;
        let mid = (sx0 + sx1) / 2.0;
        match s.style {
            SeriesStyle::Line | SeriesStyle::LineMarkers(_) => {
                c.dashed_polyline(&[(sx0, y), (sx1, y)], color, lw, &dash.pattern(lw))
            }
            SeriesStyle::Stems(_) => c.dashed_polyline(
                &[(mid, y + ms * 0.8), (mid, y)],
                color,
                lw,
                &dash.pattern(lw),
            ),
            SeriesStyle::Markers(_) => {}
        }
        if let SeriesStyle::Markers(m) | SeriesStyle::LineMarkers(m) | SeriesStyle::Stems(m) =
            s.style
        {
            if hollow {
                c.hollow_marker(mid, y, m, ms, color);
            } else {
                c.marker(mid, y, m, ms, color);
            }
        }
        c.text(
            r.x0 + lm.pad + lm.sample_w + lm.pad,
            cy,
            &s.label,
            &look.style().align(HAlign::Left, VAlign::Middle),
        );
    }
}
