//! Axis mapping (data value ↔ pixel), tick placement and tick labels.
//!
//! Linear axes get "nice" major ticks: multiples of a step 1, 2 or 5 × 10^k
//! chosen so at most a given number fit. Log axes get one major tick per
//! decade (every n-th decade when there are many) with minor ticks at
//! 2..9 × 10^k; when the range spans less than two decades the majors are
//! the 1-2-5 multiples instead, since one or two decade labels alone do not
//! let anyone read a value off the axis.

/// Linear or base-10 logarithmic axis.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum AxisScale {
    #[default]
    Linear,
    Log,
}

/// Maps data values in `[lo, hi]` onto continuous pixel coordinates
/// `[px_lo, px_hi]` (see the canvas docs: pixel `i` covers `[i, i+1)`).
/// For a vertical axis `px_lo` is the bottom edge, so `px_lo > px_hi`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisMap {
    pub scale: AxisScale,
    pub lo: f64,
    pub hi: f64,
    pub px_lo: f64,
    pub px_hi: f64,
}

impl AxisMap {
    fn fwd(&self, v: f64) -> f64 {
        match self.scale {
            AxisScale::Linear => v,
            AxisScale::Log => v.log10(),
        }
    }
    /// Continuous pixel coordinate of data value `v` (may lie outside the
    /// axis; non-positive values on a log axis give NaN or -inf).
    pub fn to_px(&self, v: f64) -> f64 {
        let (a, b) = (self.fwd(self.lo), self.fwd(self.hi));
        self.px_lo + (self.fwd(v) - a) / (b - a) * (self.px_hi - self.px_lo)
    }
    /// Data value at continuous pixel coordinate `p` (inverse of [`Self::to_px`]).
    pub fn from_px(&self, p: f64) -> f64 {
        let (a, b) = (self.fwd(self.lo), self.fwd(self.hi));
        let u = a + (p - self.px_lo) / (self.px_hi - self.px_lo) * (b - a);
        match self.scale {
            AxisScale::Linear => u,
            AxisScale::Log => 10f64.powf(u),
        }
    }
    /// The pixel row/column on which a tick at `v` is drawn: the pixel
    /// containing `to_px(v)`, kept inside the axis so a tick at the upper
    /// end does not land on the frame beyond it.
    pub fn tick_pixel(&self, v: f64) -> i32 {
        let (a, b) = if self.px_lo <= self.px_hi {
            (self.px_lo, self.px_hi)
        } else {
            (self.px_hi, self.px_lo)
        };
        let p = self.to_px(v).floor();
        p.clamp(a, (b - 1.0).max(a)) as i32
    }
}

/// One tick: major ticks carry a label, minor ones do not.
#[derive(Clone, Debug, PartialEq)]
pub struct Tick {
    pub value: f64,
    pub label: Option<String>,
}

/// Exact-as-parsed `m × 10^e`: `powi` of 10 is off by an ulp for some
/// negative exponents, which would make `1e-7` print as `9.999…e-8`.
fn m_pow10(m: u32, e: i32) -> f64 {
    format!("{m}e{e}").parse().unwrap_or(f64::NAN)
}

/// The 1-2-5 × 10^k step at or just above `raw`.
pub(crate) fn nice_step(raw: f64) -> f64 {
    let e = raw.log10().floor() as i32;
    let mag = m_pow10(1, e);
    let norm = raw / mag;
    if norm <= 1.0 + 1e-9 {
        mag
    } else if norm <= 2.0 + 1e-9 {
        2.0 * mag
    } else if norm <= 5.0 + 1e-9 {
        5.0 * mag
    } else {
        10.0 * mag
    }
}

/// The next smaller 1-2-5 step.
fn smaller_step(step: f64) -> f64 {
    let e = step.log10().floor() as i32;
    let m = (step / m_pow10(1, e)).round() as u32;
    match m {
        1 => m_pow10(5, e - 1),
        2 => m_pow10(1, e),
        _ => m_pow10(2, e),
    }
}

