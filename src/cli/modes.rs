//! The `modes` job: mesh → P2 → assembly → SLEPc → HDF5/XDMF (+ WAV strike).

use super::config::{FileConfig, MaterialConfig};
use super::resolve::{check_output, inputs, resolve_mesh, MeshChoice};
use super::{fail, ModesArgs};
use crate::assembly;
use crate::audio::{self, ModalBank, WavFormat};
use crate::eigen::sensitivity::{self, ClusterTreatment};
use crate::eigen::{self, EigenConfig, ModeRequest};
use crate::fem::Material;
use crate::io::{self, MaterialRecord, ModesFile};
use crate::mesh::{self, ReadOptions, TetMesh};
use crate::petsc::Petsc;
use mpi::environment::Universe;
use std::path::{Path, PathBuf};

/// Everything the job needs, resolved from defaults, the config file and the flags.
#[derive(Clone, Debug)]
pub struct Job {
    pub mesh: PathBuf,
    pub unit_scale: f64,
    pub units: String,
    pub order: u32,
    pub fix_inverted: bool,
    pub straighten_invalid: bool,
    pub material: Material,
    pub material_name: String,
    pub request: ModeRequest,
    pub tolerance: f64,
    pub verify_count: bool,
    pub cluster_rtol: Option<f64>,
    pub shift: Option<f64>,
    pub out: PathBuf,
    pub wav: Option<PathBuf>,
    pub strike_vertex: Option<usize>,
    pub duration: f64,
    pub sample_rate: u32,
    pub timings_json: Option<PathBuf>,
    pub sensitivities: bool,
    pub node_gradients: bool,
    pub petsc_options: Vec<String>,
    pub verbose: bool,
}

/// Merges defaults < config file < command-line flags and validates the result.
pub fn resolve(args: &ModesArgs) -> Result<Job, String> {
    let file = match &args.config {
        Some(p) => FileConfig::load(p)?,
        None => FileConfig::default(),
    };
    let MeshChoice {
        mesh,
        units,
        unit_scale,
        order,
    } = resolve_mesh(
        &args.mesh,
        &file.mesh,
        &args.units,
        &file.units,
        args.order.or(file.order),
    )?;
    let flags = MaterialConfig {
        preset: args.material.clone(),
        youngs_modulus: args.youngs,
        poisson_ratio: args.poisson,
        density: args.density,
        rayleigh_alpha: args.alpha,
        rayleigh_beta: args.beta,
    };
    let (material, material_name) = file.material.resolve(&flags)?;

    let fmax = args.fmax.or(if args.modes.is_some() {
        None
    } else {
        file.solver.fmax
    });
    let request = match (
        args.modes.or(if args.fmax.is_some() {
            None
        } else {
            file.solver.modes
        }),
        fmax,
    ) {
        (Some(_), Some(_)) => {
            return Err("give either a number of modes or a frequency limit, not both".into())
        }
        (Some(0), None) => return Err("the number of modes must be at least 1".into()),
        (Some(n), None) => ModeRequest::FirstN(n),
        (None, Some(f)) if f.is_finite() && f > 0.0 => ModeRequest::UpTo { f_max_hz: f },
        (None, Some(f)) => {
            return Err(format!(
                "the frequency limit must be a positive number of Hz, got {f}"
            ))
        }
        (None, None) => ModeRequest::FirstN(20),
    };
    let tolerance = args.tol.or(file.solver.tolerance).unwrap_or(1e-10);
    if !(tolerance > 0.0 && tolerance < 1.0) {
        return Err(format!(
            "the solver tolerance must lie in (0, 1), got {tolerance}"
        ));
    }
    let duration = args.duration.or(file.output.duration).unwrap_or(2.0);
    if !(duration > 0.0 && duration <= 600.0) {
        return Err(format!(
            "the strike duration must lie in (0, 600] s, got {duration}"
        ));
    }
    let sample_rate = args
        .sample_rate
        .or(file.output.sample_rate)
        .unwrap_or(48_000);
    if !(8_000..=384_000).contains(&sample_rate) {
        return Err(format!(
            "the sample rate must lie in 8000..=384000 Hz, got {sample_rate}"
        ));
    }
    let out = args
        .out
        .clone()
        .or(file.output.h5.clone())
        .unwrap_or_else(|| {
            let stem = mesh
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "mesh".into());
            PathBuf::from(format!("{stem}_modes.h5"))
        });
    let mut petsc_options = file.solver.petsc_options.clone();
    petsc_options.extend(args.petsc_options.iter().cloned());
    Ok(Job {
        mesh,
        unit_scale,
        units,
        order,
        fix_inverted: args.fix_inverted || file.fix_inverted.unwrap_or(false),
        straighten_invalid: args.straighten_invalid,
        material,
        material_name,
        request,
        tolerance,
        verify_count: !args.no_verify && file.solver.verify_count.unwrap_or(true),
        cluster_rtol: file.solver.cluster_rtol,
        shift: args.shift.or(file.solver.shift),
        out,
        wav: args.wav.clone().or(file.output.wav.clone()),
        strike_vertex: args.strike_vertex.or(file.output.strike_vertex),
        duration,
        sample_rate,
        timings_json: args
            .timings_json
            .clone()
            .or(file.output.timings_json.clone()),
        sensitivities: args.sensitivities
            || args.node_gradients
            || file.output.sensitivities.unwrap_or(false)
            || file.output.node_gradients.unwrap_or(false),
        node_gradients: args.node_gradients || file.output.node_gradients.unwrap_or(false),
        petsc_options,
        verbose: args.verbose,
    })
}

