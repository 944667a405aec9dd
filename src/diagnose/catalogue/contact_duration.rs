//! A contact force of finite duration.
//!
//! The baseline strikes with an impulse, which excites every mode by its drive alone. A real
//! mallet stays in contact for T ≈ 0.05–2 ms; the force spectrum falls off above ~1/T and the
//! high modes are excited less. For a half-sine pulse of duration T (a Hertz-like contact;
//! [`crate::audio::excitation`]) the spectrum relative to its value at ω = 0 is
//!
//! |F(ωT)| / |F(0)| = |cos(ωT/2) / (1 − (ωT/π)²)|,
//!
//! 1 at ω = 0, π/4 at ωT = π, first zero at ωT = 3π. Computed as sin(πe/2)/e / (1 + u) with
//! u = ωT/π, e = 1 − u, which has no 0/0 at u = 1.
//!
//! Model: ln a_kc += ln |F(ω_k T)/F(0)|; parameter T ∈ [0, 2.9π/ω_max] s (ω_max the highest
//! matched mode: beyond, a mode would sit at the spectrum's first zero and be unseen). The
//! response is even in T, so the fit starts from a grid (the likelihood is flat at T = 0).
//!
//! **Beyond the first null** (variant `half_sine_envelope`). A soft mallet's first null,
//! ωT = 3π, can fall inside the band; the modes near a null go unseen, and those in the side
//! lobes sit wherever the lobes put them. Where the nulls fall depends on the pulse's exact
//! shape (a Hertzian sin^1.5 pulse has them elsewhere than a half-sine), so past the main
//! lobe the model takes the lobes' envelope rather than the half-sine itself:
//!
//! E(u) = |F(u)| for u = ωT/π ≤ 2,  E(u) = 1/(u² − 1) for u > 2
//!
//! (continuous at u = 2, where both are 1/3; the envelope touches every side-lobe peak, at
//! even u, and falls as f⁻²). A mode's place within its lobe is a level error of that mode,
//! which the level floor τ_A carries. Parameter T ∈ [T_max, 3π/ω_min] (T_max the half-sine
//! variant's top): beyond, even the lowest mode is past the knee and the envelope is a plain
//! f⁻², which the amplitude tilt already is. Generator 2's seed 23 had two such contacts
//! (0.33 and 0.24 ms on tubes whose modes reach 8.8 kHz; T_max = 0.16 ms).
//!
//! **Nulls inside the band** (variant `sine_power`). The envelope cannot show a dip and a
//! recovery: the modes just below a null in the band come out weaker than their neighbours on
//! either side. Generator 2's contacts of 0.24–0.32 ms on tubes (modes up to 9.8 kHz, first
//! half-sine null at 4.7–6.2 kHz) were missed for that reason on every seed from 31 to 43 (the
//! level residuals of case 000 of seed 43: −0.9 to −2.7 at the pair at 6 kHz, +0.3 ± 0.6 at
//! 8–9 kHz). A contact pulse sin^p(πt/T) on [0, T] has
//!
//! |F(ωT)|/|F(0)| = Γ(1 + p/2)² / |Γ(1 + (p + u)/2) Γ(1 + (p − u)/2)|,  u = ωT/π,
//!
//! (p = 1 is the half-sine, p = 1.5 about a Hertz contact, p = 2 the Hann pulse) with nulls at
//! u = p + 2, p + 4, …. The mode levels pin where the first null is, f₀ = (p + 2)/(2T), and
//! much less how T and p share it (a half-sine of 0.243 ms and a sin² pulse of 0.334 ms put
//! it at 6.2 and 6.0 kHz), so the variant's parameters are f₀ ∈ [f_min, f_max] (the lowest and
//! highest mode with a level: the null inside the band) and p ∈ [1, 3]; T follows. A null is
//! floored at −40 dB ([`SINE_POWER_NULL_DEPTH`]): a real pulse is not exactly symmetric.
//!
//! **A Hertzian pulse** (variant `hertz_pulse`). The sin^p variant pays for p, which the
//! levels pin weakly, with a parameter's ln n in ΔBIC. Contact mechanics gives the shape: a
//! sphere pressed into a flat by Hertz's law (force ∝ indentation^1.5) has a force history
//! close to sin^1.5(πt/T), so the variant fixes p = 1.5 ([`HERTZ_POWER`]) and fits the
//! first null f₀ alone; the free-p variant stays for pulses of other shapes, and the larger
//! ΔBIC is taken. It is offered only where the sin^p pulse is testable (below): a null free
//! to sit anywhere in the band can empty any one group of modes, whatever the count of its
//! parameters. Offered on one parameter's count, it named a contact on a bar in a room
//! (generator 2's calibration set 9101 case 003, two microphones, four groups of modes,
//! ΔBIC 18.4). Replayed on the saved evidence of 187 cases (generator 2's spent seeds
//! 263–283, calibration sets 9101–9104, the real bowl): two contacts found that were missed
//! (spent seeds 281 case 015 and 283 case 023, a tube and a bar on two microphones, ΔBIC 13.5
//! and 3.9, held-out gains 31.8 and 12.9; first nulls placed at 5535 and 2989 Hz against the
//! true 4735 and 5110), six contacts already named (four true, two false) now named by this
//! variant, no claim added or lost elsewhere. Generator 2's pulses are half-sines, not this variant's own shape: the
//! synthetic Hertzian contact of `a_contact_whose_first_null_is_inside_the_band_is_named_with_its_null`
//! is taken by it in 3 of 4 draws, its null within 0.3 % of the truth.
//!
//! **Testable shapes.** The levels are shaped per channel by a gain and a tilt, and a variant
//! adds k parameters (1 for the half-sine and the envelope, 2 for the sin^p pulse). Modes a few
//! per cent apart take one level from any of them, so on G groups of modes (consecutive modes
//! at most [`LEVEL_GROUP_GAP`] apart in ln f) a variant with 2 + k ≥ G parameters fits any
//! levels the groups have, a per-mode radiation error or a microphone's curvature as well as a
//! contact: it is not offered, and the report says the contact could not be tested with these
//! modes. When the levels fall faster than the tilts' bound lets them (the screen's free
//! slope lies outside the tilts' room), the tilts are held at the bound and do not count, so
//! 1 + k < G suffices. Set 1's seed 101 case 028 (clean; three split pairs at 1.8, 4.5 and
//! 8.0 kHz) was read as a sin^p pulse with its first null at 2.3 kHz while the tilts rose
//! from 0 to +2.2 (ΔBIC 18.7): four parameters through three group levels.
//!
//! Detector: per mode, the level residual (weighted mean over channels, variance
//! 1/W + τ_A², parent docs "Likelihood"); for 40 values of T
//! log-spaced over [T_max/1000, T_max] the drop in Σ z² from adding ln |F(ω_k T)| plus the
//! best constant and the best slope in ln ω (the gains absorb constants and the amplitude
//! tilt slopes, and the fit refits both with T) that keeps every channel's tilt within its
//! bound (a fall steeper than the bound is the contact's, not a nuisance's), the same with E
//! over [T_max, 3π/ω_min], and
//! with the sin^p spectrum over 40 nulls f₀ log-spaced over [f_min, f_max] times p ∈ {1, 1.5,
//! 2, 2.5, 3} (when f_max > 1.2 f_min); each variant whose best drop exceeds 1 goes on, the
//! largest drop is the statistic. Without
//! the slope the screen added the envelope's f⁻² on top of a tilt that had already taken it,
//! and saw nothing: generator 2's seed 29 case 012, a 0.36 ms contact on an eight-microphone
//! plate, whose level residuals after the tilt still showed the knee (−1.4 … −2.3 at
//! 0.5 kHz, +1 … +2.6 at 1.2–2.6 kHz, about 0 above 5 kHz), screened at a drop of 0.0.

