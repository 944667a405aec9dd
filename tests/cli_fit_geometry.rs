//! End-to-end run of `diffsound fit-geometry` (issue 7, task 3) on a tiny case under
//! `mpirun -np 2`: a box written as an OBJ file here, 6³ voxels, a 10-cell fit grid, a 14-cell
//! target, four modes, three refinement steps. Checks the HDF5 result (metrics before/after
//! and their sanity, eigenvalues, history with per-step timings, network parameters), the
//! ParaView mesh and the picture; and that bad input fails with a message and no output.

mod common;
use common::*;
use diffsound::io::results::read_dataset;
use std::time::Duration;

const LIMIT: Duration = Duration::from_secs(120);

const TINY: [&str; 18] = [
    "--units",
    "mm",
    "--voxels",
    "6",
    "--cells",
    "10",
    "--target-cells",
    "14",
    "--modes",
    "4",
    "--steps",
    "3",
    "--prefit-steps",
    "300",
    "--hidden",
    "16,16",
    "--octaves",
    "2",
];

#[test]
fn a_tiny_box_is_prefitted_refined_and_written() {
    let dir = scratch("cli_fit_geometry");
    let solid = box_obj(&dir, "box.obj", [60.0, 40.0, 30.0]);
    let out = dir.join("geometry.h5");
    let mut args = vec![
        "fit-geometry",
        "--surface",
        s(&solid),
        "--out",
        s(&out),
        "-v",
    ];
    args.extend(TINY);
    let run = mpirun(2, &args, LIMIT);
    assert!(run.success(), "{}", run.describe());
    assert!(
        run.stderr.contains("pre-fit:") && run.stderr.contains("step   3:"),
        "progress on stderr:\n{}",
        run.stderr
    );
    // The default body has the curved boundary, and the settings say so.
    match diffsound::io::results::read_attribute(&out, "/", "settings_json").unwrap() {
        diffsound::io::results::AttrValue::Text(json) => {
            assert!(json.contains("\"curved_boundary\":true"), "{json}")
        }
        other => panic!("settings_json is not text: {other:?}"),
    }
    // The box is 60 × 40 × 30 mm: every distance is a fraction of it, the IoU close to 1.
    for group in ["voxels", "before", "after", "floor"] {
        let g = format!("/metrics/{group}");
        let (c, h, iou) = (
            number_attribute(&out, &g, "chamfer"),
            number_attribute(&out, &g, "hausdorff"),
            number_attribute(&out, &g, "iou"),
        );
        assert!(
            c.is_finite() && (0.0..0.01).contains(&c),
            "{group}: Chamfer {c} m"
        );
        assert!(h >= c && h < 0.03, "{group}: Hausdorff {h} m");
        assert!(iou > 0.6 && iou <= 1.0, "{group}: IoU {iou}");
    }
    // Six voxels across a box put the centres of the outer layer inside it: the staircase is
    // the box itself.
    assert!(number_attribute(&out, "/metrics/voxels", "iou") > 0.99);
    for group in ["before", "after", "floor"] {
        let e = number_attribute(&out, &format!("/metrics/{group}"), "rms_frequency_error");
        assert!(e.is_finite() && e < 0.5, "{group}: rms frequency error {e}");
    }
    // Best of the evaluations: never worse than the pre-fit.
    let (loss, _) = read_dataset(&out, "/refine/history/loss").unwrap();
    assert_eq!(loss.len(), 4, "the pre-fit and three updates");
    let best = number_attribute(&out, "/refine", "best_step") as usize;
    assert!(loss[best] <= loss[0]);
    // The check on the target's cell count decides between the refined and the pre-fitted field.
    let (before, after) = (
        number_attribute(&out, "/check", "before_loss"),
        number_attribute(&out, "/check", "after_loss"),
    );
    assert!(
        before.is_finite() && after.is_finite() && before >= 0.0 && after >= 0.0,
        "{before} {after}"
    );
    if number_attribute(&out, "/check", "refined_kept") == 1.0 {
        assert!(
            best > 0 && after < before,
            "kept: best step {best}, {before} → {after}"
        );
    } else {
        assert_eq!(best, 0, "not kept: the answer is the pre-fit");
    }
    for column in [
        "eigen_loss",
        "voxel_loss",
        "eikonal_loss",
        "tets",
        "meshing_s",
        "assembly_s",
        "solve_s",
        "gradient_s",
        "network_s",
        "failed",
    ] {
        let (v, _) = read_dataset(&out, &format!("/refine/history/{column}")).unwrap();
        assert_eq!(v.len(), 4, "{column}");
        if column.ends_with("_s") {
            assert!(
                v.iter().all(|x| x.is_finite() && *x >= 0.0),
                "{column}: {v:?}"
            );
        }
    }
    let (target, _) = read_dataset(&out, "/modes/target_frequency_hz").unwrap();
    let (after, _) = read_dataset(&out, "/modes/after_frequency_hz").unwrap();
    assert_eq!((target.len(), after.len()), (4, 4));
    assert!(
        target.windows(2).all(|w| w[0] <= w[1]) && target[0] > 1000.0,
        "{target:?}"
    );
    let (theta, _) = read_dataset(&out, "/network/parameters").unwrap();
    // 15 features → 16 → 16 → 1.
    assert_eq!(theta.len(), 15 * 16 + 16 + 16 * 16 + 16 + 16 + 1);
    let (prefit, _) = read_dataset(&out, "/prefit/loss").unwrap();
    assert_eq!(prefit.len(), 300);
    assert!(number_attribute(&out, "/prefit", "centre_accuracy") > 0.9);
    assert!(number_attribute(&out, "/timings", "total") > 0.0);
    // The refined body for ParaView, and the picture.
    let summary = diffsound::io::read_modes(&dir.join("geometry_mesh.h5")).unwrap();
    assert_eq!(summary.nodes_per_tet, 10);
    assert!(summary.n_modes >= 4 && summary.n_tets > 50);
    let xdmf = std::fs::read_to_string(dir.join("geometry_mesh.xdmf")).unwrap();
    assert!(xdmf.contains("Tetrahedron_10") && xdmf.contains("geometry_mesh.h5:/mesh/nodes"));
    check_sidecar(&dir.join("geometry_mesh.xdmf"), &[]);
    let png = std::fs::read(dir.join("geometry.png")).unwrap();
    assert!(png.len() > 1000 && png.starts_with(b"\x89PNG"));
}