/// Runs the job on every rank. Input errors found before PETSc starts are returned; errors
/// after that end the job through [`fail`] so that no rank waits forever in a collective call.
pub fn run(universe: Universe, args: ModesArgs) -> Result<(), String> {
    let job = resolve(&args)?;
    let given = inputs(&job.mesh, &[]);
    check_output(&job.out, &given)?;
    if let Some(w) = &job.wav {
        check_output(w, &given)?;
    }
    if let Some(t) = &job.timings_json {
        check_output(t, &given)?;
    }
    let petsc =
        Petsc::initialize(universe, "diffsound", &job.petsc_options).map_err(|e| e.to_string())?;
    let (rank, size) = (petsc.rank(), petsc.size());
    // Fault injection for the tests: a panic on one rank must end the whole job, not hang it.
    if std::env::var("DIFFSOUND_TEST_PANIC_ON_RANK")
        .ok()
        .and_then(|v| v.parse::<usize>().ok())
        == Some(rank)
    {
        panic!("injected panic (DIFFSOUND_TEST_PANIC_ON_RANK={rank})");
    }
    match compute(&petsc, &job) {
        Ok(()) => Ok(()),
        Err(message) => fail(rank, size, &message),
    }
}

fn compute(petsc: &Petsc, job: &Job) -> Result<(), String> {
    let total = std::time::Instant::now();
    let rank = petsc.rank();
    let progress = super::stderr_progress(rank, job.verbose);

    progress.say(format!("reading {}", job.mesh.display()));
    let mut read = mesh::read_mesh(
        &job.mesh,
        &ReadOptions {
            unit_scale: job.unit_scale,
            fix_inverted: job.fix_inverted,
        },
    )
    .map_err(|e| e.to_string())?;
    // Curved 10-node tets that fold over: refused with the file and Gmsh tags named, or
    // straightened on request (`mesh::straighten`), before any assembly.
    let folded = mesh::straighten::folded_tets(&read.mesh);
    if !folded.is_empty() {
        let tags: Vec<String> = folded
            .iter()
            .take(5)
            .map(|&e| {
                read.element_tags
                    .get(e)
                    .map_or(format!("#{e}"), |t| t.to_string())
            })
            .collect();
        if !job.straighten_invalid {
            return Err(format!(
                "{}: {} curved 10-node tetrahedra fold over (Jacobian determinant ≤ 0 inside the element; Gmsh element tags {}{}): rerun with --straighten-invalid to straighten their mid-edge nodes, or untangle the mesh with `gmsh -optimize_ho`",
                job.mesh.display(),
                folded.len(),
                tags.join(", "),
                if folded.len() > 5 { ", …" } else { "" }
            ));
        }
        let moved = mesh::straighten::straighten(&mut read.mesh, &folded);
        if rank == 0 {
            eprintln!("warning: straightened {} folded curved tetrahedra ({moved} mid-edge nodes moved to their edge midpoints; Gmsh element tags {}{})", folded.len(), tags.join(", "), if folded.len() > 5 { ", …" } else { "" });
        }
    }
    if rank == 0 {
        for w in &read.warnings {
            eprintln!("warning: {w}");
        }
    }
    let input_order = read.mesh.nodes_per_tet();

    let mesh: TetMesh = if job.order == 2 {
        mesh::lift_to_quadratic(&read.mesh)
    } else {
        mesh::to_linear(&read.mesh)
    };
    drop(read);
    // Check the strike point now, not after a long solve.
    let strike_point = match &job.wav {
        Some(_) => Some(strike(&mesh, job.strike_vertex)?),
        None => None,
    };
    let (lo, hi) = mesh.bounding_box();
    let diagonal =
        ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2) + (hi[2] - lo[2]).powi(2)).sqrt();
    progress.say(format!(
        "mesh: {} tets, {} nodes (P{}, from {}-node input), {} DOF on {} rank(s)",
        mesh.n_tets(),
        mesh.n_nodes(),
        job.order,
        input_order,
        3 * mesh.n_nodes(),
        petsc.size()
    ));

    let assembled = assembly::assemble(petsc, &mesh).map_err(|e| e.to_string())?;
    let stats = assembled.stats.clone();
    progress.say(format!(
        "assembled M, K_λ, K_μ in {:.2} s ({:.0} nonzeros each, {} mallocs)",
        stats.seconds, stats.nonzeros, stats.mallocs
    ));
    let t_ops = std::time::Instant::now();
    // Sensitivities need the split K_λ, K_μ and M₁; a forward-only run releases them.
    let (k, m, layout, split) = if job.sensitivities {
        let (k, m) = assembled
            .operators(&job.material)
            .map_err(|e| e.to_string())?;
        let layout = assembled.layout.clone();
        (k, m, layout, Some(assembled))
    } else {
        let (k, m, layout, _) = assembled
            .into_operators(&job.material)
            .map_err(|e| e.to_string())?;
        (k, m, layout, None)
    };
    let operator_seconds = t_ops.elapsed().as_secs_f64();

    let scale = eigen::spectrum_scale(job.material.lame_mu(), job.material.density, diagonal);
    let mut cfg = EigenConfig::new(job.request, scale);
    cfg.tolerance = job.tolerance;
    cfg.verify_count = job.verify_count;
    cfg.shift = job.shift;
    if let Some(r) = job.cluster_rtol {
        cfg.cluster_rtol = r;
    }
    progress.say(match job.request {
        ModeRequest::FirstN(n) => format!(
            "solving for the first {n} elastic modes (shift {:.3e} rad²/s²)",
            cfg.effective_shift()
        ),
        ModeRequest::UpTo { f_max_hz } => {
            format!("solving for every mode up to {f_max_hz} Hz (spectrum slicing)")
        }
    });
    let modes = eigen::solve_modes(petsc, &k, &m, &cfg).map_err(|e| e.to_string())?;
    if rank == 0 {
        for w in &modes.warnings {
            eprintln!("warning: {w}");
        }
    }
    progress.say(format!(
        "{} elastic modes in {:.2} s",
        modes.eigenvalues.len(),
        modes.solve_seconds
    ));

    let t_sens = std::time::Instant::now();
    let material_sens = match &split {
        Some(a) => Some(
            sensitivity::material_sensitivities(
                &a.k_lambda,
                &a.k_mu,
                &a.mass_unit,
                &modes,
                &job.material,
            )
            .map_err(|e| e.to_string())?,
        ),
        None => None,
    };
    let material_seconds = t_sens.elapsed().as_secs_f64();
    let t_nodes = std::time::Instant::now();
    let node_grads = if job.node_gradients {
        sensitivity::node_gradients(
            petsc,
            &mesh,
            &layout,
            &modes,
            &job.material,
            ClusterTreatment::Mean,
        )
        .map_err(|e| e.to_string())?
    } else {
        None
    };
    let node_gradient_seconds = t_nodes.elapsed().as_secs_f64();
    let sensitivity_seconds = t_sens.elapsed().as_secs_f64();
    if material_sens.is_some() {
        progress.say(format!("sensitivities in {sensitivity_seconds:.2} s (material {material_seconds:.2} s, node positions {node_gradient_seconds:.2} s)"));
    }

    // Gather every mode to rank 0 in original node order, with a deterministic sign: the entry
    // of largest magnitude is made positive, so runs on any number of ranks agree.
    let mut shapes = layout
        .gather_original_order(&modes.vectors)
        .map_err(|e| e.to_string())?;
    for s in &mut shapes {
        let (imax, _) = s.iter().enumerate().fold((0, 0.0f64), |(bi, bv), (i, &x)| {
            if x.abs() > bv + 1e-12 * bv {
                (i, x.abs())
            } else {
                (bi, bv)
            }
        });
        if s[imax] < 0.0 {
            s.iter_mut().for_each(|x| *x = -*x);
        }
    }
    let frequencies: Vec<f64> = modes
        .eigenvalues
        .iter()
        .map(|&l| eigen::frequency_hz(l))
        .collect();
    let solve_seconds = modes.solve_seconds;
    let peak_rss_local = petsc.peak_rss_bytes();
    let peak_rss_sum: f64 = {
        use mpi::collective::{CommunicatorCollectives, SystemOperation};
        let mut sum = 0.0;
        petsc
            .world()
            .all_reduce_into(&peak_rss_local, &mut sum, SystemOperation::sum());
        sum
    };

    if rank == 0 {
        let mut solver = modes.settings.clone();
        solver.push(("petsc_options".into(), job.petsc_options.join(" ")));
        let (pv, sv) = petsc.versions();
        solver.push(("petsc_version".into(), pv));
        solver.push(("slepc_version".into(), sv));
        if let Some(c) = &modes.inertia_check {
            solver.push(("inertia_check".into(), inertia_line(c)));
        }
        solver.push((
            "clusters".into(),
            modes
                .clusters
                .iter()
                .map(|r| format!("{}-{}", r.start, r.end - 1))
                .collect::<Vec<_>>()
                .join(","),
        ));
        let timings = vec![
            ("assembly".to_string(), stats.seconds + operator_seconds),
            ("solve".to_string(), solve_seconds),
            (
                "inertia_check".to_string(),
                modes.inertia_check.as_ref().map_or(0.0, |c| c.seconds),
            ),
            ("sensitivities".to_string(), sensitivity_seconds),
            ("material_sensitivities".to_string(), material_seconds),
            ("node_gradients".to_string(), node_gradient_seconds),
            ("total".to_string(), total.elapsed().as_secs_f64()),
            ("peak_rss_bytes_sum".to_string(), peak_rss_sum),
        ];
        let provenance = vec![
            ("mesh".to_string(), job.mesh.display().to_string()),
            (
                "units".to_string(),
                format!("{} ({} m per unit)", job.units, job.unit_scale),
            ),
            (
                "command_line".to_string(),
                std::env::args().collect::<Vec<_>>().join(" "),
            ),
            (
                "diffsound_version".to_string(),
                env!("CARGO_PKG_VERSION").to_string(),
            ),
        ];
        let width = io::mode_index_width(modes.eigenvalues.len());
        let node_field_names: Vec<String> = (0..node_grads.as_ref().map_or(0, Vec::len))
            .map(|k| format!("d_lambda_dx_mode_{k:0width$}"))
            .collect();
        let file = ModesFile {
            nodes: &mesh.nodes,
            connectivity: &mesh.connectivity,
            nodes_per_tet: mesh.nodes_per_tet(),
            material: MaterialRecord {
                name: job.material_name.clone(),
                youngs_modulus: job.material.youngs_modulus,
                poisson_ratio: job.material.poisson_ratio,
                density: job.material.density,
                rayleigh_alpha: job.material.rayleigh_alpha,
                rayleigh_beta: job.material.rayleigh_beta,
            },
            eigenvalues: &modes.eigenvalues,
            frequencies_hz: &frequencies,
            mode_shapes: &shapes,
            residual_norms: &modes.residuals,
            rigid_eigenvalues: &modes.rigid_eigenvalues,
            solver,
            n_ranks: petsc.size(),
            element_order: job.order,
            timings,
            provenance,
            extra_datasets: material_sens
                .as_ref()
                .map(|s| sensitivity_datasets(s, &modes, &job.material))
                .unwrap_or_default(),
            node_fields: node_field_names
                .iter()
                .zip(node_grads.iter().flatten())
                .map(|(name, data)| io::NodeField {
                    name: name.clone(),
                    data,
                    units: "rad^2/s^2/m".into(),
                })
                .collect(),
        };
        io::write_modes(&job.out, &file).map_err(|e| e.to_string())?;
        progress.say(format!("wrote {} and its .xdmf sidecar", job.out.display()));

        if let (Some(wav), Some(vertex)) = (&job.wav, strike_point) {
            render_strike(wav, &mesh, vertex, &modes.eigenvalues, &shapes, job)?;
            progress.say(format!(
                "wrote {} (strike at node {})",
                wav.display(),
                vertex.0
            ));
        }

        print_summary(
            job,
            &mesh,
            &stats,
            &modes,
            &frequencies,
            total.elapsed().as_secs_f64(),
            petsc.size(),
            material_sens.as_ref(),
        );
        if let Some(path) = &job.timings_json {
            let json = serde_json::json!({
                "ndof": stats.n_dofs,
                "n_ranks": petsc.size(),
                "assembly_s": stats.seconds + operator_seconds,
                "solve_s": solve_seconds,
                "inertia_check_s": modes.inertia_check.as_ref().map_or(0.0, |c| c.seconds),
                "material_sensitivities_s": material_seconds,
                "node_gradients_s": node_gradient_seconds,
                "total_s": total.elapsed().as_secs_f64(),
                "peak_rss_mb": peak_rss_sum / 1048576.0,
                "mallocs": stats.mallocs,
                "eigenvalues": modes.eigenvalues,
                "frequencies_hz": frequencies,
                "rigid_eigenvalues": modes.rigid_eigenvalues,
                "residuals": modes.residuals,
                "factor_retries": modes.setting("factor_retries").and_then(|v| v.parse::<usize>().ok()).unwrap_or(0),
                "factor_attempts": modes.setting("factor_attempts").unwrap_or(""),
                "inertia": modes.inertia_check.as_ref().map(|c| serde_json::json!({
                    "threshold": c.threshold,
                    "below": c.below,
                    "found": c.found,
                    "proven": c.proven,
                    "second": c.second.map(|(t, b, f)| serde_json::json!({"threshold": t, "below": b, "found": f})),
                    "verdict": c.verdict.word(),
                    "factor_retries": c.factor_log.retries(),
                    "factor_attempts": c.factor_log.describe(),
                })),
            });
            io::write_atomically(path, |tmp| {
                std::fs::write(tmp, serde_json::to_string_pretty(&json).unwrap_or_default())
                    .map_err(|e| io::IoError::Fs {
                        path: tmp.to_path_buf(),
                        context: "writing timings".into(),
                        source: e,
                    })
            })
            .map_err(|e| e.to_string())?;
        }
    }
    Ok(())
}