use std::sync::Arc;

use super::{weighted_line, Detection, Effect, Fit, ModeTable, ParamSpec, Proposal, Term};

pub struct ContactDuration;

/// |F(x)|/|F(0)| of the half-sine pulse at x = ωT (module docs).
pub fn half_sine_spectrum(x: f64) -> f64 {
    let u = x / std::f64::consts::PI;
    let e = 1.0 - u;
    let sinc = if e.abs() < 1e-9 {
        0.5 * std::f64::consts::PI
    } else {
        (0.5 * std::f64::consts::PI * e).sin() / e
    };
    (sinc / (1.0 + u)).abs()
}

/// |F(x)|/|F(0)| at x = ωT of the pulse sin^p(πt/T) on [0, T] (p > 0; p = 1 is the
/// half-sine, p = 2 the Hann pulse). With u = x/π,
///
/// |F|/|F(0)| = Γ(1 + p/2)² / |Γ(1 + (p + u)/2) Γ(1 + (p − u)/2)|
///
/// from ∫_{−π/2}^{π/2} cos^p θ cos(uθ) dθ = π Γ(p + 1) / (2^p Γ(1 + (p + u)/2) Γ(1 + (p − u)/2)).
/// Its nulls are at u = p + 2, p + 4, …: the first at fT = 1.5 for the half-sine, 2 for Hann,
/// so the pulse's shape moves the nulls, and a profiled p lets a model fit a null inside the
/// band without assuming the half-sine.
pub fn sine_power_spectrum(x: f64, p: f64) -> f64 {
    use crate::numerics::{ln_abs_recip_gamma, ln_gamma};
    let u = (x / std::f64::consts::PI).abs();
    (2.0 * ln_gamma(1.0 + 0.5 * p)
        + ln_abs_recip_gamma(1.0 + 0.5 * (p + u))
        + ln_abs_recip_gamma(1.0 + 0.5 * (p - u)))
    .exp()
}

