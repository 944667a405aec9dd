//! Realistic mistakes, on 2 ranks, each ending at once with a message that names the cause
//! and no output file (issue 41): outputs that cannot be written or would destroy an input,
//! a band past a recording's Nyquist frequency, and dead, noise-only or late microphones.
//! Every refusal here happens before any solve, so each takes seconds. Recordings that are
//! readable but hold too few modes are not an error: the diagnosis says so in its report.

mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

const LIMIT: Duration = Duration::from_secs(120);

fn bowl_wav(i: usize) -> PathBuf {
    repo().join("examples/bowl").join(format!("mic{i}.wav"))
}

/// A mono float WAV at `rate` Hz.
fn write_wav(path: &Path, x: &[f64], rate: u32) {
    let spec = hound::WavSpec {
        channels: 1,
        sample_rate: rate,
        bits_per_sample: 32,
        sample_format: hound::SampleFormat::Float,
    };
    let mut w = hound::WavWriter::create(path, spec).unwrap();
    for v in x {
        w.write_sample(*v as f32).unwrap();
    }
    w.finalize().unwrap();
}

fn read_wav(path: &Path) -> (Vec<f64>, u32) {
    let mut r = hound::WavReader::open(path).unwrap();
    let spec = r.spec();
    let x: Vec<f64> = match spec.sample_format {
        hound::SampleFormat::Float => r.samples::<f32>().map(|v| f64::from(v.unwrap())).collect(),
        hound::SampleFormat::Int => {
            let scale = (1i64 << (spec.bits_per_sample - 1)) as f64;
            r.samples::<i32>()
                .map(|v| f64::from(v.unwrap()) / scale)
                .collect()
        }
    };
    (x, spec.sample_rate)
}

/// Runs and asserts a refusal: non-zero exit within `seconds`, every `needles` in stderr, and
/// no `out`.
fn refused(args: &[&str], needles: &[&str], out: &Path, seconds: f64) {
    let started = Instant::now();
    let run = mpirun(2, args, LIMIT);
    let took = started.elapsed().as_secs_f64();
    assert!(
        !run.success() && !run.timed_out,
        "must be refused:\n{}",
        run.describe()
    );
    for n in needles {
        assert!(
            run.stderr.contains(n),
            "the message must say {n:?}:\n{}",
            run.describe()
        );
    }
    assert!(!out.exists(), "no output may be written: {}", out.display());
    assert!(took < seconds, "the refusal took {took:.1} s");
    // Bad input is met by every rank together: the job ends with the message, not with
    // MPI_Abort's screen.
    assert!(!run.stderr.contains("MPI_ABORT"), "{}", run.describe());
    println!(
        "refused in {took:.1} s: {}",
        run.stderr
            .lines()
            .find(|l| l.contains("rror"))
            .unwrap_or("")
    );
}

#[test]
fn outputs_are_checked_before_the_work() {
    let dir = scratch("bad_outputs");
    let mesh = dir.join("bowl.msh");
    std::fs::copy(bowl_mesh(), &mesh).unwrap();
    let before = std::fs::read(&mesh).unwrap();
    let out = dir.join("out.h5");
    // --out naming the input mesh.
    refused(
        &[
            "modes",
            "--mesh",
            s(&mesh),
            "--modes",
            "5",
            "--out",
            s(&mesh),
        ],
        &["also an input of this job (the mesh)"],
        &dir.join("never.h5"),
        20.0,
    );
    assert_eq!(
        std::fs::read(&mesh).unwrap(),
        before,
        "the mesh must be untouched"
    );
    // --out naming a directory; a folder that takes no file; a timings file in a missing folder.
    refused(
        &[
            "modes",
            "--mesh",
            s(&mesh),
            "--modes",
            "5",
            "--out",
            s(&dir),
        ],
        &["is a directory"],
        &out,
        20.0,
    );
    refused(
        &[
            "modes",
            "--mesh",
            s(&mesh),
            "--modes",
            "5",
            "--out",
            "/proc/diffsound_modes.h5",
        ],
        &["cannot write /proc/diffsound_modes.h5"],
        Path::new("/proc/diffsound_modes.h5"),
        20.0,
    );
    let missing = dir.join("no_such_folder").join("t.json");
    refused(
        &[
            "modes",
            "--mesh",
            s(&mesh),
            "--modes",
            "5",
            "--out",
            s(&out),
            "--timings-json",
            s(&missing),
        ],
        &["does not exist"],
        &out,
        20.0,
    );
    // A diagnosis whose --out is one of its recordings.
    let wav = dir.join("mic0.wav");
    std::fs::copy(bowl_wav(0), &wav).unwrap();
    refused(
        &[
            "diagnose",
            "--mesh",
            s(&mesh),
            "--recording",
            s(&wav),
            "--recording",
            s(&bowl_wav(1)),
            "--density",
            "2400",
            "--out",
            s(&wav),
        ],
        &["also an input of this job (a recording)"],
        &out,
        20.0,
    );
    assert!(
        read_wav(&wav).0.len() > 1000,
        "the recording must be untouched"
    );
}

