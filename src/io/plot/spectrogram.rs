//! Spectrogram figures: panels of dB images side by side on shared axes,
//! with one colour bar.

use std::path::Path;

use super::axes::{self, Look};
use super::canvas::{Canvas, HAlign, PixelRect, Rgb, VAlign};
use super::colormap::colormap;
use super::draw::{ImageFormat, RASTER_FORMATS};
use super::ticks::{linear_ticks, AxisMap, AxisScale, Tick};
use super::PlotError;

/// Colour of plot area that no panel data covers (a shorter recording, a
/// lower Nyquist frequency): light grey, distinct from every map colour.
const NO_DATA: Rgb = [232, 232, 232];
/// Horizontal gap between panels at scale 1; their tick labels share it.
const PANEL_GAP: f64 = 40.0;
const COLORBAR_W: f64 = 20.0;
const COLORBAR_GAP: f64 = 24.0;
/// Frequencies shown in kHz from this top frequency up (labels stay short).
const KHZ_FROM_HZ: f64 = 2000.0;
/// Refuse figures beyond this many pixels (300 MB of RGB): a mistake, not
/// something anyone wants to look at.
const MAX_PIXELS: i64 = 100_000_000;

/// One time-frequency image.
#[derive(Clone, Debug)]
pub struct SpectrogramPanel<'a> {
    /// Shown above the panel (may be empty).
    pub title: String,
    /// Magnitudes in dB, row-major `[n_frames][n_bins]`: frame `i` bin `j`
    /// is `db[i * n_bins + j]`. `-inf` and NaN (silence, `log(0)`) show as
    /// the bottom of the colour scale.
    pub db: &'a [f64],
    pub n_frames: usize,
    pub n_bins: usize,
    /// Frame `i` is centred at `time_offset_s + i * time_step_s` seconds.
    pub time_step_s: f64,
    pub time_offset_s: f64,
    /// Bin `j` is centred at `j * freq_step_hz` Hz.
    pub freq_step_hz: f64,
}

/// How the data grid becomes pixels.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Resampling {
    /// Each pixel shows the loudest cell whose centre falls inside it, or
    /// (when the cells are larger than pixels) the cell under its centre.
    /// Taking the loudest keeps narrow partials visible when there are more
    /// frames or bins than pixels.
    #[default]
    Nearest,
    /// Bilinear interpolation in dB between cell centres, evaluated at
    /// each pixel centre: smoother when the grid is coarser than the
    /// pixels, but it can miss peaks when it is finer.
    Bilinear,
}

/// A figure of one or more spectrogram panels, see [`spectrogram_png`].
#[derive(Clone, Debug)]
pub struct SpectrogramFigure<'a> {
    /// Shown centred above everything (may be empty).
    pub title: String,
    pub panels: Vec<SpectrogramPanel<'a>>,
    /// Top of the frequency axis in Hz; default: the highest bin centre of
    /// any panel.
    pub max_freq_hz: Option<f64>,
    /// Top of the colour scale in dB; default: the largest finite value in
    /// any panel, over all bins (not only those below `max_freq_hz`, so the
    /// colours do not change when the view is cropped).
    pub db_max: Option<f64>,
    /// Bottom of the colour scale in dB; default `db_max - 80`.
    pub db_min: Option<f64>,
    pub resampling: Resampling,
    /// Size of each panel's plot area (the image itself) in pixels; the
    /// figure adds margins, labels and the colour bar around the panels.
    pub panel_width: u32,
    pub panel_height: u32,
    /// Size of text, ticks, margins and gaps (1 = 15 px per em labels), like
    /// a DPI setting; the panels keep their pixel size.
    pub scale: f64,
}

impl<'a> SpectrogramFigure<'a> {
    /// Defaults: 480 × 320 px panels, automatic frequency and dB ranges,
    /// nearest-cell resampling.
    pub fn new(title: impl Into<String>, panels: Vec<SpectrogramPanel<'a>>) -> Self {
        SpectrogramFigure {
            title: title.into(),
            panels,
            max_freq_hz: None,
            db_max: None,
            db_min: None,
            resampling: Resampling::Nearest,
            panel_width: 480,
            panel_height: 320,
            scale: 1.0,
        }
    }
}

