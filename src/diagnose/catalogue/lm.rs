//! The two numerical kernels of the likelihood fit (parent module docs, "Likelihood"):
//! box-bounded Levenberg–Marquardt on a sum of squared standardised residuals with a
//! central-difference Jacobian, and the profiled model-error floor τ² of one quantity.
//!
//! # Levenberg–Marquardt
//!
//! Minimises C(x) = Σ_i r_i(x)² over the free components of x within [lower, upper], by the
//! crate's driver ([`crate::numerics::lm`]). Each iteration solves (JᵀJ + λ D) δ = −Jᵀr with
//! D = diag(JᵀJ) (Marquardt's scaling: the step does not depend on the units of the
//! parameters), projects x + δ onto the box and keeps it if C falls; λ starts at 10⁻³, shrinks
//! by 3 after a success (not below 10⁻¹²) and grows by 4 after a failure; the fit gives up
//! when λ reaches 10¹⁶ and stops when a step lowers C by at most 10⁻¹² C. A parameter on
//! a bound whose descent direction −∂C/∂x_j points out of the box is held for that iteration
//! (otherwise the projection would eat the whole step and the iteration would stall). A
//! parameter the residuals do not depend on (a zero Jacobian column) is held too.
//!
//! The Jacobian is by central differences, h_j = 10⁻⁶ · max(|x_j|, s_j) with s_j the
//! parameter's typical magnitude, one-sided next to a bound. The models here are a few
//! hundred residuals and at most a few dozen parameters, so 2P evaluations per iteration
//! cost microseconds, and one generic fitter serves every effect of the catalogue.
//!
//! # Profiled floor
//!
//! For residuals r_i with measurement variances v_i and a common extra variance t = τ² ≥ 0,
//! −2 ln L = Σ_i [ln 2π(v_i + t) + r_i²/(v_i + t)]. Its minimum over t has no closed form when
//! the v_i differ; h(t) = Σ [ln(v_i + t) + r_i²/(v_i + t)] is searched on t = 0 and 64
//! log-spaced values from 10⁻⁴ min v to 10 max r² + max v, then refined by golden section
//! between the neighbours of the best grid point (h can have more than one local minimum
//! when the v_i span decades, which is why a plain Newton iteration from t = 0 is not used).

use nalgebra::{DMatrix, DVector};

use crate::numerics::lm;

/// What [`minimise`] returns.
#[derive(Clone, Debug)]
pub(super) struct Minimum {
    pub x: Vec<f64>,
    /// Σ r² at `x` (∞ if the start gave non-finite residuals).
    pub cost: f64,
}

/// Residuals of `x` into `out`; true when they are all finite.
fn evaluate<F: FnMut(&[f64], &mut [f64])>(f: &mut F, x: &[f64], out: &mut [f64]) -> f64 {
    f(x, out);
    let mut cost = 0.0;
    for r in out.iter() {
        if !r.is_finite() {
            return f64::INFINITY;
        }
        cost += r * r;
    }
    cost
}

/// Central-difference Jacobian of the residuals with respect to the free parameters, rows =
/// residuals, one column per entry of `columns`. A column whose shifted residuals are not
/// finite on both sides is left zero (the parameter is then held by the caller).
pub(super) fn jacobian<F: FnMut(&[f64], &mut [f64])>(
    f: &mut F,
    x: &[f64],
    columns: &[usize],
    lower: &[f64],
    upper: &[f64],
    scale: &[f64],
    n_residuals: usize,
) -> DMatrix<f64> {
    let mut jac = DMatrix::<f64>::zeros(n_residuals, columns.len());
    let mut plus = vec![0.0; n_residuals];
    let mut minus = vec![0.0; n_residuals];
    let mut centre = vec![0.0; n_residuals];
    let centre_cost = evaluate(f, x, &mut centre);
    let mut xs = x.to_vec();
    for (col, &j) in columns.iter().enumerate() {
        let h = 1e-6 * x[j].abs().max(scale[j]);
        let hi = (x[j] + h).min(upper[j]);
        let lo = (x[j] - h).max(lower[j]);
        xs[j] = hi;
        let cost_hi = evaluate(f, &xs, &mut plus);
        xs[j] = lo;
        let cost_lo = evaluate(f, &xs, &mut minus);
        xs[j] = x[j];
        let (a, b, step) = match (cost_hi.is_finite(), cost_lo.is_finite()) {
            (true, true) if hi > lo => (&plus, &minus, hi - lo),
            (true, _) if hi > x[j] && centre_cost.is_finite() => (&plus, &centre, hi - x[j]),
            (_, true) if x[j] > lo && centre_cost.is_finite() => (&centre, &minus, x[j] - lo),
            _ => continue,
        };
        for i in 0..n_residuals {
            jac[(i, col)] = (a[i] - b[i]) / step;
        }
    }
    jac
}

