//! Diagnostics for the shape tasks (issue 7): how the spectrum of a hollow body depends on the
//! background grid and on t, measured rather than guessed (the numbers in the module docs of
//! `diffsound::inverse::shape` come from here).
//!
//!   shape_probe [--cells 14,20,32] [--thickness 0.3,0.5,0.7] [--modes 8] [--snap 0.05]
//!               [--shifts K] [--exact] [--curved] [--subdivide] [--grid-max] [--scan LO:HI:STEP]
//!               [--ab-deflation R] SURFACE.obj
//!   shape_probe --analytic-sphere R [--cells ..] [--snap ..]      (solid ball vs Lamb)
//!   shape_probe --analytic-shell R [--thickness ..] [--exact|--curved] (hollow ball 0 < R − |x| ≤ tR)
//!
//! The surface is centred and scaled to a 0.1 m diagonal, ceramic. For every grid (and K
//! randomly shifted copies of it): its size, the largest sample S_grid against the deepest
//! point S of the continuous signed distance, and for every t the tets, volume, pieces, snapped
//! values, clusters, time split and the first modes' frequencies. `--grid-max` uses S_grid as the
//! reference depth (the first version's definition); `--exact` moves every crossing onto the
//! continuous field's zero ([`diffsound::shape::refine_crossings`]); `--curved` does that
//! and moves every boundary mid-edge node onto it too ([`diffsound::shape::curve_boundary`], the
//! thickness fit's default body); `--subdivide` splits
//! every marched tet into eight (the same polyhedral body: what changes is the finite-element
//! error alone). `--scan` prints
//! L(t) and ln(λ_k/λ*_k) per mode on a t grid at every grid but the last, against the target at
//! the first t on the last grid, and per mode the t where its eigenvalue crosses the target's.
//! `--ab-deflation R` solves every body R more times in turns without and with the six rigid
//! motions deflated ([`diffsound::eigen::solve_modes_deflated`], what the fits use), side by
//! side on the same matrices, and prints both times, SLEPc's restarts and the largest
//! eigenvalue difference.
use diffsound::fem::Material;
use diffsound::mesh::{self};
use diffsound::petsc::Petsc;
use diffsound::shape;
use diffsound::shape::{shape_spectrum, ShapeSpectrum};
use diffsound::shape::{BackgroundGrid, MarchingOptions, SignedDistance, TriangleSurface};

fn list<T: std::str::FromStr>(s: &str) -> Vec<T> {
    s.split(',')
        .map(|v| v.parse().ok().expect("a comma-separated list"))
        .collect()
}

