use super::*;
use crate::audio::synth::{render_backward, render_samples};

const FS: f64 = 16_000.0;
const N: usize = 4000;

/// `n` values uniform in [−1, 1) from a seeded generator.
fn uniform_noise(seed: u64, n: usize) -> Vec<f64> {
    crate::testing::Rng(seed).uniform_vec(n, -1.0, 1.0)
}

/// L = Σ w[n] s[n] for a fixed random w: linear in the signal, so the test isolates the chain.
fn loss(eig: &[f64], proj: &[f64], damping: &DampingModel, strike: &Strike, w: &[f64]) -> f64 {
    let (bank, _) = ModalChain::new(eig, proj, damping, strike).unwrap();
    render_samples(&bank, FS, N)
        .iter()
        .zip(w)
        .map(|(a, b)| a * b)
        .sum()
}

fn modes() -> (Vec<f64>, Vec<f64>) {
    let freqs = [310.0, 777.0, 1234.5, 2999.0, 5100.0];
    let eig = freqs
        .iter()
        .map(|f: &f64| (2.0 * std::f64::consts::PI * f).powi(2))
        .collect();
    (eig, vec![0.7, -1.2, 0.4, 0.9, -0.3])
}

fn rel_close(fd: f64, exact: f64, scale: f64, tol: f64) -> bool {
    (fd - exact).abs() <= tol * scale.max(exact.abs())
}

#[test]
fn gradients_match_finite_differences_for_every_damping_model_and_strike() {
    let (eig, proj) = modes();
    let w = uniform_noise(5, N);
    let curve = DampingCurve::new(vec![200.0, 1000.0, 4000.0], &[3.0, 8.0, 40.0]).unwrap();
    let dampings = [
        DampingModel::Rayleigh {
            alpha: 6.0,
            beta: 1e-7,
        },
        DampingModel::PerMode {
            decay_rates: vec![2.0, 5.0, 9.0, 20.0, 31.0],
        },
        DampingModel::Curve(curve),
    ];
    let strikes = [
        Strike {
            force: ContactForce::Impulse,
            response: Response::Acceleration,
        },
        Strike {
            force: ContactForce::HalfSine { duration_s: 3e-4 },
            response: Response::Velocity,
        },
        Strike {
            force: ContactForce::HalfSine { duration_s: 1e-3 },
            response: Response::Displacement,
        },
    ];
    for damping in &dampings {
        for strike in &strikes {
            let (bank, chain) = ModalChain::new(&eig, &proj, damping, strike).unwrap();
            let grad = chain.backward(&render_backward(&bank, FS, &w));
            let l = |e: &[f64], p: &[f64], d: &DampingModel| loss(e, p, d, strike, &w);
            let scale_l: f64 = grad
                .eigenvalues
                .iter()
                .zip(&eig)
                .map(|(g, e)| (g * e).abs())
                .fold(0.0, f64::max);
            let scale_c = grad.projections.iter().fold(0.0_f64, |m, g| m.max(g.abs()));
            for k in 0..eig.len() {
                let h = eig[k] * 1e-7;
                let (mut ep, mut em) = (eig.clone(), eig.clone());
                ep[k] += h;
                em[k] -= h;
                let fd = (l(&ep, &proj, damping) - l(&em, &proj, damping)) / (2.0 * h);
                assert!(
                    rel_close(fd * eig[k], grad.eigenvalues[k] * eig[k], scale_l, 1e-5),
                    "{damping:?} {strike:?} dλ_{k}: fd {fd} vs {}",
                    grad.eigenvalues[k]
                );
                let h = 1e-6;
                let (mut pp, mut pm) = (proj.clone(), proj.clone());
                pp[k] += h;
                pm[k] -= h;
                let fd = (l(&eig, &pp, damping) - l(&eig, &pm, damping)) / (2.0 * h);
                assert!(
                    rel_close(fd, grad.projections[k], scale_c, 1e-6),
                    "dc_{k}: fd {fd} vs {}",
                    grad.projections[k]
                );
            }
            // Damping parameters.
            let perturbed: Vec<(f64, DampingModel, DampingModel)> = match (damping, &grad.damping) {
                (
                    DampingModel::Rayleigh { alpha, beta },
                    DampingGradient::Rayleigh {
                        alpha: ga,
                        beta: gb,
                    },
                ) => vec![
                    (
                        *ga * 1e-2,
                        DampingModel::Rayleigh {
                            alpha: alpha + 1e-2,
                            beta: *beta,
                        },
                        DampingModel::Rayleigh {
                            alpha: alpha - 1e-2,
                            beta: *beta,
                        },
                    ),
                    (
                        *gb * 1e-11,
                        DampingModel::Rayleigh {
                            alpha: *alpha,
                            beta: beta + 1e-11,
                        },
                        DampingModel::Rayleigh {
                            alpha: *alpha,
                            beta: beta - 1e-11,
                        },
                    ),
                ],
                (
                    DampingModel::PerMode { decay_rates },
                    DampingGradient::PerMode { decay_rates: g },
                ) => (0..decay_rates.len())
                    .map(|k| {
                        let (mut p, mut m) = (decay_rates.clone(), decay_rates.clone());
                        p[k] += 1e-3;
                        m[k] -= 1e-3;
                        (
                            g[k] * 1e-3,
                            DampingModel::PerMode { decay_rates: p },
                            DampingModel::PerMode { decay_rates: m },
                        )
                    })
                    .collect(),
                (DampingModel::Curve(c), DampingGradient::Curve { log_decay: g }) => {
                    (0..c.log_decay.len())
                        .map(|i| {
                            let (mut p, mut m) = (c.clone(), c.clone());
                            p.log_decay[i] += 1e-4;
                            m.log_decay[i] -= 1e-4;
                            (g[i] * 1e-4, DampingModel::Curve(p), DampingModel::Curve(m))
                        })
                        .collect()
                }
                other => panic!("gradient of the wrong shape: {other:?}"),
            };
            for (i, (expected_change, plus, minus)) in perturbed.into_iter().enumerate() {
                let fd_change = 0.5 * (l(&eig, &proj, &plus) - l(&eig, &proj, &minus));
                assert!((fd_change - expected_change).abs() <= 1e-5 * expected_change.abs().max(1e-9), "{damping:?} {strike:?} damping parameter {i}: fd {fd_change} vs {expected_change}");
            }
        }
    }
}

