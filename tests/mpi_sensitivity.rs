//! Eigenvalue sensitivities against central finite differences, under MPI on 1 and 2 ranks.
//!
//! Run by `cargo test`: the launcher (no MPI environment) starts this same binary with
//! `mpirun -np 1` and `-np 2`; the children solve, differentiate and check, and rank 0 prints one
//! `check … ok|FAILED` line per check. The launcher ends with `N passed, N failed`.
//!
//! Step rule for the finite differences: a relative step h = 1e-4 for E and ρ, an absolute 1e-5
//! for ν, and for node positions a displacement field scaled so its largest node displacement is
//! 3e-6 × the bounding-box diagonal L. Central differences carry a truncation error of order h²;
//! the other error is the eigenvalues' rounding noise (~1e-13 relative, from re-assembling the
//! perturbed mesh) divided by the step, which is why the node step is not smaller. Node-position
//! errors are measured relative to max(|g·v|, λ·|v|∞/L): the directional derivative of a mode
//! can nearly cancel, and the second term is the size a uniform deformation of the same amplitude
//! would give.
//!
//! Audio loss, end to end (`check brick audio-loss …`): 12 modes of the brick (ceramic, Rayleigh
//! α = 20 1/s, β = 2e-9 s) → `ModalChain` (default strike) → `synth::render_samples` at
//! f_s = 4 × the highest frequency (rounded up to 1 kHz; 139 kHz), 0.1 s → loss against a target
//! rendered from E·1.03, ν + 0.02, α·1.3, β·0.8. Both the multi-scale spectral loss (default FFT
//! sizes, ε = 1e-2) and the transport loss (defaults). The exact gradient runs
//! `value_and_gradient` → `render_backward` → `ModalChain::backward` → `material_gradient` with
//! the per-mode dλ/dp (the brick's clusters are accidental near-coincidences of distinct modes,
//! and the loss is not symmetric in them, so cluster means would be wrong here). The projections
//! c_k are fixed numbers (alternating signs, |z_k| ≈ 1/(1+k)), held fixed in the differences for
//! E, ν, α, β and scaled as c_k·√(ρ0/ρ) for ρ, matching `material_gradient`'s shape term. The
//! differences re-solve the eigenproblem for E, ν, ρ; α and β only re-render. Only the spectral
//! check sees the shape term: the transport loss normalises each frame, so a common scale of
//! all c_k leaves it unchanged.
//!
//! Steps for the audio loss: relative 1e-6 for E, ρ, α, β and absolute 1e-6 for ν, not the
//! eigenvalue rule above. A loss of a decaying partial is curved in its frequency on the scale
//! δf ~ 1/(2πτ), τ the time it is heard (here its decay time 1/d ≈ 20–60 ms, whatever the clip
//! length): with the 1e-4 rule the top partial (35 kHz) moves by 1.7 Hz, and central
//! differences of the transport loss are off by 3.5 %, converging as h² (6e-4 at 1e-5, ~1e-6 at
//! 1e-6). At 1e-6 the eigenvalue noise divided by the step is still ≤ 1e-5 per mode. α and β
//! get the same relative step: d moves by ≤ 5e-5 1/s, far inside the linear range, and
//! re-rendering adds no solver noise. Error measure: |FD − exact| / max(|exact|,
//! Σ_k |∂L/∂λ_k ∂λ_k/∂p| (+ the |shape terms| for ρ)), i.e. relative to the terms summed before
//! they can cancel (only |exact| for α, β). Bar: 1e-3. The transport loss lands at ~1e-6. The
//! spectral loss is a sum of |·| over ~2·10⁵ (frame, bin) terms, each with a kink where S_x = S_y; a central difference that
//! straddles a kink errs by up to half its slope jump, independently of h once h exceeds the
//! kink's distance, so its error stays at ~5e-5…4e-4 for steps 1e-7…1e-6 instead of vanishing.
//! ε = 1e-2 (~65–95 dB below the spectral peaks, S being unnormalised) rather than the default
//! 1e-7: with 1e-7 the log term's slope 1/(S + ε) is dominated by bins near the nulls of the
//! window's side lobes, the loss is rough on the 1e-7 scale, and differences scatter by ~5 %
//! (they only converge below steps of 1e-8, where the solver noise takes over). A last check
//! demands that every rank computed bit for bit the same values, gradients and differences.
//!
//! Ranks: the brick's checks, the hollow ellipsoid's shape chain on its plain grid, the morph
//! chain and the loaded Ritz model run on 1 and on 2 ranks. The bowl's checks, the ellipsoid's
//! refined grid and the neural-field chains run on 2 ranks only: they take nine tenths of the
//! 1-rank run's time (157 s of it measured), and the distributed run is the one that can fail
//! where the serial one passes (the 1-rank path is the 2-rank one without the ghost exchange).

use diffsound::assembly;
use diffsound::audio::chain::{self, DampingGradient, DampingModel, ModalChain, Strike};
use diffsound::audio::loss::{
    MultiScaleSpectralLoss, SpectralLossConfig, TransportLoss, TransportLossConfig,
};
use diffsound::audio::synth;
use diffsound::eigen::reduced::{lame_unit, AttachmentPlacement, PoissonBasis};
use diffsound::eigen::sensitivity::{self, ClusterTreatment};
use diffsound::eigen::{self, EigenConfig, ModeRequest};
use diffsound::fem::Material;
use diffsound::inverse::loaded_match::{
    loaded_modes, loaded_modes_enriched, Enrichment, ModesAtPoisson,
};
use diffsound::mesh::{self, TetMesh};
use diffsound::petsc::Petsc;
use diffsound::shape;
use mpi::collective::{CommunicatorCollectives, SystemOperation};
use std::path::PathBuf;
use std::process::Command;

/// Audio-loss checks (module docs): relative step for E, ρ, α, β; absolute step for ν; the
/// spectral loss's ε; the clip length [s]; the bar on the relative error.
const AUDIO_H_REL: f64 = 1e-6;
const AUDIO_H_NU: f64 = 1e-6;
const AUDIO_LOG_EPSILON: f64 = 1e-2;
const AUDIO_SECONDS: f64 = 0.1;
const AUDIO_TOL: f64 = 1e-3;
/// Bar on the enriched loaded Ritz model's frequency error against the full solve
/// (`check_loaded_ritz`): measured 1.39 % on 1 and on 2 ranks (the modes alone: 35.5 %), so the
/// bar is about twice that; the comparison with the modes alone is the sharper half of the check.
const LOADED_RITZ_TOL: f64 = 3e-2;

/// An audio loss: its value and its gradient with respect to the samples.
type LossFn<'a> = dyn Fn(&[f64]) -> (f64, Vec<f64>) + 'a;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn main() {
    if std::env::var_os("DIFFSOUND_MPI_CHILD").is_some() {
        child();
        return;
    }
    let (mut passed, mut failed) = (0usize, 0usize);
    for np in [1, 2] {
        // A hung job (a rank waiting in a collective another rank left) fails here after 20
        // minutes instead of stalling the suite; the full run takes about five.
        let out = Command::new("timeout")
            .args(["--kill-after=10", "1200", "mpirun", "-np", &np.to_string()])
            .arg(std::env::current_exe().expect("test binary path"))
            .env("DIFFSOUND_MPI_CHILD", "1")
            .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
            .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
            .env("OPENBLAS_NUM_THREADS", "1")
            .env("OMPI_MCA_btl", "self,vader")
            .output()
            .expect("run mpirun (scripts/install-deps.sh installs it)");
        let stdout = String::from_utf8_lossy(&out.stdout);
        for line in stdout.lines() {
            println!("[np={np}] {line}");
            if line.starts_with("check ") {
                if line.ends_with(" ok") {
                    passed += 1;
                } else {
                    failed += 1;
                }
            }
        }
        if !out.status.success() {
            failed += 1;
            println!(
                "[np={np}] the MPI job failed: {}\n{}",
                out.status,
                String::from_utf8_lossy(&out.stderr)
            );
        }
    }
    println!("{passed} passed, {failed} failed");
    if failed > 0 || passed == 0 {
        std::process::exit(1);
    }
}

struct Checker {
    rank: usize,
    failures: usize,
}

impl Checker {
    fn check(&mut self, name: &str, ok: bool, detail: String) {
        if self.rank == 0 {
            if ok {
                println!("check {name}: {detail} ... ok");
            } else {
                println!("check {name}: {detail} ... FAILED");
            }
        }
        if !ok {
            self.failures += 1;
        }
    }
}

