//! Results on disk: one HDF5 file per modal solve, plus an XDMF sidecar so
//! ParaView can show every mode shape on the mesh without any plugin.
//!
//! Everything here is serial: the caller gathers the distributed data to rank 0
//! and calls [`write_modes`] there. Both files are written through
//! [`write_atomically`], so a reader never sees a half-written file: after a
//! crash there is either the complete previous file, the complete new one, or
//! nothing (plus possibly a stale `.<name>.tmp.<pid>`).
//!
//! The run configuration files (TOML, the `--config` of every command) are [`config`].
//!
//! # HDF5 layout
//!
//! Every dataset carries a string attribute `units` ("1" for dimensionless, "" for indices),
//! the same convention as the fit results ([`results`]).
//!
//! | path                        | type / shape                        | units, meaning |
//! |-----------------------------|-------------------------------------|----------------|
//! | `/` attrs                   | `format` = `"diffsound.modes"`, `format_version` (u64) = 4 | identifies the file (1: no `/modes/by_mode`; 2: no `/node_fields`, no extra datasets; 3: no `units` attributes, node fields always `[n_nodes, 3]`) |
//! | `/mesh/nodes`               | f64 `[n_nodes, 3]`                  | `m`, original mesh numbering |
//! | `/mesh/tets`                | u64 `[n_tets, nodes_per_tet]`       | `""`: 0-based node ids, Gmsh order; attr `element_order` (u32, 1 or 2) |
//! | `/mesh/tets_vtk`            | u64 `[n_tets, nodes_per_tet]`       | `""`: same cells in VTK/XDMF order (used by the sidecar, and what meshio returns) |
//! | `/material` attrs           | `youngs_modulus` f64, `poisson_ratio` f64, `density` f64, `rayleigh_alpha` f64, `rayleigh_beta` f64, `name` string | Pa, –, kg/m³, 1/s, s |
//! | `/modes/eigenvalues`        | f64 `[n_modes]`                     | `rad^2/s^2`: λ = ω², elastic modes only, ascending |
//! | `/modes/frequencies`        | f64 `[n_modes]`                     | `Hz`, f = √λ / 2π |
//! | `/modes/shapes`             | f64 `[n_modes, n_nodes, 3]`         | `kg^-1/2`: mass-normalised φ (φᵀMφ = 1), node-major x,y,z |
//! | `/modes/by_mode/mode_KKK`   | f64 `[n_nodes, 3]`, virtual         | `kg^-1/2`: mode `KKK` = `/modes/shapes[KKK, :, :]`, no copy (see below) |
//! | `/modes/residual_norms`     | f64 `[n_modes]`                     | `1`: relative residual ‖Kφ − λMφ‖ / … |
//! | `/modes/rigid_eigenvalues`  | f64 `[k]`                           | `rad^2/s^2`, the near-zero modes that were removed |
//! | `/solver` attrs             | key → value strings, plus `n_ranks` (u64) | solver settings and PETSc options |
//! | `/timings` attrs            | key → f64                           | seconds (assembly, solve, total, …) |
//! | `/provenance` attrs         | key → value strings                 | mesh path, units, command line, diffsound version |
//! | `/node_fields/<name>`       | f64 `[n_nodes]` (scalar) or `[n_nodes, 3]` (vector); attr `units` | optional per-node fields ([`NodeField`], e.g. `d_lambda_dx_mode_003`), vectors node-major x,y,z, original numbering; also in the XDMF sidecar |
//! | `/sensitivities/…`          | f64, any shape; string attrs (e.g. `units`) | written when sensitivities are requested: see `eigen::sensitivity` |
//! | any other `/<group>/…/<name>` | f64 (i64 where `integer`), any shape; string attrs | extra datasets ([`ExtraDataset`]), e.g. the `/sensitivities/…` above |
//!
//! `/node_fields` and the extra datasets are optional: a file without them
//! (including every format-1 and format-2 file) reads back with both lists
//! empty. An extra dataset's path is absolute (`/a/b/name`), every component
//! is non-empty `[A-Za-z0-9_.-]` (not `.` or `..`), and its first component
//! must not be one of the fixed top-level groups ([`RESERVED_GROUPS`]: `mesh`,
//! `material`, `modes`, `solver`, `timings`, `provenance`, `node_fields`), so
//! [`read_modes`] can tell extras from the fixed layout: every dataset outside
//! those groups (root-level ones included) is an extra. Intermediate groups
//! are created as needed; two extras may share groups but neither may sit at
//! or below the other's path. Node field names are non-empty `[A-Za-z0-9_]`
//! and unique. [`read_modes`] returns both lists sorted by path / name (HDF5's
//! link order), not in the order they were given.
//!
//! `/modes/shapes` is the only stored copy of the shapes. Each
//! `/modes/by_mode/mode_KKK` is an HDF5 virtual dataset (HDF5 ≥ 1.10) whose
//! one mapping takes all of it from the slab `[KKK, :, :]` of
//! `/modes/shapes` in source file `"."`, which `H5Pset_virtual` documents as
//! naming a source dataset in the same file; so the mapping survives the
//! temp-file rename and moving the file. (With no nodes they are plain empty
//! datasets: an empty selection cannot be mapped.) `KKK` is the mode index zero-padded to
//! [`mode_index_width`] digits (enough for `n_modes - 1`, at least 3). They
//! exist for XDMF readers that cannot take a slab of a 3-D dataset (below).
//!
//! Strings are variable-length UTF-8. Attribute keys must be non-empty and
//! unique within their group (a repeated key is an error, not a silent
//! overwrite); `/solver` may not use the key `n_ranks`, which is reserved.
//!
//! # XDMF sidecar
//!
//! `<path>` with the extension replaced by `.xdmf`, XDMF 3 (`<Xdmf Version="3.0">`),
//! written by [`xdmf_document`] for every file [`write_modes`] writes (the modes job and the
//! maps of `locate-impact`, `diagnose` and the shape fits): one uniform Grid `mesh`
//! whose Topology is `Tetrahedron` (4 nodes) or
//! `Tetrahedron_10` (10 nodes) reading `/mesh/tets_vtk`, Geometry `XYZ` reading
//! `/mesh/nodes`, and per mode `k` a node-centred vector Attribute named
//! `mode_KKK (F Hz)` whose plain HDF DataItem (`Dimensions="n_nodes 3"`)
//! reads `/modes/by_mode/mode_KKK`; then per node field a node-centred
//! Attribute named `<name>`: `AttributeType="Scalar"` with a DataItem of
//! `Dimensions="n_nodes"` for a scalar field (ParaView colours it by its value, sign
//! included), `AttributeType="Vector"` with `Dimensions="n_nodes 3"` for a vector
//! field, reading `/node_fields/<name>`. The HDF5 file is named
//! by its file name only (relative to the sidecar), so the pair can be moved
//! together. Connectivity is declared `NumberType="Int" Precision="8"`: HDF5
//! converts the stored u64 on read, and signed 64-bit is the index type every
//! XDMF reader accepts.
//!
//! Every element holds exactly one DataItem and nothing else: no `<Information>`
//! (meshio's reader refuses a Grid `Information` without text and an Attribute with
//! two children, "Couldn't read file … as xdmf"). What such elements carried lives in
//! the HDF5 file: the material's name in `/material`, a field's units in the `units`
//! attribute of `/node_fields/<name>`.
//!
//! Readers checked by the tests: meshio (Python; `meshio.read` gives `tetra10` or
//! `tetra` cells and every Attribute as a point field, scalars 1-D; the CLI test of
//! every command that writes a sidecar reads it so, `tests/python/check_sidecar.py`) and, when `pvbatch` is
//! installed, ParaView's default `.xdmf` reader
//! (`Xdmf3ReaderS`) and the legacy "XDMF Reader" (quadratic tets, every mode as
//! a point vector with the stored values, and every node field likewise). The per-mode virtual datasets are
//! what makes the Xdmf3 readers work: given a HyperSlab DataItem instead they
//! load the mesh but drop the attribute ("Skipping unrecognized array type
//! [None]").
//!
//! If writing the sidecar fails after the HDF5 file was
//! renamed into place, the HDF5 file stays (it is complete and self-describing)
//! and the error is returned.
//!
//! # Tet10 node order: Gmsh → XDMF/VTK
//!
//! Gmsh's 10-node tet puts the mid-edge nodes on edges
//! 4:(0,1) 5:(1,2) 6:(0,2) 7:(0,3) 8:(2,3) 9:(1,3); VTK's `VTK_QUADRATIC_TETRA`
//! (vtkQuadraticTetra.h) uses (0,1) (1,2) (2,0) (0,3) (1,3) (2,3). ParaView's
//! XDMF readers (VTK `vtkXdmfHeavyData`, `vtkXdmf3DataSet`) map
//! `Tetrahedron_10` to `VTK_QUADRATIC_TETRA` and copy the connectivity
//! verbatim, so XDMF order is VTK order and the conversion is swapping local
//! nodes 8 and 9: `vtk[i] = gmsh[GMSH_TO_VTK_TET10[i]]`.

