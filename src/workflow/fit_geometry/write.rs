//! The files of a geometry fit: the HDF5 result (`diffsound.fit_geometry`, layout in the
//! module docs of [`super`]), the refined body's mesh with its modes (HDF5 + XDMF) and the
//! before/after/true picture (PNG).

use super::{Error, Job, Report};
use crate::inverse::geometry::GeometryFit;
use crate::io::plot::{surface_png, SurfaceFigure, SurfacePanel, View};
use crate::io::results::ResultsFile;
use crate::shape::TriangleSurface;
use crate::workflow::write_body_modes;
use std::path::Path;

/// Writes `job.out`, `job.mesh_out` (+ .xdmf) and `job.png` from the report (rank 0); `truth`
/// is the true surface, drawn beside the fitted bodies.
pub fn write_outputs(job: &Job, report: &Report, truth: &TriangleSurface) -> Result<(), Error> {
    write_results(job, report).map_err(Error::Output)?;
    render_comparison(&job.png, &report.fit, truth, &format!("{}: {}³ voxels → pre-fit (before) → refined by {} eigenvalues (after); C = Chamfer distance", job.surface.file_name().map_or(String::new(), |n| n.to_string_lossy().to_string()), job.settings.voxels, job.settings.modes)).map_err(Error::Output)
}

/// The voxels, the pre-fitted and refined bodies and the true surface side by side (two views,
/// one scale), in millimetres.
pub fn render_comparison(
    path: &Path,
    fit: &GeometryFit,
    truth: &TriangleSurface,
    title: &str,
) -> Result<(), String> {
    let mm = |s: &TriangleSurface| {
        s.vertices
            .iter()
            .map(|v| v.map(|x| 1e3 * x))
            .collect::<Vec<_>>()
    };
    let voxels = fit.voxels.boundary_surface();
    // Titles stay short enough for one cell.
    let label = |name: &str, a: &crate::inverse::geometry::Assessed| {
        format!(
            "{name}: C {:.2} mm, IoU {:.3}",
            1e3 * a.comparison.chamfer,
            a.comparison.iou
        )
    };
    let panels = vec![
        SurfacePanel::new(
            format!(
                "{n}³ voxels: C {:.2} mm",
                1e3 * fit.voxel_comparison.chamfer,
                n = fit.voxels.resolution
            ),
            mm(&voxels),
            voxels.triangles.clone(),
        ),
        SurfacePanel::new(
            label("before", &fit.before),
            mm(&fit.before.surface),
            fit.before.surface.triangles.clone(),
        ),
        SurfacePanel::new(
            label("after", &fit.after),
            mm(&fit.after.surface),
            fit.after.surface.triangles.clone(),
        ),
        SurfacePanel::new("true", mm(truth), truth.triangles.clone()),
    ];
    let mut fig = SurfaceFigure::new(title, panels);
    fig.views = vec![
        View::new(30.0, 25.0),
        View::new(210.0, 20.0),
        View::labelled(0.0, 89.0, "top"),
    ];
    fig.panel_size = 340;
    surface_png(path, &fig).map_err(|e| e.to_string())
}

