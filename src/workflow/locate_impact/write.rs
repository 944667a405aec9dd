//! The job's files (module docs of [`super`], "Output"): the HDF5 result, the JSON summary,
//! the map on the mesh (HDF5 + XDMF for ParaView) and the PNG. Each writer only writes; the
//! command says what it wrote.

use super::{Error, Job, Report};
use crate::io::plot::{surface_png, SurfaceFigure, SurfaceMarker, SurfacePanel, View};
use crate::io::results::ResultsFile;
use crate::io::{write_modes, MaterialRecord, ModesFile, NodeField};

/// The `format` attribute of `OUT.h5`.
pub const FORMAT: &str = "diffsound.locate_impact";
/// Its `format_version`: 2 stores indices as integers, flags as u8, `recordings` as a string
/// array and the material's source as `source` + `source_path` (1: all f64, joined text).
pub const FORMAT_VERSION: u64 = 2;

/// `OUT.h5`: the result (the material, the map, the top candidates, the modes and poles, the
/// clusters' amplitudes, the evaluation, the timings).
pub fn write_hdf5(job: &Job, r: &Report) -> Result<(), Error> {
    let (map, table) = (&r.map, &r.table);
    let best = table.candidates[map.best].vertex;
    let mut file = ResultsFile::new(FORMAT, FORMAT_VERSION);
    file.text("/", "mesh", &job.mesh.display().to_string())
        .texts(
            "/",
            "recordings",
            job.recordings
                .iter()
                .map(|p| p.display().to_string())
                .collect(),
        )
        .integer("/", "n_ranks", r.n_ranks as i64)
        .text("/", "command", &job.command)
        .text("/", "version", env!("CARGO_PKG_VERSION"))
        .number("/material", "youngs_modulus", job.material.youngs_modulus)
        .number("/material", "poisson_ratio", job.material.poisson_ratio)
        .number("/material", "density", job.material.density)
        .text("/material", "source", job.material_source.kind())
        .integer("/impact", "best_vertex", best as i64)
        .number("/impact", "strength", map.strength)
        .number("/impact", "strength_sd", map.strength_sd)
        .text(
            "/impact",
            "strength_units",
            "recording units per N·s of impulse",
        )
        .number("/impact", "sigma_model_at_best", map.sigma_model[map.best])
        .integer("/impact", "terms", map.terms as i64)
        .integer("/impact", "terms_below_limit", map.terms_below_limit as i64)
        .number("/impact", "frequency_scale", r.assignment.scale)
        .text("/impact", "transfer", &r.transfer_note)
        .dataset(
            "/impact/best_position",
            &[3],
            r.mesh.nodes[best].to_vec(),
            "m",
        );
    if let Some(p) = job.material_source.path() {
        file.text("/material", "source_path", &p.display().to_string());
    }
    file.indices(
        "/map/vertex",
        table.candidates.iter().map(|c| c.vertex).collect(),
    )
    .column("/map/posterior", map.posterior.clone(), "1")
    .column("/map/log_likelihood", map.log_likelihood.clone(), "1")
    .column("/map/cosine", map.cosine.clone(), "1")
    .column("/map/area_share", map.area_share.clone(), "1")
    .column(
        "/map/log_strength",
        map.log_strength.clone(),
        "ln(recording units per N·s)",
    )
    .column("/map/sigma_model", map.sigma_model.clone(), "ln amplitude");
    file.indices("/top/vertex", map.top.iter().map(|t| t.vertex).collect())
        .dataset(
            "/top/position",
            &[map.top.len(), 3],
            map.top.iter().flat_map(|t| t.position).collect(),
            "m",
        )
        .column(
            "/top/neighbourhood_mass",
            map.top.iter().map(|t| t.neighbourhood_mass).collect(),
            "1",
        )
        .column(
            "/top/log_likelihood",
            map.top.iter().map(|t| t.log_likelihood).collect(),
            "1",
        )
        .column(
            "/top/strength",
            map.top.iter().map(|t| t.strength).collect(),
            "recording units per N·s",
        );
    file.column("/modes/simulated_hz", r.sim_hz.to_vec(), "Hz")
        .indices("/modes/cluster", r.cluster_of.to_vec());
    file.column(
        "/poles/frequency_hz",
        r.assignment.poles.iter().map(|p| p.frequency_hz).collect(),
        "Hz",
    )
    .column(
        "/poles/decay_rate",
        r.assignment.poles.iter().map(|p| p.decay_rate).collect(),
        "1/s",
    )
    .signed("/poles/cluster", r.assignment.pole_cluster.to_vec());
    let (nc, nm) = (table.clusters.len(), table.microphones);
    let flat = |v: &Vec<Vec<f64>>| v.iter().flatten().copied().collect::<Vec<f64>>();
    let predicted: Vec<f64> = (0..nc)
        .flat_map(|c| (0..nm).map(move |m| (c, m)))
        .map(|(c, m)| table.amplitude(map.best, c, m) * map.strength)
        .collect();
    file.dataset(
        "/clusters/measured_amplitude",
        &[nc, nm],
        flat(&r.fit_clusters.amplitude),
        "recording units",
    )
    .dataset(
        "/clusters/measured_sd",
        &[nc, nm],
        flat(&r.fit_clusters.sd),
        "recording units",
    )
    .dataset(
        "/clusters/predicted_at_best",
        &[nc, nm],
        predicted,
        "recording units",
    )
    .flags("/clusters/heard", r.assignment.observed.to_vec());
    if let Some(e) = &r.evaluation {
        file.integer("/evaluation", "true_vertex", e.true_vertex as i64)
            .number("/evaluation", "geodesic_error_m", e.geodesic_error_m)
            .number("/evaluation", "area_rank", e.area_rank)
            .integer("/evaluation", "orbit_size", e.orbit_size as i64)
            .flag("/evaluation", "best_on_orbit", e.best_on_orbit)
            .number("/evaluation", "orbit_error_m", e.orbit_error_m);
    }
    for (k, v) in &r.timings {
        file.number("/timings", k, *v);
    }
    file.write(&job.out)
        .map_err(|e| Error::Output(e.to_string()))?;
    Ok(())
}