/// Where everything landed; the tests read pixels back through these maps.
#[derive(Clone, Debug)]
// Only the tests read the fields; rendering just fills them in.
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) struct SpectrogramLayout {
    /// Per panel: plot area, time axis (s), frequency axis (Hz).
    pub panels: Vec<(PixelRect, AxisMap, AxisMap)>,
    pub colorbar: PixelRect,
    /// dB axis of the colour bar.
    pub db_map: AxisMap,
    pub x_ticks: Vec<Tick>,
}

/// Renders `fig` and writes it to `path` as a PNG, atomically. Nothing is
/// written if the figure is invalid (see [`PlotError::InvalidInput`]) or
/// `path` does not end in `.png` ([`PlotError::UnsupportedFormat`]).
pub fn spectrogram_png(path: &Path, fig: &SpectrogramFigure) -> Result<(), PlotError> {
    ImageFormat::for_path(path, RASTER_FORMATS)?;
    let (canvas, _) = render_spectrogram(path, fig)?;
    canvas.write_png(path)
}

fn invalid(path: &Path, reason: String) -> PlotError {
    PlotError::InvalidInput {
        path: path.to_path_buf(),
        reason,
    }
}

/// Checks `fig`; returns the colour-scale range (db_min, db_max).
fn validate(path: &Path, fig: &SpectrogramFigure) -> Result<(f64, f64), PlotError> {
    let bad = |r: String| invalid(path, r);
    if fig.panels.is_empty() {
        return Err(bad("spectrogram figure has no panels".into()));
    }
    if fig.panel_width < 32
        || fig.panel_height < 32
        || fig.panel_width > 8192
        || fig.panel_height > 8192
    {
        return Err(bad(format!(
            "panel size {}x{} px is outside 32..=8192",
            fig.panel_width, fig.panel_height
        )));
    }
    let mut global_max = f64::NEG_INFINITY;
    for (k, p) in fig.panels.iter().enumerate() {
        let name = if p.title.is_empty() {
            format!("panel {k}")
        } else {
            format!("panel {k} ('{}')", p.title)
        };
        if p.n_frames == 0 || p.n_bins == 0 {
            return Err(bad(format!(
                "{name} is empty ({} frames x {} bins)",
                p.n_frames, p.n_bins
            )));
        }
        if p.n_frames.checked_mul(p.n_bins) != Some(p.db.len()) {
            return Err(bad(format!(
                "{name}: {} dB values for {} frames x {} bins",
                p.db.len(),
                p.n_frames,
                p.n_bins
            )));
        }
        if !(p.time_step_s > 0.0 && p.time_step_s.is_finite() && p.time_offset_s.is_finite()) {
            return Err(bad(format!(
                "{name}: time step {} s / offset {} s must be finite and the step positive",
                p.time_step_s, p.time_offset_s
            )));
        }
        if !(p.freq_step_hz > 0.0 && p.freq_step_hz.is_finite()) {
            return Err(bad(format!(
                "{name}: frequency step {} Hz must be finite and positive",
                p.freq_step_hz
            )));
        }
        global_max =
            p.db.iter()
                .copied()
                .filter(|v| v.is_finite())
                .fold(global_max, f64::max);
    }
    if let Some(f) = fig.max_freq_hz {
        if !(f > 0.0 && f.is_finite()) {
            return Err(bad(format!(
                "max frequency {f} Hz must be finite and positive"
            )));
        }
    }
    let db_max = match fig.db_max {
        Some(v) => v,
        None if global_max.is_finite() => global_max,
        None => {
            return Err(bad(
                "no finite dB value in any panel (and no db_max given)".into()
            ))
        }
    };
    let db_min = fig.db_min.unwrap_or(db_max - 80.0);
    if !(db_min.is_finite() && db_max.is_finite() && db_min < db_max) {
        return Err(bad(format!(
            "colour scale {db_min} dB .. {db_max} dB must be finite and increasing"
        )));
    }
    Ok((db_min, db_max))
}