use std::fmt::Write as _;
use std::fs;
use std::path::{Path, PathBuf};

use hdf5::types::VarLenUnicode;

pub mod atomic;
pub mod config;
pub mod fit_material;
pub mod paths;
pub mod plot;
pub mod preflight;
pub mod results;
#[cfg(test)]
pub(crate) mod test_support;

/// Value of the root attribute `format`.
pub const FORMAT_NAME: &str = "diffsound.modes";
/// Value of the root attribute `format_version`; bump on any layout change.
/// Version 2 added `/modes/by_mode`, version 3 the optional `/node_fields`
/// and extra datasets, version 4 the `units` attributes and scalar node fields;
/// [`read_modes`] still reads versions 1 to 3 (it needs only `/modes/shapes`,
/// and reads the optional parts only where present).
pub const FORMAT_VERSION: u64 = 4;

/// Top-level groups of the fixed layout. An [`ExtraDataset`] may not live in
/// (or be) any of them.
pub const RESERVED_GROUPS: [&str; 7] = [
    "mesh",
    "material",
    "modes",
    "solver",
    "timings",
    "provenance",
    "node_fields",
];

/// An additional f64 dataset stored at an arbitrary path outside the fixed
/// layout (see module docs), e.g. `/sensitivities/d_eigenvalue_d_youngs`.
/// Also what [`read_modes`] returns for each one found.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ExtraDataset {
    /// Absolute HDF5 path, `/group/…/name`; intermediate groups are created.
    pub path: String,
    /// Dataset shape, row-major; `[]` is a scalar (one value).
    pub shape: Vec<usize>,
    /// Row-major values; length = product of `shape`.
    pub data: Vec<f64>,
    /// String attributes on the dataset (e.g. `("units", "rad²/s²/Pa")`);
    /// keys non-empty and unique.
    pub attrs: Vec<(String, String)>,
    /// Stored as i64 (indices, counts, ranges): every value must then be a whole number
    /// within ±2⁵³. Read back true for any integer dataset.
    pub integer: bool,
}

/// Values per node of a [`NodeField`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum FieldKind {
    /// One value per node: dataset `[n_nodes]`, XDMF `AttributeType="Scalar"`.
    Scalar,
    /// x, y, z per node: dataset `[n_nodes, 3]`, XDMF `AttributeType="Vector"`.
    Vector,
}

impl FieldKind {
    /// Values per node: 1 or 3.
    pub fn components(self) -> usize {
        match self {
            FieldKind::Scalar => 1,
            FieldKind::Vector => 3,
        }
    }

    /// The dataset shape for `n_nodes` nodes.
    fn shape(self, n_nodes: usize) -> Vec<usize> {
        match self {
            FieldKind::Scalar => vec![n_nodes],
            FieldKind::Vector => vec![n_nodes, 3],
        }
    }
}

/// A per-node field shown on the mesh, stored as `/node_fields/<name>` and
/// referenced from the XDMF sidecar.
#[derive(Clone, Debug, PartialEq)]
pub struct NodeField<'a> {
    /// Non-empty `[A-Za-z0-9_]`, unique; dataset and ParaView array name
    /// (e.g. `d_lambda_dx_mode_003`).
    pub name: String,
    pub kind: FieldKind,
    /// `kind.components()`·n_nodes values, node-major (x,y,z for a vector),
    /// original mesh numbering.
    pub data: &'a [f64],
    /// Stored as the dataset's `units` attribute (e.g. `rad^2/s^2/m`).
    pub units: String,
}

