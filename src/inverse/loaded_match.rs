//! The line-spectrum match with a candidate added mass: E, ν, mass m and its site together.
//!
//! A mass attached to the object (a label, a glue spot, a weight) lowers the modes that move
//! where it sits, and on a symmetric object it splits every degenerate pair: the member with an
//! antinode at the mass falls, the one with a node there stays. The plain line-spectrum match
//! ([`super::material::line_spectrum_start`]) can only scale and re-shape the unloaded pattern
//! with E and ν, so a few per cent of mass pulls ν far off (the blind diagnosis benchmark:
//! ν 0.40 for a true 0.35, 0.17 for 0.155, match distance ~10⁻² against ~10⁻⁵ on clean cases),
//! and everything matched downstream is then wrong.
//!
//! Here the mass is part of the model. With the unloaded modes of the reduced basis at ν
//! (θ_k for E/ρ = 1, mass-normalised shapes φ_k for ρ = 1) as a Ritz basis, a lumped mass
//! m_v [kg] on each of the |R| surface vertices of a region R adds Σ_{v∈R} m_v P_v to the mass
//! matrix ρM₁, so in modal coordinates x = Φy
//!
//! (E/ρ) diag(θ) y = ω² (I + α G_R) y,   G_R = Σ_{v∈R} Φ_vᵀΦ_v,   α = m_v/ρ [m³]
//!
//! (Φ_v the 3 × n values of the modes at vertex v). Its eigenvalues θ'_k (with E/ρ = 1) give
//! the loaded frequencies ln f'_k = ½ ln θ'_k + ½ ln(E/ρ) − ln 2π, and the loaded drive at the
//! strike is (Σ_j y_jk s_j)² with s_j = φ_j(x_s)·n. The Ritz values are upper bounds: with a
//! basis of the band's modes a concentrated mass shifts a little less than it would in the
//! full model, so the fitted mass is, if anything, a little high.
//!
//! The search minimises the plain match's distance (mean capped nearest-line distance, both
//! ways, over the audible partials) over ν, the site, the mass and the scale (E):
//! a coarse pass over ν (step 0.01), a subset of candidate sites and a ladder of mass
//! fractions (0.5–16 % of the body's mass), with E searched in a window around the plain
//! match's; then a fine pass around the best (ν ± 0.01 by 0.001, the sites next to the best,
//! the mass ± 15 %). The caller decides whether the loaded match is good enough to believe
//! (the `diagnose` job: at most half the plain distance).

use nalgebra::{DMatrix, DVector, SymmetricEigen};

use super::material::line_distance;
#[cfg(test)]
use super::material::capped_nearest;

/// The unloaded Ritz modes at one ν, as the search needs them.
#[derive(Clone, Debug)]
pub struct ModesAtPoisson {
    /// θ_k for E/ρ = 1 [rad²/s² per Pa·m³/kg], ascending, all > 0.
    pub theta: Vec<f64>,
    /// s_k = φ_k(x_s)·n at the strike (ρ = 1 mass-normalisation).
    pub strike: Vec<f64>,
    /// Mode values at the candidate vertices: row 3i + c is component c at candidate vertex i,
    /// column k mode k (ρ = 1 mass-normalisation).
    pub values: DMatrix<f64>,
}

/// Loaded Ritz values θ'_k ascending and their drive weights (Σ_j y_jk s_j)², for a lumped
/// mass α = m_v/ρ [m³] on each vertex of `region` (indices into the candidate vertices).
/// `gram` is G_R ([`region_gram`]).
pub fn loaded_modes(modes: &ModesAtPoisson, gram: &DMatrix<f64>, alpha: f64) -> Vec<(f64, f64)> {
    let n = modes.theta.len();
    let mass = DMatrix::identity(n, n) + gram * alpha;
    // I + αG is symmetric positive definite for α ≥ 0; Cholesky M = LLᵀ, then
    // A = L⁻¹ diag(θ) L⁻ᵀ has the same eigenvalues and y = L⁻ᵀ v.
    let Some(chol) = mass.cholesky() else {
        return Vec::new();
    };
    let l = chol.l();
    let sqrt_theta = DMatrix::from_diagonal(&DVector::from_iterator(n, modes.theta.iter().map(|t| t.max(0.0).sqrt())));
    let Some(b) = l.solve_lower_triangular(&sqrt_theta) else {
        return Vec::new();
    };
    let a = &b * b.transpose();
    let eig = SymmetricEigen::new((&a + a.transpose()) * 0.5);
    let lt = l.transpose();
    let strike = DVector::from_column_slice(&modes.strike);
    let mut out: Vec<(f64, f64)> = (0..n)
        .map(|k| {
            let v = eig.eigenvectors.column(k).into_owned();
            let y = lt.solve_upper_triangular(&v).unwrap_or(v);
            let drive = strike.dot(&y);
            (eig.eigenvalues[k], drive * drive)
        })
        .collect();
    out.sort_by(|p, q| p.0.total_cmp(&q.0));
    out
}

