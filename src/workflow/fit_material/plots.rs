//! The PNG plots of a fit-material report (prefix `job.plots`).

use super::{Error, Job, Report};
use crate::audio::loss::LossPhase;
use crate::audio::stft::StftPlan;
use crate::io::paths::plot_path;
use crate::io::plot::{
    line_plot, scientific as sci, spectrogram_png, AxisScale, LineFigure, Marker, Series,
    SpectrogramFigure, SpectrogramPanel,
};

/// Which plots [`write_plots`] wrote beyond the three it always writes (`_spectrogram`,
/// `_damping`, `_loss`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PlotsWritten {
    /// `_frequencies.png`: written only when some recorded mode found a simulated partner.
    pub frequencies: bool,
}

/// Writes the plots of the module docs of [`super`].
pub fn write_plots(job: &Job, report: &Report) -> Result<PlotsWritten, Error> {
    draw(job, report).map_err(Error::Output)
}

fn draw(job: &Job, report: &Report) -> Result<PlotsWritten, String> {
    let stage = &report.stage;
    let targets = &report.targets;
    let start = &report.start_render;
    let fitted = &report.fit_render;
    let fit = &report.fit;
    let matches = &report.matches;
    let recorded_hz = &report.recorded_hz;
    let sim_hz = &report.sim_hz;
    let fs = f64::from(job.sample_rate);
    // Spectrograms of channel 0: recording, target, start, fit; one dB scale (the recording's peak).
    let plan = StftPlan::new(2048, 256).map_err(|e| e.to_string())?;
    let signals: [(&str, &[f64]); 4] = [
        ("recording", &stage.channels[0]),
        ("target (recorded lines in band)", &targets[0]),
        ("start", &start[0]),
        ("fit", &fitted[0]),
    ];
    let specs: Vec<_> = signals.iter().map(|(_, s)| plan.forward(s)).collect();
    let peak = specs
        .iter()
        .flat_map(|s| s.magnitude.iter())
        .fold(0.0_f64, |m, &v| m.max(v));
    let dbs: Vec<Vec<f64>> = specs
        .iter()
        .map(|s| s.decibels(peak.max(1e-300), -120.0))
        .collect();
    let panels: Vec<SpectrogramPanel> = signals
        .iter()
        .zip(&specs)
        .zip(&dbs)
        .map(|(((title, _), s), db)| SpectrogramPanel {
            title: format!("{title} ({})", stage.names[0]),
            db,
            n_frames: s.n_frames,
            n_bins: s.n_bins,
            time_step_s: plan.hop() as f64 / fs,
            time_offset_s: 0.0,
            freq_step_hz: fs / plan.n_fft() as f64,
        })
        .collect();
    let mut figure = SpectrogramFigure::new(
        format!(
            "fit-material: E = {} Pa, ν = {:.4}",
            sci(fit.youngs, 4),
            fit.poisson
        ),
        panels,
    );
    figure.max_freq_hz = Some((1.3 * job.max_frequency_hz).min(fs / 2.0));
    figure.db_max = Some(0.0);
    figure.db_min = Some(-90.0);
    let p = plot_path(&job.plots, "_spectrogram.png");
    spectrogram_png(&p, &figure).map_err(|e| e.to_string())?;

    // Damping: per-mode decay rates (kept / rejected), the curve, the Rayleigh fit.
    let modes = &stage.damping.modes;
    let (kept, rejected): (Vec<_>, Vec<_>) = modes.iter().partition(|m| m.kept());
    let f_lo = modes
        .iter()
        .map(|m| m.frequency_hz)
        .fold(f64::INFINITY, f64::min)
        .max(1.0);
    let f_hi = modes
        .iter()
        .map(|m| m.frequency_hz)
        .fold(0.0_f64, f64::max)
        .max(2.0 * f_lo);
    let grid: Vec<f64> = (0..200)
        .map(|i| f_lo * (f_hi / f_lo).powf(i as f64 / 199.0))
        .collect();
    let (alpha, beta) = (stage.damping.rayleigh.alpha, stage.damping.rayleigh.beta);
    let mut fig = LineFigure::new(
        "damping: measured decay rates, curve d(f) and Rayleigh fit",
        "frequency (Hz)",
        "decay rate d (1/s)",
    );
    fig.x_scale = AxisScale::Log;
    fig.y_scale = AxisScale::Log;
    let peaks: Vec<_> = stage.damping.peaks.iter().filter(|p| p.kept).collect();
    fig.series = vec![
        Series::markers(
            "peaks (curve data)",
            peaks.iter().map(|p| p.frequency_hz).collect(),
            peaks.iter().map(|p| p.decay_rate).collect(),
            Marker::Diamond,
        ),
        Series::markers(
            "kept poles",
            kept.iter().map(|m| m.frequency_hz).collect(),
            kept.iter().map(|m| m.decay_rate).collect(),
            Marker::Circle,
        ),
        Series::markers(
            "rejected poles",
            rejected.iter().map(|m| m.frequency_hz).collect(),
            rejected.iter().map(|m| m.decay_rate.max(1e-3)).collect(),
            Marker::Cross,
        ),
        Series::line(
            "curve d(f)",
            grid.clone(),
            grid.iter().map(|&f| stage.damping.curve.decay(f)).collect(),
        ),
        Series::line(
            format!("Rayleigh α = {alpha:.3} s⁻¹, β = {} s", sci(beta, 2)),
            grid.clone(),
            grid.iter()
                .map(|&f| 0.5 * (alpha + beta * (2.0 * std::f64::consts::PI * f).powi(2)))
                .collect(),
        ),
    ];
    line_plot(&plot_path(&job.plots, "_damping.png"), &fig).map_err(|e| e.to_string())?;

    // Loss history: one curve per phase the fit went through (the hybrid
    // schedule's transport phase only when it ran).
    let (tr, sp): (Vec<_>, Vec<_>) = fit
        .history
        .iter()
        .partition(|s| s.phase == LossPhase::Transport);
    let phases: Vec<(&str, &Vec<_>)> = [("transport", &tr), ("spectral", &sp)]
        .into_iter()
        .filter(|(_, h)| !h.is_empty())
        .collect();
    let mut fig = LineFigure::new(
        format!(
            "material fit: loss per step ({})",
            phases
                .iter()
                .map(|(name, _)| *name)
                .collect::<Vec<_>>()
                .join(", then ")
        ),
        "step",
        "loss",
    );
    fig.y_scale = AxisScale::Log;
    fig.series = phases
        .iter()
        .map(|(name, h)| {
            Series::line(
                *name,
                h.iter().map(|s| s.step as f64).collect(),
                h.iter().map(|s| s.loss.max(1e-300)).collect(),
            )
        })
        .collect();
    if !fig.series.is_empty() {
        line_plot(&plot_path(&job.plots, "_loss.png"), &fig).map_err(|e| e.to_string())?;
    }

    if matches.is_empty() {
        return Ok(PlotsWritten { frequencies: false });
    }
    let mut fig = LineFigure::new(
        "recorded vs simulated modes: relative frequency error",
        "recorded frequency (Hz)",
        "(f_sim − f_rec) / f_rec (%)",
    );
    fig.series = vec![Series::markers(
        "matched modes",
        matches.iter().map(|m| recorded_hz[m.recorded]).collect(),
        matches
            .iter()
            .map(|m| {
                100.0 * (sim_hz[m.simulated] - recorded_hz[m.recorded]) / recorded_hz[m.recorded]
            })
            .collect(),
        Marker::Diamond,
    )];
    line_plot(&plot_path(&job.plots, "_frequencies.png"), &fig).map_err(|e| e.to_string())?;
    Ok(PlotsWritten { frequencies: true })
}
