//! End-to-end runs of `diffsound fit-thickness` and `fit-morph` (issue 7) on small grids:
//! boxes written as OBJ files here, synthesised targets on a finer shifted grid, the result
//! files and the ParaView sidecar checked, and bad input failing with a message and no output.

mod common;
use common::*;
use diffsound::io::results::read_dataset;
use std::time::Duration;

const LIMIT: Duration = Duration::from_secs(300);

const SMALL: [&str; 10] = [
    "--units",
    "mm",
    "--cells",
    "12,14",
    "--modes",
    "4",
    "--scan-points",
    "5",
    "--max-refinements",
    "3",
];

#[test]
fn thickness_and_morph_fits_write_results_and_a_paraview_mesh() {
    let dir = scratch("cli_fit_shape");
    let solid = box_obj(&dir, "box.obj", [60.0, 40.0, 30.0]);
    let out = dir.join("thickness.h5");
    let mut args = vec![
        "fit-thickness",
        "--surface",
        s(&solid),
        "--target-thickness",
        "0.5",
        "--target-cells",
        "18",
        "--out",
        s(&out),
        "-v",
    ];
    args.extend(SMALL);
    let run = mpirun(2, &args, LIMIT);
    assert!(run.success(), "{}", run.describe());
    assert!(
        run.stderr.contains("level 0 (12 cells) scan"),
        "progress per evaluation on stderr:\n{}",
        run.stderr
    );
    // Grids this coarse (the wall is 1–2 cells) only get near; the benchmark measures accuracy.
    let t = number_attribute(&out, "/fit", "parameter");
    assert!((t - 0.5).abs() < 0.1, "thickness {t}");
    let finest = number_attribute(&out, "/fit", "finest_level_parameter");
    assert!(
        (finest - 0.5).abs() < 0.06,
        "finest-level thickness {finest}"
    );
    assert_eq!(number_attribute(&out, "/fit", "true_parameter"), 0.5);
    assert!((number_attribute(&out, "/fit", "abs_error") - (t - 0.5).abs()).abs() < 1e-12);
    // S of a 60 × 40 × 30 mm box is half its smallest side.
    assert!((number_attribute(&out, "/shape", "reference_depth") - 0.015).abs() < 1e-9);
    // The default boundary is curved. The body's volume is the hollow box's at the answer t
    // (the inner wall at depth 15t mm) within 5 %: the cavity's edges and corners are cut by
    // the 14-cell grid.
    assert_eq!(number_attribute(&out, "/shape", "curved_boundary"), 1.0);
    let volume = number_attribute(&out, "/shape", "volume");
    let d = 30.0 * t;
    let hollow = 1e-9 * (60.0 * 40.0 * 30.0 - (60.0 - d) * (40.0 - d) * (30.0 - d));
    assert!(
        (volume / hollow - 1.0).abs() < 0.05,
        "volume {volume:.4e} m³ against {hollow:.4e} m³ at t = {t}"
    );
    let (levels, _) = read_dataset(&out, "/fit/levels/parameter").unwrap();
    assert_eq!(levels.len(), 2);
    let (loss, _) = read_dataset(&out, "/fit/history/loss").unwrap();
    let n = loss.len();
    assert!(n >= 7, "5 scan points and refinements, got {n}");
    for column in [
        "level",
        "phase",
        "parameter",
        "gradient",
        "tets",
        "meshing_s",
        "assembly_s",
        "solve_s",
        "gradient_s",
        "failed",
    ] {
        let (v, _) = read_dataset(&out, &format!("/fit/history/{column}")).unwrap();
        assert_eq!(v.len(), n, "{column}");
    }
    let (solve, _) = read_dataset(&out, "/fit/history/solve_s").unwrap();
    assert!(solve.iter().all(|s| s.is_finite() && *s >= 0.0));
    let (target, _) = read_dataset(&out, "/modes/target_frequency_hz").unwrap();
    let (fitted, _) = read_dataset(&out, "/modes/fitted_frequency_hz").unwrap();
    assert_eq!((target.len(), fitted.len()), (4, 4));
    assert!(
        target
            .iter()
            .zip(&fitted)
            .all(|(a, b)| (a / b - 1.0).abs() < 0.05),
        "{target:?} vs {fitted:?}"
    );
    // The fitted body for ParaView: P2 mesh with its modes and the XDMF sidecar.
    let mesh = dir.join("thickness_mesh.h5");
    let summary = diffsound::io::read_modes(&mesh).unwrap();
    assert_eq!(summary.nodes_per_tet, 10);
    assert!(summary.n_modes >= 4 && summary.n_tets > 100);
    let xdmf = std::fs::read_to_string(dir.join("thickness_mesh.xdmf")).unwrap();
    assert!(xdmf.contains("Tetrahedron_10") && xdmf.contains("thickness_mesh.h5:/mesh/nodes"));
    check_sidecar(&dir.join("thickness_mesh.xdmf"), &[]);

    // A morph between two boxes of different proportions, from a target file in Hz.
    let a = box_obj(&dir, "a.obj", [60.0, 40.0, 30.0]);
    let b = box_obj(&dir, "b.obj", [45.0, 45.0, 40.0]);
    let morph = dir.join("morph.h5");
    let mut args = vec![
        "fit-morph",
        "--shape-a",
        s(&a),
        "--shape-b",
        s(&b),
        "--target-weight",
        "0.3",
        "--target-cells",
        "18",
        "--out",
        s(&morph),
    ];
    args.extend(SMALL);
    let run = mpirun(1, &args, LIMIT);
    assert!(run.success(), "{}", run.describe());
    let c = number_attribute(&morph, "/fit", "parameter");
    assert!((c - 0.3).abs() < 0.1, "morph weight {c}");
    assert!(dir.join("morph_mesh.xdmf").is_file());
    // The same target as a file of frequencies, for the run with replicas below.
    let (hz, _) = read_dataset(&morph, "/modes/target_frequency_hz").unwrap();
    let file = dir.join("target.txt");
    std::fs::write(
        &file,
        format!(
            "# target, Hz\n{}\n",
            hz.iter()
                .map(|f| f.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    )
    .unwrap();
    // Two grid replicas of the finer level: one more level of the same spacing, half a cell off.
    let replicas = dir.join("morph_replicas.h5");
    let mut args = vec![
        "fit-morph",
        "--shape-a",
        s(&a),
        "--shape-b",
        s(&b),
        "--target",
        s(&file),
        "--target-spacing",
        "0.003",
        "--replicas",
        "2",
        "--out",
        s(&replicas),
    ];
    args.extend(SMALL);
    let run = mpirun(1, &args, LIMIT);
    assert!(run.success(), "{}", run.describe());
    let (cells, _) = read_dataset(&replicas, "/fit/levels/cells").unwrap();
    assert_eq!(cells, vec![12.0, 14.0, 14.0]);
    // Its first two levels are the plain run's grids: from the target file they must reach the
    // plain run's answers (the fit does not need to know where the target came from).
    let (by_level, _) = read_dataset(&replicas, "/fit/levels/parameter").unwrap();
    let finest = number_attribute(&morph, "/fit", "finest_level_parameter");
    assert!(
        (by_level[1] - finest).abs() < 1e-9,
        "same target, same answer on the same grid: {} from the file, {finest} synthesised",
        by_level[1]
    );
    let (spacing, _) = read_dataset(&replicas, "/fit/levels/spacing").unwrap();
    assert!((spacing[1] - spacing[2]).abs() < 1e-15, "{spacing:?}");
    let c_replicas = number_attribute(&replicas, "/fit", "parameter");
    assert!(
        (c_replicas - 0.3).abs() < 0.1,
        "morph weight with replicas {c_replicas}"
    );
}

/// `fit-thickness` of the 60 × 40 × 30 mm box to t* = 0.5 on 2 ranks (4 modes, 5 scan points,
/// 3 refinements) with `grids` (the target's and the fit's grids and their options), in the
/// scratch directory `name`. The run must succeed; returns it and its result file.
fn fit_box_thickness(name: &str, grids: &[&str]) -> (Run, std::path::PathBuf) {
    let dir = scratch(name);
    let solid = box_obj(&dir, "box.obj", [60.0, 40.0, 30.0]);
    let out = dir.join("thickness.h5");
    let mut args = vec![
        "fit-thickness",
        "--surface",
        s(&solid),
        "--target-thickness",
        "0.5",
        "--units",
        "mm",
        "--modes",
        "4",
        "--scan-points",
        "5",
        "--max-refinements",
        "3",
        "--out",
        s(&out),
    ];
    args.extend(grids);
    let run = mpirun(2, &args, LIMIT);
    assert!(run.success(), "{}", run.describe());
    (run, out)
}

/// The curved thickness body answers with its finest level, so `--replicas` replicates that
/// level alone, and the answer is the mean over its grids.
#[test]
fn thickness_replicas_go_on_the_finest_level_alone() {
    let (_, out) = fit_box_thickness(
        "cli_fit_shape_replicas",
        &[
            "--target-cells",
            "16",
            "--cells",
            "10,12,14",
            "--replicas",
            "2",
        ],
    );
    let (cells, _) = read_dataset(&out, "/fit/levels/cells").unwrap();
    assert_eq!(cells, vec![10.0, 12.0, 14.0, 14.0]);
    let (levels, _) = read_dataset(&out, "/fit/levels/parameter").unwrap();
    let answer = number_attribute(&out, "/fit", "parameter");
    assert!(
        (answer - 0.5 * (levels[2] + levels[3])).abs() < 1e-12,
        "answer {answer}, levels {levels:?}"
    );
    assert!((number_attribute(&out, "/fit", "finest_level_parameter") - answer).abs() < 1e-12);
    assert!((answer - 0.5).abs() < 0.1, "thickness {answer}");
}

/// `--wall-refinement 1`: the scanned level stays plain, the finer one is refined near the
/// walls around the coarser answer (the box's edges and corners are creases the samples do not
/// resolve), and the result records it.
#[test]
fn thickness_fit_refines_the_finer_levels_near_the_walls() {
    let (run, out) = fit_box_thickness(
        "cli_fit_shape_wall",
        &[
            "--target-cells",
            "14",
            "--cells",
            "10,12",
            "--wall-refinement",
            "1",
        ],
    );
    assert_eq!(number_attribute(&out, "/fit", "wall_refinement"), 1.0);
    let (levels, _) = read_dataset(&out, "/fit/levels/parameter").unwrap();
    let (centres, _) = read_dataset(&out, "/fit/levels/wall_centre").unwrap();
    let (tets, _) = read_dataset(&out, "/fit/levels/grid_tets").unwrap();
    let (cells, _) = read_dataset(&out, "/fit/levels/cells").unwrap();
    assert!(
        centres[0].is_nan(),
        "the scanned level is not refined: {centres:?}"
    );
    assert!(
        (centres[1] - levels[0]).abs() < 1e-12,
        "the finer level is refined around the coarser answer: {centres:?} vs {levels:?}"
    );
    // The box's plain 12-cell grid: 12 × 9 × 7 cells of 6 mm (one of margin each side), 6 tets each.
    let plain = 6.0
        * cells[1]
        * ((40.0 / 60.0 * (cells[1] - 2.0)).ceil() + 2.0)
        * ((30.0 / 60.0 * (cells[1] - 2.0)).ceil() + 2.0);
    assert!(
        tets[1] > plain,
        "refined grid {} tets against {plain} plain",
        tets[1]
    );
    let answer = number_attribute(&out, "/fit", "parameter");
    assert!((answer - 0.5).abs() < 0.1, "thickness {answer}");
    assert!(
        run.stdout.contains("refined near the walls"),
        "{}",
        run.describe()
    );
}

#[test]
fn bad_input_fails_cleanly_without_output() {
    let dir = scratch("cli_fit_shape_bad");
    let solid = box_obj(&dir, "box.obj", [60.0, 40.0, 30.0]);
    let out = dir.join("never.h5");
    let garbage = dir.join("garbage.obj");
    std::fs::write(&garbage, "v 0 0 0\nf 1 2 3\n").unwrap();
    let bad_target = dir.join("bad.txt");
    std::fs::write(&bad_target, "100 two 300\n").unwrap();
    let missing = dir.join("missing.obj");
    let config = dir.join("typo.toml");
    std::fs::write(&config, "[fit]\nmodse = 8\n").unwrap();
    let straight = dir.join("straight.toml");
    std::fs::write(&straight, "straight_boundary = true\n").unwrap();
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (
            vec![
                "fit-thickness",
                "--surface",
                s(&missing),
                "--target-thickness",
                "0.5",
            ],
            "does not exist",
        ),
        (vec!["fit-thickness", "--surface", s(&solid)], "no target"),
        (
            vec![
                "fit-thickness",
                "--surface",
                s(&solid),
                "--target-thickness",
                "1.5",
            ],
            "outside the bounds",
        ),
        (
            vec![
                "fit-thickness",
                "--surface",
                s(&solid),
                "--target-thickness",
                "0.5",
                "--cells",
                "12,14",
                "--target-cells",
                "14",
            ],
            "--target-cells must exceed",
        ),
        (
            vec![
                "fit-thickness",
                "--surface",
                s(&solid),
                "--target",
                s(&bad_target),
            ],
            "\"two\" is not a number",
        ),
        (
            vec![
                "fit-thickness",
                "--surface",
                s(&garbage),
                "--target-thickness",
                "0.5",
            ],
            "garbage.obj",
        ),
        (
            vec![
                "fit-thickness",
                "--config",
                s(&config),
                "--surface",
                s(&solid),
                "--target-thickness",
                "0.5",
            ],
            "modse",
        ),
        (
            vec![
                "fit-morph",
                "--shape-a",
                s(&solid),
                "--target-weight",
                "0.5",
            ],
            "no shape B",
        ),
        (
            vec![
                "fit-morph",
                "--config",
                s(&straight),
                "--shape-a",
                s(&solid),
                "--shape-b",
                s(&solid),
                "--target-weight",
                "0.5",
            ],
            "straight_boundary",
        ),
        (
            vec![
                "fit-thickness",
                "--surface",
                s(&solid),
                "--target-thickness",
                "0.5",
                "--replicas",
                "5",
            ],
            "--replicas must lie in 1..=4",
        ),
        (
            vec![
                "fit-thickness",
                "--surface",
                s(&solid),
                "--target-thickness",
                "0.5",
                "--extrapolate",
                "--no-extrapolate",
            ],
            "exclude each other",
        ),
        (
            vec![
                "fit-thickness",
                "--surface",
                s(&solid),
                "--target-thickness",
                "0.5",
                "--wall-refinement",
                "4",
            ],
            "wall_refinement must lie in 0..=3",
        ),
        (
            vec![
                "fit-thickness",
                "--surface",
                s(&solid),
                "--target-thickness",
                "0.5",
                "--wall-refinement",
                "1",
                "--straight-boundary",
            ],
            "needs the curved thickness body",
        ),
        (
            vec![
                "fit-thickness",
                "--surface",
                s(&solid),
                "--target-thickness",
                "0.5",
                "--wall-tolerance",
                "-1",
            ],
            "wall_tolerance must be ≥ 0",
        ),
        (
            vec![
                "fit-morph",
                "--shape-a",
                s(&solid),
                "--shape-b",
                s(&solid),
                "--target-weight",
                "0.5",
                "--cells",
                "14,12",
            ],
            "must increase",
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
            !out.exists() && !dir.join("never_mesh.h5").exists(),
            "{args:?} left output"
        );
    }
}