/// The strike point: the given node (must be on the surface) or, by default, the surface vertex
/// farthest from the bounding-box centre (a rim or corner, where most modes move). Returns the
/// node and its outward unit normal, the strike direction.
fn strike(mesh: &TetMesh, requested: Option<usize>) -> Result<(usize, [f64; 3]), String> {
    let vertex = match requested {
        Some(v) => v,
        None => mesh
            .default_strike_vertex()
            .ok_or("the mesh has no surface vertices to strike")?,
    };
    let point = mesh.surface_point_at_vertex(vertex).ok_or_else(|| {
        format!(
            "strike vertex {vertex} is not a surface vertex of the mesh ({} nodes)",
            mesh.n_nodes()
        )
    })?;
    Ok((vertex, point.normal))
}

/// A unit impulse along the normal at `vertex`: mode k starts with velocity amplitude
/// φ_k(v)·n (mass-normalised modes), rings at its Rayleigh-damped frequency and decays at
/// (α + βω²)/2. The signal is normalised to a peak of 0.9 and written as 16-bit PCM.
fn render_strike(
    path: &Path,
    mesh: &TetMesh,
    (vertex, normal): (usize, [f64; 3]),
    eigenvalues: &[f64],
    shapes: &[Vec<f64>],
    job: &Job,
) -> Result<(), String> {
    let amplitudes: Vec<f64> = shapes
        .iter()
        .map(|s| (0..3).map(|d| s[3 * vertex + d] * normal[d]).sum())
        .collect();
    let bank = ModalBank::from_eigenvalues(
        eigenvalues,
        &amplitudes,
        job.material.rayleigh_alpha,
        job.material.rayleigh_beta,
    );
    let _ = mesh;
    let samples = audio::render(&bank, job.sample_rate as f64, job.duration);
    audio::write_wav(path, &samples, job.sample_rate, WavFormat::Pcm16, Some(0.9))
        .map_err(|e| e.to_string())
}

