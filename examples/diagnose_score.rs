//! Scorer of the blind mismatch-diagnosis benchmark (issue 6, section 5).
//!
//! Reads the cases rendered by `examples/diagnose_generate.rs`, their sealed labels, and the
//! report `diffsound diagnose` wrote for each, and scores the reports against the labels. A
//! plain serial program: no MPI, no PETSc.
//!
//! # Usage
//!
//! ```text
//! target/release/examples/diagnose_score --cases DIR [--report diagnosis.json] [--bins 3]
//!        [--out DIR/score.json] [--glide-span SECONDS]
//! ```
//!
//! # Input
//!
//! * `DIR/cases.json`: the case list (`cases[].case`, `cases[].directory`).
//! * `DIR/labels/<case>.json`: the sealed labels (parsed as `inject::CaseTruth` and read
//!   field by field for the parameters; a missing label file is an error: the set is broken).
//! * `DIR/<directory>/<report>` (`--report`, default `diagnosis.json`): format
//!   `diffsound.diagnose`, version 1, with `catalogue` (the catalogue's `CatalogueReport`),
//!   `material` and `held_out_audio` (before/after, or null); other fields are ignored. A case
//!   without its report is **not run**; one that cannot be read is **unreadable**. Both are
//!   listed on stderr and in the output, and the other cases are scored.
//! * `DIR/<directory>/metadata.toml`: `duration_after_onset_s`, the analysis span L of the
//!   pitch-glide comparison unless `--glide-span` gives one (see below).
//!
//! # Output (printed, and written as JSON to `--out`, default `DIR/score.json`)
//!
//! 1. **Detection** ([`inject::score`]): precision, recall and F1 per effect, the macro F1,
//!    the false-positive rate on clean cases (fraction of clean cases with any accepted
//!    effect), and per case the true effects with their strength u, the accepted ones and a
//!    verdict per effect (TP, FN, FP; TN for a clean case with no detection). A detected
//!    effect is a catalogue acceptance (`catalogue.accepted[].name`, `reverb_noise` read as
//!    `reverb`).
//! 2. **Recall by strength**: per effect, detected/present in `--bins` equal bins of u.
//! 3. **Parameter errors** of the true positives, where the detector's parameter and the
//!    injected one measure the same physical quantity: error = detected/expected − 1 with
//!    "expected" derived from the labels ([`inject::compare_parameters`]; the mapping of each
//!    effect, with its equations, is in the module docs of `diffsound::diagnose::inject`,
//!    "Comparing parameters"). In short:
//!    * `non_rayleigh_damping`: the detector's decay rates at its three knots against the
//!      injected Zener law there; one RMS relative error per case.
//!    * `beating_pair`: each fitted relative split δf/f against the labels' split of the
//!      re-solved cluster at the same centre frequency (paired within 0.2 %).
//!    * `support_contact`: n/a — the detector's Δd_k = γ w_k needs the CLI's support weights
//!      w_k, which the report does not carry; γ and the labels' largest Δd_k are listed.
//!    * `contact_duration`: the detector fits a half-sine, the generator used a Hertz
//!      sin^(3/2) pulse, so T_half-sine/T_Hertz ≠ 1 is expected: 0.904 for the same
//!      low-frequency roll-off, 0.901 for the same −3 dB frequency, 6/7 for the same first
//!      zero (printed, from `inject::contact_shape_ratios`); beyond the main lobe the
//!      detector's bound T ≤ 2.9π/ω_max binds. Expected T: the half-sine fitted to the labels'
//!      Hertz attenuation of the modes the detector matched; the raw ratio is listed.
//!    * `reverb`: T60 against T60.
//!    * `radiation`: n/a — the labels' strength (a dB misfit of the multipole transfers to a
//!      rank-one level model) is not the detector's η or u_k v_c.
//!    * `added_mass`: the detector's μ is the added modal mass of its most affected mode
//!      relative to its own, not the mass fraction; the labels give that per mode as
//!      (f_base/f)² − 1, so expected μ = its largest value (the lowest mode's for the
//!      `fluid_loading` variant). n/a when another FEM effect moved the frequencies too.
//!    * `pitch_glide`: reports with `glide_observable = "offset_at_onset"` (the chirp fit of
//!      `analysis::extract::glide`) detect the generator's own g, the offset at t = 0 of
//!      f₀(1 + g e^(−2dt)): expected = the labels' g. In older reports
//!      the detector's g is (f_early − f_late)/f of its most energetic mode;
//!      the generator's g is the offset at t = 0 of f₀(1 + g e^(−2dt)). Expected:
//!      g (1 − e^(−dL)) E(L/2) for the labels' most energetic matched mode, **assuming** the
//!      early and late frequencies are least-squares fits to the two halves of the L seconds
//!      after the onset (L = `--glide-span`, else the case's `duration_after_onset_s`), unless
//!      the report gives its windows (`glide_windows_s`: early [0, T₁], late [T₁, T₂]; then
//!      `inject::glide_window_contrast`, and `--glide-span` overrides them with halves). It is a first-order reference: the
//!      library's extractor resolves each half of a gliding mode into several poles (measured
//!      in the `inject` docs), and which of them the CLI reports sets the true factor.
//!
//!    Per effect: n, median and largest |error| and the median signed error (bias), or "n/a"
//!    with the reason.
//! 4. **Held-out improvement**: for every case with ≥ 1 accepted effect, the catalogue's
//!    held-out error of the baseline and of the final model (`catalogue.baseline`,
//!    `catalogue.final_model`, both with the baseline's floors as the yardstick) and, when
//!    present, `held_out_audio` before/after: how many dropped, how many did not, and the
//!    median relative drop (before − after)/before. The case's catalogue error covers the
//!    modal rows only, so a case whose only accepted effect is reverberation shows no change
//!    there; hence also, per accepted effect, its own held-out error before and after it at its
//!    selection step (`held_out_before`/`held_out_after` of the accepted entry: the held-out
//!    microphones' modal rows, or for reverberation the odd STFT frames of the residual
//!    envelopes), summed up per effect.
//!
//! Also, when the report carries `material`: E and ν against the labels (relative error of
//! E, difference of ν).
//!
//! Exit status 0 when at least one case was scored (even with cases not run: the banner on
//! stderr says so), 1 on an unusable set (no cases.json, a missing label, nothing to score),
//! 2 on bad arguments.

