//! Shape from eigenvalues (issue 7), tasks 1 and 2: for each shape (or pair) and each true
//! parameter, a target spectrum is rendered on a finer grid than the fit's, then the parameter is
//! fitted back ([`diffsound::inverse::shape`]). Prints markdown tables (per target: the answer,
//! its absolute error, the per-level answers, evaluations, time per evaluation split into
//! meshing / assembly / solve / gradient at each level, total seconds) and a per-shape summary;
//! `--json FILE` writes every fit with its history.
//!
//!   mpirun -np 2 target/release/examples/shape_benchmark thickness [--levels 20,28]
//!       [--target-cells 40] [--modes 8] [--seed 1] [--values 0.3,0.4,0.5,0.6,0.7]
//!       [--replicas K] [--extrapolate|--no-extrapolate] [--free-scale] [--straight-boundary] [--json FILE] SURFACE...
//!   mpirun -np 2 target/release/examples/shape_benchmark morph [--levels 16,22]
//!       [--target-cells 32] [--values 0,0.2,0.4,0.6,0.8,1] A.obj:B.obj...
//!
//! Shapes are centred and scaled to a 0.1 m bounding-box diagonal ([`normalise_surface`]);
//! ceramic (E, ν, ρ known). The seed draws, per target, a random shift of the target grid by up
//! to half a cell along each axis, so that the target's grid is never nested in a fit grid (20
//! and 40 cells over the same box would share every coarse vertex). The fit knows the target's
//! grid spacing (the extrapolation in h needs it; for a measured object it is 0) but not the
//! true parameter. The thickness reference S (deepest point of the surface) is computed once
//! per surface and used by target and fit alike.
//!
//! `--replicas K` fits the finest level (when the answer is the finest level's: the curved
//! thickness body's default) or every level after the first (when the answer is the line) on K
//! grids of its spacing, moved by r/K of a cell along the diagonal (r = 0 … K−1,
//! [`replica_shift`]), each replica a level of its own (starting from the previous one's
//! answer); the finest level's answer is the mean of its K grids', and the line in h goes
//! through every replica of the finest three spacings: the grids' alignment noise averages
//! over the replicas instead of riding on one alignment per spacing (module docs of
//! `diffsound::inverse::shape`, "Grid bias").
use diffsound::fem::Material;
use diffsound::inverse::shape::{
    answers_with_line, fit_morph, fit_thickness, replica_levels, replica_line_levels,
    replica_shift, FitEvaluation, ShapeFamily, ShapeFit, ShapeFitSettings, SpectrumTarget,
};
use diffsound::petsc::Petsc;
use diffsound::random::SplitMix64;
use diffsound::shape::{normalise_surface, read_surface, reference_depth, union_box, SampledField};
use diffsound::shape::{BackgroundGrid, MarchingOptions, SignedDistance, TriangleSurface};
use std::sync::Arc;
use std::time::Instant;

struct Args {
    task: String,
    levels: Vec<usize>,
    replicas: usize,
    target_cells: usize,
    modes: usize,
    seed: u64,
    values: Vec<f64>,
    /// None: the family's default (ShapeFamily::extrapolates_by_default).
    extrapolate: Option<bool>,
    free_scale: bool,
    straight_boundary: bool,
    json: Option<String>,
    inputs: Vec<String>,
}

fn usage() -> ! {
    eprintln!("usage: shape_benchmark thickness|morph [--levels N,N] [--target-cells N] [--modes N] [--seed S] [--values a,b,..] [--replicas K] [--extrapolate|--no-extrapolate] [--free-scale] [--straight-boundary] [--json FILE] SURFACE... | A:B...");
    std::process::exit(2)
}