impl<'a> NodeField<'a> {
    /// One value per node.
    pub fn scalar(name: &str, data: &'a [f64], units: &str) -> NodeField<'a> {
        NodeField {
            name: name.into(),
            kind: FieldKind::Scalar,
            data,
            units: units.into(),
        }
    }

    /// x, y, z per node, node-major.
    pub fn vector(name: &str, data: &'a [f64], units: &str) -> NodeField<'a> {
        NodeField {
            name: name.into(),
            kind: FieldKind::Vector,
            data,
            units: units.into(),
        }
    }
}

/// A node field as [`read_modes`] returns it.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NodeFieldData {
    pub name: String,
    /// Scalar for a `[n_nodes]` dataset, vector for `[n_nodes, 3]` (every
    /// field of a format-3 file).
    pub kind: FieldKind,
    /// `kind.components()`·n_nodes values, node-major.
    pub data: Vec<f64>,
    pub units: String,
}

/// `units` of the eigenvalue datasets (λ = ω²).
pub const EIGENVALUE_UNITS: &str = "rad^2/s^2";
/// `units` of the mass-normalised mode shapes (φᵀMφ = 1 with M in kg).
pub const SHAPE_UNITS: &str = "kg^-1/2";

/// `vtk[i] = gmsh[GMSH_TO_VTK_TET10[i]]` for one 10-node tet (see module docs).
pub const GMSH_TO_VTK_TET10: [usize; 10] = [0, 1, 2, 3, 4, 5, 6, 7, 9, 8];

/// Material as stored under `/material`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MaterialRecord {
    /// "custom" when the material was not taken from a named preset.
    pub name: String,
    /// Young's modulus E, Pa.
    pub youngs_modulus: f64,
    /// Poisson's ratio ν, dimensionless.
    pub poisson_ratio: f64,
    /// Density ρ, kg/m³.
    pub density: f64,
    /// Rayleigh mass-proportional damping α, 1/s (C = αM + βK).
    pub rayleigh_alpha: f64,
    /// Rayleigh stiffness-proportional damping β, s.
    pub rayleigh_beta: f64,
}

impl MaterialRecord {
    /// The record of `material` under `name`.
    pub fn of(name: impl Into<String>, material: &crate::fem::Material) -> Self {
        MaterialRecord {
            name: name.into(),
            youngs_modulus: material.youngs_modulus,
            poisson_ratio: material.poisson_ratio,
            density: material.density,
            rayleigh_alpha: material.rayleigh_alpha,
            rayleigh_beta: material.rayleigh_beta,
        }
    }

    /// The record of an elastic material under `name` with no damping law (α = β = 0), for
    /// the modes files of jobs that carry none (E \[Pa\], ν, ρ \[kg/m³\]).
    pub fn undamped(
        name: impl Into<String>,
        youngs_modulus: f64,
        poisson_ratio: f64,
        density: f64,
    ) -> Self {
        MaterialRecord {
            name: name.into(),
            youngs_modulus,
            poisson_ratio,
            density,
            rayleigh_alpha: 0.0,
            rayleigh_beta: 0.0,
        }
    }
}

/// Everything one modal solve produces, borrowed from the caller (rank 0).
pub struct ModesFile<'a> {
    /// Node coordinates, m, original mesh numbering.
    pub nodes: &'a [[f64; 3]],
    /// `nodes_per_tet` 0-based node ids per tet, Gmsh order
    /// (tet10: corners 0..3, mid-edge 4:(0,1) 5:(1,2) 6:(0,2) 7:(0,3) 8:(2,3) 9:(1,3)).
    pub connectivity: &'a [usize],
    /// 4 or 10.
    pub nodes_per_tet: usize,
    pub material: MaterialRecord,
    /// λ = ω², rad²/s², elastic modes only, ascending.
    pub eigenvalues: &'a [f64],
    /// f = √λ / 2π, Hz.
    pub frequencies_hz: &'a [f64],
    /// One per mode, length 3·n_nodes, node-major (x,y,z), mass-normalised.
    pub mode_shapes: &'a [Vec<f64>],
    /// Relative residual per mode.
    pub residual_norms: &'a [f64],
    /// The near-zero (rigid-body) eigenvalues that were removed, rad²/s².
    pub rigid_eigenvalues: &'a [f64],
    /// Solver settings and PETSc options as key/value strings.
    pub solver: Vec<(String, String)>,
    pub n_ranks: usize,
    /// 1 (tet4) or 2 (tet10).
    pub element_order: u32,
    /// Wall-clock seconds per phase (assembly, solve, total, …).
    pub timings: Vec<(String, f64)>,
    /// Mesh path, units, command line, diffsound version, …
    pub provenance: Vec<(String, String)>,
    /// Additional f64 datasets outside the fixed layout (e.g. `/sensitivities/…`).
    pub extra_datasets: Vec<ExtraDataset>,
    /// Per-node scalar or vector fields, written to `/node_fields` and the sidecar.
    pub node_fields: Vec<NodeField<'a>>,
}

/// What [`read_modes`] returns: the whole file, owned.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ModesSummary {
    pub n_nodes: usize,
    pub n_tets: usize,
    pub n_modes: usize,
    pub nodes_per_tet: usize,
    pub element_order: u32,
    /// m, original numbering.
    pub nodes: Vec<[f64; 3]>,
    /// Gmsh order, flattened `nodes_per_tet` per tet.
    pub connectivity: Vec<usize>,
    pub material: MaterialRecord,
    /// rad²/s².
    pub eigenvalues: Vec<f64>,
    /// Hz.
    pub frequencies_hz: Vec<f64>,
    /// One per mode, length 3·n_nodes, node-major (x,y,z).
    pub mode_shapes: Vec<Vec<f64>>,
    pub residual_norms: Vec<f64>,
    pub rigid_eigenvalues: Vec<f64>,
    pub n_ranks: usize,
    /// Attribute order as HDF5 lists it (by name), without `n_ranks`.
    pub solver: Vec<(String, String)>,
    pub timings: Vec<(String, f64)>,
    pub provenance: Vec<(String, String)>,
    /// Every dataset outside [`RESERVED_GROUPS`], sorted by path; attributes
    /// in HDF5's (name) order. Empty for files without any.
    pub extra_datasets: Vec<ExtraDataset>,
    /// `/node_fields/<name>`, sorted by name. Empty for files without
    /// `/node_fields`.
    pub node_fields: Vec<NodeFieldData>,
}

/// Errors of this module; every variant names the file it concerns.
#[derive(thiserror::Error, Debug)]
pub enum IoError {
    #[error("{path}: {context}: {source}")]
    Hdf5 {
        path: PathBuf,
        context: String,
        #[source]
        source: hdf5::Error,
    },
    #[error("{path}: {context}: {source}")]
    Fs {
        path: PathBuf,
        context: String,
        #[source]
        source: std::io::Error,
    },
    /// The data handed to a writer is inconsistent (nothing was written).
    #[error("{path}: refusing to write: {reason}")]
    InvalidInput { path: PathBuf, reason: String },
    /// The file exists and is HDF5 but does not hold the layout documented above.
    #[error("{path}: not a valid diffsound modes file: {reason}")]
    BadLayout { path: PathBuf, reason: String },
    /// Writing failed for a cause found by [`atomic::replace_atomically`] (disk full, quota,
    /// file size limit, …); nothing was written at `path`.
    #[error("cannot write {path}: {reason}")]
    WriteFailed { path: PathBuf, reason: String },
    /// The file is HDF5 but not the kind of result the reader wants (its root `format`
    /// attribute differs), or a version this build cannot read.
    #[error("{path}: not a {expected} file ({found})")]
    WrongFormat {
        path: PathBuf,
        /// The `format` the reader wants, e.g. `diffsound.fit_material`.
        expected: &'static str,
        /// What the file holds instead.
        found: String,
    },
}

