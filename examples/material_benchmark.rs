//! Synthetic benchmark of the material fit (issue 5).
//!
//! For each mesh and each seed (an *object*): draw a true material E ~ U[1e10, 1e11] Pa,
//! ν ~ U[0.1, 0.4] (ρ = 2700 kg/m³, Rayleigh α = 6 s⁻¹, β = 1e-7 s) and a start
//! E₀ = E·3^(±1) (random sign), ν₀ ~ U[0.1, 0.45]. The target is rendered from a full SLEPc
//! solve on the P2 mesh with the first `--modes` modes (default 16): impulse at the default
//! strike vertex along its normal, acceleration response, 48 kHz, 0.5 s, peak-normalised to 0.5.
//! Then four fits from the same start: P1 / P2 model × ν held at the true value / ν learned.
//! The P1 model is the linear mesh as read; the P2 model is its lift (same vertex numbering, so
//! the same strike vertex and normal).
//!
//! Reported per fit: relative error of E and ν, the spectrogram error, the wall time of the
//! basis build and of the fit (the per-object time of a variant is their sum), the steps, and
//! the agreement of the reduced basis with a full solve at the fitted ν (max relative
//! eigenvalue difference over the modes fitted).
//!
//! Spectrogram error: relative L1 distance of linear STFT magnitudes (Hann, n_fft 2048,
//! hop 512, [`diffsound::audio::stft`]) of the fitted render (fitted E, ν and gain) against
//! the target: Σ | |S_fit| − |S_tgt| | / Σ |S_tgt|. 0 is a perfect match; a silent prediction
//! scores 1.
//!
//! Seeds: the object seed is splitmix64(seed ⊕ FNV-1a(mesh file name)), so an object does not
//! depend on the order of the meshes on the command line; every seed is printed.
//!
//! Usage: material_benchmark [--seeds 1,2,3] [--modes 16] [--max-steps N] [--variants LIST]
//!        [--json FILE] MESH...
//! (LIST: comma-separated among p1-fixed, p2-fixed, p1-learned, p2-learned; default all four.)
//! Markdown tables go to stdout, progress to stderr.
use diffsound::analysis::estimate::{estimate_modes, EstimateOptions};
use diffsound::assembly::{self, Assembled};
use diffsound::audio::chain::{DampingModel, ModalChain, Strike};
use diffsound::audio::stft::spectrogram_error;
use diffsound::audio::synth::render_samples;
use diffsound::eigen::reduced::PoissonBasis;
use diffsound::inverse::material::{
    fit_material, render_channels, rms_matched_log_gains, FitStep, MaterialFitSettings,
    MaterialProblem,
};
use diffsound::mesh;
use diffsound::petsc::{Petsc, PetscInt};
use diffsound::random::SplitMix64;
use serde_json::json;
use std::time::Instant;

const RHO: f64 = 2700.0;
const ALPHA: f64 = 6.0;
const BETA: f64 = 1e-7;
const SAMPLE_RATE: f64 = 48000.0;
const N_SAMPLES: usize = 24000;
const BASIS_SAMPLES: [f64; 4] = [0.05, 0.2, 0.35, 0.45];
const BASIS_MARGIN: usize = 8;

fn fnv1a(s: &str) -> u64 {
    s.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ b as u64).wrapping_mul(0x100_0000_01b3)
    })
}

fn object_seed(seed: u64, mesh_name: &str) -> u64 {
    SplitMix64::new(seed ^ fnv1a(mesh_name)).next_u64()
}

#[derive(Clone, Copy, PartialEq)]
enum Order {
    P1,
    P2,
}

#[derive(Clone, Copy)]
struct Variant {
    order: Order,
    learn_poisson: bool,
}

impl Variant {
    fn name(&self) -> &'static str {
        match (self.order, self.learn_poisson) {
            (Order::P1, false) => "p1-fixed",
            (Order::P2, false) => "p2-fixed",
            (Order::P1, true) => "p1-learned",
            (Order::P2, true) => "p2-learned",
        }
    }
    fn parse(s: &str) -> Option<Variant> {
        let all = [
            (Order::P1, false),
            (Order::P2, false),
            (Order::P1, true),
            (Order::P2, true),
        ];
        all.into_iter()
            .map(|(order, learn_poisson)| Variant {
                order,
                learn_poisson,
            })
            .find(|v| v.name() == s)
    }
}

