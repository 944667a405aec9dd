//! How much the refinement near the walls (src/inverse/shape.rs, "Refinement near the walls")
//! takes out of the grid-alignment noise of a hollow body's spectrum, measured on the
//! thickness fit's own body (curved boundary) and solve.
//!
//!   mpirun -np 2 target/release/examples/wall_probe [--cells 28,36] [--levels 0,1] \
//!       [--thickness 0.7] [--shifts 3] [--modes 16] [--band 0.05] [--seed 7]
//!       [--where inner|outer|both] [--tolerance ε] SURFACE
//!
//! The surface is centred and scaled to a 0.1 m diagonal, ceramic. For every grid size, the
//! centred grid and `shifts` randomly shifted copies (the same shifts for every refinement
//! level); `--where` refines near the inner wall (t ± band, the fit's), the outer surface
//! (s = 0) or both; with `--tolerance` ε > 0 only where the samples do not resolve s
//! ([`diffsound::inverse::shape::refine_unresolved`]). For every t and refinement level L: background tets, body tets, P2 nodes, time per
//! stage and the first `modes` frequencies. Then per (size, t, L) the spread of ln f_k over the
//! alignments (the largest max − min over the modes, and its mean over the modes), and with two
//! or more thickness values the mean d ln f/dt between the first two on the centred grid, so
//! that the spread reads as a thickness: spread / |d ln f/dt| per mode.

use diffsound::fem::Material;
use diffsound::inverse::shape::refine_unresolved;
use diffsound::petsc::Petsc;
use diffsound::shape::{
    curved_shell_spectrum, normalise_surface, read_surface, reference_depth, shifted_covering,
};
use diffsound::shape::{MarchingOptions, SignedDistance};

fn list<T: std::str::FromStr>(s: &str) -> Vec<T> {
    s.split(',')
        .map(|v| v.parse().ok().expect("a comma-separated list"))
        .collect()
}

/// (cells, t, level) → per alignment ln f.
type Table = Vec<((usize, usize, usize), Vec<Vec<f64>>)>;

