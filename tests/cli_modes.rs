//! End-to-end runs of `diffsound modes` under mpirun: parallel consistency, both ways of asking
//! for modes, the output files, PETSc option overrides, and clear failures on bad input.

mod common;
use common::*;
use std::time::Duration;

const LIMIT: Duration = Duration::from_secs(240);

#[test]
fn one_and_two_ranks_give_the_same_bowl_eigenvalues() {
    let dir = scratch("ranks");
    let mut results = Vec::new();
    for np in [1, 2] {
        let json = dir.join(format!("np{np}.json"));
        let out = dir.join(format!("np{np}.h5"));
        let run = mpirun(
            np,
            &[
                "modes",
                "--mesh",
                s(&bowl_mesh()),
                "--modes",
                "20",
                "--out",
                s(&out),
                "--timings-json",
                s(&json),
            ],
            LIMIT,
        );
        assert!(run.success(), "{}", run.describe());
        let v = read_json(&json);
        assert_eq!(v["n_ranks"].as_u64(), Some(np as u64));
        assert_eq!(
            v["mallocs"].as_f64(),
            Some(0.0),
            "preallocation must be exact"
        );
        results.push(f64s(&v, "eigenvalues"));
        let summary = diffsound::io::read_modes(&out).expect("read back the HDF5 file");
        assert_eq!(summary.n_ranks, np);
    }
    assert_eq!(results[0].len(), results[1].len());
    let worst = results[0]
        .iter()
        .zip(&results[1])
        .map(|(a, b)| (a - b).abs() / a.abs())
        .fold(0.0, f64::max);
    println!("max relative eigenvalue difference 1 vs 2 ranks: {worst:e}");
    assert!(
        worst < 1e-9,
        "1-rank and 2-rank eigenvalues differ by {worst:e}"
    );
}

#[test]
fn frequency_limit_finds_exactly_the_modes_below_it() {
    let dir = scratch("fmax");
    let mesh = fixture("mesh/sphere_tet10_msh41_bin.msh");
    let first = dir.join("first.json");
    let run = mpirun(
        2,
        &[
            "modes",
            "--mesh",
            s(&mesh),
            "--modes",
            "40",
            "--out",
            s(&dir.join("first.h5")),
            "--timings-json",
            s(&first),
        ],
        LIMIT,
    );
    assert!(run.success(), "{}", run.describe());
    let f_first = f64s(&read_json(&first), "frequencies_hz");
    // A limit halfway between two well separated modes.
    let k = (20..f_first.len() - 1)
        .max_by(|&a, &b| (f_first[a + 1] / f_first[a]).total_cmp(&(f_first[b + 1] / f_first[b])))
        .unwrap();
    let fmax = 0.5 * (f_first[k] + f_first[k + 1]);
    let sliced = dir.join("sliced.json");
    let run = mpirun(
        2,
        &[
            "modes",
            "--mesh",
            s(&mesh),
            "--fmax",
            &fmax.to_string(),
            "--out",
            s(&dir.join("sliced.h5")),
            "--timings-json",
            s(&sliced),
        ],
        LIMIT,
    );
    assert!(run.success(), "{}", run.describe());
    assert!(
        run.stdout.contains("complete"),
        "inertia check should report complete:\n{}",
        run.stdout
    );
    let f_sliced = f64s(&read_json(&sliced), "frequencies_hz");
    assert_eq!(
        f_sliced.len(),
        k + 1,
        "spectrum slicing up to {fmax} Hz found {} modes, expected {}",
        f_sliced.len(),
        k + 1
    );
    for (a, b) in f_sliced.iter().zip(&f_first) {
        assert!((a - b).abs() / b < 1e-8, "{a} vs {b}");
    }
}

#[test]
fn writes_hdf5_xdmf_and_a_strike() {
    let dir = scratch("outputs");
    let out = dir.join("cube.h5");
    let wav = dir.join("cube.wav");
    let run = mpirun(
        2,
        &[
            "modes",
            "--mesh",
            s(&fixture("mesh/cube_tet4_msh22_ascii.msh")),
            "--modes",
            "8",
            "--out",
            s(&out),
            "--wav",
            s(&wav),
            "--duration",
            "0.5",
            "--sample-rate",
            "32000",
        ],
        LIMIT,
    );
    assert!(run.success(), "{}", run.describe());
    let summary = diffsound::io::read_modes(&out).expect("read back");
    assert!(summary.n_modes >= 8);
    assert_eq!(summary.nodes_per_tet, 10, "P2 by default");
    assert_eq!(summary.mode_shapes[0].len(), 3 * summary.n_nodes);
    assert_eq!(summary.rigid_eigenvalues.len(), 6);
    // meshio (Python) reads the sidecar: tetra10 cells, every mode an (n, 3) point array.
    check_sidecar(&out.with_extension("xdmf"), &[]);
    let (channels, rate) = diffsound::audio::read_wav(&wav).expect("read the strike");
    assert_eq!(rate, 32000);
    assert_eq!(channels[0].len(), 16000);
    let peak = channels[0].iter().fold(0.0f64, |m, x| m.max(x.abs()));
    assert!(peak > 0.5, "strike should be audible, peak {peak}");
    // No temporary files are left behind.
    let leftovers: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
}