#[test]
fn a_band_past_a_recordings_nyquist_is_refused_with_the_file_named() {
    let dir = scratch("bad_nyquist");
    // The bowl's first microphone decimated to 8 kHz (every sixth sample of 48 kHz: aliased,
    // as a careless export would be).
    let (x, rate) = read_wav(&bowl_wav(0));
    assert_eq!(rate, 48_000);
    let low: Vec<f64> = x.iter().step_by(6).copied().collect();
    let (a, b) = (dir.join("low0.wav"), dir.join("low1.wav"));
    write_wav(&a, &low, 8000);
    write_wav(&b, &low, 8000);
    let out = dir.join("fit.h5");
    refused(
        &[
            "fit-material",
            "--mesh",
            s(&bowl_mesh()),
            "--recording",
            s(&a),
            "--recording",
            s(&b),
            "--density",
            "2400",
            "--youngs",
            "7e10",
            "--poisson",
            "0.2",
            "--fmax",
            "6000",
            "--out",
            s(&out),
        ],
        &["low0.wav", "Nyquist frequency 4000 Hz", "--fmax"],
        &out,
        30.0,
    );
    let out = dir.join("diagnosis.h5");
    refused(
        &[
            "diagnose",
            "--mesh",
            s(&bowl_mesh()),
            "--recording",
            s(&a),
            "--recording",
            s(&b),
            "--density",
            "2400",
            "--fmax",
            "6000",
            "--out",
            s(&out),
        ],
        &["low0.wav", "Nyquist frequency 4000 Hz"],
        &out,
        30.0,
    );
}

#[test]
fn no_microphone_with_the_strike_is_refused_with_every_file_named() {
    let dir = scratch("bad_channels");
    let n = read_wav(&bowl_wav(0)).0.len();
    let (silent, hiss) = (dir.join("silent.wav"), dir.join("hiss.wav"));
    write_wav(&silent, &vec![0.0; n], 48_000);
    let mut state = 7u64;
    let noise: Vec<f64> = (0..n)
        .map(|_| {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            0.01 * (((state >> 11) as f64 / (1u64 << 53) as f64) - 0.5)
        })
        .collect();
    write_wav(&hiss, &noise, 48_000);
    let out = dir.join("impact.h5");
    let run = mpirun(
        2,
        &[
            "locate-impact",
            "--mesh",
            s(&bowl_mesh()),
            "--recording",
            s(&silent),
            "--recording",
            s(&hiss),
            "--density",
            "2400",
            "--youngs",
            "7e10",
            "--poisson",
            "0.2",
            "--out",
            s(&out),
        ],
        LIMIT,
    );
    assert!(!run.success() && !run.timed_out, "{}", run.describe());
    assert!(!out.exists());
    println!(
        "{}",
        run.stderr
            .lines()
            .filter(|l| l.contains("rror") || l.contains("strike"))
            .collect::<Vec<_>>()
            .join("\n")
    );
    assert!(
        run.stderr.contains("silent") || run.stderr.contains("hiss"),
        "the files must be named:\n{}",
        run.describe()
    );
}

