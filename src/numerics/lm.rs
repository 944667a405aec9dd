//! Levenberg–Marquardt, written once: the damping loop, the damped solve and the stopping rules
//! of every nonlinear least-squares fit in the crate, over a small [`Problem`] that supplies the
//! normal equations and the cost of a trial step.
//!
//! # The iteration
//!
//! A problem minimises a cost C(x) = Σ_i w_i |r_i(x)|² over parameters x (real, or complex when
//! the model is holomorphic in them). At the current point it supplies the Gauss–Newton normal
//! equations
//!
//! H = Jᴴ W J,   g = Jᴴ W r   (½ ∇C; J = ∂r/∂x, W = diag w),
//!
//! over the parameters that move in this iteration. With D = diag(max(Re H_jj, 0)) each
//! iteration solves
//!
//! (H + λ D) δ = −g
//!
//! (Marquardt's scaling: the step does not depend on the units of the parameters), asks the
//! problem for C at x + δ (the problem may project the trial point, e.g. onto bounds), and keeps
//! it if C falls (strictly, or without rising: [`Accept`]); λ is then divided by
//! [`Damping::shrink`] (not below [`Damping::min`]). A rejected step, or a damped matrix that is
//! not positive definite, multiplies λ by [`Damping::grow`] and solves again; once λ exceeds
//! [`Damping::max`] the fit stops ([`Stop::DampingExhausted`]). One iteration is one set of
//! normal equations; at most [`Settings::max_iterations`] of them.
//!
//! The damped system is solved by Cholesky, either as it stands ([`Solve::Direct`]: H_jj + λ
//! max(H_jj, f64::MIN_POSITIVE) on the diagonal) or Jacobi-scaled ([`Solve::Scaled`]: with
//! s_j = 1/√max(D_jj, 10⁻¹⁴ max D), M = S H S with M_jj = (1 + λ) Re(S H S)_jj, M y = −S g,
//! δ = S y; a non-finite step counts as a failed factorisation). The two are the same equation;
//! the scaled form keeps the factorisation accurate when diag H spans many decades or has
//! zeros (the extraction's poles without amplitude).
//!
//! # Complex parameters
//!
//! For a model holomorphic in complex parameters ℓ the complex Gauss–Newton step with the
//! Hermitian H = Jᴴ W J and the Wirtinger gradient g equals the real Gauss–Newton step in
//! (Re ℓ, Im ℓ), so the same iteration runs on [`Problem::Scalar`] = `Complex64` (the
//! extraction's log-poles) at a quarter of the real system's size, with λ scaling both halves of
//! each parameter by the same D_jj. Step sizes are moduli |δ_j|.
//!
//! # Stopping rules ([`Stopping`], each optional)
//!
//! * Newton decrement, before a step: gᴴ H⁻¹ g < ε² (the full Gauss–Newton step is below ε in
//!   its Mahalanobis norm √(δᴴHδ), the whole parameter vector's standard deviations when W holds
//!   the inverse noise variances). H⁻¹ by [`symmetric_inverse`]; a singular H does not stop.
//! * Step in standard deviations, per parameter: σ_j = |δ_j| √D_jj (with the others held, 1/√H_jj
//!   is parameter j's standard deviation) below ε_j for every j. Tested on every solved step: an
//!   accepted one stops after it is taken, a rejected one stops the fit where it is (steps below
//!   the tolerance that do not lower C mean the minimum to rounding).
//! * Largest step, after an accepted step: max_j |δ_j| ≤ ε (in the parameters' own units).
//! * Relative decrease, after an accepted step: C_before − C_after ≤ ε · max(C_ref, 10⁻³⁰⁰),
//!   C_ref the cost before or after the step ([`CostReference`]; the floor lets a zero cost
//!   stop).
//!
//! The fit also stops when the problem has no parameter left to move
//! ([`Problem::normal_equations`] returns `None`) or when no diagonal entry of H is positive and
//! finite (the cost does not depend on any parameter): [`Stop::NothingToMove`].
//!
//! # Who uses it
//!
//! The catalogue's box-bounded fit ([`crate::diagnose::catalogue`]: central-difference Jacobian,
//! held parameters on the bounds), the Rayleigh fit of the damping curve
//! ([`crate::inverse::damping::fit_rayleigh`]), the extraction's variable projection on complex
//! log-poles ([`crate::analysis::extract`]) and its glide stage. Each keeps its own damping
//! factors and stopping rules in its [`Settings`]. (The minimum-norm Levenberg step of
//! [`crate::inverse::geometry`], for an underdetermined system, is a different algorithm.)

use nalgebra::{ComplexField, DMatrix, DVector};

