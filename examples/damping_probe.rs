//! Stage 1 on the real bowl: damping from the eight-microphone recording.
//!
//! `cargo run --release --example damping_probe [duration_s] [steps] [skip_s] [max_modes] [out.json]`
//! (defaults 1 s, the fit's default steps, skip and mode count; with a fifth argument the
//! whole fit is written there as JSON).
use diffsound::analysis::recording::{load_recording, RecordingOptions};
use diffsound::inverse::damping::{fit_damping, DampingFitSettings, ModeVerdict};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let arg = |i: usize| {
        args.get(i)
            .map(|s| s.parse::<f64>().expect("numeric argument"))
    };
    let duration = arg(1).unwrap_or(1.0);
    let mut settings = DampingFitSettings::default();
    if let Some(steps) = arg(2) {
        settings.steps = steps as usize;
    }
    if let Some(skip) = arg(3) {
        settings.estimate_skip_s = skip;
    }
    if let Some(modes) = arg(4) {
        settings.max_modes = modes as usize;
    }
    let paths: Vec<String> = (0..8)
        .map(|i| format!("examples/bowl/mic{i}.wav"))
        .collect();
    // The files hold ~1 s before the strike: cut at the detected onset, keep `duration` s.
    let options = RecordingOptions {
        pre_roll_s: 0.0,
        duration_s: Some(duration),
        ..RecordingOptions::default()
    };
    let recording = load_recording(&paths, &options).expect("loading the bowl recording");
    let fs = f64::from(recording.sample_rate);
    println!(
        "bowl: {} channels × {} samples at {fs} Hz, onset {:.4} s, gain {:.2}",
        recording.channels.len(),
        recording.channels[0].len(),
        recording.onset_s,
        recording.gain
    );
    let started = std::time::Instant::now();
    let fit = fit_damping(&recording.channels, fs, &settings, |s| {
        if s.step % 25 == 0 {
            println!(
                "  step {:4}  loss {:.5}  {:.1} s",
                s.step, s.loss, s.elapsed_s
            );
        }
    })
    .expect("damping fit");
    let total = started.elapsed().as_secs_f64();
    let count = |v: ModeVerdict| fit.modes.iter().filter(|m| m.verdict().reason == v).count();
    println!(
        "modes: {} estimated, {} refined, {} kept in {} of {} peaks; rejected: {} too fast, {} too slow, {} low SNR, {} weak, {} in peaks off the curve",
        fit.n_estimated,
        fit.modes.len(),
        fit.kept().count(),
        fit.kept_peaks().count(),
        fit.peaks.len(),
        count(ModeVerdict::DecayTooFast),
        count(ModeVerdict::DecayTooSlow),
        count(ModeVerdict::LowSnr),
        count(ModeVerdict::Weak),
        count(ModeVerdict::OffCurve)
    );
    println!(
        "loss: estimate alone {:.5}, estimate + initial noise {:.5}, refined {:.5} (best step {})",
        fit.loss_initial, fit.history[0].loss, fit.loss_final, fit.best_step
    );
    println!(
        "time: estimate {:.2} s, refinement {:.1} s ({:.3} s/step, {} steps), total {:.1} s",
        fit.estimate_seconds,
        fit.refine_seconds,
        fit.seconds_per_step,
        fit.history.len() - 1,
        total
    );
    println!("curve (rms ln error {:.3}):", fit.curve_rms_log_error);
    for (f, t) in fit.curve.frequencies_hz.iter().zip(&fit.curve.log_decay) {
        println!("  {f:9.1} Hz  d = {:8.3} 1/s", t.exp());
    }
    let r = fit.rayleigh;
    println!(
        "Rayleigh: α = {:.4} 1/s, β = {:.4e} s (rms ln error {:.3})",
        r.alpha, r.beta, r.rms_log_error
    );
    println!(
        "first 20 kept peaks (d: of the peak's energy-decay curve; members: f, d of each mode):"
    );
    for p in fit.kept_peaks().take(20) {
        let members: Vec<String> = p
            .members
            .iter()
            .map(|&k| {
                format!(
                    "{:.1}/{:.1}",
                    fit.modes[k].frequency_hz, fit.modes[k].decay_rate
                )
            })
            .collect();
        println!(
            "  {:9.2} Hz  d {:7.3}  curve {:7.3}  {:6.1} dB  SNR {:5.1}  [{}]",
            p.frequency_hz,
            p.decay_rate,
            fit.curve.decay(p.undamped_frequency_hz),
            p.level_db,
            p.snr_db,
            members.join(" ")
        );
    }
    let modes: Vec<String> = fit
        .kept()
        .take(20)
        .map(|m| format!("{:.1}/{:.2}", m.frequency_hz, m.decay_rate))
        .collect();
    println!("first 20 kept modes (f Hz/d 1/s): {}", modes.join(" "));
    if let Some(path) = args.get(5) {
        std::fs::write(path, serde_json::to_string_pretty(&fit).expect("JSON"))
            .expect("writing the JSON");
        println!("fit written to {path}");
    }
}