fn parse_args() -> Args {
    let mut it = std::env::args().skip(1);
    let task = it.next().unwrap_or_else(|| usage());
    let morph = match task.as_str() {
        "thickness" => false,
        "morph" => true,
        _ => usage(),
    };
    let mut a = Args {
        task,
        levels: if morph { vec![16, 22] } else { vec![20, 28] },
        replicas: 1,
        target_cells: if morph { 32 } else { 40 },
        modes: 8,
        seed: 1,
        values: if morph {
            vec![0.0, 0.2, 0.4, 0.6, 0.8, 1.0]
        } else {
            vec![0.3, 0.4, 0.5, 0.6, 0.7]
        },
        extrapolate: None,
        free_scale: false,
        straight_boundary: false,
        json: None,
        inputs: Vec::new(),
    };
    let list = |s: String| -> Vec<f64> {
        s.split(',')
            .map(|v| v.parse().unwrap_or_else(|_| usage()))
            .collect()
    };
    while let Some(x) = it.next() {
        let mut value = || it.next().unwrap_or_else(|| usage());
        match x.as_str() {
            "--levels" => a.levels = list(value()).into_iter().map(|v| v as usize).collect(),
            "--target-cells" => a.target_cells = value().parse().unwrap_or_else(|_| usage()),
            "--modes" => a.modes = value().parse().unwrap_or_else(|_| usage()),
            "--seed" => a.seed = value().parse().unwrap_or_else(|_| usage()),
            "--values" => a.values = list(value()),
            "--replicas" => {
                a.replicas = value()
                    .parse()
                    .ok()
                    .filter(|&k| (1..=4).contains(&k))
                    .unwrap_or_else(|| usage())
            }
            "--no-extrapolate" => a.extrapolate = Some(false),
            "--extrapolate" => a.extrapolate = Some(true),
            "--free-scale" => a.free_scale = true,
            "--straight-boundary" => a.straight_boundary = true,
            "--json" => a.json = Some(value()),
            _ if x.starts_with("--") => usage(),
            _ => a.inputs.push(x),
        }
    }
    // A level as fine as the target is allowed: on its unshifted grid it measures the floor
    // that the target grid's alignment alone sets (same spacing, different vertices).
    if a.inputs.is_empty() || a.levels.is_empty() || a.levels.iter().any(|&l| l > a.target_cells) {
        eprintln!("need inputs, and no fit level finer than --target-cells");
        usage();
    }
    a
}

fn load(path: &str) -> (String, TriangleSurface, SignedDistance) {
    let name = std::path::Path::new(path)
        .file_stem()
        .map(|s| s.to_string_lossy().trim_end_matches("_surf").to_string())
        .unwrap_or_default();
    let (mut surface, _) =
        read_surface(std::path::Path::new(path)).unwrap_or_else(|e| panic!("{path}: {e}"));
    normalise_surface(&mut surface, 0.1).unwrap_or_else(|e| panic!("{path}: {e}"));
    let sdf = SignedDistance::new(&surface).unwrap_or_else(|e| panic!("{path}: {e}"));
    (name, surface, sdf)
}

/// The target's grid: `cells` along the longest axis of [lo, hi] with one cell of margin,
/// shifted by a random fraction (up to ±½) of a cell along each axis.
fn shifted_grid(lo: [f64; 3], hi: [f64; 3], cells: usize, rng: &mut SplitMix64) -> BackgroundGrid {
    let base = BackgroundGrid::covering(lo, hi, cells, 1.0).expect("grid");
    let h = base.spacing();
    let origin = [0, 1, 2].map(|d| base.origin()[d] + rng.uniform(-0.5, 0.5) * h[d]);
    BackgroundGrid::new(origin, h, base.cells()).expect("grid")
}

/// One shape's summary row: name, fit errors, finest-level-alone errors, line errors, fit
/// seconds.
type SummaryRow = (String, Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>);

/// The shape family on a (target, optional second) sampled field.
type FamilyAt = Box<dyn Fn(&SampledField, Option<&SampledField>) -> ShapeFamily>;