use diffsound::diagnose::catalogue::CatalogueReport;
use diffsound::diagnose::inject::{
    self, CaseTruth, Effect, ErrorSummary, HeldOutSummary, ParameterComparison, ScoringContext,
};
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

const USAGE: &str = "usage: diagnose_score --cases DIR [--report diagnosis.json] [--bins 3] [--out DIR/score.json] [--glide-span SECONDS]";

struct Args {
    cases: PathBuf,
    report: String,
    bins: usize,
    out: Option<PathBuf>,
    glide_span: Option<f64>,
}

fn parse_args() -> Result<Args, String> {
    let mut a = Args {
        cases: PathBuf::new(),
        report: "diagnosis.json".into(),
        bins: 3,
        out: None,
        glide_span: None,
    };
    let mut cases = None;
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        let mut value = |name: &str| it.next().ok_or(format!("{name} needs a value\n{USAGE}"));
        match arg.as_str() {
            "--cases" => cases = Some(PathBuf::from(value("--cases")?)),
            "--report" => a.report = value("--report")?,
            "--bins" => {
                let v = value("--bins")?;
                a.bins = v
                    .parse()
                    .map_err(|_| format!("--bins: cannot read {v:?} as a whole number"))?;
            }
            "--out" => a.out = Some(PathBuf::from(value("--out")?)),
            "--glide-span" => {
                let v = value("--glide-span")?;
                a.glide_span = Some(v.parse().map_err(|_| {
                    format!("--glide-span: cannot read {v:?} as a number (seconds)")
                })?);
            }
            "-h" | "--help" => {
                eprintln!("{USAGE}");
                std::process::exit(0);
            }
            other => return Err(format!("unknown argument {other:?}\n{USAGE}")),
        }
    }
    a.cases = cases.ok_or(format!("--cases DIR is required\n{USAGE}"))?;
    if !(1..=100).contains(&a.bins) {
        return Err(format!("--bins must lie in 1..=100, got {}", a.bins));
    }
    if let Some(s) = a.glide_span {
        if !(s > 0.0 && s.is_finite()) {
            return Err(format!(
                "--glide-span must be a positive number of seconds, got {s}"
            ));
        }
    }
    if a.report.is_empty() || a.report.contains('/') {
        return Err(format!(
            "--report must be a file name inside each case directory, got {:?}",
            a.report
        ));
    }
    Ok(a)
}