/// Nice linear ticks inside `[lo, hi]`: multiples of one step 1, 2 or
/// 5 × 10^k, at least two of them (for any `lo < hi`) and at most
/// `max_ticks + 1`, unless the step that allows only one tick has to be
/// refined (then up to 6). Consecutive ticks and the ends are never more
/// than one step apart. Returns the tick values and the step.
pub fn nice_ticks(lo: f64, hi: f64, max_ticks: usize) -> (Vec<f64>, f64) {
    if !(lo.is_finite() && hi.is_finite()) || hi <= lo {
        return (if lo.is_finite() { vec![lo] } else { vec![] }, 0.0);
    }
    if !(hi - lo).is_finite() {
        // Wider than f64 can subtract: no tick spacing is representable.
        return (vec![], 0.0);
    }
    let mut step = nice_step((hi - lo) / max_ticks.max(1) as f64);
    loop {
        let first = (lo / step - 1e-9).ceil();
        let last = (hi / step + 1e-9).floor();
        let n = last - first + 1.0;
        // A step so small the ticks no longer differ in f64 cannot be
        // helped: return what we have rather than loop forever.
        if n >= 2.0 || step <= (hi - lo) * 1e-12 {
            let ticks = (0..n.max(0.0) as i64)
                .map(|k| {
                    let v = (first + k as f64) * step;
                    // Snap the rounding residue of 0 (e.g. -0.1 + 0.1).
                    if v.abs() < step * 1e-9 {
                        0.0
                    } else {
                        v
                    }
                })
                .collect();
            return (ticks, step);
        }
        step = smaller_step(step);
    }
}

/// Ticks for a log axis over `[lo, hi]` (both > 0) with at most about
/// `max_major` labelled ones; see the module docs for the rules.
pub fn log_ticks(lo: f64, hi: f64, max_major: usize) -> Vec<Tick> {
    if !(lo > 0.0 && hi > lo && hi.is_finite()) {
        return Vec::new();
    }
    let max_major = max_major.max(2);
    let inside = |v: f64| v >= lo * (1.0 - 1e-9) && v <= hi * (1.0 + 1e-9);
    let e_lo = lo.log10().floor() as i32;
    let e_hi = hi.log10().ceil() as i32;
    let decades: Vec<i32> = (e_lo..=e_hi).filter(|&e| inside(m_pow10(1, e))).collect();

    let mut majors: Vec<f64> = Vec::new();
    let mut minors: Vec<f64> = Vec::new();
    if decades.len() >= 3 {
        // One label every `stride` decades, on exponents divisible by it so
        // the labelled decades stay the same when the range shifts.
        let stride = decades.len().div_ceil(max_major) as i32;
        for e in e_lo..=e_hi {
            let v = m_pow10(1, e);
            if inside(v) {
                if e.rem_euclid(stride) == 0 {
                    majors.push(v);
                } else {
                    minors.push(v);
                }
            }
            if stride == 1 {
                minors.extend((2..=9).map(|m| m_pow10(m, e)).filter(|&v| inside(v)));
            }
        }
    } else {
        let cand: Vec<f64> = (e_lo..=e_hi)
            .flat_map(|e| [1, 2, 5].map(|m| m_pow10(m, e)))
            .filter(|&v| inside(v))
            .collect();
        if cand.len() >= 2 && cand.len() <= max_major + 1 {
            majors = cand;
            for e in e_lo..=e_hi {
                minors.extend(
                    [3, 4, 6, 7, 8, 9]
                        .map(|m| m_pow10(m, e))
                        .into_iter()
                        .filter(|&v| inside(v)),
                );
            }
        } else if cand.len() > max_major + 1 {
            majors = decades.iter().map(|&e| m_pow10(1, e)).collect();
            for e in e_lo..=e_hi {
                minors.extend((2..=9).map(|m| m_pow10(m, e)).filter(|&v| inside(v)));
            }
        } else {
            // Less than a factor of ~2.5: plain nice ticks read best.
            let (vals, step) = nice_ticks(lo, hi, max_major);
            let labels = format_ticks(&vals, step);
            return vals
                .into_iter()
                .zip(labels)
                .map(|(value, l)| Tick {
                    value,
                    label: Some(l),
                })
                .collect();
        }
    }
    let labels = format_log_ticks(&majors);
    let mut ticks: Vec<Tick> = majors
        .into_iter()
        .zip(labels)
        .map(|(value, l)| Tick {
            value,
            label: Some(l),
        })
        .collect();
    ticks.extend(minors.into_iter().map(|value| Tick { value, label: None }));
    ticks
}

/// Linear-axis ticks with labels (see [`nice_ticks`] and [`format_ticks`]).
pub fn linear_ticks(lo: f64, hi: f64, max_ticks: usize) -> Vec<Tick> {
    let (vals, step) = nice_ticks(lo, hi, max_ticks);
    let labels = format_ticks(&vals, step);
    vals.into_iter()
        .zip(labels)
        .map(|(value, l)| Tick {
            value,
            label: Some(l),
        })
        .collect()
}

