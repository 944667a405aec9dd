//! Synthetic benchmark of impact localisation (issue 8), [`diffsound::inverse::impact`].
//!
//! For each mesh: the first `--modes` elastic modes (P2, SLEPc on every rank, shapes gathered to
//! rank 0 as the CLI does); the acoustic transfer of every mode to `--mics` microphones at
//! random directions (seeded) on a sphere of 3× the object's bounding radius about its
//! bounding-box centre (multipole fit, [`diffsound::audio::radiation`]), and the
//! direction-averaged fallback at the same radius. Then `--strikes` random strikes: a surface
//! vertex drawn from [`diffsound::diagnose::inject::strike_candidates`] (up = +z, 5 % clearance),
//! struck into the surface with an impulse J ~ log-uniform [1e-3, 1e-2] N·s (half-sine contact
//! of 0.1 ms, displacement response, so that z·T̄ is pressure in Pa), rendered at
//! `--sample-rate` for `--duration` s after 50 ms of pre-roll at every microphone **through the
//! true transfer** (bank amplitude z_k·conj(T_km), phase included), with white noise at
//! `--snr-db` below each channel's peak. The amplitudes are fitted with the poles known, the
//! clusters (modes within 0.5 % in frequency) compared by energy, and the map computed twice:
//!
//! * `transfer`: with the multipole transfer to the known microphones (the same model that
//!   rendered: circular, see below);
//! * `no transfer`: microphone positions unknown, the direction-averaged transfer (magnitudes
//!   only) — what the fallback costs.
//!
//! Reported per mesh and variant: geodesic distance (edge paths, [`SurfaceGraph`]) from the true
//! vertex to the best candidate, median and 90th percentile, in mm and in % of the bounding-box
//! diagonal; the fraction of strikes whose true vertex lies in the top 1 % of the map (area
//! rank ≤ 0.01); the same counting the true vertex's symmetry orbit as correct (drive
//! signatures within `--orbit-rtol`, default 10 %, [`symmetry_orbit`]: distance to the nearest orbit member, best rank
//! over the orbit); the median |ŝ/J − 1|; and the wall time of each part. A second table
//! describes the objects: modes, clusters, transfer fit residuals, orbit sizes.
//!
//! Circularity: the `transfer` variant renders and scores with the same mode shapes, damping
//! and multipole transfer, so it measures only the noise, the contact low-pass and the unknown
//! bases of degenerate clusters (rendered in the solver's basis, scored by the basis-averaged
//! cluster energy). On the bowl the transfer itself is a rough guess (concave body, see the
//! radiation module's Limits), which this benchmark cannot see.
//!
//! Usage (rank 0 prints the markdown tables on stdout, progress on stderr):
//!   mpirun -np 2 target/release/examples/impact_benchmark [--seed 1] [--strikes 20]
//!       [--snr-db 40] [--mics 4] [--modes 32] [--duration 1] [--sample-rate 48000]
//!       [--orbit-rtol 0.1] [MESH...]
//! Default meshes: examples/bowl/bowl.msh (the shared bowl), examples/solids/plate.msh,
//! examples/solids/mug.msh.
use diffsound::analysis::MeasuredMode;
use diffsound::assembly;
use diffsound::audio::chain::{DampingCurve, DampingModel, ModalChain, Strike};
use diffsound::audio::excitation::{ContactForce, Response};
use diffsound::audio::radiation::{fit_multipoles, MultipoleSettings, SurfaceQuadrature};
use diffsound::audio::synth::{render_samples, ModalBank};
use diffsound::diagnose::evidence::cluster_ids;
use diffsound::diagnose::inject::strike_candidates;
use diffsound::eigen::{self, EigenConfig, ModeRequest};
use diffsound::fem::Material;
use diffsound::inverse::impact::{
    cluster_amplitudes, drive_signatures, fit_amplitudes, forward_amplitudes, likelihood_map,
    surface_candidates, symmetry_orbit, AmplitudeFitOptions, MapOptions, SurfaceGraph, Transfer,
};
use diffsound::mesh::{self, ReadOptions};
use diffsound::petsc::Petsc;
use diffsound::random::SplitMix64;
use rustfft::num_complex::Complex64;
use std::time::Instant;

const PRE_ROLL_S: f64 = 0.05;
const CLUSTER_RTOL: f64 = 0.005;
const MIC_RADIUS_FACTOR: f64 = 3.0;
const CONTACT_S: f64 = 1e-4;

