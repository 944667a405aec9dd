//! Thickness from eigenvalues (issue 7, task 1): for each surface and each target thickness t*,
//! the target spectrum comes from the hollow body at a finer grid, and the fit starts from a
//! seeded random t₀ ∈ [0.3, 0.7] on a coarser grid. Prints a markdown table (absolute error of t,
//! iterations, time per step split into meshing / assembly / solve / gradient) and a summary.
//!
//!   mpirun -np 2 target/release/examples/thickness_benchmark [--fit-cells 16] [--target-cells 24]
//!       [--modes 8] [--seed 1] [--thickness 0.3,0.4,0.5,0.6,0.7] SURFACE.obj...
//!
//! Material: ceramic preset (E, ν, ρ known; only t is fitted). Surfaces are scaled to a 0.1 m
//! bounding-box diagonal so every shape has the same frequency range.
use diffsound::diagnose::inject::SplitMix64;
use diffsound::fem::Material;
use diffsound::inverse::shape::{fit_thickness, shape_spectrum, ThicknessFitSettings};
use diffsound::mesh::{self, BackgroundGrid, MarchingOptions, SignedDistance, TriangleSurface};
use diffsound::petsc::Petsc;
use std::time::Instant;

struct Args {
    fit_cells: usize,
    target_cells: usize,
    modes: usize,
    seed: u64,
    thickness: Vec<f64>,
    surfaces: Vec<String>,
}

fn parse_args() -> Args {
    let mut a = Args { fit_cells: 16, target_cells: 24, modes: 8, seed: 1, thickness: vec![0.3, 0.4, 0.5, 0.6, 0.7], surfaces: Vec::new() };
    let mut it = std::env::args().skip(1);
    while let Some(x) = it.next() {
        let mut value = || it.next().unwrap_or_else(|| panic!("{x} needs a value"));
        match x.as_str() {
            "--fit-cells" => a.fit_cells = value().parse().expect("--fit-cells N"),
            "--target-cells" => a.target_cells = value().parse().expect("--target-cells N"),
            "--modes" => a.modes = value().parse().expect("--modes N"),
            "--seed" => a.seed = value().parse().expect("--seed N"),
            "--thickness" => a.thickness = value().split(',').map(|v| v.parse().expect("--thickness a,b,c")).collect(),
            _ => a.surfaces.push(x),
        }
    }
    assert!(!a.surfaces.is_empty(), "usage: thickness_benchmark [--fit-cells N] [--target-cells N] [--modes N] [--seed S] [--thickness a,b] SURFACE.obj...");
    a
}

/// The field of `sdf` (the scaled surface's signed distance) on a grid of `cells` over its box.
fn field(sdf: &SignedDistance, surface: &TriangleSurface, cells: usize) -> (BackgroundGrid, Vec<f64>) {
    let (lo, hi) = surface.bounding_box();
    let grid = BackgroundGrid::covering(lo, hi, cells, 1.0).expect("grid");
    let values = sdf.evaluate(&grid.vertex_positions());
    (grid, values)
}

fn main() {
    let args = parse_args();
    let universe = mpi::initialize().unwrap();
    let petsc = Petsc::initialize(universe, "thickness_benchmark", &[]).unwrap();
    let root = petsc.rank() == 0;
    let material = Material::preset("ceramic").unwrap();
    let options = MarchingOptions::default();
    let settings = ThicknessFitSettings { modes: args.modes, ..Default::default() };
    let mut rng = SplitMix64::new(args.seed);
    if root {
        println!("## Thickness benchmark\n\nseed {}, {} modes, fit grid {} cells, target grid {} cells (longest axis), {} rank(s), ceramic, surfaces scaled to a 0.1 m diagonal.\n", args.seed, args.modes, args.fit_cells, args.target_cells, petsc.size());
        println!("| shape | t* | t₀ | t fit | abs err | iterations | evals | tets (fit) | mesh s/step | assembly s/step | solve s/step | gradient s/step | total s |");
        println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    }
    let mut per_shape = Vec::new();
    for path in &args.surfaces {
        let name = std::path::Path::new(path).file_stem().unwrap().to_string_lossy().to_string();
        let read = mesh::read_obj(std::path::Path::new(path)).unwrap_or_else(|e| panic!("{e}"));
        let mut surface = read.surface;
        let (lo, hi) = surface.bounding_box();
        let diag = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
        let centre = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2])];
        for v in &mut surface.vertices {
            for d in 0..3 {
                v[d] = (v[d] - centre[d]) * 0.1 / diag;
            }
        }
        let sdf = SignedDistance::new(&surface).expect("signed distance");
        let (fine_grid, fine) = field(&sdf, &surface, args.target_cells);
        let (grid, coarse) = field(&sdf, &surface, args.fit_cells);
        let mut errors = Vec::new();
        for &t_true in &args.thickness {
            let shell = mesh::shell(&fine, t_true).unwrap();
            let target = shape_spectrum(&petsc, &fine_grid, &shell.values, &options, &material, args.modes, false).unwrap();
            let t0 = rng.uniform(0.3, 0.7);
            let clock = Instant::now();
            let fit = fit_thickness(&petsc, &grid, &coarse, &target.eigenvalues, t0, &options, &material, &settings, |s| {
                if root {
                    eprintln!("[{name} t*={t_true}] it {} t {:.5} loss {:.3e} dL/dt {:.3e} ({} tets)", s.iteration, s.thickness, s.loss, s.gradient, s.tets);
                }
            })
            .unwrap();
            let seconds = clock.elapsed().as_secs_f64();
            let n = fit.history.len() as f64;
            let sum = |f: &dyn Fn(&diffsound::inverse::shape::StepTimings) -> f64| fit.history.iter().map(|h| f(&h.timings)).sum::<f64>() / n;
            let err = (fit.thickness - t_true).abs();
            errors.push(err);
            if root {
                println!(
                    "| {name} | {t_true} | {t0:.3} | {:.4} | {err:.4} | {} | {} | {} | {:.2} | {:.2} | {:.2} | {:.2} | {seconds:.1} |",
                    fit.thickness,
                    fit.history.len() - 1,
                    fit.evaluations,
                    fit.history.last().unwrap().tets,
                    sum(&|t| t.meshing),
                    sum(&|t| t.assembly),
                    sum(&|t| t.solve),
                    sum(&|t| t.gradient)
                );
            }
        }
        per_shape.push((name, errors));
    }
    if root {
        println!("\n| shape | mean abs error of t | max |\n|---|---|---|");
        for (name, e) in &per_shape {
            println!("| {name} | {:.4} | {:.4} |", e.iter().sum::<f64>() / e.len() as f64, e.iter().cloned().fold(0.0, f64::max));
        }
    }
}