#[test]
fn overdamped_and_negative_modes_stay_silent_with_zero_gradient() {
    let eig = [-5.0, 100.0, (2.0 * std::f64::consts::PI * 500.0f64).powi(2)];
    let (bank, chain) = ModalChain::new(
        &eig,
        &[1.0, 1.0, 1.0],
        &DampingModel::Rayleigh {
            alpha: 30.0,
            beta: 0.0,
        },
        &Strike::default(),
    )
    .unwrap();
    assert_eq!(bank.amplitudes[0], 0.0);
    assert_eq!(bank.amplitudes[1], 0.0, "ω = 10 < d = 15: overdamped");
    assert!(bank.amplitudes[2] > 0.0);
    let g = chain.backward(&render_backward(&bank, FS, &uniform_noise(1, N)));
    assert_eq!(&g.eigenvalues[..2], &[0.0, 0.0]);
    assert!(g.eigenvalues[2] != 0.0);
}

#[test]
fn damping_curve_interpolates_in_log_log_and_extrapolates_as_a_power_law() {
    let c = DampingCurve::new(vec![100.0, 1000.0], &[2.0, 20.0]).unwrap();
    assert!((c.decay(100.0) - 2.0).abs() < 1e-12);
    assert!((c.decay(316.227_766_016_837_9) - 6.324_555_320_336_759).abs() < 1e-9);
    assert!(
        (c.decay(10_000.0) - 200.0).abs() < 1e-9,
        "slope 1 continues"
    );
    let (_, slope, _) = c.evaluate(500.0);
    let fd = (c.decay(500.0 + 1e-4) - c.decay(500.0 - 1e-4)) / 2e-4;
    assert!((slope - fd).abs() < 1e-7);
    assert!(DampingCurve::new(vec![100.0, 100.0], &[1.0, 1.0]).is_err());
    assert!(DampingCurve::new(vec![100.0], &[-1.0]).is_err());
    assert!(DampingCurve::new(vec![], &[]).is_err());
    let single = DampingCurve::new(vec![300.0], &[4.0]).unwrap();
    assert!((single.decay(5000.0) - 4.0).abs() < 1e-12);
}

#[test]
fn material_gradient_scales_the_projection_with_density() {
    let g = ChainGradient {
        eigenvalues: vec![2.0, 3.0],
        projections: vec![0.5, -1.0],
        damping: DampingGradient::Rayleigh {
            alpha: 0.0,
            beta: 0.0,
        },
    };
    let [de, dn, dr] = material_gradient(
        &g,
        &[1.0, 10.0],
        &[-1.0, 1.0],
        &[0.1, 0.2],
        &[4.0, 2.0],
        2.0,
    );
    assert_eq!(de, 32.0);
    assert_eq!(dn, 1.0);
    assert!((dr - (0.8 - (0.5 * 4.0 - 2.0) / 4.0)).abs() < 1e-15);
}

#[test]
fn bad_inputs_are_errors() {
    let d = DampingModel::Rayleigh {
        alpha: 1.0,
        beta: 0.0,
    };
    assert!(ModalChain::new(&[1.0], &[], &d, &Strike::default()).is_err());
    assert!(ModalChain::new(
        &[1.0],
        &[1.0],
        &DampingModel::Rayleigh {
            alpha: -1.0,
            beta: 0.0
        },
        &Strike::default()
    )
    .is_err());
    assert!(ModalChain::new(
        &[1.0, 2.0],
        &[1.0, 1.0],
        &DampingModel::PerMode {
            decay_rates: vec![1.0]
        },
        &Strike::default()
    )
    .is_err());
    let bad_strike = Strike {
        force: ContactForce::HalfSine { duration_s: -1.0 },
        response: Response::Velocity,
    };
    assert!(ModalChain::new(&[1.0], &[1.0], &d, &bad_strike).is_err());
}
