//! The fit-material result file (`diffsound fit-material --out F.h5`): both sides of the
//! format. [`write_result`] writes a [`FitMaterialResult`]; [`read_material`] reads back what
//! other jobs need from it. `format = "diffsound.fit_material"` at the root; `/material`
//! carries the fitted Young's modulus E (Pa), Poisson's ratio ν (1) and the density ρ (kg/m³)
//! as attributes.
//!
//! # Layout
//!
//! | path | contents |
//! |------|----------|
//! Types follow [`super::results`]: values f64, indices and counts u64 (datasets) or i64
//! (attributes), flags u8 (0/1), lists 1-D arrays.
//!
//! | path | contents |
//! |------|----------|
//! | `/` attrs | `format` = `diffsound.fit_material`, `format_version` = 2, `mesh` (string), `recordings` (string array), `order` (i64), `n_ranks` (i64), `command`, `version` |
//! | `/material` attrs | `youngs_modulus` [Pa], `poisson_ratio`, `density` [kg/m³], `youngs_over_density` [m²/s²], `start_youngs_modulus`, `start_poisson_ratio`, `poisson_learned` (u8 flag) |
//! | `/fit/history/{step,phase,loss,youngs_modulus,poisson_ratio}` | per step; `step` u64, `phase` u8: 0 = transport, 1 = spectral |
//! | `/fit/log_gains` `[C]`, `/fit/log_amplitude_offsets` `[K, C]` | learned levels (natural log) |
//! | `/fit/start_probes/{youngs_modulus,poisson_ratio,loss}` | the starts tried before the fit (E [Pa], ν, the mean spectral loss of their last five steps); present only when starts were tried |
//! | `/fit` attrs | `steps` (i64), `switched_at` (i64, −1: never), `seconds`, `basis_samples` (f64 array: ν of the basis solves), `max_ritz_residual`, `line_start_youngs_modulus`, `line_start_poisson_ratio`, `line_start_distance` |
//! | `/damping/curve/{frequencies_hz,decay_rates}` | knots of d(f) [Hz, 1/s] |
//! | `/damping/modes/{frequency_hz,decay_rate,level_db,kept}` `[M]`, `…/amplitudes`, `…/phases` `[M, C]` | every stage-1 mode; `kept` u8 flag |
//! | `/damping/peaks/{frequency_hz,decay_rate,level_db,kept}` | the peaks the curve is fitted to; `kept` u8 flag |
//! | `/damping` attrs | `rayleigh_alpha` [1/s], `rayleigh_beta` [s], `curve_rms_log_error`, `rayleigh_rms_log_error`, `loss_initial`, `loss_final` |
//! | `/modes/simulated/{frequency_hz,eigenvalues,full_eigenvalues,relative_difference}` `[K]` | fitted modes, reduced vs full solve |
//! | `/modes/matched/{recorded_frequency_hz,simulated_frequency_hz,error_hz,relative_error,recorded_decay_rate,simulated_decay_rate,simulated_index}` | one row per recorded mode in the band that found a partner; `simulated_index` u64 |
//! | `/errors` attrs | `spectrogram_start`, `spectrogram_fit`, `max_relative_eigenvalue_difference`, `mean_abs_relative_frequency_error`, `line_start_mean_abs_relative_frequency_error` |
//! | `/timings` attrs | seconds per stage |
//!
//! The `line_start_*` attributes are present only when the fit began from a line-spectrum
//! start.
//!
//! Version 1 stored every index, count and flag as f64, `recordings` as one string joined by
//! ", " and `basis_samples` as Rust's debug text of a list; [`read_material`] reads both
//! versions (the attributes it reads did not change).

use super::results::{read_attribute, read_dataset, AttrValue, ResultsFile};
use super::IoError;
use std::path::Path;

/// The `format` attribute at the root of a fit-material result.
pub const FORMAT: &str = "diffsound.fit_material";
/// The `format_version` written by [`write_result`] (module docs for what changed).
pub const FORMAT_VERSION: u64 = 2;