impl IoError {
    fn hdf5(path: &Path, context: impl Into<String>) -> impl FnOnce(hdf5::Error) -> IoError + '_ {
        let context = context.into();
        move |source| IoError::Hdf5 {
            path: path.to_path_buf(),
            context,
            source,
        }
    }
    fn fs(path: &Path, context: impl Into<String>) -> impl FnOnce(std::io::Error) -> IoError + '_ {
        let context = context.into();
        move |source| IoError::Fs {
            path: path.to_path_buf(),
            context,
            source,
        }
    }
}

/// The sidecar path: `<path>` with its extension replaced by `xdmf`.
pub fn xdmf_path(h5_path: &Path) -> PathBuf {
    h5_path.with_extension("xdmf")
}

/// Permutes Gmsh-ordered connectivity into VTK/XDMF order (identity for tet4).
pub fn gmsh_to_vtk_connectivity(connectivity: &[usize], nodes_per_tet: usize) -> Vec<usize> {
    if nodes_per_tet != 10 {
        return connectivity.to_vec();
    }
    connectivity
        .chunks_exact(10)
        .flat_map(|tet| GMSH_TO_VTK_TET10.iter().map(move |&g| tet[g]))
        .collect()
}

/// Writes `path` via a temporary `<dir>/.<name>.tmp.<pid>` in the same
/// directory, then renames it over `path`. Rename within one directory is
/// atomic on POSIX, so readers see the old file or the complete new one. The
/// temporary is fsynced before the rename (so a crash cannot leave a renamed
/// but empty file) and removed if `write` or anything after it fails.
/// A thin wrapper over [`atomic::replace_atomically`].
pub fn write_atomically<F>(path: &Path, write: F) -> Result<(), IoError>
where
    F: FnOnce(&Path) -> Result<(), IoError>,
{
    atomic::replace_atomically(path, write)
}

impl atomic::AtomicWriteError for IoError {
    fn fs(path: &Path, context: String, source: std::io::Error) -> Self {
        IoError::Fs {
            path: path.to_path_buf(),
            context,
            source,
        }
    }
    fn no_file_name(path: &Path) -> Self {
        IoError::InvalidInput {
            path: path.to_path_buf(),
            reason: "path has no file name".into(),
        }
    }
    fn write_failed(path: &Path, reason: String) -> Self {
        IoError::WriteFailed {
            path: path.to_path_buf(),
            reason,
        }
    }
    fn os_error(&self) -> Option<std::io::Error> {
        match self {
            IoError::Fs { source, .. } => {
                source.raw_os_error().map(std::io::Error::from_raw_os_error)
            }
            IoError::Hdf5 { source, .. } => atomic::errno_in(&source.to_string()),
            _ => None,
        }
    }
}

/// Writes the HDF5 results file `path` and its XDMF sidecar (see module docs),
/// each atomically, HDF5 first so the sidecar never points at a missing file.
/// The input is validated before anything touches the disk.
pub fn write_modes(path: &Path, f: &ModesFile) -> Result<(), IoError> {
    validate(path, f)?;
    let h5_name = path
        .file_name()
        .and_then(|n| n.to_str())
        .ok_or_else(|| IoError::InvalidInput {
            path: path.to_path_buf(),
            reason: "file name is not valid UTF-8 (the XDMF sidecar must name it)".into(),
        })?
        .to_string();
    write_atomically(path, |tmp| write_h5(tmp, f))?;
    let xml = xdmf_document(&h5_name, f);
    let xdmf = xdmf_path(path);
    write_atomically(&xdmf, |tmp| {
        fs::write(tmp, xml.as_bytes()).map_err(IoError::fs(tmp, "writing XDMF sidecar"))
    })
}

fn validate(path: &Path, f: &ModesFile) -> Result<(), IoError> {
    let bad = |reason: String| {
        Err(IoError::InvalidInput {
            path: path.to_path_buf(),
            reason,
        })
    };
    let n_nodes = f.nodes.len();
    let npt = f.nodes_per_tet;
    let expected_order = match npt {
        4 => 1,
        10 => 2,
        _ => return bad(format!("nodes_per_tet is {npt}, expected 4 or 10")),
    };
    if f.element_order != expected_order {
        return bad(format!(
            "element_order {} does not match nodes_per_tet {npt}",
            f.element_order
        ));
    }
    if f.connectivity.len() % npt != 0 {
        return bad(format!(
            "connectivity length {} is not a multiple of {npt}",
            f.connectivity.len()
        ));
    }
    if let Some(&id) = f.connectivity.iter().find(|&&id| id >= n_nodes) {
        return bad(format!(
            "connectivity refers to node {id} but there are {n_nodes} nodes"
        ));
    }
    let n_modes = f.eigenvalues.len();
    for (what, len) in [
        ("frequencies_hz", f.frequencies_hz.len()),
        ("mode_shapes", f.mode_shapes.len()),
        ("residual_norms", f.residual_norms.len()),
    ] {
        if len != n_modes {
            return bad(format!(
                "{what} has {len} entries but there are {n_modes} eigenvalues"
            ));
        }
    }
    if let Some((k, s)) = f
        .mode_shapes
        .iter()
        .enumerate()
        .find(|(_, s)| s.len() != 3 * n_nodes)
    {
        return bad(format!(
            "mode shape {k} has length {}, expected 3·n_nodes = {}",
            s.len(),
            3 * n_nodes
        ));
    }
    check_keys(
        path,
        "solver",
        f.solver.iter().map(|(k, _)| k.as_str()),
        &["n_ranks"],
    )?;
    check_keys(
        path,
        "timings",
        f.timings.iter().map(|(k, _)| k.as_str()),
        &[],
    )?;
    check_keys(
        path,
        "provenance",
        f.provenance.iter().map(|(k, _)| k.as_str()),
        &[],
    )?;
    validate_node_fields(path, f)?;
    validate_extra_datasets(path, &f.extra_datasets)?;
    Ok(())
}