/// Smallest magnitude the log model uses: a mode at a spectral zero is 300 dB down, not −∞.
const FLOOR: f64 = 1e-15;

/// ln a_kc += ln_level(ω_k) on every channel c of each mode k (ω_k = 2π e^{ln f_k}): a contact
/// force's spectrum scales every microphone's view of a mode alike.
fn add_on_every_channel(
    table: &ModeTable,
    ln_f: &[f64],
    ln_a: &mut [f64],
    ln_level: impl Fn(f64) -> f64,
) {
    let c_n = table.channels;
    for (k, &lf) in ln_f.iter().enumerate() {
        let g = ln_level(2.0 * std::f64::consts::PI * lf.exp());
        for a in &mut ln_a[k * c_n..(k + 1) * c_n] {
            *a += g;
        }
    }
}

/// ln max(E_p(x), N) of the sin^p pulse at x = ωT ([`sine_power_spectrum`], N =
/// [`SINE_POWER_NULL_DEPTH`]): the model's level, shared by the term and its screen.
fn sine_power_ln_level(x: f64, p: f64) -> f64 {
    sine_power_spectrum(x, p).max(SINE_POWER_NULL_DEPTH).ln()
}

/// The contact's shape in the model: the half-sine's own spectrum, or past its first null the
/// side lobes' envelope (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ContactShape {
    HalfSine,
    Envelope,
}

impl ContactShape {
    /// |F(x)|/|F(0)| at x = ωT.
    pub fn level(self, x: f64) -> f64 {
        match self {
            ContactShape::HalfSine => half_sine_spectrum(x),
            ContactShape::Envelope => half_sine_envelope(x),
        }
    }
}

/// ln a += ln level(ωT) on every channel, T ∈ [min, max] s.
#[derive(Debug)]
pub struct HalfSineContact {
    pub shape: ContactShape,
    pub min_duration_s: f64,
    pub max_duration_s: f64,
}

impl Term for HalfSineContact {
    fn effect(&self) -> &'static str {
        "contact_duration"
    }
    fn variant(&self) -> &'static str {
        match self.shape {
            ContactShape::HalfSine => "half_sine",
            ContactShape::Envelope => "half_sine_envelope",
        }
    }
    fn params(&self) -> Vec<ParamSpec> {
        vec![ParamSpec::new(
            "contact duration T",
            "s",
            self.min_duration_s,
            self.max_duration_s,
            1e-4,
        )]
    }
    fn amplitude(&self, table: &ModeTable, p: &[f64], ln_f: &[f64], ln_a: &mut [f64]) {
        add_on_every_channel(table, ln_f, ln_a, |w| {
            self.shape.level(w * p[0]).max(FLOOR).ln()
        });
    }
    fn shapes_levels(&self) -> bool {
        true
    }
}

/// The sin^p pulse with its nulls inside the band (module docs, "Nulls inside the band"):
/// ln a += ln max(E_p(ωT), N) on every channel with T = (p + 2)/(2 f₀). Parameters: the first
/// null f₀ ∈ [min, max] Hz, and p ∈ [1, 3] unless `power` fixes it (the `hertz_pulse`
/// variant, p = [`HERTZ_POWER`]); N = [`SINE_POWER_NULL_DEPTH`].
#[derive(Debug)]
pub struct SinePowerContact {
    pub min_null_hz: f64,
    pub max_null_hz: f64,
    pub power: Option<f64>,
}