/// Everything a fit-material result file holds (module docs for the layout).
#[derive(Clone, Debug)]
pub struct FitMaterialResult {
    /// The mesh path as given.
    pub mesh: String,
    /// The recording paths as given (a string array).
    pub recordings: Vec<String>,
    pub order: u32,
    pub n_ranks: usize,
    /// The command line that produced the file.
    pub command: String,
    /// The program version.
    pub version: String,
    /// C, the channels fitted: the second dimension of the per-channel tables.
    pub channels: usize,
    pub material: MaterialRecord,
    pub fit: FitRecord,
    pub damping: DampingRecord,
    pub simulated: SimulatedModesRecord,
    /// One row per recorded mode in the band that found a simulated partner.
    pub matched: Vec<MatchedModeRecord>,
    pub errors: ErrorsRecord,
    /// (stage, seconds), in order.
    pub timings: Vec<(String, f64)>,
}

/// `/material`.
#[derive(Clone, Debug)]
pub struct MaterialRecord {
    /// Fitted E [Pa].
    pub youngs_modulus: f64,
    /// Fitted ν.
    pub poisson_ratio: f64,
    /// ρ [kg/m³] (given; E is reported at this ρ and E/ρ is stored beside it).
    pub density: f64,
    pub start_youngs_modulus: f64,
    pub start_poisson_ratio: f64,
    pub poisson_learned: bool,
}

/// One step of the fit's history.
#[derive(Clone, Debug)]
pub struct FitStepRecord {
    pub step: usize,
    /// The transport phase (stored as 0) or the spectral one (1).
    pub transport: bool,
    pub loss: f64,
    pub youngs_modulus: f64,
    pub poisson_ratio: f64,
}

/// `/fit`.
#[derive(Clone, Debug)]
pub struct FitRecord {
    pub history: Vec<FitStepRecord>,
    /// Per channel [C].
    pub log_gains: Vec<f64>,
    /// Per mode and channel, mode-major `[K, C]`.
    pub log_amplitude_offsets: Vec<f64>,
    pub steps: usize,
    pub switched_at: Option<usize>,
    pub seconds: f64,
    pub max_ritz_residual: f64,
    /// ν of the full solves spanning the reduced basis (an f64 array attribute).
    pub basis_samples: Vec<f64>,
    pub line_start: Option<LineStartRecord>,
    /// The starts tried before the fit, (E [Pa], ν, mean loss of their last five steps);
    /// empty: none tried.
    pub start_probes: Vec<(f64, f64, f64)>,
}

/// The line-spectrum start of the fit and its frequency error.
#[derive(Clone, Debug)]
pub struct LineStartRecord {
    pub youngs_modulus: f64,
    pub poisson_ratio: f64,
    pub distance: f64,
    /// Stored in `/errors`.
    pub mean_abs_relative_frequency_error: f64,
}

/// One stage-1 mode.
#[derive(Clone, Debug)]
pub struct DampingModeRecord {
    pub frequency_hz: f64,
    pub decay_rate: f64,
    pub level_db: f64,
    pub kept: bool,
    /// Per channel [C] (full scale).
    pub amplitudes: Vec<f64>,
    /// Per channel [C] (rad).
    pub phases: Vec<f64>,
}

/// One peak of the damping curve's data.
#[derive(Clone, Debug)]
pub struct DampingPeakRecord {
    pub frequency_hz: f64,
    pub decay_rate: f64,
    pub level_db: f64,
    pub kept: bool,
}

/// `/damping`.
#[derive(Clone, Debug)]
pub struct DampingRecord {
    /// Knots of d(f) [Hz].
    pub curve_frequencies_hz: Vec<f64>,
    /// d at the knots [1/s].
    pub curve_decay_rates: Vec<f64>,
    pub modes: Vec<DampingModeRecord>,
    pub peaks: Vec<DampingPeakRecord>,
    pub rayleigh_alpha: f64,
    pub rayleigh_beta: f64,
    pub rayleigh_rms_log_error: f64,
    pub curve_rms_log_error: f64,
    pub loss_initial: f64,
    pub loss_final: f64,
}

/// `/modes/simulated`, per fitted mode [K].
#[derive(Clone, Debug)]
pub struct SimulatedModesRecord {
    pub frequency_hz: Vec<f64>,
    /// Reduced-basis eigenvalues at the fit [rad²/s²].
    pub eigenvalues: Vec<f64>,
    /// Full-solve eigenvalues at the fit [rad²/s²].
    pub full_eigenvalues: Vec<f64>,
    pub relative_difference: Vec<f64>,
}

/// One row of `/modes/matched`.
#[derive(Clone, Debug)]
pub struct MatchedModeRecord {
    pub recorded_frequency_hz: f64,
    pub simulated_frequency_hz: f64,
    pub relative_error: f64,
    pub recorded_decay_rate: f64,
    pub simulated_decay_rate: f64,
    pub simulated_index: usize,
}