/// The normal equations of one iteration, over the parameters that move in it (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct NormalEquations<T: ComplexField<RealField = f64>> {
    /// H = Jᴴ W J, Hermitian positive semi-definite.
    pub h: DMatrix<T>,
    /// g = Jᴴ W r.
    pub g: DVector<T>,
}

/// A least-squares problem as the driver sees it. The problem holds its current point; the
/// driver never sees the parameters, only steps for the ones the last normal equations covered.
pub trait Problem {
    /// f64, or Complex64 for a holomorphic model (module docs, "Complex parameters").
    type Scalar: ComplexField<RealField = f64> + Copy;

    /// The normal equations at the current point, over the parameters that may move now (a
    /// problem with bounds leaves out those held on them); `None` when none may move.
    fn normal_equations(&mut self) -> Option<NormalEquations<Self::Scalar>>;

    /// The cost at the current point plus `step` (projected as the problem requires), `None` if
    /// that point is outside the model's domain. The problem keeps the trial for [`accept`].
    ///
    /// [`accept`]: Problem::accept
    fn trial(&mut self, step: &DVector<Self::Scalar>) -> Option<f64>;

    /// Makes the last trial the current point.
    fn accept(&mut self);
}

/// λ's start, bounds and updates (module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Damping {
    pub start: f64,
    /// λ is not shrunk below this.
    pub min: f64,
    /// The fit stops once λ exceeds this.
    pub max: f64,
    /// λ ← max(λ / shrink, min) after an accepted step.
    pub shrink: f64,
    /// λ ← λ · grow after a rejected step or a failed factorisation.
    pub grow: f64,
}

/// When a trial step is taken.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Accept {
    /// C(x + δ) < C(x).
    Decrease,
    /// C(x + δ) ≤ C(x): a step along a flat valley is taken.
    NoIncrease,
}

/// How the damped system is solved (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Solve {
    Direct,
    Scaled,
}

/// Which cost the relative-decrease rule compares the decrease with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CostReference {
    Before,
    After,
}

/// The optional stopping rules (module docs).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Stopping {
    /// ε of gᴴH⁻¹g < ε².
    pub newton_decrement: Option<f64>,
    /// ε_j per parameter of σ_j = |δ_j| √D_jj < ε_j.
    pub step_sigma: Option<Vec<f64>>,
    /// ε of max_j |δ_j| ≤ ε.
    pub max_step: Option<f64>,
    /// ε of C_before − C_after ≤ ε · max(C_ref, 10⁻³⁰⁰).
    pub relative_decrease: Option<(f64, CostReference)>,
}

/// Everything a caller chooses.
#[derive(Clone, Debug, PartialEq)]
pub struct Settings {
    pub damping: Damping,
    /// Sets of normal equations at most.
    pub max_iterations: usize,
    pub accept: Accept,
    pub solve: Solve,
    pub stopping: Stopping,
}

/// A stopping rule of [`Stopping`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rule {
    NewtonDecrement,
    StepSigma,
    MaxStep,
    RelativeDecrease,
}

/// Why the fit ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stop {
    Converged(Rule),
    /// No parameter may move, or the cost depends on none.
    NothingToMove,
    /// λ exceeded [`Damping::max`] without an accepted step.
    DampingExhausted,
    IterationLimit,
}

/// What [`minimise`] returns; the point itself is the problem's current one.
#[derive(Clone, Debug, PartialEq)]
pub struct Outcome {
    /// C at the final point.
    pub cost: f64,
    /// Sets of normal equations used.
    pub iterations: usize,
    pub stop: Stop,
    /// σ_j of the last accepted step, or of the rejected step that stopped the fit by
    /// [`Rule::StepSigma`]; `None` if neither happened.
    pub step_sigma: Option<Vec<f64>>,
}

