//! The run configuration: defaults < TOML file (`--config`) < command-line flags.
//!
//! Every path a configuration file names (mesh, recordings, a fit-material result, outputs) is
//! read relative to the file's own folder, as includes are in most tools: a config next to its
//! data works from any current directory (`--config /path/to/examples/bowl/fit.toml`), and a
//! folder of configs and data can be moved whole. Paths given as flags stay relative to the
//! current directory, like any command-line path. Absolute paths are taken as they are.
//! [`ConfigPaths`] is how each command's file type says which of its fields are paths, and
//! [`load_toml`] reads a file and resolves them.
//!
//! A configuration file mirrors the flags of `diffsound modes` (every key optional):
//!
//! ```toml
//! mesh = "bowl.msh"                # Gmsh .msh 2.2 or 4.1, ASCII or binary (relative to this file)
//! units = "m"                       # mesh length unit: m, cm, mm, um, in, ft or metres per unit
//! order = 2                         # 1 (P1 baseline) or 2 (P2, default)
//! fix_inverted = false              # flip inverted tets instead of rejecting the mesh
//!
//! [material]                        # a preset, then any field overridden
//! preset = "ceramic"
//! youngs_modulus = 72e9             # Pa
//! poisson_ratio = 0.19
//! density = 2700.0                  # kg/m³
//! rayleigh_alpha = 6.0              # 1/s
//! rayleigh_beta = 1e-7              # s
//!
//! [solver]
//! modes = 20                        # first N elastic modes …
//! # fmax = 20000.0                  # … or every mode up to this frequency (Hz)
//! tolerance = 1e-10
//! verify_count = true               # prove the mode count by an inertia check
//! cluster_rtol = 1e-2               # relative eigenvalue gap below which modes form a cluster
//! petsc_options = ["-eps_ncv", "64"] # applied before the options after `--`
//!
//! [output]
//! h5 = "../../out/bowl_modes.h5"    # an .xdmf sidecar is written next to it
//! wav = "../../out/bowl_strike.wav"
//! strike_vertex = 1234              # 0-based node id on the surface; default: farthest from the centre
//! duration = 2.0                    # s
//! sample_rate = 48000               # Hz
//! timings_json = "../../out/timings.json"
//! sensitivities = true              # dλ/dE, dλ/dν, dλ/dρ per mode (and df/d·) in /sensitivities
//! node_gradients = false            # dλ/dx per node and mode, as ParaView fields (implies the above)
//! ```

use crate::fem::Material;
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// A configuration file type whose path fields are resolved against the file's folder.
pub trait ConfigPaths {
    /// Replaces every relative path in `self` by `base` joined with it.
    fn rebase(&mut self, base: &Path);
}

/// `path` joined to `base` when it is relative (absolute paths are kept). A `..` after a
/// folder name of `base` cancels it (`examples/bowl` + `../../out/a.h5` is `out/a.h5`), so
/// messages name the file as a person would; `..` that cannot cancel is kept.
pub fn rebased(base: &Path, path: &Path) -> PathBuf {
    if path.is_absolute() {
        return path.to_path_buf();
    }
    use std::path::Component;
    let mut out: Vec<Component> = Vec::new();
    for c in base.components().chain(path.components()) {
        match c {
            Component::CurDir => {}
            Component::ParentDir if matches!(out.last(), Some(Component::Normal(_))) => {
                out.pop();
            }
            c => out.push(c),
        }
    }
    if out.is_empty() {
        return PathBuf::from(".");
    }
    out.iter().collect()
}

/// [`rebased`] on an optional path, in place.
pub fn rebase_opt(base: &Path, path: &mut Option<PathBuf>) {
    if let Some(p) = path {
        *p = rebased(base, p);
    }
}

/// [`rebased`] on every path of a list, in place.
pub fn rebase_all(base: &Path, paths: &mut [PathBuf]) {
    for p in paths {
        *p = rebased(base, p);
    }
}

