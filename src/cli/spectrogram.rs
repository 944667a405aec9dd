//! The `spectrogram` command: its flags and the printed line. The job (onset trimming, STFT,
//! one dB scale over all panels, the PNG) is [`crate::workflow::spectrogram`].

use crate::audio::stft::StftPlan;
use crate::io::plot::{ImageFormat, RASTER_FORMATS};
use crate::workflow::spectrogram::{self as workflow, Job};
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug, Clone)]
pub struct SpectrogramArgs {
    /// WAV files, one panel each (e.g. `rendered.wav recording.wav`).
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    /// Output image (.png).
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

/// Checks the flags and turns them into a [`Job`].
pub fn resolve(args: &SpectrogramArgs) -> Result<Job, String> {
    if !(args.range_db > 0.0 && args.range_db <= 300.0) {
        return Err(format!(
            "--range-db must lie in (0, 300], got {}",
            args.range_db
        ));
    }
    // A figure format we do not write fails here, before any file is read.
    ImageFormat::for_path(&args.out, RASTER_FORMATS).map_err(|e| e.to_string())?;
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
    Ok(Job {
        inputs: args.inputs.clone(),
        titles,
        out: args.out.clone(),
        channel: args.channel,
        title: args.title.clone().unwrap_or_else(|| "spectrogram".into()),
        trim_onset: args.trim_onset,
        duration: args.duration,
        plan,
        fmax: args.fmax,
        range_db: args.range_db,
        each_own_peak: args.each_own_peak,
    })
}

pub fn run(args: SpectrogramArgs) -> Result<(), String> {
    let job = resolve(&args)?;
    let report = workflow::run(&job).map_err(|e| e.to_string())?;
    workflow::write_png(&job, &report).map_err(|e| e.to_string())?;
    println!("wrote {}", job.out.display());
    Ok(())
}
