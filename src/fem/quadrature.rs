//! Quadrature on the reference tetrahedron {ξ,η,ζ ≥ 0, ξ+η+ζ ≤ 1} (volume 1/6).
//!
//! * degree ≤ 1: the centroid (1 point);
//! * degree 2: the classical symmetric 4-point rule;
//! * degree 3: the collapsed product rule with 2 points per direction (8 points);
//! * degree 4–5: the symmetric 14-point degree-5 rule (all weights positive);
//!   14 points is far cheaper than the 27 of the collapsed product rule, and
//!   degree 4 is the rule used for every straight P2 element, so it matters;
//! * degree ≥ 6: the collapsed (Stroud conical / Duffy) Gauss–Jacobi product rule
//!   with q = ⌈(degree+1)/2⌉ points per direction (exact to degree 2q−1).
//!
//! All rules have strictly positive weights and strictly interior points, so
//! mass matrices built with them are positive definite and a Jacobian check at
//! the points never touches a (possibly degenerate) boundary.

/// Quadrature points on the reference tetrahedron and their weights
/// (weights sum to 1/6, the reference volume).
#[derive(Clone, Debug, PartialEq)]
pub struct QuadratureRule {
    pub points: Vec<[f64; 3]>,
    pub weights: Vec<f64>,
}

impl QuadratureRule {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.weights.len()
    }

    /// True if the rule has no points.
    pub fn is_empty(&self) -> bool {
        self.weights.is_empty()
    }
}

/// A rule exact for all polynomials of total degree ≤ `degree` on the reference
/// tetrahedron, with positive weights and interior points. Any degree works
/// (the point count grows like ((degree+2)/2)³ above degree 5).
pub fn tet_rule(degree: usize) -> QuadratureRule {
    match degree {
        0 | 1 => QuadratureRule {
            points: vec![[0.25; 3]],
            weights: vec![1.0 / 6.0],
        },
        2 => {
            // Symmetric 4-point rule: barycentric (b, a, a, a) orbits with
            // a = (5 − √5)/20, b = 1 − 3a.
            let a = (5.0 - 5f64.sqrt()) / 20.0;
            let b = 1.0 - 3.0 * a;
            QuadratureRule {
                points: orbit_31(a, b),
                weights: vec![1.0 / 24.0; 4],
            }
        }
        3 => collapsed_rule(2),
        4 | 5 => fourteen_point_rule(),
        _ => collapsed_rule((degree + 1).div_ceil(2)),
    }
}

/// Cartesian reference points of the 4-point barycentric orbit where three
/// barycentric coordinates equal `a` and one equals `b = 1 − 3a`.
fn orbit_31(a: f64, b: f64) -> Vec<[f64; 3]> {
    // Cartesian coordinates are the barycentric L1, L2, L3 (L0 = 1 − ξ − η − ζ).
    vec![[a, a, a], [b, a, a], [a, b, a], [a, a, b]]
}

/// 6-point orbit with barycentric coordinates (a, a, b, b), b = 1/2 − a.
fn orbit_22(a: f64) -> Vec<[f64; 3]> {
    let b = 0.5 - a;
    // The pairs of barycentric slots holding `a`: (0,1),(0,2),(0,3),(1,2),(1,3),(2,3).
    let mut pts = Vec::with_capacity(6);
    for (i, j) in [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)] {
        let mut l = [b; 4];
        l[i] = a;
        l[j] = a;
        pts.push([l[1], l[2], l[3]]);
    }
    pts
}

/// Symmetric 14-point rule of degree 5 (two 4-point orbits and one 6-point
/// orbit, all weights positive). Coefficients solve the moment equations of
/// the S4-invariant polynomials up to degree 5; the unit tests check every
/// monomial up to degree 5 to rounding. (Literals keep more digits than f64 holds.)
#[allow(clippy::excessive_precision)]
fn fourteen_point_rule() -> QuadratureRule {
    const A1: f64 = 0.310_885_919_263_300_609_8;
    const W1: f64 = 0.018_781_320_953_002_641_80;
    const A2: f64 = 0.092_735_250_310_891_226_40;
    const W2: f64 = 0.012_248_840_519_393_658_26;
    const A3: f64 = 0.045_503_704_125_649_649_49;
    const W3: f64 = 0.007_091_003_462_846_911_073;
    let mut points = orbit_31(A1, 1.0 - 3.0 * A1);
    points.extend(orbit_31(A2, 1.0 - 3.0 * A2));
    points.extend(orbit_22(A3));
    let mut weights = vec![W1; 4];
    weights.extend([W2; 4]);
    weights.extend([W3; 6]);
    QuadratureRule { points, weights }
}

