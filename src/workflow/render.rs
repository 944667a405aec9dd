//! The `render` job: a strike rendered from a modes HDF5 file to WAV.
//!
//! Mode k sounds with complex amplitude z_k = J (φ_k(x)·n) G_k (see [`crate::audio::excitation`]),
//! where x is the impact point (a surface vertex, or the surface point nearest a given
//! position, read with the element's shape functions), n the strike direction (default the
//! outward normal, inwards), J the impulse [N·s], and G_k the contact-force spectrum and response
//! factor; it decays with the chosen damping (the file's Rayleigh α, β by default, or a
//! damping curve d(f) from a TOML file with `frequencies_hz` and `decay_rates` arrays).

use crate::audio::chain::{ChainError, DampingCurve, DampingModel, ModalChain, Strike};
use crate::audio::excitation::{ContactForce, Response};
use crate::audio::{self, AudioError, WavFormat};
use crate::io::IoError;
use crate::mesh::{ElementOrder, SurfacePoint, TetMesh};
use std::path::{Path, PathBuf};

/// Where the hammer lands.
#[derive(Clone, Copy, Debug)]
pub enum StrikeAt {
    /// This surface node (0-based, as in the modes file).
    Vertex(usize),
    /// The surface point nearest to this position [m].
    Position([f64; 3]),
    /// The mesh's default strike point.
    Default,
}

/// How the modes decay.
#[derive(Clone, Debug)]
pub enum Damping {
    /// Rayleigh α [1/s] and β [s]; each `None` takes the modes file's material value.
    Rayleigh {
        alpha: Option<f64>,
        beta: Option<f64>,
    },
    /// A damping curve d(f) read from this TOML file.
    Curve(PathBuf),
}

/// Everything the job needs, checked as far as the flags alone allow.
#[derive(Clone, Debug)]
pub struct Job {
    /// Modes HDF5 file written by the `modes` job.
    pub modes: PathBuf,
    /// Output WAV file.
    pub out: PathBuf,
    pub at: StrikeAt,
    /// Strike direction (normalised by the job); `None`: the inward surface normal.
    pub direction: Option<[f64; 3]>,
    pub force: ContactForce,
    pub response: Response,
    /// Impulse J of the strike [N·s].
    pub impulse: f64,
    pub damping: Damping,
    /// Length [s].
    pub duration: f64,
    /// Sample rate [Hz].
    pub sample_rate: u32,
    pub format: WavFormat,
    /// Peak level after normalisation; `None` keeps physical units.
    pub normalise: Option<f64>,
}

