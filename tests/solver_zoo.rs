//! The mesh zoo: ordinary meshes that once broke the solver, each solved with the defaults on 1 and
//! 2 ranks by `--modes 40` and on 2 ranks by `--fmax` (the thin plate, whose 2-rank factor once
//! ran out of workspace, on 1 rank too), and each run must end with a complete inertia proof.
//! The other meshes' 1-rank slices (33 s of the suite's time) are left to `--modes 40`'s 1-rank
//! runs, which prove their counts through the same inertia path.
//!
//! The meshes are made here from the `.geo` files in `tests/data/zoo/` by Gmsh: a thin plate
//! (thickness/length 1/40, Gmsh's own 10-node tets; MUMPS ran out of workspace on it on 2 ranks),
//! a slender rod (25:1), a thin hemispherical shell (thickness/radius 1/40), an L bracket in
//! millimetres (`--units mm`), a single extruded layer of flat, high-aspect tets, and the bowl.
//! Each test prints its table rows (DOF, ranks, request, factor retries, the two inertia counts,
//! time) for the note.

mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

const LIMIT: Duration = Duration::from_secs(300);

/// Meshes `tests/data/zoo/NAME.geo` with the settings in the file (MSH 2.2, as a user would).
fn zoo_mesh(name: &str) -> PathBuf {
    let dir = scratch(&format!("zoo_{name}"));
    let geo = repo().join("tests/data/zoo").join(format!("{name}.geo"));
    let out = dir.join(format!("{name}.msh"));
    let mut cmd = Command::new("gmsh");
    cmd.arg(&geo)
        .args(["-3", "-format", "msh22", "-o"])
        .arg(&out);
    let r = run_with_limit(cmd, Duration::from_secs(120));
    assert!(
        r.success() && out.exists(),
        "gmsh failed on {} (is gmsh installed? run scripts/install-deps.sh):\n{}",
        geo.display(),
        r.describe()
    );
    out
}

struct Solved {
    frequencies: Vec<f64>,
    eigenvalues: Vec<f64>,
}

/// One `modes` run with the defaults; asserts success and a complete two-count proof, and prints
/// the table row.
fn solve(name: &str, mesh: &Path, extra: &[&str], np: usize, request: &[&str]) -> Solved {
    let dir = mesh.parent().unwrap();
    let tag = format!("{name}_np{np}_{}", request[0].trim_start_matches('-'));
    let json = dir.join(format!("{tag}.json"));
    let out = dir.join(format!("{tag}.h5"));
    let mut args = vec![
        "modes",
        "--mesh",
        s(mesh),
        "--out",
        s(&out),
        "--timings-json",
        s(&json),
    ];
    args.extend_from_slice(extra);
    args.extend_from_slice(request);
    let run = mpirun(np, &args, LIMIT);
    assert!(
        run.success(),
        "{tag}: the default solve failed\n{}",
        run.describe()
    );
    assert!(
        run.stdout.contains("-> complete"),
        "{tag}: the inertia proof is not complete\n{}",
        run.describe()
    );
    assert!(
        !run.stderr.contains("spurious") && !run.stderr.contains("not proven"),
        "{tag}: the proof was doubted\n{}",
        run.describe()
    );
    let v = read_json(&json);
    let inertia = &v["inertia"];
    assert_eq!(
        inertia["verdict"].as_str(),
        Some("complete"),
        "{tag}: {inertia}"
    );
    assert_eq!(inertia["below"], inertia["found"], "{tag}: {inertia}");
    let second = &inertia["second"];
    assert!(
        second.is_object(),
        "{tag}: a second count must be made: {inertia}"
    );
    assert_eq!(second["below"], second["found"], "{tag}: {inertia}");
    println!(
        "zoo | {name:<12} | {:>6} DOF | {np} rank(s) | {:<16} | solve retries {} ({}) | inertia {}/{} below {:.4e}, {}/{} below {:.4e}, retries {} | {:.2} s",
        v["ndof"],
        request.join(" "),
        v["factor_retries"],
        v["factor_attempts"].as_str().unwrap_or(""),
        inertia["below"],
        inertia["found"],
        inertia["threshold"].as_f64().unwrap_or(0.0),
        second["below"],
        second["found"],
        second["threshold"].as_f64().unwrap_or(0.0),
        inertia["factor_retries"],
        v["total_s"].as_f64().unwrap_or(0.0)
    );
    Solved {
        frequencies: f64s(&v, "frequencies_hz"),
        eigenvalues: f64s(&v, "eigenvalues"),
    }
}