/// Box-bounded Levenberg–Marquardt (module docs). `residuals(x, out)` writes the
/// `n_residuals` standardised residuals of `x`; only components with `free[j]` move.
#[allow(clippy::too_many_arguments)]
pub(super) fn minimise<F: FnMut(&[f64], &mut [f64])>(
    mut residuals: F,
    n_residuals: usize,
    x0: &[f64],
    free: &[bool],
    lower: &[f64],
    upper: &[f64],
    scale: &[f64],
    max_iterations: usize,
) -> Minimum {
    let x: Vec<f64> = x0
        .iter()
        .zip(lower.iter().zip(upper))
        .map(|(&v, (&lo, &hi))| v.clamp(lo, hi))
        .collect();
    let mut r = vec![0.0; n_residuals];
    let cost = evaluate(&mut residuals, &x, &mut r);
    if !cost.is_finite() {
        return Minimum { x, cost };
    }
    let columns: Vec<usize> = (0..x.len()).filter(|&j| free[j]).collect();
    if columns.is_empty() || n_residuals == 0 {
        return Minimum { x, cost };
    }
    let mut problem = BoxedResiduals {
        residuals,
        x,
        r,
        columns,
        lower,
        upper,
        scale,
        active: vec![],
        trial_x: vec![],
        trial_r: vec![0.0; n_residuals],
    };
    let outcome = lm::minimise(&mut problem, cost, &settings(max_iterations));
    Minimum {
        x: problem.x,
        cost: outcome.cost,
    }
}

/// The fit's damping and stopping (module docs): λ from 10⁻³, ÷3 after a success (not below
/// 10⁻¹²), ×4 after a failure, given up at 10¹⁶; a step must lower C, and the fit stops when
/// one lowers it by at most 10⁻¹² of the new C.
fn settings(max_iterations: usize) -> lm::Settings {
    lm::Settings {
        damping: lm::Damping {
            start: 1e-3,
            min: 1e-12,
            // Tried while λ < 10¹⁶: the largest f64 below it.
            max: f64::from_bits(1e16f64.to_bits() - 1),
            shrink: 3.0,
            grow: 4.0,
        },
        max_iterations,
        accept: lm::Accept::Decrease,
        solve: lm::Solve::Direct,
        stopping: lm::Stopping {
            relative_decrease: Some((1e-12, lm::CostReference::After)),
            ..lm::Stopping::default()
        },
    }
}

/// [`minimise`]'s problem: the current point and its residuals, and the free parameters that
/// move in this iteration (`active`, indices into `columns`).
struct BoxedResiduals<'a, F> {
    residuals: F,
    x: Vec<f64>,
    r: Vec<f64>,
    columns: Vec<usize>,
    lower: &'a [f64],
    upper: &'a [f64],
    scale: &'a [f64],
    active: Vec<usize>,
    trial_x: Vec<f64>,
    trial_r: Vec<f64>,
}

impl<F: FnMut(&[f64], &mut [f64])> lm::Problem for BoxedResiduals<'_, F> {
    type Scalar = f64;

    fn normal_equations(&mut self) -> Option<lm::NormalEquations<f64>> {
        let jac = jacobian(
            &mut self.residuals,
            &self.x,
            &self.columns,
            self.lower,
            self.upper,
            self.scale,
            self.r.len(),
        );
        let jtj = jac.transpose() * &jac;
        let grad = jac.transpose() * DVector::from_column_slice(&self.r);
        let max_diag = (0..self.columns.len())
            .map(|c| jtj[(c, c)])
            .fold(0.0, f64::max);
        if max_diag <= 0.0 {
            return None;
        }
        // Active set: drop parameters with no influence and those pushed against a bound.
        let (x, lower, upper) = (&self.x, self.lower, self.upper);
        let columns = &self.columns;
        self.active = (0..columns.len())
            .filter(|&c| {
                let j = columns[c];
                let influential = jtj[(c, c)] > 1e-14 * max_diag;
                let blocked_low = x[j] <= lower[j] && grad[c] > 0.0;
                let blocked_high = x[j] >= upper[j] && grad[c] < 0.0;
                influential && !blocked_low && !blocked_high
            })
            .collect();
        let a = &self.active;
        (!a.is_empty()).then(|| lm::NormalEquations {
            h: DMatrix::from_fn(a.len(), a.len(), |p, q| jtj[(a[p], a[q])]),
            g: DVector::from_fn(a.len(), |p, _| grad[a[p]]),
        })
    }

    fn trial(&mut self, step: &DVector<f64>) -> Option<f64> {
        self.trial_x.clone_from(&self.x);
        for (p, &c) in self.active.iter().enumerate() {
            let j = self.columns[c];
            self.trial_x[j] = (self.x[j] + step[p]).clamp(self.lower[j], self.upper[j]);
        }
        Some(evaluate(
            &mut self.residuals,
            &self.trial_x,
            &mut self.trial_r,
        ))
    }

    fn accept(&mut self) {
        std::mem::swap(&mut self.x, &mut self.trial_x);
        std::mem::swap(&mut self.r, &mut self.trial_r);
    }
}

