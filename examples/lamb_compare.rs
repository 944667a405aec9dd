//! Compares the frequencies of a free solid sphere computed by `diffsound modes` (read from its
//! `--timings-json`) with Lamb's analytic ones (`diffsound::eigen::analytic::sphere_modes`), mode
//! by mode: the k-th computed frequency against the k-th analytic one, each degenerate cluster
//! of degree ℓ counted 2ℓ+1 times. Prints every mode's relative error and the largest.
//!
//! Run: `cargo run --release --example lamb_compare -- TIMINGS.json RADIUS E NU RHO`
//! (SI units; the sphere of `tests/data/analytic/sphere.geo` has radius 0.5 m).
use std::process::ExitCode;

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() != 5 {
        eprintln!("usage: lamb_compare TIMINGS.json RADIUS E NU RHO");
        return ExitCode::from(2);
    }
    let numbers: Result<Vec<f64>, _> = args[1..].iter().map(|a| a.parse::<f64>()).collect();
    let [radius, youngs, poisson, density] = match numbers.as_deref() {
        Ok(&[r, e, nu, rho]) => [r, e, nu, rho],
        _ => {
            eprintln!(
                "RADIUS, E, NU and RHO must be numbers, got {:?}",
                &args[1..]
            );
            return ExitCode::from(2);
        }
    };
    let text = match std::fs::read_to_string(&args[0]) {
        Ok(t) => t,
        Err(e) => {
            eprintln!("{}: {e}", args[0]);
            return ExitCode::from(1);
        }
    };
    let json: serde_json::Value = match serde_json::from_str(&text) {
        Ok(j) => j,
        Err(e) => {
            eprintln!("{}: not JSON: {e}", args[0]);
            return ExitCode::from(1);
        }
    };
    let Some(computed) = json["frequencies_hz"].as_array().map(|a| {
        a.iter()
            .filter_map(serde_json::Value::as_f64)
            .collect::<Vec<_>>()
    }) else {
        eprintln!("{}: no frequencies_hz array", args[0]);
        return ExitCode::from(1);
    };
    let f_top = computed.iter().copied().fold(0.0, f64::max) * 1.2;
    let mut analytic = Vec::new();
    for m in diffsound::eigen::analytic::sphere_modes(radius, youngs, poisson, density, f_top) {
        for _ in 0..m.multiplicity {
            analytic.push(m.clone());
        }
    }
    println!("mode  computed [Hz]     Lamb [Hz]         family ℓ   relative error");
    let mut worst: f64 = 0.0;
    for (i, (f, m)) in computed.iter().zip(&analytic).enumerate() {
        let err = (f - m.frequency_hz) / m.frequency_hz;
        worst = worst.max(err.abs());
        println!(
            "{i:>4}  {f:>14.6}  {:>14.6}   {:?} {}   {err:+.3e}",
            m.frequency_hz, m.family, m.degree
        );
    }
    println!(
        "{} modes compared; largest relative error {worst:.3e}",
        computed.len().min(analytic.len())
    );
    ExitCode::SUCCESS
}
