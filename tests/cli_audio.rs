//! End-to-end runs of `diffsound render` and `diffsound spectrogram`: the WAV written by the
//! command line equals the synthesiser driven by hand from the same modes file, and bad input
//! fails with a message and no output file.

mod common;
use common::*;
use diffsound::audio::chain::{DampingModel, ModalChain, Strike};
use diffsound::audio::excitation::{ContactForce, Response};
use diffsound::mesh::{ElementOrder, TetMesh};
use std::path::PathBuf;
use std::process::Command;
use std::sync::OnceLock;
use std::time::Duration;

const LIMIT: Duration = Duration::from_secs(240);

/// Modes of the small cube fixture, computed once for all tests here.
fn cube_modes() -> PathBuf {
    static PATH: OnceLock<PathBuf> = OnceLock::new();
    PATH.get_or_init(|| {
        let dir = scratch("cli_audio_modes");
        let out = dir.join("cube.h5");
        let run = mpirun(
            2,
            &[
                "modes",
                "--mesh",
                s(&fixture("mesh/cube_tet4_msh22_ascii.msh")),
                "--modes",
                "12",
                "--material",
                "aluminium",
                "--out",
                s(&out),
            ],
            LIMIT,
        );
        assert!(run.success(), "{}", run.describe());
        out
    })
    .clone()
}

fn diffsound(args: &[&str]) -> Run {
    let mut cmd = Command::new(binary());
    cmd.args(args);
    run_with_limit(cmd, LIMIT)
}

#[test]
fn render_writes_what_the_synthesiser_gives_for_the_same_strike() {
    let modes = cube_modes();
    let dir = scratch("cli_render");
    let wav = dir.join("strike.wav");
    let position = [0.31, 0.12, 1.05]; // just off a face of the unit cube; metres
    let run = diffsound(&[
        "render",
        "--modes",
        s(&modes),
        "--out",
        s(&wav),
        "--position",
        "0.31,0.12,1.05",
        "--direction",
        "0,0,-2",
        "--force",
        "half-sine:0.0002",
        "--response",
        "velocity",
        "--alpha",
        "3",
        "--beta",
        "2e-7",
        "--duration",
        "0.25",
        "--sample-rate",
        "32000",
        "--normalise",
        "none",
        "--format",
        "float32",
    ]);
    assert!(run.success(), "{}", run.describe());
    let (channels, rate) = diffsound::audio::read_wav(&wav).unwrap();
    assert_eq!(rate, 32000);
    assert_eq!(channels[0].len(), 8000);

    let file = diffsound::io::read_modes(&modes).unwrap();
    let mesh = TetMesh {
        nodes: file.nodes.clone(),
        connectivity: file.connectivity.clone(),
        order: ElementOrder::Quadratic,
    };
    let point = mesh.closest_surface_point(position).unwrap();
    assert!(
        (point.position[2] - 1.0).abs() < 1e-9,
        "projected onto the top face: {point:?}"
    );
    let projections: Vec<f64> = file
        .mode_shapes
        .iter()
        .map(|u| -mesh.interpolate_vector(u, &point)[2])
        .collect();
    let strike = Strike {
        force: ContactForce::HalfSine { duration_s: 2e-4 },
        response: Response::Velocity,
    };
    let (bank, _) = ModalChain::new(
        &file.eigenvalues,
        &projections,
        &DampingModel::Rayleigh {
            alpha: 3.0,
            beta: 2e-7,
        },
        &strike,
    )
    .unwrap();
    let expected = diffsound::audio::render(&bank, 32000.0, 0.25);
    let peak = expected.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    assert!(peak > 0.0);
    let worst = channels[0]
        .iter()
        .zip(&expected)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    // float32 storage: 6e-8 relative.
    assert!(
        worst < 1e-6 * peak,
        "CLI and library differ by {worst:e} (peak {peak:e})"
    );
}

#[test]
fn render_defaults_to_a_normalised_16_bit_strike_at_a_rim_vertex() {
    let modes = cube_modes();
    let dir = scratch("cli_render_default");
    let wav = dir.join("default.wav");
    let run = diffsound(&[
        "render",
        "--modes",
        s(&modes),
        "--out",
        s(&wav),
        "--duration",
        "0.5",
    ]);
    assert!(run.success(), "{}", run.describe());
    assert!(run.stdout.contains("modes audible"), "{}", run.stdout);
    let (channels, rate) = diffsound::audio::read_wav(&wav).unwrap();
    assert_eq!((rate, channels[0].len()), (48000, 24000));
    let peak = channels[0].iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    assert!((peak - 0.9).abs() < 1e-3, "peak {peak}");
}

