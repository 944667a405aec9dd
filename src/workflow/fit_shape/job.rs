//! The resolved job of a shape fit, and the checks every way of building one shares.

use crate::fem::Material;
use crate::inverse::shape::{answers_with_line, replica_line_levels, ShapeFitSettings};
use std::path::{Path, PathBuf};

/// Whether replicas go on every level after the first (the answer is the line through the
/// levels) or on the finest alone (the answer is the finest spacing's mean: the curved
/// thickness body unless told `--extrapolate`).
pub fn replicate_every_level(task: &Task, settings: &ShapeFitSettings) -> bool {
    answers_with_line(
        settings.extrapolate,
        matches!(task, Task::Thickness { curved: true, .. }),
    )
}

/// Which parameter is fitted, and of what.
#[derive(Clone, Debug)]
pub enum Task {
    /// `curved`: exact crossings and a curved boundary on the continuous signed distance.
    Thickness {
        surface: PathBuf,
        curved: bool,
    },
    Morph {
        a: PathBuf,
        b: PathBuf,
    },
}

/// Where the target spectrum comes from.
#[derive(Clone, Debug)]
pub enum TargetSource {
    /// λ* [rad²/s²] from a file, and the spacing the extrapolation aims at.
    Given {
        path: PathBuf,
        eigenvalues: Vec<f64>,
        spacing: f64,
    },
    /// The true parameter on a shifted grid of `cells`.
    Synthetic {
        value: f64,
        cells: usize,
        seed: u64,
        spacing: Option<f64>,
    },
}

/// Everything resolved and checked before PETSc starts.
#[derive(Clone, Debug)]
pub struct Job {
    pub task: Task,
    pub unit_scale: f64,
    pub diagonal: Option<f64>,
    pub cells: Vec<usize>,
    /// Grids per replicated level ([`crate::inverse::shape::replica_levels`], [`crate::inverse::shape::replica_shift`]).
    pub replicas: usize,
    pub target: TargetSource,
    pub material: Material,
    pub settings: ShapeFitSettings,
    pub out: PathBuf,
    pub mesh_out: PathBuf,
    pub petsc_options: Vec<String>,
    pub verbose: bool,
}

impl Task {
    pub fn name(&self) -> &'static str {
        match self {
            Task::Thickness { .. } => "thickness",
            Task::Morph { .. } => "morph",
        }
    }

    /// The fitted parameter's name, as [`ShapeFamily::parameter_name`] says it.
    pub fn parameter_name(&self) -> &'static str {
        match self {
            Task::Thickness { .. } => "thickness",
            Task::Morph { .. } => "morph weight c",
        }
    }
}

/// Reads frequencies or eigenvalues: numbers separated by whitespace or commas, `#` comments.
pub fn parse_target(text: &str, path: &Path, hertz: bool) -> Result<Vec<f64>, String> {
    let mut values = Vec::new();
    for (line_no, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("");
        for token in line
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|t| !t.is_empty())
        {
            let v: f64 = token.parse().map_err(|_| {
                format!(
                    "{}: line {}: {token:?} is not a number",
                    path.display(),
                    line_no + 1
                )
            })?;
            if !(v.is_finite() && v > 0.0) {
                return Err(format!(
                    "{}: line {}: target values must be positive, got {v}",
                    path.display(),
                    line_no + 1
                ));
            }
            values.push(if hertz {
                (2.0 * std::f64::consts::PI * v).powi(2)
            } else {
                v
            });
        }
    }
    if values.is_empty() {
        return Err(format!("{}: no target values in the file", path.display()));
    }
    values.sort_by(f64::total_cmp);
    Ok(values)
}

/// The grid levels `cells` (coarse to fine, cells along the longest axis) and the grids per
/// replicated level.
pub fn check_levels(cells: &[usize], replicas: usize) -> Result<(), String> {
    if cells.is_empty() || cells.iter().any(|&c| !(4..=200).contains(&c)) {
        return Err(format!(
            "--cells must be one or more grid sizes in 4..=200, got {cells:?}"
        ));
    }
    if cells.windows(2).any(|w| w[0] >= w[1]) {
        return Err(format!(
            "--cells must increase from coarse to fine, got {cells:?}"
        ));
    }
    if !(1..=4).contains(&replicas) {
        return Err(format!("--replicas must lie in 1..=4, got {replicas}"));
    }
    Ok(())
}