/// `OUT.json`: the summary.
pub fn write_json(job: &Job, r: &Report) -> Result<(), Error> {
    let (map, table) = (&r.map, &r.table);
    let value = serde_json::json!({
        "format": "diffsound.locate_impact",
        "format_version": 1,
        "command": job.command,
        "version": env!("CARGO_PKG_VERSION"),
        "mesh": job.mesh.display().to_string(),
        "recordings": job.recordings.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
        "onset_s": r.measured.onset_s,
        "material": {"youngs_modulus": job.material.youngs_modulus, "poisson_ratio": job.material.poisson_ratio, "density": job.material.density, "source": job.material_source.to_string()},
        "transfer": r.transfer_note,
        "frequency_scale": r.assignment.scale,
        "clusters": table.clusters.len(),
        "clusters_heard": r.assignment.observed.iter().filter(|o| **o).count(),
        "best_vertex": table.candidates[map.best].vertex,
        "best_position_m": r.mesh.nodes[table.candidates[map.best].vertex],
        "strength": map.strength,
        "strength_sd": map.strength_sd,
        "strength_units": "recording units per N·s of impulse",
        "sigma_model_at_best": map.sigma_model[map.best],
        "top": map.top,
        "evaluation": r.evaluation,
        "timings_s": r.timings.iter().map(|(k, v)| (k.to_string(), *v)).collect::<std::collections::BTreeMap<_, _>>(),
    });
    let text = serde_json::to_string_pretty(&value).map_err(|e| Error::Output(e.to_string()))?;
    crate::io::write_atomically(&job.json, |tmp| {
        std::fs::write(tmp, &text).map_err(|source| crate::io::IoError::Fs {
            path: tmp.to_path_buf(),
            context: "writing the JSON summary".into(),
            source,
        })
    })
    .map_err(|e| Error::Output(e.to_string()))?;
    Ok(())
}

/// Posterior density (normalised to a maximum of 1) and log-likelihood ratio per mesh node.
fn node_fields(r: &Report) -> (Vec<f64>, Vec<f64>) {
    let (map, table) = (&r.map, &r.table);
    let n = r.mesh.n_nodes();
    let density: Vec<f64> = map
        .posterior
        .iter()
        .zip(&map.area_share)
        .map(|(p, a)| if *a > 0.0 { p / a } else { 0.0 })
        .collect();
    let top_density = density.iter().cloned().fold(0.0, f64::max);
    let top_ll = map.log_likelihood[map.best];
    let mut dens = vec![0.0; n];
    let mut ratio = vec![LOG_RATIO_FLOOR; n];
    for (i, c) in table.candidates.iter().enumerate() {
        dens[c.vertex] = if top_density > 0.0 {
            density[i] / top_density
        } else {
            0.0
        };
        ratio[c.vertex] = (map.log_likelihood[i] - top_ll).max(LOG_RATIO_FLOOR);
    }
    (dens, ratio)
}

