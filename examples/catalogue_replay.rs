//! Re-runs the diagnosis catalogue on saved inputs (a developer tool for calibrating the
//! catalogue's rules without re-running whole diagnoses: a 30-case benchmark replays in
//! seconds instead of half an hour of extraction, material fits and eigen-solves).
//!
//! `diagnose` writes, under `catalogue_input` of its JSON report, the [`Evidence`] and the
//! [`CatalogueSettings`] its final catalogue pass was given. For every `case_*/<from>.json`
//! under `--cases`, this runs [`catalogue::diagnose`] again on that evidence, with the saved
//! settings changed by any `--set key=value` (a value is read as JSON, e.g. `--set
//! min_held_out_gain=3`), and writes `case_*/<to>.json`: the input report with `catalogue`
//! replaced and a `replay` record (source, overrides), so that `examples/diagnose_score` scores
//! it like any other report (`--report <to>.json`).
//!
//! What a replay does not redo: the recording's extraction, the material, the simulated
//! modes, and the choice of the candidate added-mass region (taken from the first catalogue
//! pass of the original run); a rule change that would have moved that region is not seen.
//!
//! ```text
//! cargo run --release --example catalogue_replay -- --cases /tmp/dbench/set1 --from v13 --to r1 \
//!     [--set min_held_out_gain=3 ...]
//! ```

use diffsound::diagnose::catalogue::{self, CatalogueSettings, Evidence};
use diffsound::io::{write_atomically, IoError};
use std::path::{Path, PathBuf};

struct Args {
    cases: PathBuf,
    from: String,
    to: String,
    overrides: Vec<(String, serde_json::Value)>,
}

fn usage() -> ! {
    eprintln!("usage: catalogue_replay --cases DIR --from NAME --to NAME [--set key=value ...]");
    std::process::exit(2)
}

fn parse_args() -> Args {
    let mut it = std::env::args().skip(1);
    let (mut cases, mut from, mut to, mut overrides) = (None, None, None, Vec::new());
    while let Some(a) = it.next() {
        let mut value = || it.next().unwrap_or_else(|| usage());
        match a.as_str() {
            "--cases" => cases = Some(PathBuf::from(value())),
            "--from" => from = Some(value()),
            "--to" => to = Some(value()),
            "--set" => {
                let kv = value();
                let Some((k, v)) = kv.split_once('=') else {
                    usage()
                };
                // A bare word that is not JSON (a string setting) is taken as a string.
                let v = serde_json::from_str(v)
                    .unwrap_or_else(|_| serde_json::Value::String(v.to_string()));
                overrides.push((k.to_string(), v));
            }
            _ => usage(),
        }
    }
    match (cases, from, to) {
        (Some(cases), Some(from), Some(to)) if from != to => Args {
            cases,
            from,
            to,
            overrides,
        },
        _ => usage(),
    }
}

/// One case: the replayed report's accepted effect names, or why it could not be replayed.
fn replay(path: &Path, out: &Path, args: &Args) -> Result<Vec<String>, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut report: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?;
    let input = report.get("catalogue_input").ok_or_else(|| {
        format!(
            "{}: no catalogue_input (written by diagnose since this tool exists)",
            path.display()
        )
    })?;
    let evidence: Evidence = serde_json::from_value(input["evidence"].clone())
        .map_err(|e| format!("{}: evidence: {e}", path.display()))?;
    let mut settings = input["settings"].clone();
    for (k, v) in &args.overrides {
        settings
            .as_object_mut()
            .ok_or("settings are not a JSON object")?
            .insert(k.clone(), v.clone());
    }
    // catalogue::diagnose validates the settings.
    let settings: CatalogueSettings =
        serde_json::from_value(settings).map_err(|e| format!("settings: {e}"))?;
    let result =
        catalogue::diagnose(&evidence, &settings).map_err(|e| format!("catalogue: {e}"))?;
    let accepted = result.accepted.iter().map(|a| a.name.clone()).collect();
    report["catalogue"] = serde_json::to_value(&result).map_err(|e| e.to_string())?;
    report["replay"] = serde_json::json!({
        "from": path.display().to_string(),
        "overrides": args.overrides.iter().map(|(k, v)| (k.clone(), v.clone())).collect::<serde_json::Map<_, _>>(),
        "settings": settings,
    });
    let text = serde_json::to_string_pretty(&report).map_err(|e| e.to_string())?;
    // Atomic, as diagnose writes its reports: an interrupted replay leaves no half-written file.
    write_atomically(out, |tmp| {
        std::fs::write(tmp, &text).map_err(|source| IoError::Fs {
            path: tmp.to_path_buf(),
            context: "writing the replayed report".into(),
            source,
        })
    })
    .map_err(|e| e.to_string())?;
    Ok(accepted)
}

fn main() {
    let args = parse_args();
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(&args.cases)
        .unwrap_or_else(|e| {
            eprintln!("{}: {e}", args.cases.display());
            std::process::exit(1)
        })
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.is_dir()
                && p.file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with("case_"))
        })
        .collect();
    dirs.sort();
    let mut failed = 0;
    for dir in &dirs {
        let name = dir
            .file_name()
            .unwrap_or_default()
            .to_string_lossy()
            .to_string();
        let path = dir.join(format!("{}.json", args.from));
        if !path.exists() {
            println!("{name}: no {}.json", args.from);
            continue;
        }
        match replay(&path, &dir.join(format!("{}.json", args.to)), &args) {
            Ok(accepted) => println!(
                "{name}: {}",
                if accepted.is_empty() {
                    "–".to_string()
                } else {
                    accepted.join(", ")
                }
            ),
            Err(e) => {
                failed += 1;
                println!("{name}: FAILED {e}");
            }
        }
    }
    if failed > 0 {
        std::process::exit(1);
    }
}
