//! Damping that depends on frequency in a way Rayleigh damping cannot follow.
//!
//! Rayleigh damping d(ω) = (α + βω²)/2 with α, β ≥ 0 is, in log–log coordinates, a convex
//! curve whose slope rises from 0 to 2. Internal friction of ceramics, wood or plastics is
//! closer to a constant loss factor (d ∝ f, slope 1) or a weak power law, and radiation or
//! support losses can make d fall with f over a band: none of these is a Rayleigh curve.
//!
//! Model: ln d is piecewise linear in ln f through three knots (the lowest, the geometric mid
//! and the highest frequency of the modes with a decay rate), linearly extrapolated beyond;
//! parameters d₀, d₁, d₂ \[1/s\] at the knots. It replaces α and β, so it costs one parameter
//! more than the baseline. A power law d ∝ f^p is exactly representable; so is Rayleigh to
//! within a few per cent over four octaves.
//!
//! A second variant, `power_law`, is the law itself: d = d_ref (f/f_ref)^p, f_ref the
//! geometric mid of the modes with a decay rate, parameters d_ref \[1/s\] and p \[1\] (bounded
//! to \[−2, 4\]). Constant loss factor is p = 1; measured materials and generator 2's damping
//! are power laws (the real bowl's decay rates rise about as f^1.3). It replaces α and β with
//! as many parameters, so it is charged nothing beyond its fit, and it extrapolates to modes
//! outside the fit's band as the law does, where the three-knot curve continues its end
//! segments. Both variants are offered; the criterion takes the better. On the real bowl it
//! names the damping at ΔBIC 5.7 (p = 1.54), where the three-knot curve cleared the threshold
//! of 3 by 0.5; on generator 2's spent seeds 71, 73 and 79 it changed no verdict and took 6 of
//! the 7 accepted non-Rayleigh dampings. It did not rescue seed 73 case 006 (a tube, p = 0.34,
//! one fit microphone): there the power law too gains ΔBIC 34.9 and raises the held-out error
//! (1.966 → 2.019), as the three-knot curve did.
//!
//! Detector: the weighted least-squares fit of the three hat functions of the knots to the
//! current ln d residuals; its drop in Σ z² (χ² with 3 degrees of freedom under the
//! baseline) is the statistic, and anything above 1 goes on to the criterion. The power law
//! is fitted the same way to the observed ln d (a line in ln f with the residuals' weights),
//! and goes on when its Σ z² is below the current fit's by more than 1.

use std::sync::Arc;

use super::{weighted_line, Detection, Effect, Fit, ModeTable, ParamSpec, Proposal, Term};

pub struct NonRayleighDamping;

/// Fewest modes with a decay rate for the power law: two more than its two parameters, the
/// count Rayleigh's α and β leave to test it on.
pub const MIN_POWER_LAW_MODES: usize = 4;
/// Fewest modes with a decay rate for the three-knot curve.
pub const MIN_THREE_KNOT_MODES: usize = 6;

/// Hat functions of three knots at ln f values `knots` evaluated at x (linear extrapolation
/// beyond the ends: the outer hats continue as straight lines).
pub(super) fn hats(knots: &[f64; 3], x: f64) -> [f64; 3] {
    if x <= knots[1] {
        let t = (x - knots[0]) / (knots[1] - knots[0]);
        [1.0 - t, t, 0.0]
    } else {
        let t = (x - knots[1]) / (knots[2] - knots[1]);
        [0.0, 1.0 - t, t]
    }
}

/// Weighted least squares of y on the three hats: returns (coefficients, drop in Σ w y²).
fn fit_hats(knots: &[f64; 3], points: &[(f64, f64, f64)]) -> Option<([f64; 3], f64)> {
    let mut a = nalgebra::Matrix3::<f64>::zeros();
    let mut b = nalgebra::Vector3::<f64>::zeros();
    let mut total = 0.0;
    for &(x, y, w) in points {
        let h = hats(knots, x);
        for i in 0..3 {
            b[i] += w * h[i] * y;
            for j in 0..3 {
                a[(i, j)] += w * h[i] * h[j];
            }
        }
        total += w * y * y;
    }
    let coef = a.cholesky()?.solve(&b);
    let rest: f64 = points
        .iter()
        .map(|&(x, y, w)| {
            let h = hats(knots, x);
            w * (y - h[0] * coef[0] - h[1] * coef[1] - h[2] * coef[2]).powi(2)
        })
        .sum();
    Some(([coef[0], coef[1], coef[2]], total - rest))
}

