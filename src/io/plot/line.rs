//! Line and scatter figures on linear or log axes, with a legend.

use std::path::Path;

use super::axes::{self, MARGIN, TEXT_H, TICK};
use super::canvas::{Canvas, HAlign, Marker, PixelRect, Rgb, VAlign};
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
}

impl Series {
    pub fn new(label: impl Into<String>, x: Vec<f64>, y: Vec<f64>, style: SeriesStyle) -> Series {
        Series {
            label: label.into(),
            x,
            y,
            style,
            color: None,
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
}

/// Where the legend goes, inside the plot area.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LegendPlacement {
    /// The corner covering the fewest data.
    #[default]
    Auto,
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
    /// Whole image size in pixels.
    pub width: u32,
    pub height: u32,
}

impl LineFigure {
    /// Linear axes, automatic limits, legend placed automatically, 960 × 640 px.
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
            width: 960,
            height: 640,
        }
    }
}

const LINE_WIDTH: f64 = 2.0;
const MARKER_SIZE: f64 = 9.0;

/// Where everything landed (for the tests).
#[derive(Clone, Debug)]
// Only the tests read the fields; rendering just fills them in.
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) struct LineLayout {
    pub plot: PixelRect,
    pub x: AxisMap,
    pub y: AxisMap,
    pub x_ticks: Vec<Tick>,
    pub legend: Option<PixelRect>,
}