/// `--modes 40` on 1 and 2 ranks and `--fmax` on `slice_ranks`; the ranks agree and the slice
/// finds exactly the modes below its limit.
fn zoo_case(name: &str, mesh: &Path, extra: &[&str], slice_ranks: &[usize]) {
    let first: Vec<Solved> = [1, 2]
        .iter()
        .map(|&np| solve(name, mesh, extra, np, &["--modes", "40"]))
        .collect();
    assert!(
        first[0].eigenvalues.len() >= 40,
        "{name}: {} modes",
        first[0].eigenvalues.len()
    );
    let n = first[0].eigenvalues.len().min(first[1].eigenvalues.len());
    for i in 0..n {
        let (a, b) = (first[0].eigenvalues[i], first[1].eigenvalues[i]);
        assert!(
            (a - b).abs() <= 1e-8 * a.abs(),
            "{name}: mode {} differs between 1 and 2 ranks: {a:e} vs {b:e}",
            i + 1
        );
    }
    // A limit in the widest relative gap among modes 15-30, so that it lies far from any mode
    // (and the slice stays cheap).
    let f = &first[0].frequencies;
    let k = (14..29)
        .max_by(|&a, &b| (f[a + 1] / f[a]).total_cmp(&(f[b + 1] / f[b])))
        .unwrap();
    let fmax = (f[k] * f[k + 1]).sqrt();
    let fmax_arg = format!("{fmax}");
    for &np in slice_ranks {
        let sliced = solve(name, mesh, extra, np, &["--fmax", &fmax_arg]);
        assert_eq!(
            sliced.frequencies.len(),
            k + 1,
            "{name}: {np} rank(s), the slice up to {fmax} Hz found {} modes, expected {}",
            sliced.frequencies.len(),
            k + 1
        );
        for (i, (a, b)) in sliced.frequencies.iter().zip(f).enumerate() {
            assert!(
                (a - b).abs() <= 1e-8 * b,
                "{name}: {np} rank(s), mode {} sliced {a} vs {b}",
                i + 1
            );
        }
    }
}

#[test]
fn thin_plate() {
    let mesh = zoo_mesh("thin_plate");
    zoo_case("thin_plate", &mesh, &["--material", "aluminium"], &[1, 2]);
}

#[test]
fn slender_rod() {
    let mesh = zoo_mesh("slender_rod");
    zoo_case("slender_rod", &mesh, &["--material", "steel"], &[2]);
}

#[test]
fn thin_curved_shell() {
    let mesh = zoo_mesh("thin_shell");
    zoo_case("thin_shell", &mesh, &["--material", "glass"], &[2]);
}

#[test]
fn bracket_in_millimetres() {
    let mesh = zoo_mesh("bracket_mm");
    zoo_case(
        "bracket_mm",
        &mesh,
        &["--material", "aluminium", "--units", "mm"],
        &[2],
    );
}

#[test]
fn high_aspect_and_sliver_tets() {
    let mesh = zoo_mesh("slivers");
    zoo_case("slivers", &mesh, &["--material", "aluminium"], &[2]);
}

#[test]
fn bowl() {
    let dir = scratch("zoo_bowl");
    let mesh = dir.join("bowl.msh");
    std::fs::copy(bowl_mesh(), &mesh).expect("copy the bowl");
    // The bowl's slice on 2 ranks only, as for every mesh but the thin plate (module docs).
    zoo_case("bowl", &mesh, &["--material", "ceramic"], &[2]);
}

/// A workspace run short in the inertia factor (INFOG(1) = −9) used to give a silently wrong, too
/// small inertia count on 2 ranks. Whether MUMPS really runs short at a starved ICNTL(14) depends
/// on its dynamic scheduling (it did on an idle machine, not on CI), so the failure of the first
/// attempt is injected (`-diffsound_fault_workspace inertia`: the real factor is reported as −9);
/// the retry that follows is a real factorisation with more room. The retry must be logged, the
/// proof must end complete and the modes must equal a run without the fault.
#[test]
fn starved_inertia_workspace_is_retried_not_miscounted() {
    let mesh = zoo_mesh("thin_plate");
    let dir = mesh.parent().unwrap();
    let json = dir.join("starved.json");
    let (faulted, plain) = (dir.join("starved.h5"), dir.join("unstarved.h5"));
    let common = [
        "modes",
        "--mesh",
        s(&mesh),
        "--material",
        "aluminium",
        "--modes",
        "40",
        "--timings-json",
        s(&json),
    ];
    let mut args = common.to_vec();
    args.extend_from_slice(&[
        "--out",
        s(&faulted),
        "--",
        "-diffsound_fault_workspace",
        "inertia",
    ]);
    let run = mpirun(2, &args, LIMIT);
    assert!(run.success(), "{}", run.describe());
    assert!(run.stdout.contains("-> complete"), "{}", run.describe());
    let v = read_json(&json);
    let retried = f64s(&v, "frequencies_hz");
    println!(
        "inertia factor attempts: {}",
        v["inertia"]["factor_attempts"]
    );
    assert!(
        v["inertia"]["factor_retries"].as_u64().unwrap_or(0) >= 1,
        "the injected shortage must be retried: {}",
        v["inertia"]
    );
    assert!(
        run.stderr
            .contains("MUMPS workspace too small for the inertia matrix"),
        "the retry must be logged:\n{}",
        run.stderr
    );
    assert!(
        !run.stderr.contains("diffsound_fault_workspace"),
        "the hook is read, so never reported unused:\n{}",
        run.stderr
    );
    let mut args = common.to_vec();
    args.extend_from_slice(&["--out", s(&plain)]);
    let run = mpirun(2, &args, LIMIT);
    assert!(run.success(), "{}", run.describe());
    let (a, b) = (retried, f64s(&read_json(&json), "frequencies_hz"));
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(&b) {
        assert!(
            (x - y).abs() <= 1e-8 * y,
            "the retry changed a mode: {x} vs {y}"
        );
    }
}

