//! Adam (Kingma & Ba, 2015) with per-parameter step sizes and box bounds.
//!
//! For parameter θ_i with gradient g_i at step t (t = 1, 2, …):
//!
//! m_i ← β₁ m_i + (1 − β₁) g_i,   v_i ← β₂ v_i + (1 − β₂) g_i²
//! θ_i ← clamp( θ_i − η_i · m̂_i / (√v̂_i + ε), lo_i, hi_i ),   m̂ = m/(1 − β₁ᵗ), v̂ = v/(1 − β₂ᵗ)
//!
//! η_i is in the units of θ_i: the largest step a parameter takes is about η_i whatever the
//! scale of its gradient, which is why the fits choose parameterisations (ln E, ln d, …) where
//! one η per group makes sense. Defaults β₁ = 0.9, β₂ = 0.999, ε = 10⁻³⁰ (gradients here can be
//! tiny in absolute terms; ε only guards 0/0).

/// The optimiser state for a fixed set of parameters.
#[derive(Clone, Debug)]
pub struct Adam {
    pub beta1: f64,
    pub beta2: f64,
    pub epsilon: f64,
    step_sizes: Vec<f64>,
    lower: Vec<f64>,
    upper: Vec<f64>,
    m: Vec<f64>,
    v: Vec<f64>,
    t: i32,
}

impl Adam {
    /// One step size per parameter; no bounds.
    pub fn new(step_sizes: Vec<f64>) -> Adam {
        let n = step_sizes.len();
        Adam {
            beta1: 0.9,
            beta2: 0.999,
            epsilon: 1e-30,
            step_sizes,
            lower: vec![f64::NEG_INFINITY; n],
            upper: vec![f64::INFINITY; n],
            m: vec![0.0; n],
            v: vec![0.0; n],
            t: 0,
        }
    }

    /// Box bounds applied after every step.
    ///
    /// # Panics
    /// If the lengths differ from the number of parameters or some lo > hi.
    pub fn with_bounds(mut self, lower: Vec<f64>, upper: Vec<f64>) -> Adam {
        assert!(
            lower.len() == self.m.len() && upper.len() == self.m.len(),
            "one bound per parameter"
        );
        assert!(
            lower.iter().zip(&upper).all(|(l, u)| l <= u),
            "lower bound above upper bound"
        );
        self.lower = lower;
        self.upper = upper;
        self
    }

    pub fn len(&self) -> usize {
        self.m.len()
    }

    pub fn is_empty(&self) -> bool {
        self.m.is_empty()
    }

    /// Steps taken so far.
    pub fn steps(&self) -> i32 {
        self.t
    }

    /// Scales every step size by `factor` (learning-rate decay).
    pub fn scale_steps(&mut self, factor: f64) {
        self.step_sizes.iter_mut().for_each(|s| *s *= factor);
    }

    /// Replaces the step sizes (e.g. at a change of loss).
    ///
    /// # Panics
    /// If the length differs from the number of parameters.
    pub fn set_step_sizes(&mut self, step_sizes: Vec<f64>) {
        assert_eq!(
            step_sizes.len(),
            self.step_sizes.len(),
            "one step size per parameter"
        );
        self.step_sizes = step_sizes;
    }

    /// Forgets the moment estimates (after a change of loss, whose gradients have another
    /// scale).
    pub fn reset_moments(&mut self) {
        self.m.iter_mut().for_each(|m| *m = 0.0);
        self.v.iter_mut().for_each(|v| *v = 0.0);
        self.t = 0;
    }

    /// One update of `params` in place. Non-finite gradient entries are treated as 0 (the
    /// parameter holds still) rather than poisoning the moments.
    ///
    /// # Panics
    /// If `params` or `grad` have the wrong length.
    pub fn step(&mut self, params: &mut [f64], grad: &[f64]) {
        assert!(
            params.len() == self.m.len() && grad.len() == self.m.len(),
            "one gradient per parameter"
        );
        self.t += 1;
        let c1 = 1.0 - self.beta1.powi(self.t);
        let c2 = 1.0 - self.beta2.powi(self.t);
        for i in 0..params.len() {
            let g = if grad[i].is_finite() { grad[i] } else { 0.0 };
            self.m[i] = self.beta1 * self.m[i] + (1.0 - self.beta1) * g;
            self.v[i] = self.beta2 * self.v[i] + (1.0 - self.beta2) * g * g;
            let step =
                self.step_sizes[i] * (self.m[i] / c1) / ((self.v[i] / c2).sqrt() + self.epsilon);
            params[i] = (params[i] - step).clamp(self.lower[i], self.upper[i]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn minimises_an_ill_scaled_quadratic_within_bounds() {
        // f = (x − 3)² + 1e6 (y + 1)²: Adam's per-coordinate scaling copes with the 10⁶ ratio.
        let mut p = [0.0, 0.0];
        let mut adam = Adam::new(vec![0.05, 0.05]);
        for _ in 0..2000 {
            let g = [2.0 * (p[0] - 3.0), 2e6 * (p[1] + 1.0)];
            adam.step(&mut p, &g);
        }
        assert!(
            (p[0] - 3.0).abs() < 1e-2 && (p[1] + 1.0).abs() < 1e-2,
            "{p:?}"
        );
        let mut q = [0.0];
        let mut bounded = Adam::new(vec![0.1]).with_bounds(vec![-1.0], vec![2.0]);
        for _ in 0..500 {
            let g = [2.0 * (q[0] - 3.0)];
            bounded.step(&mut q, &g);
        }
        assert_eq!(q[0], 2.0, "held at the upper bound");
    }

    #[test]
    fn first_step_moves_each_parameter_by_its_step_size_and_nan_holds_still() {
        let mut p = [1.0, 1.0, 1.0];
        let mut adam = Adam::new(vec![0.5, 0.01, 0.3]);
        adam.step(&mut p, &[1e-12, -1e9, f64::NAN]);
        assert!(
            (p[0] - 0.5).abs() < 1e-9 && (p[1] - 1.01).abs() < 1e-9 && p[2] == 1.0,
            "{p:?}"
        );
    }
}