/// Checks the merged settings against the task and sets the line's levels for `replicas`.
pub fn finish_settings(
    task: &Task,
    settings: &mut ShapeFitSettings,
    replicas: usize,
) -> Result<(), String> {
    if settings.wall_refinement > 0 && !matches!(task, Task::Thickness { curved: true, .. }) {
        return Err("wall refinement needs the curved thickness body (not fit-morph, not --straight-boundary)".into());
    }
    settings.validate().map_err(|e| e.to_string())?;
    // The line goes through the same number of spacings, each with all its replicas.
    settings.extrapolation_levels = replica_line_levels(
        settings.extrapolation_levels,
        replicas,
        replicate_every_level(task, settings),
    );
    let (lo, hi) = settings.bounds;
    match task {
        Task::Thickness { .. } if !(lo > 0.0 && hi <= 1.0) => {
            Err(format!("thickness bounds ({lo}, {hi}) must lie in (0, 1]"))
        }
        Task::Morph { .. } if !(lo >= 0.0 && hi <= 1.0) => Err(format!(
            "morph weight bounds ({lo}, {hi}) must lie in [0, 1]"
        )),
        _ => Ok(()),
    }
}

/// The lowest `modes` values of a target file ([`parse_target`]), as λ* [rad²/s²].
fn read_target(
    path: PathBuf,
    hertz: bool,
    modes: usize,
    spacing: f64,
) -> Result<TargetSource, String> {
    let text = std::fs::read_to_string(&path)
        .map_err(|e| format!("target file {}: {e}", path.display()))?;
    let eigenvalues = parse_target(&text, &path, hertz)?;
    if eigenvalues.len() < modes {
        return Err(format!(
            "{}: {} target values for {modes} compared modes (lower --modes or give more)",
            path.display(),
            eigenvalues.len()
        ));
    }
    Ok(TargetSource::Given {
        path,
        eigenvalues: eigenvalues[..modes].to_vec(),
        spacing,
    })
}

/// A synthesised target's true value lies within the bounds and its grid is finer than the
/// finest fit level.
fn check_synthetic(
    task: &Task,
    value: f64,
    (lo, hi): (f64, f64),
    target_cells: usize,
    finest: usize,
) -> Result<(), String> {
    if !(value >= lo && value <= hi) {
        return Err(format!(
            "the true {} {value} lies outside the bounds [{lo}, {hi}]",
            task.name()
        ));
    }
    if target_cells <= finest || target_cells > 200 {
        return Err(format!("--target-cells must exceed the finest fit level ({finest}) and be at most 200, got {target_cells}"));
    }
    Ok(())
}

/// The target as the flags and the file give it, before it is read and checked.
#[derive(Clone, Debug)]
pub struct TargetChoice {
    /// A file of frequencies or eigenvalues ([`parse_target`]).
    pub file: Option<PathBuf>,
    /// The file's units: `hz` or `rad2`.
    pub units: String,
    /// The true parameter of a synthesised target.
    pub synthetic: Option<f64>,
    /// A synthesised target's grid cells and shift seed.
    pub cells: usize,
    pub seed: u64,
    /// The spacing [m] the extrapolation aims at (default: 0 for a file, the target grid's for
    /// a synthesised target).
    pub spacing: Option<f64>,
}

impl TargetChoice {
    /// Reads a target file, or checks a synthesised target against the bounds and the finest
    /// fit level (`finest` cells).
    pub fn resolve(
        self,
        task: &Task,
        settings: &ShapeFitSettings,
        finest: usize,
    ) -> Result<TargetSource, String> {
        let spacing = self.spacing;
        if let Some(h) = spacing {
            if !(h.is_finite() && h >= 0.0) {
                return Err(format!("--target-spacing must be ≥ 0 metres, got {h}"));
            }
        }
        let (lo, hi) = settings.bounds;
        match (self.file, self.synthetic) {
            (Some(_), Some(_)) => Err("give either a target file or a true value to synthesise a target from, not both".into()),
            (None, None) => Err(format!("no target: use --target FILE (frequencies in Hz) or --target-{} VALUE with --target-cells N", if matches!(task, Task::Thickness { .. }) { "thickness" } else { "weight" })),
            (Some(path), None) => {
                let hertz = match self.units.to_ascii_lowercase().as_str() {
                    "hz" => true,
                    "rad2" => false,
                    other => return Err(format!("--target-units must be hz or rad2, got {other:?}")),
                };
                read_target(path, hertz, settings.modes, spacing.unwrap_or(0.0))
            }
            (None, Some(value)) => {
                check_synthetic(task, value, (lo, hi), self.cells, finest)?;
                Ok(TargetSource::Synthetic { value, cells: self.cells, seed: self.seed, spacing })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn target_files_parse_hertz_and_eigenvalues_with_comments() {
        let p = Path::new("t.txt");
        let v = parse_target("# modes\n200, 100\n300 # last\n", p, true).unwrap();
        let w = |f: f64| (2.0 * std::f64::consts::PI * f).powi(2);
        assert_eq!(v, vec![w(100.0), w(200.0), w(300.0)]);
        assert_eq!(parse_target("4e6 1e6", p, false).unwrap(), vec![1e6, 4e6]);
        for (bad, what) in [
            ("1 x 2", "not a number"),
            ("-5", "positive"),
            ("# nothing", "no target values"),
        ] {
            let e = parse_target(bad, p, true).unwrap_err();
            assert!(e.contains(what) && e.contains("t.txt"), "{bad}: {e}");
        }
    }
}