fn main() {
    let mut cells: Vec<usize> = vec![14, 20, 32];
    let mut thickness: Vec<f64> = vec![0.3, 0.5, 0.7];
    let mut modes = 8;
    let mut snap = 0.05;
    let mut scan: Option<(f64, f64, f64)> = None;
    let mut grid_max = false;
    let mut exact = false;
    let mut subdivide = false;
    let mut curved = false;
    let mut shifts = 0usize;
    let mut ab_deflation = 0usize;
    let mut analytic: Option<f64> = None;
    let mut path = String::new();
    let mut it = std::env::args().skip(1);
    while let Some(x) = it.next() {
        match x.as_str() {
            "--cells" => cells = list(&it.next().unwrap()),
            "--thickness" => thickness = list(&it.next().unwrap()),
            "--modes" => modes = it.next().unwrap().parse().unwrap(),
            "--snap" => snap = it.next().unwrap().parse().unwrap(),
            "--grid-max" => grid_max = true,
            "--exact" => exact = true,
            "--subdivide" => subdivide = true,
            "--curved" => {
                curved = true;
                exact = true;
            }
            "--shifts" => shifts = it.next().unwrap().parse().unwrap(),
            "--ab-deflation" => ab_deflation = it.next().unwrap().parse().unwrap(),
            "--analytic-sphere" => analytic = Some(it.next().unwrap().parse().unwrap()),
            "--analytic-shell" => {
                analytic = Some(it.next().unwrap().parse().unwrap());
                path = "shell".into();
            }
            "--scan" => {
                let v: Vec<f64> = it
                    .next()
                    .unwrap()
                    .split(':')
                    .map(|v| v.parse().unwrap())
                    .collect();
                scan = Some((v[0], v[1], v[2]));
            }
            _ => path = x,
        }
    }
    let universe = mpi::initialize().unwrap();
    let petsc = Petsc::initialize(universe, "shape_probe", &[]).unwrap();
    let root = petsc.rank() == 0;
    let material = Material::preset("ceramic").unwrap();
    let options = MarchingOptions {
        snap_fraction: snap,
        ..Default::default()
    };
    // The marched bodies' slivers: MUMPS's workspace estimate falls short without this (as in
    // the shape module's own solves).
    petsc
        .set_default_option("-st_mat_mumps_icntl_14", "100")
        .unwrap();
    if let Some(radius) = analytic {
        // The solid sphere s = R − |x| against Lamb's frequencies: the order of the marching +
        // P2 discretisation on its own.
        let lamb = diffsound::eigen::analytic::sphere_modes(
            radius,
            material.youngs_modulus,
            material.poisson_ratio,
            material.density,
            1.2e5,
        );
        let mut reference = Vec::new();
        for m in lamb.iter() {
            for _ in 0..m.multiplicity {
                reference.push(m.frequency_hz);
            }
            if reference.len() >= modes {
                break;
            }
        }
        if path == "shell" {
            // The hollow analytic sphere 0 < R − |x| ≤ t R: no creases, no features.
            for &t in &thickness {
                for &n in &cells {
                    let grid = BackgroundGrid::covering([-radius; 3], [radius; 3], n, 1.0).unwrap();
                    let depth = t * radius;
                    let values: Vec<f64> = grid
                        .vertex_positions()
                        .iter()
                        .map(|p| {
                            let s = radius - (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                            s.min(depth - s)
                        })
                        .collect();
                    let marched = shape::march(&grid, &values, None, &options).unwrap();
                    let f = |p: [f64; 3]| {
                        let s = radius - (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                        s.min(depth - s)
                    };
                    let linear = if exact {
                        diffsound::shape::refine_crossings(&marched, &grid, &f, None, 0.01).0
                    } else {
                        marched.mesh.clone()
                    };
                    let quadratic = mesh::lift_to_quadratic(&linear);
                    let quadratic = if curved {
                        shape::curve_boundary(&quadratic, &f, None, 0.5, 0.05).0
                    } else {
                        quadratic
                    };
                    let assembled = diffsound::assembly::assemble(&petsc, &quadratic).unwrap();
                    let (k, m) = assembled.operators(&material).unwrap();
                    let mut cfg = diffsound::eigen::EigenConfig::new(
                        diffsound::eigen::ModeRequest::FirstN(modes),
                        diffsound::eigen::spectrum_scale(
                            material.lame_mu(),
                            material.density,
                            2.0 * radius,
                        ),
                    );
                    cfg.verify_count = false;
                    let solved = diffsound::eigen::solve_modes(&petsc, &k, &m, &cfg).unwrap();
                    let exact_volume = 4.0 / 3.0
                        * std::f64::consts::PI
                        * (radius.powi(3) - (radius - depth).powi(3));
                    let f: Vec<f64> = solved
                        .eigenvalues
                        .iter()
                        .map(|l| l.sqrt() / (2.0 * std::f64::consts::PI))
                        .collect();
                    let mean = |r: std::ops::Range<usize>| {
                        r.clone().map(|k| f[k]).sum::<f64>() / r.len() as f64
                    };
                    if root {
                        println!("shell t {t} grid {n:3} h {:.3} mm: {} tets, V/V_exact − 1 = {:+.3e}, clusters {:?}, mean f 0-4 {:.1}, 5-9 {:.1} Hz", 1e3 * grid.spacing()[0], linear.n_tets(), linear.volume() / exact_volume - 1.0, solved.clusters, mean(0..5), mean(5..10));
                    }
                }
            }
            return;
        }
        for &n in &cells {
            let grid = BackgroundGrid::covering([-radius; 3], [radius; 3], n, 1.0).unwrap();
            let values: Vec<f64> = grid
                .vertex_positions()
                .iter()
                .map(|p| radius - (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt())
                .collect();
            let sp =
                shape_spectrum(&petsc, &grid, &values, &options, &material, modes, false).unwrap();
            let exact_volume = 4.0 / 3.0 * std::f64::consts::PI * radius.powi(3);
            let f: Vec<f64> = sp
                .eigenvalues
                .iter()
                .map(|l| l.sqrt() / (2.0 * std::f64::consts::PI))
                .collect();
            // Mean relative error over the first cluster (ℓ = 2 torsional, 5 modes) and the next.
            let err = |r: std::ops::Range<usize>| {
                r.clone().map(|k| f[k]).sum::<f64>() / r.len() as f64 / reference[r.start] - 1.0
            };
            if root {
                println!("sphere grid {n:3} h {:.3} mm: {} tets, V/V_exact − 1 = {:+.3e}, snapped {}, modes 0-4 {:+.4e}, 5-9 {:+.4e}; solve {:.1} s", 1e3 * grid.spacing()[0], sp.tets, sp.volume / exact_volume - 1.0, sp.report.snapped_vertices, err(0..5), err(5..10), sp.timings.solve);
            }
        }
        return;
    }
    let mut surface: TriangleSurface = shape::read_obj(std::path::Path::new(&path))
        .unwrap()
        .surface;
    let (lo, hi) = surface.bounding_box();
    let diag = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
    let centre = [0, 1, 2].map(|d| 0.5 * (lo[d] + hi[d]));
    for v in &mut surface.vertices {
        for d in 0..3 {
            v[d] = (v[d] - centre[d]) * 0.1 / diag;
        }
    }
    let (lo, hi) = surface.bounding_box();
    let sdf = SignedDistance::new(&surface).unwrap();
    let mut fields = Vec::new();
    let mut rng = diffsound::random::SplitMix64::new(7);
    let mut grids = Vec::new();
    for &n in &cells {
        let base = BackgroundGrid::covering(lo, hi, n, 1.0).unwrap();
        grids.push((n, base.clone()));
        for _ in 0..shifts {
            let h = base.spacing();
            let origin = [0, 1, 2].map(|d| base.origin()[d] + rng.uniform(-0.5, 0.5) * h[d]);
            grids.push((n, BackgroundGrid::new(origin, h, base.cells()).unwrap()));
        }
    }
    for (n, grid) in grids {
        let t = std::time::Instant::now();
        let values = sdf.evaluate(&grid.vertex_positions());
        let sdf_s = t.elapsed().as_secs_f64();
        let s_grid = values.iter().cloned().fold(f64::MIN, f64::max);
        let mut order: Vec<usize> = (0..values.len()).collect();
        order.sort_by(|&a, &b| values[b].total_cmp(&values[a]));
        let starts: Vec<[f64; 3]> = order
            .iter()
            .take(8)
            .map(|&v| grid.vertex_position(v))
            .collect();
        let t = std::time::Instant::now();
        let (p, s) = sdf.deepest_point(&starts, grid.spacing()[0], 1e-7);
        if root {
            println!("grid {n}: cells {:?}, h {:.3} mm, SDF {sdf_s:.2} s, S_grid {:.4} mm, S {:.5} mm at {:.2?} mm ({:.2} s); wall at t=0.3: {:.2} cells", grid.cells(), 1e3 * grid.spacing()[0], 1e3 * s_grid, 1e3 * s, p.map(|x| 1e3 * x), t.elapsed().as_secs_f64(), 0.3 * s / grid.spacing()[0]);
        }
        fields.push((n, grid, values, if grid_max { s_grid } else { s }));
    }
    let spectrum = |g: &BackgroundGrid,
                    v: &[f64],
                    s: f64,
                    t: f64|
     -> Result<ShapeSpectrum, String> {
        let depth = t * s;
        let shell: Vec<f64> = v.iter().map(|&x| x.min(depth - x)).collect();
        if !exact && !subdivide {
            return shape_spectrum(&petsc, g, &shell, &options, &material, modes, false)
                .map_err(|e| e.to_string());
        }
        // Crossings moved onto the continuous shell's zero along their edges.
        let clock = std::time::Instant::now();
        let marched = shape::march(g, &shell, None, &options).map_err(|e| e.to_string())?;
        let f = |x: [f64; 3]| {
            let d = sdf.signed_distance(x);
            d.min(depth - d)
        };
        let (linear, moved, kept) = if exact {
            diffsound::shape::refine_crossings(&marched, g, &f, None, 0.01)
        } else {
            (marched.mesh.clone(), Vec::new(), 0)
        };
        let linear = if subdivide {
            split_in_eight(&linear)
        } else {
            linear
        };
        let quadratic = mesh::lift_to_quadratic(&linear);
        let quadratic = if curved {
            let (q, _, report) = shape::curve_boundary(&quadratic, &f, None, 0.5, 0.05);
            if root {
                eprintln!("  curved: {report:?}");
            }
            q
        } else {
            quadratic
        };
        let meshing = clock.elapsed().as_secs_f64();
        let clock = std::time::Instant::now();
        let assembled =
            diffsound::assembly::assemble(&petsc, &quadratic).map_err(|e| e.to_string())?;
        let (k, m) = assembled.operators(&material).map_err(|e| e.to_string())?;
        let assembly = clock.elapsed().as_secs_f64();
        let clock = std::time::Instant::now();
        let (lo, hi) = quadratic.bounding_box();
        let diagonal = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
        let mut cfg = diffsound::eigen::EigenConfig::new(
            diffsound::eigen::ModeRequest::FirstN(modes),
            diffsound::eigen::spectrum_scale(material.lame_mu(), material.density, diagonal),
        );
        cfg.verify_count = false;
        let solved =
            diffsound::eigen::solve_modes(&petsc, &k, &m, &cfg).map_err(|e| e.to_string())?;
        let solve = clock.elapsed().as_secs_f64();
        if ab_deflation > 0 {
            let rigid =
                diffsound::eigen::rigid_body_vectors(&k, &assembled.layout, &quadratic.nodes)
                    .map_err(|e| e.to_string())?;
            let (mut plain_s, mut deflated_s) = (0.0, 0.0);
            for round in 0..ab_deflation {
                let clock = std::time::Instant::now();
                let plain = diffsound::eigen::solve_modes(&petsc, &k, &m, &cfg)
                    .map_err(|e| e.to_string())?;
                let a = clock.elapsed().as_secs_f64();
                let clock = std::time::Instant::now();
                let deflated = diffsound::eigen::solve_modes_deflated(&petsc, &k, &m, &cfg, &rigid)
                    .map_err(|e| e.to_string())?;
                let b = clock.elapsed().as_secs_f64();
                let worst = (0..modes)
                    .map(|i| {
                        (plain.eigenvalues[i] - deflated.eigenvalues[i]).abs()
                            / plain.eigenvalues[i]
                    })
                    .fold(0.0, f64::max);
                plain_s += a;
                deflated_s += b;
                if root {
                    eprintln!("  A/B round {round}: plain {a:.2} s ({} restarts), deflated {b:.2} s ({} restarts), ratio {:.3}, worst relative eigenvalue difference {worst:.1e}", plain.setting("iterations").unwrap_or("?"), deflated.setting("iterations").unwrap_or("?"), b / a);
                }
            }
            if root {
                eprintln!("  A/B over {ab_deflation} rounds: plain {plain_s:.2} s, deflated {deflated_s:.2} s, deflated/plain {:.3}", deflated_s / plain_s);
            }
        }
        if root {
            eprintln!(
                "  exact crossings: {} moved, {} kept linear, {:.2} s",
                moved.len(),
                kept,
                meshing
            );
        }
        Ok(ShapeSpectrum {
            eigenvalues: solved.eigenvalues[..modes].to_vec(),
            gradient: None,
            clusters: solved.clusters.clone(),
            report: marched.report.clone(),
            tets: linear.n_tets(),
            p2_nodes: quadratic.n_nodes(),
            volume: linear.volume(),
            timings: diffsound::shape::StepTimings {
                meshing,
                assembly,
                solve,
                gradient: 0.0,
            },
        })
    };
    let hz = |l: &[f64]| {
        l.iter()
            .map(|&x| format!("{:8.1}", x.sqrt() / (2.0 * std::f64::consts::PI)))
            .collect::<Vec<_>>()
            .join(" ")
    };
    for &t in &thickness {
        for (n, g, v, s) in &fields {
            match spectrum(g, v, *s, t) {
                Ok(sp) => {
                    if root {
                        println!("t {t:.3} grid {n:3}: {:6} tets {:6} P2 nodes, V {:.4e}, pieces {} (dropped {} tets), snapped {}, clusters {:?}; mesh {:.2} asm {:.2} solve {:.2} s | Hz {}", sp.tets, sp.p2_nodes, sp.volume, sp.report.components, sp.report.dropped_component_tets, sp.report.snapped_vertices, sp.clusters, sp.timings.meshing, sp.timings.assembly, sp.timings.solve, hz(&sp.eigenvalues));
                    }
                }
                Err(e) => {
                    if root {
                        println!("t {t:.3} grid {n:3}: error {e}");
                    }
                }
            }
        }
    }
    if let Some((a, b, step)) = scan {
        let (_, gf, vf, sf) = fields.last().unwrap();
        let t_true = thickness[0];
        let target = spectrum(gf, vf, *sf, t_true).unwrap().eigenvalues;
        for (n, g, v, s) in &fields[..fields.len() - 1] {
            let mut rows: Vec<(f64, Vec<f64>)> = Vec::new();
            let mut t = a;
            while t <= b + 1e-12 {
                if let Ok(sp) = spectrum(g, v, *s, t) {
                    let loss: f64 = sp
                        .eigenvalues
                        .iter()
                        .zip(&target)
                        .map(|(l, m)| (l / m).ln().powi(2))
                        .sum();
                    if root {
                        println!(
                            "scan grid {n} t {t:.4} L {loss:.4e} tets {} | ln(λ/λ*) {}",
                            sp.tets,
                            sp.eigenvalues
                                .iter()
                                .zip(&target)
                                .map(|(l, m)| format!("{:+.4}", (l / m).ln()))
                                .collect::<Vec<_>>()
                                .join(" ")
                        );
                    }
                    rows.push((t, sp.eigenvalues));
                }
                t += step;
            }
            // Per mode: where ln(λ_k/λ*_k) crosses 0 (linear interpolation between scan points).
            if root {
                let mut crossings = Vec::new();
                // Index loop: mode k indexes every scan row and the target together.
                #[allow(clippy::needless_range_loop)]
                for k in 0..modes {
                    let mut found = None;
                    for w in rows.windows(2) {
                        let (r0, r1) = ((w[0].1[k] / target[k]).ln(), (w[1].1[k] / target[k]).ln());
                        if r0 * r1 <= 0.0 && r0 != r1 {
                            found = Some(w[0].0 + (w[1].0 - w[0].0) * r0 / (r0 - r1));
                        }
                    }
                    crossings.push(found.map_or("   -   ".into(), |x| format!("{:.4}", x)));
                }
                println!(
                    "grid {n}: t* = {t_true}: per-mode crossings {}",
                    crossings.join(" ")
                );
            }
        }
    }
}

/// Every linear tet split into eight by its edge midpoints (the same polyhedral body): the
/// eigenvalue change it makes is the finite-element error of the unsplit mesh on that body.
fn split_in_eight(linear: &mesh::TetMesh) -> mesh::TetMesh {
    let quadratic = mesh::lift_to_quadratic(linear);
    let nodes = quadratic.nodes.clone();
    let volume = |t: &[usize; 4]| {
        let p = t.map(|i| nodes[i]);
        let a = [0, 1, 2].map(|d| p[1][d] - p[0][d]);
        let b = [0, 1, 2].map(|d| p[2][d] - p[0][d]);
        let c = [0, 1, 2].map(|d| p[3][d] - p[0][d]);
        a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
            + a[2] * (b[0] * c[1] - b[1] * c[0])
    };
    let mut connectivity = Vec::new();
    for e in 0..quadratic.n_tets() {
        let q = quadratic.tet(e);
        let c = [q[0], q[1], q[2], q[3]];
        // mid[a][b]: the midpoint node of the edge between corners a and b.
        let mut mid = [[0usize; 4]; 4];
        for (k, &(a, b)) in mesh::TET10_EDGES.iter().enumerate() {
            (mid[a][b], mid[b][a]) = (q[4 + k], q[4 + k]);
        }
        let m = |a: usize, b: usize| mid[a][b];
        let children = [
            [c[0], m(0, 1), m(0, 2), m(0, 3)],
            [m(0, 1), c[1], m(1, 2), m(1, 3)],
            [m(0, 2), m(1, 2), c[2], m(2, 3)],
            [m(0, 3), m(1, 3), m(2, 3), c[3]],
            [m(0, 2), m(1, 3), m(0, 1), m(1, 2)],
            [m(0, 2), m(1, 3), m(1, 2), m(2, 3)],
            [m(0, 2), m(1, 3), m(2, 3), m(0, 3)],
            [m(0, 2), m(1, 3), m(0, 3), m(0, 1)],
        ];
        for mut t in children {
            if volume(&t) < 0.0 {
                t.swap(0, 1);
            }
            connectivity.extend_from_slice(&t);
        }
    }
    mesh::TetMesh {
        nodes,
        connectivity,
        order: mesh::ElementOrder::Linear,
    }
}