/// A cap on MUMPS's memory (ICNTL(23)) too small to factor is not retried: the job fails at once
/// with the option named, on every rank, and leaves no output file.
#[test]
fn a_memory_cap_too_small_fails_with_the_option_named() {
    let mesh = zoo_mesh("slivers");
    let dir = mesh.parent().unwrap();
    let out = dir.join("capped.h5");
    let run = mpirun(
        2,
        &[
            "modes",
            "--mesh",
            s(&mesh),
            "--modes",
            "10",
            "--out",
            s(&out),
            "--",
            "-mat_mumps_icntl_23",
            "1",
        ],
        LIMIT,
    );
    assert!(!run.success() && !run.timed_out, "{}", run.describe());
    assert!(
        run.stderr.contains("-mat_mumps_icntl_23") && run.stderr.contains("INFOG(1) = -19"),
        "{}",
        run.describe()
    );
    assert!(!out.exists(), "no output may be written");
}

/// Requests the mesh cannot meet end at once with a message that says what to change, instead
/// of spinning inside SLEPc (more modes than degrees of freedom; a shift that is no number).
#[test]
fn requests_the_mesh_cannot_meet_fail_at_once() {
    let mesh = zoo_mesh("slivers");
    let dir = mesh.parent().unwrap();
    let out = dir.join("impossible.h5");
    let cases: [(&[&str], &str); 3] = [
        (&["--modes", "2000"], "at most 1335 elastic modes exist"),
        (&["--modes", "5", "--shift", "nan"], "leave --shift out"),
        (
            &["--modes", "5", "--shift", "-1e30"],
            "not a finite number near the spectrum",
        ),
    ];
    for (request, expected) in cases {
        let mut args = vec!["modes", "--mesh", s(&mesh), "--out", s(&out)];
        args.extend_from_slice(request);
        let started = std::time::Instant::now();
        let run = mpirun(2, &args, Duration::from_secs(60));
        assert!(
            !run.success() && !run.timed_out,
            "{request:?}: {}",
            run.describe()
        );
        assert!(
            run.stderr.contains(expected),
            "{request:?}: expected «{expected}»:\n{}",
            run.describe()
        );
        assert!(
            started.elapsed() < Duration::from_secs(30),
            "{request:?} took {:?}",
            started.elapsed()
        );
        assert!(!out.exists(), "{request:?}: no output may be written");
    }
}

/// A misspelled PETSc option, or a word after `--` that is no option, is reported instead of
/// ignored in silence; options that were used (and a MUMPS control in either spelling) are not.
#[test]
fn unused_petsc_options_are_reported() {
    let mesh = zoo_mesh("slivers");
    let out = mesh.parent().unwrap().join("options.h5");
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
            "--",
            "-foo_bar",
            "1",
            "notanoption",
            "-eps_ncv",
            "40",
            "-mat_mumps_icntl_14",
            "60",
        ],
        LIMIT,
    );
    assert!(run.success(), "{}", run.describe());
    assert!(
        run.stderr.contains("never used") && run.stderr.contains("-foo_bar 1"),
        "{}",
        run.describe()
    );
    assert!(
        run.stderr
            .contains("'notanoption' after -- is not a PETSc option"),
        "{}",
        run.describe()
    );
    let unused_line = run
        .stderr
        .lines()
        .find(|l| l.contains("never used"))
        .unwrap_or("");
    assert!(
        !unused_line.contains("eps_ncv") && !unused_line.contains("mumps"),
        "used options reported: {unused_line}"
    );
}
