//! The iterative eigen path (`modes --solver iterative`: generalised Davidson with algebraic
//! multigrid, no factor; `diffsound::eigen::iterative`) against the direct path on the same
//! mesh, on 1 and 2 ranks: the same eigenvalues (1e-8 relative), the same modes (the principal
//! angles between each cluster's mode spaces), the completeness probe's verdict, and the
//! requests it refuses.

mod common;
use common::*;
use std::path::Path;
use std::time::Duration;

const MATERIAL: [&str; 6] = ["--youngs", "72e9", "--poisson", "0.19", "--density", "2700"];
const N_MODES: usize = 16;

fn modes(np: usize, mesh: &Path, out: &Path, json: &Path, extra: &[&str]) -> Run {
    let n = N_MODES.to_string();
    let mut args = vec![
        "modes",
        "--mesh",
        s(mesh),
        "--modes",
        &n,
        "--out",
        s(out),
        "--timings-json",
        s(json),
    ];
    args.extend(MATERIAL);
    args.extend(extra);
    mpirun(np, &args, Duration::from_secs(600))
}

/// The largest sine of the principal angles between the spans of `a` and `b` (Euclidean inner
/// product over the node displacements; both sets are orthonormalised first).
fn largest_angle_sine(a: &[Vec<f64>], b: &[Vec<f64>]) -> f64 {
    fn orthonormal(v: &[Vec<f64>]) -> Vec<Vec<f64>> {
        let mut q: Vec<Vec<f64>> = Vec::new();
        for x in v {
            let mut w = x.clone();
            for _ in 0..2 {
                for u in &q {
                    let c: f64 = u.iter().zip(&w).map(|(p, q)| p * q).sum();
                    w.iter_mut().zip(u).for_each(|(wi, ui)| *wi -= c * ui);
                }
            }
            let n = w.iter().map(|x| x * x).sum::<f64>().sqrt();
            q.push(w.into_iter().map(|x| x / n).collect());
        }
        q
    }
    let (qa, qb) = (orthonormal(a), orthonormal(b));
    // sin² of the largest angle = 1 − σ_min²(QaᵀQb); with equal dimensions the residual of
    // projecting each of qa onto span(qb) bounds it: take the largest.
    qa.iter()
        .map(|x| {
            let mut r = x.clone();
            for u in &qb {
                let c: f64 = u.iter().zip(&r).map(|(p, q)| p * q).sum();
                r.iter_mut().zip(u).for_each(|(ri, ui)| *ri -= c * ui);
            }
            r.iter().map(|x| x * x).sum::<f64>().sqrt()
        })
        .fold(0.0, f64::max)
}