struct Args {
    seed: u64,
    strikes: usize,
    snr_db: f64,
    mics: usize,
    modes: usize,
    duration: f64,
    sample_rate: f64,
    orbit_rtol: f64,
    meshes: Vec<String>,
}

fn parse_args() -> Args {
    let mut a = Args {
        seed: 1,
        strikes: 20,
        snr_db: 40.0,
        mics: 4,
        modes: 32,
        duration: 1.0,
        sample_rate: 48_000.0,
        orbit_rtol: 0.1,
        meshes: Vec::new(),
    };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        let mut value = |name: &str| it.next().unwrap_or_else(|| panic!("{name} needs a value"));
        match arg.as_str() {
            "--seed" => a.seed = value("--seed").parse().expect("--seed: unsigned integer"),
            "--strikes" => a.strikes = value("--strikes").parse().expect("--strikes: integer"),
            "--snr-db" => a.snr_db = value("--snr-db").parse().expect("--snr-db: number"),
            "--mics" => a.mics = value("--mics").parse().expect("--mics: integer"),
            "--modes" => a.modes = value("--modes").parse().expect("--modes: integer"),
            "--duration" => a.duration = value("--duration").parse().expect("--duration: seconds"),
            "--sample-rate" => {
                a.sample_rate = value("--sample-rate").parse().expect("--sample-rate: Hz")
            }
            "--orbit-rtol" => {
                a.orbit_rtol = value("--orbit-rtol").parse().expect("--orbit-rtol: number")
            }
            "-h" | "--help" => {
                eprintln!("usage: impact_benchmark [--seed 1] [--strikes 20] [--snr-db 40] [--mics 4] [--modes 32] [--duration 1] [--sample-rate 48000] [--orbit-rtol 0.1] [MESH...]");
                std::process::exit(0);
            }
            s if s.starts_with("--") => panic!("unknown option {s}"),
            s => a.meshes.push(s.to_string()),
        }
    }
    assert!(
        a.strikes > 0 && a.mics > 0 && a.modes > 0,
        "--strikes, --mics and --modes must be positive"
    );
    if a.meshes.is_empty() {
        a.meshes = [
            "examples/bowl/bowl.msh",
            "examples/solids/plate.msh",
            "examples/solids/mug.msh",
        ]
        .map(String::from)
        .to_vec();
    }
    a
}

/// The material and damping of a mesh: the bowl's values fitted from its recordings (README:
/// E = 7.469e10 Pa, ν = 0.188, ρ = 2700 assumed; damping curve 3.1 1/s at 1.68 kHz, 31 at
/// 7.3 kHz, 66 at 22 kHz); aluminium with its preset Rayleigh damping for the others.
fn material_of(name: &str) -> (Material, DampingModel) {
    if name.contains("bowl") {
        let m = Material {
            youngs_modulus: 7.469e10,
            poisson_ratio: 0.188,
            density: 2700.0,
            rayleigh_alpha: 0.0,
            rayleigh_beta: 0.0,
        };
        let curve = DampingCurve::new(vec![1680.0, 7300.0, 22_000.0], &[3.1, 31.0, 66.0])
            .expect("damping curve");
        (m, DampingModel::Curve(curve))
    } else {
        let m = Material::preset("aluminium").expect("preset");
        (
            m,
            DampingModel::Rayleigh {
                alpha: m.rayleigh_alpha,
                beta: m.rayleigh_beta,
            },
        )
    }
}

fn fnv1a(s: &str) -> u64 {
    s.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ b as u64).wrapping_mul(0x100_0000_01b3)
    })
}

fn quantile(values: &[f64], q: f64) -> f64 {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| !x.is_nan()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let pos = q * (v.len() - 1) as f64;
    let (lo, hi) = (pos.floor() as usize, pos.ceil() as usize);
    v[lo] + (v[hi] - v[lo]) * (pos - lo as f64)
}

/// One strike's outcome for one variant.
#[derive(Default, Clone)]
struct Outcome {
    distance: f64,
    orbit_distance: f64,
    rank: f64,
    orbit_rank: f64,
    strength_error: f64,
    map_seconds: f64,
}

struct Row {
    mesh: String,
    variant: &'static str,
    size: f64,
    outcomes: Vec<Outcome>,
    modes_seconds: f64,
    transfer_seconds: f64,
    fit_seconds: f64,
}