/// Renders `fig` and writes it to `path` as a PNG, atomically. Nothing is
/// written if the figure is invalid (see [`PlotError::InvalidInput`]).
pub fn line_plot_png(path: &Path, fig: &LineFigure) -> Result<(), PlotError> {
    let (canvas, _) = render_line_plot(path, fig)?;
    canvas.write_png(path)
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

pub(crate) fn render_line_plot(
    path: &Path,
    fig: &LineFigure,
) -> Result<(Canvas, LineLayout), PlotError> {
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

    // Vertical layout first: the y ticks (and so the left margin) depend
    // only on the plot height.
    let (w, h) = (fig.width as i32, fig.height as i32);
    let title_h = if fig.title.is_empty() { 0 } else { TEXT_H + 14 };
    // Half a label of headroom so the top y tick label is not cut.
    let plot_y0 = MARGIN + title_h + TEXT_H / 2 + 2;
    let x_label_h = if fig.x_label.is_empty() {
        0
    } else {
        TEXT_H + 10
    };
    let plot_y1 = h - MARGIN - x_label_h - TEXT_H - axes::LABEL_GAP - TICK - 1;
    let y_ticks = axis_ticks(
        fig.y_scale,
        y_lo,
        y_hi,
        axes::tick_budget(plot_y1 - plot_y0, 56),
    );
    let y_label_w = if fig.y_label.is_empty() {
        0
    } else {
        TEXT_H + 10
    };
    let plot_x0 = MARGIN + y_label_w + axes::max_label_w(&y_ticks) + axes::LABEL_GAP + TICK + 1;
    // Room for half of a tick label centred on the right edge.
    let plot_x1 = w - MARGIN - 24;
    if plot_x1 - plot_x0 < 40 || plot_y1 - plot_y0 < 40 {
        return Err(bad(format!(
            "image size {}x{} px leaves no room for the plot",
            fig.width, fig.height
        )));
    }
    let plot = PixelRect::new(plot_x0, plot_y0, plot_x1, plot_y1);
    let x_ticks = axis_ticks(
        fig.x_scale,
        x_lo,
        x_hi,
        axes::tick_budget(plot.width(), 100),
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

    let mut c = Canvas::new(fig.width, fig.height, axes::BACKGROUND);
    axes::grid(&mut c, plot, &xm, &x_ticks, &ym, &y_ticks);

    // Data, clipped to the plot area. Stem bases: y = 0 on a linear axis
    // (drawn as a baseline), the bottom edge on a log axis.
    let base_y = match fig.y_scale {
        AxisScale::Linear => ym.to_px(0.0),
        AxisScale::Log => plot.y1 as f64,
    };
    if stems && fig.y_scale == AxisScale::Linear {
        c.set_clip(Some(plot));
        c.line(
            plot.x0 as f64,
            base_y,
            plot.x1 as f64,
            base_y,
            axes::INK,
            1.0,
        );
    }
    let mut screen_pts: Vec<(f64, f64)> = Vec::new();
    for (k, s) in fig.series.iter().enumerate() {
        let color = s.color.unwrap_or(PALETTE[k % PALETTE.len()]);
        let pts: Vec<(f64, f64)> =
            s.x.iter()
                .zip(&s.y)
                .map(|(&x, &y)| {
                    if valid(fig.x_scale, x) && valid(fig.y_scale, y) {
                        (xm.to_px(x), ym.to_px(y))
                    } else {
                        (f64::NAN, f64::NAN)
                    }
                })
                .collect();
        c.set_clip(Some(plot));
        match s.style {
            SeriesStyle::Line | SeriesStyle::LineMarkers(_) => c.polyline(&pts, color, LINE_WIDTH),
            SeriesStyle::Stems(_) => {
                for &(x, y) in pts.iter().filter(|p| p.0.is_finite()) {
                    c.line(x, base_y, x, y, color, LINE_WIDTH);
                }
            }
            SeriesStyle::Markers(_) => {}
        }
        if let SeriesStyle::Markers(m) | SeriesStyle::LineMarkers(m) | SeriesStyle::Stems(m) =
            s.style
        {
            for &(x, y) in &pts {
                c.marker(x, y, m, MARKER_SIZE, color);
            }
        }
        // For legend placement: points, plus samples along segments so a
        // line crossing a corner counts even with no point there.
        for win in pts.windows(2) {
            let (a, b) = (win[0], win[1]);
            if a.0.is_finite() && b.0.is_finite() {
                let n = ((b.0 - a.0).hypot(b.1 - a.1) / 6.0).ceil().min(500.0) as usize;
                for i in 0..n {
                    let t = i as f64 / n as f64;
                    screen_pts.push((a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1)));
                }
            }
        }
        screen_pts.extend(pts.iter().filter(|p| p.0.is_finite()));
    }
    c.set_clip(None);

    axes::frame(&mut c, plot);
    let below = axes::x_axis(&mut c, plot, &xm, &x_ticks, true, (0, w));
    axes::y_axis(&mut c, plot, &ym, &y_ticks, true);
    if !fig.x_label.is_empty() {
        c.text(
            (plot.x0 + plot.x1) / 2,
            below + 10,
            &fig.x_label,
            &axes::style().align(HAlign::Center, VAlign::Top),
        );
    }
    if !fig.y_label.is_empty() {
        c.text(
            MARGIN,
            (plot.y0 + plot.y1) / 2,
            &fig.y_label,
            &axes::style().align(HAlign::Center, VAlign::Top).rotated(),
        );
    }
    if !fig.title.is_empty() {
        c.text(
            w / 2,
            MARGIN,
            &fig.title,
            &axes::style().align(HAlign::Center, VAlign::Top).bold(),
        );
    }
    let legend = draw_legend(&mut c, plot, fig, &screen_pts);
    Ok((
        c,
        LineLayout {
            plot,
            x: xm,
            y: ym,
            x_ticks,
            legend,
        },
    ))
}

const LEGEND_PAD: i32 = 10;
const LEGEND_SAMPLE_W: i32 = 32;
const LEGEND_ROW: i32 = TEXT_H + 10;
const LEGEND_INSET: i32 = 10;

/// Draws the legend box; returns where it went (`None` if there is none).
fn draw_legend(
    c: &mut Canvas,
    plot: PixelRect,
    fig: &LineFigure,
    data: &[(f64, f64)],
) -> Option<PixelRect> {
    let entries: Vec<(usize, &Series)> = fig
        .series
        .iter()
        .enumerate()
        .filter(|(_, s)| !s.label.is_empty())
        .collect();
    if entries.is_empty() || fig.legend == LegendPlacement::Hidden {
        return None;
    }
    let text_w = entries
        .iter()
        .map(|(_, s)| axes::text_w(&s.label))
        .max()
        .unwrap_or(0);
    let bw = LEGEND_PAD * 2 + LEGEND_SAMPLE_W + 10 + text_w;
    let bh = LEGEND_PAD * 2 + LEGEND_ROW * entries.len() as i32 - 10;
    let corner = |p: LegendPlacement| {
        let x0 = match p {
            LegendPlacement::TopLeft | LegendPlacement::BottomLeft => plot.x0 + LEGEND_INSET,
            _ => plot.x1 - LEGEND_INSET - bw,
        };
        let y0 = match p {
            LegendPlacement::TopLeft | LegendPlacement::TopRight => plot.y0 + LEGEND_INSET,
            _ => plot.y1 - LEGEND_INSET - bh,
        };
        PixelRect::new(x0, y0, x0 + bw, y0 + bh)
    };
    let place = match fig.legend {
        LegendPlacement::Auto => {
            // Fewest data samples under the box wins; ties keep this order.
            let order = [
                LegendPlacement::TopRight,
                LegendPlacement::TopLeft,
                LegendPlacement::BottomRight,
                LegendPlacement::BottomLeft,
            ];
            let count = |r: PixelRect| {
                let r = r.inflate(4);
                data.iter()
                    .filter(|p| r.contains(p.0.floor() as i32, p.1.floor() as i32))
                    .count()
            };
            let mut best = order[0];
            let mut best_n = usize::MAX;
            for p in order {
                let n = count(corner(p));
                if n < best_n {
                    best = p;
                    best_n = n;
                }
            }
            best
        }
        p => p,
    };
    let r = corner(place);
    c.set_clip(Some(plot));
    c.fill_rect(r, axes::BACKGROUND);
    c.stroke_rect(r, [170, 170, 170], 1);
    for (row, (k, s)) in entries.iter().enumerate() {
        let color = s.color.unwrap_or(PALETTE[k % PALETTE.len()]);
        let cy = r.y0 + LEGEND_PAD + row as i32 * LEGEND_ROW + TEXT_H / 2;
        let (sx0, sx1) = (
            (r.x0 + LEGEND_PAD) as f64,
            (r.x0 + LEGEND_PAD + LEGEND_SAMPLE_W) as f64,
        );
        let y = cy as f64 + 0.5;
        let mid = (sx0 + sx1) / 2.0;
        match s.style {
            SeriesStyle::Line => c.line(sx0, y, sx1, y, color, LINE_WIDTH),
            SeriesStyle::LineMarkers(m) => {
                c.line(sx0, y, sx1, y, color, LINE_WIDTH);
                c.marker(mid, y, m, MARKER_SIZE, color);
            }
            SeriesStyle::Markers(m) => c.marker(mid, y, m, MARKER_SIZE, color),
            SeriesStyle::Stems(m) => {
                c.line(mid, y + 7.0, mid, y, color, LINE_WIDTH);
                c.marker(mid, y - 1.0, m, MARKER_SIZE, color);
            }
        }
        c.text(
            r.x0 + LEGEND_PAD + LEGEND_SAMPLE_W + 10,
            cy,
            &s.label,
            &axes::style().align(HAlign::Left, VAlign::Middle),
        );
    }
    c.set_clip(None);
    Some(r)
}
