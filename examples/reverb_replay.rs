//! Replays the catalogue's reverberation / noise-floor evaluation on saved residual envelopes
//! (a developer tool for calibrating that entry without re-running whole diagnoses).
//!
//! Input (stdin): a JSON list of `{"case": ..., "labels": [...], "env": ResidualEnvelopes}`,
//! e.g. dumped from the `/envelopes` groups of `diagnose` HDF5 results. Prints one line per
//! case: the outcome, ΔBIC, the held-out error before → after, T60 and ρ_b/σ_b per band.
//!
//! ```text
//! cargo run --release --example reverb_replay < envelopes.json
//! ```

use std::io::Read;

use diffsound::diagnose::catalogue::{
    acceptance, CatalogueSettings, Effect, Evidence, OwnOutcome, ResidualEnvelopes, ReverbNoise,
};

#[derive(serde::Deserialize)]
struct Case {
    case: String,
    labels: Vec<String>,
    env: ResidualEnvelopes,
}

fn main() {
    let mut text = String::new();
    std::io::stdin().read_to_string(&mut text).expect("stdin");
    let cases: Vec<Case> = serde_json::from_str(&text).expect("a JSON list of cases");
    let settings = CatalogueSettings::default();
    for c in cases {
        let truth = c.labels.iter().any(|l| l == "reverb");
        let evidence = Evidence {
            fit: Vec::new(),
            held_out: None,
            simulated: Vec::new(),
            residual_envelopes: Some(c.env),
            split_sites: None,
        };
        let eval = ReverbNoise
            .evaluate_own(&evidence, &settings)
            .expect("reverb evaluates itself");
        let line = match eval.outcome {
            OwnOutcome::NotEnoughData(why) => format!("not enough data: {why}"),
            OwnOutcome::Nothing { statistic, .. } => format!("nothing (z = {statistic:.1})"),
            OwnOutcome::Fitted {
                statistic,
                delta_bic,
                held_out,
                params,
                detail,
                signature_missing,
                ..
            } => {
                let accepted = signature_missing.is_none()
                    && acceptance(delta_bic, Some(held_out), &settings).is_none();
                let (held_out_before, held_out_after) = (held_out.before, held_out.after);
                let rho: Vec<String> = params[1..]
                    .iter()
                    .map(|p| format!("{:.1}", p.value / p.sigma.unwrap_or(f64::NAN).max(1e-300)))
                    .collect();
                format!(
                    "{} z = {statistic:.1} ΔBIC {delta_bic:.1} held {held_out_before:.3} → {held_out_after:.3} T60 {:.3} ρ/σ [{}] | {detail} {}",
                    if accepted { "ACCEPT" } else { "reject" },
                    params[0].value,
                    rho.join(", "),
                    signature_missing.unwrap_or_default()
                )
            }
        };
        println!(
            "{} {:<6} {line}",
            c.case,
            if truth { "REVERB" } else { "-" }
        );
    }
}