/// Whether `c` may appear in a node field name.
fn is_name_char(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

fn check_no_nul(path: &Path, what: &str, value: &str) -> Result<(), IoError> {
    if value.contains('\0') {
        return Err(IoError::InvalidInput {
            path: path.to_path_buf(),
            reason: format!("{what} contains a NUL character"),
        });
    }
    Ok(())
}

fn validate_node_fields(path: &Path, f: &ModesFile) -> Result<(), IoError> {
    let bad = |reason: String| {
        Err(IoError::InvalidInput {
            path: path.to_path_buf(),
            reason,
        })
    };
    let n_nodes = f.nodes.len();
    let mut seen = std::collections::HashSet::new();
    for field in &f.node_fields {
        let name = &field.name;
        if name.is_empty() {
            return bad("node field with an empty name".into());
        }
        if !name.chars().all(is_name_char) {
            return bad(format!(
                "node field name '{name}' has characters outside [A-Za-z0-9_]"
            ));
        }
        if !seen.insert(name.as_str()) {
            return bad(format!("node field '{name}' is given twice"));
        }
        let per_node = field.kind.components();
        if field.data.len() != per_node * n_nodes {
            return bad(format!(
                "node field '{name}' has length {}, expected {per_node}·n_nodes = {}",
                field.data.len(),
                per_node * n_nodes
            ));
        }
        check_no_nul(path, &format!("units of node field '{name}'"), &field.units)?;
    }
    Ok(())
}

fn validate_extra_datasets(path: &Path, extras: &[ExtraDataset]) -> Result<(), IoError> {
    let bad = |reason: String| {
        Err(IoError::InvalidInput {
            path: path.to_path_buf(),
            reason,
        })
    };
    let mut datasets = std::collections::HashSet::new();
    // Every proper prefix of every extra path: the groups it needs.
    let mut groups = std::collections::HashSet::new();
    for e in extras {
        let p = e.path.as_str();
        let Some(rest) = p.strip_prefix('/') else {
            return bad(format!(
                "extra dataset path '{p}' is not absolute (must start with '/')"
            ));
        };
        let parts: Vec<&str> = rest.split('/').collect();
        for part in &parts {
            let ok = !part.is_empty()
                && *part != "."
                && *part != ".."
                && part
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || "_.-".contains(c));
            if !ok {
                return bad(format!(
                    "extra dataset path '{p}': component '{part}' is empty, '.', '..' \
                     or has characters outside [A-Za-z0-9_.-]"
                ));
            }
        }
        if RESERVED_GROUPS.contains(&parts[0]) {
            return bad(format!(
                "extra dataset path '{p}' collides with the fixed layout (/{} is reserved)",
                parts[0]
            ));
        }
        let n = e
            .shape
            .iter()
            .try_fold(1usize, |acc, &d| acc.checked_mul(d));
        if n != Some(e.data.len()) {
            return bad(format!(
                "extra dataset '{p}' has {} values but shape {:?}",
                e.data.len(),
                e.shape
            ));
        }
        if e.integer
            && e.data
                .iter()
                .any(|v| v.fract() != 0.0 || v.abs() > 9.007_199_254_740_992e15)
        {
            return bad(format!("extra dataset '{p}' is integer but holds a value that is not a whole number within ±2^53"));
        }
        if !datasets.insert(p) {
            return bad(format!("extra dataset '{p}' is given twice"));
        }
        for i in 1..parts.len() {
            groups.insert(format!("/{}", parts[..i].join("/")));
        }
        check_keys(path, rest, e.attrs.iter().map(|(k, _)| k.as_str()), &[])?;
        for (k, v) in &e.attrs {
            check_no_nul(path, &format!("attribute '{k}' of {p}"), v)?;
        }
    }
    if let Some(p) = extras.iter().map(|e| &e.path).find(|p| groups.contains(*p)) {
        return bad(format!(
            "extra dataset '{p}' collides with another extra dataset below it"
        ));
    }
    Ok(())
}

fn check_keys<'k>(
    path: &Path,
    group: &str,
    keys: impl Iterator<Item = &'k str>,
    reserved: &[&str],
) -> Result<(), IoError> {
    let mut seen = std::collections::HashSet::new();
    for key in keys {
        let reason = if key.is_empty() {
            format!("/{group} has an empty attribute name")
        } else if reserved.contains(&key) {
            format!("/{group} attribute name '{key}' is reserved")
        } else if !seen.insert(key) {
            format!("/{group} attribute '{key}' is given twice")
        } else {
            continue;
        };
        return Err(IoError::InvalidInput {
            path: path.to_path_buf(),
            reason,
        });
    }
    Ok(())
}

fn write_h5(path: &Path, f: &ModesFile) -> Result<(), IoError> {
    let file = hdf5::File::create(path).map_err(IoError::hdf5(path, "creating HDF5 file"))?;
    // All group/dataset handles live inside this call, so they are closed
    // before `file.close()`; HDF5 keeps a file open while any handle is alive.
    fill_h5(path, &file, f)?;
    file.close()
        .map_err(IoError::hdf5(path, "closing HDF5 file"))
}