struct ObjectRow {
    mesh: String,
    nodes: usize,
    surface: usize,
    size_mm: f64,
    modes: usize,
    f_lo: f64,
    f_hi: f64,
    clusters_multi: usize,
    transfer_residual_median: f64,
    orbit_size_median: f64,
    orbit_extent_median: f64,
    /// Fraction of strikes whose orbit reaches beyond 20 % of the size, at each of
    /// [`SYMMETRY_RTOLS`].
    orbit_far_fraction: Vec<f64>,
}

/// Orbit tolerances reported in the object table (symmetry detection).
const SYMMETRY_RTOLS: [f64; 3] = [0.05, 0.1, 0.2];

fn main() {
    let args = parse_args();
    let universe = mpi::initialize().expect("MPI");
    let petsc = Petsc::initialize(universe, "impact_benchmark", &[]).expect("PETSc");
    let root = petsc.rank() == 0;
    if root {
        eprintln!(
            "seed {}, {} strikes, SNR {} dB, {} microphones, {} modes, {} s at {} Hz, {} ranks",
            args.seed,
            args.strikes,
            args.snr_db,
            args.mics,
            args.modes,
            args.duration,
            args.sample_rate,
            petsc.size()
        );
    }
    let mut rows: Vec<Row> = Vec::new();
    let mut objects: Vec<ObjectRow> = Vec::new();
    for path in &args.meshes {
        let name = std::path::Path::new(path)
            .file_stem()
            .unwrap()
            .to_string_lossy()
            .to_string();
        let read = mesh::read_mesh(std::path::Path::new(path), &ReadOptions::default())
            .unwrap_or_else(|e| panic!("{path}: {e}"));
        let model = mesh::lift_to_quadratic(&read.mesh);
        drop(read);
        let (lo, hi) = model.bounding_box();
        let size = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
        let centre = [
            0.5 * (lo[0] + hi[0]),
            0.5 * (lo[1] + hi[1]),
            0.5 * (lo[2] + hi[2]),
        ];
        let (material, damping) = material_of(&name);

        // Modes on every rank, shapes to rank 0.
        let t_modes = Instant::now();
        let assembled =
            assembly::assemble(&petsc, &model).unwrap_or_else(|e| panic!("{name}: assembly: {e}"));
        let (k, m) = assembled.operators(&material).expect("operators");
        let cfg = EigenConfig::new(
            ModeRequest::FirstN(args.modes),
            eigen::spectrum_scale(material.lame_mu(), material.density, size),
        );
        let modes = eigen::solve_modes(&petsc, &k, &m, &cfg)
            .unwrap_or_else(|e| panic!("{name}: modes: {e}"));
        let shapes = assembled
            .layout
            .gather_original_order(&modes.vectors)
            .expect("gather");
        let modes_seconds = t_modes.elapsed().as_secs_f64();
        if !root {
            continue;
        }
        let eigenvalues = modes.eigenvalues.clone();
        eprintln!(
            "[{name}] {} nodes (P2), {} modes {:.0}–{:.0} Hz in {modes_seconds:.1} s",
            model.n_nodes(),
            eigenvalues.len(),
            eigen::frequency_hz(eigenvalues[0]),
            eigen::frequency_hz(*eigenvalues.last().unwrap())
        );

        // Poles as the renderer makes them; modes above 0.45 f_s are left out.
        let strike = Strike {
            force: ContactForce::HalfSine {
                duration_s: CONTACT_S,
            },
            response: Response::Displacement,
        };
        let (bank1, _) = ModalChain::new(
            &eigenvalues,
            &vec![1.0; eigenvalues.len()],
            &damping,
            &strike,
        )
        .expect("chain");
        let keep: Vec<usize> = (0..eigenvalues.len())
            .filter(|&k| {
                bank1.frequencies_hz[k] > 0.0 && bank1.frequencies_hz[k] < 0.45 * args.sample_rate
            })
            .collect();
        let eigenvalues: Vec<f64> = keep.iter().map(|&k| eigenvalues[k]).collect();
        let shapes: Vec<Vec<f64>> = keep.iter().map(|&k| shapes[k].clone()).collect();
        // The kept modes' decay rates, fixed per mode from here on.
        let decays: Vec<f64> = keep.iter().map(|&k| bank1.decay_rates[k]).collect();
        let damping = DampingModel::PerMode {
            decay_rates: decays.clone(),
        };
        let poles: Vec<MeasuredMode> = keep
            .iter()
            .map(|&k| MeasuredMode::pole(bank1.frequencies_hz[k], bank1.decay_rates[k]))
            .collect();
        let frequencies: Vec<f64> = poles.iter().map(|p| p.frequency_hz).collect();
        let ids = cluster_ids(&frequencies, CLUSTER_RTOL);

        // Microphones and transfers.
        let mut rng = SplitMix64::stream(args.seed, fnv1a(&name));
        let radius = MIC_RADIUS_FACTOR * 0.5 * size;
        let mics: Vec<[f64; 3]> = (0..args.mics)
            .map(|_| {
                let d = [rng.normal(), rng.normal(), rng.normal()];
                let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                [
                    centre[0] + radius * d[0] / n,
                    centre[1] + radius * d[1] / n,
                    centre[2] + radius * d[2] / n,
                ]
            })
            .collect();
        let t_transfer = Instant::now();
        let quadrature = SurfaceQuadrature::new(&model).expect("surface quadrature");
        let mut directional: Vec<Vec<Complex64>> = Vec::new();
        let mut averaged: Vec<Vec<f64>> = Vec::new();
        let mut residuals = Vec::new();
        for (shape, &lambda) in shapes.iter().zip(&eigenvalues) {
            let un = quadrature
                .normal_displacement(shape)
                .expect("normal displacement");
            let fit = fit_multipoles(
                quadrature.samples(),
                &un,
                lambda.sqrt(),
                &MultipoleSettings::default(),
            )
            .expect("multipole fit");
            let nearest = mics
                .iter()
                .map(|x| {
                    (0..3)
                        .map(|d| (x[d] - fit.centre[d]).powi(2))
                        .sum::<f64>()
                        .sqrt()
                })
                .fold(f64::INFINITY, f64::min);
            assert!(
                nearest > fit.source_radius,
                "{name}: a microphone lies inside the source sphere"
            );
            directional.push(fit.transfer(&mics).expect("transfer"));
            averaged.push(
                fit.transfer_unknown_positions(args.mics, radius)
                    .expect("averaged")
                    .iter()
                    .map(|t| t.norm())
                    .collect(),
            );
            residuals.push(fit.residual);
        }
        let transfer_seconds = t_transfer.elapsed().as_secs_f64();

        // Tables, graph, orbits.
        let candidates = surface_candidates(&model);
        let graph = SurfaceGraph::from_mesh(&model).expect("surface graph");
        let t_tables = Instant::now();
        let table_dir = forward_amplitudes(
            &shapes,
            &eigenvalues,
            &decays,
            &strike,
            &candidates,
            &Transfer::Directional(&directional),
            &ids,
        )
        .expect("table");
        let table_avg = forward_amplitudes(
            &shapes,
            &eigenvalues,
            &decays,
            &strike,
            &candidates,
            &Transfer::Magnitude(&averaged),
            &ids,
        )
        .expect("table");
        let tables_seconds = t_tables.elapsed().as_secs_f64();
        let signatures = drive_signatures(&table_dir);
        let index_of: std::collections::HashMap<usize, usize> = table_dir
            .candidates
            .iter()
            .enumerate()
            .map(|(i, c)| (c.vertex, i))
            .collect();
        eprintln!(
            "[{name}] {} clusters ({} of several modes), transfer of {} modes to {} microphones at {radius:.3} m in {transfer_seconds:.1} s (boundary residual ε min {:.3}, median {:.3}, max {:.3}), tables {tables_seconds:.2} s",
            table_dir.clusters.len(),
            table_dir.clusters.iter().filter(|c| c.len() > 1).count(),
            shapes.len(),
            args.mics,
            quantile(&residuals, 0.0),
            quantile(&residuals, 0.5),
            quantile(&residuals, 1.0)
        );

        // Strikes.
        let mut pool: Vec<usize> = strike_candidates(&model, [0.0, 0.0, -1.0], 0.05)
            .into_iter()
            .map(|(v, _)| v)
            .filter(|v| index_of.contains_key(v))
            .collect();
        rng.shuffle(&mut pool);
        pool.truncate(args.strikes);
        let fs = args.sample_rate;
        let pre = (PRE_ROLL_S * fs).round() as usize;
        let n_samples = pre + (args.duration * fs).round() as usize;
        let mut outcomes = [Vec::new(), Vec::new()];
        let (mut fit_seconds, mut orbit_sizes, mut orbit_extents) = (0.0, Vec::new(), Vec::new());
        let mut far = vec![0usize; SYMMETRY_RTOLS.len()];
        for (s, &vertex) in pool.iter().enumerate() {
            let truth = index_of[&vertex];
            let impulse = rng.log_uniform(1e-3, 1e-2);
            let projections: Vec<f64> =
                table_dir.drive[truth].iter().map(|d| impulse * d).collect();
            let (bank, _) =
                ModalChain::new(&eigenvalues, &projections, &damping, &strike).expect("chain");
            let channels: Vec<Vec<f64>> = (0..args.mics)
                .map(|mic| {
                    let z: Vec<Complex64> = (0..shapes.len())
                        .map(|k| {
                            Complex64::from_polar(bank.amplitudes[k], bank.phases[k])
                                * directional[k][mic].conj()
                        })
                        .collect();
                    let heard = ModalBank {
                        frequencies_hz: bank.frequencies_hz.clone(),
                        decay_rates: bank.decay_rates.clone(),
                        amplitudes: z.iter().map(|z| z.norm()).collect(),
                        phases: z.iter().map(|z| z.arg()).collect(),
                    };
                    let clean = render_samples(&heard, fs, n_samples - pre);
                    let peak = clean.iter().fold(0.0_f64, |p, x| p.max(x.abs()));
                    let sigma = peak * 10f64.powf(-args.snr_db / 20.0);
                    let mut x = vec![0.0; pre];
                    x.extend(clean);
                    x.iter_mut().for_each(|v| *v += sigma * rng.normal());
                    x
                })
                .collect();
            let t_fit = Instant::now();
            let fit = fit_amplitudes(
                &channels,
                fs,
                pre as f64 / fs,
                &poles,
                &AmplitudeFitOptions::default(),
            )
            .expect("amplitude fit");
            let measured = cluster_amplitudes(&fit, &ids).expect("cluster amplitudes");
            fit_seconds += t_fit.elapsed().as_secs_f64();
            let orbit = symmetry_orbit(&signatures, truth, args.orbit_rtol).expect("orbit");
            let from_truth = graph
                .distances_from(vertex, f64::INFINITY)
                .expect("geodesic");
            orbit_sizes.push(orbit.len() as f64);
            let extent = |orbit: &[usize]| {
                orbit
                    .iter()
                    .map(|&u| from_truth[graph.index_of(table_dir.candidates[u].vertex).unwrap()])
                    .fold(0.0, f64::max)
                    / size
            };
            orbit_extents.push(extent(&orbit));
            for (count, &rtol) in far.iter_mut().zip(&SYMMETRY_RTOLS) {
                *count += usize::from(
                    extent(&symmetry_orbit(&signatures, truth, rtol).expect("orbit")) > 0.2,
                );
            }
            for (variant, table) in [&table_dir, &table_avg].into_iter().enumerate() {
                let t_map = Instant::now();
                let map =
                    likelihood_map(&measured, table, &graph, &MapOptions::default()).expect("map");
                let map_seconds = t_map.elapsed().as_secs_f64();
                let best_vertex = table.candidates[map.best].vertex;
                let from_best = graph
                    .distances_from(best_vertex, f64::INFINITY)
                    .expect("geodesic");
                let at = |u: usize| graph.index_of(table.candidates[u].vertex).unwrap();
                let outcome = Outcome {
                    distance: from_best[at(truth)],
                    orbit_distance: orbit
                        .iter()
                        .map(|&u| from_best[at(u)])
                        .fold(f64::INFINITY, f64::min),
                    rank: map.area_rank(truth),
                    orbit_rank: orbit
                        .iter()
                        .map(|&u| map.area_rank(u))
                        .fold(f64::INFINITY, f64::min),
                    strength_error: map.strength / impulse - 1.0,
                    map_seconds,
                };
                eprintln!(
                    "[{name}] strike {s:2} vertex {vertex:5} J {impulse:.2e} {:12}: best {best_vertex:5} at {:6.1} mm, rank {:.4}, orbit {} (dist {:.1} mm, rank {:.4}), ŝ/J − 1 = {:+.3}, σ_model {:.3}, {} terms ({} below limit), {:.2} s",
                    ["transfer", "no transfer"][variant],
                    1e3 * outcome.distance,
                    outcome.rank,
                    orbit.len(),
                    1e3 * outcome.orbit_distance,
                    outcome.orbit_rank,
                    outcome.strength_error,
                    map.sigma_model[map.best],
                    map.terms,
                    map.terms_below_limit,
                    map_seconds
                );
                outcomes[variant].push(outcome);
            }
        }
        for (variant, out) in outcomes.into_iter().enumerate() {
            rows.push(Row {
                mesh: name.clone(),
                variant: ["transfer", "no transfer"][variant],
                size,
                outcomes: out,
                modes_seconds,
                transfer_seconds,
                fit_seconds,
            });
        }
        objects.push(ObjectRow {
            mesh: name.clone(),
            nodes: model.n_nodes(),
            surface: graph.len(),
            size_mm: 1e3 * size,
            modes: shapes.len(),
            f_lo: frequencies[0],
            f_hi: *frequencies.last().unwrap(),
            clusters_multi: table_dir.clusters.iter().filter(|c| c.len() > 1).count(),
            transfer_residual_median: quantile(&residuals, 0.5),
            orbit_size_median: quantile(&orbit_sizes, 0.5),
            orbit_extent_median: quantile(&orbit_extents, 0.5),
            orbit_far_fraction: far
                .iter()
                .map(|&c| c as f64 / pool.len().max(1) as f64)
                .collect(),
        });
    }
    if !root {
        return;
    }
    println!("\n## Impact localisation, synthetic (seed {}, {} strikes per mesh, SNR {} dB re peak, {} microphones)\n", args.seed, args.strikes, args.snr_db, args.mics);
    println!("| mesh | map | strikes | dist median mm (% size) | dist p90 mm (% size) | top 1 % | orbit dist median mm | orbit top 1 % | median abs(ŝ/J − 1) | modes s | transfer s | fit s/strike | map s/strike |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for r in &rows {
        let d: Vec<f64> = r.outcomes.iter().map(|o| o.distance).collect();
        let od: Vec<f64> = r.outcomes.iter().map(|o| o.orbit_distance).collect();
        let n = r.outcomes.len().max(1) as f64;
        let top = r.outcomes.iter().filter(|o| o.rank <= 0.01).count() as f64 / n;
        let otop = r.outcomes.iter().filter(|o| o.orbit_rank <= 0.01).count() as f64 / n;
        let se: Vec<f64> = r.outcomes.iter().map(|o| o.strength_error.abs()).collect();
        let map_s = r.outcomes.iter().map(|o| o.map_seconds).sum::<f64>() / n;
        let (m50, m90) = (quantile(&d, 0.5), quantile(&d, 0.9));
        println!(
            "| {} | {} | {} | {:.1} ({:.1} %) | {:.1} ({:.1} %) | {:.0} % | {:.1} | {:.0} % | {:.3} | {:.1} | {:.1} | {:.3} | {:.3} |",
            r.mesh,
            r.variant,
            r.outcomes.len(),
            1e3 * m50,
            100.0 * m50 / r.size,
            1e3 * m90,
            100.0 * m90 / r.size,
            100.0 * top,
            1e3 * quantile(&od, 0.5),
            100.0 * otop,
            quantile(&se, 0.5),
            r.modes_seconds,
            r.transfer_seconds,
            r.fit_seconds / n,
            map_s
        );
    }
    println!(
        "\n| mesh | P2 nodes | surface vertices | size mm | modes | band Hz | clusters > 1 mode | transfer ε median | orbit size median (vertices, rtol {}) | orbit extent median (% size) | strikes with orbit > 20 % size at rtol {:?} |",
        args.orbit_rtol, SYMMETRY_RTOLS
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for o in &objects {
        println!(
            "| {} | {} | {} | {:.0} | {} | {:.0}–{:.0} | {} | {:.3} | {:.0} | {:.1} % | {} |",
            o.mesh,
            o.nodes,
            o.surface,
            o.size_mm,
            o.modes,
            o.f_lo,
            o.f_hi,
            o.clusters_multi,
            o.transfer_residual_median,
            o.orbit_size_median,
            100.0 * o.orbit_extent_median,
            o.orbit_far_fraction
                .iter()
                .map(|f| format!("{:.0} %", 100.0 * f))
                .collect::<Vec<_>>()
                .join(" / ")
        );
    }
}
