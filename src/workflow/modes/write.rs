//! The `modes` job's files: the HDF5 modes file with its XDMF sidecar, the WAV of one strike,
//! and the timings JSON for benchmarks. All are written on rank 0.

use super::{Error, Job, Report};
use crate::audio::{self, ModalBank, WavFormat};
use crate::eigen::{self, sensitivity};
use crate::io::{self, MaterialRecord, ModesFile};
use crate::mesh::TetMesh;
use crate::workflow::Progress;
use std::path::Path;

/// Writes the HDF5 modes file (+ XDMF) and, if asked for, the WAV of the strike. Rank 0 only.
pub fn write_outputs(job: &Job, report: &Report<'_>, progress: &Progress) -> Result<(), Error> {
    let modes = &report.modes;
    let stats = &report.stats;
    let t = &report.timings;
    let mut solver = modes.settings.clone();
    solver.push(("petsc_options".into(), job.petsc_options.join(" ")));
    let (pv, sv) = report.versions.clone();
    solver.push(("petsc_version".into(), pv));
    solver.push(("slepc_version".into(), sv));
    if let Some(c) = &modes.inertia_check {
        solver.push(("inertia_check".into(), inertia_line(c)));
    }
    if let Some(c) = &modes.probe_check {
        solver.push(("completeness_probe".into(), probe_line(c)));
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
        ("assembly".to_string(), stats.seconds + t.operator_seconds),
        ("solve".to_string(), modes.solve_seconds),
        (
            "inertia_check".to_string(),
            modes.inertia_check.as_ref().map_or(0.0, |c| c.seconds),
        ),
        (
            "completeness_probe".to_string(),
            modes.probe_check.as_ref().map_or(0.0, |c| c.seconds),
        ),
        ("sensitivities".to_string(), t.sensitivity_seconds),
        ("material_sensitivities".to_string(), t.material_seconds),
        ("node_gradients".to_string(), t.node_gradient_seconds),
        ("total".to_string(), t.total_seconds()),
        ("peak_rss_bytes_sum".to_string(), t.peak_rss_sum),
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
    let node_field_names: Vec<String> = (0..report.node_gradients.as_ref().map_or(0, Vec::len))
        .map(|k| format!("d_lambda_dx_mode_{k:0width$}"))
        .collect();
    let mesh = &report.mesh;
    let file = ModesFile {
        nodes: &mesh.nodes,
        connectivity: &mesh.connectivity,
        nodes_per_tet: mesh.nodes_per_tet(),
        material: MaterialRecord::of(job.material_name.clone(), &job.material),
        eigenvalues: &modes.eigenvalues,
        frequencies_hz: &report.frequencies,
        mode_shapes: &report.shapes,
        residual_norms: &modes.residuals,
        rigid_eigenvalues: &modes.rigid_eigenvalues,
        solver,
        n_ranks: report.n_ranks,
        element_order: job.order,
        timings,
        provenance,
        extra_datasets: report
            .material_sensitivities
            .as_ref()
            .map(|s| sensitivity_datasets(s, modes, &job.material))
            .unwrap_or_default(),
        node_fields: node_field_names
            .iter()
            .zip(report.node_gradients.iter().flatten())
            .map(|(name, data)| io::NodeField::vector(name, data, "rad^2/s^2/m"))
            .collect(),
    };
    io::write_modes(&job.out, &file)?;
    progress.say(format!("wrote {} and its .xdmf sidecar", job.out.display()));

    if let (Some(wav), Some(vertex)) = (&job.wav, report.strike) {
        render_strike(wav, mesh, vertex, &modes.eigenvalues, &report.shapes, job)?;
        progress.say(format!(
            "wrote {} (strike at node {})",
            wav.display(),
            vertex.0
        ));
    }
    Ok(())
}

/// Assembly/solve timings, memory and eigenvalues as JSON (for benchmarks), to `path`.
pub fn write_timings_json(path: &Path, report: &Report<'_>) -> Result<(), Error> {
    let modes = &report.modes;
    let stats = &report.stats;
    let t = &report.timings;
    let json = serde_json::json!({
        "ndof": stats.n_dofs,
        "n_ranks": report.n_ranks,
        "assembly_s": stats.seconds + t.operator_seconds,
        "solve_s": modes.solve_seconds,
        "inertia_check_s": modes.inertia_check.as_ref().map_or(0.0, |c| c.seconds),
        "solver_path": modes.path.word(),
        "probe_s": modes.probe_check.as_ref().map_or(0.0, |c| c.seconds),
        "probe": modes.probe_check.as_ref().map(|c| serde_json::json!({
            "last_kept": c.last_kept,
            "lowest_in_complement": c.lowest_in_complement,
            "complement_of": c.complement_of,
            "verdict": c.verdict.word(),
        })),
        "preconditioner_setup_s": modes.preconditioner_setup.map_or(0.0, |s| s.seconds),
        "iterative_preconditioner": modes.setting("iterative_preconditioner"),
        "iterations": modes.setting("iterations").and_then(|v| v.parse::<usize>().ok()),
        "peak_rss_mb_after": report.timings.peak_rss_after.iter().map(|(k, v)| (k.clone(), serde_json::json!(v / 1048576.0))).collect::<serde_json::Map<_, _>>(),
        "material_sensitivities_s": t.material_seconds,
        "node_gradients_s": t.node_gradient_seconds,
        "total_s": t.total_seconds(),
        "peak_rss_mb": t.peak_rss_sum / 1048576.0,
        "mallocs": stats.mallocs,
        "eigenvalues": modes.eigenvalues,
        "frequencies_hz": report.frequencies,
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
        std::fs::write(tmp, serde_json::to_string_pretty(&json).unwrap_or_default()).map_err(|e| {
            io::IoError::Fs {
                path: tmp.to_path_buf(),
                context: "writing timings".into(),
                source: e,
            }
        })
    })?;
    Ok(())
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
) -> Result<(), Error> {
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
    audio::write_wav(path, &samples, job.sample_rate, WavFormat::Pcm16, Some(0.9))?;
    Ok(())
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
        integer: false,
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
        integer: true,
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
            integer: false,
        });
    }
    out
}

/// The iterative path's completeness probe in one line (module docs of
/// [`crate::eigen::iterative`]: a check, not a proof).
pub fn probe_line(c: &eigen::ProbeCheck) -> String {
    let lowest = c
        .lowest_in_complement
        .map_or("not found".to_string(), |l| format!("{l:.6e}"));
    let verdict = match &c.verdict {
        eigen::ProbeVerdict::Consistent => "consistent (a check, not a proof: no factor)",
        eigen::ProbeVerdict::Missed => "MISSED MODES",
        eigen::ProbeVerdict::Inconclusive(_) => "INCONCLUSIVE (see the warning)",
    };
    format!(
        "lowest eigenvalue orthogonal to the {} modes returned {lowest} rad^2/s^2, last kept {:.6e} -> {verdict}",
        c.complement_of, c.last_kept
    )
}

/// The inertia proof in one line: both counts and the verdict (the summary's line and the HDF5
/// file's `inertia_check` setting).
pub fn inertia_line(c: &eigen::InertiaCheck) -> String {
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
