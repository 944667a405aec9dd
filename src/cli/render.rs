//! The `render` job: a strike rendered from a modes HDF5 file to WAV.
//!
//! Mode k sounds with complex amplitude z_k = J (φ_k(x)·n) G_k (see [`crate::audio::excitation`]),
//! where x is the impact point (a surface vertex, or the surface point nearest a given
//! position, read with the element's shape functions), n the strike direction (default the
//! outward normal), J the impulse [N·s], and G_k the contact-force spectrum and response
//! factor; it decays with the chosen damping (the file's Rayleigh α, β by default, or a
//! damping curve d(f) from a TOML file with `frequencies_hz` and `decay_rates` arrays).

use crate::audio::chain::{DampingCurve, DampingModel, ModalChain, Strike};
use crate::audio::excitation::{ContactForce, Response};
use crate::audio::{self, WavFormat};
use crate::mesh::{ElementOrder, TetMesh};
use clap::Args;
use std::path::{Path, PathBuf};

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

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct CurveFile {
    frequencies_hz: Vec<f64>,
    decay_rates: Vec<f64>,
}

/// Reads a damping curve TOML file.
pub fn read_damping_curve(path: &Path) -> Result<DampingCurve, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let file: CurveFile = toml::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?;
    DampingCurve::new(file.frequencies_hz, &file.decay_rates)
        .map_err(|e| format!("{}: {e}", path.display()))
}

pub fn run(args: RenderArgs) -> Result<(), String> {
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
    if let Some(parent) = args.out.parent().filter(|p| !p.as_os_str().is_empty()) {
        if !parent.is_dir() {
            return Err(format!(
                "output directory {} does not exist",
                parent.display()
            ));
        }
    }
    let file = crate::io::read_modes(&args.modes).map_err(|e| e.to_string())?;
    if file.n_modes == 0 {
        return Err(format!("{}: the file holds no modes", args.modes.display()));
    }
    let order = match file.nodes_per_tet {
        4 => ElementOrder::Linear,
        10 => ElementOrder::Quadratic,
        n => {
            return Err(format!(
                "{}: {n} nodes per tet is not a tet mesh we know",
                args.modes.display()
            ))
        }
    };
    let mesh = TetMesh {
        nodes: file.nodes.clone(),
        connectivity: file.connectivity.clone(),
        order,
    };
    let point = match (args.vertex, args.position) {
        (Some(v), _) => mesh.surface_point_at_vertex(v).ok_or_else(|| {
            format!(
                "--vertex {v} is not a surface corner node of the mesh ({} nodes)",
                mesh.n_nodes()
            )
        })?,
        (None, Some(p)) => {
            let sp = mesh
                .closest_surface_point(p)
                .ok_or("the mesh has no surface")?;
            let (lo, hi) = mesh.bounding_box();
            let diagonal = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
            if sp.distance > 0.05 * diagonal {
                return Err(format!(
                    "--position {:?} is {:.4} m from the surface (more than 5 % of the mesh size {:.4} m); is it in the mesh's units (metres)?",
                    p, sp.distance, diagonal
                ));
            }
            sp
        }
        (None, None) => mesh
            .default_strike_point()
            .ok_or("the mesh has no surface")?,
    };
    // The hammer pushes into the body: along −n unless told otherwise.
    let direction = match args.direction {
        Some(d) => {
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            if n == 0.0 {
                return Err("--direction must not be the zero vector".into());
            }
            [d[0] / n, d[1] / n, d[2] / n]
        }
        None => [-point.normal[0], -point.normal[1], -point.normal[2]],
    };
    let projections: Vec<f64> = file
        .mode_shapes
        .iter()
        .map(|shape| {
            let u = mesh.interpolate_vector(shape, &point);
            args.impulse * (u[0] * direction[0] + u[1] * direction[1] + u[2] * direction[2])
        })
        .collect();
    let damping = match &args.damping_curve {
        Some(path) => DampingModel::Curve(read_damping_curve(path)?),
        None => DampingModel::Rayleigh {
            alpha: args.alpha.unwrap_or(file.material.rayleigh_alpha),
            beta: args.beta.unwrap_or(file.material.rayleigh_beta),
        },
    };
    let strike = Strike {
        force: args.force,
        response: args.response,
    };
    let (bank, _) = ModalChain::new(&file.eigenvalues, &projections, &damping, &strike)?;
    let fs = f64::from(args.sample_rate);
    let audible = bank
        .frequencies_hz
        .iter()
        .zip(&bank.amplitudes)
        .filter(|(f, a)| **f > 0.0 && **f < fs / 2.0 && **a > 0.0)
        .count();
    if audible == 0 {
        return Err(format!("no mode rings below the Nyquist frequency {} Hz at this strike point; nothing to render", fs / 2.0));
    }
    let samples = audio::render(&bank, fs, args.duration);
    audio::write_wav(&args.out, &samples, args.sample_rate, format, normalise)
        .map_err(|e| e.to_string())?;
    let peak = samples.iter().fold(0.0_f64, |m, s| m.max(s.abs()));
    println!(
        "wrote {} ({:.2} s at {} Hz): {} of {} modes audible, strike at ({:.4}, {:.4}, {:.4}) m along ({:.3}, {:.3}, {:.3}), {:?}, {:?}, physical peak {:.3e}",
        args.out.display(),
        args.duration,
        args.sample_rate,
        audible,
        file.n_modes,
        point.position[0],
        point.position[1],
        point.position[2],
        direction[0],
        direction[1],
        direction[2],
        args.force,
        args.response,
        peak
    );
    Ok(())
}