/// Log-likelihood ratios below this are drawn at it (e^−50: no support).
const LOG_RATIO_FLOOR: f64 = -50.0;

/// `OUT_map.h5` + `.xdmf`: the mesh and the modes with the node fields `posterior_density`
/// and `log_likelihood_ratio`.
pub fn write_map(job: &Job, r: &Report) -> Result<(), Error> {
    let (eigenvalues, shapes, rigid) = (&r.eigenvalues, &r.shapes, &r.rigid_eigenvalues);
    let (dens, ratio) = node_fields(r);
    let residual_norms = vec![f64::NAN; eigenvalues.len()];
    let m = &job.material;
    let file = ModesFile {
        nodes: &r.mesh.nodes,
        connectivity: &r.mesh.connectivity,
        nodes_per_tet: r.mesh.nodes_per_tet(),
        material: MaterialRecord::undamped(
            "locate-impact",
            m.youngs_modulus,
            m.poisson_ratio,
            m.density,
        ),
        eigenvalues,
        frequencies_hz: &r.sim_hz,
        mode_shapes: shapes,
        residual_norms: &residual_norms,
        rigid_eigenvalues: rigid,
        solver: Vec::new(),
        n_ranks: 1,
        element_order: 2,
        timings: Vec::new(),
        provenance: vec![("command".into(), job.command.clone())],
        extra_datasets: Vec::new(),
        node_fields: vec![
            NodeField::scalar(
                "posterior_density",
                &dens,
                "1 (posterior per unit area over its maximum; 0 off the surface)",
            ),
            NodeField::scalar(
                "log_likelihood_ratio",
                &ratio,
                "1 (ℓ − max ℓ, floored at −50)",
            ),
        ],
    };
    write_modes(&job.map_file, &file).map_err(|e| Error::Output(e.to_string()))?;
    Ok(())
}

/// `OUT_map.png`: the log-likelihood ratio on the surface seen from four sides, the top three
/// candidates (and the truth, when known) marked.
pub fn write_png(job: &Job, r: &Report) -> Result<(), Error> {
    let (_, ratio) = node_fields(r);
    let triangles = r.mesh.boundary_faces();
    let mut values = vec![f64::NAN; r.mesh.n_nodes()];
    for c in &r.table.candidates {
        // ℓ − max ℓ on a readable scale: 0 (best) down to −20.
        values[c.vertex] = ratio[c.vertex].max(-20.0);
    }
    let colours = [[214, 39, 40], [255, 127, 14], [255, 187, 120]];
    let mut panel = SurfacePanel::new(
        "log-likelihood ratio ℓ − max ℓ",
        r.mesh.nodes.clone(),
        triangles.clone(),
    )
    .with_values(values);
    for (i, t) in r.map.top.iter().take(3).enumerate() {
        panel = panel.with_marker(SurfaceMarker::new(
            r.mesh.nodes[t.vertex],
            format!("{}", i + 1),
            colours[i],
        ));
    }
    if let Some(e) = &r.evaluation {
        panel = panel.with_marker(SurfaceMarker::new(
            r.mesh.nodes[e.true_vertex],
            "true",
            [255, 255, 255],
        ));
    }
    let mut fig = SurfaceFigure::new(
        format!(
            "Where was it struck? {} (best vertex {})",
            job.mesh
                .file_name()
                .map_or(String::new(), |n| n.to_string_lossy().to_string()),
            r.table.candidates[r.map.best].vertex
        ),
        vec![panel],
    );
    fig.views = vec![
        View::new(30.0, 35.0),
        View::new(210.0, 35.0),
        View::labelled(0.0, 89.0, "top"),
        View::labelled(0.0, -89.0, "below"),
    ];
    fig.value_label = "ℓ − max ℓ".into();
    fig.value_range = Some((-20.0, 0.0));
    surface_png(&job.png, &fig).map_err(|e| Error::Output(e.to_string()))?;
    Ok(())
}
