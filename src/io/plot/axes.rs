//! Drawing shared by the figure types: frame, ticks, tick labels, grid and
//! the look (colours, sizes) they have in common.
//!
//! Sizes scale together with a figure's `scale` ([`Look`]), like a DPI
//! setting: a figure drawn at scale 2 is the scale-1 figure with every
//! length doubled, so a large image for print keeps its proportions.

use super::canvas::{text_size, HAlign, PixelRect, Rgb, TextStyle, VAlign};
use super::draw::Draw;
use super::ticks::{AxisMap, Tick};

pub(crate) const BACKGROUND: Rgb = [255, 255, 255];
/// Text and axis colour: near-black reads as black but is softer on white.
pub(crate) const INK: Rgb = [34, 34, 34];
pub(crate) const GRID_MAJOR: Rgb = [226, 226, 226];
pub(crate) const GRID_MINOR: Rgb = [242, 242, 242];

/// The sizes of a figure at a given scale (1 = the base look: 15 px per em
/// for labels, about 11 px capitals, 6 px ticks, 16 px margins).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Look {
    pub scale: f64,
}

impl Look {
    pub fn new(scale: f64) -> Look {
        Look {
            scale: if scale.is_finite() && scale > 0.0 {
                scale
            } else {
                1.0
            },
        }
    }
    /// A length of `base` pixels at scale 1, rounded, at least 1.
    pub fn px(&self, base: f64) -> i32 {
        (base * self.scale).round().max(1.0) as i32
    }
    /// Em size of labels, tick labels and legends.
    pub fn font_size(&self) -> f32 {
        (15.0 * self.scale) as f32
    }
    /// Em size of titles (bold).
    pub fn title_size(&self) -> f32 {
        (17.0 * self.scale) as f32
    }
    /// The label style: near-black, top-left anchored.
    pub fn style(&self) -> TextStyle {
        TextStyle::new(self.font_size(), INK)
    }
    pub fn title_style(&self) -> TextStyle {
        TextStyle::new(self.title_size(), INK).bold()
    }
    /// The title style for `title` on an image `width` pixels wide: the usual size, or smaller
    /// so that the whole title fits between the margins (a diagnosis names every accepted
    /// effect in its title, and a cut title hides which).
    pub fn title_style_within(&self, title: &str, width: i32) -> TextStyle {
        let room = (width - 2 * self.margin()).max(1) as f32;
        let wide = text_size(title, &self.title_style()).0 as f32;
        if wide <= room {
            self.title_style()
        } else {
            TextStyle::new(self.title_size() * room / wide, INK).bold()
        }
    }
    /// Cap height of label text in pixels.
    pub fn text_h(&self) -> i32 {
        text_size("H", &self.style()).1 as i32
    }
    /// Cap height of the title in pixels.
    pub fn title_h(&self) -> i32 {
        text_size("H", &self.title_style()).1 as i32
    }
    /// Depth of descenders below the baseline of label text.
    pub fn descent(&self) -> i32 {
        (0.24 * self.font_size() as f64).ceil() as i32
    }
    /// Width of `s` as a label.
    pub fn text_w(&self, s: &str) -> i32 {
        text_size(s, &self.style()).0 as i32
    }
    /// Major tick length (outside the frame, so ticks never hide data).
    pub fn tick(&self) -> i32 {
        self.px(6.0)
    }
    pub fn minor_tick(&self) -> i32 {
        self.px(3.0)
    }
    /// Gap between a tick and its label.
    pub fn label_gap(&self) -> i32 {
        self.px(4.0)
    }
    /// Outer margin of every figure.
    pub fn margin(&self) -> i32 {
        self.px(16.0)
    }
    /// Width of the frame and tick lines.
    pub fn rule(&self) -> i32 {
        self.px(1.0)
    }
    /// Widest label among `ticks` in pixels (0 if none).
    pub fn max_label_w(&self, ticks: &[Tick]) -> i32 {
        ticks
            .iter()
            .filter_map(|t| t.label.as_deref())
            .map(|l| self.text_w(l))
            .max()
            .unwrap_or(0)
    }
}

/// A frame `look.rule()` pixels wide drawn just outside `plot`, so the plot
/// area itself is entirely data.
pub(crate) fn frame<D: Draw>(c: &mut D, look: &Look, plot: PixelRect) {
    c.set_clip(None);
    let t = look.rule();
    c.stroke_rect(plot.inflate(t), INK, t);
}