fn main() {
    let mut cells: Vec<usize> = vec![28, 36];
    let mut levels: Vec<usize> = vec![0, 1];
    let mut thickness: Vec<f64> = vec![0.7];
    let mut shifts = 3usize;
    let mut modes = 16usize;
    let mut band = 0.05;
    let mut seed = 7u64;
    let mut place = "inner".to_string();
    let mut tolerance = 0.0;
    let mut path = String::new();
    let mut it = std::env::args().skip(1);
    while let Some(x) = it.next() {
        let mut value = || it.next().unwrap_or_else(|| panic!("{x} takes a value"));
        match x.as_str() {
            "--cells" => cells = list(&value()),
            "--levels" => levels = list(&value()),
            "--thickness" => thickness = list(&value()),
            "--shifts" => shifts = value().parse().expect("a count"),
            "--modes" => modes = value().parse().expect("a count"),
            "--band" => band = value().parse().expect("a number"),
            "--seed" => seed = value().parse().expect("a seed"),
            "--where" => place = value(),
            "--tolerance" => tolerance = value().parse().expect("a number"),
            _ => path = x,
        }
    }
    let universe = mpi::initialize().expect("MPI");
    let petsc = Petsc::initialize(universe, "wall_probe", &[]).expect("PETSc");
    let root = petsc.rank() == 0;
    let material = Material::preset("ceramic").expect("preset");
    let options = MarchingOptions::default();
    let (mut surface, _) = read_surface(std::path::Path::new(&path)).expect("a surface");
    normalise_surface(&mut surface, 0.1).expect("scaled");
    let sdf = SignedDistance::new(&surface).expect("signed distance");
    let depth = reference_depth(&sdf, &surface).expect("depth");
    let (lo, hi) = surface.bounding_box();
    let mut rng = diffsound::random::SplitMix64::new(seed);
    let shift_list: Vec<[f64; 3]> = std::iter::once([0.0; 3])
        .chain((0..shifts).map(|_| [0; 3].map(|_| rng.uniform(-0.5, 0.5))))
        .collect();
    if root {
        println!(
            "{path}: S = {:.4} mm, band ±{band}, {modes} modes, shifts {shift_list:.3?}",
            1e3 * depth
        );
    }
    // (cells, t, level) → per alignment ln f.
    let mut table: Table = Vec::new();
    for &n in &cells {
        for (a, &shift) in shift_list.iter().enumerate() {
            let grid = shifted_covering(lo, hi, n, shift).expect("grid");
            let solid = sdf.evaluate(&grid.vertex_positions());
            for (ti, &t) in thickness.iter().enumerate() {
                for &l in &levels {
                    let clock = std::time::Instant::now();
                    let inner = ((t - band) * depth, (t + band) * depth);
                    let bands: Vec<(f64, f64)> = match place.as_str() {
                        "inner" => vec![inner],
                        "outer" => vec![(0.0, 0.0)],
                        "both" => vec![(0.0, 0.0), inner],
                        other => panic!("--where takes inner, outer or both, not {other}"),
                    };
                    let (g, s) = if l == 0 {
                        (grid.clone(), solid.clone())
                    } else {
                        refine_unresolved(&grid, &solid, &sdf, &bands, l, tolerance)
                            .expect("refined")
                    };
                    let refine_s = clock.elapsed().as_secs_f64();
                    match curved_shell_spectrum(
                        &petsc, &g, &s, &sdf, depth, t, &options, &material, modes, false,
                    ) {
                        Ok((sp, _)) => {
                            let f: Vec<f64> = sp
                                .eigenvalues
                                .iter()
                                .map(|l| l.sqrt() / (2.0 * std::f64::consts::PI))
                                .collect();
                            if root {
                                println!("cells {n} shift {a} t {t:.3} L {l}: {} background tets, {} tets, {} P2 nodes; refine {refine_s:.2} s, mesh {:.2} s, assembly {:.2} s, solve {:.2} s | Hz {}", g.n_tets(), sp.tets, sp.p2_nodes, sp.timings.meshing, sp.timings.assembly, sp.timings.solve, f.iter().map(|x| format!("{x:.1}")).collect::<Vec<_>>().join(" "));
                            }
                            let key = (n, ti, l);
                            let ln: Vec<f64> = f.iter().map(|x| x.ln()).collect();
                            match table.iter_mut().find(|(k, _)| *k == key) {
                                Some((_, rows)) => rows.push(ln),
                                None => table.push((key, vec![ln])),
                            }
                        }
                        Err(e) => {
                            if root {
                                println!("cells {n} shift {a} t {t:.3} L {l}: failed: {e}");
                            }
                        }
                    }
                }
            }
        }
    }
    if !root {
        return;
    }
    println!("\nspread of ln f over the alignments (max − min per mode), and as a thickness (spread / |d ln f/dt|, d ln f/dt from the first two t on the centred grid):");
    for (key, rows) in &table {
        let (n, ti, l) = *key;
        let per_mode: Vec<f64> = (0..modes)
            .map(|k| {
                rows.iter().map(|r| r[k]).fold(f64::NEG_INFINITY, f64::max)
                    - rows.iter().map(|r| r[k]).fold(f64::INFINITY, f64::min)
            })
            .collect();
        let worst = per_mode.iter().cloned().fold(0.0, f64::max);
        let mean = per_mode.iter().sum::<f64>() / modes as f64;
        // d ln f/dt between the first two thickness values on the centred grid, same size and L.
        let centred = |t_index: usize| {
            table
                .iter()
                .find(|(k, _)| *k == (n, t_index, l))
                .map(|(_, r)| r[0].clone())
        };
        let slope = match (thickness.len() >= 2, centred(0), centred(1)) {
            (true, Some(a), Some(b)) => Some(
                (0..modes)
                    .map(|k| (b[k] - a[k]) / (thickness[1] - thickness[0]))
                    .collect::<Vec<f64>>(),
            ),
            _ => None,
        };
        let as_t = slope.map(|s| {
            // The Gauss–Newton reading of a common shift: Σ s_k δ_k / Σ s_k², with δ the spread.
            let num: f64 = (0..modes).map(|k| s[k].abs() * per_mode[k]).sum();
            let den: f64 = (0..modes).map(|k| s[k] * s[k]).sum();
            format!(
                ", mean |d ln f/dt| {:.4}, spread as t ≈ {:.4}",
                s.iter().map(|x| x.abs()).sum::<f64>() / modes as f64,
                num / den
            )
        });
        println!(
            "cells {n} t {:.3} L {l}: {} alignments, spread max {:.2e}, mean {:.2e}{}",
            thickness[ti],
            rows.len(),
            worst,
            mean,
            as_t.unwrap_or_default()
        );
    }
}