/// The folder the relative paths of config file `config` are read from: its parent ("" for a
/// file in the current directory, so its paths stay as written).
pub fn config_dir(config: &Path) -> &Path {
    config.parent().unwrap_or(Path::new(""))
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FileConfig {
    pub mesh: Option<PathBuf>,
    pub units: Option<String>,
    pub order: Option<u32>,
    pub fix_inverted: Option<bool>,
    #[serde(default)]
    pub material: MaterialConfig,
    #[serde(default)]
    pub solver: SolverConfig,
    #[serde(default)]
    pub output: OutputConfig,
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialConfig {
    pub preset: Option<String>,
    pub youngs_modulus: Option<f64>,
    pub poisson_ratio: Option<f64>,
    pub density: Option<f64>,
    pub rayleigh_alpha: Option<f64>,
    pub rayleigh_beta: Option<f64>,
}

impl MaterialConfig {
    /// The preset (the command line's `flags`, else the file's, else ceramic) with every value
    /// the flags or the file set (a flag overrides the file), validated. Returns the material and
    /// its name (the preset's, with " (modified)" when any value was overridden).
    pub fn resolve(&self, flags: &MaterialConfig) -> Result<(Material, String), String> {
        let name = flags
            .preset
            .clone()
            .or_else(|| self.preset.clone())
            .unwrap_or_else(|| "ceramic".into());
        let mut material = Material::preset(&name).ok_or_else(|| {
            format!(
                "unknown material preset '{name}'; known: {}",
                Material::preset_names().join(", ")
            )
        })?;
        let mut modified = false;
        let mut set = |field: &mut f64, flag: Option<f64>, file: Option<f64>| {
            if let Some(v) = flag.or(file) {
                *field = v;
                modified = true;
            }
        };
        set(
            &mut material.youngs_modulus,
            flags.youngs_modulus,
            self.youngs_modulus,
        );
        set(
            &mut material.poisson_ratio,
            flags.poisson_ratio,
            self.poisson_ratio,
        );
        set(&mut material.density, flags.density, self.density);
        set(
            &mut material.rayleigh_alpha,
            flags.rayleigh_alpha,
            self.rayleigh_alpha,
        );
        set(
            &mut material.rayleigh_beta,
            flags.rayleigh_beta,
            self.rayleigh_beta,
        );
        material.validate().map_err(|e| format!("material: {e}"))?;
        Ok((
            material,
            if modified {
                format!("{name} (modified)")
            } else {
                name
            },
        ))
    }
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SolverConfig {
    pub modes: Option<usize>,
    pub fmax: Option<f64>,
    pub tolerance: Option<f64>,
    pub verify_count: Option<bool>,
    pub cluster_rtol: Option<f64>,
    pub shift: Option<f64>,
    #[serde(default)]
    pub petsc_options: Vec<String>,
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputConfig {
    pub h5: Option<PathBuf>,
    pub wav: Option<PathBuf>,
    pub strike_vertex: Option<usize>,
    pub duration: Option<f64>,
    pub sample_rate: Option<u32>,
    pub timings_json: Option<PathBuf>,
    pub sensitivities: Option<bool>,
    pub node_gradients: Option<bool>,
}

/// A command's TOML file (`--config`): read and parsed, its relative paths resolved against the
/// file's folder (module docs), or the defaults without one. Errors name the file.
pub fn load_toml<T: serde::de::DeserializeOwned + Default + ConfigPaths>(
    path: &Option<PathBuf>,
) -> Result<T, String> {
    match path {
        Some(p) => {
            let text = std::fs::read_to_string(p).map_err(|e| format!("{}: {e}", p.display()))?;
            let mut value: T =
                toml::from_str(&text).map_err(|e| format!("{}: {e}", p.display()))?;
            value.rebase(config_dir(p));
            Ok(value)
        }
        None => Ok(T::default()),
    }
}

/// The `[material]` table of the shape fits' TOML files: a preset and E, ν, ρ (no damping).
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ElasticConfig {
    pub preset: Option<String>,
    pub youngs_modulus: Option<f64>,
    pub poisson_ratio: Option<f64>,
    pub density: Option<f64>,
}

/// The shape fits' material flags.
#[derive(clap::Args, Debug, Clone, Default)]
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

impl ElasticConfig {
    /// The preset with the flags' and then the file's E, ν, ρ, validated: the shared
    /// resolution of [`MaterialConfig::resolve`] (shape fits take no damping).
    pub fn resolve(&self, args: &ElasticArgs) -> Result<Material, String> {
        let flags = MaterialConfig {
            preset: args.material.clone(),
            youngs_modulus: args.youngs,
            poisson_ratio: args.poisson,
            density: args.density,
            ..Default::default()
        };
        let shared = MaterialConfig {
            preset: self.preset.clone(),
            youngs_modulus: self.youngs_modulus,
            poisson_ratio: self.poisson_ratio,
            density: self.density,
            ..Default::default()
        };
        shared.resolve(&flags).map(|(material, _)| material)
    }
}

/// The `[solver]` table of the fits' and the diagnosis's TOML files: PETSc options only.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PetscConfig {
    #[serde(default)]
    pub petsc_options: Vec<String>,
}

impl ConfigPaths for FileConfig {
    fn rebase(&mut self, base: &Path) {
        rebase_opt(base, &mut self.mesh);
        rebase_opt(base, &mut self.output.h5);
        rebase_opt(base, &mut self.output.wav);
        rebase_opt(base, &mut self.output.timings_json);
    }
}

impl FileConfig {
    /// Reads `path`; its relative paths are resolved against its folder (module docs).
    pub fn load(path: &Path) -> Result<FileConfig, String> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| format!("cannot read config file {}: {e}", path.display()))?;
        let mut file: FileConfig =
            toml::from_str(&text).map_err(|e| format!("config file {}: {e}", path.display()))?;
        file.rebase(config_dir(path));
        Ok(file)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_paths_are_relative_to_the_file() {
        let dir = std::env::temp_dir().join(format!("diffsound-config-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("run.toml");
        std::fs::write(
            &path,
            "mesh = \"bowl.msh\"\n[output]\nh5 = \"../out/b.h5\"\nwav = \"/abs/s.wav\"\n",
        )
        .unwrap();
        let file = FileConfig::load(&path).unwrap();
        assert_eq!(file.mesh, Some(dir.join("bowl.msh")));
        assert_eq!(file.output.h5, Some(dir.parent().unwrap().join("out/b.h5")));
        assert_eq!(file.output.wav, Some(PathBuf::from("/abs/s.wav")));
        assert_eq!(file.output.timings_json, None);
        std::fs::remove_dir_all(&dir).unwrap();
        // A file named without a folder keeps its paths as written.
        assert_eq!(config_dir(Path::new("run.toml")), Path::new(""));
        assert_eq!(
            rebased(Path::new(""), Path::new("a.msh")),
            PathBuf::from("a.msh")
        );
        assert_eq!(
            rebased(Path::new("examples/bowl"), Path::new("../../out/a.h5")),
            PathBuf::from("out/a.h5")
        );
        assert_eq!(
            rebased(Path::new("./cfg"), Path::new("../../x.h5")),
            PathBuf::from("../x.h5")
        );
    }
}
