//! Drawing shared by the figure types: frame, ticks, tick labels, grid and
//! the look (colours, sizes) they have in common.

use super::canvas::{text_size, Canvas, HAlign, PixelRect, Rgb, TextStyle, VAlign};
use super::ticks::{AxisMap, Tick};

pub(crate) const BACKGROUND: Rgb = [255, 255, 255];
/// Text and axis colour: near-black reads as black but is softer on white.
pub(crate) const INK: Rgb = [34, 34, 34];
pub(crate) const GRID_MAJOR: Rgb = [226, 226, 226];
pub(crate) const GRID_MINOR: Rgb = [242, 242, 242];
/// Font magnification for all figure text: 14 px capitals, legible on any
/// screen without being dominant.
pub(crate) const FONT_SCALE: u32 = 2;
/// Cap height of figure text in pixels.
pub(crate) const TEXT_H: i32 = 7 * FONT_SCALE as i32;
/// Major tick length (outside the frame, so ticks never hide data).
pub(crate) const TICK: i32 = 6;
pub(crate) const MINOR_TICK: i32 = 3;
/// Gap between a tick and its label.
pub(crate) const LABEL_GAP: i32 = 4;
/// Outer margin of every figure.
pub(crate) const MARGIN: i32 = 16;

pub(crate) fn style() -> TextStyle {
    TextStyle::new(FONT_SCALE, INK)
}

pub(crate) fn text_w(s: &str) -> i32 {
    text_size(s, FONT_SCALE).0 as i32
}

/// Widest label among `ticks` in pixels (0 if none).
pub(crate) fn max_label_w(ticks: &[Tick]) -> i32 {
    ticks
        .iter()
        .filter_map(|t| t.label.as_deref())
        .map(text_w)
        .max()
        .unwrap_or(0)
}

/// A 1 px frame drawn just outside `plot`, so the plot area itself is
/// entirely data.
pub(crate) fn frame(c: &mut Canvas, plot: PixelRect) {
    c.set_clip(None);
    c.stroke_rect(plot.inflate(1), INK, 1);
}

/// Light grid lines across `plot` at the ticks of both axes (major ticks
/// darker than minor ones).
pub(crate) fn grid(
    c: &mut Canvas,
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
pub(crate) fn x_axis(
    c: &mut Canvas,
    plot: PixelRect,
    map: &AxisMap,
    ticks: &[Tick],
    labels: bool,
    (lim_lo, lim_hi): (i32, i32),
) -> i32 {
    c.set_clip(None);
    let base = plot.y1 + 1; // the frame row is plot.y1
    let mut last_right = i32::MIN;
    for t in ticks {
        let px = map.tick_pixel(t.value);
        let len = if t.label.is_some() { TICK } else { MINOR_TICK };
        c.fill_rect(PixelRect::new(px, base, px + 1, base + len), INK);
        if let (true, Some(l)) = (labels, &t.label) {
            let w = text_w(l);
            let (l0, l1) = (px - w / 2, px - w / 2 + w);
            if l0 >= last_right + 8 && l0 >= lim_lo && l1 <= lim_hi {
                c.text(
                    px,
                    base + TICK + LABEL_GAP,
                    l,
                    &style().align(HAlign::Center, VAlign::Top),
                );
                last_right = l1;
            }
        }
    }
    base + TICK + LABEL_GAP + TEXT_H
}

/// Ticks left of the left frame line of `plot` and, if `labels`, their
/// labels right-aligned against them, vertically centred on the tick.
/// Labels that would overlap the previous one are skipped.
pub(crate) fn y_axis(c: &mut Canvas, plot: PixelRect, map: &AxisMap, ticks: &[Tick], labels: bool) {
    y_axis_at(c, plot.x0 - 1, map, ticks, labels, true);
}

/// Ticks and labels on the vertical line at column `edge` (the frame
/// column); on its left side if `left`, else on its right (colour bars).
pub(crate) fn y_axis_at(
    c: &mut Canvas,
    edge: i32,
    map: &AxisMap,
    ticks: &[Tick],
    labels: bool,
    left: bool,
) {
    c.set_clip(None);
    let mut last: Option<i32> = None;
    for t in ticks {
        let py = map.tick_pixel(t.value);
        let len = if t.label.is_some() { TICK } else { MINOR_TICK };
        if left {
            c.fill_rect(PixelRect::new(edge - len, py, edge, py + 1), INK);
        } else {
            c.fill_rect(PixelRect::new(edge + 1, py, edge + 1 + len, py + 1), INK);
        }
        if let (true, Some(l)) = (labels, &t.label) {
            if last.is_some_and(|p| (p - py).abs() < TEXT_H + 4) {
                continue;
            }
            let st = if left {
                style().align(HAlign::Right, VAlign::Middle)
            } else {
                style().align(HAlign::Left, VAlign::Middle)
            };
            let x = if left {
                edge - TICK - LABEL_GAP
            } else {
                edge + 1 + TICK + LABEL_GAP
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
