use super::*;
use nalgebra::Complex;

type C64 = Complex<f64>;

/// Real residuals r(x) with an analytic Jacobian, optionally box-bounded: the held parameters
/// and the projection are the problem's, as in the catalogue.
struct Residuals<F> {
    f: F,
    x: Vec<f64>,
    lower: Vec<f64>,
    upper: Vec<f64>,
    moving: Vec<usize>,
    trial: Vec<f64>,
    trials: usize,
}

impl<F: Fn(&[f64]) -> (Vec<f64>, DMatrix<f64>)> Residuals<F> {
    fn new(f: F, x0: &[f64]) -> Self {
        let n = x0.len();
        Residuals {
            f,
            x: x0.to_vec(),
            lower: vec![f64::NEG_INFINITY; n],
            upper: vec![f64::INFINITY; n],
            moving: vec![],
            trial: vec![],
            trials: 0,
        }
    }

    fn cost_at(&self, x: &[f64]) -> f64 {
        (self.f)(x).0.iter().map(|r| r * r).sum()
    }
}

impl<F: Fn(&[f64]) -> (Vec<f64>, DMatrix<f64>)> Problem for Residuals<F> {
    type Scalar = f64;

    fn normal_equations(&mut self) -> Option<NormalEquations<f64>> {
        let (r, j) = (self.f)(&self.x);
        let h = j.transpose() * &j;
        let g = j.transpose() * DVector::from_vec(r);
        // Hold a parameter on a bound whose descent direction points out of the box.
        self.moving = (0..self.x.len())
            .filter(|&k| {
                let blocked_low = self.x[k] <= self.lower[k] && g[k] > 0.0;
                let blocked_high = self.x[k] >= self.upper[k] && g[k] < 0.0;
                !blocked_low && !blocked_high
            })
            .collect();
        let m = &self.moving;
        (!m.is_empty()).then(|| NormalEquations {
            h: DMatrix::from_fn(m.len(), m.len(), |p, q| h[(m[p], m[q])]),
            g: DVector::from_fn(m.len(), |p, _| g[m[p]]),
        })
    }

    fn trial(&mut self, step: &DVector<f64>) -> Option<f64> {
        self.trials += 1;
        self.trial = self.x.clone();
        for (p, &k) in self.moving.iter().enumerate() {
            self.trial[k] = (self.x[k] + step[p]).clamp(self.lower[k], self.upper[k]);
        }
        Some(self.cost_at(&self.trial))
    }

    fn accept(&mut self) {
        std::mem::swap(&mut self.x, &mut self.trial);
    }
}

fn settings(solve: Solve, stopping: Stopping) -> Settings {
    Settings {
        damping: Damping {
            start: 1e-3,
            min: 1e-12,
            max: 1e12,
            shrink: 10.0,
            grow: 10.0,
        },
        max_iterations: 500,
        accept: Accept::NoIncrease,
        solve,
        stopping,
    }
}

fn rosenbrock(x: &[f64]) -> (Vec<f64>, DMatrix<f64>) {
    let r = vec![10.0 * (x[1] - x[0] * x[0]), 1.0 - x[0]];
    let j = DMatrix::from_row_slice(2, 2, &[-20.0 * x[0], 10.0, -1.0, 0.0]);
    (r, j)
}

#[test]
fn rosenbrock_from_the_classic_start() {
    for solve in [Solve::Direct, Solve::Scaled] {
        let stopping = Stopping {
            relative_decrease: Some((1e-15, CostReference::Before)),
            ..Stopping::default()
        };
        let mut p = Residuals::new(rosenbrock, &[-1.2, 1.0]);
        let c0 = p.cost_at(&p.x);
        let out = minimise(&mut p, c0, &settings(solve, stopping));
        assert!(
            (p.x[0] - 1.0).abs() < 1e-8 && (p.x[1] - 1.0).abs() < 1e-8,
            "{solve:?}: {:?} {out:?}",
            p.x
        );
        assert!(out.cost < 1e-16 && out.cost == p.cost_at(&p.x), "{out:?}");
        // The banana valley takes more than a handful of steps, fewer than a few hundred.
        assert!(out.iterations > 5 && out.iterations < 200, "{out:?}");
    }
}