/// The pulse power of the `hertz_pulse` variant: a Hertzian contact's force history is close
/// to sin^1.5(πt/T) (module docs, "A Hertzian pulse").
pub const HERTZ_POWER: f64 = 1.5;

/// Depth of the sin^p pulse's nulls in the model (−40 dB): a real pulse is not exactly
/// symmetric and a mode is not a single frequency, so no mode sits 300 dB down.
pub const SINE_POWER_NULL_DEPTH: f64 = 1e-2;

/// Name of [`SinePowerContact`]'s first parameter (read back by the benchmarks' scoring).
pub const FIRST_NULL_PARAM: &str = "first spectral null f0 of the contact force";

/// Duration T [s] of the sin^p pulse whose first spectral null is at `null_hz`:
/// ωT = π(p + 2) at the null, so T = (p + 2)/(2 f₀).
pub fn sine_power_duration(null_hz: f64, power: f64) -> f64 {
    (power + 2.0) / (2.0 * null_hz)
}

impl Term for SinePowerContact {
    fn effect(&self) -> &'static str {
        "contact_duration"
    }
    fn variant(&self) -> &'static str {
        if self.power.is_some() {
            "hertz_pulse"
        } else {
            "sine_power"
        }
    }
    fn params(&self) -> Vec<ParamSpec> {
        let mut specs = vec![ParamSpec::new(
            FIRST_NULL_PARAM,
            "Hz",
            self.min_null_hz,
            self.max_null_hz,
            0.1 * self.min_null_hz,
        )];
        if self.power.is_none() {
            specs.push(ParamSpec::new("pulse power p", "1", 1.0, 3.0, 1.0));
        }
        specs
    }
    fn amplitude(&self, table: &ModeTable, p: &[f64], ln_f: &[f64], ln_a: &mut [f64]) {
        let power = self.power.unwrap_or_else(|| p[1]);
        let t = sine_power_duration(p[0], power);
        add_on_every_channel(table, ln_f, ln_a, |w| sine_power_ln_level(w * t, power));
    }
    fn shapes_levels(&self) -> bool {
        true
    }
}

/// E(u) of the module docs, "Beyond the first null".
pub fn half_sine_envelope(x: f64) -> f64 {
    let u = x / std::f64::consts::PI;
    if u <= 2.0 {
        half_sine_spectrum(x)
    } else {
        1.0 / (u * u - 1.0)
    }
}

/// The range [lo, hi] of a common slope t in ln ω that the channels' amplitude tilts can still
/// take: η_c + t within the model's tilt bound for every channel c (module docs, "Detector").
/// A fall steeper than the bound lets is not a nuisance (model::DEFAULT_TILT_BOUND), so the
/// screen must not take it with a free slope: generator 2's tubes and cups recorded as a
/// displacement (tilt −2) with a contact past its knee (another f⁻²) fitted their tilts at
/// the bound −3, and the screen's free slope took the rest and found nothing.
fn tilt_room(current: &Fit) -> (f64, f64) {
    let bound = current.model.tilt_bound;
    let tilts: Vec<f64> = (0..current.model.channels)
        .map(|c| current.x[current.model.tilt_index(c)])
        .collect();
    if tilts.is_empty() {
        return (f64::NEG_INFINITY, f64::INFINITY);
    }
    let lo = -bound - tilts.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = bound - tilts.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    // Tilts spread wider than the bound allows (not from a bounded fit): no common room.
    if lo > hi {
        (0.0, 0.0)
    } else {
        (lo, hi)
    }
}

/// Largest ln-frequency gap between modes counted as one level group (2 %): a contact's
/// spectrum changes little across it (module docs, "Testable shapes").
pub const LEVEL_GROUP_GAP: f64 = 0.02;

/// Number of groups of `ln_f` (any order) with consecutive members at most
/// [`LEVEL_GROUP_GAP`] apart.
pub(super) fn level_groups(ln_f: impl Iterator<Item = f64>) -> usize {
    let mut v: Vec<f64> = ln_f.collect();
    v.sort_by(f64::total_cmp);
    v.windows(2)
        .filter(|w| w[1] - w[0] > LEVEL_GROUP_GAP)
        .count()
        + usize::from(!v.is_empty())
}

