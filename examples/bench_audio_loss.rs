//! Times one loss-plus-gradient evaluation of the audio pipeline: render the predicted modal bank,
//! evaluate the loss against a fixed target with its gradient dL/ds, and map that back to the
//! bank's parameters (render_backward). `scripts/bench_audio.py` runs this side by side with the
//! same computation in PyTorch; it writes the problem file this example reads.
//!
//! Run: cargo run --release --example bench_audio_loss -- problem.json result.json [threads]
//!
//! problem.json: {"sample_rate": 48000, "n_samples": 48000, "repeats": 10,
//!                "loss": "spectral" | "transport",
//!                "target": BANK, "prediction": BANK}
//! with BANK = {"frequencies_hz": [..], "decay_rates": [..], "amplitudes": [..], "phases": [..]}.
//!
//! Threads: the third argument if given, else DIFFSOUND_THREADS, else the crate's default
//! (the machine's parallelism). The count used is reported. The target is rendered and the loss
//! built once, outside the timed loop; one untimed warm-up evaluation precedes the `repeats`
//! timed ones. Measures only; asserts nothing about time.
//!
//! With DIFFSOUND_BENCH_DUMP=DIR set, the target, the rendered prediction and dL/ds are also
//! written to DIR as raw little-endian f64 (target.f64, signal.f64, grad_signal.f64), untimed.
use diffsound::audio::loss::{
    MultiScaleSpectralLoss, SpectralLossConfig, TransportLoss, TransportLossConfig,
};
use diffsound::audio::synth::{
    render_backward, render_samples, set_worker_threads, worker_threads, BankGradient,
};
use diffsound::audio::ModalBank;
use std::time::Instant;

#[derive(serde::Deserialize)]
struct Bank {
    frequencies_hz: Vec<f64>,
    decay_rates: Vec<f64>,
    amplitudes: Vec<f64>,
    phases: Vec<f64>,
}

impl From<Bank> for ModalBank {
    fn from(b: Bank) -> ModalBank {
        ModalBank {
            frequencies_hz: b.frequencies_hz,
            decay_rates: b.decay_rates,
            amplitudes: b.amplitudes,
            phases: b.phases,
        }
    }
}

#[derive(serde::Deserialize)]
struct Problem {
    sample_rate: f64,
    n_samples: usize,
    repeats: usize,
    loss: String,
    target: Bank,
    prediction: Bank,
}

enum Loss {
    Spectral(MultiScaleSpectralLoss),
    Transport(TransportLoss),
}

impl Loss {
    fn value_and_gradient(&self, x: &[f64]) -> (f64, Vec<f64>) {
        match self {
            Loss::Spectral(l) => l.value_and_gradient(x),
            Loss::Transport(l) => l.value_and_gradient(x),
        }
        .expect("loss evaluation")
    }
}

/// One full evaluation: (loss, gradient, [render, loss, backward] seconds).
fn evaluate(loss: &Loss, bank: &ModalBank, rate: f64, n: usize) -> (f64, BankGradient, [f64; 3]) {
    let t0 = Instant::now();
    let x = render_samples(bank, rate, n);
    let t1 = Instant::now();
    let (value, grad_signal) = loss.value_and_gradient(&x);
    let t2 = Instant::now();
    let grad = render_backward(bank, rate, &grad_signal);
    let t3 = Instant::now();
    (
        value,
        grad,
        [
            (t1 - t0).as_secs_f64(),
            (t2 - t1).as_secs_f64(),
            (t3 - t2).as_secs_f64(),
        ],
    )
}

/// Writes the intermediate signals as raw little-endian f64 (target.f64, signal.f64 and
/// grad_signal.f64 = dL/ds), so a reference can be compared stage by stage on identical inputs.
fn dump_stages(
    dir: &std::path::Path,
    loss: &Loss,
    bank: &ModalBank,
    target: &[f64],
    rate: f64,
    n: usize,
) {
    let x = render_samples(bank, rate, n);
    let (_, g) = loss.value_and_gradient(&x);
    std::fs::create_dir_all(dir).expect("create the dump directory");
    for (name, v) in [
        ("target", target),
        ("signal", &x[..]),
        ("grad_signal", &g[..]),
    ] {
        let bytes: Vec<u8> = v.iter().flat_map(|f| f.to_le_bytes()).collect();
        std::fs::write(dir.join(format!("{name}.f64")), bytes).expect("write a dump file");
    }
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let m = s.len() / 2;
    if s.len() % 2 == 1 {
        s[m]
    } else {
        0.5 * (s[m - 1] + s[m])
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        eprintln!("usage: {} problem.json result.json [threads]", args[0]);
        std::process::exit(2);
    }
    if let Some(t) = args.get(3) {
        let t: usize = t.parse().expect("threads must be a non-negative integer");
        set_worker_threads(t);
    }
    let threads = worker_threads();
    let text = std::fs::read_to_string(&args[1]).expect("read the problem file");
    let p: Problem = serde_json::from_str(&text).expect("parse the problem file");
    let (rate, n) = (p.sample_rate, p.n_samples);
    let target_bank: ModalBank = p.target.into();
    let bank: ModalBank = p.prediction.into();

    let target = render_samples(&target_bank, rate, n);
    let loss = match p.loss.as_str() {
        "spectral" => Loss::Spectral(
            MultiScaleSpectralLoss::new(&target, SpectralLossConfig::default())
                .expect("spectral loss"),
        ),
        "transport" => Loss::Transport(
            TransportLoss::new(&target, rate, TransportLossConfig::default())
                .expect("transport loss"),
        ),
        other => panic!("unknown loss {other:?} (spectral | transport)"),
    };

    if let Ok(dir) = std::env::var("DIFFSOUND_BENCH_DUMP") {
        dump_stages(std::path::Path::new(&dir), &loss, &bank, &target, rate, n);
    }
    // Warm-up (page faults, FFT plans' first use); its result is the one reported.
    let (value, grad, _) = evaluate(&loss, &bank, rate, n);
    let mut totals = Vec::with_capacity(p.repeats);
    let mut parts: [Vec<f64>; 3] = Default::default();
    let mut deterministic = true;
    for _ in 0..p.repeats.max(1) {
        let (v, _, t) = evaluate(&loss, &bank, rate, n);
        deterministic &= v.to_bits() == value.to_bits();
        totals.push(1e3 * t.iter().sum::<f64>());
        for (acc, s) in parts.iter_mut().zip(t) {
            acc.push(1e3 * s);
        }
    }
    let min = totals.iter().copied().fold(f64::INFINITY, f64::min);
    let out = serde_json::json!({
        "loss": p.loss,
        "value": value,
        "threads": threads,
        "deterministic": deterministic,
        "n_modes": bank.len(),
        "n_samples": n,
        "sample_rate": rate,
        "repeats": totals.len(),
        "time_ms": {
            "median": median(&totals),
            "min": min,
            "all": totals,
            "render_median": median(&parts[0]),
            "loss_median": median(&parts[1]),
            "backward_median": median(&parts[2]),
        },
        "gradient": {
            "frequencies_hz": grad.frequencies_hz,
            "decay_rates": grad.decay_rates,
            "amplitudes": grad.amplitudes,
            "phases": grad.phases,
        },
    });
    std::fs::write(
        &args[2],
        serde_json::to_string_pretty(&out).expect("serialise"),
    )
    .expect("write the result file");
    eprintln!(
        "{}: value {:.12e}, {} threads, median {:.2} ms, min {:.2} ms over {} repeats",
        p.loss,
        value,
        threads,
        median(&totals),
        min,
        totals.len()
    );
}