fn fill_h5(path: &Path, file: &hdf5::File, f: &ModesFile) -> Result<(), IoError> {
    let n_nodes = f.nodes.len();
    let npt = f.nodes_per_tet;
    let n_tets = f.connectivity.len() / npt;
    let n_modes = f.eigenvalues.len();

    write_str_attr(path, file, "format", FORMAT_NAME)?;
    write_attr(path, file, "format_version", &FORMAT_VERSION)?;

    let mesh = create_group(path, file, "mesh")?;
    let flat_nodes: Vec<f64> = f.nodes.iter().flatten().copied().collect();
    let ds = write_dataset(path, &mesh, "nodes", &[n_nodes, 3], &flat_nodes)?;
    write_units(path, &ds, "m")?;
    let tets: Vec<u64> = f.connectivity.iter().map(|&i| i as u64).collect();
    let tets_ds = write_dataset(path, &mesh, "tets", &[n_tets, npt], &tets)?;
    write_attr(path, &tets_ds, "element_order", &f.element_order)?;
    write_units(path, &tets_ds, "")?;
    let tets_vtk: Vec<u64> = gmsh_to_vtk_connectivity(f.connectivity, npt)
        .into_iter()
        .map(|i| i as u64)
        .collect();
    let ds = write_dataset(path, &mesh, "tets_vtk", &[n_tets, npt], &tets_vtk)?;
    write_units(path, &ds, "")?;

    let mat = create_group(path, file, "material")?;
    let m = &f.material;
    for (key, value) in [
        ("youngs_modulus", m.youngs_modulus),
        ("poisson_ratio", m.poisson_ratio),
        ("density", m.density),
        ("rayleigh_alpha", m.rayleigh_alpha),
        ("rayleigh_beta", m.rayleigh_beta),
    ] {
        write_attr(path, &mat, key, &value)?;
    }
    write_str_attr(path, &mat, "name", &m.name)?;

    let modes = create_group(path, file, "modes")?;
    let ds = write_dataset(path, &modes, "eigenvalues", &[n_modes], f.eigenvalues)?;
    write_units(path, &ds, EIGENVALUE_UNITS)?;
    let ds = write_dataset(path, &modes, "frequencies", &[n_modes], f.frequencies_hz)?;
    write_units(path, &ds, "Hz")?;
    // One contiguous buffer: hdf5-metno writes multi-dimensional slabs only
    // from ndarray views, which this crate does not depend on. The cost is
    // a transient copy of the shapes.
    let shapes: Vec<f64> = f.mode_shapes.iter().flatten().copied().collect();
    let ds = write_dataset(path, &modes, "shapes", &[n_modes, n_nodes, 3], &shapes)?;
    write_units(path, &ds, SHAPE_UNITS)?;
    drop(shapes);
    write_mode_views(path, &modes, n_modes, n_nodes)?;
    let ds = write_dataset(path, &modes, "residual_norms", &[n_modes], f.residual_norms)?;
    write_units(path, &ds, "1")?;
    let ds = write_dataset(
        path,
        &modes,
        "rigid_eigenvalues",
        &[f.rigid_eigenvalues.len()],
        f.rigid_eigenvalues,
    )?;
    write_units(path, &ds, EIGENVALUE_UNITS)?;

    let solver = create_group(path, file, "solver")?;
    for (key, value) in &f.solver {
        write_str_attr(path, &solver, key, value)?;
    }
    write_attr(path, &solver, "n_ranks", &(f.n_ranks as u64))?;

    let timings = create_group(path, file, "timings")?;
    for (key, seconds) in &f.timings {
        write_attr(path, &timings, key, seconds)?;
    }

    let provenance = create_group(path, file, "provenance")?;
    for (key, value) in &f.provenance {
        write_str_attr(path, &provenance, key, value)?;
    }

    if !f.node_fields.is_empty() {
        let fields = create_group(path, file, "node_fields")?;
        for field in &f.node_fields {
            let shape = field.kind.shape(n_nodes);
            let ds = write_dataset(path, &fields, &field.name, &shape, field.data)?;
            write_units(path, &ds, &field.units)?;
        }
    }

    for e in &f.extra_datasets {
        // Validated: absolute, non-empty components, outside the fixed groups.
        let (parent, name) = e.path.rsplit_once('/').unwrap_or(("", &e.path));
        let mut group: hdf5::Group = (**file).clone();
        for part in parent.split('/').filter(|s| !s.is_empty()) {
            group = if group.link_exists(part) {
                group.group(part)
            } else {
                group.create_group(part)
            }
            .map_err(IoError::hdf5(
                path,
                format!(
                    "creating group {}/{part}",
                    group.name().trim_end_matches('/')
                ),
            ))?;
        }
        let ds = if e.integer {
            let whole: Vec<i64> = e.data.iter().map(|&v| v as i64).collect();
            write_dataset(path, &group, name, &e.shape, &whole)?
        } else {
            write_dataset(path, &group, name, &e.shape, &e.data)?
        };
        for (key, value) in &e.attrs {
            write_str_attr(path, &ds, key, value)?;
        }
    }
    Ok(())
}

/// Name of mode `k`'s virtual dataset under `/modes/by_mode` (and the stem of
/// its XDMF attribute name): `mode_` plus `k` zero-padded to
/// [`mode_index_width`] digits.
pub fn mode_name(k: usize, n_modes: usize) -> String {
    format!("mode_{k:0w$}", w = mode_index_width(n_modes))
}

/// Digits in the mode index of [`mode_name`]: enough for the largest index
/// `n_modes - 1`, and at least 3, so names sort in mode order.
pub fn mode_index_width(n_modes: usize) -> usize {
    let digits = n_modes.saturating_sub(1).max(1).ilog10() as usize + 1;
    digits.max(3)
}

/// `/modes/by_mode/mode_KKK` for every mode: HDF5 virtual datasets, each
/// mapping all of its `[n_nodes, 3]` onto the slab `[k, :, :]` of
/// `/modes/shapes` in the same file (source file name `"."`, which HDF5
/// resolves to the file holding the virtual dataset, so renaming or moving
/// the file keeps the mapping valid). No data is duplicated.
fn write_mode_views(
    path: &Path,
    modes: &hdf5::Group,
    n_modes: usize,
    n_nodes: usize,
) -> Result<(), IoError> {
    let by_mode = modes
        .create_group("by_mode")
        .map_err(IoError::hdf5(path, "creating group /modes/by_mode"))?;
    for k in 0..n_modes {
        let name = mode_name(k, n_modes);
        let mut builder = by_mode.new_dataset::<f64>().shape([n_nodes, 3]);
        // A zero-element selection cannot be mapped; an empty mesh gets
        // plain empty datasets instead.
        if n_nodes > 0 {
            builder = builder.virtual_map(
                ".",
                "/modes/shapes",
                [n_modes, n_nodes, 3],
                (k, 0..n_nodes, 0..3),
                [n_nodes, 3],
                hdf5::Selection::All,
            );
        }
        let ds = builder.create(name.as_str()).map_err(IoError::hdf5(
            path,
            format!("creating virtual dataset /modes/by_mode/{name}"),
        ))?;
        write_units(path, &ds, SHAPE_UNITS)?;
    }
    Ok(())
}

/// Opens or creates the group `/parts[0]/parts[1]/…` (the root for no parts).
fn create_nested(path: &Path, file: &hdf5::File, parts: &[&str]) -> Result<hdf5::Group, IoError> {
    let mut group: hdf5::Group = (**file).clone();
    for part in parts {
        group = match group.group(part) {
            Ok(g) => g,
            Err(_) => group.create_group(part).map_err(IoError::hdf5(
                path,
                format!("creating group {part} in {}", group.name()),
            ))?,
        };
    }
    Ok(group)
}

fn create_group(path: &Path, file: &hdf5::File, name: &str) -> Result<hdf5::Group, IoError> {
    file.create_group(name)
        .map_err(IoError::hdf5(path, format!("creating group /{name}")))
}

fn write_dataset<T: hdf5::H5Type>(
    path: &Path,
    group: &hdf5::Group,
    name: &str,
    shape: &[usize],
    data: &[T],
) -> Result<hdf5::Dataset, IoError> {
    let full = format!("{}/{name}", group.name().trim_end_matches('/'));
    let ds = group
        .new_dataset::<T>()
        .shape(shape)
        .create(name)
        .map_err(IoError::hdf5(path, format!("creating dataset {full}")))?;
    // A zero-size dataset (e.g. no rigid modes) has nothing to write, and
    // hdf5-metno rejects writing an empty buffer.
    if !data.is_empty() {
        ds.write_raw(data)
            .map_err(IoError::hdf5(path, format!("writing dataset {full}")))?;
    }
    Ok(ds)
}

fn write_attr<T: hdf5::H5Type>(
    path: &Path,
    loc: &hdf5::Location,
    name: &str,
    value: &T,
) -> Result<(), IoError> {
    let where_ = format!("attribute '{name}' on {}", loc.name());
    loc.new_attr::<T>()
        .create(name)
        .and_then(|a| a.write_scalar(value))
        .map_err(IoError::hdf5(path, format!("writing {where_}")))
}

/// The `units` string attribute of a dataset.
fn write_units(path: &Path, ds: &hdf5::Dataset, units: &str) -> Result<(), IoError> {
    write_str_attr(path, ds, "units", units)
}