#[test]
fn p1_baseline_is_stiffer_than_p2() {
    let dir = scratch("p1");
    let mesh = fixture("mesh/cube_tet4_msh41_bin.msh");
    let mut first = Vec::new();
    for order in ["1", "2"] {
        let json = dir.join(format!("p{order}.json"));
        let run = mpirun(
            2,
            &[
                "modes",
                "--mesh",
                s(&mesh),
                "--order",
                order,
                "--modes",
                "6",
                "--out",
                s(&dir.join(format!("p{order}.h5"))),
                "--timings-json",
                s(&json),
            ],
            LIMIT,
        );
        assert!(run.success(), "{}", run.describe());
        first.push(f64s(&read_json(&json), "eigenvalues")[0]);
    }
    // Conforming elements approximate eigenvalues from above; the richer space is lower.
    assert!(
        first[0] > first[1] * 1.001,
        "P1 {} should exceed P2 {}",
        first[0],
        first[1]
    );
}

#[test]
fn petsc_options_after_double_dash_override_defaults() {
    let dir = scratch("options");
    let out = dir.join("o.h5");
    let run = mpirun(
        2,
        &[
            "modes",
            "--mesh",
            s(&fixture("mesh/cube_tet4_msh22_bin.msh")),
            "--modes",
            "5",
            "--out",
            s(&out),
            "--",
            "-eps_ncv",
            "37",
            "-eps_tol",
            "1e-9",
        ],
        LIMIT,
    );
    assert!(run.success(), "{}", run.describe());
    let summary = diffsound::io::read_modes(&out).expect("read back");
    let get = |k: &str| {
        summary
            .solver
            .iter()
            .find(|(a, _)| a == k)
            .map(|(_, v)| v.clone())
            .unwrap_or_default()
    };
    assert_eq!(get("eps_ncv"), "37");
    assert_eq!(get("eps_tol"), "1e-9");
    // A bad PETSc option value ends the job with PETSc's own message, not a hang.
    let run = mpirun(
        2,
        &[
            "modes",
            "--mesh",
            s(&fixture("mesh/cube_tet4_msh22_bin.msh")),
            "--modes",
            "5",
            "--out",
            s(&dir.join("bad.h5")),
            "--",
            "-eps_type",
            "no_such_solver",
        ],
        LIMIT,
    );
    assert!(!run.success() && !run.timed_out, "{}", run.describe());
    assert!(run.stderr.contains("no_such_solver"), "{}", run.describe());
    assert!(!dir.join("bad.h5").exists());
}

/// Runs a failing job on 2 ranks and checks: non-zero exit, no hang, the expected words in the
/// message, and no output file under the final name.
fn expect_failure(name: &str, args: &[&str], words: &[&str]) {
    let dir = scratch(&format!("bad_{name}"));
    let out = dir.join("never.h5");
    let mut all: Vec<&str> = vec!["modes"];
    all.extend_from_slice(args);
    all.extend_from_slice(&["--out", s(&out)]);
    let run = mpirun(2, &all, Duration::from_secs(120));
    assert!(
        !run.timed_out,
        "job hung on bad input {name}:\n{}",
        run.describe()
    );
    assert!(
        !run.success(),
        "bad input {name} was accepted:\n{}",
        run.describe()
    );
    for w in words {
        assert!(
            run.stderr.contains(w),
            "message for {name} should mention {w:?}:\n{}",
            run.describe()
        );
    }
    assert!(
        !run.stderr.contains("panicked"),
        "{name} panicked:\n{}",
        run.describe()
    );
    assert!(!out.exists(), "{name}: output written despite the error");
    assert!(
        std::fs::read_dir(&dir).unwrap().next().is_none(),
        "{name}: files left in the output dir"
    );
}