#[test]
fn bad_input_fails_cleanly_without_output() {
    let dir = scratch("cli_fit_geometry_bad");
    let solid = box_obj(&dir, "box.obj", [60.0, 40.0, 30.0]);
    let out = dir.join("never.h5");
    let garbage = dir.join("garbage.obj");
    std::fs::write(&garbage, "v 0 0 0\nf 1 2 3\n").unwrap();
    let missing = dir.join("missing.obj");
    let config = dir.join("typo.toml");
    std::fs::write(&config, "[geometry]\nvoxles = 8\n").unwrap();
    let nowhere = dir.join("no/such/dir/x.h5");
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (
            vec!["fit-geometry", "--surface", s(&missing)],
            "does not exist",
        ),
        (vec!["fit-geometry"], "no surface"),
        (
            vec!["fit-geometry", "--surface", s(&solid), "--voxels", "1"],
            "voxels must lie in",
        ),
        (
            vec![
                "fit-geometry",
                "--surface",
                s(&solid),
                "--cells",
                "16",
                "--target-cells",
                "14",
            ],
            "target grid at least as many as the fit grid",
        ),
        (
            vec![
                "fit-geometry",
                "--surface",
                s(&solid),
                "--learning-rate",
                "-1",
            ],
            "learning_rate must be positive",
        ),
        (
            vec!["fit-geometry", "--surface", s(&solid), "--hidden", "0"],
            "hidden layers",
        ),
        (
            vec!["fit-geometry", "--surface", s(&solid), "--method", "newton"],
            "adam or gauss_newton",
        ),
        (
            vec!["fit-geometry", "--surface", s(&solid), "--damping", "0"],
            "damping must be positive",
        ),
        (
            vec![
                "fit-geometry",
                "--surface",
                s(&solid),
                "--free-scale",
                "--modes",
                "1",
            ],
            "at least two modes",
        ),
        (
            vec!["fit-geometry", "--surface", s(&garbage)],
            "garbage.obj",
        ),
        (
            vec![
                "fit-geometry",
                "--config",
                s(&config),
                "--surface",
                s(&solid),
            ],
            "voxles",
        ),
        (
            vec![
                "fit-geometry",
                "--surface",
                s(&solid),
                "--material",
                "cheese",
            ],
            "unknown material",
        ),
    ];
    for (mut args, expected) in cases {
        args.extend(["--out", s(&out)]);
        let run = mpirun(2, &args, LIMIT);
        assert!(!run.success(), "{args:?} should fail");
        assert!(
            run.stderr.contains(expected),
            "{args:?}: expected {expected:?} in\n{}",
            run.describe()
        );
        assert!(
            !out.exists() && !dir.join("never_mesh.h5").exists() && !dir.join("never.png").exists(),
            "{args:?} left output"
        );
    }
    let run = mpirun(
        1,
        &["fit-geometry", "--surface", s(&solid), "--out", s(&nowhere)],
        LIMIT,
    );
    assert!(
        !run.success() && run.stderr.contains("does not exist"),
        "{}",
        run.describe()
    );
}
