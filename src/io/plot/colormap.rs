//! The colour scale for spectrograms: dark violet → blue → teal → green →
//! yellow, perceptually ordered so louder always reads as lighter.
//!
//! The control points were designed for this module in OKLab: lightness
//! L rises linearly from 0.25 to 0.95, hue turns from 305° down to 105°
//! (through blue, teal and green), and chroma stays near 0.1 in the dark half
//! and rises to 0.16 at the yellow end, each point pulled back into the sRGB
//! gamut. Because L is linear in the scale position, equal steps in dB give
//! equal steps in perceived lightness; interpolating linearly in sRGB between
//! nine points keeps that to within a few percent (the unit tests check
//! that CIE L* rises monotonically along the map).

use super::canvas::Rgb;

const POINTS: [Rgb; 9] = [
    [46, 10, 74],
    [47, 47, 104],
    [41, 79, 127],
    [29, 112, 145],
    [15, 145, 156],
    [11, 179, 157],
    [98, 208, 142],
    [176, 230, 117],
    [255, 244, 101],
];

/// Colour at position `t` in `[0, 1]` (clamped; NaN maps to 0, the floor,
/// since the only NaN a dB image should hold is an undefined `log(0)`).
pub fn colormap(t: f64) -> Rgb {
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
    let x = t * (POINTS.len() - 1) as f64;
    let i = (x.floor() as usize).min(POINTS.len() - 2);
    let f = x - i as f64;
    let (a, b) = (POINTS[i], POINTS[i + 1]);
    let mix = |k: usize| (a[k] as f64 + (b[k] as f64 - a[k] as f64) * f).round() as u8;
    [mix(0), mix(1), mix(2)]
}

/// CIE L* (0..100) of an sRGB colour; used by the tests to check the map.
#[cfg(test)]
pub(crate) fn lightness(c: Rgb) -> f64 {
    let lin = |u: u8| {
        let u = u as f64 / 255.0;
        if u <= 0.04045 {
            u / 12.92
        } else {
            ((u + 0.055) / 1.055).powf(2.4)
        }
    };
    let y = 0.2126 * lin(c[0]) + 0.7152 * lin(c[1]) + 0.0722 * lin(c[2]);
    if y > 216.0 / 24389.0 {
        116.0 * y.cbrt() - 16.0
    } else {
        y * 24389.0 / 27.0
    }
}
