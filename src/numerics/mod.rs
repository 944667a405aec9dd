//! Small numerical tools every stage shares, each written once: 3-vector arithmetic
//! ([`sub`], [`dot`], [`cross`], [`norm`]), the [`median`], the golden-section search on a
//! bracket ([`golden_section`]), the nearest element of a sorted list ([`nearest_sorted`]),
//! ln Γ on the whole real line ([`ln_gamma`],
//! [`ln_abs_recip_gamma`]), Levenberg–Marquardt ([`lm`]: one driver for the damping
//! curve's Rayleigh fit, the extraction's variable projection and its glide stage, and the
//! catalogue's bounded fit, each with its own damping and stopping settings), and the
//! eigenvalues of a symmetric matrix with one vector's weight on each eigenvector
//! ([`spectral_weights`]).

pub mod lm;
pub mod spectral_weights;

/// a − b.
pub fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// a · b.
pub fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// a × b.
pub fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// |a|, as √(a · a).
pub fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

/// The median of `values` (the mean of the two middle values for an even count; sorted by
/// [`f64::total_cmp`], so NaNs sort to the ends by sign); `None` for no values.
pub fn median(values: &[f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len();
    Some(if n % 2 == 1 {
        sorted[n / 2]
    } else {
        0.5 * (sorted[n / 2 - 1] + sorted[n / 2])
    })
}

/// Index of the element of the ascending `sorted` nearest to `x` (the lower one on a tie);
/// None if `sorted` is empty.
pub fn nearest_sorted(sorted: &[f64], x: f64) -> Option<usize> {
    if sorted.is_empty() {
        return None;
    }
    let i = sorted.partition_point(|&v| v < x);
    let mut best = None::<(usize, f64)>;
    for j in [i.wrapping_sub(1), i] {
        if j < sorted.len() {
            let d = (sorted[j] - x).abs();
            if best.is_none_or(|b| d < b.1) {
                best = Some((j, d));
            }
        }
    }
    best.map(|b| b.0)
}

/// Golden-section search on the bracket [a, b]: `steps` steps, each shrinking the bracket by
/// g = (√5 − 1)/2 and evaluating `f` once (two evaluations to start). `keep_left(f₁, f₂)`
/// decides, from the values at the inner points x₁ < x₂, whether the optimum lies in
/// [a, x₂] (true) or [x₁, b] (false): `|f1, f2| f1 < f2` minimises, `|f1, f2| f1 >= f2`
/// maximises; ties and NaNs go the way the comparison says. Returns the final bracket.
pub fn golden_section(
    mut a: f64,
    mut b: f64,
    steps: usize,
    mut f: impl FnMut(f64) -> f64,
    keep_left: impl Fn(f64, f64) -> bool,
) -> (f64, f64) {
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut x1, mut x2) = (b - g * (b - a), a + g * (b - a));
    let (mut f1, mut f2) = (f(x1), f(x2));
    for _ in 0..steps {
        if keep_left(f1, f2) {
            b = x2;
            x2 = x1;
            f2 = f1;
            x1 = b - g * (b - a);
            f1 = f(x1);
        } else {
            a = x1;
            x1 = x2;
            f1 = f2;
            x2 = a + g * (b - a);
            f2 = f(x2);
        }
    }
    (a, b)
}

/// Lanczos coefficients for g = 7, nine terms (relative error of Γ below 2·10⁻¹⁵ for x > 0.5).
const LANCZOS_G: f64 = 7.0;
const LANCZOS: [f64; 9] = [
    0.999_999_999_999_809_9,
    676.520_368_121_885_1,
    -1_259.139_216_722_402_8,
    771.323_428_777_653_1,
    -176.615_029_162_140_6,
    12.507_343_278_686_905,
    -0.138_571_095_265_720_12,
    9.984_369_578_019_572e-6,
    1.505_632_735_149_311_6e-7,
];