struct Args {
    meshes: Vec<String>,
    seeds: Vec<u64>,
    modes: usize,
    max_steps: Option<usize>,
    /// `[fit]` settings as TOML (e.g. `line_match_cap = 0.05`), applied over the defaults.
    settings_toml: Option<String>,
    variants: Vec<Variant>,
    json: Option<String>,
    landscape: bool,
}

fn parse_args() -> Args {
    let mut a = Args {
        meshes: Vec::new(),
        seeds: vec![1, 2, 3],
        modes: 16,
        max_steps: None,
        variants: Vec::new(),
        json: None,
        landscape: false,
        settings_toml: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        let mut value = |name: &str| it.next().unwrap_or_else(|| panic!("{name} needs a value"));
        match arg.as_str() {
            "--seeds" => {
                a.seeds = value("--seeds")
                    .split(',')
                    .map(|s| s.trim().parse().expect("seed: unsigned integer"))
                    .collect()
            }
            "--modes" => a.modes = value("--modes").parse().expect("--modes: integer"),
            "--max-steps" => {
                a.max_steps = Some(value("--max-steps").parse().expect("--max-steps: integer"))
            }
            "--variants" => {
                a.variants = value("--variants")
                    .split(',')
                    .map(|s| {
                        Variant::parse(s.trim()).unwrap_or_else(|| panic!("unknown variant {s}"))
                    })
                    .collect()
            }
            "--settings" => a.settings_toml = Some(value("--settings")),
            "--json" => a.json = Some(value("--json")),
            "--landscape" => a.landscape = true,
            "-h" | "--help" => {
                eprintln!("usage: material_benchmark [--seeds 1,2,3] [--modes 16] [--max-steps N] [--variants p1-fixed,p2-fixed,p1-learned,p2-learned] [--json FILE] [--landscape] MESH...");
                std::process::exit(0);
            }
            s if s.starts_with("--") => panic!("unknown option {s}"),
            s => a.meshes.push(s.to_string()),
        }
    }
    if a.variants.is_empty() {
        a.variants = ["p1-fixed", "p2-fixed", "p1-learned", "p2-learned"]
            .iter()
            .map(|s| Variant::parse(s).unwrap())
            .collect();
    }
    if a.meshes.is_empty() {
        a.meshes.push("examples/bowl/bowl.msh".into());
    }
    a
}

struct Model<'p> {
    asm: Assembled<'p>,
    probe: Vec<PetscInt>,
    n_nodes: usize,
}