#[test]
fn bad_input_fails_clearly_on_every_rank() {
    let dir = scratch("bad_inputs");
    let truncated = dir.join("truncated.msh");
    let bytes = std::fs::read(bowl_mesh()).unwrap();
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
    let cube = fixture("mesh/cube_tet4_msh22_ascii.msh");
    let text = std::fs::read_to_string(&cube).unwrap();
    let nan = dir.join("nan.msh");
    // Replace the first node's x coordinate by nan.
    let nodes_at = text.find("$Nodes\n").unwrap() + "$Nodes\n".len();
    let first_line = nodes_at + text[nodes_at..].find('\n').unwrap() + 1;
    let end_line = first_line + text[first_line..].find('\n').unwrap();
    let fields: Vec<&str> = text[first_line..end_line].split_whitespace().collect();
    std::fs::write(
        &nan,
        format!(
            "{}{} nan {} {}{}",
            &text[..first_line],
            fields[0],
            fields[2],
            fields[3],
            &text[end_line..]
        ),
    )
    .unwrap();

    let bad_toml = dir.join("bad.toml");
    std::fs::write(&bad_toml, "mesh = \"x.msh\"\n[solver]\nmodez = 3\n").unwrap();
    let bad_path_toml = dir.join("bad_path.toml");
    std::fs::write(
        &bad_path_toml,
        format!("mesh = \"{}\"\n[solver]\npath = \"fastest\"\n", s(&cube)),
    )
    .unwrap();
    let bad_preconditioner_toml = dir.join("bad_preconditioner.toml");
    std::fs::write(
        &bad_preconditioner_toml,
        format!(
            "mesh = \"{}\"\n[solver]\npath = \"iterative\"\npreconditioner = \"amg\"\n",
            s(&cube)
        ),
    )
    .unwrap();
    let broken_toml = dir.join("broken.toml");
    std::fs::write(&broken_toml, "mesh = [unclosed\n").unwrap();

    expect_failure(
        "config_unknown_key",
        &["--config", s(&bad_toml)],
        &["bad.toml", "modez"],
    );
    expect_failure(
        "config_solver_path",
        &["--config", s(&bad_path_toml)],
        &[
            "bad_path.toml",
            "[solver] path",
            "\"fastest\"",
            "auto, direct or iterative",
        ],
    );
    expect_failure(
        "config_preconditioner",
        &["--config", s(&bad_preconditioner_toml)],
        &[
            "bad_preconditioner.toml",
            "[solver] preconditioner",
            "\"amg\"",
            "auto, gamg, pmg or pmg-mumps",
        ],
    );
    expect_failure(
        "config_syntax",
        &["--config", s(&broken_toml)],
        &["broken.toml"],
    );
    expect_failure(
        "config_missing",
        &["--config", "no/such/run.toml"],
        &["no/such/run.toml"],
    );
    expect_failure(
        "fmax",
        &["--mesh", s(&cube), "--fmax", "-5"],
        &["frequency limit"],
    );
    expect_failure(
        "missing_mesh",
        &["--mesh", "no/such/file.msh"],
        &["no/such/file.msh"],
    );
    expect_failure("truncated", &["--mesh", s(&truncated)], &["truncated.msh"]);
    expect_failure("nan", &["--mesh", s(&nan)], &["nan.msh"]);
    expect_failure(
        "poisson",
        &["--mesh", s(&cube), "--poisson", "0.5"],
        &["oisson"],
    );
    expect_failure(
        "preset",
        &["--mesh", s(&cube), "--material", "unobtainium"],
        &["unobtainium", "ceramic"],
    );
    expect_failure(
        "zero_modes",
        &["--mesh", s(&cube), "--modes", "0"],
        &["at least 1"],
    );
    expect_failure(
        "units",
        &["--mesh", s(&cube), "--units", "furlong"],
        &["furlong"],
    );
    expect_failure(
        "outdir",
        &["--mesh", s(&cube), "--wav", "no/such/dir/x.wav"],
        &["no/such/dir"],
    );
    expect_failure(
        "strike",
        &[
            "--mesh",
            s(&cube),
            "--modes",
            "3",
            "--wav",
            s(&dir.join("x.wav")),
            "--strike-vertex",
            "999999",
        ],
        &["999999"],
    );
}

#[test]
fn ten_node_input_is_kept_curved_and_linear_input_is_lifted() {
    // The same sphere meshed with 4-node and with curved 10-node tets: the curved P2 geometry
    // holds more volume (closer to 4/3 π r³), which lowers nothing but must change the modes.
    let dir = scratch("curved");
    let mut first = Vec::new();
    for f in ["sphere_tet4_msh22_bin.msh", "sphere_tet10_msh22_bin.msh"] {
        let json = dir.join(format!("{f}.json"));
        let run = mpirun(
            2,
            &[
                "modes",
                "--mesh",
                s(&fixture(&format!("mesh/{f}"))),
                "--modes",
                "5",
                "--out",
                s(&dir.join(format!("{f}.h5"))),
                "--timings-json",
                s(&json),
            ],
            LIMIT,
        );
        assert!(run.success(), "{}", run.describe());
        first.push(f64s(&read_json(&json), "frequencies_hz")[0]);
    }
    assert!(
        (first[0] - first[1]).abs() / first[1] > 1e-3,
        "curved geometry should change the modes: {first:?}"
    );
}

