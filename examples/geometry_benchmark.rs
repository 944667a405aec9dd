//! Geometry from a coarse voxel constraint (issue 7, task 3): for each surface and each voxel
//! resolution, an MLP signed distance is pre-fitted to the voxels and refined by the first N
//! eigenvalues of the true shape (rendered on a finer, randomly shifted grid), with the voxel
//! signs as a constraint ([`diffsound::inverse::geometry`]). Prints markdown tables: shape
//! distance to the true surface (Chamfer, Hausdorff, volume IoU) and the rms frequency error
//! before and after refinement, next to the voxels' own staircase and the floor (the true signed
//! distance marched on the same fit grid); the time per step split into meshing / assembly /
//! eigen-solve / gradient (chain dλ/ds) / network (MLP forward and backpropagation); totals.
//!
//!   mpirun -np 2 target/release/examples/geometry_benchmark [--voxels 16,8] [--cells 20]
//!       [--target-cells 32] [--modes 12] [--steps 30] [--seed 1] [--lr 1e-3]
//!       [--voxel-weight 1] [--eikonal-weight 0.1] [--prefit-steps 1000] [--max-field-change 0.2]
//!       [--method gauss_newton|adam] [--damping 1e-3] [--no-bias-correction] [--free-scale] [--straight-boundary] [--no-target-grid-check] [--step-metrics] [--out-dir DIR] SURFACE...
//!
//! Shapes are centred and scaled to a 0.1 m bounding-box diagonal; ceramic. The seed sets the
//! target grid's shift, the network's initialisation, the pre-fit batches and the eikonal
//! points. With --out-dir, one PNG per case (voxels / before / after / true) and `results.json`.
use diffsound::fem::Material;
use diffsound::inverse::geometry::{
    assess, eigenvalue_loss, fit_geometry, GeometryProgress, GeometrySettings,
};
use diffsound::petsc::Petsc;
use diffsound::workflow::fit_geometry::{load_surface, step_line, write::render_comparison};

struct Args {
    voxels: Vec<usize>,
    settings: GeometrySettings,
    out_dir: Option<std::path::PathBuf>,
    inputs: Vec<String>,
    verbose: bool,
    step_metrics: bool,
}

fn usage() -> ! {
    eprintln!("usage: geometry_benchmark [--voxels 16,8] [--cells N] [--target-cells N] [--modes N] [--steps N] [--seed S] [--lr X] [--voxel-weight X] [--eikonal-weight X] [--prefit-steps N] [--max-field-change X] [--method adam|gauss_newton] [--damping X] [--no-bias-correction] [--free-scale] [--straight-boundary] [--no-target-grid-check] [--step-metrics] [--out-dir DIR] [-v] SURFACE...");
    std::process::exit(2)
}

fn parse_args() -> Args {
    let mut a = Args {
        voxels: vec![16, 8],
        settings: GeometrySettings::default(),
        out_dir: None,
        inputs: Vec::new(),
        verbose: false,
        step_metrics: false,
    };
    let mut it = std::env::args().skip(1);
    fn num<T: std::str::FromStr>(v: Option<String>) -> T {
        v.and_then(|v| v.parse().ok()).unwrap_or_else(|| usage())
    }
    while let Some(x) = it.next() {
        let s = &mut a.settings;
        match x.as_str() {
            "--voxels" => {
                a.voxels = it
                    .next()
                    .unwrap_or_else(|| usage())
                    .split(',')
                    .map(|v| v.parse().unwrap_or_else(|_| usage()))
                    .collect()
            }
            "--cells" => s.cells = num(it.next()),
            "--target-cells" => s.target_cells = num(it.next()),
            "--modes" => s.modes = num(it.next()),
            "--steps" => s.refine.steps = num(it.next()),
            "--lr" => s.refine.learning_rate = num(it.next()),
            "--voxel-weight" => s.refine.voxel_weight = num(it.next()),
            "--eikonal-weight" => s.refine.eikonal_weight = num(it.next()),
            "--prefit-steps" => s.prefit.steps = num(it.next()),
            "--max-field-change" => s.refine.max_field_change = num(it.next()),
            "--method" => s.refine.method = num(it.next()),
            "--no-bias-correction" => s.bias_correction = false,
            "--damping" => s.refine.damping = num(it.next()),
            "--free-scale" => s.refine.free_scale = true,
            "--straight-boundary" => s.refine.curved_boundary = false,
            "--no-target-grid-check" => s.target_grid_check = false,
            "--step-metrics" => a.step_metrics = true,
            "--seed" => {
                let seed: u64 = num(it.next());
                (s.target_seed, s.network_seed, s.prefit.seed, s.refine.seed) =
                    (seed, seed, seed, seed);
            }
            "--out-dir" => a.out_dir = Some(it.next().unwrap_or_else(|| usage()).into()),
            "-v" => a.verbose = true,
            _ if x.starts_with('-') => usage(),
            _ => a.inputs.push(x),
        }
    }
    if a.inputs.is_empty() || a.voxels.is_empty() {
        usage();
    }
    a
}