#[test]
fn exponential_fit_stops_on_the_newton_decrement() {
    let t: Vec<f64> = (0..30).map(|i| 0.1 * i as f64).collect();
    let y: Vec<f64> = t.iter().map(|t| 2.0 * (-0.7 * t).exp()).collect();
    let model = move |x: &[f64]| {
        let r: Vec<f64> = t
            .iter()
            .zip(&y)
            .map(|(t, y)| x[0] * (-x[1] * t).exp() - y)
            .collect();
        let j = DMatrix::from_fn(t.len(), 2, |i, k| {
            let e = (-x[1] * t[i]).exp();
            if k == 0 {
                e
            } else {
                -x[0] * t[i] * e
            }
        });
        (r, j)
    };
    let stopping = Stopping {
        newton_decrement: Some(1e-9),
        ..Stopping::default()
    };
    let mut p = Residuals::new(model, &[1.0, 0.1]);
    let c0 = p.cost_at(&p.x);
    let out = minimise(&mut p, c0, &settings(Solve::Direct, stopping));
    assert_eq!(out.stop, Stop::Converged(Rule::NewtonDecrement), "{out:?}");
    assert!(
        (p.x[0] - 2.0).abs() < 1e-9 && (p.x[1] - 0.7).abs() < 1e-9,
        "{:?}",
        p.x
    );
}

#[test]
fn bounded_optimum_on_a_bound() {
    // C = (x0 − 3)² + (x1 − 2)² + (x0 − x1)² with x0 ≤ 1: at x0 = 1 the rest gives x1 = 1.5, and
    // ∂C/∂x0 = −5 there still pushes against the bound (the unbounded minimum is (8/3, 7/3)).
    let f = |x: &[f64]| {
        let r = vec![x[0] - 3.0, x[1] - 2.0, x[0] - x[1]];
        let j = DMatrix::from_row_slice(3, 2, &[1.0, 0.0, 0.0, 1.0, 1.0, -1.0]);
        (r, j)
    };
    let stopping = Stopping {
        relative_decrease: Some((1e-14, CostReference::After)),
        ..Stopping::default()
    };
    let mut p = Residuals::new(f, &[0.0, 0.0]);
    p.upper[0] = 1.0;
    let c0 = p.cost_at(&p.x);
    let mut s = settings(Solve::Direct, stopping);
    s.accept = Accept::Decrease;
    let out = minimise(&mut p, c0, &s);
    assert_eq!(p.x[0], 1.0, "{out:?}");
    assert!((p.x[1] - 1.5).abs() < 1e-7, "{:?} {out:?}", p.x);
    assert!((out.cost - 4.5).abs() < 1e-12, "{out:?}");
}

#[test]
fn damping_runs_out_after_the_expected_trials() {
    // Every trial is refused: λ = 1, 10, 100, 1000 are tried, then λ > max stops the fit.
    struct Refuses(usize);
    impl Problem for Refuses {
        type Scalar = f64;
        fn normal_equations(&mut self) -> Option<NormalEquations<f64>> {
            Some(NormalEquations {
                h: DMatrix::identity(2, 2),
                g: DVector::from_vec(vec![1.0, -1.0]),
            })
        }
        fn trial(&mut self, _: &DVector<f64>) -> Option<f64> {
            self.0 += 1;
            None
        }
        fn accept(&mut self) {
            unreachable!("nothing is accepted")
        }
    }
    let mut s = settings(Solve::Direct, Stopping::default());
    s.damping = Damping {
        start: 1.0,
        min: 1e-12,
        max: 1e3,
        shrink: 10.0,
        grow: 10.0,
    };
    let mut p = Refuses(0);
    let out = minimise(&mut p, 1.0, &s);
    assert_eq!(
        (out.stop, out.iterations, p.0),
        (Stop::DampingExhausted, 1, 4)
    );
    assert_eq!(out.step_sigma, None);
}