/// G_R = Σ_{v∈R} Φ_vᵀΦ_v over the candidate vertices `region`.
pub fn region_gram(modes: &ModesAtPoisson, region: &[usize]) -> DMatrix<f64> {
    let n = modes.theta.len();
    let mut g = DMatrix::zeros(n, n);
    for &v in region {
        for c in 0..3 {
            let row = modes.values.row(3 * v + c);
            g += row.transpose() * row;
        }
    }
    g
}

/// Search settings.
#[derive(Clone, Debug)]
pub struct LoadedMatchSettings {
    /// Mass fractions of the body tried in the coarse pass.
    pub mass_fractions: Vec<f64>,
    /// ν range.
    pub poisson_bounds: (f64, f64),
    /// Window of the scale c = ½ ln(E/ρ) − ln 2π around the plain match's, (below, above): a
    /// mass only lowers frequencies, so E is found higher than the plain match put it.
    pub shift_window: (f64, f64),
    /// The cap of the capped distance (ln f), as the plain match's.
    pub cap: f64,
    /// Partials whose drive is below this fraction of the loudest are inaudible.
    pub audible: f64,
}

impl Default for LoadedMatchSettings {
    fn default() -> Self {
        LoadedMatchSettings {
            mass_fractions: vec![0.005, 0.0075, 0.01, 0.015, 0.02, 0.03, 0.04, 0.05, 0.065, 0.08, 0.10, 0.13, 0.16],
            poisson_bounds: (0.0, 0.49),
            shift_window: (0.05, 0.15),
            cap: 0.02,
            audible: 1e-3,
        }
    }
}

/// The best loaded match.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct LoadedMatch {
    pub youngs: f64,
    pub poisson: f64,
    /// Total added mass [kg] (spread evenly over the region's vertices).
    pub mass_kg: f64,
    /// Index of the best region in the caller's list.
    pub region: usize,
    pub distance: f64,
    pub evaluations: usize,
}

/// The problem: target line frequencies, the body, and the candidate regions.
pub struct LoadedMatchProblem<'a> {
    /// ln of the target's mode frequencies [ln Hz].
    pub target_ln_f: &'a [f64],
    /// Simulated partials above this (ln Hz) are not compared (band limit).
    pub ceiling_ln_f: f64,
    pub density: f64,
    /// Body volume [m³] (its mass is ρV).
    pub volume: f64,
    /// Candidate regions: indices into the candidate vertices of [`ModesAtPoisson::values`].
    pub regions: &'a [Vec<usize>],
    /// Regions tried in the coarse pass (indices into `regions`).
    pub coarse: &'a [usize],
    /// Regions tried in the fine pass around region r (indices into `regions`, r included).
    pub neighbours: &'a dyn Fn(usize) -> Vec<usize>,
    /// E of the plain match [Pa]: the centre of the scale window.
    pub plain_youngs: f64,
}

