//! The diagnosis's PNG plots: standardised residuals per matched mode (baseline vs final),
//! spectrograms of the recording and of what the modes leave, and the residual energy per
//! band against the pre-roll's floor.

use super::write::output;
use super::{Error, Report};
use crate::audio::stft::StftPlan;
use crate::diagnose::catalogue;
use crate::io::paths::plot_path;
use crate::io::plot::{
    line_plot, spectrogram_png, AxisScale, Dash, LegendPlacement, LineFigure, Marker, Series,
    SpectrogramFigure, SpectrogramPanel, PALETTE,
};

/// Writes the PNG plots (prefix `plots`): `_residuals.png`, `_timefreq.png` and, with the
/// residual envelopes, `_envelopes.png` (module docs, "Output").
pub fn write_plots(r: &Report) -> Result<(), Error> {
    let (job, measured, report) = (&r.job, &r.measured, &r.catalogue);
    let fs = f64::from(job.sample_rate);
    // Standardised residuals per matched mode, baseline vs final.
    let rows = &report.residuals;
    let f: Vec<f64> = rows.iter().map(|r| r.frequency_hz).collect();
    let mut series = Vec::new();
    let pick =
        |g: &dyn Fn(&catalogue::ZScores) -> Option<f64>, after: bool| -> (Vec<f64>, Vec<f64>) {
            rows.iter()
                .filter_map(|r| {
                    g(if after { &r.after } else { &r.before })
                        .filter(|v| v.is_finite())
                        .map(|v| (r.frequency_hz, v))
                })
                .unzip()
        };
    /// A plotted quantity: its label and how it is read from a mode's z-scores.
    type Quantity<'q> = (&'q str, Box<dyn Fn(&catalogue::ZScores) -> Option<f64>>);
    let quantities: [Quantity; 3] = [
        (
            "ln f",
            Box::new(|z: &catalogue::ZScores| Some(z.ln_frequency)),
        ),
        ("ln d", Box::new(|z: &catalogue::ZScores| z.ln_decay)),
        (
            "ln a (RMS over mics)",
            Box::new(|z: &catalogue::ZScores| {
                let v: Vec<f64> = z.ln_amplitude.iter().flatten().copied().collect();
                (!v.is_empty())
                    .then(|| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt())
            }),
        ),
    ];
    // One colour and shape per quantity; the baseline hollow, the final
    // model filled, so a final point on top of its baseline stays visible.
    let markers = [Marker::Circle, Marker::Square, Marker::Diamond];
    for (q, ((name, g), m)) in quantities.iter().zip(markers).enumerate() {
        let (xb, yb) = pick(g.as_ref(), false);
        let (xa, ya) = pick(g.as_ref(), true);
        series.push(
            Series::markers(format!("{name}, baseline"), xb, yb, m)
                .with_color(PALETTE[q])
                .with_hollow(true),
        );
        series.push(
            Series::markers(format!("{name}, final"), xa, ya, m)
                .with_color(PALETTE[q])
                .with_hollow(false),
        );
    }
    if !f.is_empty() {
        let accepted: Vec<String> = report.accepted.iter().map(|a| a.name.clone()).collect();
        let mut fig = LineFigure::new(
            format!(
                "standardised residuals per mode: baseline vs final ({})",
                if accepted.is_empty() {
                    "no effect accepted".into()
                } else {
                    accepted.join(", ")
                }
            ),
            "observed frequency (Hz)",
            "z = residual / σ (with the model floor)",
        );
        fig.x_scale = AxisScale::Log;
        fig.series = series;
        line_plot(&plot_path(&job.plots, "_residuals.png"), &fig).map_err(output)?;
    }
    // Time–frequency: the recording and what the modes leave.
    let plan = StftPlan::new(2048, 256).map_err(output)?;
    let signals: [(&str, &[f64]); 2] = [
        ("recording (fit mic 0)", &measured.plot_signal),
        ("recording − modal resynthesis", &measured.plot_residual),
    ];
    let specs: Vec<_> = signals.iter().map(|(_, s)| plan.forward(s)).collect();
    let peak = specs[0].magnitude.iter().fold(0.0_f64, |m, &v| m.max(v));
    let dbs: Vec<Vec<f64>> = specs
        .iter()
        .map(|s| s.decibels(peak.max(1e-300), -140.0))
        .collect();
    let panels: Vec<SpectrogramPanel> = signals
        .iter()
        .zip(&specs)
        .zip(&dbs)
        .map(|(((title, _), s), db)| SpectrogramPanel {
            title: title.to_string(),
            db,
            n_frames: s.n_frames,
            n_bins: s.n_bins,
            time_step_s: plan.hop() as f64 / fs,
            time_offset_s: 0.0,
            freq_step_hz: fs / plan.n_fft() as f64,
        })
        .collect();
    let mut figure = SpectrogramFigure::new("where the modes do not explain the recording", panels);
    figure.max_freq_hz = Some((1.1 * job.max_frequency_hz).min(fs / 2.0));
    figure.db_max = Some(0.0);
    figure.db_min = Some(-120.0);
    spectrogram_png(&plot_path(&job.plots, "_timefreq.png"), &figure).map_err(output)?;
    // Residual energy per band over time against the pre-roll floor.
    if let Some(env) = &measured.envelopes {
        let mut fig = LineFigure::new(
            "residual energy per band (lines) vs pre-roll noise floor (flat)",
            "time after the strike (s)",
            "energy (full scale²)",
        );
        fig.y_scale = AxisScale::Log;
        // Band b and its floor share a colour (solid: the residual, dashed:
        // the floor); past the palette, colours repeat with dotted lines.
        // The legend goes outside: these curves fill the whole plot.
        fig.legend = LegendPlacement::Outside;
        for (b, band) in env.energy.iter().enumerate() {
            let label = format!(
                "{:.0}–{:.0} Hz",
                env.band_edges_hz[b],
                env.band_edges_hz[b + 1]
            );
            let color = PALETTE[b % PALETTE.len()];
            let (band_dash, floor_dash) = if b < PALETTE.len() {
                (Dash::Solid, Dash::Dashed)
            } else {
                (Dash::DashDot, Dash::Dotted)
            };
            fig.series.push(
                Series::line(
                    label.clone(),
                    env.times_s.clone(),
                    band.iter().map(|e| e.max(1e-300)).collect(),
                )
                .with_color(color)
                .with_dash(band_dash),
            );
            if env.noise_floor_estimate[b] > 0.0 {
                fig.series.push(
                    Series::line(
                        format!("{label}, floor"),
                        vec![env.times_s[0], *env.times_s.last().unwrap_or(&1.0)],
                        vec![env.noise_floor_estimate[b]; 2],
                    )
                    .with_color(color)
                    .with_dash(floor_dash),
                );
            }
        }
        line_plot(&plot_path(&job.plots, "_envelopes.png"), &fig).map_err(output)?;
    }
    Ok(())
}
