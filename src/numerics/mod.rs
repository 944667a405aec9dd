//! Small numerical tools every stage shares, each written once: 3-vector arithmetic
//! ([`sub`], [`dot`], [`cross`], [`norm`]), the [`median`], the golden-section search on a
//! bracket ([`golden_section`]), and Levenberg–Marquardt ([`lm`]: one driver for the damping
//! curve's Rayleigh fit, the extraction's variable projection and its glide stage, and the
//! catalogue's bounded fit, each with its own damping and stopping settings).

pub mod lm;

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
}