fn main() {
    let args = parse_args();
    let universe = mpi::initialize().unwrap();
    let petsc = Petsc::initialize(universe, "material_benchmark", &[]).unwrap();
    let n_modes = args.modes;
    let damping = DampingModel::Rayleigh {
        alpha: ALPHA,
        beta: BETA,
    };
    let strike = Strike::default();
    let base_settings = {
        let mut s: MaterialFitSettings =
            toml::from_str(args.settings_toml.as_deref().unwrap_or(""))
                .expect("--settings: TOML of the [fit] section");
        if let Some(n) = args.max_steps {
            s.max_steps = n;
        }
        s
    };
    eprintln!(
        "seeds {:?}, {} modes, variants {:?}",
        args.seeds,
        n_modes,
        args.variants.iter().map(|v| v.name()).collect::<Vec<_>>()
    );
    let mut rows = Vec::new();
    let mut objects = Vec::new();
    for path in &args.meshes {
        let name = std::path::Path::new(path)
            .file_stem()
            .unwrap()
            .to_string_lossy()
            .to_string();
        let read = mesh::read_mesh(std::path::Path::new(path), &Default::default())
            .unwrap_or_else(|e| panic!("{path}: {e}"));
        let linear = mesh::to_linear(&read.mesh);
        let quadratic = mesh::lift_to_quadratic(&linear);
        let (lo, hi) = quadratic.bounding_box();
        let size = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
        let point = quadratic
            .default_strike_point()
            .expect("mesh without surface");
        let vertex =
            quadratic.tet(point.tet)[point.barycentric.iter().position(|&b| b == 1.0).unwrap()];
        let t_asm = Instant::now();
        let models: Vec<Model> = [&linear, &quadratic]
            .into_iter()
            .map(|m| {
                let asm = assembly::assemble(&petsc, m).unwrap();
                let probe = (0..3)
                    .map(|c| asm.layout.global_dof(vertex, c) as PetscInt)
                    .collect();
                Model {
                    asm,
                    probe,
                    n_nodes: m.n_nodes(),
                }
            })
            .collect();
        eprintln!("[{name}] {} tets, {} P1 / {} P2 nodes, size {:.3} m, strike vertex {vertex}, assembly {:.2} s", linear.n_tets(), models[0].n_nodes, models[1].n_nodes, size, t_asm.elapsed().as_secs_f64());
        for &seed in &args.seeds {
            let oseed = object_seed(seed, &name);
            let mut rng = SplitMix64::new(oseed);
            let e_true = rng.uniform(1e10, 1e11);
            let nu_true = rng.uniform(0.1, 0.4);
            let factor = if rng.unit() < 0.5 { 1.0 / 3.0 } else { 3.0 };
            let e0 = e_true * factor;
            let nu0 = rng.uniform(0.1, 0.45);
            // Target: full P2 solve.
            let t_target = Instant::now();
            let p2 = &models[1];
            let (theta, vecs) =
                PoissonBasis::full_theta(&petsc, &p2.asm, size, nu_true, n_modes).unwrap();
            let eig: Vec<f64> = theta
                .iter()
                .take(n_modes)
                .map(|t| e_true / RHO * t)
                .collect();
            let proj: Vec<f64> = vecs
                .iter()
                .take(n_modes)
                .map(|v| {
                    let p = v.gather_indices(&p2.probe).unwrap();
                    let a: f64 = (0..3).map(|c| p[c] * point.normal[c]).sum();
                    a * a / RHO
                })
                .collect();
            let (bank, _) = ModalChain::new(&eig, &proj, &damping, &strike).unwrap();
            let raw = render_samples(&bank, SAMPLE_RATE, N_SAMPLES);
            let peak = raw.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
            let target: Vec<f64> = raw.iter().map(|v| v / peak * 0.5).collect();
            let freqs: Vec<f64> = bank.frequencies_hz.iter().map(|f| f.round()).collect();
            let target_seconds = t_target.elapsed().as_secs_f64();
            // The P1 discretisation bias: the E at which the P1 spectrum best matches the P2 one
            // (geometric mean of the eigenvalue ratios at the true ν); a P1 fit cannot beat it.
            let (theta1, _) =
                PoissonBasis::full_theta(&petsc, &models[0].asm, size, nu_true, n_modes).unwrap();
            let log_ratio = theta
                .iter()
                .zip(&theta1)
                .take(n_modes)
                .map(|(t2, t1)| (t2 / t1).ln())
                .sum::<f64>()
                / n_modes as f64;
            let e_p1_best = e_true * log_ratio.exp();
            eprintln!(
                "[{name} seed {seed} -> {oseed:#018x}] E {e_true:.4e} nu {nu_true:.4} start E0 {e0:.4e} (x{}) nu0 {nu0:.4}; target {:.1} s, freqs {:?}; P1 best E {e_p1_best:.4e}",
                if factor > 1.0 { "3" } else { "1/3" },
                target_seconds,
                freqs
            );
            objects.push(json!({"mesh": path, "name": name, "seed": seed, "object_seed": oseed, "youngs": e_true, "poisson": nu_true,
                "start_youngs": e0, "start_poisson": nu0, "target_frequencies_hz": bank.frequencies_hz, "target_seconds": target_seconds, "p1_best_youngs": e_p1_best}));
            let targets = vec![target];
            // The target's modes, found in its audio (as stage 1 would): the line-spectrum start.
            let t_estimate = Instant::now();
            let estimate =
                estimate_modes(&targets, SAMPLE_RATE, &EstimateOptions::default()).unwrap();
            let target_modes_hz: Vec<f64> = estimate.modes.iter().map(|m| m.frequency_hz).collect();
            let estimate_seconds = t_estimate.elapsed().as_secs_f64();
            let problem = MaterialProblem {
                targets: &targets,
                sample_rate: SAMPLE_RATE,
                density: RHO,
                damping: damping.clone(),
                strike,
                direction_weights: point.normal.to_vec(),
                max_frequency_hz: None,
                target_modes_hz,
            };
            if args.landscape {
                let mut basis = PoissonBasis::build(
                    &petsc,
                    &p2.asm,
                    size,
                    n_modes,
                    BASIS_MARGIN,
                    &BASIS_SAMPLES,
                    p2.probe.clone(),
                )
                .unwrap();
                landscape(
                    &petsc,
                    &p2.asm,
                    &mut basis,
                    &problem,
                    &base_settings,
                    &name,
                    seed,
                    (e_true, nu_true),
                    (e0, nu0),
                );
                continue;
            }
            for variant in &args.variants {
                let model = &models[if variant.order == Order::P1 { 0 } else { 1 }];
                let settings = MaterialFitSettings {
                    learn_poisson: variant.learn_poisson,
                    ..base_settings.clone()
                };
                let start = (e0, if variant.learn_poisson { nu0 } else { nu_true });
                let t0 = Instant::now();
                let mut basis = PoissonBasis::build(
                    &petsc,
                    &model.asm,
                    size,
                    n_modes,
                    BASIS_MARGIN,
                    &BASIS_SAMPLES,
                    model.probe.clone(),
                )
                .unwrap();
                let basis_seconds = t0.elapsed().as_secs_f64();
                let solves_before = basis.full_solves;
                let t1 = Instant::now();
                let mut last_print = Instant::now();
                let fit = fit_material(
                    &mut basis,
                    &problem,
                    start,
                    &settings,
                    |b, nu| {
                        b.refresh_if_needed(
                            &petsc,
                            &model.asm,
                            nu,
                            settings.residual_tolerance,
                            settings.min_sample_spacing,
                        )
                    },
                    |s: &FitStep| {
                        if last_print.elapsed().as_secs_f64() > 10.0 {
                            last_print = Instant::now();
                            eprintln!(
                                "    step {} {:?} loss {:.4e} E {:.5e} nu {:.5}",
                                s.step, s.phase, s.loss, s.youngs, s.poisson
                            );
                        }
                    },
                );
                let fit_seconds = t1.elapsed().as_secs_f64();
                let fit = match fit {
                    Ok(f) => f,
                    Err(e) => {
                        eprintln!("  {} FAILED: {e}", variant.name());
                        rows.push(json!({"mesh": name, "seed": seed, "object_seed": oseed, "variant": variant.name(), "error": e.to_string()}));
                        continue;
                    }
                };
                let rendered = render_channels(
                    &basis,
                    &problem,
                    fit.youngs,
                    fit.poisson,
                    &fit.log_gains,
                    None,
                )
                .unwrap();
                let spec_err = spectrogram_error(&rendered[0], &targets[0]).unwrap();
                // A full solve at the optimum against the reduced basis there.
                let reduced = basis.solve(fit.poisson);
                let (full, _) =
                    PoissonBasis::full_theta(&petsc, &model.asm, size, fit.poisson, n_modes)
                        .unwrap();
                let full_vs_reduced = reduced
                    .theta
                    .iter()
                    .zip(&full)
                    .map(|(r, f)| (r - f).abs() / f)
                    .fold(0.0, f64::max);
                let rel_e = (fit.youngs - e_true).abs() / e_true;
                let e_reference = if variant.order == Order::P1 {
                    e_p1_best
                } else {
                    e_true
                };
                let rel_e_reference = (fit.youngs - e_reference).abs() / e_reference;
                let rel_nu = (fit.poisson - nu_true).abs() / nu_true;
                let switch_loss = fit
                    .switched_at
                    .and_then(|s| fit.history.get(s))
                    .map(|h| h.loss);
                eprintln!(
                    "  {:<10} E {:.5e} ({:.2e}) nu {:.4} ({:.2e}) spec {:.3} | basis {:.1} s + fit {:.1} s, {} steps, switch {:?}, extra solves {}, full-vs-reduced {:.1e}",
                    variant.name(),
                    fit.youngs,
                    rel_e,
                    fit.poisson,
                    rel_nu,
                    spec_err,
                    basis_seconds,
                    fit_seconds,
                    fit.steps,
                    fit.switched_at,
                    basis.full_solves - solves_before,
                    full_vs_reduced
                );
                rows.push(json!({
                    "mesh": name, "seed": seed, "object_seed": oseed, "variant": variant.name(),
                    "youngs_true": e_true, "poisson_true": nu_true, "start_youngs": start.0, "start_poisson": start.1,
                    "youngs": fit.youngs, "poisson": fit.poisson, "rel_err_youngs": rel_e, "rel_err_poisson": rel_nu, "youngs_reference": e_reference, "rel_err_youngs_reference": rel_e_reference,
                    "spectrogram_error": spec_err, "basis_seconds": basis_seconds, "fit_seconds": fit_seconds,
                    "estimate_seconds": estimate_seconds, "object_seconds": estimate_seconds + basis_seconds + fit_seconds, "steps": fit.steps, "switched_at": fit.switched_at,
                    "switch_loss": switch_loss, "final_loss": fit.history.last().map(|h| h.loss),
                    "basis_samples": fit.basis_samples, "extra_full_solves": basis.full_solves - solves_before,
                    "basis_full_solve_seconds": basis.full_solve_seconds, "basis_dimensions": basis.dimensions(),
                    "max_residual": fit.max_residual, "full_vs_reduced_max_rel": full_vs_reduced, "log_gains": fit.log_gains,
                    "history": fit.history,
                }));
            }
        }
    }
    print_markdown(&args, &rows, &objects);
    if let Some(path) = &args.json {
        let doc = json!({
            "settings": {"seeds": args.seeds, "modes": n_modes, "rho": RHO, "alpha": ALPHA, "beta": BETA, "sample_rate": SAMPLE_RATE,
                "samples": N_SAMPLES, "basis_samples": BASIS_SAMPLES, "basis_margin": BASIS_MARGIN, "fit": base_settings,
                "spectrogram_error": "sum | |S_fit| - |S_target| | / sum |S_target|, STFT Hann n_fft 2048 hop 512"},
            "objects": objects, "fits": rows,
        });
        std::fs::write(path, serde_json::to_string_pretty(&doc).unwrap()).unwrap();
        eprintln!("wrote {path}");
    }
}