/// A curved 10-node tet whose map folds over (a mid-edge node pushed across the element, as a
/// second-order Gmsh mesh of a thin curved part can make): refused before any assembly with
/// the file and the Gmsh element tag named and both ways forward; with `--straighten-invalid`
/// it runs, and the straightening is reported.
#[test]
fn a_folded_curved_tet_is_named_by_its_gmsh_tag_and_straightened_on_request() {
    let dir = scratch("bad_folded");
    let mesh = folded_mesh(&dir);
    let out = dir.join("folded_modes.h5");
    refused(
        &[
            "modes",
            "--mesh",
            s(&mesh),
            "--modes",
            "5",
            "--out",
            s(&out),
        ],
        &[
            "folded.msh",
            "fold over",
            "Gmsh element tags 4287",
            "--straighten-invalid",
            "gmsh -optimize_ho",
        ],
        &out,
        20.0,
    );
    let run = mpirun(
        2,
        &[
            "modes",
            "--mesh",
            s(&mesh),
            "--modes",
            "5",
            "--out",
            s(&out),
            "--straighten-invalid",
        ],
        LIMIT,
    );
    assert!(run.success(), "{}", run.describe());
    assert!(
        run.stderr
            .contains("straightened 1 folded curved tetrahedra (1 mid-edge nodes moved"),
        "{}",
        run.stderr
    );
    assert!(out.exists());
    // The same from a configuration file's `straighten_invalid` key.
    let config = dir.join("straighten.toml");
    std::fs::write(
        &config,
        "mesh = \"folded.msh\"\nstraighten_invalid = true\n",
    )
    .unwrap();
    let out = dir.join("folded_modes_config.h5");
    let run = mpirun(
        2,
        &[
            "modes",
            "--config",
            s(&config),
            "--modes",
            "5",
            "--out",
            s(&out),
        ],
        LIMIT,
    );
    assert!(run.success(), "{}", run.describe());
    assert!(
        run.stderr.contains("straightened 1 folded curved"),
        "{}",
        run.stderr
    );
}

/// A folded curved mesh: one 10-node tet, Gmsh tag 4287, whose mid-edge node of
/// edge (0,1) is pushed across the element.
fn folded_mesh(dir: &Path) -> PathBuf {
    let mesh = dir.join("folded.msh");
    std::fs::write(
        &mesh,
        "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n10\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 0.5 0.9 0.9\n6 0.5 0.5 0\n7 0 0.5 0\n8 0 0 0.5\n9 0 0.5 0.5\n10 0.5 0 0.5\n$EndNodes\n$Elements\n1\n4287 11 2 0 1 1 2 3 4 5 6 7 8 9 10\n$EndElements\n",
    )
    .unwrap();
    mesh
}

/// Every job that assembles a mesh it reads (not only `modes`) refuses folded curved tets
/// with the file, the Gmsh tag and both ways forward, before the recordings are analysed.
#[test]
fn every_job_that_assembles_a_mesh_refuses_folded_curved_tets_by_gmsh_tag() {
    let dir = scratch("bad_folded_jobs");
    let mesh = folded_mesh(&dir);
    let needles = [
        "folded.msh",
        "fold over",
        "Gmsh element tags 4287",
        "--straighten-invalid",
        "gmsh -optimize_ho",
    ];
    for job in ["diagnose", "fit-material", "locate-impact"] {
        let out = dir.join(format!("{job}.h5"));
        refused(
            &[
                job,
                "--mesh",
                s(&mesh),
                "--recording",
                s(&bowl_wav(0)),
                "--recording",
                s(&bowl_wav(1)),
                "--density",
                "2400",
                "--youngs",
                "7e10",
                "--poisson",
                "0.2",
                "--out",
                s(&out),
            ],
            &needles,
            &out,
            30.0,
        );
    }
}

