//! The `render` command: its flags and the printed line. The job (impact point, direction,
//! contact force, damping, synthesis) is [`crate::workflow::render`].

use crate::audio::excitation::{ContactForce, Response};
use crate::audio::WavFormat;
use crate::workflow::render::{self as workflow, Damping, Job, StrikeAt};
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug, Clone)]
#[command(allow_negative_numbers = true)]
pub struct RenderArgs {
    /// Modes HDF5 file written by `diffsound modes`.
    #[arg(long)]
    pub modes: PathBuf,
    /// Output WAV file.
    #[arg(long)]
    pub out: PathBuf,
    /// Strike this surface node (0-based, as in the modes file).
    #[arg(long, conflicts_with = "position")]
    pub vertex: Option<usize>,
    /// Strike the surface point nearest to x,y,z (metres).
    #[arg(long, value_parser = parse_vec3)]
    pub position: Option<[f64; 3]>,
    /// Strike direction x,y,z (normalised); default: the outward surface normal, inwards.
    #[arg(long, value_parser = parse_vec3)]
    pub direction: Option<[f64; 3]>,
    /// Contact force: `impulse` (default) or `half-sine:<duration s>` (Hertz-like contact).
    #[arg(long, default_value = "impulse")]
    pub force: ContactForce,
    /// Which motion the sound follows: displacement, velocity or acceleration (default).
    #[arg(long, default_value = "acceleration")]
    pub response: Response,
    /// Impulse of the strike in N·s (scales the output before any normalisation).
    #[arg(long, default_value_t = 1.0)]
    pub impulse: f64,
    /// Rayleigh mass damping α in 1/s (default: the file's material).
    #[arg(long)]
    pub alpha: Option<f64>,
    /// Rayleigh stiffness damping β in s (default: the file's material).
    #[arg(long)]
    pub beta: Option<f64>,
    /// Damping curve d(f): TOML with `frequencies_hz = [...]` and `decay_rates = [...]` (1/s).
    #[arg(long, conflicts_with_all = ["alpha", "beta"])]
    pub damping_curve: Option<PathBuf>,
    /// Length in s.
    #[arg(long, default_value_t = 2.0)]
    pub duration: f64,
    /// Sample rate in Hz.
    #[arg(long, default_value_t = 48_000)]
    pub sample_rate: u32,
    /// Peak level after normalisation; `none` keeps physical units (then use --format float32).
    #[arg(long, default_value = "0.9")]
    pub normalise: String,
    /// pcm16 (default) or float32.
    #[arg(long, default_value = "pcm16")]
    pub format: String,
}

pub(crate) fn parse_vec3(s: &str) -> Result<[f64; 3], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(format!("expected x,y,z, got {s:?}"));
    }
    let mut v = [0.0_f64; 3];
    for (slot, p) in v.iter_mut().zip(parts) {
        *slot = p.parse().map_err(|_| format!("{p:?} is not a number"))?;
        if !slot.is_finite() {
            return Err(format!("{p:?} is not finite"));
        }
    }
    Ok(v)
}

/// Checks the flags and turns them into a [`Job`].
pub fn resolve(args: &RenderArgs) -> Result<Job, String> {
    if !(args.duration > 0.0 && args.duration <= 600.0) {
        return Err(format!(
            "--duration must lie in (0, 600] s, got {}",
            args.duration
        ));
    }
    if args.sample_rate < 1000 || args.sample_rate > 768_000 {
        return Err(format!(
            "--sample-rate must lie in [1000, 768000] Hz, got {}",
            args.sample_rate
        ));
    }
    if !(args.impulse.is_finite() && args.impulse != 0.0) {
        return Err(format!(
            "--impulse must be a finite non-zero number, got {}",
            args.impulse
        ));
    }
    let format = match args.format.as_str() {
        "pcm16" => WavFormat::Pcm16,
        "float32" => WavFormat::Float32,
        other => return Err(format!("--format must be pcm16 or float32, got {other:?}")),
    };
    let normalise = match args.normalise.as_str() {
        "none" => None,
        v => Some(
            v.parse::<f64>()
                .ok()
                .filter(|p| *p > 0.0 && *p <= 1.0)
                .ok_or_else(|| {
                    format!("--normalise must be a peak in (0, 1] or `none`, got {v:?}")
                })?,
        ),
    };
    let at = match (args.vertex, args.position) {
        (Some(v), _) => StrikeAt::Vertex(v),
        (None, Some(p)) => StrikeAt::Position(p),
        (None, None) => StrikeAt::Default,
    };
    let damping = match &args.damping_curve {
        Some(path) => Damping::Curve(path.clone()),
        None => Damping::Rayleigh {
            alpha: args.alpha,
            beta: args.beta,
        },
    };
    Ok(Job {
        modes: args.modes.clone(),
        out: args.out.clone(),
        at,
        direction: args.direction,
        force: args.force,
        response: args.response,
        impulse: args.impulse,
        damping,
        duration: args.duration,
        sample_rate: args.sample_rate,
        format,
        normalise,
    })
}

pub fn run(args: RenderArgs) -> Result<(), String> {
    let job = resolve(&args)?;
    if let Some(parent) = job.out.parent().filter(|p| !p.as_os_str().is_empty()) {
        if !parent.is_dir() {
            return Err(format!(
                "output directory {} does not exist",
                parent.display()
            ));
        }
    }
    let report = workflow::run(&job).map_err(|e| e.to_string())?;
    workflow::write_wav(&job, &report).map_err(|e| e.to_string())?;
    let (point, direction) = (report.point, report.direction);
    println!(
        "wrote {} ({:.2} s at {} Hz): {} of {} modes audible, strike at ({:.4}, {:.4}, {:.4}) m along ({:.3}, {:.3}, {:.3}), {} force, {} response, physical peak {:.3e}",
        job.out.display(),
        job.duration,
        job.sample_rate,
        report.audible,
        report.n_modes,
        point.position[0],
        point.position[1],
        point.position[2],
        direction[0],
        direction[1],
        direction[2],
        job.force,
        job.response,
        report.peak
    );
    Ok(())
}