/// Light grid lines across `plot` at the ticks of both axes (major ticks
/// darker than minor ones).
pub(crate) fn grid<D: Draw>(
    c: &mut D,
    plot: PixelRect,
    x: &AxisMap,
    xt: &[Tick],
    y: &AxisMap,
    yt: &[Tick],
) {
    c.set_clip(Some(plot));
    // Minor first so a major line always wins where both fall.
    for major in [false, true] {
        let col = if major { GRID_MAJOR } else { GRID_MINOR };
        for t in xt.iter().filter(|t| t.label.is_some() == major) {
            let px = x.tick_pixel(t.value);
            c.fill_rect(PixelRect::new(px, plot.y0, px + 1, plot.y1), col);
        }
        for t in yt.iter().filter(|t| t.label.is_some() == major) {
            let py = y.tick_pixel(t.value);
            c.fill_rect(PixelRect::new(plot.x0, py, plot.x1, py + 1), col);
        }
    }
    c.set_clip(None);
}

/// Ticks below the bottom frame line of `plot` and, if `labels`, their
/// labels centred under them. A label that would overlap the previous one
/// or leave `[lim_lo, lim_hi)` horizontally is skipped rather than drawn
/// over something else. Returns the row just below the labels.
pub(crate) fn x_axis<D: Draw>(
    c: &mut D,
    look: &Look,
    plot: PixelRect,
    map: &AxisMap,
    ticks: &[Tick],
    labels: bool,
    (lim_lo, lim_hi): (i32, i32),
) -> i32 {
    c.set_clip(None);
    let rule = look.rule();
    let base = plot.y1 + rule; // the frame rows are plot.y1 .. plot.y1 + rule
    let mut last_right = i32::MIN;
    for t in ticks {
        let px = map.tick_pixel(t.value);
        let len = if t.label.is_some() {
            look.tick()
        } else {
            look.minor_tick()
        };
        let x0 = px - (rule - 1) / 2;
        c.fill_rect(PixelRect::new(x0, base, x0 + rule, base + len), INK);
        if let (true, Some(l)) = (labels, &t.label) {
            let w = look.text_w(l);
            let (l0, l1) = (px - w / 2, px - w / 2 + w);
            if l0 >= last_right + look.px(8.0) && l0 >= lim_lo && l1 <= lim_hi {
                c.text(
                    px,
                    base + look.tick() + look.label_gap(),
                    l,
                    &look.style().align(HAlign::Center, VAlign::Top),
                );
                last_right = l1;
            }
        }
    }
    base + look.tick() + look.label_gap() + look.text_h() + look.descent()
}

/// Ticks left of the left frame line of `plot` and, if `labels`, their
/// labels right-aligned against them, vertically centred on the tick.
/// Labels that would overlap the previous one are skipped.
pub(crate) fn y_axis<D: Draw>(
    c: &mut D,
    look: &Look,
    plot: PixelRect,
    map: &AxisMap,
    ticks: &[Tick],
    labels: bool,
) {
    y_axis_at(c, look, plot.x0 - look.rule(), map, ticks, labels, true);
}

/// Ticks and labels on the vertical rule starting at column `edge` (the
/// frame's first column on the left, its last on the right); on its left
/// side if `left`, else on its right (colour bars).
pub(crate) fn y_axis_at<D: Draw>(
    c: &mut D,
    look: &Look,
    edge: i32,
    map: &AxisMap,
    ticks: &[Tick],
    labels: bool,
    left: bool,
) {
    c.set_clip(None);
    let rule = look.rule();
    let mut last: Option<i32> = None;
    for t in ticks {
        let py = map.tick_pixel(t.value);
        let len = if t.label.is_some() {
            look.tick()
        } else {
            look.minor_tick()
        };
        let y0 = py - (rule - 1) / 2;
        if left {
            c.fill_rect(PixelRect::new(edge - len, y0, edge, y0 + rule), INK);
        } else {
            c.fill_rect(PixelRect::new(edge + 1, y0, edge + 1 + len, y0 + rule), INK);
        }
        if let (true, Some(l)) = (labels, &t.label) {
            if last.is_some_and(|p| (p - py).abs() < look.text_h() + look.px(4.0)) {
                continue;
            }
            let st = if left {
                look.style().align(HAlign::Right, VAlign::Middle)
            } else {
                look.style().align(HAlign::Left, VAlign::Middle)
            };
            let x = if left {
                edge - look.tick() - look.label_gap()
            } else {
                edge + 1 + look.tick() + look.label_gap()
            };
            c.text(x, py, l, &st);
            last = Some(py);
        }
    }
}

/// How many major ticks fit along `len_px` pixels, one per `per_tick` pixels.
pub(crate) fn tick_budget(len_px: i32, per_tick: i32) -> usize {
    (len_px / per_tick.max(1)).clamp(2, 10) as usize
}