/// `/errors`.
#[derive(Clone, Debug)]
pub struct ErrorsRecord {
    pub spectrogram_start: f64,
    pub spectrogram_fit: f64,
    pub max_relative_eigenvalue_difference: f64,
    pub mean_abs_relative_frequency_error: f64,
}

/// Writes a fit-material result (atomically, see [`ResultsFile::write`]).
pub fn write_result(path: &Path, r: &FitMaterialResult) -> Result<(), IoError> {
    let mut file = ResultsFile::new(FORMAT, FORMAT_VERSION);
    let m = &r.material;
    file.text("/", "mesh", &r.mesh)
        .texts("/", "recordings", r.recordings.clone())
        .integer("/", "order", i64::from(r.order))
        .integer("/", "n_ranks", r.n_ranks as i64)
        .text("/", "command", &r.command)
        .text("/", "version", &r.version)
        .number("/material", "youngs_modulus", m.youngs_modulus)
        .number("/material", "poisson_ratio", m.poisson_ratio)
        .number("/material", "density", m.density)
        .number(
            "/material",
            "youngs_over_density",
            m.youngs_modulus / m.density,
        )
        .number("/material", "start_youngs_modulus", m.start_youngs_modulus)
        .number("/material", "start_poisson_ratio", m.start_poisson_ratio)
        .flag("/material", "poisson_learned", m.poisson_learned);
    let fit = &r.fit;
    let h = &fit.history;
    file.indices("/fit/history/step", h.iter().map(|s| s.step).collect())
        .flags(
            "/fit/history/phase",
            h.iter().map(|s| !s.transport).collect(),
        )
        .column("/fit/history/loss", h.iter().map(|s| s.loss).collect(), "1")
        .column(
            "/fit/history/youngs_modulus",
            h.iter().map(|s| s.youngs_modulus).collect(),
            "Pa",
        )
        .column(
            "/fit/history/poisson_ratio",
            h.iter().map(|s| s.poisson_ratio).collect(),
            "1",
        )
        .column("/fit/log_gains", fit.log_gains.clone(), "1")
        .dataset(
            "/fit/log_amplitude_offsets",
            &[fit.log_amplitude_offsets.len() / r.channels, r.channels],
            fit.log_amplitude_offsets.clone(),
            "1",
        )
        .integer("/fit", "steps", fit.steps as i64)
        .integer(
            "/fit",
            "switched_at",
            fit.switched_at.map_or(-1, |s| s as i64),
        )
        .number("/fit", "seconds", fit.seconds)
        .number("/fit", "max_ritz_residual", fit.max_ritz_residual)
        .numbers("/fit", "basis_samples", fit.basis_samples.clone());
    let d = &r.damping;
    let dm = &d.modes;
    let c = r.channels;
    file.column(
        "/damping/curve/frequencies_hz",
        d.curve_frequencies_hz.clone(),
        "Hz",
    )
    .column(
        "/damping/curve/decay_rates",
        d.curve_decay_rates.clone(),
        "1/s",
    )
    .column(
        "/damping/modes/frequency_hz",
        dm.iter().map(|m| m.frequency_hz).collect(),
        "Hz",
    )
    .column(
        "/damping/modes/decay_rate",
        dm.iter().map(|m| m.decay_rate).collect(),
        "1/s",
    )
    .column(
        "/damping/modes/level_db",
        dm.iter().map(|m| m.level_db).collect(),
        "dB",
    )
    .flags("/damping/modes/kept", dm.iter().map(|m| m.kept).collect())
    .dataset(
        "/damping/modes/amplitudes",
        &[dm.len(), c],
        dm.iter().flat_map(|m| m.amplitudes.clone()).collect(),
        "full scale",
    )
    .dataset(
        "/damping/modes/phases",
        &[dm.len(), c],
        dm.iter().flat_map(|m| m.phases.clone()).collect(),
        "rad",
    )
    .column(
        "/damping/peaks/frequency_hz",
        d.peaks.iter().map(|p| p.frequency_hz).collect(),
        "Hz",
    )
    .column(
        "/damping/peaks/decay_rate",
        d.peaks.iter().map(|p| p.decay_rate).collect(),
        "1/s",
    )
    .column(
        "/damping/peaks/level_db",
        d.peaks.iter().map(|p| p.level_db).collect(),
        "dB",
    )
    .flags(
        "/damping/peaks/kept",
        d.peaks.iter().map(|p| p.kept).collect(),
    )
    .number("/damping", "rayleigh_alpha", d.rayleigh_alpha)
    .number("/damping", "rayleigh_beta", d.rayleigh_beta)
    .number(
        "/damping",
        "rayleigh_rms_log_error",
        d.rayleigh_rms_log_error,
    )
    .number("/damping", "curve_rms_log_error", d.curve_rms_log_error)
    .number("/damping", "loss_initial", d.loss_initial)
    .number("/damping", "loss_final", d.loss_final);
    let s = &r.simulated;
    let matched = &r.matched;
    let e = &r.errors;
    file.column(
        "/modes/simulated/frequency_hz",
        s.frequency_hz.clone(),
        "Hz",
    )
    .column(
        "/modes/simulated/eigenvalues",
        s.eigenvalues.clone(),
        "rad^2/s^2",
    )
    .column(
        "/modes/simulated/full_eigenvalues",
        s.full_eigenvalues.clone(),
        "rad^2/s^2",
    )
    .column(
        "/modes/simulated/relative_difference",
        s.relative_difference.clone(),
        "1",
    )
    .column(
        "/modes/matched/recorded_frequency_hz",
        matched.iter().map(|m| m.recorded_frequency_hz).collect(),
        "Hz",
    )
    .column(
        "/modes/matched/simulated_frequency_hz",
        matched.iter().map(|m| m.simulated_frequency_hz).collect(),
        "Hz",
    )
    .column(
        "/modes/matched/error_hz",
        matched
            .iter()
            .map(|m| m.simulated_frequency_hz - m.recorded_frequency_hz)
            .collect(),
        "Hz",
    )
    .column(
        "/modes/matched/relative_error",
        matched.iter().map(|m| m.relative_error).collect(),
        "1",
    )
    .column(
        "/modes/matched/recorded_decay_rate",
        matched.iter().map(|m| m.recorded_decay_rate).collect(),
        "1/s",
    )
    .column(
        "/modes/matched/simulated_decay_rate",
        matched.iter().map(|m| m.simulated_decay_rate).collect(),
        "1/s",
    )
    .indices(
        "/modes/matched/simulated_index",
        matched.iter().map(|m| m.simulated_index).collect(),
    )
    .number("/errors", "spectrogram_start", e.spectrogram_start)
    .number("/errors", "spectrogram_fit", e.spectrogram_fit)
    .number(
        "/errors",
        "max_relative_eigenvalue_difference",
        e.max_relative_eigenvalue_difference,
    )
    .number(
        "/errors",
        "mean_abs_relative_frequency_error",
        e.mean_abs_relative_frequency_error,
    );
    if !fit.start_probes.is_empty() {
        let probes = &fit.start_probes;
        file.column(
            "/fit/start_probes/youngs_modulus",
            probes.iter().map(|p| p.0).collect(),
            "Pa",
        )
        .column(
            "/fit/start_probes/poisson_ratio",
            probes.iter().map(|p| p.1).collect(),
            "1",
        )
        .column(
            "/fit/start_probes/loss",
            probes.iter().map(|p| p.2).collect(),
            "1",
        );
    }
    if let Some(l) = &fit.line_start {
        file.number("/fit", "line_start_youngs_modulus", l.youngs_modulus)
            .number("/fit", "line_start_poisson_ratio", l.poisson_ratio)
            .number("/fit", "line_start_distance", l.distance)
            .number(
                "/errors",
                "line_start_mean_abs_relative_frequency_error",
                l.mean_abs_relative_frequency_error,
            );
    }
    for (k, v) in &r.timings {
        file.number("/timings", k, *v);
    }
    file.write(path)
}