/// Renders the figure into a canvas (used by [`spectrogram_png`] and the
/// tests, which check where the data landed against the returned layout).
pub(crate) fn render_spectrogram(
    path: &Path,
    fig: &SpectrogramFigure,
) -> Result<(Canvas, SpectrogramLayout), PlotError> {
    let (db_min, db_max) = validate(path, fig)?;
    let (pw, ph) = (fig.panel_width as i32, fig.panel_height as i32);

    // Shared axes: the union of the panels' time extents (each cell spans
    // ±half a step around its centre) so recordings of different lengths
    // compare at the same scale; frequency from 0 to the top bin centre.
    let t_lo = fig
        .panels
        .iter()
        .map(|p| p.time_offset_s - p.time_step_s / 2.0)
        .fold(f64::INFINITY, f64::min);
    let t_hi = fig
        .panels
        .iter()
        .map(|p| p.time_offset_s + (p.n_frames as f64 - 0.5) * p.time_step_s)
        .fold(f64::NEG_INFINITY, f64::max);
    let f_top = fig.max_freq_hz.unwrap_or_else(|| {
        fig.panels
            .iter()
            .map(|p| {
                // One bin has no extent to show; give it its own cell.
                if p.n_bins == 1 {
                    p.freq_step_hz / 2.0
                } else {
                    (p.n_bins - 1) as f64 * p.freq_step_hz
                }
            })
            .fold(0.0, f64::max)
    });
    if !(t_hi - t_lo).is_finite() {
        return Err(invalid(
            path,
            format!("time axis {t_lo} s .. {t_hi} s is not representable"),
        ));
    }
    let khz = f_top >= KHZ_FROM_HZ;
    let unit = if khz { 1000.0 } else { 1.0 };

    // Frequency ticks are nice in the display unit, then mapped back to Hz.
    let y_ticks: Vec<Tick> = linear_ticks(
        0.0,
        f_top / unit,
        axes::tick_budget(ph, Look::new(fig.scale).px(48.0)),
    )
    .into_iter()
    .map(|t| Tick {
        value: t.value * unit,
        label: t.label,
    })
    .collect();
    let db_ticks = linear_ticks(
        db_min,
        db_max,
        axes::tick_budget(ph, Look::new(fig.scale).px(48.0)),
    );
    let x_ticks = linear_ticks(
        t_lo,
        t_hi,
        axes::tick_budget(pw, Look::new(fig.scale).px(90.0)),
    );

    // Layout, top to bottom: title, panel titles (and "dB"), plots, tick
    // labels, axis label. Left to right: rotated y label, y tick labels,
    // panels, colour bar and its labels.
    let look = Look::new(fig.scale);
    let (text_h, rule) = (look.text_h(), look.rule());
    let (panel_gap, cb_w, cb_gap) = (
        look.px(PANEL_GAP),
        look.px(COLORBAR_W),
        look.px(COLORBAR_GAP),
    );
    let title_h = if fig.title.is_empty() {
        0
    } else {
        look.title_h() + look.px(16.0)
    };
    let plot_y0 = look.margin() + title_h + text_h + look.px(14.0);
    let plot_y1 = plot_y0 + ph;
    let x_label_y = plot_y1 + rule + look.tick() + look.label_gap() + text_h + look.px(12.0);
    let height = x_label_y + text_h + look.descent() + look.margin();
    let y_label_x = look.margin(); // left edge of the rotated label
    let plot_x0 = y_label_x
        + text_h
        + look.descent()
        + look.px(10.0)
        + look.max_label_w(&y_ticks)
        + look.label_gap()
        + look.tick()
        + rule;
    let n = fig.panels.len() as i32;
    let panels_x1 = plot_x0 + n * pw + (n - 1) * panel_gap;
    let cb_x0 = panels_x1 + rule + cb_gap;
    let cb_x1 = cb_x0 + cb_w;
    let width = cb_x1
        + rule
        + look.tick()
        + look.label_gap()
        + look.max_label_w(&db_ticks).max(look.text_w("dB"))
        + look.margin();

    if width as i64 * height as i64 > MAX_PIXELS {
        return Err(invalid(
            path,
            format!("figure would be {width}x{height} px; use fewer or smaller panels"),
        ));
    }
    let mut c = Canvas::new(width as u32, height as u32, axes::BACKGROUND);
    let mut layout = SpectrogramLayout {
        panels: Vec::new(),
        colorbar: PixelRect::new(cb_x0, plot_y0, cb_x1, plot_y1),
        db_map: AxisMap {
            scale: AxisScale::Linear,
            lo: db_min,
            hi: db_max,
            px_lo: plot_y1 as f64,
            px_hi: plot_y0 as f64,
        },
        x_ticks: x_ticks.clone(),
    };
    let color_of = |v: f64| colormap((v - db_min) / (db_max - db_min));

    for (k, p) in fig.panels.iter().enumerate() {
        let x0 = plot_x0 + k as i32 * (pw + panel_gap);
        let plot = PixelRect::new(x0, plot_y0, x0 + pw, plot_y1);
        let xm = AxisMap {
            scale: AxisScale::Linear,
            lo: t_lo,
            hi: t_hi,
            px_lo: plot.x0 as f64,
            px_hi: plot.x1 as f64,
        };
        let ym = AxisMap {
            scale: AxisScale::Linear,
            lo: 0.0,
            hi: f_top,
            px_lo: plot.y1 as f64,
            px_hi: plot.y0 as f64,
        };
        draw_image(&mut c, plot, &xm, &ym, p, fig.resampling, &color_of);
        axes::frame(&mut c, &look, plot);
        // Labels may spill half-way into the gaps beside the panel.
        let lim = (plot.x0 - panel_gap / 2, plot.x1 + panel_gap / 2);
        let below = axes::x_axis(&mut c, &look, plot, &xm, &x_ticks, true, lim);
        axes::y_axis(&mut c, &look, plot, &ym, &y_ticks, k == 0);
        let mid = (plot.x0 + plot.x1) / 2;
        c.text(
            mid,
            below + look.px(8.0),
            "time (s)",
            &look.style().align(HAlign::Center, VAlign::Top),
        );
        if !p.title.is_empty() {
            c.text(
                mid,
                plot_y0 - look.px(12.0),
                &p.title,
                &look.style().align(HAlign::Center, VAlign::Bottom).bold(),
            );
        }
        layout.panels.push((plot, xm, ym));
    }

    let y_label = if khz {
        "frequency (kHz)"
    } else {
        "frequency (Hz)"
    };
    c.text(
        y_label_x,
        (plot_y0 + plot_y1) / 2,
        y_label,
        &look.style().align(HAlign::Center, VAlign::Top).rotated(),
    );

    // Colour bar: one row per pixel, coloured by the dB value at its centre.
    let cb = layout.colorbar;
    for y in cb.y0..cb.y1 {
        let col = color_of(layout.db_map.from_px(y as f64 + 0.5));
        c.fill_rect(PixelRect::new(cb.x0, y, cb.x1, y + 1), col);
    }
    axes::frame(&mut c, &look, cb);
    axes::y_axis_at(
        &mut c,
        &look,
        cb.x1 + rule - 1,
        &layout.db_map,
        &db_ticks,
        true,
        false,
    );
    c.text(
        (cb.x0 + cb.x1) / 2,
        plot_y0 - look.px(12.0),
        "dB",
        &look.style().align(HAlign::Center, VAlign::Bottom),
    );

    if !fig.title.is_empty() {
        c.text(
            width / 2,
            look.margin(),
            &fig.title,
            &look
                .title_style_within(&fig.title, width)
                .align(HAlign::Center, VAlign::Top),
        );
    }
    Ok((c, layout))
}