/// Collapsed product rule with `q` points per direction, exact to degree 2q−1.
///
/// The map (t1,t2,t3) ∈ \[0,1\]³ → (ξ,η,ζ) = (t1, t2(1−t1), t3(1−t1)(1−t2))
/// has Jacobian (1−t1)²(1−t2); Gauss–Jacobi rules with weights (1−t)² and
/// (1−t) absorb it, so a total-degree-d polynomial becomes a polynomial of
/// degree ≤ d in each t_i against the rule's own weight function.
pub fn collapsed_rule(q: usize) -> QuadratureRule {
    let q = q.max(1);
    let (x1, w1) = gauss_jacobi_01(q, 2);
    let (x2, w2) = gauss_jacobi_01(q, 1);
    let (x3, w3) = gauss_jacobi_01(q, 0);
    let mut points = Vec::with_capacity(q * q * q);
    let mut weights = Vec::with_capacity(q * q * q);
    for i in 0..q {
        for j in 0..q {
            for k in 0..q {
                let (t1, t2, t3) = (x1[i], x2[j], x3[k]);
                points.push([t1, t2 * (1.0 - t1), t3 * (1.0 - t1) * (1.0 - t2)]);
                weights.push(w1[i] * w2[j] * w3[k]);
            }
        }
    }
    QuadratureRule { points, weights }
}

/// Gauss–Legendre rule with `n` points on [0,1] (nodes, weights summing to 1).
pub(crate) fn gauss_legendre_01(n: usize) -> (Vec<f64>, Vec<f64>) {
    gauss_jacobi_01(n, 0)
}