/// ln Γ(x) for x > 0 (Lanczos' approximation; for x < ½ through the reflection
/// Γ(x)Γ(1 − x) = π / sin(πx)). NaN for x ≤ 0.
pub fn ln_gamma(x: f64) -> f64 {
    if !(x > 0.0) {
        return f64::NAN;
    }
    if x < 0.5 {
        let pi = std::f64::consts::PI;
        return (pi / (pi * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let sum = LANCZOS[1..]
        .iter()
        .enumerate()
        .fold(LANCZOS[0], |acc, (i, c)| acc + c / (x + (i + 1) as f64));
    let t = x + LANCZOS_G + 0.5;
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + sum.ln()
}

/// ln |1/Γ(y)| for any real y: −∞ at the poles of Γ (y = 0, −1, −2, …), where 1/Γ vanishes.
/// For y ≤ 0 by the reflection 1/Γ(y) = sin(πy) Γ(1 − y) / π.
pub fn ln_abs_recip_gamma(y: f64) -> f64 {
    if y > 0.0 {
        return -ln_gamma(y);
    }
    let pi = std::f64::consts::PI;
    // sin(πy) from the distance to the nearest integer, exactly 0 at the poles.
    let s = (pi * (y - y.round())).sin().abs();
    if s == 0.0 {
        return f64::NEG_INFINITY;
    }
    s.ln() + ln_gamma(1.0 - y) - pi.ln()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vector_helpers() {
        let (a, b) = ([1.0, 2.0, 3.0], [4.0, -5.0, 6.0]);
        assert_eq!(sub(a, b), [-3.0, 7.0, -3.0]);
        assert_eq!(dot(a, b), 12.0);
        assert_eq!(cross(a, b), [27.0, 6.0, -13.0]);
        assert_eq!(dot(cross(a, b), a), 0.0);
        assert_eq!(norm([3.0, 4.0, 12.0]), 13.0);
    }

    #[test]
    fn median_of_odd_even_and_empty() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), Some(2.5));
        assert_eq!(median(&[-0.0, 0.0]), Some(0.0));
        assert_eq!(median(&[]), None);
    }

    #[test]
    fn golden_section_minimises_and_maximises() {
        let (a, b) = golden_section(0.0, 3.0, 60, |x| (x - 1.3f64).powi(2), |f1, f2| f1 < f2);
        assert!(
            (0.5 * (a + b) - 1.3).abs() < 1e-9 && b - a < 1e-9,
            "{a} {b}"
        );
        let (a, b) = golden_section(-2.0, 2.0, 60, |x| -(x + 0.7f64).powi(2), |f1, f2| f1 >= f2);
        assert!((0.5 * (a + b) + 0.7).abs() < 1e-9, "{a} {b}");
        // The bracket shrinks by g per step.
        let g = 0.5 * (5f64.sqrt() - 1.0);
        let (a, b) = golden_section(0.0, 1.0, 10, |x| x, |f1, f2| f1 < f2);
        assert!(((b - a) / g.powi(10) - 1.0).abs() < 1e-9, "{}", b - a);
    }

    #[test]
    fn ln_gamma_matches_factorials_and_half_integers() {
        // Γ(n) = (n − 1)!, Γ(½) = √π, Γ(3/2) = √π/2, and across the reflection at ½.
        let mut factorial = 1.0_f64;
        for n in 1..20 {
            assert!(
                (ln_gamma(n as f64) - factorial.ln()).abs() < 1e-12 * factorial.ln().max(1.0),
                "n = {n}"
            );
            factorial *= n as f64;
        }
        let sqrt_pi = std::f64::consts::PI.sqrt();
        assert!((ln_gamma(0.5) - sqrt_pi.ln()).abs() < 1e-13);
        assert!((ln_gamma(1.5) - (0.5 * sqrt_pi).ln()).abs() < 1e-13);
        // Γ(x + 1) = x Γ(x) on both sides of ½.
        for x in [0.01, 0.3, 0.49, 0.51, 2.7, 17.3] {
            let lhs = ln_gamma(x + 1.0);
            let rhs = x.ln() + ln_gamma(x);
            assert!((lhs - rhs).abs() < 1e-12 * lhs.abs().max(1.0), "x = {x}");
        }
        assert!(ln_gamma(0.0).is_nan() && ln_gamma(-1.5).is_nan());
    }

    #[test]
    fn reciprocal_gamma_vanishes_at_the_poles_and_reflects_between() {
        for n in 0..6 {
            assert_eq!(ln_abs_recip_gamma(-(n as f64)), f64::NEG_INFINITY);
        }
        // Γ(−½) = −2√π, Γ(−3/2) = 4√π/3.
        let sqrt_pi = std::f64::consts::PI.sqrt();
        assert!((ln_abs_recip_gamma(-0.5) + (2.0 * sqrt_pi).ln()).abs() < 1e-13);
        assert!((ln_abs_recip_gamma(-1.5) + (4.0 * sqrt_pi / 3.0).ln()).abs() < 1e-13);
        assert!((ln_abs_recip_gamma(4.0) + 6f64.ln()).abs() < 1e-13);
    }
}