/// Reads the damping curve's knots from a fit-material result: (frequencies [Hz], decay rates
/// [1/s]).
pub fn read_damping_curve(path: &Path) -> Result<(Vec<f64>, Vec<f64>), IoError> {
    let (f, _) = read_dataset(path, "/damping/curve/frequencies_hz")?;
    let (d, _) = read_dataset(path, "/damping/curve/decay_rates")?;
    Ok((f, d))
}

/// Reads E [Pa], ν and ρ [kg/m³] from a fit-material result (format version 1 or 2).
pub fn read_material(path: &Path) -> Result<(f64, f64, f64), IoError> {
    let wrong = |found: String| IoError::WrongFormat {
        path: path.to_path_buf(),
        expected: FORMAT,
        found,
    };
    match read_attribute(path, "/", "format")? {
        AttrValue::Text(t) if t == FORMAT => {}
        other => return Err(wrong(format!("format {other}"))),
    }
    match read_attribute(path, "/", "format_version")? {
        AttrValue::Integer(v) if (1..=FORMAT_VERSION as i64).contains(&v) => {}
        other => {
            return Err(wrong(format!(
                "format_version {other}; this build reads 1 to {FORMAT_VERSION}"
            )))
        }
    }
    let number = |key: &str| -> Result<f64, IoError> {
        match read_attribute(path, "/material", key)? {
            AttrValue::Number(v) => Ok(v),
            other => Err(IoError::BadLayout {
                path: path.to_path_buf(),
                reason: format!("/material {key} is {other}, expected a number"),
            }),
        }
    };
    Ok((
        number("youngs_modulus")?,
        number("poisson_ratio")?,
        number("density")?,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::results::{read_dataset, read_integers};
    use crate::io::test_support::TempDir;

    fn sample(line_start: bool) -> FitMaterialResult {
        FitMaterialResult {
            mesh: "bowl.msh".into(),
            recordings: vec!["a.wav".into(), "b.wav".into()],
            order: 2,
            n_ranks: 2,
            command: "diffsound fit-material".into(),
            version: "0".into(),
            channels: 2,
            material: MaterialRecord {
                youngs_modulus: 5e10,
                poisson_ratio: 0.3,
                density: 2500.0,
                start_youngs_modulus: 7e10,
                start_poisson_ratio: 0.25,
                poisson_learned: true,
            },
            fit: FitRecord {
                history: vec![
                    FitStepRecord {
                        step: 0,
                        transport: true,
                        loss: 2.0,
                        youngs_modulus: 7e10,
                        poisson_ratio: 0.25,
                    },
                    FitStepRecord {
                        step: 1,
                        transport: false,
                        loss: 1.0,
                        youngs_modulus: 5e10,
                        poisson_ratio: 0.3,
                    },
                ],
                log_gains: vec![0.1, 0.2],
                log_amplitude_offsets: vec![0.0; 6],
                steps: 2,
                switched_at: None,
                seconds: 1.5,
                max_ritz_residual: 1e-9,
                basis_samples: vec![0.15, 0.35],
                start_probes: if line_start {
                    vec![(6e10, 0.275, 2.5), (6.1e10, 0.28, 2.25)]
                } else {
                    Vec::new()
                },
                line_start: line_start.then_some(LineStartRecord {
                    youngs_modulus: 6e10,
                    poisson_ratio: 0.28,
                    distance: 0.01,
                    mean_abs_relative_frequency_error: 0.002,
                }),
            },
            damping: DampingRecord {
                curve_frequencies_hz: vec![100.0, 1000.0],
                curve_decay_rates: vec![1.0, 3.0],
                modes: vec![DampingModeRecord {
                    frequency_hz: 440.0,
                    decay_rate: 2.0,
                    level_db: -20.0,
                    kept: true,
                    amplitudes: vec![0.5, 0.25],
                    phases: vec![0.0, 1.0],
                }],
                peaks: vec![DampingPeakRecord {
                    frequency_hz: 440.0,
                    decay_rate: 2.0,
                    level_db: -20.0,
                    kept: false,
                }],
                rayleigh_alpha: 1.0,
                rayleigh_beta: 1e-8,
                rayleigh_rms_log_error: 0.1,
                curve_rms_log_error: 0.05,
                loss_initial: 3.0,
                loss_final: 1.0,
            },
            simulated: SimulatedModesRecord {
                frequency_hz: vec![430.0, 900.0, 2000.0],
                eigenvalues: vec![1.0, 2.0, 3.0],
                full_eigenvalues: vec![1.0, 2.0, 3.0],
                relative_difference: vec![0.0; 3],
            },
            matched: vec![MatchedModeRecord {
                recorded_frequency_hz: 440.0,
                simulated_frequency_hz: 430.0,
                relative_error: -10.0 / 440.0,
                recorded_decay_rate: 2.0,
                simulated_decay_rate: 2.1,
                simulated_index: 0,
            }],
            errors: ErrorsRecord {
                spectrogram_start: 0.9,
                spectrogram_fit: 0.3,
                max_relative_eigenvalue_difference: 1e-6,
                mean_abs_relative_frequency_error: 10.0 / 440.0,
            },
            timings: vec![("total".into(), 3.0)],
        }
    }

    /// What the writer puts in, the reader and the documented paths get back.
    #[test]
    fn a_written_result_reads_back() {
        let dir = TempDir::new("fit-material-result");
        let path = dir.path("fit.h5");
        write_result(&path, &sample(true)).unwrap();
        assert_eq!(read_material(&path).unwrap(), (5e10, 0.3, 2500.0));
        let number = |group: &str, key: &str| match read_attribute(&path, group, key).unwrap() {
            AttrValue::Number(v) => v,
            other => panic!("{group} {key} is {other:?}"),
        };
        let attr = |group: &str, key: &str| read_attribute(&path, group, key).unwrap();
        assert_eq!(number("/material", "youngs_over_density"), 5e10 / 2500.0);
        assert_eq!(attr("/fit", "switched_at"), AttrValue::Integer(-1));
        assert_eq!(attr("/", "n_ranks"), AttrValue::Integer(2));
        assert_eq!(attr("/", "format_version"), AttrValue::Integer(2));
        assert_eq!(attr("/material", "poisson_learned"), AttrValue::Integer(1));
        assert_eq!(number("/fit", "line_start_distance"), 0.01);
        assert_eq!(
            number("/errors", "line_start_mean_abs_relative_frequency_error"),
            0.002
        );
        assert_eq!(
            attr("/", "recordings"),
            AttrValue::Texts(vec!["a.wav".into(), "b.wav".into()])
        );
        assert_eq!(
            attr("/fit", "basis_samples"),
            AttrValue::Numbers(vec![0.15, 0.35])
        );
        let (phase, _) = read_integers(&path, "/fit/history/phase").unwrap();
        assert_eq!(phase, vec![0, 1]);
        assert_eq!(
            read_integers(&path, "/damping/modes/kept").unwrap().0,
            vec![1]
        );
        assert_eq!(
            read_integers(&path, "/modes/matched/simulated_index")
                .unwrap()
                .0,
            vec![0]
        );
        let (offsets, shape) = read_dataset(&path, "/fit/log_amplitude_offsets").unwrap();
        assert_eq!((offsets.len(), shape), (6, vec![3, 2]));
        let (amplitudes, shape) = read_dataset(&path, "/damping/modes/amplitudes").unwrap();
        assert_eq!((amplitudes, shape), (vec![0.5, 0.25], vec![1, 2]));
        let (error_hz, _) = read_dataset(&path, "/modes/matched/error_hz").unwrap();
        assert_eq!(error_hz, vec![-10.0]);
        let (probe_nu, _) = read_dataset(&path, "/fit/start_probes/poisson_ratio").unwrap();
        assert_eq!(probe_nu, vec![0.275, 0.28]);
        let (probe_loss, _) = read_dataset(&path, "/fit/start_probes/loss").unwrap();
        assert_eq!(probe_loss, vec![2.5, 2.25]);

        // Without a line-spectrum start, its attributes are absent.
        let path = dir.path("plain.h5");
        write_result(&path, &sample(false)).unwrap();
        assert!(read_attribute(&path, "/fit", "line_start_distance").is_err());
    }

    /// A version-1 file (everything f64, lists as text) still gives its material; another
    /// format or a future version is refused by name.
    #[test]
    fn read_material_takes_version_1_and_refuses_other_files() {
        let dir = TempDir::new("fit-material-v1");
        let path = dir.path("v1.h5");
        ResultsFile::new(FORMAT, 1)
            .text("/", "recordings", "a.wav, b.wav")
            .number("/", "n_ranks", 2.0)
            .number("/material", "youngs_modulus", 7e10)
            .number("/material", "poisson_ratio", 0.2)
            .number("/material", "density", 2400.0)
            .write(&path)
            .unwrap();
        assert_eq!(read_material(&path).unwrap(), (7e10, 0.2, 2400.0));
        for (format, version) in [("diffsound.diagnose", 1), (FORMAT, FORMAT_VERSION + 1)] {
            let path = dir.path("other.h5");
            ResultsFile::new(format, version)
                .number("/material", "youngs_modulus", 7e10)
                .write(&path)
                .unwrap();
            let err = read_material(&path).unwrap_err();
            assert!(matches!(err, IoError::WrongFormat { .. }), "{err}");
            assert!(
                err.to_string()
                    .contains("not a diffsound.fit_material file"),
                "{err}"
            );
        }
    }
}
