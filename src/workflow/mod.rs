//! The jobs: each command of the tool as a `Job` in and a `Report` out, above the pipeline's
//! stages (mesh → fem → assembly → eigen → shape → audio → analysis → inverse → diagnose) and
//! below the command line, which only parses, merges configuration files and prints.
//!
//! A job reports progress through a [`Progress`] callback, so the same job runs silently in a
//! test, prints timed lines on a terminal, or feeds another program.

pub mod diagnose;
pub mod fit_geometry;
pub mod fit_material;
pub mod fit_shape;
pub mod locate_impact;
pub mod material;
pub mod modes;
pub mod render;
pub mod spectrogram;

use crate::petsc::Petsc;
use mpi::traits::{Communicator, Root};
use std::time::Instant;

/// Progress of a long job: each message goes to a callback with the seconds since the job began.
pub struct Progress {
    start: Instant,
    sink: Option<Box<Sink>>,
}

/// Where progress messages go: (seconds since the start, message).
type Sink = dyn Fn(f64, &str);

impl Progress {
    /// Progress that goes nowhere (tests, library use).
    pub fn silent() -> Self {
        Progress {
            start: Instant::now(),
            sink: None,
        }
    }

    /// Progress handed to `callback(seconds_since_start, message)`.
    pub fn new(callback: impl Fn(f64, &str) + 'static) -> Self {
        Progress {
            start: Instant::now(),
            sink: Some(Box::new(callback)),
        }
    }

    /// Whether anyone listens (so a job can skip composing costly messages).
    pub fn enabled(&self) -> bool {
        self.sink.is_some()
    }

    /// Reports one message.
    pub fn say(&self, msg: impl AsRef<str>) {
        if let Some(sink) = &self.sink {
            sink(self.start.elapsed().as_secs_f64(), msg.as_ref());
        }
    }
}

static QUIET: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Silences (or restores) progress lines made by [`crate::cli::stderr_progress`] and [`note`]s
/// for the rest of the process (`--quiet`). Warnings, errors and results still print: they are
/// what a quiet run is for.
pub fn set_quiet(quiet: bool) {
    QUIET.store(quiet, std::sync::atomic::Ordering::Relaxed);
}

/// Whether [`set_quiet`] silenced progress and notes.
pub fn quiet() -> bool {
    QUIET.load(std::sync::atomic::Ordering::Relaxed)
}

/// A non-essential remark on stderr (`note: …`), unless quiet.
pub fn note(msg: impl std::fmt::Display) {
    if !quiet() {
        eprintln!("note: {msg}");
    }
}

/// `items` joined with ", " for a message, at most `max` of them, then "… (N in all)", so a
/// list of forty frequencies does not make a 400-character progress line.
pub fn short_list<T: std::fmt::Display>(items: &[T], max: usize) -> String {
    let shown: Vec<String> = items.iter().take(max).map(|v| v.to_string()).collect();
    let mut s = shown.join(", ");
    if items.len() > max {
        s.push_str(&format!(", … ({} in all)", items.len()));
    }
    s
}

/// The mesh a job assembles on: read with the fold check ([`crate::mesh::read_for_fem`]; curved
/// tets that fold over are refused with the file and Gmsh tags named, or straightened on
/// request), its warnings printed on rank 0 (before any later error), then lifted to 10-node
/// tets (`order` 2) or reduced to 4-node ones (`order` 1). Also returns the file's own order
/// (nodes per tet).
pub fn model_mesh(
    petsc: &Petsc,
    path: &std::path::Path,
    options: &crate::mesh::ReadOptions,
    straighten_invalid: bool,
    order: u32,
) -> Result<(crate::mesh::TetMesh, usize), crate::mesh::MeshError> {
    let read = crate::mesh::read_for_fem(path, options, straighten_invalid)?;
    if petsc.rank() == 0 {
        for w in &read.warnings {
            eprintln!("warning: {w}");
        }
    }
    let input_order = read.mesh.nodes_per_tet();
    let mesh = if order == 2 {
        crate::mesh::lift_to_quadratic(&read.mesh)
    } else {
        crate::mesh::to_linear(&read.mesh)
    };
    Ok((mesh, input_order))
}