/// For each pixel along one axis, the range of data cells it shows (see
/// [`Resampling::Nearest`]), or `None` outside the data. Cell `i` is centred
/// at `c0 + i * step` and spans half a step either side.
fn nearest_spans(
    map: &AxisMap,
    p0: i32,
    p1: i32,
    c0: f64,
    step: f64,
    n: usize,
) -> Vec<Option<(usize, usize)>> {
    let ext_lo = c0 - step / 2.0;
    let ext_hi = c0 + (n as f64 - 0.5) * step;
    (p0..p1)
        .map(|p| {
            let (a, b) = {
                let (u, v) = (map.from_px(p as f64), map.from_px(p as f64 + 1.0));
                (u.min(v), u.max(v))
            };
            // Cells with centres in [a, b).
            let lo = ((a - c0) / step).ceil().max(0.0);
            let hi = (((b - c0) / step).ceil() - 1.0).min(n as f64 - 1.0);
            if lo <= hi {
                return Some((lo as usize, hi as usize));
            }
            let mid = (a + b) / 2.0;
            if mid >= ext_lo && mid < ext_hi {
                let i = ((mid - c0) / step).round().clamp(0.0, n as f64 - 1.0) as usize;
                Some((i, i))
            } else {
                None
            }
        })
        .collect()
}