#[test]
fn iterative_path_agrees_with_the_direct_path_on_one_and_two_ranks() {
    let dir = scratch("solver_iterative");
    let mesh = dir.join("sphere.msh");
    gmsh_mesh(&fixture("analytic/sphere.geo"), 0.16, 2, &mesh);

    let direct = modes(
        2,
        &mesh,
        &dir.join("direct.h5"),
        &dir.join("direct.json"),
        &["--solver", "direct"],
    );
    assert!(direct.success(), "{}", direct.describe());
    let mut iterative = Vec::new();
    for np in [1, 2] {
        let (out, json) = (
            dir.join(format!("iterative_{np}.h5")),
            dir.join(format!("iterative_{np}.json")),
        );
        let run = modes(np, &mesh, &out, &json, &["--solver", "iterative"]);
        assert!(run.success(), "{}", run.describe());
        assert!(
            run.stdout.contains("completeness probe:") && run.stdout.contains("consistent"),
            "the probe's line is missing or not consistent:\n{}",
            run.stdout
        );
        let j = read_json(&json);
        assert_eq!(j["solver_path"], "iterative");
        // The default preconditioner on a P2 mesh is the p-multigrid.
        assert_eq!(j["iterative_preconditioner"], "pmg");
        assert_eq!(j["probe"]["verdict"], "consistent");
        assert!(j["inertia"].is_null(), "the iterative path made a factor");
        // The probe's lowest eigenvalue in the complement is the next mode, not below the last.
        let last = j["probe"]["last_kept"].as_f64().unwrap();
        let lowest = j["probe"]["lowest_in_complement"].as_f64().unwrap();
        assert!(lowest >= last * (1.0 - 1e-7), "probe {lowest} below {last}");
        iterative.push((out, j));
    }
    let d = read_json(&dir.join("direct.json"));
    assert_eq!(d["solver_path"], "direct");
    let ld = f64s(&d, "eigenvalues");
    for (_, j) in &iterative {
        let li = f64s(j, "eigenvalues");
        let worst = worst_relative(&ld, &li, N_MODES);
        println!(
            "iterative on {} rank(s) vs direct: max relative eigenvalue difference {worst:.2e}",
            j["n_ranks"]
        );
        assert!(
            worst < 1e-8,
            "iterative vs direct: {worst:e}\n{ld:?}\n{li:?}"
        );
    }
    let (l1, l2) = (
        f64s(&iterative[0].1, "eigenvalues"),
        f64s(&iterative[1].1, "eigenvalues"),
    );
    let worst = worst_relative(&l1, &l2, l1.len().min(l2.len()));
    println!("iterative, 1 rank vs 2 ranks: {worst:.2e}");
    assert!(worst < 1e-9, "1 vs 2 ranks: {worst:e}");

    // The same modes: each cluster's span (grouped on the direct path's eigenvalues at the
    // default 1e-2 relative gap) against the iterative one's.
    let fd = diffsound::io::read_modes(&dir.join("direct.h5")).unwrap();
    let fi = diffsound::io::read_modes(&iterative[1].0).unwrap();
    let clusters = diffsound::eigen::find_clusters(&fd.eigenvalues[..N_MODES], 1e-2);
    let mut start = 0;
    let mut groups = Vec::new();
    for c in clusters {
        for i in start..c.start {
            groups.push(i..i + 1);
        }
        start = c.end;
        groups.push(c);
    }
    for i in start..N_MODES {
        groups.push(i..i + 1);
    }
    for g in groups {
        if g.end > N_MODES || g.end > fi.mode_shapes.len() {
            continue;
        }
        let sine = largest_angle_sine(&fd.mode_shapes[g.clone()], &fi.mode_shapes[g.clone()]);
        println!("modes {g:?}: largest principal angle sine {sine:.2e}");
        assert!(
            sine < 1e-4,
            "modes {g:?} differ between the paths: sin θ = {sine:e}"
        );
    }
}

#[test]
fn iterative_path_refuses_what_it_cannot_do() {
    let dir = scratch("solver_iterative_refusals");
    let mesh = dir.join("sphere.msh");
    gmsh_mesh(&fixture("analytic/sphere.geo"), 0.2, 2, &mesh);
    let out = dir.join("out.h5");
    let mut args = vec![
        "modes",
        "--mesh",
        s(&mesh),
        "--fmax",
        "5000",
        "--solver",
        "iterative",
        "--out",
        s(&out),
    ];
    args.extend(MATERIAL);
    let run = mpirun(2, &args, Duration::from_secs(120));
    assert!(!run.success());
    assert!(
        run.stderr.contains("--fmax") && run.stderr.contains("iterative"),
        "{}",
        run.describe()
    );
    assert!(!out.exists(), "a refused run left {out:?}");
    let mut args = vec![
        "modes",
        "--mesh",
        s(&mesh),
        "--solver",
        "lanczos",
        "--out",
        s(&out),
    ];
    args.extend(MATERIAL);
    let run = mpirun(1, &args, Duration::from_secs(60));
    assert!(!run.success());
    assert!(
        run.stderr.contains("lanczos") && run.stderr.contains("auto, direct or iterative"),
        "{}",
        run.describe()
    );
}