/// The `/sensitivities` datasets: dλ/dp (cluster means for clustered modes), the per-mode
/// values, df/dp through f = √λ/2π, and the cluster ranges with their split derivatives.
fn sensitivity_datasets(
    s: &sensitivity::MaterialSensitivities,
    modes: &eigen::Modes<'_>,
    material: &crate::fem::Material,
) -> Vec<io::ExtraDataset> {
    let ds = |name: &str, data: Vec<f64>, units: &str, what: &str| io::ExtraDataset {
        path: format!("/sensitivities/{name}"),
        shape: vec![data.len()],
        data,
        attrs: vec![
            ("units".into(), units.into()),
            ("meaning".into(), what.into()),
        ],
    };
    let df = |d: &[f64]| -> Vec<f64> {
        d.iter()
            .zip(&modes.eigenvalues)
            .map(|(x, &l)| x / (4.0 * std::f64::consts::PI * l.sqrt()))
            .collect()
    };
    let mean = "derivative of the mode's eigenvalue; inside a near-degenerate cluster, of the cluster mean";
    let mut out = vec![
        ds(
            "d_eigenvalue_d_youngs",
            s.d_youngs.clone(),
            "rad^2/s^2/Pa",
            mean,
        ),
        ds(
            "d_eigenvalue_d_poisson",
            s.d_poisson.clone(),
            "rad^2/s^2",
            mean,
        ),
        ds(
            "d_eigenvalue_d_density",
            s.d_density.clone(),
            "rad^2/s^2/(kg/m^3)",
            mean,
        ),
        ds(
            "d_frequency_d_youngs",
            df(&s.d_youngs),
            "Hz/Pa",
            "df = dlambda / (4 pi sqrt(lambda))",
        ),
        ds(
            "d_frequency_d_poisson",
            df(&s.d_poisson),
            "Hz",
            "df = dlambda / (4 pi sqrt(lambda))",
        ),
        ds(
            "d_frequency_d_density",
            df(&s.d_density),
            "Hz/(kg/m^3)",
            "df = dlambda / (4 pi sqrt(lambda))",
        ),
        ds(
            "per_mode_d_eigenvalue_d_youngs",
            s.per_mode_youngs.clone(),
            "rad^2/s^2/Pa",
            "each mode on its own (undefined inside a cluster)",
        ),
        ds(
            "per_mode_d_eigenvalue_d_poisson",
            s.per_mode_poisson.clone(),
            "rad^2/s^2",
            "each mode on its own (undefined inside a cluster)",
        ),
        ds(
            "per_mode_d_eigenvalue_d_density",
            s.per_mode_density.clone(),
            "rad^2/s^2/(kg/m^3)",
            "each mode on its own (undefined inside a cluster)",
        ),
    ];
    let chain: Vec<_> = modes
        .eigenvalues
        .iter()
        .map(|&l| sensitivity::damped_chain(l, material.rayleigh_alpha, material.rayleigh_beta))
        .collect();
    let pick = |f: &dyn Fn(&sensitivity::DampedChain) -> f64| {
        chain
            .iter()
            .map(|c| c.as_ref().map_or(f64::NAN, f))
            .collect::<Vec<_>>()
    };
    out.push(ds(
        "d_damped_omega_d_eigenvalue",
        pick(&|c| c.domega_d_dlambda),
        "(rad/s)/(rad^2/s^2)",
        "Rayleigh damping; NaN where overdamped",
    ));
    out.push(ds(
        "d_decay_d_eigenvalue",
        pick(&|c| c.ddecay_dlambda),
        "(1/s)/(rad^2/s^2)",
        "decay d = (alpha + beta lambda)/2",
    ));
    let mut ranges = Vec::new();
    for c in &s.clusters {
        ranges.extend_from_slice(&[c.modes.start as f64, c.modes.end as f64]);
    }
    out.push(io::ExtraDataset {
        path: "/sensitivities/clusters".into(),
        shape: vec![s.clusters.len(), 2],
        data: ranges,
        attrs: vec![
            (
                "meaning".into(),
                "mode index ranges [start, end) of near-degenerate clusters".into(),
            ),
            ("cluster_rtol".into(), format!("{:e}", modes.cluster_rtol)),
        ],
    });
    for (k, c) in s.clusters.iter().enumerate() {
        let mut data = Vec::new();
        for v in [&c.d_youngs, &c.d_poisson, &c.d_density] {
            data.extend_from_slice(v);
        }
        out.push(io::ExtraDataset {
            path: format!("/sensitivities/cluster_split/{k:03}"),
            shape: vec![3, c.modes.len()],
            data,
            attrs: vec![
                (
                    "modes".into(),
                    format!("{}..{}", c.modes.start, c.modes.end),
                ),
                (
                    "rows".into(),
                    "d/dE [rad^2/s^2/Pa], d/dnu [rad^2/s^2], d/drho [rad^2/s^2/(kg/m^3)]".into(),
                ),
                (
                    "meaning".into(),
                    "eigenvalues of Phi^T (dK - mean(lambda) dM) Phi over the cluster".into(),
                ),
            ],
        });
    }
    out
}

