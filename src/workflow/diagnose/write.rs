//! The diagnosis's files (module docs of [`crate::workflow::diagnose`], "Output"): the HDF5
//! result, the JSON report, and the map of the localisation for ParaView.

use super::{Error, Refusal, Report};
use crate::diagnose::catalogue;
use crate::io::results::ResultsFile;
use crate::io::{write_modes, MaterialRecord, ModesFile, NodeField};

pub(super) fn output(e: impl std::fmt::Display) -> Error {
    Error::Output(e.to_string())
}

/// Writes `<out stem>.json`, the whole report (module docs, "Output"), atomically.
pub fn write_json(r: &Report) -> Result<(), Error> {
    let (job, measured, report, youngs, poisson) =
        (&r.job, &r.measured, &r.catalogue, r.youngs, r.poisson);
    let (line_start, loaded, feats, localised) =
        (r.line_start, r.loaded.as_ref(), &r.features, &r.localised);
    let catalogue_input = (&r.evidence, &r.final_settings);
    let rest = serde_json::json!({
        // The pitch-glide rows are the chirp fit's g per mode (relative offset at the onset),
        // not an early-minus-late frequency difference: the scorer compares accordingly.
        "glide_observable": "offset_at_onset",
        "material": {"youngs_modulus": youngs, "poisson_ratio": poisson, "density": job.density, "source": job.material_source, "line_spectrum_start": line_start, "line_spectrum_poisson_at_edge": line_start.is_some_and(|s| s.poisson_at_edge()), "loaded_line_match": loaded},
        "strike": feats.strike_note,
        "localisation": {"best_vertex": localised.best.map(|b| b.0), "best_z": localised.best.map(|b| b.1), "offered_region": localised.region},
        "catalogue": report,
        // What the final catalogue pass saw, so that it can be replayed without the audio,
        // the mesh or the solver (examples/catalogue_replay).
        "catalogue_input": {"evidence": catalogue_input.0, "settings": catalogue_input.1},
    });
    let value = with_common_keys(job, measured, true, &report.untested(), &r.timings, rest);
    write_json_value(&job.json, &value)
}

/// Writes `<out stem>.json` for a diagnosis the recordings could not support (module docs of
/// [`crate::workflow::diagnose`], "Too few modes"), atomically: the same keys a reader of a
/// full report looks for first, with nothing accepted and every effect untested.
pub fn write_refusal_json(r: &Refusal) -> Result<(), Error> {
    let rest = serde_json::json!({
        "refusal": r.reason,
        "catalogue": {"accepted": [], "rejected": r.untested},
    });
    let untested: Vec<&catalogue::RejectedEffect> = r.untested.iter().collect();
    let value = with_common_keys(&r.job, &r.measured, false, &untested, &r.timings, rest);
    write_json_value(&r.job.json, &value)
}