fn load(name: &str) -> TetMesh {
    let m = mesh::read_mesh(&repo().join(name), &Default::default())
        .expect("test mesh")
        .mesh;
    mesh::lift_to_quadratic(&m)
}

fn diagonal(m: &TetMesh) -> f64 {
    let (lo, hi) = m.bounding_box();
    (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt()
}

fn config(m: &TetMesh, mat: &Material, n: usize) -> EigenConfig {
    let mut cfg = EigenConfig::new(
        ModeRequest::FirstN(n),
        eigen::spectrum_scale(mat.lame_mu(), mat.density, diagonal(m)),
    );
    cfg.tolerance = 1e-12;
    cfg.verify_count = false;
    cfg
}

/// Eigenvalues (ascending, first n) of `m` with `mat`.
fn eigenvalues(petsc: &Petsc, m: &TetMesh, mat: &Material, n: usize) -> Vec<f64> {
    let a = assembly::assemble(petsc, m).expect("assembly");
    let (k, mm) = a.operators(mat).expect("operators");
    let modes = eigen::solve_modes(petsc, &k, &mm, &config(m, mat, n)).expect("solve");
    modes.eigenvalues[..n].to_vec()
}

fn displaced(m: &TetMesh, v: &[[f64; 3]], t: f64) -> TetMesh {
    let mut out = m.clone();
    for (x, d) in out.nodes.iter_mut().zip(v) {
        for c in 0..3 {
            x[c] += t * d[c];
        }
    }
    out
}

fn rel(a: f64, b: f64, scale: f64) -> f64 {
    (a - b).abs() / scale.abs().max(1e-300)
}

fn check_mesh(petsc: &Petsc, c: &mut Checker, label: &str, m: &TetMesh, n: usize) {
    let mat = Material::preset("ceramic").unwrap();
    let assembled = assembly::assemble(petsc, m).expect("assembly");
    let (k, mm) = assembled.operators(&mat).expect("operators");
    let modes = eigen::solve_modes(petsc, &k, &mm, &config(m, &mat, n)).expect("solve");
    let n = n.min(modes.eigenvalues.len());
    let sens = sensitivity::material_sensitivities(
        &assembled.k_lambda,
        &assembled.k_mu,
        &assembled.mass_unit,
        &modes,
        &mat,
    )
    .expect("material sensitivities");
    let grads = sensitivity::node_gradients(
        petsc,
        m,
        &assembled.layout,
        &modes,
        &mat,
        ClusterTreatment::Mean,
    )
    .expect("node gradients");
    let per_mode = sensitivity::node_gradients(
        petsc,
        m,
        &assembled.layout,
        &modes,
        &mat,
        ClusterTreatment::PerMode,
    )
    .expect("node gradients");
    let separated: Vec<usize> = (0..n)
        .filter(|&i| !modes.clusters.iter().any(|r| r.contains(&i)))
        .collect();
    let lam = &modes.eigenvalues;

    // dλ/dE = λ/E exactly (λ_L, μ ∝ E) and dλ/dρ = −λ/ρ exactly.
    let worst_e = (0..n)
        .map(|i| {
            rel(
                sens.per_mode_youngs[i],
                lam[i] / mat.youngs_modulus,
                lam[i] / mat.youngs_modulus,
            )
        })
        .fold(0.0, f64::max);
    c.check(
        &format!("{label} dλ/dE = λ/E"),
        worst_e < 1e-8,
        format!("worst relative error {worst_e:.2e}"),
    );

    // Material finite differences.
    let fd = |f: &dyn Fn(&mut Material, f64), h: f64| -> Vec<f64> {
        let (mut plus, mut minus) = (mat, mat);
        f(&mut plus, h);
        f(&mut minus, -h);
        let (kp, mp) = assembled.operators(&plus).unwrap();
        let (km, mm2) = assembled.operators(&minus).unwrap();
        let lp = eigen::solve_modes(petsc, &kp, &mp, &config(m, &plus, n))
            .unwrap()
            .eigenvalues;
        let lm = eigen::solve_modes(petsc, &km, &mm2, &config(m, &minus, n))
            .unwrap()
            .eigenvalues;
        (0..n).map(|i| (lp[i] - lm[i]) / (2.0 * h)).collect()
    };
    // The bar per parameter. ν's step is 1e-5 absolute, 10⁻⁵/0.3 relative against 10⁻⁴ for E
    // and ρ, and ν moves a brick's λ by only (dλ/dν)/λ ~ 0.1–1: the eigen-solve's run-to-run
    // scatter on two ranks (MUMPS's parallel pivoting, ~10⁻¹² relative in λ) divided by 2h
    // is then up to ~10⁻⁶ of dλ/dν by itself. On two ranks the brick's worst separated mode
    // gave 4.05–4.06e-7 in 16 of 18 suite runs kept from the last stops, 2.78e-7 once and 1.10e-6
    // once (a failure of the suite at the former bar of 1e-6 with no change to this path); a
    // wrong term is off by 10⁻³ or more.
    for (name, fdv, exact, step, bar) in [
        (
            "E",
            fd(&|m, h| m.youngs_modulus += h, 1e-4 * mat.youngs_modulus),
            &sens.per_mode_youngs,
            "1e-4·E",
            1e-6,
        ),
        (
            "ν",
            fd(&|m, h| m.poisson_ratio += h, 1e-5),
            &sens.per_mode_poisson,
            "1e-5",
            5e-6,
        ),
        (
            "ρ",
            fd(&|m, h| m.density += h, 1e-4 * mat.density),
            &sens.per_mode_density,
            "1e-4·ρ",
            1e-6,
        ),
    ] {
        let worst = separated
            .iter()
            .map(|&i| rel(fdv[i], exact[i], exact[i]))
            .fold(0.0, f64::max);
        c.check(
            &format!(
                "{label} dλ/d{name} vs FD (step {step}, {} separated modes)",
                separated.len()
            ),
            worst < bar,
            format!("worst relative error {worst:.2e} (bar {bar:.0e})"),
        );
        // Cluster means are differentiable too: compare the mean of the FD derivatives.
        for r in &modes.clusters {
            if r.end > n {
                continue;
            }
            let mean_fd = fdv[r.clone()].iter().sum::<f64>() / r.len() as f64;
            let mean_exact = match name {
                "E" => sens.d_youngs[r.start],
                "ν" => sens.d_poisson[r.start],
                _ => sens.d_density[r.start],
            };
            let e = rel(mean_fd, mean_exact, mean_exact);
            c.check(
                &format!(
                    "{label} cluster {}-{} mean dλ/d{name} vs FD",
                    r.start,
                    r.end - 1
                ),
                e < 1e-6,
                format!("relative error {e:.2e}"),
            );
        }
    }

    // Node positions: only rank 0 holds the gradients; every rank joins the solves.
    let l = diagonal(m);
    let (lo, _) = m.bounding_box();
    let field: Vec<[f64; 3]> = m
        .nodes
        .iter()
        .map(|x| {
            let s = [(x[0] - lo[0]) / l, (x[1] - lo[1]) / l, (x[2] - lo[2]) / l];
            [
                (3.0 * s[1]).sin() + s[2],
                (2.0 * s[2]).cos() * s[0],
                (5.0 * s[0]).sin() * s[1] + 0.3,
            ]
        })
        .collect();
    let vmax = field
        .iter()
        .map(|v| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt())
        .fold(0.0, f64::max);
    let t = 3e-6 * l / vmax;
    let natural = |i: usize, exact: f64| exact.abs().max(lam[i] * vmax / l);
    let lp = eigenvalues(petsc, &displaced(m, &field, t), &mat, n);
    let lm = eigenvalues(petsc, &displaced(m, &field, -t), &mat, n);
    // A degenerate pair under a perturbation that splits it: the cluster-mean gradient must not
    // jump (individual modes inside the pair may swap or rotate freely). Collective: all ranks.
    // Only for a symmetric object (the bowl): an accidental near-coincidence of two unrelated
    // modes (the brick's) is no degenerate pair.
    let stability = modes
        .clusters
        .first()
        .filter(|r| r.end <= n && label == "bowl")
        .cloned()
        .map(|r| {
            let split = displaced(m, &field, 1e-4 * l / vmax);
            let a2 = assembly::assemble(petsc, &split).unwrap();
            let (k2, m2) = a2.operators(&mat).unwrap();
            let modes2 = eigen::solve_modes(petsc, &k2, &m2, &config(&split, &mat, n)).unwrap();
            (
                r,
                sensitivity::node_gradients(
                    petsc,
                    &split,
                    &a2.layout,
                    &modes2,
                    &mat,
                    ClusterTreatment::PerMode,
                )
                .unwrap(),
            )
        });
    let dot = |g: &[f64], v: &[[f64; 3]]| {
        g.chunks_exact(3)
            .zip(v)
            .map(|(a, b)| a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
            .sum::<f64>()
    };
    let ok_rank0 = |ok: bool| ok || petsc.rank() != 0;
    if let Some(g) = &grads {
        let worst = separated
            .iter()
            .map(|&i| {
                rel(
                    (lp[i] - lm[i]) / (2.0 * t),
                    dot(&g[i], &field),
                    natural(i, dot(&g[i], &field)),
                )
            })
            .fold(0.0, f64::max);
        c.check(
            &format!(
                "{label} dλ/dx·v vs FD (max node step 3e-6·L, {} separated modes)",
                separated.len()
            ),
            ok_rank0(worst < 1e-6),
            format!("worst relative error {worst:.2e}"),
        );
        for r in &modes.clusters {
            if r.end > n {
                continue;
            }
            let mean_fd = (r.clone())
                .map(|i| (lp[i] - lm[i]) / (2.0 * t))
                .sum::<f64>()
                / r.len() as f64;
            // The cluster mean is smooth, so the same bar applies as for separated modes.
            let e = rel(mean_fd, dot(&g[r.start], &field), natural(r.start, mean_fd));
            c.check(
                &format!(
                    "{label} cluster {}-{} mean dλ/dx·v vs FD",
                    r.start,
                    r.end - 1
                ),
                e < 1e-6,
                format!("relative error {e:.2e}"),
            );
        }
        if let (Some((r, Some(g2))), Some(g1)) = (&stability, &per_mode) {
            // Mean over the same mode positions of per-mode gradients, before and after.
            let mean = |gs: &Vec<Vec<f64>>| {
                r.clone().map(|i| dot(&gs[i], &field)).sum::<f64>() / r.len() as f64
            };
            let (before, after) = (mean(g1), mean(g2));
            let e = rel(after, before, natural(r.start, before));
            let swing = r
                .clone()
                .map(|i| rel(dot(&g2[i], &field), dot(&g1[i], &field), natural(i, before)))
                .fold(0.0, f64::max);
            c.check(
                &format!(
                    "{label} cluster {}-{} mean gradient stable under a 1e-4·L perturbation",
                    r.start,
                    r.end - 1
                ),
                e < 1e-3,
                format!("relative change {e:.2e} (individual modes change by up to {swing:.2e})"),
            );
        }
        // Uniform scaling x → (1+s)x gives λ ∝ 1/L²: Σ x·g = −2λ (−2λ̄ for a cluster mean).
        let xs: Vec<[f64; 3]> = m.nodes.clone();
        let target = |i: usize| match modes.clusters.iter().find(|r| r.contains(&i)) {
            Some(r) => lam[r.clone()].iter().sum::<f64>() / r.len() as f64,
            None => lam[i],
        };
        let worst = (0..n)
            .map(|i| rel(dot(&g[i], &xs), -2.0 * target(i), lam[i]))
            .fold(0.0, f64::max);
        c.check(
            &format!("{label} scaling Σx·dλ/dx = −2λ"),
            worst < 1e-8,
            format!("worst relative error {worst:.2e}"),
        );
        // Rigid motions leave λ unchanged.
        let gnorm = |gi: &[f64]| gi.iter().map(|x| x * x).sum::<f64>().sqrt();
        let mut worst = 0.0f64;
        for d in 0..3 {
            let mut tr = vec![[0.0; 3]; m.n_nodes()];
            tr.iter_mut().for_each(|v| v[d] = 1.0);
            let mut rot = vec![[0.0; 3]; m.n_nodes()];
            for (v, x) in rot.iter_mut().zip(&m.nodes) {
                let (a, b) = ((d + 1) % 3, (d + 2) % 3);
                v[a] = -(x[b] - lo[b]);
                v[b] = x[a] - lo[a];
            }
            for gi in &g[..n] {
                let scale = gnorm(gi) * (m.n_nodes() as f64).sqrt() * l;
                worst = worst
                    .max(dot(gi, &tr).abs() * l / scale)
                    .max(dot(gi, &rot).abs() / scale);
            }
        }
        c.check(
            &format!("{label} rigid translations and rotations leave λ unchanged"),
            worst < 1e-8,
            format!("worst |g·v|/(|g||v|) {worst:.2e}"),
        );
    }
}

/// The audio-loss gradient with respect to E, ν, ρ, α, β through the whole chain, against
/// central finite differences of the loss (see the module docs for the set-up, the steps and
/// the error bar). Collective: every rank solves and evaluates the same losses; rank 0 prints.
fn check_audio_loss(petsc: &Petsc, c: &mut Checker, label: &str, m: &TetMesh, n: usize) {
    // Ceramic, with Rayleigh damping under which every mode rings through the clip and both α
    // and β matter: d = (α + βλ)/2 runs from 17 1/s (lowest mode) to 57 1/s (highest).
    let mat = Material {
        rayleigh_alpha: 20.0,
        rayleigh_beta: 2e-9,
        ..Material::preset("ceramic").unwrap()
    };
    let assembled = assembly::assemble(petsc, m).expect("assembly");
    let solve = |mat: &Material| -> Vec<f64> {
        let (k, mm) = assembled.operators(mat).expect("operators");
        let lam = eigen::solve_modes(petsc, &k, &mm, &config(m, mat, n))
            .expect("solve")
            .eigenvalues;
        assert!(lam.len() >= n, "only {} modes", lam.len());
        lam[..n].to_vec()
    };
    let (k, mm) = assembled.operators(&mat).expect("operators");
    let modes = eigen::solve_modes(petsc, &k, &mm, &config(m, &mat, n)).expect("solve");
    let sens = sensitivity::material_sensitivities(
        &assembled.k_lambda,
        &assembled.k_mu,
        &assembled.mass_unit,
        &modes,
        &mat,
    )
    .expect("material sensitivities");
    let lam0 = modes.eigenvalues[..n].to_vec();

    // Sample rate: 4× the highest frequency, rounded up to 1 kHz; AUDIO_SECONDS of audio.
    let f_max = lam0[n - 1].sqrt() / (2.0 * std::f64::consts::PI);
    let fs = (4.0 * f_max / 1000.0).ceil() * 1000.0;
    let len = (AUDIO_SECONDS * fs).round() as usize;
    // Fixed projections, alternating in sign, with |z_k| = |c_k|·|s_k|²/ω_d ≈ 1/(1+k) under
    // the default strike (impulse, acceleration). For ρ they scale as √(ρ0/ρ) (module docs).
    let proj0: Vec<f64> = (0..n)
        .map(|k| if k % 2 == 0 { 1.0 } else { -1.0 } / ((1 + k) as f64 * lam0[k].sqrt()))
        .collect();
    let scaled = |density: f64| -> Vec<f64> {
        proj0
            .iter()
            .map(|p| p * (mat.density / density).sqrt())
            .collect()
    };
    let strike = Strike::default();
    let bank = |lam: &[f64], proj: &[f64], alpha: f64, beta: f64| {
        ModalChain::new(lam, proj, &DampingModel::Rayleigh { alpha, beta }, &strike).expect("chain")
    };
    let signal = |lam: &[f64], proj: &[f64], alpha: f64, beta: f64| {
        synth::render_samples(&bank(lam, proj, alpha, beta).0, fs, len)
    };

    // Target: another material (E·1.03, ν + 0.02, α·1.3, β·0.8), same projections.
    let target_mat = Material {
        youngs_modulus: 1.03 * mat.youngs_modulus,
        poisson_ratio: mat.poisson_ratio + 0.02,
        rayleigh_alpha: 1.3 * mat.rayleigh_alpha,
        rayleigh_beta: 0.8 * mat.rayleigh_beta,
        ..mat
    };
    let target = signal(
        &solve(&target_mat),
        &proj0,
        target_mat.rayleigh_alpha,
        target_mat.rayleigh_beta,
    );
    let spectral_config = SpectralLossConfig {
        log_epsilon: AUDIO_LOG_EPSILON,
        log_epsilon_relative: 0.0,
        ..SpectralLossConfig::default()
    };
    let spectral = MultiScaleSpectralLoss::new(&target, spectral_config).expect("spectral loss");
    let transport =
        TransportLoss::new(&target, fs, TransportLossConfig::default()).expect("transport loss");
    let losses: [(&str, &LossFn); 2] = [
        ("spectral", &|x| {
            spectral.value_and_gradient(x).expect("spectral loss")
        }),
        ("transport", &|x| {
            transport.value_and_gradient(x).expect("transport loss")
        }),
    ];

    // The perturbed signals, ± one step (E, ν, ρ need a solve each; α, β none).
    let (a0, b0) = (mat.rayleigh_alpha, mat.rayleigh_beta);
    let perturbed = |name: &str, s: f64| -> Vec<f64> {
        match name {
            "E" => signal(
                &solve(&Material {
                    youngs_modulus: mat.youngs_modulus * (1.0 + s * AUDIO_H_REL),
                    ..mat
                }),
                &proj0,
                a0,
                b0,
            ),
            "ν" => signal(
                &solve(&Material {
                    poisson_ratio: mat.poisson_ratio + s * AUDIO_H_NU,
                    ..mat
                }),
                &proj0,
                a0,
                b0,
            ),
            "ρ" => {
                let rho = mat.density * (1.0 + s * AUDIO_H_REL);
                signal(
                    &solve(&Material {
                        density: rho,
                        ..mat
                    }),
                    &scaled(rho),
                    a0,
                    b0,
                )
            }
            "α" => signal(&lam0, &proj0, a0 * (1.0 + s * AUDIO_H_REL), b0),
            _ => signal(&lam0, &proj0, a0, b0 * (1.0 + s * AUDIO_H_REL)),
        }
    };
    let names = ["E", "ν", "ρ", "α", "β"];
    let steps = [
        AUDIO_H_REL * mat.youngs_modulus,
        AUDIO_H_NU,
        AUDIO_H_REL * mat.density,
        AUDIO_H_REL * a0,
        AUDIO_H_REL * b0,
    ];
    let signals: Vec<(Vec<f64>, Vec<f64>)> = names
        .iter()
        .map(|p| (perturbed(p, 1.0), perturbed(p, -1.0)))
        .collect();

    let (bank0, chain0) = bank(&lam0, &proj0, a0, b0);
    let x0 = synth::render_samples(&bank0, fs, len);
    let mut all_ranks = Vec::new(); // every number each rank computed, to compare across ranks
    for (loss_name, loss) in losses {
        let (value, g) = loss(&x0);
        let cg = chain0.backward(&synth::render_backward(&bank0, fs, &g));
        // Per-mode dλ/dp: the brick's clusters are accidental near-coincidences of distinct
        // modes, each differentiable on its own, and the loss is not symmetric in them.
        let per_mode = [
            &sens.per_mode_youngs[..n],
            &sens.per_mode_poisson[..n],
            &sens.per_mode_density[..n],
        ];
        let [de, dnu, drho] = chain::material_gradient(
            &cg,
            per_mode[0],
            per_mode[1],
            per_mode[2],
            &proj0,
            mat.density,
        );
        let DampingGradient::Rayleigh {
            alpha: da,
            beta: db,
        } = cg.damping
        else {
            panic!("a Rayleigh damping gradient")
        };
        // The size of the terms summed into dL/dp, which may cancel (module docs).
        let terms = |p: usize| -> f64 {
            let through_lambda: f64 = cg
                .eigenvalues
                .iter()
                .zip(per_mode[p])
                .map(|(g, d)| (g * d).abs())
                .sum();
            let shape: f64 = if p == 2 {
                cg.projections
                    .iter()
                    .zip(&proj0)
                    .map(|(g, c)| (g * c / (2.0 * mat.density)).abs())
                    .sum()
            } else {
                0.0
            };
            through_lambda + shape
        };
        all_ranks.push(value);
        for (p, (exact, (plus, minus))) in [de, dnu, drho, da, db]
            .into_iter()
            .zip(&signals)
            .enumerate()
        {
            let fd = (loss(plus).0 - loss(minus).0) / (2.0 * steps[p]);
            let scale = if p < 3 {
                exact.abs().max(terms(p))
            } else {
                exact.abs()
            };
            let e = rel(fd, exact, scale);
            all_ranks.extend([exact, fd]);
            let step = if p == 1 {
                format!("{AUDIO_H_NU:e}")
            } else {
                format!("{AUDIO_H_REL:e}·{}", names[p])
            };
            c.check(
                &format!("{label} audio-loss {loss_name} dL/d{} vs FD (step {step}, {n} modes, fs {fs} Hz)", names[p]),
                e < AUDIO_TOL,
                format!("exact {exact:.6e}, FD {fd:.6e}, relative error {e:.2e}"),
            );
        }
    }
    // Every rank must have computed bit for bit the same losses, gradients and differences.
    let (mut lo, mut hi) = (vec![0.0; all_ranks.len()], vec![0.0; all_ranks.len()]);
    petsc
        .world()
        .all_reduce_into(&all_ranks[..], &mut lo[..], SystemOperation::min());
    petsc
        .world()
        .all_reduce_into(&all_ranks[..], &mut hi[..], SystemOperation::max());
    let differ = lo.iter().zip(&hi).filter(|(a, b)| a != b).count();
    c.check(
        &format!(
            "{label} audio-loss values identical on all {} ranks",
            petsc.size()
        ),
        differ == 0,
        format!("{differ} of {} numbers differ", all_ranks.len()),
    );
}

/// Shape chain (issue 7), end to end: field → marching tets → P2 → SLEPc → node sensitivities →
/// back to the field → shell thickness t. A hollow ellipsoid (semi-axes 50, 40, 30 mm, field
/// s = 1 − |x/a|, so max s ≈ 1 at the centre) on a 12×10×8-cell grid, 6 modes, ceramic. The
/// exact dλ_k/dt against central differences of re-meshed, re-solved spectra with h = 1e-5 (a
/// crossing moves by ~h·cell, far from any topology change at this t; the snap rule would break
/// the difference only if a value sat within 5 % of a cell of zero, which the check reports).
/// Members of a near-degenerate cluster (modes 3–4 here, 0.16 % apart) are compared as the
/// cluster mean, which is what the chain differentiates. Bar: 1e-4 relative to λ_k/t.
fn check_shape_chain(petsc: &Petsc, c: &mut Checker) {
    use diffsound::shape::shape_spectrum;
    let grid = shape::BackgroundGrid::covering([-0.05, -0.04, -0.03], [0.05, 0.04, 0.03], 12, 1.0)
        .expect("grid");
    let solid: Vec<f64> = grid
        .vertex_positions()
        .iter()
        .map(|p| {
            1.0 - ((p[0] / 0.05).powi(2) + (p[1] / 0.04).powi(2) + (p[2] / 0.03).powi(2)).sqrt()
        })
        .collect();
    let options = shape::MarchingOptions::default();
    let material = Material::preset("ceramic").expect("preset");
    let n = 6;
    let t0 = 0.45;
    let shell = shape::shell(&solid, t0).expect("shell");
    let base = shape_spectrum(petsc, &grid, &shell.values, &options, &material, n, true)
        .expect("spectrum");
    let gradient = base.gradient.as_ref().expect("gradient");
    let h = 1e-5;
    let at = |t: f64| {
        let s = shape::shell(&solid, t).expect("shell");
        let sp = shape_spectrum(petsc, &grid, &s.values, &options, &material, n, false)
            .expect("spectrum");
        (sp.eigenvalues, sp.tets, sp.report.snapped_vertices)
    };
    let (plus, tets_p, snap_p) = at(t0 + h);
    let (minus, tets_m, snap_m) = at(t0 - h);
    let same_topology = tets_p == base.tets
        && tets_m == base.tets
        && snap_p == base.report.snapped_vertices
        && snap_m == base.report.snapped_vertices;
    // Members of a near-degenerate cluster carry the cluster-mean derivative: compare it with
    // the difference of the cluster mean.
    let mut worst: f64 = 0.0;
    // Index loop: k indexes the gradients and the eigenvalues and is looked up in the clusters.
    #[allow(clippy::needless_range_loop)]
    for k in 0..n {
        let group = base
            .clusters
            .iter()
            .find(|r| r.contains(&k))
            .cloned()
            .unwrap_or(k..k + 1);
        let exact = shell.vjp(&gradient[k]).expect("vjp").thickness;
        let fd = group
            .clone()
            .map(|j| (plus[j] - minus[j]) / (2.0 * h))
            .sum::<f64>()
            / group.len() as f64;
        worst = worst.max((exact - fd).abs() / (base.eigenvalues[k] / t0));
    }
    c.check(
        "hollow-ellipsoid shape chain dλ/dt (field → marching → P2 → SLEPc → back)",
        same_topology && worst < 1e-4,
        format!("{} tets, {} P2 nodes, worst relative error {worst:.2e}, topology unchanged by ±h: {same_topology}", base.tets, base.p2_nodes),
    );
}

/// Curved shell chain (issue 7): dλ_k/dt of the hollow body meshed with exact crossings and a
/// curved P2 boundary ([`diffsound::shape::curved_shell_spectrum`]: crossings and
/// boundary mid-edge nodes move with t on the inner wall) against central differences of
/// re-meshed, re-solved spectra. The solid is a triangulated ellipsoid (semi-axes 50, 40, 30 mm,
/// 24 bands), its signed distance sampled on a 12×10×8-cell grid, S its deepest point's depth,
/// t = 0.45, 6 modes, ceramic, h = 1e-5, cluster means. Measured at 2e-8: bar 1e-4 relative to
/// λ_k/t, as for the straight chain.
/// The grid refined near the inner walls (as the fit's finer levels are) is not solved here:
/// three solves of its 8 modes took a minute of the suite's time on 2 ranks. Its chain is
/// checked without solves by `curved_shell_chain_follows_the_nodes_on_plain_and_refined_grids`
/// in `src/inverse/shape/tests.rs` (the nodes' velocities, where the stop-35 fault was: the
/// mid-edge nodes' turn where the signed distance has a crease), and through SLEPc by
/// `examples/wall_chain_probe.rs` (measured on 2 ranks: 5.4e-6, 4.2e-6, 1.0e-6, 2.4e-6 on
/// modes 1–4 against the bar of 1e-4).
fn check_curved_shell_chain(petsc: &Petsc, c: &mut Checker) {
    use diffsound::shape::{curved_shell_spectrum, reference_depth};
    let surface = shape::TriangleSurface::ellipsoid([0.05, 0.04, 0.03], 24);
    let sdf = shape::SignedDistance::new(&surface).expect("sdf");
    let depth = reference_depth(&sdf, &surface).expect("depth");
    let grid = shape::BackgroundGrid::covering([-0.05, -0.04, -0.03], [0.05, 0.04, 0.03], 12, 1.0)
        .expect("grid");
    let solid = sdf.evaluate(&grid.vertex_positions());
    let options = shape::MarchingOptions::default();
    let material = Material::preset("ceramic").expect("preset");
    let (n, t0, h) = (6, 0.45, 1e-5);
    let bar = 1e-4;
    let (base, derivative) = curved_shell_spectrum(
        petsc, &grid, &solid, &sdf, depth, t0, &options, &material, n, true,
    )
    .expect("spectrum");
    let derivative = derivative.expect("derivative");
    let at = |t: f64| {
        let (sp, _) = curved_shell_spectrum(
            petsc, &grid, &solid, &sdf, depth, t, &options, &material, n, false,
        )
        .expect("spectrum");
        (sp.eigenvalues, sp.tets, sp.report.snapped_vertices)
    };
    let (plus, tets_p, snap_p) = at(t0 + h);
    let (minus, tets_m, snap_m) = at(t0 - h);
    let same_topology = tets_p == base.tets
        && tets_m == base.tets
        && snap_p == base.report.snapped_vertices
        && snap_m == base.report.snapped_vertices;
    let mut worst: f64 = 0.0;
    let mut rows = Vec::new();
    // Index loop: k indexes the derivatives and the eigenvalues and is looked up in the clusters.
    #[allow(clippy::needless_range_loop)]
    for k in 0..n {
        let group = base
            .clusters
            .iter()
            .find(|r| r.contains(&k))
            .cloned()
            .unwrap_or(k..k + 1);
        let fd = group
            .clone()
            .map(|j| (plus[j] - minus[j]) / (2.0 * h))
            .sum::<f64>()
            / group.len() as f64;
        let error = (derivative[k] - fd).abs() / (base.eigenvalues[k] / t0);
        rows.push(format!("{:.4e}/{:.4e}", derivative[k], fd));
        worst = worst.max(error);
    }
    c.check(
        "curved hollow-ellipsoid chain dλ/dt (exact crossings + curved P2 boundary → SLEPc → back)",
        same_topology && worst < bar,
        format!("{} tets, {} P2 nodes, worst relative error {worst:.2e} (exact/FD {}), topology unchanged by ±h: {same_topology}", base.tets, base.p2_nodes, rows.join(" ")),
    );
}

/// Morph chain (issue 7): dλ_k/dc of m = c·A + (1 − c)·B through marching → P2 → SLEPc → back
/// to the field → [`shape::morph_vjp`], against central differences of re-meshed, re-solved
/// spectra. A = 1 − |x/a| for the ellipsoid of semi-axes (50, 40, 30) mm, B the same for
/// (38, 46, 27) mm turned by 20° about z (so the morph changes shape, not only size), c = 0.4,
/// on the 12×10×8-cell grid of the shell check, 6 modes, ceramic; h = 1e-5, cluster means,
/// bar 1e-4 relative to λ_k (c is a dimensionless weight of order 1).
fn check_morph_chain(petsc: &Petsc, c: &mut Checker) {
    use diffsound::shape::shape_spectrum;
    let grid =
        shape::BackgroundGrid::covering([-0.05, -0.046, -0.03], [0.05, 0.046, 0.03], 12, 1.0)
            .expect("grid");
    let ellipsoid = |axes: [f64; 3], angle: f64| -> Vec<f64> {
        let (cs, sn) = (angle.cos(), angle.sin());
        grid.vertex_positions()
            .iter()
            .map(|p| {
                let (x, y) = (cs * p[0] + sn * p[1], -sn * p[0] + cs * p[1]);
                1.0 - ((x / axes[0]).powi(2) + (y / axes[1]).powi(2) + (p[2] / axes[2]).powi(2))
                    .sqrt()
            })
            .collect()
    };
    let a = ellipsoid([0.05, 0.04, 0.03], 0.0);
    let b = ellipsoid([0.038, 0.046, 0.027], 20f64.to_radians());
    let options = shape::MarchingOptions::default();
    let material = Material::preset("ceramic").expect("preset");
    let n = 6;
    let c0 = 0.4;
    let base = shape_spectrum(
        petsc,
        &grid,
        &shape::morph(&a, &b, c0).expect("morph"),
        &options,
        &material,
        n,
        true,
    )
    .expect("spectrum");
    let gradient = base.gradient.as_ref().expect("gradient");
    let h = 1e-5;
    let at = |cw: f64| {
        let sp = shape_spectrum(
            petsc,
            &grid,
            &shape::morph(&a, &b, cw).expect("morph"),
            &options,
            &material,
            n,
            false,
        )
        .expect("spectrum");
        (sp.eigenvalues, sp.tets, sp.report.snapped_vertices)
    };
    let (plus, tets_p, snap_p) = at(c0 + h);
    let (minus, tets_m, snap_m) = at(c0 - h);
    let same_topology = tets_p == base.tets
        && tets_m == base.tets
        && snap_p == base.report.snapped_vertices
        && snap_m == base.report.snapped_vertices;
    let mut worst: f64 = 0.0;
    // Index loop: k indexes the gradients and the eigenvalues and is looked up in the clusters.
    #[allow(clippy::needless_range_loop)]
    for k in 0..n {
        let group = base
            .clusters
            .iter()
            .find(|r| r.contains(&k))
            .cloned()
            .unwrap_or(k..k + 1);
        let exact = shape::morph_vjp(&a, &b, c0, &gradient[k]).expect("vjp").c;
        let fd = group
            .clone()
            .map(|j| (plus[j] - minus[j]) / (2.0 * h))
            .sum::<f64>()
            / group.len() as f64;
        worst = worst.max((exact - fd).abs() / base.eigenvalues[k]);
    }
    c.check(
        "ellipsoid morph chain dλ/dc (field → marching → P2 → SLEPc → back → morph_vjp)",
        same_topology && worst < 1e-4,
        format!("{} tets, {} P2 nodes, worst relative error {worst:.2e}, topology unchanged by ±h: {same_topology}", base.tets, base.p2_nodes),
    );
}

/// Neural-field chain (issue 7, task 3): θ → s(x_i; θ) at the grid vertices (the MLP of
/// `shape::neural_sdf`) → marching → P2 → SLEPc → dλ/ds → the network's backpropagation.
/// The network (2 octaves, 12 × 12 softplus units) is pre-fitted for 200 updates to 8³ voxels of
/// the ellipsoid of the shell check (semi-axes 50, 40, 30 mm), built here from the analytic
/// field, so it encloses one smooth body; 12×10×8-cell grid, 6 modes, ceramic. For three seeded
/// random directions v in θ, scaled so that the field moves by at most one grid cell per unit
/// of ε at any vertex, the exact dλ_k/dε = (J_θᵀ dλ_k/ds) · v is compared with central
/// differences of re-meshed, re-solved spectra at ε = ±1e-5 (crossings move by 1e-5 cells).
/// The chain is exact only between topology changes of the marching (shape module docs), so the
/// check demands an unchanged tet count and snap count at ±ε and reports it; then the
/// difference errs by O(ε²) and the eigenvalues' rounding noise over ε (~1e-13/1e-5 relative),
/// and the bar is 1e-4 relative to λ_k (as for the morph weight, also a unit-order parameter).
/// Cluster members are compared as cluster means.
///
/// With `curved` the body is the geometry task's default one (the shape module's "Curved
/// boundary"): crossings on the network's zero along their grid edges and boundary mid-edge
/// nodes on it along ∇s, so dλ/dθ is Σ_j w_kj ∂s(x_j)/∂θ over the grid vertices, the moved
/// points and the points where each mid-edge node's direction of move (∇s at its midpoint)
/// turns with θ. Without those turns this check missed by 1e-2.
fn check_neural_chain(petsc: &Petsc, c: &mut Checker, curved: bool) {
    use diffsound::inverse::geometry::{field_spectrum, prefit, PrefitSettings, Voxels};
    use diffsound::shape::neural_sdf::{NeuralSdf, NeuralSdfConfig};
    let axes = [0.05, 0.04, 0.03];
    let inside = |p: [f64; 3]| {
        (p[0] / axes[0]).powi(2) + (p[1] / axes[1]).powi(2) + (p[2] / axes[2]).powi(2) < 1.0
    };
    let n = 8;
    let size = [0, 1, 2].map(|d| 2.0 * axes[d] / n as f64);
    let origin = [0, 1, 2].map(|d| -axes[d] - size[d]);
    let m = n + 2;
    let mut voxels = Voxels {
        origin,
        size,
        resolution: n,
        inside: vec![false; m * m * m],
    };
    for v in 0..voxels.len() {
        voxels.inside[v] = inside(voxels.centre(v));
    }
    let (lo, hi) = voxels.padded_box();
    let mut net = NeuralSdf::new(
        NeuralSdfConfig::for_box(lo, hi, 2, vec![12, 12]).expect("config"),
        3,
    )
    .expect("network");
    prefit(
        &mut net,
        &voxels,
        &PrefitSettings {
            steps: 200,
            batch: 256,
            eikonal_batch: 64,
            learning_rate: 1e-2,
            final_learning_rate: 2e-3,
            ..Default::default()
        },
    )
    .expect("pre-fit");
    let grid = shape::BackgroundGrid::covering([-0.05, -0.04, -0.03], [0.05, 0.04, 0.03], 12, 1.0)
        .expect("grid");
    let points = grid.vertex_positions();
    let options = shape::MarchingOptions::default();
    let material = Material::preset("ceramic").expect("preset");
    let modes = 6;
    let theta0 = net.parameters().to_vec();
    let (base, gradient) = field_spectrum(
        petsc,
        &grid,
        &net.values(&points),
        &|x| net.value(x),
        curved,
        &options,
        &material,
        modes,
        true,
    )
    .expect("spectrum");
    let gradient = gradient.expect("gradient");
    let per_mode: Vec<Vec<f64>> = gradient
        .per_mode
        .iter()
        .map(|g| net.vjp(&gradient.points, g).expect("vjp"))
        .collect();
    let at = |theta: &[f64]| {
        let mut moved = net.clone();
        moved.set_parameters(theta).expect("θ");
        let (sp, _) = field_spectrum(
            petsc,
            &grid,
            &moved.values(&points),
            &|x| moved.value(x),
            curved,
            &options,
            &material,
            modes,
            false,
        )
        .expect("spectrum");
        (
            sp.eigenvalues,
            sp.tets,
            sp.report.snapped_vertices,
            moved.values(&points),
        )
    };
    let cell = grid.spacing()[0];
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut uniform = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    let (mut worst, mut same_topology) = (0.0f64, true);
    let mut largest = 0.0f64;
    for _ in 0..3 {
        let raw: Vec<f64> = (0..theta0.len()).map(|_| uniform()).collect();
        // Scale v so that max_i |J v|_i = one cell (J v by a small central difference of the
        // smooth network, used only for the scale).
        let probe = |t: f64| {
            let mut moved = net.clone();
            moved
                .set_parameters(
                    &theta0
                        .iter()
                        .zip(&raw)
                        .map(|(a, b)| a + t * b)
                        .collect::<Vec<_>>(),
                )
                .expect("θ");
            moved.values(&points)
        };
        let (p, q) = (probe(1e-6), probe(-1e-6));
        let speed = p
            .iter()
            .zip(&q)
            .map(|(a, b)| ((a - b) / 2e-6).abs())
            .fold(0.0, f64::max);
        let v: Vec<f64> = raw.iter().map(|r| r * cell / speed).collect();
        let h = 1e-5;
        let (plus, tets_p, snap_p, _) = at(&theta0
            .iter()
            .zip(&v)
            .map(|(a, b)| a + h * b)
            .collect::<Vec<_>>());
        let (minus, tets_m, snap_m, _) = at(&theta0
            .iter()
            .zip(&v)
            .map(|(a, b)| a - h * b)
            .collect::<Vec<_>>());
        same_topology &= tets_p == base.tets
            && tets_m == base.tets
            && snap_p == base.report.snapped_vertices
            && snap_m == base.report.snapped_vertices;
        // Index loop: k indexes the gradients and the eigenvalues and is looked up in the clusters.
        #[allow(clippy::needless_range_loop)]
        for k in 0..modes {
            let group = base
                .clusters
                .iter()
                .find(|r| r.contains(&k))
                .cloned()
                .unwrap_or(k..k + 1);
            let exact: f64 = per_mode[k].iter().zip(&v).map(|(g, d)| g * d).sum();
            let fd = group
                .clone()
                .map(|j| (plus[j] - minus[j]) / (2.0 * h))
                .sum::<f64>()
                / group.len() as f64;
            worst = worst.max((exact - fd).abs() / base.eigenvalues[k]);
            largest = largest.max(exact.abs() / base.eigenvalues[k]);
        }
    }
    let label = if curved {
        "neural-field chain dλ/dθ, curved boundary (MLP → crossings and mid-edge nodes on its zero → P2 → SLEPc → back → backpropagation at the moved points), 3 directions"
    } else {
        "neural-field chain dλ/dθ (MLP → grid field → marching → P2 → SLEPc → back → backpropagation), 3 directions"
    };
    c.check(
        label,
        same_topology && worst < 1e-4 && largest > 1e-3,
        format!("{} tets, {} parameters, largest |dλ/dε|/λ {largest:.2e}, worst relative error {worst:.2e}, topology unchanged by ±ε: {same_topology}", base.tets, theta0.len()),
    );
}

/// The loaded Ritz model's distributed pieces (`PoissonBasis::attachment_solver`, `attachments`,
/// `rigid_probe_values`, MUMPS Cholesky) against a full solve with the mass, on this many ranks:
/// 6 % of the brick's mass on the three surface vertices nearest a top corner, ν = 0.3. The
/// enriched Ritz values (modes, rigid motions, two blocks of attachment vectors) must bound the
/// full solve's from above and lie within `LOADED_RITZ_TOL` of them, and beat the modes alone
/// (rigid motions kept) by at least 3 times: a wrongly distributed load, gather or projection
/// breaks either.
fn check_loaded_ritz(petsc: &Petsc, c: &mut Checker) {
    let brick = mesh::lift_to_quadratic(&mesh::box_mesh([5, 4, 3], [0.10, 0.07, 0.04]));
    let assembled = assembly::assemble(petsc, &brick).expect("assembly");
    let (nu, density, youngs, fraction) = (0.3, 2700.0, 7e10, 0.06);
    let corner = [0.10, 0.07, 0.04];
    let d2 = |x: &[f64; 3]| (0..3).map(|k| (x[k] - corner[k]).powi(2)).sum::<f64>();
    let mut order: Vec<usize> = (0..brick.n_nodes()).collect();
    order.sort_by(|&a, &b| {
        d2(&brick.nodes[a])
            .total_cmp(&d2(&brick.nodes[b]))
            .then(a.cmp(&b))
    });
    let region_nodes: Vec<usize> = order[..3].to_vec();
    let strike_node = order[order.len() - 1];
    // Probes: the strike node's z DOF, then the region's nodes' three DOFs each.
    let mut probes: Vec<i32> = vec![assembled.layout.global_dof(strike_node, 2) as i32];
    for &v in &region_nodes {
        for k in 0..3 {
            probes.push(assembled.layout.global_dof(v, k) as i32);
        }
    }
    let n = 8;
    let basis = PoissonBasis::build(
        petsc,
        &assembled,
        diagonal(&brick),
        n,
        4,
        &[0.2, 0.3, 0.4],
        probes.iter().map(|&p| p as _).collect(),
    )
    .expect("reduced basis");
    let modes = basis.solve(nu);
    let lowest = modes.theta[0];
    let solver = basis
        .attachment_solver(petsc, &assembled, &brick.nodes, nu, 0.1 * lowest)
        .expect("attachment solver");
    let rigid_all = basis.rigid_probe_values(&solver).expect("rigid motions");
    let all = basis.probe_all(&modes);
    let region: Vec<usize> = (0..3).collect();
    let at_modes = ModesAtPoisson {
        theta: modes.theta[..n].to_vec(),
        strike: (0..n).map(|k| all[(0, k)]).collect(),
        values: all.view((1, 0), (9, n)).into_owned(),
        lame: lame_unit(nu),
        coefficients: modes.coefficient_matrix().columns(0, n).into_owned(),
        rigid: rigid_all.rows(1, 9).into_owned(),
        rigid_strike: rigid_all.row(0).iter().copied().collect(),
    };
    let loads: Vec<Vec<(_, f64)>> = (0..3)
        .map(|k| {
            region_nodes
                .iter()
                .map(|&v| (assembled.layout.global_dof(v, k) as _, 1.0))
                .collect()
        })
        .collect();
    let projections = basis
        .attachments(petsc, &assembled, &solver, &loads, 2)
        .expect("attachments");
    // The batched path (several groups through one multiple-right-hand-side solve) gives the
    // same numbers as one group alone, whatever else shares its chunk.
    let single: Vec<Vec<(_, f64)>> = (0..3)
        .map(|k| vec![(assembled.layout.global_dof(region_nodes[0], k) as _, 1.0)])
        .collect();
    let many = basis
        .attachments_many(
            petsc,
            &assembled,
            &solver,
            &[single.clone(), loads.clone()],
            2,
        )
        .expect("batched attachments");
    let rel = |a: &nalgebra::DMatrix<f64>, b: &nalgebra::DMatrix<f64>| {
        (a - b).norm() / b.norm().max(1e-300)
    };
    let p = &projections;
    let q = &many[1];
    let batched = [
        rel(&q.cross_lambda, &p.cross_lambda),
        rel(&q.cross_mu, &p.cross_mu),
        rel(&q.cross_mass, &p.cross_mass),
        rel(&q.self_lambda, &p.self_lambda),
        rel(&q.self_mu, &p.self_mu),
        rel(&q.self_mass, &p.self_mass),
        rel(&q.probe_values, &p.probe_values),
    ]
    .into_iter()
    .fold(0.0_f64, f64::max);
    c.check(
        "brick attachments batched",
        many.len() == 2 && batched < 1e-10,
        format!("a region's projections solved alone and beside another region: largest relative difference {batched:.1e}"),
    );
    // Both placements of the attachment problem (one factor over every rank, or the whole
    // problem on each rank with the groups shared out and gathered) give the same projections
    // and rigid motions, up to the factors' rounding.
    let placed = |placement| {
        let s = basis
            .attachment_solver_placed(petsc, &assembled, &brick.nodes, nu, 0.1 * lowest, placement)
            .expect("placed attachment solver");
        let rigid = basis.rigid_probe_values(&s).expect("rigid motions");
        let list = basis
            .attachments_many(
                petsc,
                &assembled,
                &s,
                &[loads.clone(), single.clone(), loads.clone()],
                2,
            )
            .expect("placed attachments");
        (rigid, list)
    };
    let (rigid_d, list_d) = placed(AttachmentPlacement::Distributed);
    let (rigid_r, list_r) = placed(AttachmentPlacement::Redundant);
    let mut placement_diff = rel(&rigid_r, &rigid_d);
    for (r, d) in list_r.iter().zip(&list_d) {
        for (a, b) in [
            (&r.cross_lambda, &d.cross_lambda),
            (&r.cross_mu, &d.cross_mu),
            (&r.cross_mass, &d.cross_mass),
            (&r.self_lambda, &d.self_lambda),
            (&r.self_mu, &d.self_mu),
            (&r.self_mass, &d.self_mass),
            (&r.probe_values, &d.probe_values),
        ] {
            placement_diff = placement_diff.max(rel(a, b));
        }
    }
    c.check(
        "brick attachments placed",
        list_r.len() == 3 && list_d.len() == 3 && placement_diff < 1e-9,
        format!("three groups (9 columns) on {} rank(s), redundant against distributed: largest relative difference {placement_diff:.1e}", petsc.size()),
    );
    let na = projections.probe_values.ncols();
    let extra = Enrichment {
        region_values: projections.probe_values.rows(1, 9).into_owned(),
        strike: projections.probe_values.row(0).iter().copied().collect(),
        projections,
    };
    let volume = brick.volume();
    let alpha = fraction * volume / 3.0;
    let enriched =
        loaded_modes_enriched(&at_modes, &region, &extra, alpha).expect("enriched Ritz problem");
    let modal = loaded_modes(&at_modes, &region, alpha);
    // The full solve with the mass lumped on the same nodes.
    let material = Material {
        youngs_modulus: youngs,
        poisson_ratio: nu,
        density,
        rayleigh_alpha: 0.0,
        rayleigh_beta: 0.0,
    };
    let (k, mut m) = assembled.operators(&material).expect("operators");
    assembly::add_nodal_diagonal(
        petsc,
        &mut m,
        &assembled.layout,
        &region_nodes,
        [fraction * density * volume / 3.0; 3],
    )
    .expect("nodal mass");
    m.set_symmetric().expect("symmetric");
    let full =
        eigen::solve_modes(petsc, &k, &m, &config(&brick, &material, 6)).expect("loaded solve");
    let (mut worst, mut worst_modal, mut bounded) = (0.0_f64, 0.0_f64, true);
    for (j, lambda) in full.eigenvalues[..6].iter().enumerate() {
        let theta_full = lambda * density / youngs;
        let f = |theta: f64| (theta / theta_full).sqrt() - 1.0;
        bounded &= f(enriched[j].0) > -1e-6;
        worst = worst.max(f(enriched[j].0).abs());
        worst_modal = worst_modal.max(f(modal[j].0).abs());
    }
    c.check(
        "brick loaded-ritz",
        bounded && worst < LOADED_RITZ_TOL && worst_modal > 3.0 * worst,
        format!("6 % on 3 corner nodes, {na} attachment vectors: first 6 loaded frequencies within {:.4} % of the full solve (modes alone {:.4} %), upper bound: {bounded}", 100.0 * worst, 100.0 * worst_modal),
    );
}

/// A failure on one rank reaches every rank as the same error, instead of leaving the others
/// waiting in the next collective (before `petsc::collective`, rank 0 carrying a shape gradient
/// or one rank's share of a network backpropagation could return early and hang the job; this
/// check would then hang, and the launcher's time limit fails it). Every rank's outcome is
/// reduced, so a wrong answer on any rank fails the check.
fn check_collective_failures(petsc: &Petsc, c: &mut Checker) {
    use diffsound::petsc::collective::{agree, share_from_root};
    let (rank, size) = (petsc.rank(), petsc.size());
    let root_only = |r: Result<Vec<f64>, String>| if rank == 0 { Some(r) } else { None };
    let shared = share_from_root(petsc, root_only(Ok(vec![1.5, -2.0, 3.25])), 3);
    let shared_ok = shared == Ok(vec![1.5, -2.0, 3.25]);
    let failed = share_from_root(petsc, root_only(Err("the carry failed".into())), 3);
    let failed_ok = matches!(&failed, Err(m) if m.contains("the carry failed"));
    let wrong_length = share_from_root(petsc, root_only(Ok(vec![1.0; 2])), 3);
    let wrong_length_ok = matches!(&wrong_length, Err(m) if m.contains("2 numbers where 3"));
    let last = size - 1;
    let agreed_ok = agree(petsc, Ok::<usize, String>(rank)) == Ok(rank);
    let one_failed = agree(
        petsc,
        if rank == last {
            Err(format!("share {rank} is not finite"))
        } else {
            Ok(rank)
        },
    );
    // On one rank there is nobody to tell, and the error comes back as it was.
    let expected = if size > 1 {
        format!("rank {last}: share {last} is not finite")
    } else {
        "share 0 is not finite".to_string()
    };
    let one_failed_ok = matches!(&one_failed, Err(m) if m == &expected);
    let all = [
        shared_ok,
        failed_ok,
        wrong_length_ok,
        agreed_ok,
        one_failed_ok,
    ];
    let mine: Vec<i32> = all.iter().map(|&b| b as i32).collect();
    let mut everywhere = vec![0i32; mine.len()];
    petsc
        .world()
        .all_reduce_into(&mine[..], &mut everywhere[..], SystemOperation::min());
    c.check(
        "collective failures",
        everywhere.iter().all(|&b| b == 1),
        format!(
            "on every one of {size} rank(s): rank 0's rows shared {}, rank 0's error shared {}, a wrong length refused {}, all-ok agreed {}, rank {last}'s error agreed {} ({failed:?} / {one_failed:?} on rank {rank})",
            everywhere[0] == 1,
            everywhere[1] == 1,
            everywhere[2] == 1,
            everywhere[3] == 1,
            everywhere[4] == 1
        ),
    );
}

/// Rigid-mode deflation (`eigen::solve_modes_deflated`): the same elastic modes as the plain
/// solve, each M-orthogonal to the six rigid motions, the six motions' Rayleigh quotients
/// reported as the rigid eigenvalues, and a vector that is not a rigid motion refused.
/// Every mode up to a frequency, counted first ([`eigen::UpToMethod::CountThenNearest`], the
/// diagnosis's way) against SLEPc's spectrum slicing: the same modes below the limit (eigenvalues
/// to 1e-9 relative), none above it, and the count proven complete by both. The limit sits in the
/// widest relative gap among modes 8–16 of a first-20 solve, far from any eigenvalue.
fn check_up_to_by_count(petsc: &Petsc, c: &mut Checker, label: &str, m: &TetMesh) {
    let mat = Material::preset("ceramic").unwrap();
    let assembled = assembly::assemble(petsc, m).expect("assembly");
    let (k, mm) = assembled.operators(&mat).expect("operators");
    let first = eigen::solve_modes(petsc, &k, &mm, &config(m, &mat, 20)).expect("first 20");
    let l = &first.eigenvalues;
    let j = (7..16)
        .max_by(|&a, &b| (l[a + 1] / l[a]).total_cmp(&(l[b + 1] / l[b])))
        .unwrap();
    let upper = (l[j] * l[j + 1]).sqrt();
    let mut cfg = config(m, &mat, 1);
    cfg.request = ModeRequest::UpTo {
        f_max_hz: eigen::frequency_hz(upper),
    };
    cfg.verify_count = true;
    let sliced = eigen::solve_modes(petsc, &k, &mm, &cfg).expect("slicing");
    cfg.up_to = eigen::UpToMethod::CountThenNearest;
    let counted = eigen::solve_modes(petsc, &k, &mm, &cfg).expect("count then nearest");
    let same_count = sliced.eigenvalues.len() == j + 1 && counted.eigenvalues.len() == j + 1;
    let worst = sliced
        .eigenvalues
        .iter()
        .zip(&counted.eigenvalues)
        .map(|(a, b)| rel(*b, *a, *a))
        .fold(0.0, f64::max);
    let complete = |modes: &eigen::Modes<'_>| {
        modes
            .inertia_check
            .as_ref()
            .is_some_and(|i| matches!(i.verdict, eigen::CountVerdict::Complete))
    };
    let by_count = counted.setting("up_to_method") == Some("count_then_nearest");
    c.check(
        &format!("{label} modes up to a limit counted first, against spectrum slicing"),
        same_count && worst < 1e-9 && complete(&sliced) && complete(&counted) && by_count,
        format!(
            "{} sliced, {} counted, {} expected below {upper:.4e} rad²/s²; worst relative eigenvalue difference {worst:.2e}; proofs complete {} / {}; counted path taken {by_count}",
            sliced.eigenvalues.len(),
            counted.eigenvalues.len(),
            j + 1,
            complete(&sliced),
            complete(&counted)
        ),
    );
}

fn check_rigid_deflation(petsc: &Petsc, c: &mut Checker, label: &str, m: &TetMesh, n: usize) {
    let mat = Material::preset("ceramic").unwrap();
    let assembled = assembly::assemble(petsc, m).expect("assembly");
    let (k, mm) = assembled.operators(&mat).expect("operators");
    let cfg = config(m, &mat, n);
    let plain = eigen::solve_modes(petsc, &k, &mm, &cfg).expect("plain solve");
    let rigid = eigen::rigid_body_vectors(&k, &assembled.layout, &m.nodes).expect("rigid vectors");
    let deflated =
        eigen::solve_modes_deflated(petsc, &k, &mm, &cfg, &rigid).expect("deflated solve");
    let worst = (0..n)
        .map(|i| {
            rel(
                deflated.eigenvalues[i],
                plain.eigenvalues[i],
                plain.eigenvalues[i],
            )
        })
        .fold(0.0, f64::max);
    let worst_residual = deflated
        .residuals
        .iter()
        .take(n)
        .copied()
        .fold(0.0, f64::max);
    let limit = cfg.rigid_threshold * cfg.spectrum_scale;
    let rigid_ok = deflated.rigid_eigenvalues.len() == 6
        && deflated.rigid_eigenvalues.iter().all(|q| q.abs() < limit);
    // |φ_kᵀ M r| / (‖φ_k‖_M ‖r‖_M), φ_k mass-normalised.
    let mut worst_overlap: f64 = 0.0;
    let mut mr = k.create_vector().expect("vector");
    for r in &rigid {
        mm.mult(r, &mut mr).expect("M r");
        let norm = r.dot(&mr).expect("rMr").sqrt();
        for phi in deflated.vectors.iter().take(n) {
            worst_overlap = worst_overlap.max(phi.dot(&mr).expect("φMr").abs() / norm);
        }
    }
    // A stretch along x is no rigid motion: it must be refused, not deflated.
    let nodes = assembled.layout.owned_nodes();
    let mut stretch = k.create_vector().expect("vector");
    let values: Vec<f64> = nodes
        .flat_map(|new| {
            let x = m.nodes[assembled.layout.partition.old_of_new[new]];
            [x[0], 0.0, 0.0]
        })
        .collect();
    stretch.set_local_values(&values).expect("set");
    let refused = matches!(eigen::solve_modes_deflated(petsc, &k, &mm, &cfg, &[stretch]), Err(eigen::EigenError::BadRequest(ref e)) if e.contains("not a rigid-body motion"));
    c.check(
        &format!("{label} rigid-mode deflation"),
        worst < 1e-9 && worst_residual < 1e-8 && rigid_ok && worst_overlap < 1e-8 && refused,
        format!(
            "{n} modes: worst relative eigenvalue difference {worst:.2e}, worst residual {worst_residual:.2e}, rigid quotients {:?} (limit {limit:.1e}), worst M-overlap with a rigid motion {worst_overlap:.2e}, a stretch refused {refused}; Krylov–Schur restarts {} plain / {} deflated",
            deflated.rigid_eigenvalues.iter().map(|q| format!("{q:.1e}")).collect::<Vec<_>>(),
            plain.setting("iterations").unwrap_or("?"),
            deflated.setting("iterations").unwrap_or("?")
        ),
    );
}

fn child() {
    let universe = mpi::initialize().expect("MPI");
    let petsc = Petsc::initialize(universe, "mpi_sensitivity", &[]).expect("PETSc");
    let mut c = Checker {
        rank: petsc.rank(),
        failures: 0,
    };
    check_collective_failures(&petsc, &mut c);
    // The bowl and the longer chains run on 2 ranks only (module docs, "Ranks").
    let distributed = petsc.size() > 1;
    // A small brick with unequal sides, so that its low modes are well separated.
    let brick = mesh::lift_to_quadratic(&mesh::box_mesh([5, 4, 3], [0.10, 0.07, 0.04]));
    check_mesh(&petsc, &mut c, "brick", &brick, 12);
    check_audio_loss(&petsc, &mut c, "brick", &brick, 12);
    if distributed {
        check_mesh(&petsc, &mut c, "bowl", &load("examples/bowl/bowl.msh"), 10);
    }
    check_rigid_deflation(&petsc, &mut c, "brick", &brick, 12);
    check_up_to_by_count(&petsc, &mut c, "brick", &brick);
    if distributed {
        check_rigid_deflation(&petsc, &mut c, "bowl", &load("examples/bowl/bowl.msh"), 16);
    }
    check_shape_chain(&petsc, &mut c);
    check_curved_shell_chain(&petsc, &mut c);
    check_morph_chain(&petsc, &mut c);
    if distributed {
        check_neural_chain(&petsc, &mut c, false);
        check_neural_chain(&petsc, &mut c, true);
    }
    check_loaded_ritz(&petsc, &mut c);
    let _ = c.failures;
}
