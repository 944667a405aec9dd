//! The `spectrogram` job: a PNG of one WAV file, or of several side by side (e.g. a rendered
//! strike against a recording), on one dB colour scale.
//!
//! Each file's channel is optionally trimmed to its onset ([`crate::analysis::onset`]), then
//! transformed with the STFT of [`crate::audio::stft`] (periodic Hann window of `n_fft`
//! samples, hop `hop`). Levels are 20·log10(|X| / peak) dB with the peak of all panels at
//! 0 dB, so quieter files look quieter; `each_own_peak` puts every panel's peak at 0 dB.

use crate::analysis::onset::{detect_shared_onset, OnsetOptions};
use crate::audio::stft::StftPlan;
use crate::audio::{read_wav, AudioError};
use crate::io::plot::{spectrogram_png, PlotError, SpectrogramFigure, SpectrogramPanel};
use std::path::PathBuf;

/// Everything the job needs, checked as far as the flags alone allow.
#[derive(Clone, Debug)]
pub struct Job {
    /// WAV files, one panel each.
    pub inputs: Vec<PathBuf>,
    /// One title per input.
    pub titles: Vec<String>,
    /// Output PNG.
    pub out: PathBuf,
    /// Channel of multichannel files (0-based).
    pub channel: usize,
    /// Figure title.
    pub title: String,
    /// Start each file at its detected onset.
    pub trim_onset: bool,
    /// Show at most this many seconds (must be > 0).
    pub duration: Option<f64>,
    pub plan: StftPlan,
    /// Highest frequency shown [Hz].
    pub fmax: Option<f64>,
    /// Dynamic range of the colour scale [dB].
    pub range_db: f64,
    pub each_own_peak: bool,
}

/// What can stop the job.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Audio(#[from] AudioError),
    #[error("{}: no channel {channel} (the file has {available})", path.display())]
    NoChannel {
        path: PathBuf,
        channel: usize,
        available: usize,
    },
    #[error("--duration must be > 0, got {0}")]
    Duration(f64),
    #[error("{}: nothing left to show after trimming", .0.display())]
    NothingLeft(PathBuf),
    #[error("every input is silent")]
    Silent,
    #[error(transparent)]
    Plot(#[from] PlotError),
}

/// One panel: levels in dB, `[frame][bin]`, with the steps of its axes.
#[derive(Clone, Debug)]
pub struct Panel {
    pub title: String,
    pub db: Vec<f64>,
    pub n_frames: usize,
    pub n_bins: usize,
    pub time_step_s: f64,
    pub freq_step_hz: f64,
}

/// The panels, on one dB scale.
#[derive(Clone, Debug)]
pub struct Report {
    pub panels: Vec<Panel>,
}

/// Reads and transforms every input. A file whose onset cannot be found is shown from its
/// start, with a note on stderr.
pub fn run(job: &Job) -> Result<Report, Error> {
    let plan = &job.plan;
    let mut spectra = Vec::new();
    for (path, title) in job.inputs.iter().zip(job.titles.iter().cloned()) {
        let (channels, rate) = read_wav(path)?;
        let Some(signal) = channels.get(job.channel) else {
            return Err(Error::NoChannel {
                path: path.clone(),
                channel: job.channel,
                available: channels.len(),
            });
        };
        let fs = f64::from(rate);
        let mut start = 0;
        if job.trim_onset {
            // A file that starts with the strike (a rendering) has no pre-roll to measure a
            // noise floor in; it is shown from its start.
            match detect_shared_onset(&[signal.as_slice()], rate, &OnsetOptions::default()) {
                Ok(onset) => start = onset.sample,
                Err(e) => super::note(format!("{}: showing from the start ({e})", path.display())),
            }
        }
        let mut end = signal.len();
        if let Some(d) = job.duration {
            if !(d > 0.0) {
                return Err(Error::Duration(d));
            }
            end = end.min(start + (d * fs).round() as usize);
        }
        let piece = &signal[start..end.max(start)];
        if piece.is_empty() {
            return Err(Error::NothingLeft(path.clone()));
        }
        let spec = plan.forward(piece);
        let peak = spec.magnitude.iter().fold(0.0_f64, |m, &v| m.max(v));
        spectra.push((title, spec, peak, fs));
    }
    let global_peak = spectra.iter().fold(0.0_f64, |m, s| m.max(s.2));
    if !(global_peak > 0.0) {
        return Err(Error::Silent);
    }
    let floor = -job.range_db - 20.0;
    let panels = spectra
        .into_iter()
        .map(|(title, spec, peak, fs)| {
            let reference = if job.each_own_peak && peak > 0.0 {
                peak
            } else {
                global_peak
            };
            Panel {
                title,
                db: spec.decibels(reference, floor),
                n_frames: spec.n_frames,
                n_bins: spec.n_bins,
                time_step_s: plan.hop() as f64 / fs,
                freq_step_hz: fs / plan.n_fft() as f64,
            }
        })
        .collect();
    Ok(Report { panels })
}

/// Draws the panels side by side to the job's PNG, 0 dB at the top of the colour scale.
pub fn write_png(job: &Job, report: &Report) -> Result<(), Error> {
    let panels: Vec<SpectrogramPanel> = report
        .panels
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
    let mut figure = SpectrogramFigure::new(job.title.clone(), panels);
    figure.max_freq_hz = job.fmax;
    figure.db_max = Some(0.0);
    figure.db_min = Some(-job.range_db);
    spectrogram_png(&job.out, &figure)?;
    Ok(())
}
