//! End-to-end runs of `diffsound locate-impact` on strikes rendered by the benchmark generator
//! `examples/diagnose_generate.rs` (a plate struck at a known vertex, four microphones with
//! unknown gains, white or pink noise at 50–70 dB): the outputs are complete and consistent,
//! the map finds the strike (on its symmetry orbit, the plate being symmetric), 1 and 2 ranks
//! agree, and bad input fails with a clear message and no output.

mod common;
use common::*;
use std::process::Command;
use std::time::Duration;

#[test]
fn locate_impact_finds_the_strike_and_agrees_across_ranks() {
    let dir = scratch("cli_impact");
    let mesh_path = dir.join("plate.msh");
    // A free 300 × 200 × 20 mm plate, 6 × 4 × 1 cells (lifted to P2).
    diffsound::mesh::write_msh22_ascii(
        &diffsound::mesh::box_mesh([6, 4, 1], [0.3, 0.2, 0.02]),
        &mesh_path,
    )
    .unwrap();
    let bench = dir.join("bench");
    // Non-Rayleigh damping changes only the decay rates, which the amplitude fit measures.
    let mut cmd = Command::new("mpirun");
    cmd.args(["-np", "1"])
        .arg(generator())
        .args([
            "--cases",
            "2",
            "--seed",
            "8",
            "--mics",
            "4",
            "--effects",
            "non_rayleigh_damping",
            "--fmax",
            "9000",
            "--mesh",
        ])
        .arg(&mesh_path)
        .arg("--out")
        .arg(&bench);
    let run = run_with_limit(cmd, Duration::from_secs(300));
    assert!(run.success(), "{}", run.describe());

    for case in ["case_000", "case_001"] {
        let labels = read_json(&bench.join("labels").join(format!("{case}.json")));
        let (e, nu) = (
            format!("{}", labels["youngs_modulus"].as_f64().unwrap()),
            format!("{}", labels["poisson_ratio"].as_f64().unwrap()),
        );
        let meta = bench.join(case).join("metadata.toml");
        let out = bench.join(case).join("impact.h5");
        let args = [
            "locate-impact",
            "--case",
            meta.to_str().unwrap(),
            "--youngs",
            e.as_str(),
            "--poisson",
            nu.as_str(),
            "--transfer",
            "none",
            "--fmax",
            "9000",
            "--out",
            out.to_str().unwrap(),
        ];
        let run = mpirun(2, &args, Duration::from_secs(300));
        assert!(run.success(), "{case}: {}", run.describe());
        eprintln!("{case}:\n{}", run.stdout);
        for suffix in [
            "impact.h5",
            "impact.json",
            "impact_map.h5",
            "impact_map.xdmf",
            "impact_map.png",
        ] {
            let p = bench.join(case).join(suffix);
            assert!(
                p.is_file() && std::fs::metadata(&p).unwrap().len() > 0,
                "{case}: {} missing or empty",
                p.display()
            );
        }
        let report = read_json(&bench.join(case).join("impact.json"));
        assert_eq!(report["format"], "diffsound.locate_impact");
        // The map as Python sees it: scalars, one value per node.
        check_sidecar(
            &bench.join(case).join("impact_map.xdmf"),
            &[
                ("log_likelihood_ratio", "scalar"),
                ("posterior_density", "scalar"),
            ],
        );
        check_hdf5_types(&out, report["best_vertex"].as_i64().unwrap());
        let ev = &report["evaluation"];
        let truth = ev["true_vertex"].as_u64().unwrap();
        // The plate has three mirror planes: a strike is found when the best candidate lies on
        // the truth's symmetry orbit (vertices no mode cluster can tell apart), or right next to it.
        let orbit_error = ev["orbit_error_m"].as_f64().unwrap();
        assert!(
            ev["best_on_orbit"].as_bool().unwrap() || orbit_error < 0.03,
            "{case}: best vertex {} is {orbit_error} m from the orbit of the true vertex {truth}",
            report["best_vertex"]
        );
        let rank = ev["area_rank"].as_f64().unwrap();
        assert!(
            rank <= 0.1,
            "{case}: {rank} of the surface ranks at or above the truth"
        );
        // The map is a normalised posterior over the surface.
        let (posterior, _) = diffsound::io::results::read_dataset(&out, "/map/posterior").unwrap();
        assert!((posterior.iter().sum::<f64>() - 1.0).abs() < 1e-9);
        assert!(posterior.iter().all(|p| p.is_finite() && *p >= 0.0));
        assert!(report["strength"].as_f64().unwrap() > 0.0);
        assert!(!report["top"].as_array().unwrap().is_empty());
    }

    // 1 rank vs 2 ranks: the same map.
    let meta = bench.join("case_000").join("metadata.toml");
    let labels = read_json(&bench.join("labels").join("case_000.json"));
    let (e, nu) = (
        format!("{}", labels["youngs_modulus"].as_f64().unwrap()),
        format!("{}", labels["poisson_ratio"].as_f64().unwrap()),
    );
    let one = bench.join("case_000").join("np1.h5");
    let run = mpirun(
        1,
        &[
            "locate-impact",
            "--case",
            meta.to_str().unwrap(),
            "--youngs",
            e.as_str(),
            "--poisson",
            nu.as_str(),
            "--transfer",
            "none",
            "--fmax",
            "9000",
            "--out",
            one.to_str().unwrap(),
        ],
        Duration::from_secs(300),
    );
    assert!(run.success(), "{}", run.describe());
    let (a, b) = (
        read_json(&bench.join("case_000").join("np1.json")),
        read_json(&bench.join("case_000").join("impact.json")),
    );
    assert_eq!(a["best_vertex"], b["best_vertex"]);
    let (sa, sb) = (
        a["strength"].as_f64().unwrap(),
        b["strength"].as_f64().unwrap(),
    );
    assert!((sa / sb - 1.0).abs() < 1e-6, "strength {sa} vs {sb}");
    let (la, _) = diffsound::io::results::read_dataset(&one, "/map/log_likelihood").unwrap();
    let (lb, _) = diffsound::io::results::read_dataset(
        &bench.join("case_000").join("impact.h5"),
        "/map/log_likelihood",
    )
    .unwrap();
    let worst = la
        .iter()
        .zip(&lb)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max);
    assert!(
        worst < 1e-6,
        "log-likelihood maps differ between 1 and 2 ranks by {worst}"
    );
}