/// Writes a shape fit's final body with its modes (the modes file of [`crate::io`], which
/// ParaView opens through its XDMF sidecar) at `path`; `name` labels the material, `fit` is the
/// fit's own result file (recorded as provenance).
pub fn write_body_modes(
    path: &std::path::Path,
    body: &crate::shape::ShapeModes,
    material: &crate::fem::Material,
    name: String,
    n_ranks: usize,
    fit: &std::path::Path,
) -> Result<(), crate::io::IoError> {
    let frequencies: Vec<f64> = body
        .eigenvalues
        .iter()
        .map(|&l| crate::eigen::frequency_hz(l))
        .collect();
    let file = crate::io::ModesFile {
        nodes: &body.mesh.nodes,
        connectivity: &body.mesh.connectivity,
        nodes_per_tet: body.mesh.nodes_per_tet(),
        material: crate::io::MaterialRecord::of(name, material),
        eigenvalues: &body.eigenvalues,
        frequencies_hz: &frequencies,
        mode_shapes: &body.shapes,
        residual_norms: &body.residuals,
        rigid_eigenvalues: &body.rigid_eigenvalues,
        solver: Vec::new(),
        n_ranks,
        element_order: 2,
        timings: Vec::new(),
        provenance: vec![
            (
                "command".into(),
                std::env::args().collect::<Vec<_>>().join(" "),
            ),
            ("fit".into(), fit.display().to_string()),
        ],
        extra_datasets: Vec::new(),
        node_fields: Vec::new(),
    };
    crate::io::write_modes(path, &file)
}

/// Broadcasts a value from rank 0 (a length, then the bytes of [`encode_for_broadcast`]).
/// Every rank returns the same value or the same error: a value rank 0 cannot encode is an
/// error on every rank, not a rank waiting forever for bytes that never come.
pub fn broadcast_from_root<T: serde::Serialize + serde::de::DeserializeOwned>(
    petsc: &Petsc,
    value: Option<T>,
) -> Result<T, String> {
    broadcast_from(petsc, 0, value)
}

/// [`broadcast_from_root`] from rank `root` (which passes `Some`; the others `None`).
pub fn broadcast_from<T: serde::Serialize + serde::de::DeserializeOwned>(
    petsc: &Petsc,
    root: i32,
    value: Option<T>,
) -> Result<T, String> {
    let root = petsc.world().process_at_rank(root);
    let (mut bytes, failure) = match value.as_ref().map(encode_for_broadcast) {
        Some(Ok(bytes)) => (bytes, None),
        Some(Err(e)) => (Vec::new(), Some(e)),
        None => (Vec::new(), None),
    };
    // u64::MAX: rank 0 could not encode the value.
    let mut len = if failure.is_some() {
        u64::MAX
    } else {
        bytes.len() as u64
    };
    root.broadcast_into(&mut len);
    if len == u64::MAX {
        return Err(format!(
            "broadcast from rank {}: {}",
            root.rank(),
            failure.unwrap_or_else(|| "the rank could not encode its result".into())
        ));
    }
    bytes.resize(len as usize, 0);
    root.broadcast_into(&mut bytes[..]);
    match value {
        Some(v) => Ok(v),
        None => decode_from_broadcast(&bytes),
    }
}

/// CBOR, which carries every f64 bit for bit. The first version sent JSON: a NaN or ±∞
/// anywhere in a diagnosis's extraction became `null`, which the other ranks could not read
/// (seed 404 case 019 of the blind benchmark stopped with "invalid type: null, expected f64"),
/// and JSON's decimal round trip is not guaranteed exact, so ranks could differ in the last bit.
pub fn encode_for_broadcast<T: serde::Serialize>(value: &T) -> Result<Vec<u8>, String> {
    let mut bytes = Vec::new();
    ciborium::into_writer(value, &mut bytes)
        .map_err(|e| format!("encoding rank 0's result: {e}"))?;
    Ok(bytes)
}

/// The inverse of [`encode_for_broadcast`].
pub fn decode_from_broadcast<T: serde::de::DeserializeOwned>(bytes: &[u8]) -> Result<T, String> {
    ciborium::from_reader(bytes).map_err(|e| format!("broadcast from rank 0: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What rank 0 broadcasts reaches the other ranks bit for bit, NaN and ±∞ included (JSON
    /// turned them into null and the other ranks failed to read it).
    #[test]
    fn a_broadcast_value_survives_bit_for_bit() {
        #[derive(serde::Serialize, serde::Deserialize, Debug)]
        struct Sample {
            values: Vec<f64>,
            pair: Option<(f64, f64)>,
            name: String,
        }
        let sample = Sample {
            values: vec![
                f64::NAN,
                f64::INFINITY,
                f64::NEG_INFINITY,
                0.1 + 0.2,
                -0.0,
                5e-324,
                f64::MAX,
            ],
            pair: Some((1.0 / 3.0, f64::NAN)),
            name: "ν".into(),
        };
        let back: Sample = decode_from_broadcast(&encode_for_broadcast(&sample).unwrap()).unwrap();
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<u64>>();
        assert_eq!(bits(&back.values), bits(&sample.values));
        let (a, b) = back.pair.unwrap();
        assert_eq!(
            (a.to_bits(), b.to_bits()),
            ((1.0f64 / 3.0).to_bits(), f64::NAN.to_bits())
        );
        assert_eq!(back.name, "ν");
        assert!(decode_from_broadcast::<Sample>(&[0xff, 0x00]).is_err());
    }
}