#[test]
fn ties_are_taken_only_when_asked_and_the_cap_holds() {
    // A flat cost: every step ties.
    let flat = |_: &[f64]| (vec![1.0, 0.0], DMatrix::identity(2, 2));
    let mut s = settings(Solve::Direct, Stopping::default());
    s.max_iterations = 3;
    let mut p = Residuals::new(flat, &[0.0, 0.0]);
    let out = minimise(&mut p, 1.0, &s);
    assert_eq!(
        (out.stop, out.iterations, p.trials),
        (Stop::IterationLimit, 3, 3)
    );
    s.accept = Accept::Decrease;
    let mut p = Residuals::new(flat, &[0.0, 0.0]);
    let out = minimise(&mut p, 1.0, &s);
    assert_eq!((out.stop, out.iterations), (Stop::DampingExhausted, 1));
}

#[test]
fn nothing_to_move_when_the_cost_ignores_the_parameters() {
    let constant = |_: &[f64]| (vec![1.0], DMatrix::zeros(1, 2));
    let mut p = Residuals::new(constant, &[0.5, 0.5]);
    let out = minimise(&mut p, 1.0, &settings(Solve::Scaled, Stopping::default()));
    assert_eq!((out.stop, p.trials), (Stop::NothingToMove, 0));
}

/// r_m = e^(m ℓ) − y_m, m = 0 … 24, holomorphic in the complex ℓ (a damped phasor).
struct Phasor {
    y: Vec<C64>,
    l: C64,
    trial: C64,
}

impl Phasor {
    fn cost_at(&self, l: C64) -> f64 {
        self.y
            .iter()
            .enumerate()
            .map(|(m, y)| ((l * m as f64).exp() - y).norm_sqr())
            .sum()
    }
}

impl Problem for Phasor {
    type Scalar = C64;

    fn normal_equations(&mut self) -> Option<NormalEquations<C64>> {
        let (mut h, mut g) = (0.0, C64::new(0.0, 0.0));
        for (m, y) in self.y.iter().enumerate() {
            let e = (self.l * m as f64).exp();
            let j = e * m as f64;
            h += j.norm_sqr();
            g += j.conj() * (e - y);
        }
        Some(NormalEquations {
            h: DMatrix::from_element(1, 1, C64::new(h, 0.0)),
            g: DVector::from_element(1, g),
        })
    }

    fn trial(&mut self, step: &DVector<C64>) -> Option<f64> {
        self.trial = self.l + step[0];
        Some(self.cost_at(self.trial))
    }

    fn accept(&mut self) {
        self.l = self.trial;
    }
}

#[test]
fn complex_parameter_converges_by_its_step_in_standard_deviations() {
    let truth = C64::new(-0.05, 0.3);
    let y: Vec<C64> = (0..25).map(|m| (truth * m as f64).exp()).collect();
    let start = C64::new(-0.08, 0.27);
    let mut p = Phasor {
        y,
        l: start,
        trial: start,
    };
    let stopping = Stopping {
        step_sigma: Some(vec![1e-6]),
        ..Stopping::default()
    };
    let mut s = settings(Solve::Scaled, stopping);
    s.accept = Accept::Decrease;
    let c0 = p.cost_at(start);
    let out = minimise(&mut p, c0, &s);
    assert_eq!(out.stop, Stop::Converged(Rule::StepSigma), "{out:?}");
    assert!((p.l - truth).norm() < 1e-9, "{} {out:?}", p.l);
    assert!(
        out.step_sigma.as_ref().is_some_and(|s| s[0] < 1e-6),
        "{out:?}"
    );
}

#[test]
fn symmetric_inverse_of_a_badly_scaled_matrix() {
    // diag spans 10¹²: the Jacobi scaling keeps the inverse accurate.
    let h = DMatrix::from_row_slice(2, 2, &[1e6, 0.5, 0.5, 1e-6]);
    let inv = symmetric_inverse(&h).expect("positive definite");
    let eye = &h * &inv;
    assert!((eye - DMatrix::identity(2, 2)).abs().max() < 1e-9, "{inv}");
    let singular = DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 1.0, 1.0]);
    assert!(symmetric_inverse(&singular).is_none());
}