/// Levenberg–Marquardt on `problem` from its current point, whose cost is `cost` (module docs).
pub fn minimise<P: Problem>(problem: &mut P, cost: f64, settings: &Settings) -> Outcome {
    let Damping {
        start,
        min,
        max,
        shrink,
        grow,
    } = settings.damping;
    let rules = &settings.stopping;
    let mut cost = cost;
    let mut lambda = start;
    let mut iterations = 0;
    let mut step_sigma = None;
    let stop = 'fit: loop {
        if iterations >= settings.max_iterations {
            break Stop::IterationLimit;
        }
        iterations += 1;
        let Some(NormalEquations { h, g }) = problem.normal_equations() else {
            break Stop::NothingToMove;
        };
        let diag: Vec<f64> = (0..h.nrows()).map(|j| h[(j, j)].real().max(0.0)).collect();
        let top = diag.iter().cloned().fold(0.0, f64::max);
        if !(top > 0.0 && top.is_finite()) {
            break Stop::NothingToMove;
        }
        if let Some(eps) = rules.newton_decrement {
            let decrement = symmetric_inverse(&h).map(|inv| g.dotc(&(&inv * &g)).real());
            if decrement.is_some_and(|v| v < eps * eps) {
                break Stop::Converged(Rule::NewtonDecrement);
            }
        }
        loop {
            if !(lambda <= max) {
                break 'fit Stop::DampingExhausted;
            }
            let Some(step) = damped_step(&h, &g, &diag, top, lambda, settings.solve) else {
                lambda *= grow;
                continue;
            };
            let sigma: Vec<f64> = step
                .iter()
                .zip(&diag)
                .map(|(s, d)| s.modulus() * d.sqrt())
                .collect();
            let small = rules
                .step_sigma
                .as_ref()
                .is_some_and(|eps| sigma.iter().zip(eps).all(|(s, e)| s < e));
            let taken = problem.trial(&step).filter(|&c| {
                c.is_finite()
                    && match settings.accept {
                        Accept::Decrease => c < cost,
                        Accept::NoIncrease => c <= cost,
                    }
            });
            let Some(new_cost) = taken else {
                if small {
                    step_sigma = Some(sigma);
                    break 'fit Stop::Converged(Rule::StepSigma);
                }
                lambda *= grow;
                continue;
            };
            problem.accept();
            let before = std::mem::replace(&mut cost, new_cost);
            lambda = (lambda / shrink).max(min);
            step_sigma = Some(sigma);
            if small {
                break 'fit Stop::Converged(Rule::StepSigma);
            }
            if let Some(eps) = rules.max_step {
                let largest = step.iter().map(|s| s.modulus()).fold(0.0, f64::max);
                if !(largest > eps) {
                    break 'fit Stop::Converged(Rule::MaxStep);
                }
            }
            if let Some((eps, reference)) = rules.relative_decrease {
                let c_ref = match reference {
                    CostReference::Before => before,
                    CostReference::After => cost,
                };
                if before - cost <= eps * c_ref.max(1e-300) {
                    break 'fit Stop::Converged(Rule::RelativeDecrease);
                }
            }
            break;
        }
    };
    Outcome {
        cost,
        iterations,
        stop,
        step_sigma,
    }
}

/// δ of (H + λ D) δ = −g (module docs), `None` if the damped matrix is not positive definite
/// (or, scaled, the step not finite). `diag` = D, `top` = max D > 0.
fn damped_step<T: ComplexField<RealField = f64> + Copy>(
    h: &DMatrix<T>,
    g: &DVector<T>,
    diag: &[f64],
    top: f64,
    lambda: f64,
    solve: Solve,
) -> Option<DVector<T>> {
    match solve {
        Solve::Direct => {
            let mut a = h.clone();
            for j in 0..a.nrows() {
                a[(j, j)] += T::from_real(lambda * h[(j, j)].real().max(f64::MIN_POSITIVE));
            }
            Some(a.cholesky()?.solve(&(-g)))
        }
        Solve::Scaled => {
            let n = h.nrows();
            // A parameter the cost does not depend on has D_jj = 0; the floor keeps the scaled
            // system defined (its step is then ~0).
            let scale: Vec<f64> = diag
                .iter()
                .map(|&d| 1.0 / d.max(1e-14 * top).sqrt())
                .collect();
            let m = DMatrix::from_fn(n, n, |i, j| {
                let v = h[(i, j)].scale(scale[i]).scale(scale[j]);
                if i == j {
                    T::from_real(v.real() * (1.0 + lambda))
                } else {
                    v
                }
            });
            let rhs = DVector::from_fn(n, |i, _| (-g[i]).scale(scale[i]));
            let y = m.cholesky()?.solve(&rhs);
            let step = DVector::from_fn(n, |i, _| y[i].scale(scale[i]));
            step.iter().all(|v| v.is_finite()).then_some(step)
        }
    }
}

/// H⁻¹ of a Hermitian positive definite H, by Cholesky after Jacobi scaling (so that the
/// factorisation does not depend on the parameters' units); `None` if H is singular.
pub fn symmetric_inverse<T: ComplexField<RealField = f64> + Copy>(
    h: &DMatrix<T>,
) -> Option<DMatrix<T>> {
    let p = h.nrows();
    let scale: Vec<f64> = (0..p)
        .map(|i| 1.0 / h[(i, i)].real().max(f64::MIN_POSITIVE).sqrt())
        .collect();
    let scaled = DMatrix::from_fn(p, p, |i, j| h[(i, j)].scale(scale[i]).scale(scale[j]));
    let inv = scaled.cholesky()?.inverse();
    Some(DMatrix::from_fn(p, p, |i, j| {
        inv[(i, j)].scale(scale[i]).scale(scale[j])
    }))
}

#[cfg(test)]
mod tests;