#[test]
fn locate_impact_rejects_bad_input_clearly() {
    let dir = scratch("cli_impact_bad");
    let wav = repo().join("examples/bowl/mic0.wav");
    let mesh = repo().join("examples/bowl/bowl.msh");
    let (wav, mesh) = (wav.to_str().unwrap(), mesh.to_str().unwrap());
    let out = dir.join("i.h5");
    let out = out.to_str().unwrap();
    let cases: [(&[&str], &str); 5] = [
        (
            &[
                "locate-impact",
                "--mesh",
                mesh,
                "--recording",
                "/nonexistent.wav",
                "--youngs",
                "7e10",
                "--poisson",
                "0.2",
                "--out",
                out,
            ],
            "does not exist",
        ),
        (
            &[
                "locate-impact",
                "--mesh",
                mesh,
                "--recording",
                wav,
                "--out",
                out,
            ],
            "material is needed",
        ),
        (
            &[
                "locate-impact",
                "--mesh",
                mesh,
                "--recording",
                wav,
                "--youngs",
                "7e10",
                "--out",
                out,
            ],
            "go together",
        ),
        (
            &[
                "locate-impact",
                "--mesh",
                mesh,
                "--recording",
                wav,
                "--youngs",
                "7e10",
                "--poisson",
                "0.2",
                "--transfer",
                "bem",
                "--out",
                out,
            ],
            "unknown transfer",
        ),
        (
            &[
                "locate-impact",
                "--mesh",
                mesh,
                "--recording",
                wav,
                "--youngs",
                "7e10",
                "--poisson",
                "0.2",
                "--true-vertex",
                "99999999",
                "--out",
                out,
            ],
            "does not exist",
        ),
    ];
    for (args, expect) in cases {
        let run = mpirun(2, args, Duration::from_secs(120));
        assert!(
            !run.success() && !run.timed_out,
            "{args:?} should fail: {}",
            run.describe()
        );
        assert!(
            run.stderr.contains(expect),
            "{args:?}: expected {expect:?} in\n{}",
            run.stderr
        );
        assert!(!run.stderr.contains("panicked"), "{}", run.stderr);
    }
    for f in ["i.h5", "i.json", "i_map.h5", "i_map.xdmf", "i_map.png"] {
        assert!(!dir.join(f).exists(), "no output after a failed run: {f}");
    }
}

/// The HDF5 result's types (format 2): vertex indices integers, flags u8, lists arrays.
fn check_hdf5_types(out: &std::path::Path, best_vertex: i64) {
    use diffsound::io::results::{read_attribute, read_integers, AttrValue};
    let attr = |g: &str, k: &str| read_attribute(out, g, k).unwrap();
    assert_eq!(attr("/", "format_version"), AttrValue::Integer(2));
    assert_eq!(attr("/", "n_ranks"), AttrValue::Integer(2));
    assert_eq!(
        attr("/impact", "best_vertex"),
        AttrValue::Integer(best_vertex)
    );
    assert!(matches!(attr("/", "recordings"), AttrValue::Texts(v) if v.len() == 4));
    assert_eq!(attr("/material", "source"), AttrValue::Text("given".into()));
    let (vertices, _) = read_integers(out, "/map/vertex").unwrap();
    assert!(vertices.contains(&best_vertex));
    let (heard, _) = read_integers(out, "/clusters/heard").unwrap();
    assert!(heard.iter().all(|&h| h == 0 || h == 1));
    let (poles, _) = read_integers(out, "/poles/cluster").unwrap();
    assert!(poles.iter().all(|&c| c >= -1));
}