/// The three-knot log–log damping curve; replaces Rayleigh.
#[derive(Debug)]
pub struct ThreeKnotDamping {
    /// ln f of the knots (Hz).
    pub knots: [f64; 3],
}

impl Term for ThreeKnotDamping {
    fn effect(&self) -> &'static str {
        "non_rayleigh_damping"
    }
    fn variant(&self) -> &'static str {
        "three_knot_log_log"
    }
    fn shapes_decays(&self) -> bool {
        true
    }
    fn params(&self) -> Vec<ParamSpec> {
        self.knots
            .iter()
            .map(|k| {
                ParamSpec::new(
                    format!("decay rate at {:.0} Hz", k.exp()),
                    "1/s",
                    1e-6,
                    1e6,
                    1.0,
                )
            })
            .collect()
    }
    fn replaces_rayleigh(&self) -> bool {
        true
    }
    fn damping(&self, _table: &ModeTable, p: &[f64], ln_f: &[f64], decay: &mut [f64]) {
        let ln_knot = [p[0].ln(), p[1].ln(), p[2].ln()];
        for (d, &x) in decay.iter_mut().zip(ln_f) {
            let h = hats(&self.knots, x);
            *d = (h[0] * ln_knot[0] + h[1] * ln_knot[1] + h[2] * ln_knot[2]).exp();
        }
    }
}

/// Bounds of the power law's exponent p (module docs): from a loss falling as 1/f² to one
/// rising as f⁴, beyond anything a material or a radiation loss gives in an audio band.
pub const POWER_LAW_EXPONENT: (f64, f64) = (-2.0, 4.0);

/// The power law d = d_ref (f/f_ref)^p; replaces Rayleigh (module docs).
#[derive(Debug)]
pub struct PowerLawDamping {
    /// ln f_ref (Hz).
    pub ln_f_ref: f64,
}

impl Term for PowerLawDamping {
    fn effect(&self) -> &'static str {
        "non_rayleigh_damping"
    }
    fn variant(&self) -> &'static str {
        "power_law"
    }
    fn shapes_decays(&self) -> bool {
        true
    }
    fn params(&self) -> Vec<ParamSpec> {
        vec![
            ParamSpec::new(
                format!("decay rate at {:.0} Hz", self.ln_f_ref.exp()),
                "1/s",
                1e-6,
                1e6,
                1.0,
            ),
            ParamSpec::new(
                "damping exponent p",
                "1",
                POWER_LAW_EXPONENT.0,
                POWER_LAW_EXPONENT.1,
                0.1,
            ),
        ]
    }
    fn replaces_rayleigh(&self) -> bool {
        true
    }
    fn damping(&self, _table: &ModeTable, p: &[f64], ln_f: &[f64], decay: &mut [f64]) {
        let ln_d_ref = p[0].ln();
        for (d, &x) in decay.iter_mut().zip(ln_f) {
            *d = (ln_d_ref + p[1] * (x - self.ln_f_ref)).exp();
        }
    }
}

/// The screen's answer from what it has: the proposals if any, else nothing seen.
fn found_or_nothing(statistic: f64, detail: String, proposals: Vec<Proposal>) -> Detection {
    if proposals.is_empty() {
        Detection::Nothing { statistic, detail }
    } else {
        Detection::Found {
            statistic,
            detail,
            proposals,
        }
    }
}