/// The shape fits refuse an output that is one of their inputs (a surface, the target file),
/// as the other jobs do, and leave the input untouched.
#[test]
fn shape_fit_outputs_may_not_overwrite_their_inputs() {
    let dir = scratch("bad_shape_outputs");
    let surface = box_obj(&dir, "box.obj", [1.0, 0.8, 0.6]);
    let other = box_obj(&dir, "other.obj", [1.0, 1.0, 0.5]);
    let before = std::fs::read(&surface).unwrap();
    let never = dir.join("never.h5");
    refused(
        &[
            "fit-thickness",
            "--surface",
            s(&surface),
            "--target-thickness",
            "0.5",
            "--out",
            s(&surface),
        ],
        &["box.obj", "also an input of this job (the surface)"],
        &never,
        20.0,
    );
    refused(
        &[
            "fit-morph",
            "--shape-a",
            s(&surface),
            "--shape-b",
            s(&other),
            "--target-weight",
            "0.4",
            "--out",
            s(&other),
        ],
        &["other.obj", "also an input of this job (shape B)"],
        &never,
        20.0,
    );
    let target = dir.join("target.txt");
    std::fs::write(
        &target,
        "1000 1200 1500 1800 2000 2300 2600 2900 3200 3500\n",
    )
    .unwrap();
    refused(
        &[
            "fit-thickness",
            "--surface",
            s(&surface),
            "--target",
            s(&target),
            "--out",
            s(&target),
        ],
        &["target.txt", "also an input of this job (the target)"],
        &never,
        20.0,
    );
    refused(
        &[
            "fit-geometry",
            "--surface",
            s(&surface),
            "--out",
            s(&surface),
        ],
        &["box.obj", "also an input of this job (the surface)"],
        &never,
        20.0,
    );
    assert_eq!(std::fs::read(&surface).unwrap(), before);
    assert_eq!(
        std::fs::read_to_string(&target).unwrap(),
        "1000 1200 1500 1800 2000 2300 2600 2900 3200 3500\n"
    );
}

/// A write that fails after the work (here the file size limit, `ulimit -f 64` in the ranks'
/// shell, as a disk filling during the run would) is one line naming the final path and the
/// cause, and leaves neither the file nor a hidden temporary. The ranks talk over TCP: the
/// limit would also stop OpenMPI's shared-memory segment.
#[test]
fn a_write_that_fails_after_the_work_names_the_output_and_the_cause() {
    let dir = scratch("bad_write_late");
    let out = dir.join("cube.h5");
    let mut cmd = std::process::Command::new("mpirun");
    cmd.args(["--mca", "btl", "self,tcp", "-np", "2", "sh", "-c"])
        .arg("ulimit -f 64; exec \"$0\" \"$@\"")
        .arg(binary())
        .args([
            "modes",
            "--mesh",
            s(&fixture("mesh/cube_tet4_msh22_ascii.msh")),
            "--modes",
            "5",
            "--out",
            s(&out),
        ]);
    let started = Instant::now();
    let run = run_with_limit(cmd, LIMIT);
    let took = started.elapsed().as_secs_f64();
    assert!(!run.success() && !run.timed_out, "{}", run.describe());
    let line = format!(
        "error: cannot write {}: file too large for the process's file size limit (`ulimit -f`)",
        out.display()
    );
    assert!(run.stderr.contains(&line), "{}", run.describe());
    assert!(!run.stderr.contains(".tmp."), "{}", run.describe());
    let left: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert!(left.is_empty(), "nothing may be left: {left:?}");
    println!("refused in {took:.1} s: {line}");
}

/// The bowl's first microphone as a float WAV with `bad` at sample `at`.
fn bowl_wav_with(dir: &Path, name: &str, at: usize, bad: f64) -> PathBuf {
    let (mut x, rate) = read_wav(&bowl_wav(0));
    x[at] = bad;
    let path = dir.join(name);
    write_wav(&path, &x, rate);
    path
}

/// A float WAV holding NaN or ∞ is refused where WAVs are read, naming the file and the first
/// bad sample: the spectrogram (which drew it black) and a 2-rank job.
#[test]
fn a_float_wav_with_nan_samples_is_refused_naming_the_first() {
    let dir = scratch("bad_nan_wav");
    let nan = bowl_wav_with(&dir, "nan.wav", 4800, f64::NAN);
    let inf = bowl_wav_with(&dir, "inf.wav", 9600, f64::INFINITY);
    let png = dir.join("spec.png");
    let mut cmd = std::process::Command::new(binary());
    cmd.args(["spectrogram", s(&nan), "--out", s(&png)]);
    let run = run_with_limit(cmd, LIMIT);
    assert_eq!(run.status, Some(1), "{}", run.describe());
    assert!(
        run.stderr
            .contains("nan.wav: holds NaN or infinite samples (1 in all), the first (NaN) at sample 4800 of channel 0 (0.100000 s)"),
        "{}",
        run.describe()
    );
    assert!(!png.exists());
    println!("spectrogram: {}", run.stderr.trim());
    let out = dir.join("fit.h5");
    refused(
        &[
            "fit-material",
            "--mesh",
            s(&bowl_mesh()),
            "--recording",
            s(&bowl_wav(1)),
            "--recording",
            s(&inf),
            "--density",
            "2400",
            "--youngs",
            "7e10",
            "--poisson",
            "0.2",
            "--out",
            s(&out),
        ],
        &["inf.wav", "(inf) at sample 9600", "0.200000 s", "re-export"],
        &out,
        30.0,
    );
}

