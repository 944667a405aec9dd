//! Experiment: recover E, ν of the bowl from audio rendered at a known material.
use diffsound::assembly;
use diffsound::audio::chain::{DampingModel, ModalChain, Strike};
use diffsound::audio::synth::render_samples;
use diffsound::eigen::reduced::PoissonBasis;
use diffsound::inverse::material::{fit_material, MaterialFitSettings, MaterialProblem};
use diffsound::mesh;
use diffsound::petsc::{Petsc, PetscInt};

fn main() {
    let universe = mpi::initialize().unwrap();
    let petsc = Petsc::initialize(universe, "material_probe", &[]).unwrap();
    let args: Vec<String> = std::env::args().collect();
    let mesh_path = args
        .get(1)
        .cloned()
        .unwrap_or("examples/bowl/bowl.msh".into());
    let (e_true, nu_true): (f64, f64) = (
        args.get(2).map_or(5e10, |s| s.parse().unwrap()),
        args.get(3).map_or(0.3, |s| s.parse().unwrap()),
    );
    let (e0, nu0): (f64, f64) = (
        args.get(4).map_or(e_true / 3.0, |s| s.parse().unwrap()),
        args.get(5).map_or(0.1, |s| s.parse().unwrap()),
    );
    let read = mesh::read_mesh(std::path::Path::new(&mesh_path), &Default::default()).unwrap();
    let m = mesh::lift_to_quadratic(&read.mesh);
    let t0 = std::time::Instant::now();
    let asm = assembly::assemble(&petsc, &m).unwrap();
    let (lo, hi) = m.bounding_box();
    let size = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
    let point = m.default_strike_point().unwrap();
    let vertex = m.tet(point.tet)[point.barycentric.iter().position(|&b| b == 1.0).unwrap()];
    let probe: Vec<PetscInt> = (0..3)
        .map(|c| asm.layout.global_dof(vertex, c) as PetscInt)
        .collect();
    let rho = 2700.0;
    let n_modes = 16;
    // Target from a full solve.
    let (theta, vecs) = PoissonBasis::full_theta(&petsc, &asm, size, nu_true, n_modes).unwrap();
    let eig: Vec<f64> = theta.iter().map(|t| e_true / rho * t).collect();
    let proj: Vec<f64> = vecs
        .iter()
        .map(|v| {
            let p = v.gather_indices(&probe).unwrap();
            let a: f64 = (0..3).map(|c| p[c] * point.normal[c]).sum();
            a * a / rho
        })
        .collect();
    let damping = DampingModel::Rayleigh {
        alpha: 6.0,
        beta: 1e-7,
    };
    let strike = Strike::default();
    let (bank, _) = ModalChain::new(&eig, &proj, &damping, &strike).unwrap();
    let fs = 48000.0;
    let target = render_samples(&bank, fs, 24000);
    let peak = target.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    let target: Vec<f64> = target.iter().map(|v| v / peak * 0.5).collect();
    println!(
        "freqs {:?}",
        bank.frequencies_hz
            .iter()
            .map(|f| f.round())
            .collect::<Vec<_>>()
    );
    let t1 = std::time::Instant::now();
    let mut basis = PoissonBasis::build(
        &petsc,
        &asm,
        size,
        n_modes,
        8,
        &[0.05, 0.2, 0.35, 0.45],
        probe.clone(),
    )
    .unwrap();
    println!(
        "assembly+target {:.1} s, basis {:.1} s dims {:?}",
        (t1 - t0).as_secs_f64(),
        t1.elapsed().as_secs_f64(),
        basis.dimensions()
    );
    let rm = basis.solve(nu_true);
    let rel: f64 = rm
        .theta
        .iter()
        .zip(&theta)
        .map(|(a, b)| (a - b).abs() / b)
        .fold(0.0, f64::max);
    println!("reduced vs full at true nu: max rel {rel:e}");
    let estimate = diffsound::analysis::estimate::estimate_modes(
        std::slice::from_ref(&target),
        fs,
        &Default::default(),
    )
    .unwrap();
    let target_modes_hz: Vec<f64> = estimate.modes.iter().map(|m| m.frequency_hz).collect();
    println!("estimated {} target modes", target_modes_hz.len());
    let targets = vec![target];
    let problem = MaterialProblem {
        targets: &targets,
        sample_rate: fs,
        density: rho,
        damping,
        strike,
        direction_weights: point.normal.to_vec(),
        max_frequency_hz: None,
        target_modes_hz,
    };
    if std::env::var("SCAN").is_ok() {
        use diffsound::audio::loss::MultiScaleSpectralLoss;
        let loss = MultiScaleSpectralLoss::new(&targets[0], Default::default()).unwrap();
        let raw = diffsound::inverse::material::render_channels(
            &basis,
            &problem,
            e_true,
            nu_true,
            &[0.0],
            None,
        )
        .unwrap();
        let rms = |x: &[f64]| (x.iter().map(|v| v * v).sum::<f64>()).sqrt();
        let g = (rms(&targets[0]) / rms(&raw[0])).ln();
        for k in -10..=10 {
            let e = e_true * (1.0 + 0.002 * k as f64);
            let r = diffsound::inverse::material::render_channels(
                &basis,
                &problem,
                e,
                nu_true,
                &[g],
                None,
            )
            .unwrap();
            let r2 = diffsound::inverse::material::render_channels(
                &basis,
                &problem,
                e,
                nu_true,
                &[g + 0.5],
                None,
            )
            .unwrap();
            println!(
                "E x {:.3}: loss {:.4e}  (gain +0.5: {:.4e})",
                e / e_true,
                loss.value(&r[0]).unwrap(),
                loss.value(&r2[0]).unwrap()
            );
        }
        return;
    }
    let settings = MaterialFitSettings {
        max_steps: 300,
        ..Default::default()
    };
    let t2 = std::time::Instant::now();
    let fit = fit_material(
        &mut basis,
        &problem,
        (e0, nu0),
        &settings,
        |b, nu| {
            let modes = b.solve(nu);
            let r = b.residuals(&asm, &modes)?;
            let worst = r.iter().fold(0.0_f64, |m, v| m.max(*v));
            if worst > settings.residual_tolerance {
                b.add_sample(&petsc, &asm, nu)?;
            }
            Ok(worst)
        },
        |s| {
            if s.step % 20 == 0 {
                println!(
                    "step {} {:?} loss {:.4e} E {:.5e} nu {:.5}",
                    s.step, s.phase, s.loss, s.youngs, s.poisson
                )
            }
        },
    )
    .unwrap();
    println!("line start {:?}", fit.line_start);
    println!("fit {:.1} s: E {:.6e} ({:.2e} rel) nu {:.5} ({:.2e} rel), steps {}, switched {:?}, samples {:?}, max residual {:.2e}", t2.elapsed().as_secs_f64(), fit.youngs, (fit.youngs - e_true).abs() / e_true, fit.poisson, (fit.poisson - nu_true).abs() / nu_true, fit.steps, fit.switched_at, fit.basis_samples, fit.max_residual);
}
