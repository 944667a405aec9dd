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
//! Detector: the weighted least-squares fit of the three hat functions of the knots to the
//! current ln d residuals; its drop in Σ z² (χ² with 3 degrees of freedom under the
//! baseline) is the statistic, and anything above 1 goes on to the criterion.

use std::sync::Arc;

use super::{Detection, Effect, Fit, ModeTable, ParamSpec, Proposal, Term};

pub struct NonRayleighDamping;

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
        if with_decay.len() < 6 {
            return Detection::NotEnoughData(format!(
                "{} modes with a decay rate; the 3-knot curve needs at least 6",
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
        let residual_points: Vec<(f64, f64, f64)> = with_decay
            .iter()
            .map(|&k| {
                let (r, v) = res.ln_d[k].expect("filtered");
                (table.modes[k].ln_f, r, 1.0 / v)
            })
            .collect();
        let Some((_, drop)) = fit_hats(&knots, &residual_points) else {
            return Detection::NotEnoughData("the decay rates do not determine three knots".into());
        };
        let detail = format!("3-knot curve on the ln d residuals lowers Σz² by {drop:.1} (3 dof)");
        if drop <= 1.0 {
            return Detection::Nothing {
                statistic: drop,
                detail,
            };
        }
        // Start from the curve through the observed ln d (same weights).
        let observed: Vec<(f64, f64, f64)> = with_decay
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
        let Some((coef, _)) = fit_hats(&knots, &observed) else {
            return Detection::NotEnoughData("the decay rates do not determine three knots".into());
        };
        Detection::Found {
            statistic: drop,
            detail,
            proposals: vec![Proposal {
                term: Arc::new(ThreeKnotDamping { knots }),
                init: coef.iter().map(|c| c.exp().clamp(1e-6, 1e6)).collect(),
            }],
        }
    }
}