#[test]
fn a_panic_on_one_rank_ends_the_whole_job() {
    // Rank 1 panics while rank 0 goes on into collective assembly: without the abort hook the
    // job would hang there forever.
    let dir = scratch("panic");
    let mut cmd = std::process::Command::new("mpirun");
    cmd.args(["-np", "2"]).arg(binary()).args([
        "modes",
        "--mesh",
        s(&bowl_mesh()),
        "--modes",
        "5",
        "--out",
        s(&dir.join("p.h5")),
    ]);
    cmd.env("DIFFSOUND_TEST_PANIC_ON_RANK", "1");
    let run = run_with_limit(cmd, Duration::from_secs(60));
    assert!(
        !run.timed_out,
        "the job hung after a panic on rank 1:\n{}",
        run.describe()
    );
    assert!(!run.success());
    assert!(
        run.stderr.contains("rank 1 of 2 panicked"),
        "{}",
        run.describe()
    );
    assert!(!dir.join("p.h5").exists());
}

#[test]
fn sensitivities_and_node_gradients_reach_the_hdf5_file() {
    let dir = scratch("sensitivities");
    let out = dir.join("s.h5");
    let run = mpirun(
        2,
        &[
            "modes",
            "--mesh",
            s(&fixture("mesh/cube_tet4_msh22_ascii.msh")),
            "--modes",
            "6",
            "--node-gradients",
            "--out",
            s(&out),
        ],
        LIMIT,
    );
    assert!(run.success(), "{}", run.describe());
    assert!(
        run.stdout.contains("df/dE"),
        "summary shows the sensitivities:\n{}",
        run.stdout
    );
    let f = diffsound::io::read_modes(&out).expect("read back");
    let get = |p: &str| {
        f.extra_datasets
            .iter()
            .find(|d| d.path == p)
            .unwrap_or_else(|| panic!("{p} missing"))
    };
    let per_mode = get("/sensitivities/per_mode_d_eigenvalue_d_youngs");
    assert_eq!(per_mode.data.len(), f.n_modes);
    // λ_L and μ are both proportional to E, so dλ/dE = λ/E exactly.
    let e = f.material.youngs_modulus;
    for (d, l) in per_mode.data.iter().zip(&f.eigenvalues) {
        assert!(
            (d - l / e).abs() < 1e-8 * l / e,
            "dλ/dE {d} vs λ/E {}",
            l / e
        );
    }
    let density = get("/sensitivities/d_eigenvalue_d_density");
    assert!(density
        .attrs
        .iter()
        .any(|(k, v)| k == "units" && v.contains("kg")));
    assert_eq!(f.node_fields.len(), f.n_modes);
    assert_eq!(f.node_fields[0].data.len(), 3 * f.n_nodes);
    let xdmf = std::fs::read_to_string(out.with_extension("xdmf")).unwrap();
    assert!(xdmf.contains("d_lambda_dx_mode_000"));
    let names: Vec<String> = f.node_fields.iter().map(|d| d.name.clone()).collect();
    let fields: Vec<(&str, &str)> = names.iter().map(|n| (n.as_str(), "vector")).collect();
    check_sidecar(&out.with_extension("xdmf"), &fields);
}

#[test]
fn config_paths_are_relative_to_the_config_file() {
    // The config and its mesh live in a folder of their own; mpirun runs from the repository
    // root, so the old behaviour (paths from the current directory) would not find the mesh.
    let dir = scratch("config_relative");
    let conf = dir.join("conf");
    std::fs::create_dir_all(conf.join("out")).unwrap();
    std::fs::copy(
        fixture("mesh/cube_tet4_msh22_ascii.msh"),
        conf.join("cube.msh"),
    )
    .unwrap();
    let config = conf.join("run.toml");
    std::fs::write(
        &config,
        "mesh = \"cube.msh\"\norder = 1\n[solver]\nmodes = 4\n[output]\nh5 = \"out/cube.h5\"\n",
    )
    .unwrap();
    let run = mpirun(
        1,
        &["modes", "--config", s(&config), "--verbose", "--quiet"],
        LIMIT,
    );
    assert!(run.success(), "{}", run.describe());
    let out = conf.join("out/cube.h5");
    assert!(out.exists(), "{} not written", out.display());
    assert!(run.stdout.contains("cube.h5"), "{}", run.stdout);
    // --quiet wins over --verbose: no timed progress lines.
    assert!(!run.stderr.contains(" s] "), "{}", run.stderr);
    // A flag path stays relative to the current directory (the repository root here).
    let elsewhere = dir.join("flag.h5");
    let run = mpirun(
        1,
        &[
            "modes",
            "--config",
            s(&config),
            "--out",
            s(&elsewhere),
            "-q",
        ],
        LIMIT,
    );
    assert!(run.success(), "{}", run.describe());
    assert!(elsewhere.exists());
}