fn main() {
    let args = parse_args();
    let universe = mpi::initialize().expect("MPI");
    let petsc = Petsc::initialize(universe, "geometry_benchmark", &[]).expect("PETSc");
    let root = petsc.rank() == 0;
    let material = Material::preset("ceramic").expect("preset");
    let s = &args.settings;
    if root {
        println!("## Geometry from a coarse voxel constraint\n");
        println!(
            "seed {}, {} modes, fit grid {} cells, target grid {} cells (randomly shifted), {} refinement steps ({}, step cap {} cells, grid-bias correction {}, free scale {}), {} boundary, voxel weight {}, eikonal weight {}, pre-fit {} updates, MLP {:?} with {} octaves, {} rank(s), ceramic, shapes scaled to a 0.1 m diagonal. Distances in mm against the true surface; rms relative frequency error of the N modes against the target.\n",
            s.target_seed, s.modes, s.cells, s.target_cells, s.refine.steps, match s.refine.method { diffsound::inverse::geometry::RefineMethod::Adam => format!("Adam lr {}", s.refine.learning_rate), diffsound::inverse::geometry::RefineMethod::GaussNewton => format!("minimum-norm Gauss–Newton, damping {}", s.refine.damping) }, s.refine.max_field_change, if s.bias_correction { "on" } else { "off" }, if s.refine.free_scale { "on" } else { "off" }, if s.refine.curved_boundary { "curved (crossings and boundary mid-edge nodes on the field's zero)" } else { "straight" }, s.refine.voxel_weight, s.refine.eikonal_weight, s.prefit.steps, s.hidden, s.octaves, petsc.size()
        );
        println!("| shape | voxels | Chamfer vox / before / after / floor | Hausdorff vox / before / after / floor | IoU vox / before / after / floor | freq err before / after / floor | eigen loss before → after | best step |");
        println!("|---|---|---|---|---|---|---|---|");
    }
    let mut timing_rows = Vec::new();
    let mut records = Vec::new();
    for input in &args.inputs {
        let name = std::path::Path::new(input)
            .file_stem()
            .map(|s| s.to_string_lossy().trim_end_matches("_surf").to_string())
            .unwrap_or_default();
        let (truth, sdf, _) = load_surface(std::path::Path::new(input), 1.0, Some(0.1))
            .unwrap_or_else(|e| panic!("{e}"));
        for &n in &args.voxels {
            let mut settings = args.settings.clone();
            settings.voxels = n;
            let fit = fit_geometry(&petsc, &truth, &sdf, &material, &settings, |p| {
                if root && args.verbose {
                    match p {
                        GeometryProgress::Message(m) => eprintln!("{name} {n}³: {m}"),
                        GeometryProgress::Step(st) => eprintln!("{name} {n}³: {}", step_line(st)),
                    }
                }
            });
            let fit = match fit {
                Ok(f) => f,
                Err(e) => {
                    if root {
                        println!("| {name} | {n}³ | failed: {e} | | | | | |");
                    }
                    continue;
                }
            };
            // Every evaluation's body against the truth: how the loss the fit lowers relates to
            // the shape. Diagnostics only (the fit never sees it).
            let mut step_rows = Vec::new();
            if args.step_metrics && root {
                for st in fit
                    .refinement
                    .history
                    .iter()
                    .filter(|st| st.failure.is_none())
                {
                    let net = diffsound::shape::neural_sdf::NeuralSdf::from_parameters(
                        fit.network.clone(),
                        st.parameters.clone(),
                    )
                    .expect("network");
                    let field = |x: [f64; 3]| net.value(x);
                    let curved: Option<&dyn Fn([f64; 3]) -> f64> =
                        if settings.refine.curved_boundary {
                            Some(&field)
                        } else {
                            None
                        };
                    if let Ok(assessed) = assess(
                        &fit.grid,
                        &net.values(&fit.grid.vertex_positions()),
                        curved,
                        Vec::new(),
                        &truth,
                        &settings,
                    ) {
                        let c = assessed.comparison;
                        let mark = if st.step == fit.refinement.best().step {
                            " answer"
                        } else {
                            ""
                        };
                        eprintln!("{name} {n}³ step {:2}: loss {:.3e} eigen {:.3e} | Chamfer {:.3} mm IoU {:.4}{mark}", st.step, st.loss, st.eigen_loss, 1e3 * c.chamfer, c.iou);
                        step_rows.push(serde_json::json!({"step": st.step, "loss": st.loss, "eigen_loss": st.eigen_loss, "chamfer": c.chamfer, "hausdorff": c.hausdorff, "iou": c.iou}));
                    }
                }
            }
            if !root {
                continue;
            }
            let mm = 1e3;
            let (v, b, a, f) = (
                &fit.voxel_comparison,
                &fit.before.comparison,
                &fit.after.comparison,
                &fit.floor.comparison,
            );
            let loss = |e: &[f64]| {
                eigenvalue_loss(e, &fit.target)
                    .map(|(l, _)| l)
                    .unwrap_or(f64::NAN)
            };
            println!(
                "| {name} | {n}³ | {:.2} / {:.2} / {:.2} / {:.2} | {:.2} / {:.2} / {:.2} / {:.2} | {:.3} / {:.3} / {:.3} / {:.3} | {:.2} % / {:.2} % / {:.2} % | {:.2e} → {:.2e} | {} of {} |",
                mm * v.chamfer, mm * b.chamfer, mm * a.chamfer, mm * f.chamfer,
                mm * v.hausdorff, mm * b.hausdorff, mm * a.hausdorff, mm * f.hausdorff,
                v.iou, b.iou, a.iou, f.iou,
                100.0 * fit.before.rms_frequency_error(&fit.target), 100.0 * fit.after.rms_frequency_error(&fit.target), 100.0 * fit.floor.rms_frequency_error(&fit.target),
                loss(&fit.before.eigenvalues), loss(&fit.after.eigenvalues),
                fit.refinement.best_step, fit.refinement.history.len() - 1
            );
            let (mean, network) = fit.refinement.mean_timings();
            let tets = fit
                .refinement
                .history
                .iter()
                .filter(|s| s.failure.is_none())
                .map(|s| s.tets)
                .sum::<usize>()
                / fit
                    .refinement
                    .history
                    .iter()
                    .filter(|s| s.failure.is_none())
                    .count()
                    .max(1);
            let failed = fit
                .refinement
                .history
                .iter()
                .filter(|s| s.failure.is_some())
                .count();
            timing_rows.push(format!(
                "| {name} | {n}³ | {} | {tets} | {:.2} / {:.2} / {:.2} / {:.2} / {:.2} | {:.2} | {failed} | {:.1} | {:.1} | {:.1} | {:.1} |",
                settings.cells, mean.meshing, mean.assembly, mean.solve, mean.gradient, network, mean.total() + network, fit.timings.prefit, fit.timings.target, fit.timings.refine, fit.timings.total
            ));
            if let Some(dir) = &args.out_dir {
                let png = dir.join(format!("{name}_vox{n}.png"));
                if let Err(e) = render_comparison(&png, &fit, &truth, &format!("{name}: {n}^3 voxels -> pre-fit (before) -> refined by {} eigenvalues (after); C = Chamfer distance", settings.modes)) {
                    eprintln!("{}: {e}", png.display());
                }
            }
            records.push(serde_json::json!({
                "shape": name, "voxels": n, "settings": settings,
                "metrics": {
                    "voxels": v, "before": b, "after": a, "floor": f,
                    "rms_frequency_error": {"before": fit.before.rms_frequency_error(&fit.target), "after": fit.after.rms_frequency_error(&fit.target), "floor": fit.floor.rms_frequency_error(&fit.target)},
                },
                "target_eigenvalues": fit.target.eigenvalues, "before_eigenvalues": fit.before.eigenvalues, "after_eigenvalues": fit.after.eigenvalues, "floor_eigenvalues": fit.floor.eigenvalues,
                "prefit": fit.prefit, "history": fit.refinement.history, "best_step": fit.refinement.best_step, "step_metrics": step_rows, "target_grid_check": fit.check, "bias_correction": fit.bias_correction,
                "timings": fit.timings, "n_ranks": petsc.size(),
            }));
        }
    }
    if root {
        println!("\n### Time per refinement step (mean over evaluations), seconds\n");
        println!("| shape | voxels | fit cells | tets | mesh / assembly / solve / gradient / network | step total | failed steps | pre-fit | target | refinement | task total |");
        println!("|---|---|---|---|---|---|---|---|---|---|---|");
        for r in &timing_rows {
            println!("{r}");
        }
        if let Some(dir) = &args.out_dir {
            let path = dir.join(format!("results_np{}.json", petsc.size()));
            std::fs::write(&path, serde_json::to_string_pretty(&records).expect("json"))
                .unwrap_or_else(|e| eprintln!("{}: {e}", path.display()));
        }
    }
}