/// The part of `diagnosis.json` the scorer reads (other fields are ignored).
#[derive(Deserialize)]
struct Diagnosis {
    format: String,
    format_version: u64,
    #[serde(default)]
    material: Option<MaterialOut>,
    catalogue: CatalogueReport,
    #[serde(default)]
    held_out_audio: Option<BeforeAfter>,
    /// Ends of the early and late pitch-glide windows after the onset [s] (older reports: halves).
    #[serde(default)]
    glide_windows_s: Option<(f64, f64)>,
    /// "offset_at_onset": the glide rows are the chirp fit's g at t = 0 (newer reports).
    #[serde(default)]
    glide_observable: Option<String>,
}

#[derive(Deserialize)]
struct MaterialOut {
    youngs_modulus: Option<f64>,
    poisson_ratio: Option<f64>,
    #[serde(default)]
    source: Option<String>,
}

#[derive(Deserialize, Serialize, Clone, Copy)]
struct BeforeAfter {
    before: f64,
    after: f64,
}

/// One case of the set, as far as it could be read.
struct Case {
    name: String,
    truth: CaseTruth,
    labels: serde_json::Value,
    context: ScoringContext,
    report: Result<Diagnosis, Missing>,
}

enum Missing {
    NotRun,
    Unreadable(String),
}

fn read_json(path: &Path) -> Result<serde_json::Value, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    serde_json::from_str(&text).map_err(|e| format!("{}: not valid JSON: {e}", path.display()))
}

fn read_report(path: &Path) -> Result<Diagnosis, Missing> {
    if !path.exists() {
        return Err(Missing::NotRun);
    }
    let value = read_json(path).map_err(Missing::Unreadable)?;
    let d: Diagnosis = serde_json::from_value(value)
        .map_err(|e| Missing::Unreadable(format!("{}: {e}", path.display())))?;
    if d.format != "diffsound.diagnose" || d.format_version != 1 {
        return Err(Missing::Unreadable(format!(
            "{}: format {:?} version {}, expected \"diffsound.diagnose\" version 1",
            path.display(),
            d.format,
            d.format_version
        )));
    }
    Ok(d)
}

/// `duration_after_onset_s` of the case's metadata, if readable.
fn analysis_span(dir: &Path) -> Option<f64> {
    let text = std::fs::read_to_string(dir.join("metadata.toml")).ok()?;
    let value: toml::Value = toml::from_str(&text).ok()?;
    value
        .get("duration_after_onset_s")?
        .as_float()
        .filter(|s| *s > 0.0)
}