#[test]
fn render_rejects_bad_input_and_writes_nothing() {
    let modes = cube_modes();
    let dir = scratch("cli_render_bad");
    let wav = dir.join("never.wav");
    let cases: [(&[&str], &str); 7] = [
        (&["--position", "40,40,40"], "from the surface"),
        (&["--vertex", "999999"], "not a surface corner node"),
        (&["--force", "half-sine:-1"], "half-sine duration"),
        (&["--duration", "0"], "--duration"),
        (&["--direction", "0,0,0"], "zero vector"),
        (&["--normalise", "2"], "--normalise"),
        (
            &["--damping-curve", "/nonexistent/curve.toml"],
            "curve.toml",
        ),
    ];
    for (extra, expected) in cases {
        let mut args = vec!["render", "--modes", s(&modes), "--out", s(&wav)];
        args.extend_from_slice(extra);
        let run = diffsound(&args);
        assert!(
            !run.success() && run.status.is_some(),
            "{extra:?} should fail cleanly: {}",
            run.describe()
        );
        assert!(
            run.stderr.contains(expected),
            "{extra:?}: expected {expected:?} in\n{}",
            run.stderr
        );
        assert!(!wav.exists(), "{extra:?} left a file");
    }
    let missing = diffsound(&[
        "render",
        "--modes",
        "/nonexistent/modes.h5",
        "--out",
        s(&wav),
    ]);
    assert_eq!(missing.status, Some(1), "{}", missing.describe());
    assert!(missing.stderr.contains("modes.h5"));
}

#[test]
fn render_with_a_damping_curve() {
    let modes = cube_modes();
    let dir = scratch("cli_render_curve");
    let curve = dir.join("curve.toml");
    std::fs::write(
        &curve,
        "frequencies_hz = [1000.0, 10000.0]\ndecay_rates = [5.0, 50.0]\n",
    )
    .unwrap();
    let wav = dir.join("curve.wav");
    let run = diffsound(&[
        "render",
        "--modes",
        s(&modes),
        "--out",
        s(&wav),
        "--damping-curve",
        s(&curve),
        "--duration",
        "0.3",
    ]);
    assert!(run.success(), "{}", run.describe());
    std::fs::write(
        &curve,
        "frequencies_hz = [1000.0, 500.0]\ndecay_rates = [5.0, 50.0]\n",
    )
    .unwrap();
    let bad = diffsound(&[
        "render",
        "--modes",
        s(&modes),
        "--out",
        s(&dir.join("bad.wav")),
        "--damping-curve",
        s(&curve),
    ]);
    assert_eq!(bad.status, Some(1));
    assert!(
        bad.stderr.contains("frequencies must increase"),
        "{}",
        bad.stderr
    );
}

#[test]
fn spectrogram_of_a_render_against_the_bowl_recording() {
    let dir = scratch("cli_spectrogram");
    let rendered = dir.join("tone.wav");
    let fs = 48000u32;
    let tone: Vec<f64> = (0..24000)
        .map(|n| {
            (-(n as f64) / 8000.0).exp()
                * (2.0 * std::f64::consts::PI * 1650.0 * n as f64 / fs as f64).sin()
        })
        .collect();
    diffsound::audio::write_wav(
        &rendered,
        &tone,
        fs,
        diffsound::audio::WavFormat::Pcm16,
        Some(0.9),
    )
    .unwrap();
    let png = dir.join("side_by_side.png");
    let mic = repo().join("examples/bowl/mic0.wav");
    let run = diffsound(&[
        "spectrogram",
        s(&rendered),
        s(&mic),
        "--trim-onset",
        "--duration",
        "1",
        "--fmax",
        "8000",
        "--titles",
        "tone,mic0",
        "--out",
        s(&png),
    ]);
    assert!(run.success(), "{}", run.describe());
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&png).unwrap()));
    let reader = decoder.read_info().unwrap();
    let info = reader.info();
    assert!(
        info.width > 2 * 480 && info.height > 320,
        "two panels: {}x{}",
        info.width,
        info.height
    );

    let garbage = dir.join("garbage.wav");
    std::fs::write(&garbage, b"not a wav file").unwrap();
    let out = dir.join("never.png");
    let bad = diffsound(&["spectrogram", s(&garbage), "--out", s(&out)]);
    assert_eq!(bad.status, Some(1), "{}", bad.describe());
    assert!(bad.stderr.contains("garbage.wav"), "{}", bad.stderr);
    assert!(!out.exists());
    let bad_channel = diffsound(&[
        "spectrogram",
        s(&rendered),
        "--channel",
        "3",
        "--out",
        s(&out),
    ]);
    assert!(
        bad_channel.stderr.contains("no channel 3"),
        "{}",
        bad_channel.stderr
    );
    // A format we do not write fails up front, before the (unreadable) input is read, and
    // leaves nothing behind.
    let pdf = dir.join("x.pdf");
    let bad_format = diffsound(&["spectrogram", s(&garbage), "--out", s(&pdf)]);
    assert_eq!(bad_format.status, Some(1), "{}", bad_format.describe());
    assert!(
        bad_format.stderr.contains("x.pdf")
            && bad_format.stderr.contains(".png")
            && !bad_format.stderr.contains("garbage.wav"),
        "{}",
        bad_format.stderr
    );
    assert!(!pdf.exists());
}