impl Effect for ContactDuration {
    fn name(&self) -> &'static str {
        "contact_duration"
    }
    fn signature(&self) -> &'static str {
        "high modes weaker than their drive predicts, increasingly with frequency (a low-pass on the amplitudes)"
    }
    fn detect(&self, table: &ModeTable, current: &Fit) -> Detection {
        if current
            .model
            .terms
            .iter()
            .any(|t| t.effect() == "contact_duration")
        {
            return Detection::NotEnoughData("contact duration already in the model".into());
        }
        let res = current.mode_residuals(table);
        // Per mode: its level residual (weighted mean over channels) and that one's variance.
        let points: Vec<(f64, f64, f64)> = table
            .modes
            .iter()
            .zip(&res.ln_a_level)
            .filter_map(|(m, level)| {
                level.map(|(r, v)| (2.0 * std::f64::consts::PI * m.ln_f.exp(), r, 1.0 / v))
            })
            .collect();
        if points.len() < 4 {
            return Detection::NotEnoughData(format!(
                "{} modes with amplitudes; at least 4 needed",
                points.len()
            ));
        }
        let omega_max = points.iter().map(|p| p.0).fold(0.0, f64::max);
        let t_max = 2.9 * std::f64::consts::PI / omega_max;
        let slopes = tilt_room(current);
        // Σ w (r − s(ω) − c − t ln ω)² at the best constant c and slope t (weighted least
        // squares, t within what the tilts can still take): the gains absorb constants and the
        // amplitude tilt absorbs slopes, so only the shape that neither can take counts (the
        // knee, the nulls, and a fall steeper than the tilts' bound).
        let chi2 = |shift: &dyn Fn(f64) -> f64| -> f64 {
            let line: Vec<(f64, f64, f64)> = points
                .iter()
                .map(|p| (p.0.ln(), p.1 - shift(p.0), p.2))
                .collect();
            let mean = |t: f64| {
                line.iter().map(|p| p.2 * (p.1 - t * p.0)).sum::<f64>()
                    / line.iter().map(|p| p.2).sum::<f64>()
            };
            let t = match weighted_line(&line) {
                Some((_, t, _)) => t.clamp(slopes.0, slopes.1),
                // One frequency: the constant alone, the weighted mean.
                None => 0.0,
            };
            let c = mean(t);
            line.iter().map(|p| p.2 * (p.1 - c - t * p.0).powi(2)).sum()
        };
        let base = chi2(&|_| 0.0);
        // What the levels can test (module docs, "Testable shapes"): the distinct frequencies
        // they sit at, and the level parameters that shape them besides the contact's own.
        let levels: Vec<(f64, f64, f64)> = points.iter().map(|p| (p.0.ln(), p.1, p.2)).collect();
        let groups = level_groups(levels.iter().map(|p| p.0));
        let pinned = weighted_line(&levels).is_some_and(|(_, t, _)| t < slopes.0 || t > slopes.1);
        let level_params = if pinned { 1 } else { 2 };
        let testable = |shape_params: usize| groups > level_params + shape_params;
        let mut untestable: Vec<String> = Vec::new();
        // The best drop in Σz² over 40 values x log-spaced over [lo, hi] of a model's one
        // scanned parameter, ln_level(x, ω) its ln level at ω: (drop, x).
        let scan = |lo: f64, hi: f64, ln_level: &dyn Fn(f64, f64) -> f64| -> (f64, f64) {
            let mut best = (0.0, hi);
            for i in 0..40 {
                let x = lo * (hi / lo).powf(i as f64 / 39.0);
                let drop = base - chi2(&|w| ln_level(x, w));
                if drop > best.0 {
                    best = (drop, x);
                }
            }
            best
        };
        let half_sine =
            |shape: ContactShape| move |t: f64, w: f64| shape.level(w * t).max(FLOOR).ln();
        let mut proposals = Vec::new();
        let mut propose = |shape: ContactShape, (drop, t): (f64, f64), t_lo: f64, t_hi: f64| {
            if drop > 1.0 && !testable(1) {
                untestable.push(match shape {
                    ContactShape::HalfSine => "half-sine (1 parameter)".to_string(),
                    ContactShape::Envelope => "side-lobe envelope (1 parameter)".to_string(),
                });
            } else if drop > 1.0 {
                proposals.push(Proposal {
                    term: Arc::new(HalfSineContact {
                        shape,
                        min_duration_s: t_lo,
                        max_duration_s: t_hi,
                    }),
                    init: vec![t],
                });
            }
        };
        let main = scan(t_max / 1000.0, t_max, &half_sine(ContactShape::HalfSine));
        propose(ContactShape::HalfSine, main, 0.0, t_max);
        let mut detail = format!(
            "half-sine low-pass on the amplitude residuals lowers Σz² by {:.1} at T = {:.3} ms",
            main.0,
            1e3 * main.1
        );
        let mut statistic = main.0;
        // Past the first null: the side lobes' envelope (module docs).
        let omega_min = points.iter().map(|p| p.0).fold(f64::INFINITY, f64::min);
        let t_env_max = 3.0 * std::f64::consts::PI / omega_min;
        if t_env_max > t_max {
            let env = scan(t_max, t_env_max, &half_sine(ContactShape::Envelope));
            propose(ContactShape::Envelope, env, t_max, t_env_max);
            detail.push_str(&format!(
                "; its side-lobe envelope by {:.1} at T = {:.3} ms",
                env.0,
                1e3 * env.1
            ));
            statistic = statistic.max(env.0);
        }
        // Nulls inside the band, the pulse's shape profiled (module docs).
        let two_pi = 2.0 * std::f64::consts::PI;
        let (f_lo, f_hi) = (omega_min / two_pi, omega_max / two_pi);
        if f_hi > 1.2 * f_lo {
            let mut best = (0.0, f_hi, 1.0);
            let mut hertz = (0.0, f_hi);
            for &power in &[1.0, HERTZ_POWER, 2.0, 2.5, 3.0] {
                let (drop, f0) = scan(f_lo, f_hi, &|f0, w| {
                    sine_power_ln_level(w * sine_power_duration(f0, power), power)
                });
                if drop > best.0 {
                    best = (drop, f0, power);
                }
                if power == HERTZ_POWER {
                    hertz = (drop, f0);
                }
            }
            // The Hertzian pulse beside the free one: the same null with the shape physics
            // gives it, one parameter (module docs, "A Hertzian pulse"), but tested as the
            // sin^p pulse is: a null free to sit anywhere in the band can empty any one group
            // of modes.
            for (drop, init, power, what) in [
                (
                    best.0,
                    vec![best.1, best.2],
                    None,
                    "sin^p pulse (2 parameters)",
                ),
                (
                    hertz.0,
                    vec![hertz.1],
                    Some(HERTZ_POWER),
                    "Hertzian pulse (its null anywhere in the band)",
                ),
            ] {
                if drop > 1.0 && !testable(2) {
                    untestable.push(what.to_string());
                } else if drop > 1.0 {
                    proposals.push(Proposal {
                        term: Arc::new(SinePowerContact {
                            min_null_hz: f_lo,
                            max_null_hz: f_hi,
                            power,
                        }),
                        init,
                    });
                }
            }
            detail.push_str(&format!(
                "; a sin^p pulse with its first null in the band by {:.1} at f0 = {:.0} Hz, p = {:.1}",
                best.0, best.1, best.2
            ));
            statistic = statistic.max(best.0);
        }
        // What these modes cannot show (the report says so rather than "not found" alone):
        // past its knee (u ≥ 2 at the lowest mode, T ≥ 1/f_min) a contact falls about as f⁻²
        // (the envelope's 1/(u² − 1)), which a response recorded two derivatives lower makes
        // too.
        detail.push_str(&format!(
            "; a contact longer than {:.3} ms would put every matched mode past its knee, \
             where it falls about as f⁻² and only its nulls or a fall steeper than the tilts' \
             bound set it apart from the response tilt",
            1e3 / f_lo
        ));
        if !untestable.is_empty() {
            detail.push_str(&format!(
                "; not testable on {groups} frequency group(s) (modes within {:.0} % merged) \
                 beside {level_params} level parameter(s) of the channels ({}): {}",
                100.0 * LEVEL_GROUP_GAP,
                if pinned {
                    "the gains; the tilts held at their bound"
                } else {
                    "the gains and the tilts"
                },
                untestable.join(", ")
            ));
            if proposals.is_empty() {
                return Detection::NotEnoughData(detail);
            }
        }
        if proposals.is_empty() {
            return Detection::Nothing { statistic, detail };
        }
        Detection::Found {
            statistic,
            detail,
            proposals,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn the_sine_power_pulse_is_the_half_sine_at_one_and_hann_at_two() {
        for i in 0..200 {
            let x = 0.05 * PI * i as f64;
            let half = half_sine_spectrum(x);
            let got = sine_power_spectrum(x, 1.0);
            assert!(
                (got - half).abs() < 1e-12 * half.max(1e-3),
                "x = {x}: {got} vs {half}"
            );
            // Hann: |sin(x/2)/(x/2)| / |1 − (x/2π)²|.
            let h = if x == 0.0 {
                1.0
            } else {
                (0.5 * x).sin() / (0.5 * x)
            };
            let e = 1.0 - (x / (2.0 * PI)).powi(2);
            let hann = if e.abs() < 1e-9 { 0.5 } else { (h / e).abs() };
            let got = sine_power_spectrum(x, 2.0);
            assert!(
                (got - hann).abs() < 1e-11 * hann.max(1e-3),
                "x = {x}: {got} vs {hann}"
            );
        }
    }

    /// The Hertzian variant is the sin^p pulse at p = 1.5 with f₀ its one parameter.
    #[test]
    fn the_hertzian_pulse_is_the_sine_power_pulse_at_one_and_a_half() {
        let free = SinePowerContact {
            min_null_hz: 500.0,
            max_null_hz: 8000.0,
            power: None,
        };
        let hertz = SinePowerContact {
            power: Some(HERTZ_POWER),
            ..free
        };
        assert_eq!(free.params().len(), 2);
        assert_eq!(hertz.params().len(), 1);
        assert_eq!(hertz.params()[0].name, FIRST_NULL_PARAM);
        assert_eq!(
            (free.variant(), hertz.variant()),
            ("sine_power", "hertz_pulse")
        );
        let table = ModeTable {
            modes: Vec::new(),
            channels: 2,
            pairs: Vec::new(),
            rows: Vec::new(),
            other_rows: Vec::new(),
            amplitude_groups: Vec::new(),
            split_sites: None,
            decay_ceiling: None,
            poles: Vec::new(),
        };
        let ln_f: Vec<f64> = (0..30).map(|i| (300.0 * 1.12f64.powi(i)).ln()).collect();
        let (mut a, mut b) = (vec![0.0; 60], vec![0.0; 60]);
        free.amplitude(&table, &[3000.0, HERTZ_POWER], &ln_f, &mut a);
        hertz.amplitude(&table, &[3000.0], &ln_f, &mut b);
        assert_eq!(a, b);
        // Its first null is where f₀ puts it: the level there is the model's null depth.
        let mut at = vec![0.0; 2];
        hertz.amplitude(&table, &[3000.0], &[3000f64.ln()], &mut at);
        assert!((at[0] - SINE_POWER_NULL_DEPTH.ln()).abs() < 1e-9, "{at:?}");
    }

    #[test]
    fn the_sine_power_pulse_has_its_nulls_at_p_plus_two() {
        for p in [1.0, 1.5, 2.0, 2.7] {
            for k in 0..3 {
                let u = p + 2.0 + 2.0 * k as f64;
                let at = sine_power_spectrum(PI * u, p);
                assert!(at < 1e-12, "p = {p}, u = {u}: {at}");
                // Beside the null the spectrum is not zero, and it is 1 at 0.
                assert!(sine_power_spectrum(PI * (u + 0.3), p) > 0.0);
            }
            assert!((sine_power_spectrum(0.0, p) - 1.0).abs() < 1e-13);
        }
        // A blunter pulse (larger p) falls faster in its side lobes (as u^−(p+1)): the largest
        // value over u in [20, 24] (two lobes of either) is smaller for Hann than for the
        // half-sine.
        let peak = |p: f64| {
            (0..=400)
                .map(|i| sine_power_spectrum(PI * (20.0 + 0.01 * i as f64), p))
                .fold(0.0_f64, f64::max)
        };
        assert!(peak(2.0) < 0.5 * peak(1.0), "{} {}", peak(2.0), peak(1.0));
    }
}