fn load(args: &Args) -> Result<Vec<Case>, String> {
    let listing = read_json(&args.cases.join("cases.json"))?;
    let entries = listing
        .get("cases")
        .and_then(|c| c.as_array())
        .ok_or_else(|| {
            format!(
                "{}: no \"cases\" list",
                args.cases.join("cases.json").display()
            )
        })?;
    let mut cases = Vec::new();
    for (i, e) in entries.iter().enumerate() {
        let name = e
            .get("case")
            .and_then(|v| v.as_str())
            .ok_or_else(|| format!("cases.json: entry {i} has no \"case\""))?
            .to_string();
        let directory = args
            .cases
            .join(e.get("directory").and_then(|v| v.as_str()).unwrap_or(&name));
        let label_path = args.cases.join("labels").join(format!("{name}.json"));
        let labels = read_json(&label_path).map_err(|e| format!("sealed labels of {name}: {e}"))?;
        let truth: CaseTruth = serde_json::from_value(labels.clone())
            .map_err(|e| format!("{}: not a case label: {e}", label_path.display()))?;
        let report = read_report(&directory.join(&args.report));
        let matched_hz = match &report {
            Ok(d) => d
                .catalogue
                .matching
                .pairs
                .iter()
                .map(|p| p.observed_hz)
                .collect(),
            Err(_) => Vec::new(),
        };
        let glide_windows_s = report
            .as_ref()
            .ok()
            .and_then(|d| d.glide_windows_s)
            .filter(|_| args.glide_span.is_none());
        let glide_offset_at_onset = report
            .as_ref()
            .ok()
            .and_then(|d| d.glide_observable.as_deref())
            == Some("offset_at_onset");
        let context = ScoringContext {
            glide_span_s: args.glide_span.or_else(|| analysis_span(&directory)),
            glide_windows_s,
            glide_offset_at_onset,
            matched_hz,
        };
        cases.push(Case {
            name,
            truth,
            labels,
            context,
            report,
        });
    }
    Ok(cases)
}

#[derive(Serialize)]
struct Verdict {
    effect: Effect,
    verdict: &'static str,
}

#[derive(Serialize)]
struct CaseRow {
    case: String,
    truth: Vec<(Effect, f64)>,
    detected: Vec<Effect>,
    /// Accepted names that are not effects of the benchmark.
    unknown_detected: Vec<String>,
    verdicts: Vec<Verdict>,
    youngs_modulus_relative_error: Option<f64>,
    poisson_ratio_error: Option<f64>,
    material_source: Option<String>,
}

#[derive(Serialize)]
struct CaseComparison {
    case: String,
    #[serde(flatten)]
    comparison: ParameterComparison,
}

#[derive(Serialize)]
struct EffectParameters {
    effect: Effect,
    summary: Option<ErrorSummary>,
    /// Why there is no (or only a partial) like-for-like comparison.
    not_comparable: Vec<String>,
    cases: Vec<CaseComparison>,
}

#[derive(Serialize)]
struct Failure {
    case: String,
    effect: String,
    error: String,
}

#[derive(Serialize)]
struct HeldOutRow {
    case: String,
    catalogue: Option<BeforeAfter>,
    audio: Option<BeforeAfter>,
}

fn pct(x: f64) -> String {
    format!("{:+.1} %", 100.0 * x)
}

fn opt(x: Option<f64>, digits: usize) -> String {
    x.map_or("–".into(), |v| format!("{v:.digits$}"))
}

fn sci(x: Option<f64>) -> String {
    x.map_or("–".into(), |v| format!("{v:.4e}"))
}

fn main() {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(2);
        }
    };
    if let Err(e) = run(&args) {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}