fn print_markdown(args: &Args, rows: &[serde_json::Value], objects: &[serde_json::Value]) {
    let f = |v: &serde_json::Value, k: &str| v[k].as_f64().unwrap_or(f64::NAN);
    println!("## Material-fit benchmark\n");
    println!("Seeds: {:?}; {} modes; ρ = {RHO}, α = {ALPHA}, β = {BETA}; target from a full P2 solve, {} samples at {} Hz.", args.seeds, args.modes, N_SAMPLES, SAMPLE_RATE);
    println!("Spectrogram error: Σ| |S_fit| − |S_tgt| | / Σ|S_tgt| (linear STFT magnitudes, Hann, n_fft 2048, hop 512).");
    println!("Time per object = mode estimate of the target (line-spectrum start) + basis build + fit (the full solve for the target and the check are not counted).");
    println!("rel E vs ref: for P1 against the P1 reference E (E·exp(mean ln θ_P2/θ_P1) at the true ν, the best a P1 model can do), for P2 against the true E.\n");
    println!("### Objects\n");
    println!("| mesh | seed | object seed | E true [Pa] | ν true | E₀ [Pa] | ν₀ | P1 ref E [Pa] | target f [Hz] |");
    println!("|---|---|---|---|---|---|---|---|---|");
    for o in objects {
        let fr: Vec<f64> = o["target_frequencies_hz"]
            .as_array()
            .map(|a| a.iter().filter_map(|v| v.as_f64()).collect())
            .unwrap_or_default();
        println!(
            "| {} | {} | {:#018x} | {:.4e} | {:.4} | {:.4e} | {:.4} | {:.4e} | {:.0}–{:.0} |",
            o["name"].as_str().unwrap(),
            o["seed"],
            o["object_seed"].as_u64().unwrap(),
            f(o, "youngs"),
            f(o, "poisson"),
            f(o, "start_youngs"),
            f(o, "start_poisson"),
            f(o, "p1_best_youngs"),
            fr.first().copied().unwrap_or(f64::NAN),
            fr.last().copied().unwrap_or(f64::NAN)
        );
    }
    println!("\n### Fits\n");
    println!("| mesh | seed | variant | E fit | rel E | rel E vs ref | ν fit | rel ν | spec err | basis s | fit s | steps | switch | +solves | full vs reduced |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for r in rows {
        if let Some(e) = r.get("error") {
            println!(
                "| {} | {} | {} | failed: {} ||||||||||||",
                r["mesh"].as_str().unwrap(),
                r["seed"],
                r["variant"].as_str().unwrap(),
                e
            );
            continue;
        }
        println!(
            "| {} | {} | {} | {:.4e} | {:.2e} | {:.2e} | {:.4} | {:.2e} | {:.3} | {:.1} | {:.1} | {} | {} | {} | {:.1e} |",
            r["mesh"].as_str().unwrap(),
            r["seed"],
            r["variant"].as_str().unwrap(),
            f(r, "youngs"),
            f(r, "rel_err_youngs"),
            f(r, "rel_err_youngs_reference"),
            f(r, "poisson"),
            f(r, "rel_err_poisson"),
            f(r, "spectrogram_error"),
            f(r, "basis_seconds"),
            f(r, "fit_seconds"),
            r["steps"],
            r["switched_at"].as_u64().map_or("–".to_string(), |v| v.to_string()),
            r["extra_full_solves"],
            f(r, "full_vs_reduced_max_rel")
        );
    }
    println!("\n### Summary (mean over objects)\n");
    println!("| variant | objects | E rel err | E rel err vs ref | ν rel err | spec err | time/object s | (basis + fit) s | E < 1% | ν < 5% | max full vs reduced |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for v in &args.variants {
        let ok: Vec<&serde_json::Value> = rows
            .iter()
            .filter(|r| r["variant"] == v.name() && r.get("error").is_none())
            .collect();
        let failed = rows
            .iter()
            .filter(|r| r["variant"] == v.name() && r.get("error").is_some())
            .count();
        if ok.is_empty() {
            println!("| {} | 0 ({failed} failed) |||||||||", v.name());
            continue;
        }
        let n = ok.len() as f64;
        let mean = |k: &str| ok.iter().map(|r| f(r, k)).sum::<f64>() / n;
        let count = |k: &str, tol: f64| ok.iter().filter(|r| f(r, k) < tol).count();
        let worst = ok
            .iter()
            .map(|r| f(r, "full_vs_reduced_max_rel"))
            .fold(0.0, f64::max);
        println!(
            "| {} | {}{} | {:.2e} | {:.2e} | {} | {:.3} | {:.1} | {:.1} + {:.1} | {}/{} | {} | {:.1e} |",
            v.name(),
            ok.len(),
            if failed > 0 { format!(" ({failed} failed)") } else { String::new() },
            mean("rel_err_youngs"),
            mean("rel_err_youngs_reference"),
            if v.learn_poisson { format!("{:.2e}", mean("rel_err_poisson")) } else { "(fixed)".into() },
            mean("spectrogram_error"),
            mean("object_seconds"),
            mean("basis_seconds"),
            mean("fit_seconds"),
            count("rel_err_youngs", 0.01),
            ok.len(),
            if v.learn_poisson { format!("{}/{}", count("rel_err_poisson", 0.05), ok.len()) } else { "–".into() },
            worst
        );
    }
}