fn main() {
    let args = parse_args();
    let universe = mpi::initialize().expect("MPI");
    let petsc = Petsc::initialize(universe, "shape_benchmark", &[]).expect("PETSc");
    let root = petsc.rank() == 0;
    let material = Material::preset("ceramic").expect("preset");
    let options = MarchingOptions::default();
    let morph = args.task == "morph";
    let mut settings = if morph {
        ShapeFitSettings::morph()
    } else {
        ShapeFitSettings::default()
    };
    settings.modes = args.modes;
    settings.extrapolate = args.extrapolate;
    settings.free_scale = args.free_scale;
    // The finest level (answer from the finest level) or every level after the first (answer
    // from the line) on `replicas` grids: (cells, replica).
    let every_level = answers_with_line(args.extrapolate, !morph && !args.straight_boundary);
    let fit_levels = replica_levels(&args.levels, args.replicas, every_level);
    settings.extrapolation_levels =
        replica_line_levels(settings.extrapolation_levels, args.replicas, every_level);
    let level_name = |&(c, r): &(usize, usize)| {
        if r == 0 {
            format!("@{c}")
        } else {
            format!("@{c}~{r}")
        }
    };
    let name_p = if morph { "c" } else { "t" };
    if root {
        println!(
            "## {} benchmark\n\nseed {}, {} modes, fit levels {:?} cells ({} grid replica(s) {}), target grid {} cells (randomly shifted), {} rank(s), ceramic, shapes scaled to a 0.1 m diagonal, extrapolation in h {}, free stiffness scale {}, thickness boundary {}.\n",
            if morph { "Morph" } else { "Thickness" },
            args.seed,
            args.modes,
            args.levels,
            args.replicas,
            if every_level { "per level after the first" } else { "of the finest level" },
            args.target_cells,
            petsc.size(),
            match args.extrapolate { Some(true) => "on", Some(false) => "off", None => "the family's default (off for the curved thickness, else on)" },
            if args.free_scale { "on" } else { "off" },
            if args.straight_boundary { "straight (samples alone)" } else { "curved (exact crossings, curved P2 edges)" }
        );
        let per_level: String = fit_levels
            .iter()
            .map(|l| format!(" {name_p} {} |", level_name(l)))
            .collect();
        let timing: String = fit_levels
            .iter()
            .map(|l| {
                format!(
                    " s/eval {0} (mesh/asm/solve/grad) | evals {0} |",
                    level_name(l)
                )
            })
            .collect();
        println!("| shape | {name_p}* | {name_p} fit | abs err |{per_level} final-level abs err | line abs err |{timing} target s | fit s |");
        println!(
            "|---|---|---|---|{}---|---|{}---|---|",
            "---|".repeat(fit_levels.len()),
            "---|---|".repeat(fit_levels.len())
        );
    }
    let mut rng = SplitMix64::new(args.seed);
    let mut records = Vec::new();
    let mut summary: Vec<SummaryRow> = Vec::new();
    for input in &args.inputs {
        // One shape (thickness) or a pair A:B (morph) on common grids.
        let (name, family_at, lo, hi): (String, FamilyAt, [f64; 3], [f64; 3]);
        let sampled: Vec<(SampledField, Option<SampledField>)>;
        let sdfs: Vec<Arc<SignedDistance>>;
        if morph {
            let (pa, pb) = input
                .split_once(':')
                .unwrap_or_else(|| panic!("morph inputs are A.obj:B.obj, got {input}"));
            let (na, sa, da) = load(pa);
            let (nb, sb, db) = load(pb);
            (lo, hi) = union_box(&[&sa, &sb]);
            name = format!("{na}/{nb}");
            sampled = fit_levels
                .iter()
                .map(|&(n, r)| {
                    (
                        SampledField::of_sdf_shifted(
                            &da,
                            lo,
                            hi,
                            n,
                            replica_shift(r, args.replicas),
                        )
                        .expect("field"),
                        Some(
                            SampledField::of_sdf_shifted(
                                &db,
                                lo,
                                hi,
                                n,
                                replica_shift(r, args.replicas),
                            )
                            .expect("field"),
                        ),
                    )
                })
                .collect();
            family_at = Box::new(|a, b| ShapeFamily::Morph {
                a: a.values.clone(),
                b: b.expect("pair").values.clone(),
            });
            sdfs = vec![Arc::new(da), Arc::new(db)];
        } else {
            let (n, s, d) = load(input);
            (lo, hi) = s.bounding_box();
            let depth = reference_depth(&d, &s).expect("reference depth");
            if root {
                eprintln!("{n}: reference depth S = {:.5} mm", 1e3 * depth);
            }
            name = n;
            sampled = fit_levels
                .iter()
                .map(|&(c, r)| {
                    (
                        SampledField::of_sdf_shifted(
                            &d,
                            lo,
                            hi,
                            c,
                            replica_shift(r, args.replicas),
                        )
                        .expect("field"),
                        None,
                    )
                })
                .collect();
            let d = Arc::new(d);
            let surface = (!args.straight_boundary).then(|| Arc::clone(&d));
            family_at = Box::new(move |a, _| ShapeFamily::Thickness {
                solid: a.values.clone(),
                depth,
                surface: surface.clone(),
            });
            sdfs = vec![d];
        }
        let (mut errors, mut finest_errors, mut line_errors, mut seconds) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for &truth in &args.values {
            // The target: the true parameter on a finer, randomly shifted grid.
            let clock = Instant::now();
            let grid = shifted_grid(lo, hi, args.target_cells, &mut rng);
            let positions = grid.vertex_positions();
            let fields: Vec<SampledField> = sdfs
                .iter()
                .map(|d| SampledField {
                    grid: grid.clone(),
                    values: d.evaluate(&positions),
                })
                .collect();
            let family = family_at(&fields[0], fields.get(1));
            let target_spectrum = family
                .spectrum(&petsc, &grid, truth, &options, &material, args.modes, false)
                .map(|(s, _)| s);
            let target_seconds = clock.elapsed().as_secs_f64();
            let target = match target_spectrum
                .and_then(|t| SpectrumTarget::new(t.eigenvalues, settings.cluster_rtol))
            {
                Ok(t) => t,
                Err(e) => {
                    if root {
                        println!("| {name} | {truth} | target failed: {e} |");
                    }
                    continue;
                }
            };
            let on_eval = |e: &FitEvaluation| {
                if root {
                    match &e.failure {
                        None => eprintln!("[{name} {name_p}*={truth}] level {} ({} cells) {:?} {name_p} {:.5} loss {:.4e} dL/d{name_p} {:+.3e} ({} tets, {:.1} s)", e.level, e.cells, e.phase, e.parameter, e.loss, e.gradient, e.tets, e.timings.total()),
                        Some(f) => eprintln!("[{name} {name_p}*={truth}] level {} ({} cells) {:?} {name_p} {:.5} failed: {f}", e.level, e.cells, e.phase, e.parameter),
                    }
                }
            };
            let h_target = grid.spacing()[0];
            let fit: Result<ShapeFit, _> = if morph {
                let pairs: Vec<(SampledField, SampledField)> = sampled
                    .iter()
                    .map(|(a, b)| (a.clone(), b.clone().expect("pair")))
                    .collect();
                fit_morph(
                    &petsc,
                    &pairs,
                    &target,
                    &options,
                    &material,
                    &settings,
                    Some(h_target),
                    on_eval,
                )
            } else {
                let solids: Vec<SampledField> = sampled.iter().map(|(a, _)| a.clone()).collect();
                let ShapeFamily::Thickness { depth, surface, .. } = family_at(&solids[0], None)
                else {
                    unreachable!()
                };
                fit_thickness(
                    &petsc,
                    &solids,
                    depth,
                    surface,
                    &target,
                    &options,
                    &material,
                    &settings,
                    Some(h_target),
                    on_eval,
                )
            };
            let fit = match fit {
                Ok(f) => f,
                Err(e) => {
                    if root {
                        println!("| {name} | {truth} | fit failed: {e} |");
                    }
                    continue;
                }
            };
            let err = (fit.parameter - truth).abs();
            let finest = (fit.finest_parameter() - truth).abs();
            let line = fit.extrapolated.map_or(f64::NAN, |e| (e - truth).abs());
            errors.push(err);
            finest_errors.push(finest);
            line_errors.push(line);
            seconds.push(fit.seconds);
            if root {
                let per_level: String = fit
                    .levels
                    .iter()
                    .map(|l| format!(" {:.4} |", l.parameter))
                    .collect();
                let timing: String = (0..fit.levels.len())
                    .map(|i| {
                        let t = fit.mean_timings(i);
                        format!(
                            " {:.1} ({:.2}/{:.2}/{:.1}/{:.2}) | {} |",
                            t.total(),
                            t.meshing,
                            t.assembly,
                            t.solve,
                            t.gradient,
                            fit.levels[i].evaluations
                        )
                    })
                    .collect();
                println!("| {name} | {truth} | {:.4} | {err:.4} |{per_level} {finest:.4} | {line:.4} |{timing} {target_seconds:.0} | {:.0} |", fit.parameter, fit.seconds);
            }
            records.push(serde_json::json!({ "shape": name, "truth": truth, "target_spacing": h_target, "target_eigenvalues": target.eigenvalues, "fit": fit }));
        }
        summary.push((name, errors, finest_errors, line_errors, seconds));
    }
    if root {
        println!("\n| shape | mean abs error | max abs error | mean abs error, finest level alone | mean abs error, line | mean fit s | max fit s |\n|---|---|---|---|---|---|---|");
        for (name, e, f, l, s) in &summary {
            let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
            let max = |v: &[f64]| v.iter().cloned().fold(0.0, f64::max);
            println!(
                "| {name} | {:.4} | {:.4} | {:.4} | {:.4} | {:.0} | {:.0} |",
                mean(e),
                max(e),
                mean(f),
                mean(l),
                mean(s),
                max(s)
            );
        }
        if let Some(path) = &args.json {
            std::fs::write(path, serde_json::to_string_pretty(&records).expect("json"))
                .unwrap_or_else(|e| panic!("{path}: {e}"));
            eprintln!("wrote {path}");
        }
    }
}