/// Ticks for either scale.
pub fn axis_ticks(scale: AxisScale, lo: f64, hi: f64, max_major: usize) -> Vec<Tick> {
    match scale {
        AxisScale::Linear => linear_ticks(lo, hi, max_major),
        AxisScale::Log => log_ticks(lo, hi, max_major),
    }
}

/// `x` with `decimals` digits after the point, trailing zeros (and a bare
/// point) removed, and no "-0".
fn fixed(x: f64, decimals: usize) -> String {
    let mut s = format!("{x:.decimals$}");
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

/// Digits after the point needed to show multiples of `step` exactly.
fn decimals_for(step: f64) -> usize {
    if step.is_nan() || step <= 0.0 {
        return 3;
    }
    (-(step.log10() + 1e-9).floor()).clamp(0.0, 12.0) as usize
}

/// The integer `e` in superscript digits, with a superscript minus: `⁻¹²`.
pub(crate) fn superscript(e: i32) -> String {
    const SUP: [char; 10] = ['⁰', '¹', '²', '³', '⁴', '⁵', '⁶', '⁷', '⁸', '⁹'];
    let digits: String = e
        .unsigned_abs()
        .to_string()
        .chars()
        .map(|c| SUP[c as usize - '0' as usize])
        .collect();
    if e < 0 {
        format!("⁻{digits}")
    } else {
        digits
    }
}

/// `1.5·10⁻⁷`-style label of `v` (`10⁻⁷` for a mantissa of 1), with enough
/// mantissa digits for `step`.
fn exp_label(v: f64, step: f64) -> String {
    if v == 0.0 {
        return "0".into();
    }
    let e = (v.abs().log10() + 1e-9).floor() as i32;
    let mant = v / m_pow10(1, e);
    // Mantissa digits: how far below the value's own decade the step sits.
    let d = if step > 0.0 {
        (e - (step.log10() + 1e-9).floor() as i32).clamp(0, 6) as usize
    } else {
        0
    };
    let m = fixed(mant, d);
    let sign = if v < 0.0 { "-" } else { "" };
    // Rounding can carry the mantissa to 10 (9.99 → "10"): renormalise.
    match m.trim_start_matches('-') {
        "10" => format!("{sign}10{}", superscript(e + 1)),
        "1" => format!("{sign}10{}", superscript(e)),
        _ => format!("{m}·10{}", superscript(e)),
    }
}

/// Compact label of `v` for an axis whose ticks are `step` apart: plain
/// decimals below 1000, `k`/`M`/`G` suffixes above (1.5k), exponent
/// notation below 1e-3 or from 1e12 (those two via [`format_ticks`]).
fn compact_label(v: f64, step: f64) -> String {
    let a = v.abs();
    for (div, suffix) in [(1e9, "G"), (1e6, "M"), (1e3, "k")] {
        if a >= div * (1.0 - 1e-12) {
            return format!("{}{suffix}", fixed(v / div, decimals_for(step / div)));
        }
    }
    fixed(v, decimals_for(step))
}

/// Labels for linear ticks `values` spaced `step` apart. The style is chosen
/// for the whole axis so labels do not switch notation midway: exponent
/// notation if the largest magnitude is below 1e-3 or at least 1e12,
/// otherwise compact decimals with k/M/G suffixes (0, 500, 1k, 1.5k).
pub fn format_ticks(values: &[f64], step: f64) -> Vec<String> {
    let amax = values.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let exp_style = amax > 0.0 && !(1e-3..1e12).contains(&amax);
    values
        .iter()
        .map(|&v| {
            if v == 0.0 {
                "0".into()
            } else if exp_style {
                exp_label(v, step)
            } else {
                compact_label(v, step)
            }
        })
        .collect()
}

/// Labels for log-axis ticks (each a power of ten, or 2 or 5 times one):
/// compact (0.01, 1, 100, 1k, 10M) when all lie in [1e-3, 1e9), otherwise
/// exponent notation throughout (10⁻⁷, 10⁻⁶, …).
pub fn format_log_ticks(values: &[f64]) -> Vec<String> {
    let compact = values
        .iter()
        .all(|&v| (1e-3 * (1.0 - 1e-9)..1e9).contains(&v));
    values
        .iter()
        .map(|&v| {
            // Each value's own decade is the precision it needs.
            let own = m_pow10(1, (v.log10() + 1e-9).floor() as i32);
            if compact {
                compact_label(v, own)
            } else {
                exp_label(v, own)
            }
        })
        .collect()
}
