//! The `spectrogram` job: a PNG of one WAV file, or of several side by side (e.g. a rendered
//! strike against a recording), on one dB colour scale.
//!
//! Each file's channel is optionally trimmed to its onset ([`crate::audio::onset`]), then
//! transformed with the STFT of [`crate::audio::stft`] (periodic Hann window of `--fft`
//! samples, hop `--hop`). Levels are 20·log10(|X| / peak) dB with the peak of all panels at
//! 0 dB, so quieter files look quieter; `--each-own-peak` puts every panel's peak at 0 dB.

use crate::audio::onset::{detect_shared_onset, OnsetOptions};
use crate::audio::read_wav;
use crate::audio::stft::StftPlan;
use crate::io::plot::{spectrogram_png, SpectrogramFigure, SpectrogramPanel};
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug, Clone)]
pub struct SpectrogramArgs {
    /// WAV files, one panel each (e.g. `rendered.wav recording.wav`).
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    /// Output PNG.
    #[arg(long)]
    pub out: PathBuf,
    /// Channel of multichannel files (0-based).
    #[arg(long, default_value_t = 0)]
    pub channel: usize,
    /// Panel titles, comma-separated (default: the file names).
    #[arg(long)]
    pub titles: Option<String>,
    /// Figure title.
    #[arg(long)]
    pub title: Option<String>,
    /// Start each file at its detected onset (for recordings with pre-roll).
    #[arg(long)]
    pub trim_onset: bool,
    /// Show at most this many seconds.
    #[arg(long)]
    pub duration: Option<f64>,
    /// FFT size in samples.
    #[arg(long, default_value_t = 2048)]
    pub fft: usize,
    /// Hop in samples (default FFT size / 4).
    #[arg(long)]
    pub hop: Option<usize>,
    /// Highest frequency shown, Hz.
    #[arg(long)]
    pub fmax: Option<f64>,
    /// Dynamic range of the colour scale, dB.
    #[arg(long, default_value_t = 80.0)]
    pub range_db: f64,
    /// Normalise each panel to its own peak instead of the loudest panel's.
    #[arg(long)]
    pub each_own_peak: bool,
}

struct PanelData {
    title: String,
    db: Vec<f64>,
    n_frames: usize,
    n_bins: usize,
    time_step_s: f64,
    freq_step_hz: f64,
}

pub fn run(args: SpectrogramArgs) -> Result<(), String> {
    if !(args.range_db > 0.0 && args.range_db <= 300.0) {
        return Err(format!(
            "--range-db must lie in (0, 300], got {}",
            args.range_db
        ));
    }
    let plan = StftPlan::new(args.fft, args.hop.unwrap_or(args.fft / 4).max(1))
        .map_err(|e| format!("--fft/--hop: {e}"))?;
    let titles: Vec<String> = match &args.titles {
        Some(t) => t.split(',').map(|s| s.trim().to_string()).collect(),
        None => args
            .inputs
            .iter()
            .map(|p| {
                p.file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default()
            })
            .collect(),
    };
    if titles.len() != args.inputs.len() {
        return Err(format!(
            "{} titles for {} input files",
            titles.len(),
            args.inputs.len()
        ));
    }
    let mut spectra = Vec::new();
    for (path, title) in args.inputs.iter().zip(titles) {
        let (channels, rate) = read_wav(path).map_err(|e| e.to_string())?;
        let Some(signal) = channels.get(args.channel) else {
            return Err(format!(
                "{}: no channel {} (the file has {})",
                path.display(),
                args.channel,
                channels.len()
            ));
        };
        let fs = f64::from(rate);
        let mut start = 0;
        if args.trim_onset {
            // A file that starts with the strike (a rendering) has no pre-roll to measure a
            // noise floor in; it is shown from its start.
            match detect_shared_onset(&[signal.as_slice()], rate, &OnsetOptions::default()) {
                Ok(onset) => start = onset.sample,
                Err(e) => eprintln!("note: {}: showing from the start ({e})", path.display()),
            }
        }
        let mut end = signal.len();
        if let Some(d) = args.duration {
            if !(d > 0.0) {
                return Err(format!("--duration must be > 0, got {d}"));
            }
            end = end.min(start + (d * fs).round() as usize);
        }
        let piece = &signal[start..end.max(start)];
        if piece.is_empty() {
            return Err(format!(
                "{}: nothing left to show after trimming",
                path.display()
            ));
        }
        let spec = plan.forward(piece);
        let peak = spec.magnitude.iter().fold(0.0_f64, |m, &v| m.max(v));
        spectra.push((title, spec, peak, fs));
    }
    let global_peak = spectra.iter().fold(0.0_f64, |m, s| m.max(s.2));
    if !(global_peak > 0.0) {
        return Err("every input is silent".into());
    }
    let floor = -args.range_db - 20.0;
    let panels_data: Vec<PanelData> = spectra
        .into_iter()
        .map(|(title, spec, peak, fs)| {
            let reference = if args.each_own_peak && peak > 0.0 {
                peak
            } else {
                global_peak
            };
            PanelData {
                title,
                db: spec.decibels(reference, floor),
                n_frames: spec.n_frames,
                n_bins: spec.n_bins,
                time_step_s: plan.hop() as f64 / fs,
                freq_step_hz: fs / plan.n_fft() as f64,
            }
        })
        .collect();
    let panels: Vec<SpectrogramPanel> = panels_data
        .iter()
        .map(|p| SpectrogramPanel {
            title: p.title.clone(),
            db: &p.db,
            n_frames: p.n_frames,
            n_bins: p.n_bins,
            time_step_s: p.time_step_s,
            time_offset_s: 0.0,
            freq_step_hz: p.freq_step_hz,
        })
        .collect();
    let mut figure = SpectrogramFigure::new(
        args.title.clone().unwrap_or_else(|| "spectrogram".into()),
        panels,
    );
    figure.max_freq_hz = args.fmax;
    figure.db_max = Some(0.0);
    figure.db_min = Some(-args.range_db);
    spectrogram_png(&args.out, &figure).map_err(|e| e.to_string())?;
    println!("wrote {}", args.out.display());
    Ok(())
}