/// The t ≥ 0 minimising `h` over [0, t_hi]: a grid of t = 0 and 64 log-spaced values from
/// `t_lo` to `t_hi`, then golden section between the neighbours of the best grid point; the
/// best of the refined value, the grid's best and t = 0 is returned.
pub(super) fn minimise_nonnegative(h: impl Fn(f64) -> f64, t_lo: f64, t_hi: f64) -> f64 {
    if !(t_hi > t_lo && t_lo > 0.0) {
        return 0.0;
    }
    const GRID: usize = 64;
    let mut grid = Vec::with_capacity(GRID + 1);
    grid.push(0.0);
    for m in 0..GRID {
        grid.push(t_lo * (t_hi / t_lo).powf(m as f64 / (GRID - 1) as f64));
    }
    let values: Vec<f64> = grid.iter().map(|&t| h(t)).collect();
    let best = (0..grid.len())
        .min_by(|&a, &b| values[a].total_cmp(&values[b]))
        .unwrap_or(0);
    let lo = if best == 0 { 0.0 } else { grid[best - 1] };
    let hi = grid[(best + 1).min(grid.len() - 1)];
    // Golden section on [lo, hi] (h is unimodal between the neighbours of the grid minimum).
    let (a, b) = crate::numerics::golden_section(lo, hi, 60, &h, |fc, fd| fc < fd);
    let t = 0.5 * (a + b);
    let candidates = [(t, h(t)), (grid[best], values[best]), (0.0, values[0])];
    candidates
        .iter()
        .min_by(|p, q| p.1.total_cmp(&q.1))
        .map(|p| p.0)
        .unwrap_or(0.0)
}

/// The maximum-likelihood extra variance τ² ≥ 0 for residuals `r` with measurement
/// variances `v` (module docs, "Profiled floor"). 0 for no residuals.
pub(super) fn profile_floor(r: &[f64], v: &[f64]) -> f64 {
    profile_floor_with(r, v, |_, r, v| v.ln() + r * r / v)
}

/// [`profile_floor`] for any row likelihood: the τ² ≥ 0 minimising h(τ²) = Σ_i
/// `row`(i, r_i, v_i + τ²), `row`(i, r, v) being row i's −2 ln L without its constant (for
/// Gaussian rows ln v + r²/v, h(t) of the module docs; the index lets a row's likelihood
/// depend on more than its residual, as a truncated row's does on its ceiling), searched over
/// [10⁻⁴ min v, 10 max r² + max v].
pub(super) fn profile_floor_with(
    r: &[f64],
    v: &[f64],
    row: impl Fn(usize, f64, f64) -> f64,
) -> f64 {
    if r.is_empty() {
        return 0.0;
    }
    let v_min = v.iter().cloned().fold(f64::INFINITY, f64::min).max(1e-300);
    let v_max = v.iter().cloned().fold(0.0, f64::max);
    let r2_max = r.iter().map(|r| r * r).fold(0.0, f64::max);
    minimise_nonnegative(
        |t| (0..r.len()).map(|i| row(i, r[i], v[i] + t)).sum(),
        1e-4 * v_min,
        10.0 * r2_max + v_max,
    )
}

/// Inverse of JᵀJ (the covariance of the parameters when the residuals are standardised),
/// by eigen-decomposition so that directions the data do not determine get an infinite
/// variance instead of a failed factorisation: returns the standard deviation per column.
pub(super) fn standard_errors(jac: &DMatrix<f64>) -> Vec<f64> {
    let n = jac.ncols();
    if n == 0 {
        return vec![];
    }
    let jtj = jac.transpose() * jac;
    // Scale to unit diagonal first so the cut-off below is relative to each parameter's own
    // information, not to the units of the others.
    let scale: Vec<f64> = (0..n).map(|j| jtj[(j, j)].sqrt()).collect();
    if scale.iter().any(|&s| !(s > 0.0) || !s.is_finite()) {
        let mut out = vec![f64::INFINITY; n];
        // Parameters with information still get a value if the rest of the matrix allows.
        let keep: Vec<usize> = (0..n)
            .filter(|&j| scale[j] > 0.0 && scale[j].is_finite())
            .collect();
        if !keep.is_empty() {
            let sub = jac.select_columns(keep.iter());
            for (s, &j) in standard_errors(&sub).into_iter().zip(&keep) {
                out[j] = s;
            }
        }
        return out;
    }
    let normalised = DMatrix::from_fn(n, n, |i, j| jtj[(i, j)] / (scale[i] * scale[j]));
    let eig = normalised.symmetric_eigen();
    let max_eig = eig.eigenvalues.iter().cloned().fold(0.0, f64::max);
    let mut variance = vec![0.0; n];
    let mut undetermined = vec![false; n];
    for (k, &lam) in eig.eigenvalues.iter().enumerate() {
        let vk = eig.eigenvectors.column(k);
        if lam > 1e-12 * max_eig {
            for j in 0..n {
                variance[j] += vk[j] * vk[j] / lam;
            }
        } else {
            for j in 0..n {
                if vk[j].abs() > 1e-6 {
                    undetermined[j] = true;
                }
            }
        }
    }
    (0..n)
        .map(|j| {
            if undetermined[j] {
                f64::INFINITY
            } else {
                variance[j].sqrt() / scale[j]
            }
        })
        .collect()
}