fn write_str_attr(
    path: &Path,
    loc: &hdf5::Location,
    name: &str,
    value: &str,
) -> Result<(), IoError> {
    let v: VarLenUnicode = value.parse().map_err(|e| IoError::InvalidInput {
        path: path.to_path_buf(),
        reason: format!(
            "attribute '{name}' on {}: value cannot be stored: {e}",
            loc.name()
        ),
    })?;
    write_attr(path, loc, name, &v)
}

/// The XDMF 3 sidecar text for a results file named `h5_name` (see module docs).
pub fn xdmf_document(h5_name: &str, f: &ModesFile) -> String {
    let n_nodes = f.nodes.len();
    let npt = f.nodes_per_tet;
    let n_tets = f.connectivity.len() / npt;
    let n_modes = f.eigenvalues.len();
    let h5 = xml_escape(h5_name);
    let topology = if npt == 10 {
        "Tetrahedron_10"
    } else {
        "Tetrahedron"
    };

    let mut x = String::new();
    // `write!` into a String cannot fail.
    let _ = write!(
        x,
        r#"<?xml version="1.0" encoding="utf-8"?>
<Xdmf Version="3.0">
  <Domain>
    <Grid Name="mesh" GridType="Uniform">
      <Topology TopologyType="{topology}" NumberOfElements="{n_tets}" NodesPerElement="{npt}">
        <DataItem Dimensions="{n_tets} {npt}" NumberType="Int" Precision="8" Format="HDF">{h5}:/mesh/tets_vtk</DataItem>
      </Topology>
      <Geometry GeometryType="XYZ">
        <DataItem Dimensions="{n_nodes} 3" NumberType="Float" Precision="8" Format="HDF">{h5}:/mesh/nodes</DataItem>
      </Geometry>
"#
    );
    for (k, freq) in f.frequencies_hz.iter().enumerate() {
        let name = mode_name(k, n_modes);
        let _ = write!(
            x,
            r#"      <Attribute Name="{name} ({freq:.1} Hz)" Center="Node" AttributeType="Vector">
        <DataItem Dimensions="{n_nodes} 3" NumberType="Float" Precision="8" Format="HDF">{h5}:/modes/by_mode/{name}</DataItem>
      </Attribute>
"#
        );
    }
    for field in &f.node_fields {
        // Names are [A-Za-z0-9_] (validated): nothing to escape. Units stay in the HDF5 file.
        let name = &field.name;
        let (kind, dims) = match field.kind {
            FieldKind::Scalar => ("Scalar", format!("{n_nodes}")),
            FieldKind::Vector => ("Vector", format!("{n_nodes} 3")),
        };
        let _ = write!(
            x,
            r#"      <Attribute Name="{name}" Center="Node" AttributeType="{kind}">
        <DataItem Dimensions="{dims}" NumberType="Float" Precision="8" Format="HDF">{h5}:/node_fields/{name}</DataItem>
      </Attribute>
"#
        );
    }
    x.push_str("    </Grid>\n  </Domain>\n</Xdmf>\n");
    x
}

fn xml_escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            _ => out.push(c),
        }
    }
    out
}

/// Reads a file written by [`write_modes`] back in full, checking the layout
/// (format tag, dataset shapes, consistent counts) as it goes.
pub fn read_modes(path: &Path) -> Result<ModesSummary, IoError> {
    if !path.exists() {
        return Err(IoError::Fs {
            path: path.to_path_buf(),
            context: "opening modes file".into(),
            source: std::io::Error::from(std::io::ErrorKind::NotFound),
        });
    }
    let file = hdf5::File::open(path).map_err(IoError::hdf5(path, "opening HDF5 file"))?;
    let bad = |reason: String| IoError::BadLayout {
        path: path.to_path_buf(),
        reason,
    };

    let format = read_str_attr(path, &file, "format")?;
    if format != FORMAT_NAME {
        return Err(bad(format!(
            "root attribute format is '{format}', expected '{FORMAT_NAME}'"
        )));
    }
    let version: u64 = read_attr(path, &file, "format_version")?;
    if !(1..=FORMAT_VERSION).contains(&version) {
        return Err(bad(format!(
            "format_version {version} is not supported (this build reads 1 to {FORMAT_VERSION})"
        )));
    }

    let (nodes_flat, nshape) = read_dataset::<f64>(path, &file, "/mesh/nodes")?;
    if nshape.len() != 2 || nshape[1] != 3 {
        return Err(bad(format!(
            "/mesh/nodes has shape {nshape:?}, expected [n_nodes, 3]"
        )));
    }
    let n_nodes = nshape[0];
    let nodes: Vec<[f64; 3]> = nodes_flat
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();

    let (tets, tshape) = read_dataset::<u64>(path, &file, "/mesh/tets")?;
    if tshape.len() != 2 || !(tshape[1] == 4 || tshape[1] == 10) {
        return Err(bad(format!(
            "/mesh/tets has shape {tshape:?}, expected [n_tets, 4 or 10]"
        )));
    }
    let (n_tets, nodes_per_tet) = (tshape[0], tshape[1]);
    let tets_ds = file
        .dataset("/mesh/tets")
        .map_err(IoError::hdf5(path, "opening /mesh/tets"))?;
    let element_order: u32 = read_attr(path, &tets_ds, "element_order")?;
    let connectivity: Vec<usize> = tets.into_iter().map(|i| i as usize).collect();

    let mat = file
        .group("material")
        .map_err(IoError::hdf5(path, "opening /material"))?;
    let material = MaterialRecord {
        name: read_str_attr(path, &mat, "name")?,
        youngs_modulus: read_attr(path, &mat, "youngs_modulus")?,
        poisson_ratio: read_attr(path, &mat, "poisson_ratio")?,
        density: read_attr(path, &mat, "density")?,
        rayleigh_alpha: read_attr(path, &mat, "rayleigh_alpha")?,
        rayleigh_beta: read_attr(path, &mat, "rayleigh_beta")?,
    };

    let (eigenvalues, _) = read_dataset::<f64>(path, &file, "/modes/eigenvalues")?;
    let n_modes = eigenvalues.len();
    let (frequencies_hz, _) = read_dataset::<f64>(path, &file, "/modes/frequencies")?;
    let (residual_norms, _) = read_dataset::<f64>(path, &file, "/modes/residual_norms")?;
    let (rigid_eigenvalues, _) = read_dataset::<f64>(path, &file, "/modes/rigid_eigenvalues")?;
    let (shapes, sshape) = read_dataset::<f64>(path, &file, "/modes/shapes")?;
    if sshape != [n_modes, n_nodes, 3] {
        return Err(bad(format!(
            "/modes/shapes has shape {sshape:?}, expected [{n_modes}, {n_nodes}, 3]"
        )));
    }
    if frequencies_hz.len() != n_modes || residual_norms.len() != n_modes {
        return Err(bad(format!(
            "{n_modes} eigenvalues but {} frequencies and {} residual norms",
            frequencies_hz.len(),
            residual_norms.len()
        )));
    }
    let mode_shapes: Vec<Vec<f64>> = if n_nodes == 0 {
        vec![Vec::new(); n_modes]
    } else {
        shapes
            .chunks_exact(3 * n_nodes)
            .map(<[f64]>::to_vec)
            .collect()
    };

    let solver_g = file
        .group("solver")
        .map_err(IoError::hdf5(path, "opening /solver"))?;
    let n_ranks: u64 = read_attr(path, &solver_g, "n_ranks")?;
    let mut solver = Vec::new();
    for key in attr_names(path, &solver_g)? {
        if key != "n_ranks" {
            let value = read_str_attr(path, &solver_g, &key)?;
            solver.push((key, value));
        }
    }
    let timings_g = file
        .group("timings")
        .map_err(IoError::hdf5(path, "opening /timings"))?;
    let mut timings = Vec::new();
    for key in attr_names(path, &timings_g)? {
        let seconds = read_attr(path, &timings_g, &key)?;
        timings.push((key, seconds));
    }
    let prov_g = file
        .group("provenance")
        .map_err(IoError::hdf5(path, "opening /provenance"))?;
    let mut provenance = Vec::new();
    for key in attr_names(path, &prov_g)? {
        let value = read_str_attr(path, &prov_g, &key)?;
        provenance.push((key, value));
    }

    let mut node_fields = Vec::new();
    if file.link_exists("node_fields") {
        let fields_g = file
            .group("node_fields")
            .map_err(IoError::hdf5(path, "opening /node_fields"))?;
        let names = fields_g
            .member_names()
            .map_err(IoError::hdf5(path, "listing /node_fields"))?;
        for name in names {
            let full = format!("/node_fields/{name}");
            let (data, shape) = read_dataset::<f64>(path, &file, &full)?;
            let kind = if shape == [n_nodes, 3] {
                FieldKind::Vector
            } else if shape == [n_nodes] {
                FieldKind::Scalar
            } else {
                return Err(bad(format!(
                    "{full} has shape {shape:?}, expected [{n_nodes}] or [{n_nodes}, 3]"
                )));
            };
            let ds = file
                .dataset(&full)
                .map_err(IoError::hdf5(path, format!("opening {full}")))?;
            let units = read_str_attr(path, &ds, "units")?;
            node_fields.push(NodeFieldData {
                name,
                kind,
                data,
                units,
            });
        }
    }

    let mut extra_datasets = Vec::new();
    read_extras(path, &file, "", true, &mut extra_datasets)?;
    // Depth-first link order is not plain path order when names hold '-' or '.'.
    extra_datasets.sort_by(|a, b| a.path.cmp(&b.path));

    Ok(ModesSummary {
        n_nodes,
        n_tets,
        n_modes,
        nodes_per_tet,
        element_order,
        nodes,
        connectivity,
        material,
        eigenvalues,
        frequencies_hz,
        mode_shapes,
        residual_norms,
        rigid_eigenvalues,
        n_ranks: n_ranks as usize,
        solver,
        timings,
        provenance,
        extra_datasets,
        node_fields,
    })
}