fn write_results(job: &Job, report: &Report) -> Result<(), String> {
    let Report {
        fit,
        body,
        final_seconds,
        total_seconds: total,
        n_ranks,
    } = report;
    let (final_seconds, total, n_ranks) = (*final_seconds, *total, *n_ranks);
    let hz = |v: &[f64]| {
        v.iter()
            .map(|&l| crate::eigen::frequency_hz(l))
            .collect::<Vec<f64>>()
    };
    let mut file = ResultsFile::new("diffsound.fit_geometry", 2);
    file.text("/", "surface", &job.surface.display().to_string())
        .text(
            "/",
            "command",
            &std::env::args().collect::<Vec<_>>().join(" "),
        )
        .text("/", "version", env!("CARGO_PKG_VERSION"))
        .text(
            "/",
            "settings_json",
            &serde_json::to_string(&job.settings).map_err(|e| e.to_string())?,
        )
        .integer("/", "n_ranks", n_ranks as i64);
    let c = &fit.voxel_comparison;
    file.number("/metrics/voxels", "chamfer", c.chamfer)
        .number("/metrics/voxels", "hausdorff", c.hausdorff)
        .number("/metrics/voxels", "iou", c.iou);
    let loss_of = |a: &crate::inverse::geometry::Assessed| {
        crate::inverse::geometry::eigenvalue_loss(&a.eigenvalues, &fit.target)
            .map(|(l, _)| l)
            .unwrap_or(f64::NAN)
    };
    for (name, a) in [
        ("before", &fit.before),
        ("after", &fit.after),
        ("floor", &fit.floor),
    ] {
        let g = format!("/metrics/{name}");
        file.number(&g, "chamfer", a.comparison.chamfer)
            .number(&g, "hausdorff", a.comparison.hausdorff)
            .number(&g, "iou", a.comparison.iou)
            .number(
                &g,
                "rms_frequency_error",
                a.rms_frequency_error(&fit.target),
            )
            .number(&g, "eigen_loss", loss_of(a))
            .number(&g, "volume", a.volume);
        file.column(
            &format!("/modes/{name}_eigenvalues"),
            a.eigenvalues.clone(),
            "rad^2/s^2",
        )
        .column(
            &format!("/modes/{name}_frequency_hz"),
            hz(&a.eigenvalues),
            "Hz",
        )
        .column(
            &format!("/modes/{name}_relative_frequency_error"),
            a.eigenvalues
                .iter()
                .zip(&fit.target.eigenvalues)
                .map(|(l, t)| (l / t).sqrt() - 1.0)
                .collect(),
            "1",
        );
    }
    if !fit.bias_correction.is_empty() {
        file.column("/modes/bias_correction", fit.bias_correction.clone(), "1");
    }
    if let Some(c) = &fit.check {
        file.number("/check", "before_loss", c.before_loss)
            .number("/check", "after_loss", c.after_loss)
            .flag("/check", "refined_kept", c.refined_kept);
    }
    file.column(
        "/modes/target_eigenvalues",
        fit.target.eigenvalues.clone(),
        "rad^2/s^2",
    )
    .column(
        "/modes/target_frequency_hz",
        hz(&fit.target.eigenvalues),
        "Hz",
    )
    .number("/modes", "target_spacing", fit.target_spacing);
    let h = &fit.refinement.history;
    let col = |f: &dyn Fn(&crate::inverse::geometry::RefineStep) -> f64| {
        h.iter().map(f).collect::<Vec<f64>>()
    };
    file.indices("/refine/history/step", h.iter().map(|s| s.step).collect())
        .column("/refine/history/loss", col(&|s| s.loss), "1")
        .column("/refine/history/eigen_loss", col(&|s| s.eigen_loss), "1")
        .column("/refine/history/voxel_loss", col(&|s| s.voxel_loss), "1")
        .column(
            "/refine/history/eikonal_loss",
            col(&|s| s.eikonal_loss),
            "1",
        )
        .indices("/refine/history/tets", h.iter().map(|s| s.tets).collect())
        .indices(
            "/refine/history/p2_nodes",
            h.iter().map(|s| s.p2_nodes).collect(),
        )
        .column(
            "/refine/history/meshing_s",
            col(&|s| s.timings.meshing),
            "s",
        )
        .column(
            "/refine/history/assembly_s",
            col(&|s| s.timings.assembly),
            "s",
        )
        .column("/refine/history/solve_s", col(&|s| s.timings.solve), "s")
        .column(
            "/refine/history/gradient_s",
            col(&|s| s.timings.gradient),
            "s",
        )
        .column(
            "/refine/history/network_s",
            col(&|s| s.network_seconds),
            "s",
        )
        .column("/refine/history/step_scale", col(&|s| s.step_scale), "1")
        .flags(
            "/refine/history/backtracked",
            h.iter().map(|s| s.backtracked).collect(),
        )
        .flags(
            "/refine/history/failed",
            h.iter().map(|s| s.failure.is_some()).collect(),
        )
        .integer("/refine", "best_step", fit.refinement.best_step as i64)
        .number("/refine", "seconds", fit.refinement.seconds);
    let (mean, network) = fit.refinement.mean_timings();
    file.number("/refine/mean_step", "meshing", mean.meshing)
        .number("/refine/mean_step", "assembly", mean.assembly)
        .number("/refine/mean_step", "solve", mean.solve)
        .number("/refine/mean_step", "gradient", mean.gradient)
        .number("/refine/mean_step", "network", network)
        .number("/refine/mean_step", "total", mean.total() + network);
    file.column("/prefit/loss", fit.prefit.loss.clone(), "1")
        .number("/prefit", "centre_accuracy", fit.prefit.centre_accuracy)
        .number("/prefit", "sign_loss", fit.prefit.sign_loss)
        .number("/prefit", "eikonal_loss", fit.prefit.eikonal_loss)
        .number("/prefit", "seconds", fit.prefit.seconds);
    let n = &fit.network;
    file.column(
        "/network/parameters",
        fit.refinement.best_parameters.clone(),
        "1",
    )
    .column(
        "/network/prefit_parameters",
        fit.prefit_parameters.clone(),
        "1",
    )
    .integer("/network", "octaves", n.octaves as i64)
    .number("/network", "length", n.length)
    .number("/network", "centre_x", n.centre[0])
    .number("/network", "centre_y", n.centre[1])
    .number("/network", "centre_z", n.centre[2])
    .text(
        "/network",
        "hidden",
        &n.hidden
            .iter()
            .map(|w| w.to_string())
            .collect::<Vec<_>>()
            .join(","),
    )
    .text(
        "/network",
        "config_json",
        &serde_json::to_string(n).map_err(|e| e.to_string())?,
    );
    let v = &fit.voxels;
    file.integer("/voxels", "resolution", v.resolution as i64)
        .integer("/voxels", "occupied", v.occupied() as i64)
        .number("/voxels", "edge_x", v.size[0])
        .number("/voxels", "edge_y", v.size[1])
        .number("/voxels", "edge_z", v.size[2]);
    file.number("/material", "youngs_modulus", job.material.youngs_modulus)
        .number("/material", "poisson_ratio", job.material.poisson_ratio)
        .number("/material", "density", job.material.density);
    let t = &fit.timings;
    for (k, value) in [
        ("voxelise", t.voxelise),
        ("prefit", t.prefit),
        ("target", t.target),
        ("refine", t.refine),
        ("assess", t.assess),
        ("final_body", final_seconds),
        ("total", total),
    ] {
        file.number("/timings", k, value);
    }
    file.write(&job.out).map_err(|e| e.to_string())?;

    write_body_modes(
        &job.mesh_out,
        body,
        &job.material,
        "refined geometry (MLP SDF)".into(),
        n_ranks,
        &job.out,
    )
    .map_err(|e| e.to_string())
}