/// Runs the search (module docs). `modes_at(ν)` gives the unloaded Ritz modes.
pub fn loaded_line_match(problem: &LoadedMatchProblem, modes_at: &dyn Fn(f64) -> ModesAtPoisson, settings: &LoadedMatchSettings) -> Result<LoadedMatch, String> {
    let mut target: Vec<f64> = problem.target_ln_f.iter().copied().filter(|x| x.is_finite()).collect();
    if target.is_empty() {
        return Err("the loaded line match needs the target's mode frequencies".into());
    }
    if problem.regions.is_empty() || problem.coarse.is_empty() {
        return Err("the loaded line match needs at least one candidate region".into());
    }
    if !(problem.density > 0.0 && problem.volume > 0.0 && problem.plain_youngs > 0.0) {
        return Err(format!("density {}, volume {} and E {} must be positive", problem.density, problem.volume, problem.plain_youngs));
    }
    target.sort_by(f64::total_cmp);
    let two_pi_ln = (2.0 * std::f64::consts::PI).ln();
    let c_plain = 0.5 * (problem.plain_youngs / problem.density).ln() - two_pi_ln;
    let cap = settings.cap;
    let ceiling = problem.ceiling_ln_f;
    let distance = |u: &[f64], c: f64| line_distance(&target, u, c, ceiling, cap);
    let pattern = |loaded: &[(f64, f64)]| -> Vec<f64> {
        let loudest = loaded.iter().fold(0.0_f64, |m, p| m.max(p.1));
        let mut u: Vec<f64> = loaded.iter().filter(|p| p.0 > 0.0 && p.1 >= settings.audible * loudest).map(|p| 0.5 * p.0.ln()).collect();
        u.sort_by(f64::total_cmp);
        u
    };
    // Best scale for a pattern over c_plain − below … c_plain + above, by `step`, then ten
    // times finer around the best.
    let best_shift = |u: &[f64], centre: f64, below: f64, above: f64, step: f64| -> (f64, f64, usize) {
        let mut best = (f64::INFINITY, centre);
        let n = ((below + above) / step).ceil() as usize;
        let mut evals = 0;
        for i in 0..=n {
            let c = centre - below + i as f64 * step;
            let d = distance(u, c);
            evals += 1;
            if d < best.0 {
                best = (d, c);
            }
        }
        let c0 = best.1;
        for i in -10..=10 {
            let c = c0 + i as f64 * step / 10.0;
            let d = distance(u, c);
            evals += 1;
            if d < best.0 {
                best = (d, c);
            }
        }
        (best.0, best.1, evals)
    };
    let body_mass = problem.density * problem.volume;
    let alpha_of = |fraction: f64, region: usize| fraction * problem.volume / problem.regions[region].len().max(1) as f64;

    // (distance, c, ν, region, fraction)
    let mut best = (f64::INFINITY, c_plain, settings.poisson_bounds.0, problem.coarse[0], 0.0);
    let mut evaluations = 0;
    let (lo, hi) = settings.poisson_bounds;
    let n_nu = ((hi - lo) / 0.01).ceil().max(1.0) as usize;
    for i in 0..=n_nu {
        let nu = lo + (hi - lo) * i as f64 / n_nu as f64;
        let modes = modes_at(nu);
        for &r in problem.coarse {
            let gram = region_gram(&modes, &problem.regions[r]);
            for &fraction in &settings.mass_fractions {
                let u = pattern(&loaded_modes(&modes, &gram, alpha_of(fraction, r)));
                let (d, c, e) = best_shift(&u, c_plain, settings.shift_window.0, settings.shift_window.1, 1e-3);
                evaluations += e;
                if d < best.0 {
                    best = (d, c, nu, r, fraction);
                }
            }
        }
    }
    // Fine pass around the best.
    let (_, c0, nu0, r0, fraction0) = best;
    let regions = (problem.neighbours)(r0);
    for j in -10..=10 {
        let nu = (nu0 + j as f64 * 0.001).clamp(lo, hi);
        let modes = modes_at(nu);
        for &r in &regions {
            let gram = region_gram(&modes, &problem.regions[r]);
            for s in -3..=3 {
                let fraction = fraction0 * (1.0 + 0.05 * s as f64);
                let u = pattern(&loaded_modes(&modes, &gram, alpha_of(fraction, r)));
                let (d, c, e) = best_shift(&u, c0, 0.005, 0.005, 2e-4);
                evaluations += e;
                if d < best.0 {
                    best = (d, c, nu, r, fraction);
                }
            }
        }
    }
    let (d, c, nu, r, fraction) = best;
    Ok(LoadedMatch { youngs: problem.density * (2.0 * (c + two_pi_ln)).exp(), poisson: nu, mass_kg: fraction * body_mass, region: r, distance: d, evaluations })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two degenerate modes and one single, a candidate vertex where mode 0 moves (along x)
    /// and mode 1 does not.
    fn toy() -> ModesAtPoisson {
        let mut values = DMatrix::zeros(6, 3);
        values[(0, 0)] = 2.0; // vertex 0, x: mode 0
        values[(4, 2)] = 1.0; // vertex 1, y: mode 2
        ModesAtPoisson { theta: vec![1.0, 1.0, 4.0], strike: vec![1.0, 1.0, 1.0], values }
    }

    #[test]
    fn a_lumped_mass_lowers_only_the_mode_that_moves_there() {
        let modes = toy();
        let gram = region_gram(&modes, &[0]);
        let alpha = 0.1;
        let loaded = loaded_modes(&modes, &gram, alpha);
        // Mode 0: θ/(1 + α·4) exactly (the mass couples nothing else); modes 1 and 2 unchanged.
        let expected = [1.0 / (1.0 + alpha * 4.0), 1.0, 4.0];
        for (got, want) in loaded.iter().zip(expected) {
            assert!((got.0 - want).abs() < 1e-12, "{loaded:?}");
        }
        // Without mass the values are θ.
        let none = loaded_modes(&modes, &gram, 0.0);
        assert!(none.iter().zip([1.0, 1.0, 4.0]).all(|(g, w)| (g.0 - w).abs() < 1e-12));
    }

    #[test]
    fn loaded_ritz_values_match_a_dense_generalised_solve() {
        // Random SPD coupling: the Cholesky route against det(K − θM) = 0 solved densely.
        let n = 5;
        let mut values = DMatrix::zeros(6, n);
        for (i, x) in values.iter_mut().enumerate() {
            *x = ((i * 37 % 11) as f64 - 5.0) / 7.0;
        }
        let modes = ModesAtPoisson { theta: vec![1.0, 1.3, 2.0, 2.2, 3.5], strike: vec![0.3, -0.2, 0.5, 0.1, 0.4], values };
        let gram = region_gram(&modes, &[0, 1]);
        let alpha = 0.07;
        let loaded = loaded_modes(&modes, &gram, alpha);
        let m = DMatrix::identity(n, n) + &gram * alpha;
        let k = DMatrix::from_diagonal(&DVector::from_vec(modes.theta.clone()));
        for (theta, _) in &loaded {
            let det = (&k - &m * *theta).determinant();
            let scale = (&k + &m).determinant().abs();
            assert!(det.abs() < 1e-9 * scale, "θ' = {theta}: det {det}");
            assert!(*theta <= 3.5 + 1e-12);
        }
        // Interlacing: adding mass never raises a Ritz value.
        for (l, t) in loaded.iter().zip(&modes.theta) {
            assert!(l.0 <= t + 1e-12);
        }
    }

    #[test]
    fn the_search_recovers_a_planted_mass_and_scale() {
        // Modes independent of ν; candidate vertex 0 moves modes 0 and 2, vertex 1 mode 1.
        let n = 6;
        let mut values = DMatrix::zeros(6, n);
        // Mass-normalised values scale as 1/√V (V = 10⁻⁴ m³): αG ≈ 0.1 at 4 % of the mass.
        values[(0, 0)] = 150.0;
        values[(0, 2)] = 80.0;
        values[(4, 1)] = 120.0;
        values[(3, 4)] = 50.0;
        let theta: Vec<f64> = [1.0_f64, 1.0, 2.6, 2.6, 5.1, 7.3].iter().map(|t| t * 1e7).collect();
        let modes = ModesAtPoisson { theta, strike: vec![1.0; n], values };
        let (density, volume) = (2700.0_f64, 1e-4);
        let truth_youngs = 7e10_f64;
        let regions = vec![vec![0], vec![1]];
        let alpha = 0.04 * volume;
        let gram = region_gram(&modes, &regions[0]);
        let two_pi_ln = (2.0 * std::f64::consts::PI).ln();
        let target: Vec<f64> = loaded_modes(&modes, &gram, alpha).iter().map(|p| 0.5 * p.0.ln() + 0.5 * (truth_youngs / density).ln() - two_pi_ln).collect();
        let neighbours = |_r: usize| vec![0, 1];
        let problem = LoadedMatchProblem { target_ln_f: &target, ceiling_ln_f: f64::INFINITY, density, volume, regions: &regions, coarse: &[0, 1], neighbours: &neighbours, plain_youngs: 0.9 * truth_youngs };
        let settings = LoadedMatchSettings { poisson_bounds: (0.2, 0.3), ..Default::default() };
        let found = loaded_line_match(&problem, &|_nu| modes.clone(), &settings).unwrap();
        assert_eq!(found.region, 0, "{found:?}");
        assert!(found.distance < 1e-4, "{found:?}");
        assert!((found.mass_kg / (density * volume) - 0.04).abs() < 0.003, "{found:?}");
        assert!((found.youngs / truth_youngs - 1.0).abs() < 2e-3, "{found:?}");
        // The plain pattern (no mass) cannot match the split.
        let plain: Vec<f64> = modes.theta.iter().map(|t| 0.5 * t.ln()).collect();
        let c = 0.5 * (truth_youngs / density).ln() - two_pi_ln;
        assert!(capped_nearest(&target, &plain, c, 0.02) > 1e-3);
    }

    #[test]
    fn bad_input_is_an_error() {
        let modes = toy();
        let regions = vec![vec![0]];
        let neighbours = |_r: usize| vec![0];
        let problem = LoadedMatchProblem { target_ln_f: &[], ceiling_ln_f: 10.0, density: 2700.0, volume: 1e-4, regions: &regions, coarse: &[0], neighbours: &neighbours, plain_youngs: 7e10 };
        assert!(loaded_line_match(&problem, &|_nu| modes.clone(), &LoadedMatchSettings::default()).is_err());
        let problem = LoadedMatchProblem { target_ln_f: &[7.0], coarse: &[], ..problem };
        assert!(loaded_line_match(&problem, &|_nu| modes.clone(), &LoadedMatchSettings::default()).is_err());
    }
}