/// What can stop the job.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    ModesFile(#[from] IoError),
    #[error("{}: the file holds no modes", .0.display())]
    NoModes(PathBuf),
    #[error("{}: {nodes_per_tet} nodes per tet is not a tet mesh we know", path.display())]
    NotTets { path: PathBuf, nodes_per_tet: usize },
    /// The strike point does not lie on the surface (or the mesh has none).
    #[error("{0}")]
    StrikePoint(String),
    #[error("--direction must not be the zero vector")]
    ZeroDirection,
    /// The damping curve file could not be read or is no curve.
    #[error(transparent)]
    DampingCurve(#[from] CurveFileError),
    /// The modal chain refused the modes and their damping.
    #[error(transparent)]
    Chain(#[from] ChainError),
    #[error("no mode rings below the Nyquist frequency {nyquist_hz} Hz at this strike point; nothing to render")]
    NothingAudible { nyquist_hz: f64 },
    #[error(transparent)]
    Audio(#[from] AudioError),
}

/// The rendered strike.
#[derive(Clone, Debug)]
pub struct Report {
    /// The signal in physical units (before any normalisation).
    pub samples: Vec<f64>,
    pub point: SurfacePoint,
    /// The unit strike direction.
    pub direction: [f64; 3],
    /// Modes that ring below the Nyquist frequency with a non-zero amplitude.
    pub audible: usize,
    /// Modes in the file.
    pub n_modes: usize,
    /// Largest |sample| before normalisation.
    pub peak: f64,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct CurveFile {
    frequencies_hz: Vec<f64>,
    decay_rates: Vec<f64>,
}

/// Why a damping-curve TOML file was refused; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum CurveFileError {
    #[error("{path}: {source}")]
    Read {
        path: String,
        source: std::io::Error,
    },
    #[error("{path}: {source}")]
    Parse {
        path: String,
        source: toml::de::Error,
    },
    #[error("{path}: {source}")]
    Invalid { path: String, source: ChainError },
}

/// Reads a damping curve TOML file.
pub fn read_damping_curve(path: &Path) -> Result<DampingCurve, CurveFileError> {
    let name = || path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| CurveFileError::Read {
        path: name(),
        source,
    })?;
    let file: CurveFile = toml::from_str(&text).map_err(|source| CurveFileError::Parse {
        path: name(),
        source,
    })?;
    DampingCurve::new(file.frequencies_hz, &file.decay_rates).map_err(|source| {
        CurveFileError::Invalid {
            path: name(),
            source,
        }
    })
}

/// Renders the strike (the WAV is written by [`write_wav`]).
pub fn run(job: &Job) -> Result<Report, Error> {
    let file = crate::io::read_modes(&job.modes)?;
    if file.n_modes == 0 {
        return Err(Error::NoModes(job.modes.clone()));
    }
    let order = match file.nodes_per_tet {
        4 => ElementOrder::Linear,
        10 => ElementOrder::Quadratic,
        n => {
            return Err(Error::NotTets {
                path: job.modes.clone(),
                nodes_per_tet: n,
            })
        }
    };
    let mesh = TetMesh {
        nodes: file.nodes.clone(),
        connectivity: file.connectivity.clone(),
        order,
    };
    let point = match job.at {
        StrikeAt::Vertex(v) => mesh.surface_point_at_vertex(v).ok_or_else(|| {
            Error::StrikePoint(format!(
                "--vertex {v} is not a surface corner node of the mesh ({} nodes)",
                mesh.n_nodes()
            ))
        })?,
        StrikeAt::Position(p) => {
            let sp = mesh
                .closest_surface_point(p)
                .ok_or_else(|| Error::StrikePoint("the mesh has no surface".into()))?;
            let (lo, hi) = mesh.bounding_box();
            let diagonal = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
            if sp.distance > 0.05 * diagonal {
                return Err(Error::StrikePoint(format!(
                    "--position {:?} is {:.4} m from the surface (more than 5 % of the mesh size {:.4} m); is it in the mesh's units (metres)?",
                    p, sp.distance, diagonal
                )));
            }
            sp
        }
        StrikeAt::Default => mesh
            .default_strike_point()
            .ok_or_else(|| Error::StrikePoint("the mesh has no surface".into()))?,
    };
    // The hammer pushes into the body: along −n unless told otherwise.
    let direction = match job.direction {
        Some(d) => {
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            if n == 0.0 {
                return Err(Error::ZeroDirection);
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
            job.impulse * (u[0] * direction[0] + u[1] * direction[1] + u[2] * direction[2])
        })
        .collect();
    let damping = match &job.damping {
        Damping::Curve(path) => DampingModel::Curve(read_damping_curve(path)?),
        Damping::Rayleigh { alpha, beta } => DampingModel::Rayleigh {
            alpha: alpha.unwrap_or(file.material.rayleigh_alpha),
            beta: beta.unwrap_or(file.material.rayleigh_beta),
        },
    };
    let strike = Strike {
        force: job.force,
        response: job.response,
    };
    let (bank, _) = ModalChain::new(&file.eigenvalues, &projections, &damping, &strike)?;
    let fs = f64::from(job.sample_rate);
    let audible = bank
        .frequencies_hz
        .iter()
        .zip(&bank.amplitudes)
        .filter(|(f, a)| **f > 0.0 && **f < fs / 2.0 && **a > 0.0)
        .count();
    if audible == 0 {
        return Err(Error::NothingAudible {
            nyquist_hz: fs / 2.0,
        });
    }
    let samples = audio::render(&bank, fs, job.duration);
    let peak = samples.iter().fold(0.0_f64, |m, s| m.max(s.abs()));
    Ok(Report {
        samples,
        point,
        direction,
        audible,
        n_modes: file.n_modes,
        peak,
    })
}

/// Writes the rendered strike to the job's WAV file, in its format and normalisation.
pub fn write_wav(job: &Job, report: &Report) -> Result<(), Error> {
    audio::write_wav(
        &job.out,
        &report.samples,
        job.sample_rate,
        job.format,
        job.normalise,
    )?;
    Ok(())
}