fn run(args: &Args) -> Result<(), String> {
    let cases = load(args)?;
    let not_run: Vec<&str> = cases
        .iter()
        .filter(|c| matches!(c.report, Err(Missing::NotRun)))
        .map(|c| c.name.as_str())
        .collect();
    let unreadable: Vec<(&str, &str)> = cases
        .iter()
        .filter_map(|c| match &c.report {
            Err(Missing::Unreadable(why)) => Some((c.name.as_str(), why.as_str())),
            _ => None,
        })
        .collect();
    if !not_run.is_empty() || !unreadable.is_empty() {
        eprintln!("{}", "!".repeat(78));
        if !not_run.is_empty() {
            eprintln!(
                "WARNING: {} of {} cases NOT RUN (no {}): {}",
                not_run.len(),
                cases.len(),
                args.report,
                not_run.join(", ")
            );
        }
        for (c, why) in &unreadable {
            eprintln!("WARNING: {c}: report UNREADABLE, not scored: {why}");
        }
        eprintln!(
            "The scores below cover the other {} cases only.",
            cases.len() - not_run.len() - unreadable.len()
        );
        eprintln!("{}", "!".repeat(78));
    }
    let scored: Vec<(&Case, &Diagnosis)> = cases
        .iter()
        .filter_map(|c| c.report.as_ref().ok().map(|d| (c, d)))
        .collect();
    if scored.is_empty() {
        return Err(format!(
            "no case of {} has a readable {}: nothing to score",
            args.cases.display(),
            args.report
        ));
    }

    // ---- 1. Detection. ----
    let mut rows = Vec::new();
    let mut detections = Vec::new();
    for (case, d) in &scored {
        let mut detected = Vec::new();
        let mut unknown = Vec::new();
        for a in &d.catalogue.accepted {
            match Effect::from_catalogue_name(&a.name) {
                Ok(e) if !detected.contains(&e) => detected.push(e),
                Ok(_) => {}
                Err(_) => unknown.push(a.name.clone()),
            }
        }
        detected.sort();
        let present: Vec<Effect> = case.truth.effects.iter().map(|l| l.effect).collect();
        let mut verdicts: Vec<Verdict> = Effect::ALL
            .iter()
            .filter_map(|&e| match (present.contains(&e), detected.contains(&e)) {
                (true, true) => Some(Verdict {
                    effect: e,
                    verdict: "TP",
                }),
                (true, false) => Some(Verdict {
                    effect: e,
                    verdict: "FN",
                }),
                (false, true) => Some(Verdict {
                    effect: e,
                    verdict: "FP",
                }),
                (false, false) => None,
            })
            .collect();
        verdicts.sort_by_key(|v| v.effect);
        let label_f64 = |k: &str| case.labels.get(k).and_then(|v| v.as_f64());
        let (e_err, nu_err) = match &d.material {
            Some(m) => (
                m.youngs_modulus
                    .zip(label_f64("youngs_modulus"))
                    .map(|(e, t)| e / t - 1.0),
                m.poisson_ratio
                    .zip(label_f64("poisson_ratio"))
                    .map(|(n, t)| n - t),
            ),
            None => (None, None),
        };
        rows.push(CaseRow {
            case: case.name.clone(),
            truth: case
                .truth
                .effects
                .iter()
                .map(|l| (l.effect, l.strength))
                .collect(),
            detected: detected.clone(),
            unknown_detected: unknown,
            verdicts,
            youngs_modulus_relative_error: e_err,
            poisson_ratio_error: nu_err,
            material_source: d.material.as_ref().and_then(|m| m.source.clone()),
        });
        detections.push(detected);
    }
    let truths: Vec<CaseTruth> = scored.iter().map(|(c, _)| c.truth.clone()).collect();
    let score = inject::score(&truths, &detections, args.bins).map_err(|e| e.to_string())?;

    println!(
        "Blind mismatch-diagnosis benchmark: {}",
        args.cases.display()
    );
    println!(
        "{} cases listed, {} scored, {} not run, {} unreadable (reports: {})\n",
        cases.len(),
        scored.len(),
        not_run.len(),
        unreadable.len(),
        args.report
    );
    println!("1. Detection");
    println!(
        "{:<22} {:>3} {:>3} {:>3} {:>9} {:>7} {:>6}",
        "effect", "TP", "FP", "FN", "precision", "recall", "F1"
    );
    for s in &score.per_effect {
        println!(
            "{:<22} {:>3} {:>3} {:>3} {:>9} {:>7} {:>6}",
            s.effect.name(),
            s.true_positives,
            s.false_positives,
            s.false_negatives,
            opt(s.precision, 2),
            opt(s.recall, 2),
            opt(s.f1, 2)
        );
    }
    println!(
        "macro F1 {}; clean cases {}, false-positive rate on clean cases {}",
        opt(score.macro_f1, 3),
        score.clean_cases,
        opt(score.clean_false_positive_rate, 2)
    );
    println!();
    println!(
        "{:<10} {:<48} {:<40} verdicts",
        "case", "true effects (u)", "detected"
    );
    for r in &rows {
        let truth = if r.truth.is_empty() {
            "clean".to_string()
        } else {
            r.truth
                .iter()
                .map(|(e, u)| format!("{e} ({u:.2})"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let mut detected: Vec<String> = r.detected.iter().map(|e| e.name().to_string()).collect();
        detected.extend(r.unknown_detected.iter().map(|n| format!("{n}?")));
        let detected = if detected.is_empty() {
            "–".into()
        } else {
            detected.join(", ")
        };
        let verdicts = if r.verdicts.is_empty() {
            "TN".into()
        } else {
            r.verdicts
                .iter()
                .map(|v| format!("{} {}", v.effect, v.verdict))
                .collect::<Vec<_>>()
                .join(", ")
        };
        println!("{:<10} {:<48} {:<40} {verdicts}", r.case, truth, detected);
    }
    let unknown: Vec<String> = rows
        .iter()
        .flat_map(|r| {
            r.unknown_detected
                .iter()
                .map(move |n| format!("{}: {n}", r.case))
        })
        .collect();
    if !unknown.is_empty() {
        println!(
            "accepted names that are no benchmark effect (ignored): {}",
            unknown.join("; ")
        );
    }

    // ---- 2. Recall by strength. ----
    println!("\n2. Recall by strength u (detected/present per bin)");
    for s in &score.per_effect {
        let bins: Vec<String> = s
            .recall_by_strength
            .iter()
            .map(|&(lo, hi, hit, n)| {
                format!(
                    "[{lo:.2}, {hi:.2}{} {hit}/{n}",
                    if hi >= 1.0 { "]" } else { ")" }
                )
            })
            .collect();
        println!("{:<22} {}", s.effect.name(), bins.join("   "));
    }

    // ---- 3. Parameters. ----
    let ratios = inject::contact_shape_ratios();
    let mut by_effect: BTreeMap<Effect, Vec<CaseComparison>> = BTreeMap::new();
    let mut failures = Vec::new();
    for (case, d) in &scored {
        for a in &d.catalogue.accepted {
            let Ok(effect) = Effect::from_catalogue_name(&a.name) else {
                continue;
            };
            if !case.truth.effects.iter().any(|l| l.effect == effect) {
                continue; // a false positive has no true parameter
            }
            match inject::compare_parameters(&case.labels, a, &case.context) {
                Ok(c) => by_effect.entry(effect).or_default().push(CaseComparison {
                    case: case.name.clone(),
                    comparison: c,
                }),
                Err(e) => failures.push(Failure {
                    case: case.name.clone(),
                    effect: a.name.clone(),
                    error: e.to_string(),
                }),
            }
        }
    }
    let mut parameters = Vec::new();
    for effect in Effect::ALL {
        let list = by_effect.remove(&effect).unwrap_or_default();
        let errors: Vec<f64> = list
            .iter()
            .flat_map(|c| c.comparison.errors.iter().copied())
            .collect();
        let mut reasons: Vec<String> = Vec::new();
        for r in list
            .iter()
            .filter_map(|c| c.comparison.not_comparable.as_ref())
        {
            if !reasons.contains(r) {
                reasons.push(r.clone());
            }
        }
        if list.is_empty() {
            reasons.push("no true positive to compare".into());
        }
        parameters.push(EffectParameters {
            effect,
            summary: ErrorSummary::of(&errors),
            not_comparable: reasons,
            cases: list,
        });
    }
    println!("\n3. Parameter errors of the true positives (error = detected/expected − 1; expected from the labels, see the module docs)");
    println!(
        "   contact shapes: T_half-sine/T_Hertz = {:.4} (same low-frequency roll-off), {:.4} (same −3 dB), {:.4} (same first zero: 3π vs {:.4}π)",
        ratios.ratio_low_frequency,
        ratios.ratio_minus_3db,
        ratios.ratio_first_zero,
        ratios.hertz_first_zero_x / std::f64::consts::PI
    );
    println!(
        "{:<22} {:>3} {:>12} {:>12} {:>12}",
        "effect", "n", "median |err|", "max |err|", "median err"
    );
    for p in &parameters {
        match &p.summary {
            Some(s) => println!(
                "{:<22} {:>3} {:>12} {:>12} {:>12}",
                p.effect.name(),
                s.n,
                pct(s.median_abs),
                pct(s.max_abs),
                pct(s.median)
            ),
            None => println!(
                "{:<22} n/a: {}",
                p.effect.name(),
                p.not_comparable.join("; ")
            ),
        }
    }
    for p in &parameters {
        for c in &p.cases {
            for v in &c.comparison.values {
                println!(
                    "   {:<9} {:<21} {} [{}]: truth {}, expected {}, detected {}{}",
                    c.case,
                    format!("{} ({})", p.effect.name(), c.comparison.variant),
                    v.quantity,
                    v.unit,
                    sci(v.truth),
                    sci(v.expected),
                    sci(v.detected),
                    v.relative_error
                        .map_or(String::new(), |e| format!(", error {}", pct(e)))
                );
            }
            if let (Some(why), true) = (&c.comparison.not_comparable, p.summary.is_some()) {
                println!("   {:<9} {:<21} partly n/a: {why}", c.case, p.effect.name());
            }
        }
    }
    for f in &failures {
        eprintln!(
            "WARNING: {} {}: parameters not compared: {}",
            f.case, f.effect, f.error
        );
        println!("   {} {}: NOT COMPARED: {}", f.case, f.effect, f.error);
    }

    // ---- 4. Held-out improvement. ----
    let mut held = Vec::new();
    let mut catalogue_missing = Vec::new();
    for (case, d) in &scored {
        if d.catalogue.accepted.is_empty() {
            continue;
        }
        let catalogue = match (
            d.catalogue.baseline.held_out_error,
            d.catalogue.final_model.held_out_error,
        ) {
            (Some(before), Some(after)) => Some(BeforeAfter { before, after }),
            _ => {
                catalogue_missing.push(case.name.clone());
                None
            }
        };
        held.push(HeldOutRow {
            case: case.name.clone(),
            catalogue,
            audio: d.held_out_audio,
        });
    }
    let catalogue_summary = HeldOutSummary::of(
        &held
            .iter()
            .filter_map(|h| h.catalogue.map(|b| (b.before, b.after)))
            .collect::<Vec<_>>(),
    );
    let audio_summary = HeldOutSummary::of(
        &held
            .iter()
            .filter_map(|h| h.audio.map(|b| (b.before, b.after)))
            .collect::<Vec<_>>(),
    );
    println!(
        "\n4. Held-out improvement ({} cases with ≥ 1 accepted effect)",
        held.len()
    );
    println!(
        "{:<10} {:>12} {:>12} {:>14} {:>14}",
        "case", "catalogue", "", "audio", ""
    );
    println!(
        "{:<10} {:>12} {:>12} {:>14} {:>14}",
        "", "before", "after", "before", "after"
    );
    for h in &held {
        println!(
            "{:<10} {:>12} {:>12} {:>14} {:>14}",
            h.case,
            opt(h.catalogue.map(|b| b.before), 4),
            opt(h.catalogue.map(|b| b.after), 4),
            sci(h.audio.map(|b| b.before)),
            sci(h.audio.map(|b| b.after))
        );
    }
    let line = |what: &str, s: &HeldOutSummary| {
        println!(
            "{what}: {} pairs, dropped in {}, did not drop in {}{}, median relative drop {}",
            s.cases - s.invalid,
            s.dropped,
            s.not_dropped,
            if s.invalid > 0 {
                format!(" ({} invalid)", s.invalid)
            } else {
                String::new()
            },
            s.median_relative_drop.map_or("–".into(), pct)
        )
    };
    line("catalogue held-out error", &catalogue_summary);
    if !catalogue_missing.is_empty() {
        println!(
            "   no catalogue held-out error (baseline or final) in: {}",
            catalogue_missing.join(", ")
        );
    }
    line("held-out audio error", &audio_summary);

    // Per accepted effect, its own held-out data at its step.
    let mut per_effect: std::collections::BTreeMap<String, Vec<(f64, f64)>> =
        std::collections::BTreeMap::new();
    let mut without = Vec::new();
    for (case, d) in &scored {
        for a in &d.catalogue.accepted {
            match (a.held_out_before, a.held_out_after) {
                (Some(b), Some(after)) => per_effect
                    .entry(a.name.clone())
                    .or_default()
                    .push((b, after)),
                _ => without.push(format!("{} {}", case.name, a.name)),
            }
        }
    }
    println!("\n   each accepted effect on its own held-out data at its step (modal effects: the held-out microphones' rows; reverb: the odd STFT frames);\n   it falls for every accepted effect by construction (the selection requires it), false positives included");
    println!(
        "   {:<22} {:>8} {:>8} {:>12} {:>22}",
        "effect", "accepted", "dropped", "not dropped", "median relative drop"
    );
    let mut all_pairs = Vec::new();
    for (name, pairs) in &per_effect {
        let s = HeldOutSummary::of(pairs);
        all_pairs.extend_from_slice(pairs);
        println!(
            "   {:<22} {:>8} {:>8} {:>12} {:>22}",
            name,
            s.cases,
            s.dropped,
            s.not_dropped,
            s.median_relative_drop.map_or("–".into(), pct)
        );
    }
    line("   every accepted effect", &HeldOutSummary::of(&all_pairs));
    if !without.is_empty() {
        println!(
            "   accepted without a held-out error: {}",
            without.join(", ")
        );
    }

    // ---- Material (when reported). ----
    let e_errors: Vec<f64> = rows
        .iter()
        .filter_map(|r| r.youngs_modulus_relative_error)
        .collect();
    let nu_errors: Vec<f64> = rows.iter().filter_map(|r| r.poisson_ratio_error).collect();
    let e_summary = ErrorSummary::of(&e_errors);
    let nu_summary = ErrorSummary::of(&nu_errors);
    if let Some(s) = &e_summary {
        println!(
            "\nMaterial: E relative error over {} cases: median |err| {}, max {}, median {}",
            s.n,
            pct(s.median_abs),
            pct(s.max_abs),
            pct(s.median)
        );
    }
    if let Some(s) = &nu_summary {
        println!(
            "          ν error over {} cases: median |Δν| {:.4}, max {:.4}, median {:+.4}",
            s.n, s.median_abs, s.max_abs, s.median
        );
    }

    if !not_run.is_empty() || !unreadable.is_empty() {
        println!("\nNOTE: {} case(s) not run and {} unreadable were left out of every number above (see stderr).", not_run.len(), unreadable.len());
    }

    let out = args
        .out
        .clone()
        .unwrap_or_else(|| args.cases.join("score.json"));
    let doc = json!({
        "format": "diffsound.diagnose_score",
        "format_version": 1,
        "cases_dir": args.cases.display().to_string(),
        "report_file": args.report,
        "strength_bins": args.bins,
        "cases_listed": cases.len(),
        "cases_scored": scored.len(),
        "not_run": not_run,
        "unreadable": unreadable.iter().map(|(c, why)| json!({"case": c, "error": why})).collect::<Vec<_>>(),
        "detection": score,
        "per_case": rows,
        "parameters": {
            "contact_shape_ratios": ratios,
            "glide_span_s": args.glide_span,
            "per_effect": parameters,
            "not_compared": failures,
        },
        "held_out": {
            "cases": held,
            "catalogue": catalogue_summary,
            "catalogue_missing": catalogue_missing,
            "audio": audio_summary,
        },
        "material": {"youngs_modulus_relative_error": e_summary, "poisson_ratio_error": nu_summary},
    });
    let text = serde_json::to_string_pretty(&doc).map_err(|e| e.to_string())?;
    diffsound::io::write_atomically(&out, |tmp| {
        std::fs::write(tmp, &text).map_err(|e| diffsound::io::IoError::Fs {
            path: tmp.to_path_buf(),
            context: "writing".into(),
            source: e,
        })
    })
    .map_err(|e| e.to_string())?;
    println!("\nwrote {}", out.display());
    Ok(())
}
