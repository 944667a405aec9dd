//! What every command resolves the same way from its flags and configuration file: the mesh
//! with its unit and element order, and output paths checked before the work.

use crate::mesh;
use std::path::{Path, PathBuf};

/// The mesh, its unit and the element order, from a flag or else the config file.
pub struct MeshChoice {
    pub mesh: PathBuf,
    pub units: String,
    pub unit_scale: f64,
    pub order: u32,
}

pub fn resolve_mesh(
    flag_mesh: &Option<PathBuf>,
    file_mesh: &Option<PathBuf>,
    flag_units: &Option<String>,
    file_units: &Option<String>,
    order: Option<u32>,
) -> Result<MeshChoice, String> {
    let mesh = flag_mesh
        .clone()
        .or(file_mesh.clone())
        .ok_or("no mesh given: use --mesh FILE or `mesh = \"…\"` in the config file")?;
    let units = flag_units
        .clone()
        .or(file_units.clone())
        .unwrap_or_else(|| "m".into());
    let unit_scale = mesh::parse_unit(&units).map_err(|e| e.to_string())?;
    let order = order.unwrap_or(2);
    if order != 1 && order != 2 {
        return Err(format!("--order must be 1 or 2, got {order}"));
    }
    Ok(MeshChoice {
        mesh,
        units,
        unit_scale,
        order,
    })
}

/// An output path checked before the work ([`crate::io::preflight`]): its folder exists and
/// takes a new file, and it is none of `inputs` (named for the message).
pub fn check_output(path: &Path, inputs: &[(&str, &Path)]) -> Result<(), String> {
    crate::io::preflight::check_output(path, inputs).map_err(|e| e.to_string())
}

/// The job's input files as [`check_output`] takes them.
pub fn inputs<'a>(mesh: &'a Path, recordings: &'a [PathBuf]) -> Vec<(&'static str, &'a Path)> {
    std::iter::once(("the mesh", mesh))
        .chain(recordings.iter().map(|r| ("a recording", r.as_path())))
        .collect()
}