/// Appends every dataset under `group` (absolute path `prefix`, `""` for the
/// root) to `out`, depth-first in link order, skipping [`RESERVED_GROUPS`]
/// at the root.
fn read_extras(
    path: &Path,
    file: &hdf5::File,
    prefix: &str,
    root: bool,
    out: &mut Vec<ExtraDataset>,
) -> Result<(), IoError> {
    let group_path = if prefix.is_empty() { "/" } else { prefix };
    let group = file
        .group(group_path)
        .map_err(IoError::hdf5(path, format!("opening group {group_path}")))?;
    let names = group
        .member_names()
        .map_err(IoError::hdf5(path, format!("listing {group_path}")))?;
    for name in names {
        if root && RESERVED_GROUPS.contains(&name.as_str()) {
            continue;
        }
        let full = format!("{prefix}/{name}");
        let kind = group
            .loc_type_by_name(&name)
            .map_err(IoError::hdf5(path, format!("inspecting {full}")))?;
        match kind {
            hdf5::LocationType::Group => read_extras(path, file, &full, false, out)?,
            hdf5::LocationType::Dataset => {
                let (data, shape) = read_dataset::<f64>(path, file, &full)?;
                let ds = file
                    .dataset(&full)
                    .map_err(IoError::hdf5(path, format!("opening {full}")))?;
                let mut attrs = Vec::new();
                for key in attr_names(path, &ds)? {
                    let value = read_str_attr(path, &ds, &key)?;
                    attrs.push((key, value));
                }
                let integer = ds.dtype().is_ok_and(|t| {
                    matches!(
                        t.to_descriptor(),
                        Ok(hdf5::types::TypeDescriptor::Integer(_)
                            | hdf5::types::TypeDescriptor::Unsigned(_))
                    )
                });
                out.push(ExtraDataset {
                    path: full,
                    shape,
                    data,
                    attrs,
                    integer,
                });
            }
            // Committed datatypes and the like are not ours; ignore them.
            _ => {}
        }
    }
    Ok(())
}

fn read_dataset<T: hdf5::H5Type>(
    path: &Path,
    file: &hdf5::File,
    name: &str,
) -> Result<(Vec<T>, Vec<usize>), IoError> {
    let ds = file
        .dataset(name)
        .map_err(IoError::hdf5(path, format!("opening dataset {name}")))?;
    let shape = ds.shape();
    let data = if shape.iter().product::<usize>() == 0 {
        Vec::new()
    } else {
        ds.read_raw::<T>()
            .map_err(IoError::hdf5(path, format!("reading dataset {name}")))?
    };
    Ok((data, shape))
}

fn read_attr<T: hdf5::H5Type>(path: &Path, loc: &hdf5::Location, name: &str) -> Result<T, IoError> {
    loc.attr(name)
        .and_then(|a| a.read_scalar::<T>())
        .map_err(IoError::hdf5(
            path,
            format!("reading attribute '{name}' on {}", loc.name()),
        ))
}

fn read_str_attr(path: &Path, loc: &hdf5::Location, name: &str) -> Result<String, IoError> {
    read_attr::<VarLenUnicode>(path, loc, name).map(|s| s.as_str().to_owned())
}

fn attr_names(path: &Path, loc: &hdf5::Location) -> Result<Vec<String>, IoError> {
    loc.attr_names().map_err(IoError::hdf5(
        path,
        format!("listing attributes of {}", loc.name()),
    ))
}

#[cfg(test)]
mod tests;
