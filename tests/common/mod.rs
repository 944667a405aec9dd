//! Helpers shared by the integration tests: run the `diffsound` binary under `mpirun` with a
//! hard time limit (a hung MPI job fails the test instead of hanging CI), and locate data.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// A path as the &str a command-line argument wants.
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A numeric attribute of an HDF5 result file, float or integer, as f64 (panics with the
/// path if it is not a number).
pub fn number_attribute(path: &Path, group: &str, key: &str) -> f64 {
    let value = diffsound::io::results::read_attribute(path, group, key).unwrap();
    value
        .as_f64()
        .unwrap_or_else(|| panic!("{group}/{key} is not a number: {value:?}"))
}

/// A closed box surface [0, a] × [0, b] × [0, c] (in the file's units), outward triangles,
/// written as `dir/name` (OBJ).
pub fn box_obj(dir: &Path, name: &str, [a, b, c]: [f64; 3]) -> PathBuf {
    let mut text = String::from("# box\n");
    for k in 0..8 {
        text.push_str(&format!(
            "v {} {} {}\n",
            if k & 1 == 1 { a } else { 0.0 },
            if k & 2 == 2 { b } else { 0.0 },
            if k & 4 == 4 { c } else { 0.0 }
        ));
    }
    // Faces as quads (1-based corners), counter-clockwise seen from outside.
    for [p, q, r, t] in [
        [1, 3, 4, 2],
        [5, 6, 8, 7],
        [1, 2, 6, 5],
        [3, 7, 8, 4],
        [1, 5, 7, 3],
        [2, 4, 8, 6],
    ] {
        text.push_str(&format!("f {p} {q} {r}\nf {p} {r} {t}\n"));
    }
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

pub fn binary() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_diffsound"))
}

pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The shared data folder: `$DIFFSOUND_SHARED`, else `<repo>/../shared`.
pub fn shared() -> Option<PathBuf> {
    let p = std::env::var_os("DIFFSOUND_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| repo().join("../shared"));
    p.join("data").is_dir().then_some(p)
}

/// The bowl mesh: bundled under examples/ (always present in a clone).
pub fn bowl_mesh() -> PathBuf {
    repo().join("examples/bowl/bowl.msh")
}

pub fn fixture(name: &str) -> PathBuf {
    repo().join("tests/data").join(name)
}

/// A fresh scratch directory under the target dir, unique per test.
pub fn scratch(name: &str) -> PathBuf {
    let dir = repo().join("target/test-scratch").join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("create scratch dir");
    dir
}

pub struct Run {
    pub status: Option<i32>,
    pub stdout: String,
    pub stderr: String,
    pub timed_out: bool,
}

impl Run {
    pub fn success(&self) -> bool {
        self.status == Some(0) && !self.timed_out
    }
    pub fn describe(&self) -> String {
        format!(
            "status {:?} (timed out: {})\n--- stdout\n{}\n--- stderr\n{}",
            self.status, self.timed_out, self.stdout, self.stderr
        )
    }
}

/// Runs `diffsound ARGS` on `np` ranks under mpirun, killing it after `limit`.
pub fn mpirun(np: usize, args: &[&str], limit: Duration) -> Run {
    let mut cmd = Command::new("mpirun");
    cmd.args(["-np", &np.to_string()]).arg(binary()).args(args);
    run_with_limit(cmd, limit)
}

pub fn run_with_limit(mut cmd: Command, limit: Duration) -> Run {
    // Each run's own OpenMPI session directory: runs started and finished side by side by the
    // test harness otherwise share /tmp/ompi.<host>.<uid>, and one run's clean-up can remove it
    // while another creates its own below it (Open MPI 4.1.4: "orte_session_dir failed",
    // "File exists"; seen once in cli_fit_geometry's bad-input test).
    static RUNS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let n = RUNS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let session = std::env::temp_dir().join(format!("ds-ompi-{}-{n}", std::process::id()));
    std::fs::create_dir_all(&session).expect("create the run's MPI session directory");
    cmd.env("OMPI_MCA_orte_tmpdir_base", &session)
        .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .env("OPENBLAS_NUM_THREADS", "1")
        .env("OMPI_MCA_btl", "self,vader")
        .current_dir(repo())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    let mut child = cmd
        .spawn()
        .expect("spawn mpirun (is openmpi-bin installed? run scripts/install-deps.sh)");
    // Drain the pipes on threads so a chatty child cannot block on a full pipe.
    let mut out = child.stdout.take().unwrap();
    let mut err = child.stderr.take().unwrap();
    let t_out = std::thread::spawn(move || {
        let mut s = String::new();
        std::io::Read::read_to_string(&mut out, &mut s).ok();
        s
    });
    let t_err = std::thread::spawn(move || {
        let mut s = String::new();
        std::io::Read::read_to_string(&mut err, &mut s).ok();
        s
    });
    let start = Instant::now();
    let mut timed_out = false;
    let status = loop {
        if let Some(st) = child.try_wait().expect("wait") {
            break st.code();
        }
        if start.elapsed() > limit {
            timed_out = true;
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let _ = std::fs::remove_dir_all(&session);
    Run {
        status,
        stdout: t_out.join().unwrap_or_default(),
        stderr: t_err.join().unwrap_or_default(),
        timed_out,
    }
}

/// Parses the `--timings-json` output.
pub fn read_json(path: &Path) -> serde_json::Value {
    let text =
        std::fs::read_to_string(path).unwrap_or_else(|e| panic!("read {}: {e}", path.display()));
    serde_json::from_str(&text).expect("valid JSON")
}

pub fn f64s(v: &serde_json::Value, key: &str) -> Vec<f64> {
    v[key]
        .as_array()
        .unwrap_or_else(|| panic!("{key} missing"))
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

/// Meshes a .geo with gmsh at element size `h` (second order: curved boundary nodes).
pub fn gmsh_mesh(geo: &Path, h: f64, order: u32, out: &Path) {
    let mut cmd = Command::new("gmsh");
    cmd.args([
        "-3",
        "-order",
        &order.to_string(),
        "-clmin",
        &h.to_string(),
        "-clmax",
        &h.to_string(),
        "-format",
        "msh41",
    ])
    .arg(geo)
    .arg("-o")
    .arg(out);
    let r = run_with_limit(cmd, Duration::from_secs(120));
    assert!(
        r.success() && out.exists(),
        "gmsh failed (is gmsh installed? run scripts/install-deps.sh):\n{}",
        r.describe()
    );
}

/// The benchmark generator example, built next to the test binaries by `cargo test --features
/// bench-generators` (target/<profile>/examples).
pub fn generator() -> PathBuf {
    let exe = std::env::current_exe().expect("test binary path");
    let profile_dir = exe
        .parent()
        .and_then(Path::parent)
        .expect("target/<profile>/deps/<test>");
    let path = profile_dir.join("examples").join("diagnose_generate");
    assert!(path.is_file(), "{} is missing: build it with `cargo build --release --features bench-generators --example diagnose_generate` (cargo test --features bench-generators builds it too)", path.display());
    path
}

/// Reads an XDMF sidecar the way a Python user would (`tests/python/check_sidecar.py`):
/// meshio must give tetra10 (or tetra) cells and every mode and node field as a point array,
/// `fields` naming each node field with its kind ("scalar": one value per node, a 1-D array;
/// "vector": three), each equal to its HDF5 dataset read with h5py. meshio and h5py come from
/// `scripts/install-deps.sh`; `DIFFSOUND_PYTHON` overrides the interpreter (default Debian's
/// `/usr/bin/python3`, which has them where a pyenv `python3` may not).
pub fn check_sidecar(xdmf: &Path, fields: &[(&str, &str)]) {
    let python = std::env::var_os("DIFFSOUND_PYTHON").unwrap_or_else(|| "/usr/bin/python3".into());
    let out = Command::new(&python)
        .arg(repo().join("tests/python/check_sidecar.py"))
        .arg(xdmf)
        .args(fields.iter().map(|(name, kind)| format!("{name}={kind}")))
        .output()
        .unwrap_or_else(|e| panic!("{}: {e}", python.to_string_lossy()));
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        out.status.success(),
        "{}: meshio/h5py check failed:\n{text}",
        xdmf.display()
    );
    eprintln!("{}", text.trim());
}