/// `--landscape`: the fit's two losses along E (ν at the truth and at the start) for the P2
/// model, with the analytic dL/d ln E next to a central difference (h = 0.5 %), and the Ritz
/// residuals the fit's basis check sees. Markdown on stdout.
#[allow(clippy::too_many_arguments)]
fn landscape<'p>(
    petsc: &'p Petsc,
    asm: &Assembled<'p>,
    basis: &mut PoissonBasis<'p>,
    problem: &MaterialProblem,
    settings: &MaterialFitSettings,
    name: &str,
    seed: u64,
    truth: (f64, f64),
    start: (f64, f64),
) {
    use diffsound::audio::loss::{MultiScaleSpectralLoss, PeakTransportLoss};
    use diffsound::audio::synth::render_backward;
    let target = &problem.targets[0];
    let transport =
        PeakTransportLoss::new(target, problem.sample_rate, settings.transport.clone()).unwrap();
    let spectral = MultiScaleSpectralLoss::new(target, settings.spectral.clone()).unwrap();
    // (loss, dL/d ln E) at (E, ν, gain); `which`: 0 transport, 1 spectral.
    let eval = |which: usize, youngs: f64, nu: f64, log_gain: f64| -> (f64, f64) {
        let modes = basis.solve(nu);
        let eig = modes.eigenvalues(youngs, problem.density);
        let proj: Vec<f64> = (0..eig.len())
            .map(|k| {
                let p = basis.probe(&modes, k);
                let a: f64 = p
                    .iter()
                    .zip(&problem.direction_weights)
                    .map(|(v, w)| v * w)
                    .sum();
                a * a / problem.density * log_gain.exp()
            })
            .collect();
        let (bank, chain) =
            ModalChain::new(&eig, &proj, &problem.damping, &problem.strike).unwrap();
        let signal = render_samples(&bank, problem.sample_rate, target.len());
        let (value, g) = if which == 0 {
            transport.value_and_gradient(&signal)
        } else {
            spectral.value_and_gradient(&signal)
        }
        .unwrap();
        let cg = chain.backward(&render_backward(&bank, problem.sample_rate, &g));
        (
            value,
            cg.eigenvalues.iter().zip(&eig).map(|(g, l)| g * l).sum(),
        )
    };
    let rms_gain = |youngs: f64, nu: f64| {
        let r = render_channels(basis, problem, youngs, nu, &[0.0], None).unwrap();
        rms_matched_log_gains(&r, problem.targets)[0]
    };
    println!(
        "\n### Landscape: {name}, seed {seed}: E {:.4e}, ν {:.4}; start E₀/E = {:.3}, ν₀ = {:.4}\n",
        truth.0,
        truth.1,
        start.0 / truth.0,
        start.1
    );
    for r in [0.2, start.1, truth.1, 0.45] {
        let res = basis.residuals(asm, &basis.solve(r)).unwrap();
        println!(
            "Ritz residual at ν = {r:.4}: max {:.2e} (tolerance {:.0e}), per mode {:?}",
            res.iter().fold(0.0_f64, |m, v| m.max(*v)),
            settings.residual_tolerance,
            res.iter().map(|v| format!("{v:.1e}")).collect::<Vec<_>>()
        );
    }
    let h: f64 = 0.005;
    for nu in [truth.1, start.1] {
        // The transport phase holds the gain at the RMS match of the start.
        let gain0 = rms_gain(start.0, nu);
        println!("\nν = {nu:.4} (transport: gain held at the start's RMS match; spectral: gain RMS-matched at each E)\n");
        println!("| E/E_true | transport L | dL/dlnE | central diff | spectral L | dL/dlnE | central diff |");
        println!("|---|---|---|---|---|---|---|");
        let n = 41;
        for i in 0..n {
            let ratio = (-(4.0_f64.ln()) + 2.0 * 4.0_f64.ln() * i as f64 / (n - 1) as f64).exp();
            let e = truth.0 * ratio;
            let (lt, gt) = eval(0, e, nu, gain0);
            let fd_t = (eval(0, e * h.exp(), nu, gain0).0 - eval(0, e * (-h).exp(), nu, gain0).0)
                / (2.0 * h);
            let g = rms_gain(e, nu);
            let (ls, gs) = eval(1, e, nu, g);
            let fd_s =
                (eval(1, e * h.exp(), nu, g).0 - eval(1, e * (-h).exp(), nu, g).0) / (2.0 * h);
            println!("| {ratio:.3} | {lt:.4} | {gt:+.3e} | {fd_t:+.3e} | {ls:.4} | {gs:+.3e} | {fd_s:+.3e} |");
        }
    }
    // Does adding ν_true as a sample bring its residual below the tolerance?
    basis.add_sample(petsc, asm, truth.1).unwrap();
    let res = basis.residuals(asm, &basis.solve(truth.1)).unwrap();
    println!(
        "\nAfter adding ν = {:.4} as a sample: max Ritz residual there {:.2e}, per mode {:?}",
        truth.1,
        res.iter().fold(0.0_f64, |m, v| m.max(*v)),
        res.iter().map(|v| format!("{v:.1e}")).collect::<Vec<_>>()
    );
}
