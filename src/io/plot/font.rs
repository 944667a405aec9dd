//! Figure text: DejaVu Sans (regular and bold), embedded in the binary and
//! rasterised with `ab_glyph`.
//!
//! Why a real outline font: figures go into papers, where a scaled bitmap
//! font looks jagged and cannot write the symbols the quantities are named
//! with (α, ν, λ, Δ, σ, ², µ, −, ×, …). Why embedded: a figure must not
//! depend on which fonts a machine has, and a clone alone must build, so the
//! two TTF files live in `assets/fonts/` (licence beside them: the Bitstream
//! Vera and Arev licences, free to redistribute unmodified) and are compiled
//! in with `include_bytes!`; no system font is ever read.
//!
//! Sizes are em sizes in pixels (what CSS calls `font-size`). Layout is a
//! single line: advances plus pair kerning, no shaping (neither Latin nor
//! Greek labels need it). A character the font lacks draws as the font's
//! `.notdef` box, so a missing glyph is visible rather than silently dropped.
//!
//! [`layout`] places glyphs along a baseline; the raster ([`super::Canvas`])
//! and vector ([`super::svg`]) writers both start from it, so a label takes
//! the same room in a PNG and in an SVG.

use ab_glyph::{Font, FontRef, GlyphId, Outline};
use std::sync::OnceLock;

static REGULAR_TTF: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSans.ttf");
static BOLD_TTF: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSans-Bold.ttf");

/// Which of the two embedded faces.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(crate) enum Face {
    Regular,
    Bold,
}

/// One embedded face with the metrics layout needs, in font units.
pub(crate) struct LoadedFace {
    pub font: FontRef<'static>,
    pub units_per_em: f32,
    /// Height of a flat capital (from the outline of `H`): what text
    /// alignment measures, so labels line up on their capitals.
    pub cap_height: f32,
    /// Depth of the lowest descender below the baseline (positive).
    pub descent: f32,
    /// Height of the tallest ascender or accent above the baseline.
    pub ascent: f32,
}

fn load(bytes: &'static [u8]) -> LoadedFace {
    // The bytes are compiled in and checked by the unit tests; a failure here
    // is a broken build, not a user error.
    let font = FontRef::try_from_slice(bytes).expect("embedded DejaVu Sans parses");
    let units_per_em = font.units_per_em().unwrap_or(2048.0);
    let cap_height = font
        .outline(font.glyph_id('H'))
        // ab_glyph keeps the top (y max, font units point up) in `min.y`.
        .map(|o| (o.bounds.min.y - o.bounds.max.y).abs())
        .unwrap_or(0.73 * units_per_em);
    LoadedFace {
        units_per_em,
        cap_height,
        descent: -font.descent_unscaled(),
        ascent: font.ascent_unscaled(),
        font,
    }
}

pub(crate) fn face(f: Face) -> &'static LoadedFace {
    static REGULAR: OnceLock<LoadedFace> = OnceLock::new();
    static BOLD: OnceLock<LoadedFace> = OnceLock::new();
    match f {
        Face::Regular => REGULAR.get_or_init(|| load(REGULAR_TTF)),
        Face::Bold => BOLD.get_or_init(|| load(BOLD_TTF)),
    }
}

/// A glyph placed on a baseline: `x` is its origin in pixels from the start
/// of the line.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Placed {
    pub id: GlyphId,
    pub x: f32,
}

/// A laid-out line of text at `size` px per em.
pub(crate) struct Line {
    pub face: Face,
    pub size: f32,
    pub glyphs: Vec<Placed>,
    /// Advance width of the whole line in pixels.
    pub width: f32,
}

impl Line {
    /// Pixels per font unit.
    pub fn scale(&self) -> f32 {
        self.size / face(self.face).units_per_em
    }
    /// Cap height in pixels.
    pub fn cap_height(&self) -> f32 {
        face(self.face).cap_height * self.scale()
    }
    pub fn descent(&self) -> f32 {
        face(self.face).descent * self.scale()
    }
    pub fn ascent(&self) -> f32 {
        face(self.face).ascent * self.scale()
    }
    /// The outline of glyph `id` in font units (y up), if it has ink.
    pub fn outline(&self, id: GlyphId) -> Option<Outline> {
        face(self.face).font.outline(id)
    }
}

/// Lays `text` out on one line at `size` px per em.
pub(crate) fn layout(text: &str, size: f32, f: Face) -> Line {
    let lf = face(f);
    let s = size / lf.units_per_em;
    let mut x = 0.0f32;
    let mut prev: Option<GlyphId> = None;
    let mut glyphs = Vec::with_capacity(text.len());
    for ch in text.chars() {
        let id = lf.font.glyph_id(ch);
        if let Some(p) = prev {
            x += lf.font.kern_unscaled(p, id) * s;
        }
        glyphs.push(Placed { id, x });
        x += lf.font.h_advance_unscaled(id) * s;
        prev = Some(id);
    }
    Line {
        face: f,
        size,
        glyphs,
        width: x,
    }
}

/// Whether the font has a glyph for `ch` (tests and callers that want to
/// fall back to a spelled-out name).
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) fn has_glyph(ch: char, f: Face) -> bool {
    face(f).font.glyph_id(ch).0 != 0
}