/// For each pixel along one axis, the two cells around its centre and the
/// weight of the second (bilinear), or `None` outside the data.
fn bilinear_spans(
    map: &AxisMap,
    p0: i32,
    p1: i32,
    c0: f64,
    step: f64,
    n: usize,
) -> Vec<Option<(usize, usize, f64)>> {
    let ext_lo = c0 - step / 2.0;
    let ext_hi = c0 + (n as f64 - 0.5) * step;
    (p0..p1)
        .map(|p| {
            let v = map.from_px(p as f64 + 0.5);
            if !(v >= ext_lo && v < ext_hi) {
                return None;
            }
            // Beyond the outer cell centres the edge cell is held.
            let x = ((v - c0) / step).clamp(0.0, n as f64 - 1.0);
            let i = (x.floor() as usize).min(n - 1);
            let j = (i + 1).min(n - 1);
            Some((i, j, x - i as f64))
        })
        .collect()
}

fn draw_image(
    c: &mut Canvas,
    plot: PixelRect,
    xm: &AxisMap,
    ym: &AxisMap,
    p: &SpectrogramPanel,
    resampling: Resampling,
    color_of: &dyn Fn(f64) -> Rgb,
) {
    c.set_clip(Some(plot));
    c.fill_rect(plot, NO_DATA);
    let at = |i: usize, j: usize| p.db[i * p.n_bins + j];
    match resampling {
        Resampling::Nearest => {
            let cols = nearest_spans(
                xm,
                plot.x0,
                plot.x1,
                p.time_offset_s,
                p.time_step_s,
                p.n_frames,
            );
            let rows = nearest_spans(ym, plot.y0, plot.y1, 0.0, p.freq_step_hz, p.n_bins);
            for (dy, row) in rows.iter().enumerate() {
                let Some((j0, j1)) = *row else { continue };
                for (dx, col) in cols.iter().enumerate() {
                    let Some((i0, i1)) = *col else { continue };
                    // f64::max ignores NaN, so a NaN cell never hides a loud one.
                    let mut v = f64::NEG_INFINITY;
                    for i in i0..=i1 {
                        for j in j0..=j1 {
                            v = v.max(at(i, j));
                        }
                    }
                    c.put(plot.x0 + dx as i32, plot.y0 + dy as i32, color_of(v));
                }
            }
        }
        Resampling::Bilinear => {
            let cols = bilinear_spans(
                xm,
                plot.x0,
                plot.x1,
                p.time_offset_s,
                p.time_step_s,
                p.n_frames,
            );
            let rows = bilinear_spans(ym, plot.y0, plot.y1, 0.0, p.freq_step_hz, p.n_bins);
            for (dy, row) in rows.iter().enumerate() {
                let Some((j0, j1, fy)) = *row else { continue };
                for (dx, col) in cols.iter().enumerate() {
                    let Some((i0, i1, fx)) = *col else { continue };
                    let q = [at(i0, j0), at(i1, j0), at(i0, j1), at(i1, j1)];
                    let v = if q.iter().all(|v| v.is_finite()) {
                        let a = q[0] + (q[1] - q[0]) * fx;
                        let b = q[2] + (q[3] - q[2]) * fx;
                        a + (b - a) * fy
                    } else {
                        // -inf next to finite values would smear the floor
                        // over the whole cell; use the nearest cell instead.
                        let i = if fx < 0.5 { i0 } else { i1 };
                        let j = if fy < 0.5 { j0 } else { j1 };
                        at(i, j)
                    };
                    c.put(plot.x0 + dx as i32, plot.y0 + dy as i32, color_of(v));
                }
            }
        }
    }
    c.set_clip(None);
}
