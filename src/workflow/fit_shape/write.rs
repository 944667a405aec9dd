//! The files of a shape fit: the HDF5 result (`diffsound.fit_shape`, layout in the module
//! docs of [`super`]) and the fitted body's mesh with its modes (HDF5 + XDMF).

use super::{Error, Job, Report, Task};
use crate::inverse::shape::SearchPhase;
use crate::io::results::ResultsFile;
use crate::shape::union_box;
use crate::workflow::write_body_modes;

/// Writes `job.out` and `job.mesh_out` (+ .xdmf) from the report (rank 0).
pub fn write_outputs(job: &Job, report: &Report) -> Result<(), Error> {
    write_results(job, report).map_err(Error::Output)
}

fn write_results(job: &Job, report: &Report) -> Result<(), String> {
    let Report {
        shapes,
        fit,
        target,
        fitted,
        depth,
        target_spacing,
        truth,
        body,
        timings,
        n_ranks,
    } = report;
    let (fitted, depth, target_spacing, truth, n_ranks) =
        (fitted.as_slice(), *depth, *target_spacing, *truth, *n_ranks);
    let (setup, target_s, fit_s, final_s, total) = (
        timings.setup,
        timings.target,
        timings.fit,
        timings.final_body,
        timings.total,
    );
    let hz = |v: &[f64]| {
        v.iter()
            .map(|&l| crate::eigen::frequency_hz(l))
            .collect::<Vec<f64>>()
    };
    let mut file = ResultsFile::new("diffsound.fit_shape", 2);
    file.text("/", "task", job.task.name())
        .text("/", "parameter_name", job.task.parameter_name())
        .text(
            "/",
            "surfaces",
            &shapes
                .iter()
                .map(|s| s.path.display().to_string())
                .collect::<Vec<_>>()
                .join(", "),
        )
        .text(
            "/",
            "command",
            &std::env::args().collect::<Vec<_>>().join(" "),
        )
        .text("/", "version", env!("CARGO_PKG_VERSION"))
        .integer("/", "n_ranks", n_ranks as i64);
    let finest = fit.levels.last().expect("at least one level");
    file.number("/fit", "parameter", fit.parameter)
        .number("/fit", "finest_level_parameter", fit.finest_parameter())
        .number("/fit", "target_spacing", target_spacing)
        .number("/fit", "loss", finest.loss)
        .integer("/fit", "evaluations", fit.history.len() as i64)
        .number("/fit", "seconds", fit.seconds);
    if let Some(e) = fit.extrapolated {
        file.number("/fit", "extrapolated", e);
    }
    if let Some((value, cells)) = truth {
        file.number("/fit", "true_parameter", value)
            .number("/fit", "abs_error", (fit.parameter - value).abs())
            .integer("/fit", "target_cells", cells as i64);
    }
    let l = &fit.levels;
    file.indices("/fit/levels/cells", l.iter().map(|l| l.cells).collect())
        .column(
            "/fit/levels/spacing",
            l.iter().map(|l| l.spacing).collect(),
            "m",
        )
        .column(
            "/fit/levels/parameter",
            l.iter().map(|l| l.parameter).collect(),
            "1",
        )
        .column("/fit/levels/loss", l.iter().map(|l| l.loss).collect(), "1")
        .column(
            "/fit/levels/log_stiffness_scale",
            l.iter().map(|l| l.log_scale).collect(),
            "1",
        )
        .indices(
            "/fit/levels/evaluations",
            l.iter().map(|l| l.evaluations).collect(),
        )
        .column(
            "/fit/levels/seconds",
            l.iter().map(|l| l.seconds).collect(),
            "s",
        )
        .indices(
            "/fit/levels/grid_tets",
            l.iter().map(|l| l.grid_tets).collect(),
        )
        .column(
            "/fit/levels/wall_centre",
            l.iter()
                .map(|l| l.wall_centre.unwrap_or(f64::NAN))
                .collect(),
            "1",
        );
    file.integer(
        "/fit",
        "wall_refinement",
        job.settings.wall_refinement as i64,
    )
    .number("/fit", "wall_band", job.settings.wall_band)
    .number("/fit", "wall_tolerance", job.settings.wall_tolerance);
    let h = &fit.history;
    file.indices("/fit/history/level", h.iter().map(|e| e.level).collect())
        .indices("/fit/history/cells", h.iter().map(|e| e.cells).collect())
        .indices(
            "/fit/history/phase",
            h.iter()
                .map(|e| usize::from(e.phase != SearchPhase::Scan))
                .collect(),
        )
        .column(
            "/fit/history/parameter",
            h.iter().map(|e| e.parameter).collect(),
            "1",
        )
        .column("/fit/history/loss", h.iter().map(|e| e.loss).collect(), "1")
        .column(
            "/fit/history/gradient",
            h.iter().map(|e| e.gradient).collect(),
            "1",
        )
        .column("/fit/history/step", h.iter().map(|e| e.step).collect(), "1")
        .indices("/fit/history/tets", h.iter().map(|e| e.tets).collect())
        .indices(
            "/fit/history/p2_nodes",
            h.iter().map(|e| e.p2_nodes).collect(),
        )
        .column(
            "/fit/history/meshing_s",
            h.iter().map(|e| e.timings.meshing).collect(),
            "s",
        )
        .column(
            "/fit/history/assembly_s",
            h.iter().map(|e| e.timings.assembly).collect(),
            "s",
        )
        .column(
            "/fit/history/solve_s",
            h.iter().map(|e| e.timings.solve).collect(),
            "s",
        )
        .column(
            "/fit/history/gradient_s",
            h.iter().map(|e| e.timings.gradient).collect(),
            "s",
        )
        .flags(
            "/fit/history/failed",
            h.iter().map(|e| e.failure.is_some()).collect(),
        );
    let (target_hz, fitted_hz) = (hz(&target.eigenvalues), hz(fitted));
    file.column(
        "/modes/target_eigenvalues",
        target.eigenvalues.clone(),
        "rad^2/s^2",
    )
    .column("/modes/fitted_eigenvalues", fitted.to_vec(), "rad^2/s^2")
    .column(
        "/modes/relative_frequency_error",
        fitted_hz
            .iter()
            .zip(&target_hz)
            .map(|(f, t)| f / t - 1.0)
            .collect(),
        "1",
    )
    .column("/modes/target_frequency_hz", target_hz, "Hz")
    .column("/modes/fitted_frequency_hz", fitted_hz, "Hz")
    .column(
        "/modes/answer_frequency_hz",
        hz(&body.eigenvalues[..fitted.len()]),
        "Hz",
    );
    // ∫ det J over the P2 elements: the curved boundary's volume, not its chords' (det J is a
    // cubic, so the degree-4 rule is exact).
    let rule = crate::fem::tet_rule(4);
    let volume = (0..body.mesh.n_tets())
        .map(|e| crate::fem::element_volume(&body.mesh.tet_coords(e), &rule))
        .sum::<Result<f64, _>>()
        .map_err(|e| format!("the fitted body's volume: {e}"))?;
    let (lo, hi) = union_box(&shapes.iter().map(|s| &s.surface).collect::<Vec<_>>());
    file.number(
        "/shape",
        "diagonal",
        (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt(),
    )
    .integer("/shape", "finest_cells", finest.cells as i64)
    .integer("/shape", "tets", body.mesh.n_tets() as i64)
    .integer("/shape", "p2_nodes", body.mesh.n_nodes() as i64)
    .number("/shape", "volume", volume);
    if let Task::Thickness { curved, .. } = job.task {
        file.number("/shape", "reference_depth", depth)
            .flag("/shape", "curved_boundary", curved);
    }
    file.number("/material", "youngs_modulus", job.material.youngs_modulus)
        .number("/material", "poisson_ratio", job.material.poisson_ratio)
        .number("/material", "density", job.material.density);
    for (k, v) in [
        ("setup", setup),
        ("target", target_s),
        ("fit", fit_s),
        ("final_body", final_s),
        ("total", total),
    ] {
        file.number("/timings", k, v);
    }
    file.write(&job.out).map_err(|e| e.to_string())?;

    write_body_modes(
        &job.mesh_out,
        body,
        &job.material,
        format!("fitted {} = {:.5}", job.task.name(), fit.parameter),
        n_ranks,
        &job.out,
    )
    .map_err(|e| e.to_string())
}
