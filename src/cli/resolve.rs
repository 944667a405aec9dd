//! What every command resolves the same way from its flags and configuration file: the mesh
//! with its unit and element order ([`MeshArgs`]), the unit and size of surfaces
//! ([`SurfaceArgs`]), the shape fits' material ([`ElasticArgs`]), input files that must exist,
//! and output paths checked before the work.

use crate::fem::Material;
use crate::io::config::ElasticConfig;
use crate::mesh;
use clap::Args;
use std::path::{Path, PathBuf};

/// `--mesh` and `--units`, flattened into the commands that read a tet mesh.
#[derive(Args, Debug, Clone, Default)]
pub struct MeshArgs {
    /// Tet mesh of the object: Gmsh .msh 2.2 or 4.1, ASCII or binary, 4- or 10-node tets.
    #[arg(long)]
    pub mesh: Option<PathBuf>,
    /// Length unit of the mesh: m, cm, mm, um, in, ft, or metres per unit (e.g. 0.1; default m).
    #[arg(long)]
    pub units: Option<String>,
    /// Straighten the mid-edge nodes of curved 10-node tets whose map folds over (Jacobian
    /// determinant ≤ 0 inside) instead of rejecting the mesh; the count is reported.
    #[arg(long)]
    pub straighten_invalid: bool,
}

impl MeshArgs {
    /// [`resolve_mesh`] with these flags over the file's `mesh` and `units`.
    pub fn resolve(
        &self,
        file_mesh: &Option<PathBuf>,
        file_units: &Option<String>,
        order: Option<u32>,
    ) -> Result<MeshChoice, String> {
        resolve_mesh(&self.mesh, file_mesh, &self.units, file_units, order)
    }

    /// [`MeshArgs::resolve`], and the mesh file must exist.
    pub fn resolve_existing(
        &self,
        file_mesh: &Option<PathBuf>,
        file_units: &Option<String>,
        order: Option<u32>,
    ) -> Result<MeshChoice, String> {
        let choice = self.resolve(file_mesh, file_units, order)?;
        require_file(&choice.mesh, "mesh")?;
        Ok(choice)
    }
}

/// `--verbose` and the PETSc options after `--`, flattened into every command that runs PETSc.
#[derive(Args, Debug, Clone, Default)]
pub struct RunArgs {
    /// Print progress even when stderr is not a terminal.
    #[arg(long, short)]
    pub verbose: bool,
    /// PETSc/SLEPc options, after `--` (e.g. -- -eps_ncv 64 -st_type sinvert).
    #[arg(last = true, allow_hyphen_values = true)]
    pub petsc_options: Vec<String>,
}

/// A recorded strike's inputs, flattened into `diagnose` and `locate-impact`: a benchmark case,
/// the recordings, and the material as a fit-material result or E and ν.
#[derive(Args, Debug, Clone, Default)]
pub struct StrikeArgs {
    /// A benchmark case's metadata.toml (examples/diagnose_generate.rs): mesh, recordings,
    /// microphone positions, strike (and support) from there.
    #[arg(long)]
    pub case: Option<PathBuf>,
    /// A WAV file of the strike (repeat for several microphones).
    #[arg(long = "recording")]
    pub recordings: Vec<PathBuf>,
    /// A fit-material HDF5 result to take E, ν, ρ (and the damping curve) from.
    #[arg(long)]
    pub material: Option<PathBuf>,
    /// Young's modulus in Pa (instead of --material).
    #[arg(long)]
    pub youngs: Option<f64>,
    /// Poisson's ratio (instead of --material).
    #[arg(long)]
    pub poisson: Option<f64>,
    /// Density in kg/m³ (with --youngs/--poisson; default 2700).
    #[arg(long)]
    pub density: Option<f64>,
}

/// The flag's path, else the config file's, else `default`.
pub fn path_or(flag: &Option<PathBuf>, file: &Option<PathBuf>, default: &str) -> PathBuf {
    flag.clone()
        .or(file.clone())
        .unwrap_or_else(|| PathBuf::from(default))
}

/// `--units` and `--diagonal`, flattened into the commands that read surfaces.
#[derive(Args, Debug, Clone, Default)]
pub struct SurfaceArgs {
    /// Length unit of the surface file(s): m, cm, mm, um, in, ft, or metres per unit (default m).
    #[arg(long)]
    pub units: Option<String>,
    /// Scale the surface(s) to this bounding-box diagonal in metres (default: keep the size).
    #[arg(long)]
    pub diagonal: Option<f64>,
}

impl SurfaceArgs {
    /// The unit's scale in metres (the flag's unit, else the file's, else m), and the diagonal
    /// (flag, else the file's), which must be a positive length.
    pub fn resolve(
        &self,
        file_units: &Option<String>,
        file_diagonal: Option<f64>,
    ) -> Result<(f64, Option<f64>), String> {
        let units = self
            .units
            .clone()
            .or(file_units.clone())
            .unwrap_or_else(|| "m".into());
        let unit_scale = mesh::parse_unit(&units).map_err(|e| e.to_string())?;
        let diagonal = self.diagonal.or(file_diagonal);
        if let Some(d) = diagonal {
            if !(d.is_finite() && d > 0.0) {
                return Err(format!(
                    "--diagonal must be a positive length in metres, got {d}"
                ));
            }
        }
        Ok((unit_scale, diagonal))
    }
}

/// The shape fits' material flags.
#[derive(Args, Debug, Clone, Default)]
pub struct ElasticArgs {
    /// Material preset (default ceramic); --youngs Pa, --poisson, --density kg/m³ override it.
    #[arg(long)]
    pub material: Option<String>,
    #[arg(long)]
    pub youngs: Option<f64>,
    #[arg(long)]
    pub poisson: Option<f64>,
    #[arg(long)]
    pub density: Option<f64>,
}

impl ElasticArgs {
    /// The material of these flags over the file's `[material]` table, validated
    /// ([`ElasticConfig::resolve`]).
    pub fn resolve(&self, file: &ElasticConfig) -> Result<Material, String> {
        let flags = ElasticConfig {
            preset: self.material.clone(),
            youngs_modulus: self.youngs,
            poisson_ratio: self.poisson,
            density: self.density,
        };
        file.resolve(&flags).map_err(|e| e.to_string())
    }
}

/// A flag overrides the value it sets: `field` becomes `flag` when the flag was given.
pub fn set<T>(field: &mut T, flag: Option<T>) {
    if let Some(v) = flag {
        *field = v;
    }
}

/// An input file that must exist: "{what} PATH does not exist" otherwise.
pub fn require_file(path: &Path, what: &str) -> Result<(), String> {
    if path.is_file() {
        Ok(())
    } else {
        Err(format!("{what} {} does not exist", path.display()))
    }
}

/// Every one of `paths` must exist ([`require_file`]).
pub fn require_files(paths: &[PathBuf], what: &str) -> Result<(), String> {
    paths.iter().try_for_each(|p| require_file(p, what))
}

/// A required input file from a flag or the config file: "no {what} given: use {flag} FILE"
/// without one, and it must exist.
pub fn existing(path: Option<PathBuf>, what: &str, flag: &str) -> Result<PathBuf, String> {
    let p = path.ok_or_else(|| format!("no {what} given: use {flag} FILE"))?;
    require_file(&p, what)?;
    Ok(p)
}

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