/// The keys of every `<out stem>.json`, a full report's or a refusal's, with `rest` (an object)
/// added: format, command, inputs, microphones and their health, the onset, the modes
/// observed, the effects the recordings could not test and why, and the seconds per stage.
fn with_common_keys(
    job: &super::Job,
    measured: &super::Measured,
    diagnosed: bool,
    untested: &[&catalogue::RejectedEffect],
    timings: &[(&'static str, f64)],
    rest: serde_json::Value,
) -> serde_json::Value {
    let mut value = serde_json::json!({
        "format": "diffsound.diagnose",
        "format_version": 1,
        "diagnosed": diagnosed,
        "command": std::env::args().collect::<Vec<_>>().join(" "),
        "version": env!("CARGO_PKG_VERSION"),
        "mesh": job.mesh.display().to_string(),
        "recordings": job.recordings.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
        "fit_microphones": job.fit_channels,
        "held_out_microphones": job.held_channels,
        // Every recording's health and verdict; the unhealthy ones were left out.
        "channel_health": job.channel_health,
        "onset_s": measured.onset_s,
        "observed": {"fit": measured.fit, "held_out": measured.held_out},
        // The effects these recordings could not test, and why (a subset of the rejections).
        "untested": untested.iter().map(|r| serde_json::json!({"name": r.name, "reason": r.reason, "detail": r.detail})).collect::<Vec<_>>(),
        "timings_s": timings.iter().map(|(k, v)| (k.to_string(), *v)).collect::<std::collections::BTreeMap<_, _>>(),
    });
    if let (Some(map), serde_json::Value::Object(rest)) = (value.as_object_mut(), rest) {
        map.extend(rest);
    }
    value
}

fn write_json_value(path: &std::path::Path, value: &serde_json::Value) -> Result<(), Error> {
    let text = serde_json::to_string_pretty(value).map_err(output)?;
    crate::io::write_atomically(path, |tmp| {
        std::fs::write(tmp, &text).map_err(|source| crate::io::IoError::Fs {
            path: tmp.to_path_buf(),
            context: "writing the JSON report".into(),
            source,
        })
    })
    .map_err(output)?;
    Ok(())
}

/// The `format` attribute of the HDF5 result.
pub const FORMAT: &str = "diffsound.diagnose";
/// Its `format_version` (module docs, "Output", for what changed).
pub const FORMAT_VERSION: u64 = 2;

/// An enum's serde name (`snake_case`), the word the HDF5 file stores.
fn serde_word<T: serde::Serialize>(value: &T) -> String {
    serde_json::to_value(value)
        .ok()
        .and_then(|v| v.as_str().map(str::to_owned))
        .unwrap_or_default()
}

/// Writes the HDF5 result `out` (module docs, "Output"), atomically.
pub fn write_hdf5(r: &Report) -> Result<(), Error> {
    let (job, n_ranks, measured, evidence, report) =
        (&r.job, r.n_ranks, &r.measured, &r.evidence, &r.catalogue);
    let (youngs, poisson, localised, feats, timings) =
        (r.youngs, r.poisson, &r.localised, &r.features, &r.timings);
    let mut file = ResultsFile::new(FORMAT, FORMAT_VERSION);
    let integers = |v: &[usize]| v.iter().map(|&i| i as i64).collect::<Vec<i64>>();
    file.text("/", "mesh", &job.mesh.display().to_string())
        .texts(
            "/",
            "recordings",
            job.recordings
                .iter()
                .map(|p| p.display().to_string())
                .collect(),
        )
        .integers("/", "fit_microphones", integers(&job.fit_channels))
        .integers("/", "held_out_microphones", integers(&job.held_channels))
        .integer("/", "n_ranks", n_ranks as i64)
        .text(
            "/",
            "command",
            &std::env::args().collect::<Vec<_>>().join(" "),
        )
        .text("/", "version", env!("CARGO_PKG_VERSION"))
        .number("/material", "youngs_modulus", youngs)
        .number("/material", "poisson_ratio", poisson)
        .number("/material", "density", job.density)
        .text("/material", "source", job.material_source.kind());
    if let Some(p) = job.material_source.path() {
        file.text("/material", "source_path", &p.display().to_string());
    }
    if !job.channel_health.is_empty() {
        // Per recording: its SNR, whether it was used (fit or held out), and the verdict.
        let used = |c: usize| job.fit_channels.contains(&c) || job.held_channels.contains(&c);
        file.column(
            "/channels/snr_db",
            job.channel_health.iter().map(|h| h.snr_db).collect(),
            "dB",
        )
        .flags(
            "/channels/used",
            (0..job.channel_health.len()).map(used).collect(),
        )
        .texts(
            "/channels",
            "names",
            job.channel_health.iter().map(|h| h.name.clone()).collect(),
        )
        .texts(
            "/channels",
            "verdicts",
            job.channel_health
                .iter()
                .map(|h| serde_word(&h.verdict))
                .collect(),
        );
    }
    for (group, modes) in [
        ("/observed", &measured.fit),
        ("/held_out", &measured.held_out),
    ] {
        if modes.is_empty() {
            continue;
        }
        let c = modes[0].amplitudes.len();
        file.column(
            &format!("{group}/frequency_hz"),
            modes.iter().map(|m| m.frequency_hz).collect(),
            "Hz",
        )
        .column(
            &format!("{group}/frequency_sd_hz"),
            modes.iter().map(|m| m.sigma_frequency_hz).collect(),
            "Hz",
        )
        .column(
            &format!("{group}/decay_rate"),
            modes.iter().map(|m| m.decay_rate).collect(),
            "1/s",
        )
        .column(
            &format!("{group}/decay_rate_sd"),
            modes.iter().map(|m| m.sigma_decay_rate).collect(),
            "1/s",
        )
        .dataset(
            &format!("{group}/amplitudes"),
            &[modes.len(), c],
            modes.iter().flat_map(|m| m.amplitudes.clone()).collect(),
            "full scale",
        );
    }
    let s = &evidence.simulated;
    file.column(
        "/simulated/frequency_hz",
        s.iter().map(|m| m.frequency_hz).collect(),
        "Hz",
    )
    .column(
        "/simulated/drive",
        s.iter().map(|m| m.drive).collect(),
        "kg^-1/2",
    )
    .column(
        "/simulated/support_weight",
        s.iter().map(|m| m.support_weight).collect(),
        "1",
    )
    .column(
        "/simulated/mass_weight",
        s.iter().map(|m| m.mass_weight).collect(),
        "1",
    )
    .indices("/simulated/cluster", s.iter().map(|m| m.cluster).collect());
    let pairs = &report.matching.pairs;
    if !pairs.is_empty() {
        file.indices(
            "/matching/observed",
            pairs.iter().map(|p| p.observed).collect(),
        )
        .signed(
            "/matching/simulated_first",
            pairs.iter().map(|p| p.simulated.first().copied()).collect(),
        )
        .column(
            "/matching/observed_hz",
            pairs.iter().map(|p| p.observed_hz).collect(),
            "Hz",
        )
        .column(
            "/matching/simulated_hz",
            pairs.iter().map(|p| p.simulated_hz).collect(),
            "Hz",
        );
    }
    let rows = &report.residuals;
    if !rows.is_empty() {
        let rms_a = |z: &catalogue::ZScores| {
            let v: Vec<f64> = z.ln_amplitude.iter().flatten().copied().collect();
            if v.is_empty() {
                f64::NAN
            } else {
                (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
            }
        };
        file.column(
            "/residuals/frequency_hz",
            rows.iter().map(|r| r.frequency_hz).collect(),
            "Hz",
        )
        .column(
            "/residuals/z_ln_f_before",
            rows.iter().map(|r| r.before.ln_frequency).collect(),
            "1",
        )
        .column(
            "/residuals/z_ln_f_after",
            rows.iter().map(|r| r.after.ln_frequency).collect(),
            "1",
        )
        .column(
            "/residuals/z_ln_d_before",
            rows.iter()
                .map(|r| r.before.ln_decay.unwrap_or(f64::NAN))
                .collect(),
            "1",
        )
        .column(
            "/residuals/z_ln_d_after",
            rows.iter()
                .map(|r| r.after.ln_decay.unwrap_or(f64::NAN))
                .collect(),
            "1",
        )
        .column(
            "/residuals/z_ln_a_before",
            rows.iter().map(|r| rms_a(&r.before)).collect(),
            "1",
        )
        .column(
            "/residuals/z_ln_a_after",
            rows.iter().map(|r| rms_a(&r.after)).collect(),
            "1",
        );
    }
    if let Some(env) = &measured.envelopes {
        file.column("/envelopes/times_s", env.times_s.clone(), "s")
            .column("/envelopes/band_edges_hz", env.band_edges_hz.clone(), "Hz")
            .column(
                "/envelopes/noise_floor",
                env.noise_floor_estimate.clone(),
                "full scale^2",
            )
            .dataset(
                "/envelopes/energy",
                &[env.energy.len(), env.times_s.len()],
                env.energy.iter().flatten().copied().collect(),
                "full scale^2",
            );
    }
    file.texts(
        "/effects",
        "accepted",
        report.accepted.iter().map(|a| a.name.clone()).collect(),
    )
    .texts(
        "/effects",
        "accepted_variants",
        report.accepted.iter().map(|a| a.variant.clone()).collect(),
    )
    .texts(
        "/effects",
        "rejected",
        report.rejected.iter().map(|r| r.name.clone()).collect(),
    )
    .texts(
        "/effects",
        "rejected_reasons",
        report
            .rejected
            .iter()
            .map(|r| serde_word(&r.reason))
            .collect(),
    )
    .number(
        "/effects",
        "held_out_before",
        report.baseline.held_out_error.unwrap_or(f64::NAN),
    )
    .number(
        "/effects",
        "held_out_after",
        report.final_model.held_out_error.unwrap_or(f64::NAN),
    )
    .number("/effects", "bic_baseline", report.baseline.bic)
    .number("/effects", "bic_final", report.final_model.bic);
    file.indices("/localisation/vertex", feats.surface.to_vec())
        .column(
            "/localisation/mu",
            localised.map.iter().map(|m| m.0).collect(),
            "1",
        )
        .column(
            "/localisation/z",
            localised.map.iter().map(|m| m.1).collect(),
            "1",
        );
    for (k, v) in timings {
        file.number("/timings", k, *v);
    }
    file.write(&job.out).map_err(output)?;
    Ok(())
}

/// Writes `<out stem>_map.h5` and its `.xdmf` sidecar: the simulated modes and the node field
/// `mass_region_z` of the localisation.
pub fn write_map(r: &Report) -> Result<(), Error> {
    let (job, mesh, eigenvalues, shapes, rigid) = (
        &r.job,
        &r.mesh,
        &r.eigenvalues,
        &r.shapes,
        &r.rigid_eigenvalues,
    );
    let (youngs, poisson, feats, localised) = (r.youngs, r.poisson, &r.features, &r.localised);
    let mut field = vec![0.0; mesh.n_nodes()];
    for (&v, m) in feats.surface.iter().zip(&localised.map) {
        field[v] = m.1;
    }
    let residual_norms = vec![f64::NAN; eigenvalues.len()];
    let file = ModesFile {
        nodes: &mesh.nodes,
        connectivity: &mesh.connectivity,
        nodes_per_tet: mesh.nodes_per_tet(),
        material: MaterialRecord::undamped("diagnosis", youngs, poisson, job.density),
        eigenvalues,
        frequencies_hz: &feats.frequencies_hz,
        mode_shapes: shapes,
        residual_norms: &residual_norms,
        rigid_eigenvalues: rigid,
        solver: Vec::new(),
        n_ranks: 1,
        element_order: 2,
        timings: Vec::new(),
        provenance: vec![(
            "command".into(),
            std::env::args().collect::<Vec<_>>().join(" "),
        )],
        extra_datasets: Vec::new(),
        node_fields: vec![NodeField::scalar(
            "mass_region_z",
            &field,
            "1 (z of the added-mass regression at this surface vertex; 0 inside)",
        )],
    };
    write_modes(&job.map, &file).map_err(output)?;
    Ok(())
}