/// The inertia proof in one line: both counts and the verdict.
fn inertia_line(c: &eigen::InertiaCheck) -> String {
    let second = c.second.map_or(String::new(), |(t2, below, found)| {
        format!("; {below} below {t2:.6e}, {found} found")
    });
    let verdict = match &c.verdict {
        eigen::CountVerdict::Complete => "complete".to_string(),
        eigen::CountVerdict::Missed => "MISSED MODES".to_string(),
        eigen::CountVerdict::Unproven(_) => "UNPROVEN (see the warning)".to_string(),
    };
    let retries = if c.factor_log.retries() > 0 {
        format!(" [factor tries {}]", c.factor_log.describe())
    } else {
        String::new()
    };
    format!(
        "{} eigenvalues below {:.6e} rad^2/s^2, {} found{second} -> {verdict}{retries}",
        c.below, c.threshold, c.found
    )
}

#[allow(clippy::too_many_arguments)]
fn print_summary(
    job: &Job,
    mesh: &TetMesh,
    stats: &assembly::AssemblyStats,
    modes: &eigen::Modes<'_>,
    freqs: &[f64],
    total: f64,
    ranks: usize,
    sens: Option<&sensitivity::MaterialSensitivities>,
) {
    println!(
        "diffsound modes: {} ({} tets, {} DOF, P{}, {} rank(s))",
        job.mesh.display(),
        mesh.n_tets(),
        stats.n_dofs,
        job.order,
        ranks
    );
    println!(
        "material: {} E={:.4e} Pa nu={} rho={} kg/m3",
        job.material_name,
        job.material.youngs_modulus,
        job.material.poisson_ratio,
        job.material.density
    );
    println!(
        "rigid modes removed: {}  |  elastic modes: {}",
        modes.rigid_eigenvalues.len(),
        modes.eigenvalues.len()
    );
    if let Some(c) = &modes.inertia_check {
        println!("inertia check: {}", inertia_line(c));
    }
    let sens_header = if sens.is_some() {
        format!(" {:>14} {:>12}", "df/dE [Hz/GPa]", "df/dnu [Hz]")
    } else {
        String::new()
    };
    println!(
        "{:>5} {:>14} {:>18} {:>10}{}",
        "mode", "freq [Hz]", "lambda [rad2/s2]", "residual", sens_header
    );
    for (i, (&l, &f)) in modes.eigenvalues.iter().zip(freqs).enumerate() {
        let tag = if modes.clusters.iter().any(|r| r.contains(&i)) {
            " *"
        } else {
            ""
        };
        let sens_cols = sens.map_or(String::new(), |s| {
            let dfdl = 1.0 / (4.0 * std::f64::consts::PI * l.sqrt());
            format!(
                " {:>14.4} {:>12.2}",
                s.d_youngs[i] * dfdl * 1e9,
                s.d_poisson[i] * dfdl
            )
        });
        println!(
            "{:>5} {:>14.4} {:>18.10e} {:>10.2e}{}{}",
            i, f, l, modes.residuals[i], sens_cols, tag
        );
    }
    if !modes.clusters.is_empty() {
        println!(
            "(* near-degenerate cluster: relative eigenvalue gap <= {:e})",
            modes.cluster_rtol
        );
    }
    println!(
        "time: assembly {:.2} s, solve {:.2} s, total {:.2} s; output {}",
        stats.seconds,
        modes.solve_seconds,
        total,
        job.out.display()
    );
}