/// The state letter of process `pid` from /proc (`T`: stopped).
fn process_state(pid: u32) -> Option<char> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    stat.rsplit_once(')')?.1.trim_start().chars().next()
}

/// The child processes of `parent` with their MPI rank (from their environment).
fn ranks_of(parent: u32) -> Vec<(usize, u32)> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(pid) = entry.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else {
            continue;
        };
        let ppid = stat
            .rsplit_once(')')
            .and_then(|(_, rest)| rest.split_whitespace().nth(1))
            .and_then(|p| p.parse::<u32>().ok());
        if ppid != Some(parent) {
            continue;
        }
        let env = std::fs::read(format!("/proc/{pid}/environ")).unwrap_or_default();
        let rank = env
            .split(|&b| b == 0)
            .filter_map(|v| std::str::from_utf8(v).ok())
            .find_map(|v| v.strip_prefix("OMPI_COMM_WORLD_RANK="))
            .and_then(|r| r.parse().ok());
        if let Some(rank) = rank {
            found.push((rank, pid));
        }
    }
    found.sort();
    found
}

/// A rank stopped with SIGSTOP in the middle of a solve: the other rank's watchdog ends the job
/// after `--rank-timeout` with a line naming the stopped rank, instead of spinning forever.
#[test]
fn a_stopped_rank_ends_the_job_after_the_rank_timeout_naming_it() {
    use std::io::{BufRead, BufReader};
    use std::process::{Command, Stdio};
    let dir = scratch("bad_stopped_rank");
    let out = dir.join("bowl.h5");
    let mut child = Command::new("mpirun")
        .args(["-np", "2"])
        .arg(binary())
        .args([
            "modes",
            "--mesh",
            s(&bowl_mesh()),
            "--modes",
            "20",
            "--out",
            s(&out),
            "--rank-timeout",
            "5",
            "--verbose",
        ])
        .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .env("OPENBLAS_NUM_THREADS", "1")
        .env("OMPI_MCA_btl", "self,vader")
        .current_dir(repo())
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn mpirun");
    let mpirun_pid = child.id();
    // Rank 0 prints its first progress line after start-up (watchdog armed on every rank).
    let (tx, rx) = std::sync::mpsc::channel::<String>();
    let stderr = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    let mut log = Vec::new();
    let launched = Instant::now();
    while launched.elapsed() < LIMIT {
        match rx.recv_timeout(Duration::from_millis(100)) {
            Ok(line) => {
                let started = line.contains("reading");
                log.push(line);
                if started {
                    break;
                }
            }
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {}
            Err(_) => break,
        }
    }
    let ranks = ranks_of(mpirun_pid);
    assert_eq!(ranks.len(), 2, "two ranks under mpirun: {ranks:?}\n{log:?}");
    let stopped = ranks[1].1;
    let signal = |sig: &str, pid: u32| {
        let _ = Command::new("kill").args([sig, &pid.to_string()]).status();
    };
    signal("-STOP", stopped);
    let stopped_at = Instant::now();
    let status = loop {
        if let Some(st) = child.try_wait().unwrap() {
            break Some(st);
        }
        if stopped_at.elapsed() > Duration::from_secs(60) {
            break None;
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let took = stopped_at.elapsed().as_secs_f64();
    if status.is_none() {
        // Clean up before failing: resume and end our own processes.
        for (_, pid) in &ranks {
            signal("-CONT", *pid);
        }
        let _ = child.kill();
        let _ = child.wait();
    }
    reader.join().unwrap();
    log.extend(rx.try_iter());
    let text = log.join("\n");
    assert!(status.is_some(), "the job must end, not hang:\n{text}");
    assert!(!status.unwrap().success(), "{text}");
    assert!(
        text.contains(&format!("error (rank 0 of 2): rank 1 (pid {stopped} on "))
            && text.contains("has been stopped for 5 s (SIGSTOP)")
            && text.contains(&format!("kill -CONT {stopped}")),
        "{text}"
    );
    assert!(took < 30.0, "the job ended {took:.1} s after the stop");
    assert!(!out.exists());
    // mpirun ends the stopped rank too.
    let gone = Instant::now();
    while matches!(process_state(stopped), Some(c) if c != 'Z')
        && gone.elapsed() < Duration::from_secs(10)
    {
        std::thread::sleep(Duration::from_millis(100));
    }
    let state = process_state(stopped);
    if matches!(state, Some(c) if c != 'Z') {
        signal("-KILL", stopped);
    }
    assert!(
        matches!(state, None | Some('Z')),
        "the stopped rank must be ended too (state {state:?})"
    );
    println!(
        "ended {took:.1} s after the stop: {}",
        text.lines()
            .find(|l| l.contains("has been stopped"))
            .unwrap_or("")
    );
}

/// A microphone that hears the strike only below about 6 kHz (the bowl's first track through a
/// 6 kHz low-pass, over a fresh white floor 20 dB under its own) is kept, with a warning naming it, when
/// the band reaches 16 kHz; the untouched second track reaches the band's top and is not
/// warned about. Checked on the library's loading path that every job takes.
#[test]
fn a_band_whose_top_is_only_noise_is_warned_about_naming_the_file() {
    use diffsound::analysis::recording::{load_recording, RecordingOptions};
    use diffsound::audio::health::{assess_recording, band_warnings};
    let dir = scratch("band_floor");
    let (x, rate) = read_wav(&bowl_wav(0));
    // Windowed-sinc low-pass, 6 kHz, 511 taps (Blackman: stop band under −70 dB past 6.5 kHz).
    let taps = 511usize;
    let fc = 6000.0 / f64::from(rate);
    let h: Vec<f64> = (0..taps)
        .map(|i| {
            let m = i as f64 - (taps / 2) as f64;
            let sinc = if m == 0.0 {
                2.0 * fc
            } else {
                (2.0 * std::f64::consts::PI * fc * m).sin() / (std::f64::consts::PI * m)
            };
            let w = 0.42 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / (taps - 1) as f64).cos()
                + 0.08 * (4.0 * std::f64::consts::PI * i as f64 / (taps - 1) as f64).cos();
            sinc * w
        })
        .collect();
    let floor_rms = {
        let pre = &x[..40_000];
        (pre.iter().map(|v| v * v).sum::<f64>() / pre.len() as f64).sqrt()
    };
    let mut state = 11u64;
    let low: Vec<f64> = (0..x.len())
        .map(|n| {
            let y: f64 = (0..taps)
                .filter(|&k| n + taps / 2 >= k && n + taps / 2 - k < x.len())
                .map(|k| h[k] * x[n + taps / 2 - k])
                .sum();
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let u = ((state >> 11) as f64 / (1u64 << 53) as f64) - 0.5;
            y + 0.1 * floor_rms * 12f64.sqrt() * u
        })
        .collect();
    let lp = dir.join("lowpassed0.wav");
    write_wav(&lp, &low, rate);
    let opts = RecordingOptions {
        band_max_hz: Some(16_000.0),
        ..Default::default()
    };
    let rec = load_recording(&[lp.as_path(), bowl_wav(1).as_path()], &opts).unwrap();
    let health = assess_recording(&rec);
    assert!(health.iter().all(|h| h.is_healthy()), "{health:?}");
    let reach: Vec<Option<f64>> = health.iter().map(|h| h.band_reach_hz).collect();
    println!("reach {reach:?}");
    assert!(
        reach[0].is_some_and(|r| (3000.0..6600.0).contains(&r)),
        "the low-passed track must end at or below the filter's 6.5 kHz stop edge: {reach:?}"
    );
    assert_eq!(reach[1], Some(16_000.0), "{reach:?}");
    let warnings = band_warnings(&health, 16_000.0).unwrap();
    println!("{warnings:?}");
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    assert!(
        warnings[0].contains("lowpassed0") && warnings[0].contains("--fmax"),
        "{warnings:?}"
    );
    // The same track asked for a band that ends below its reach is not warned about.
    assert!(band_warnings(&health, 4_000.0).unwrap().is_empty());
}

/// Two microphones that hear only two modes (a soft strike on a quiet object): the diagnosis
/// exits cleanly with a report that tests nothing and says why, and writes no HDF5 result, map
/// or plot. (Generator 2, seed 17: two such cups ended with MPI_Abort and no report.)
#[test]
fn a_recording_with_too_few_modes_gets_a_report_that_tests_nothing() {
    let dir = scratch("too_few_modes");
    let rate = 48_000u32;
    let (pre, n) = (9_600usize, 9_600 + 48_000);
    let mut state = 11u64;
    let mut noise = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        1e-5 * (((state >> 11) as f64 / (1u64 << 53) as f64) - 0.5)
    };
    let mut paths = Vec::new();
    for (mic, gains) in [[1.0, 0.6], [0.7, 0.9]].iter().enumerate() {
        let x: Vec<f64> = (0..n)
            .map(|i| {
                let t = (i as f64 - pre as f64) / f64::from(rate);
                let ring = if t < 0.0 {
                    0.0
                } else {
                    gains[0]
                        * 0.3
                        * (-6.0 * t).exp()
                        * (2.0 * std::f64::consts::PI * 1013.0 * t).sin()
                        + gains[1]
                            * 0.2
                            * (-9.0 * t).exp()
                            * (2.0 * std::f64::consts::PI * 2391.0 * t).sin()
                };
                ring + noise()
            })
            .collect();
        let p = dir.join(format!("mic{mic}.wav"));
        write_wav(&p, &x, rate);
        paths.push(p);
    }
    let out = dir.join("diagnosis.h5");
    let run = mpirun(
        2,
        &[
            "diagnose",
            "--mesh",
            s(&bowl_mesh()),
            "--recording",
            s(&paths[0]),
            "--recording",
            s(&paths[1]),
            "--density",
            "2400",
            "--out",
            s(&out),
        ],
        LIMIT,
    );
    assert!(run.success(), "a report, not an error:\n{}", run.describe());
    assert!(
        run.stderr.contains("no diagnosis: only 2 modes"),
        "{}",
        run.describe()
    );
    let report = read_json(&dir.join("diagnosis.json"));
    assert_eq!(report["diagnosed"], false);
    assert!(report["refusal"]
        .as_str()
        .unwrap()
        .contains("needs at least 4"));
    assert_eq!(report["observed"]["fit"].as_array().unwrap().len(), 2);
    assert!(report["catalogue"]["accepted"]
        .as_array()
        .unwrap()
        .is_empty());
    let untested: Vec<&str> = report["untested"]
        .as_array()
        .unwrap()
        .iter()
        .map(|u| u["name"].as_str().unwrap())
        .collect();
    for effect in [
        "contact_duration",
        "beating_pair",
        "reverb_noise",
        "added_mass",
    ] {
        assert!(
            untested.contains(&effect),
            "{effect} untested: {untested:?}"
        );
    }
    assert!(!out.exists(), "no HDF5 result without a model");
    assert!(!dir.join("diagnosis_map.h5").exists());
    assert!(!dir.join("diagnosis_residuals.png").exists());
}

#[test]
fn a_start_probe_spacing_that_is_not_a_positive_step_is_refused() {
    let dir = scratch("bad_probe_spacing");
    for (name, value) in [("nan", "nan"), ("zero", "0.0")] {
        let config = dir.join(format!("probes_{name}.toml"));
        std::fs::write(&config, format!("[fit]\nstart_probe_spacing = {value}\n")).unwrap();
        let out = dir.join(format!("fit_{name}.h5"));
        refused(
            &[
                "fit-material",
                "--config",
                s(&config),
                "--mesh",
                s(&bowl_mesh()),
                "--recording",
                s(&bowl_wav(0)),
                "--density",
                "2400",
                "--out",
                s(&out),
            ],
            &["start_probe_spacing must be a positive step in ν"],
            &out,
            30.0,
        );
    }
}