/// The preconditioners other than the default (`--preconditioner gamg`: algebraic multigrid on
/// the P2 operator; `pmg-mumps`: the p-multigrid with its P1 level factored) find the direct
/// path's eigenvalues on 1 and 2 ranks, and say which preconditioner ran; on a P1 mesh the
/// default is GAMG and the p-multigrid is refused by name.
#[test]
fn other_preconditioners_agree_with_the_direct_path() {
    let dir = scratch("solver_iterative_pmg");
    let mesh = dir.join("sphere.msh");
    gmsh_mesh(&fixture("analytic/sphere.geo"), 0.16, 2, &mesh);
    let direct_json = dir.join("direct.json");
    let direct = modes(
        2,
        &mesh,
        &dir.join("direct.h5"),
        &direct_json,
        &["--solver", "direct", "--no-verify"],
    );
    assert!(direct.success(), "{}", direct.describe());
    let ld = f64s(&read_json(&direct_json), "eigenvalues");
    for (np, pc) in [(2, "gamg"), (1, "gamg"), (2, "pmg-mumps")] {
        let json = dir.join(format!("{pc}_{np}.json"));
        let run = modes(
            np,
            &mesh,
            &dir.join(format!("{pc}_{np}.h5")),
            &json,
            &["--solver", "iterative", "--preconditioner", pc],
        );
        assert!(run.success(), "{}", run.describe());
        let j = read_json(&json);
        assert_eq!(j["iterative_preconditioner"], pc);
        assert_eq!(j["probe"]["verdict"], "consistent");
        let li = f64s(&j, "eigenvalues");
        let worst = worst_relative(&ld, &li, N_MODES);
        println!("{pc} on {np} rank(s) vs direct: max relative eigenvalue difference {worst:.2e}");
        assert!(worst < 1e-8, "{pc} vs direct: {worst:e}\n{ld:?}\n{li:?}");
    }
    // A P1 mesh has no coarser P1 space: `auto` takes GAMG there and finds the direct path's
    // P1 eigenvalues; asking for the p-multigrid is refused with the reason.
    let p1_direct = dir.join("p1_direct.json");
    let run = modes(
        2,
        &mesh,
        &dir.join("p1_direct.h5"),
        &p1_direct,
        &["--order", "1", "--solver", "direct", "--no-verify"],
    );
    assert!(run.success(), "{}", run.describe());
    let p1_json = dir.join("p1_auto.json");
    let run = modes(
        2,
        &mesh,
        &dir.join("p1_auto.h5"),
        &p1_json,
        &["--order", "1", "--solver", "iterative"],
    );
    assert!(run.success(), "{}", run.describe());
    let j = read_json(&p1_json);
    assert_eq!(j["iterative_preconditioner"], "gamg");
    let worst = worst_relative(
        &f64s(&read_json(&p1_direct), "eigenvalues"),
        &f64s(&j, "eigenvalues"),
        N_MODES,
    );
    println!("P1 mesh, auto (gamg) vs direct: max relative eigenvalue difference {worst:.2e}");
    assert!(worst < 1e-8, "P1 gamg vs direct: {worst:e}");
    let run = modes(
        1,
        &mesh,
        &dir.join("p1_pmg.h5"),
        &dir.join("p1_pmg.json"),
        &[
            "--order",
            "1",
            "--solver",
            "iterative",
            "--preconditioner",
            "pmg",
        ],
    );
    assert!(!run.success());
    assert!(run.stderr.contains("P2"), "{}", run.describe());

    // A bad word is refused by name.
    let run = modes(
        1,
        &mesh,
        &dir.join("bad.h5"),
        &dir.join("bad.json"),
        &["--solver", "iterative", "--preconditioner", "amg"],
    );
    assert!(!run.success());
    assert!(
        run.stderr.contains("amg") && run.stderr.contains("gamg, pmg or pmg-mumps"),
        "{}",
        run.describe()
    );
}

/// Largest |b − a| / a over the first `n` values of `reference` (a) and `other` (b); both must
/// hold at least `n`.
fn worst_relative(reference: &[f64], other: &[f64], n: usize) -> f64 {
    assert!(
        reference.len() >= n && other.len() >= n,
        "{} and {} values, {n} wanted",
        reference.len(),
        other.len()
    );
    reference
        .iter()
        .zip(other)
        .take(n)
        .map(|(a, b)| (a - b).abs() / a)
        .fold(0.0, f64::max)
}