/// Gauss–Jacobi rule with `n` points on [0,1] for the weight (1−t)^alpha.
///
/// Built on [−1,1] with weight (1−x)^α: the nodes are the eigenvalues of the
/// Jacobi matrix (found by Sturm-count bisection, which is accurate to
/// rounding and needs no eigen-solver), the weights follow from the
/// Christoffel formula w_i = 1 / Σ_k p̂_k(x_i)² with orthonormal p̂_k.
fn gauss_jacobi_01(n: usize, alpha: u32) -> (Vec<f64>, Vec<f64>) {
    let a = alpha as f64;
    let b = 0.0f64;
    // Recurrence coefficients of the monic Jacobi polynomials P^(a,b).
    let mut diag = vec![0.0; n];
    let mut off2 = vec![0.0; n]; // off2[k] = β_k (squared off-diagonal), k ≥ 1
    for (k, d) in diag.iter_mut().enumerate() {
        let kf = k as f64;
        let s = 2.0 * kf + a + b;
        *d = if k == 0 {
            (b - a) / (a + b + 2.0)
        } else {
            (b * b - a * a) / (s * (s + 2.0))
        };
    }
    for (k, o) in off2.iter_mut().enumerate().skip(1) {
        let kf = k as f64;
        let s = 2.0 * kf + a + b;
        *o = 4.0 * kf * (kf + a) * (kf + b) * (kf + a + b) / (s * s * (s + 1.0) * (s - 1.0));
    }
    // Total mass of the weight on [−1,1]: ∫(1−x)^a dx = 2^(a+1)/(a+1).
    let mu0 = 2f64.powi(alpha as i32 + 1) / (a + 1.0);

    // Number of eigenvalues of the Jacobi matrix below x (LDLᵀ inertia).
    let count_below = |x: f64| -> usize {
        let mut cnt = 0;
        let mut d = 1.0;
        for k in 0..n {
            d = diag[k] - x - if k > 0 { off2[k] / d } else { 0.0 };
            if d == 0.0 {
                d = -f64::EPSILON * (1.0 + x.abs());
            }
            if d < 0.0 {
                cnt += 1;
            }
        }
        cnt
    };

    let mut nodes = Vec::with_capacity(n);
    for i in 0..n {
        // i-th smallest eigenvalue lies in (−1, 1).
        let (mut lo, mut hi) = (-1.0f64, 1.0f64);
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if mid <= lo || mid >= hi {
                break;
            }
            if count_below(mid) > i {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        nodes.push(0.5 * (lo + hi));
    }

    let mut t = Vec::with_capacity(n);
    let mut w = Vec::with_capacity(n);
    for &x in &nodes {
        // Orthonormal recurrence: √β_{k+1} p̂_{k+1} = (x − α_k) p̂_k − √β_k p̂_{k−1}.
        let mut pm1 = 0.0;
        let mut p = 1.0 / mu0.sqrt();
        let mut sum = p * p;
        for k in 0..n - 1 {
            let next = ((x - diag[k]) * p - if k > 0 { off2[k].sqrt() * pm1 } else { 0.0 })
                / off2[k + 1].sqrt();
            pm1 = p;
            p = next;
            sum += p * p;
        }
        let wx = 1.0 / sum;
        // Map to [0,1]: t = (1+x)/2, (1−t)^a = ((1−x)/2)^a, dt = dx/2.
        t.push(0.5 * (1.0 + x));
        w.push(wx / 2f64.powi(alpha as i32 + 1));
    }
    (t, w)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn factorial(n: u32) -> f64 {
        (1..=n).map(|k| k as f64).product()
    }

    /// ∫_T x^a y^b z^c = a! b! c! / (a+b+c+3)!
    fn exact_monomial(a: u32, b: u32, c: u32) -> f64 {
        factorial(a) * factorial(b) * factorial(c) / factorial(a + b + c + 3)
    }

    fn check_rule(rule: &QuadratureRule, degree: u32) {
        assert_eq!(rule.points.len(), rule.weights.len());
        for (p, &w) in rule.points.iter().zip(&rule.weights) {
            assert!(w > 0.0, "non-positive weight {w}");
            assert!(
                p.iter().all(|&c| c > 0.0) && p[0] + p[1] + p[2] < 1.0,
                "point {p:?} not interior"
            );
        }
        for a in 0..=degree {
            for b in 0..=degree - a {
                for c in 0..=degree - a - b {
                    let q: f64 = rule
                        .points
                        .iter()
                        .zip(&rule.weights)
                        .map(|(p, w)| {
                            w * p[0].powi(a as i32) * p[1].powi(b as i32) * p[2].powi(c as i32)
                        })
                        .sum();
                    let e = exact_monomial(a, b, c);
                    assert!(
                        ((q - e) / e).abs() < 1e-12,
                        "degree {degree}: x^{a} y^{b} z^{c}: {q} vs {e}"
                    );
                }
            }
        }
    }

    #[test]
    fn monomials_exact_up_to_degree_12() {
        for d in 0..=12 {
            let rule = tet_rule(d);
            check_rule(&rule, d as u32);
            let s: f64 = rule.weights.iter().sum();
            assert!((s - 1.0 / 6.0).abs() < 1e-15);
        }
    }

    #[test]
    fn collapsed_rules_exact_to_2q_minus_1() {
        for q in 1..=7 {
            check_rule(&collapsed_rule(q), 2 * q as u32 - 1);
        }
    }

    #[test]
    fn rules_are_not_exact_beyond_their_degree() {
        // Guards against a test that passes vacuously: the 4-point rule must miss x^3... for some
        // degree-3 monomial, i.e. the check above can fail.
        let r = tet_rule(2);
        let q: f64 = r
            .points
            .iter()
            .zip(&r.weights)
            .map(|(p, w)| w * p[0].powi(4))
            .sum();
        assert!((q - exact_monomial(4, 0, 0)).abs() > 1e-6);
    }

    #[test]
    fn gauss_jacobi_known_values() {
        // 2-point Gauss–Legendre on [0,1]: 1/2 ± 1/(2√3), weights 1/2.
        let (x, w) = gauss_jacobi_01(2, 0);
        assert!((x[0] - (0.5 - 0.5 / 3f64.sqrt())).abs() < 1e-15);
        assert!((w[0] - 0.5).abs() < 1e-15 && (w[1] - 0.5).abs() < 1e-15);
        // 1-point rule for (1−t)^2: node at the mean 1/4, weight 1/3.
        let (x, w) = gauss_jacobi_01(1, 2);
        assert!((x[0] - 0.25).abs() < 1e-15 && (w[0] - 1.0 / 3.0).abs() < 1e-15);
    }
}