impl Effect for NonRayleighDamping {
    fn name(&self) -> &'static str {
        "non_rayleigh_damping"
    }
    fn signature(&self) -> &'static str {
        "ln d residuals bend with ln f: decays too flat, concave or falling for α + βω²"
    }
    fn detect(&self, table: &ModeTable, current: &Fit) -> Detection {
        if current.model.replaces_rayleigh() {
            return Detection::NotEnoughData("the damping curve is already free".into());
        }
        let res = current.mode_residuals(table);
        let with_decay: Vec<usize> = (0..table.modes.len())
            .filter(|&k| res.ln_d[k].is_some())
            .collect();
        if with_decay.len() < MIN_POWER_LAW_MODES {
            return Detection::NotEnoughData(format!(
                "{} modes with a decay rate; the power law needs at least {MIN_POWER_LAW_MODES}",
                with_decay.len()
            ));
        }
        let lo = with_decay
            .iter()
            .map(|&k| table.modes[k].ln_f)
            .fold(f64::INFINITY, f64::min);
        let hi = with_decay
            .iter()
            .map(|&k| table.modes[k].ln_f)
            .fold(f64::NEG_INFINITY, f64::max);
        if hi - lo < std::f64::consts::LN_2 {
            return Detection::NotEnoughData("the decay rates span less than an octave".into());
        }
        let knots = [lo, 0.5 * (lo + hi), hi];
        // The current fit's ln d residuals (ln f, r, 1/v), and their Σ z².
        let residual_points: Vec<(f64, f64, f64)> = with_decay
            .iter()
            .map(|&k| {
                let (r, v) = res.ln_d[k].expect("filtered");
                (table.modes[k].ln_f, r, 1.0 / v)
            })
            .collect();
        let current_sum: f64 = residual_points.iter().map(|p| p.2 * p.1 * p.1).sum();
        // The power law through the observed ln d, with the residuals' weights, against that
        // Σ z² over the same modes; ln f measured from the reference.
        let ln_f_ref = knots[1];
        let law_points: Vec<(f64, f64, f64)> = with_decay
            .iter()
            .map(|&k| {
                let (ln_d, _) = table.modes[k].ln_d.expect("filtered");
                (
                    table.modes[k].ln_f,
                    ln_d,
                    1.0 / res.ln_d[k].expect("filtered").1,
                )
            })
            .collect();
        let mut proposals = Vec::new();
        let mut details = Vec::new();
        let mut statistic = f64::NEG_INFINITY;
        let centred: Vec<(f64, f64, f64)> = law_points
            .iter()
            .map(|&(x, y, w)| (x - ln_f_ref, y, w))
            .collect();
        if let Some((a, b, _)) = weighted_line(&centred) {
            let rest: f64 = centred
                .iter()
                .map(|&(u, y, w)| w * (y - a - b * u).powi(2))
                .sum();
            let drop = current_sum - rest;
            details.push(format!(
                "power law d ∝ f^{b:.2} through the observed ln d lowers Σz² by {drop:.1} (2 dof, as Rayleigh's)"
            ));
            statistic = statistic.max(drop);
            if drop > 1.0 {
                proposals.push(Proposal {
                    term: Arc::new(PowerLawDamping { ln_f_ref }),
                    init: vec![
                        a.exp().clamp(1e-6, 1e6),
                        b.clamp(POWER_LAW_EXPONENT.0, POWER_LAW_EXPONENT.1),
                    ],
                });
            }
        }
        if with_decay.len() < MIN_THREE_KNOT_MODES {
            details.push(format!(
                "{} modes with a decay rate; the 3-knot curve needs at least {MIN_THREE_KNOT_MODES}",
                with_decay.len()
            ));
            return found_or_nothing(statistic, details.join("; "), proposals);
        }
        let Some((_, drop)) = fit_hats(&knots, &residual_points) else {
            // A power law's proposal stands without the three-knot curve.
            if proposals.is_empty() {
                return Detection::NotEnoughData(
                    "the decay rates do not determine three knots".into(),
                );
            }
            details.push("the decay rates do not determine three knots".into());
            return found_or_nothing(statistic, details.join("; "), proposals);
        };
        details.insert(
            0,
            format!("3-knot curve on the ln d residuals lowers Σz² by {drop:.1} (3 dof)"),
        );
        let detail = details.join("; ");
        statistic = statistic.max(drop);
        if drop <= 1.0 {
            return found_or_nothing(statistic, detail, proposals);
        }
        // Start from the curve through the observed ln d (the power law's points, same
        // weights).
        if let Some((coef, _)) = fit_hats(&knots, &law_points) {
            proposals.push(Proposal {
                term: Arc::new(ThreeKnotDamping { knots }),
                init: coef.iter().map(|c| c.exp().clamp(1e-6, 1e6)).collect(),
            });
        }
        if proposals.is_empty() {
            return Detection::NotEnoughData("the decay rates do not determine three knots".into());
        }
        Detection::Found {
            statistic,
            detail,
            proposals,
        }
    }
}
