//! Small numerical tools every stage shares, each written once: 3-vector arithmetic
//! ([`sub`], [`dot`], [`cross`], [`norm`]), the [`median`], the golden-section search on a
//! bracket ([`golden_section`]), the nearest element of a sorted list ([`nearest_sorted`]),
//! ln Γ on the whole real line ([`ln_gamma`],
//! [`ln_abs_recip_gamma`]), the normal distribution's ln Φ and inverse Mills ratio
//! ([`ln_normal_cdf`], [`inverse_mills`]), Levenberg–Marquardt ([`lm`]: one driver for the damping
//! curve's Rayleigh fit, the extraction's variable projection and its glide stage, and the
//! catalogue's bounded fit, each with its own damping and stopping settings), and the
//! eigenvalues of a symmetric matrix with one vector's weight on each eigenvector
//! ([`spectral_weights`]), the DFT at a band of bins by decimation ([`band_dft`]), and a map over items on scoped
//! threads whose result does not depend on their count ([`map_on_threads`]).

pub mod band_dft;
pub mod lm;
pub mod spectral_weights;

/// `f` of each item, results in the items' order, on up to `threads` scoped threads that take
/// the next item as they finish one (the items' costs differ: a fit may take ten times
/// another's); one thread, or one item, runs here. The result does not depend on `threads`.
pub fn map_on_threads<T: Sync, R: Send>(
    items: &[T],
    threads: usize,
    f: impl Fn(&T) -> R + Sync,
) -> Vec<R> {
    let threads = threads.clamp(1, items.len().max(1));
    if threads == 1 {
        return items.iter().map(&f).collect();
    }
    let next = std::sync::atomic::AtomicUsize::new(0);
    let (f, next) = (&f, &next);
    let mut done: Vec<(usize, R)> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..threads)
            .map(|_| {
                scope.spawn(move || {
                    let mut mine = Vec::new();
                    loop {
                        let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        let Some(item) = items.get(i) else {
                            return mine;
                        };
                        mine.push((i, f(item)));
                    }
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().expect("a worker thread panicked"))
            .collect()
    });
    done.sort_by_key(|(i, _)| *i);
    done.into_iter().map(|(_, r)| r).collect()
}

#[cfg(test)]
mod map_tests {
    #[test]
    fn the_map_on_threads_keeps_the_order_whatever_the_count() {
        let items: Vec<u64> = (0..37).collect();
        // Uneven work: item i spins i² steps.
        let f = |&i: &u64| (0..i * i).fold(i, |a, b| a.wrapping_mul(31).wrapping_add(b));
        let one = super::map_on_threads(&items, 1, f);
        for threads in [0, 2, 3, 8, 100] {
            assert_eq!(
                super::map_on_threads(&items, threads, f),
                one,
                "{threads} threads"
            );
        }
        assert!(super::map_on_threads(&[] as &[u64], 4, f).is_empty());
    }
}

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

/// ln erfc(z) for z ≥ 0 by the Chebyshev-fitted form erfc(z) ≈ t exp(−z² + P(t)),
/// t = 1/(1 + z/2), P a degree-9 polynomial (relative error of erfc below 1.2·10⁻⁷ for every
/// z ≥ 0). Written in the log, so that it stays finite where erfc underflows.
fn ln_erfc_nonnegative(z: f64) -> f64 {
    const P: [f64; 10] = [
        -1.265_512_23,
        1.000_023_68,
        0.374_091_96,
        0.096_784_18,
        -0.186_288_06,
        0.278_868_07,
        -1.135_203_98,
        1.488_515_87,
        -0.822_152_23,
        0.170_872_77,
    ];
    let t = 1.0 / (1.0 + 0.5 * z);
    let poly = P.iter().rev().fold(0.0, |acc, c| acc * t + c);
    t.ln() - z * z + poly
}

/// ln Φ(w), Φ the standard normal distribution function, for any real w (−∞ only at
/// w = −∞): Φ(w) = erfc(−w/√2)/2, taken through ln erfc below the median and as
/// ln(1 − erfc(w/√2)/2) above it, so that neither tail loses its digits. Relative error of Φ
/// about 10⁻⁷.
pub fn ln_normal_cdf(w: f64) -> f64 {
    let z = w / std::f64::consts::SQRT_2;
    if z <= 0.0 {
        ln_erfc_nonnegative(-z) - std::f64::consts::LN_2
    } else {
        (-0.5 * ln_erfc_nonnegative(z).exp()).ln_1p()
    }
}

/// The inverse Mills ratio λ(w) = φ(w)/Φ(w) (φ the standard normal density): the derivative
/// of ln Φ. λ → 0 as w → ∞ and λ ≈ −w as w → −∞, where it is computed without forming the
/// vanishing φ and Φ.
pub fn inverse_mills(w: f64) -> f64 {
    (-0.5 * w * w - 0.5 * (2.0 * std::f64::consts::PI).ln() - ln_normal_cdf(w)).exp()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_distribution_function_in_both_tails() {
        // Reference values of Φ (tables of the normal distribution).
        for (w, phi) in [
            (0.0, 0.5),
            (1.0, 0.841_344_746_068_543),
            (-1.0, 0.158_655_253_931_457),
            (-3.0, 1.349_898_031_630_09e-3),
            (2.5, 0.993_790_334_674_224),
            (-8.0, 6.220_960_574_271_78e-16),
        ] {
            let got = ln_normal_cdf(w).exp();
            assert!((got / phi - 1.0).abs() < 5e-7, "Φ({w}) = {got}, not {phi}");
        }
        // Far in the lower tail ln Φ(w) → −w²/2 − ln(−w) − ln √(2π), and λ(w) → −w.
        let w: f64 = -40.0;
        let asymptote = -0.5 * w * w - (-w).ln() - 0.5 * (2.0 * std::f64::consts::PI).ln();
        assert!(
            (ln_normal_cdf(w) - asymptote).abs() < 1e-3,
            "{}",
            ln_normal_cdf(w)
        );
        assert!(
            (inverse_mills(w) / -w - 1.0).abs() < 1e-3,
            "{}",
            inverse_mills(w)
        );
        // λ is the derivative of ln Φ (to the difference quotient's step, which must be wide
        // beside Φ's own 10⁻⁷).
        for w in [-5.0, -1.0, 0.0, 0.7, 3.0] {
            let h = 1e-3;
            let fd = (ln_normal_cdf(w + h) - ln_normal_cdf(w - h)) / (2.0 * h);
            assert!(
                (fd - inverse_mills(w)).abs() < 1e-3 * (1.0 + fd.abs()),
                "{w}: {fd}"
            );
        }
    }

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
