//! Convergence of P2 (isoparametric, curved) elements to the analytic modes of a free elastic
//! sphere (Lamb 1882; see `diffsound::eigen::analytic`), on 2 MPI ranks.
//!
//! The sphere (radius 0.5 m) is meshed by gmsh with second-order tets whose boundary mid-edge
//! nodes lie on the sphere, at three element sizes. Each analytic mode of degree ℓ is a
//! (2ℓ+1)-fold degenerate cluster; the mesh splits it slightly, so we compare the mean frequency
//! of each cluster. P2 eigenvalue errors converge as O(h⁴) for smooth modes.

mod common;
use common::*;
use diffsound::eigen::analytic;
use std::time::Duration;

const RADIUS: f64 = 0.5;
const E: f64 = 72e9;
const NU: f64 = 0.19;
const RHO: f64 = 2700.0;

#[test]
fn p2_modes_of_a_free_sphere_converge_at_fourth_order() {
    let dir = scratch("analytic_sphere");
    let geo = fixture("analytic/sphere.geo");
    let exact = analytic::sphere_modes(RADIUS, E, NU, RHO, 4500.0);
    // Torsional ℓ=2 (5), spheroidal ℓ=2 (5), spheroidal ℓ=1 (3), torsional ℓ=3 (7),
    // spheroidal ℓ=3 (7), breathing ℓ=0 (1): 28 modes.
    assert!(exact.len() >= 6, "analytic list too short: {exact:?}");
    let clusters: Vec<_> = exact.iter().take(6).collect();
    let n_modes: usize = clusters.iter().map(|m| m.multiplicity).sum();

    let sizes = [0.15, 0.1, 0.07];
    let mut errors: Vec<Vec<f64>> = Vec::new();
    for &h in &sizes {
        let mesh = dir.join(format!("sphere_{h}.msh"));
        gmsh_mesh(&geo, h, 2, &mesh);
        let json = dir.join(format!("sphere_{h}.json"));
        let out = dir.join(format!("sphere_{h}.h5"));
        let run = mpirun(
            2,
            &[
                "modes",
                "--mesh",
                mesh.to_str().unwrap(),
                "--youngs",
                "72e9",
                "--poisson",
                "0.19",
                "--density",
                "2700",
                "--modes",
                &n_modes.to_string(),
                "--out",
                out.to_str().unwrap(),
                "--timings-json",
                json.to_str().unwrap(),
            ],
            Duration::from_secs(300),
        );
        assert!(run.success(), "{}", run.describe());
        let freqs = f64s(&read_json(&json), "frequencies_hz");
        assert!(freqs.len() >= n_modes);
        let mut start = 0;
        let mut errs = Vec::new();
        for m in &clusters {
            let group = &freqs[start..start + m.multiplicity];
            let mean = group.iter().sum::<f64>() / group.len() as f64;
            // The cluster must be tight compared with the gap to its neighbours.
            let spread = group.last().unwrap() - group.first().unwrap();
            assert!(
                spread < 1e-2 * m.frequency_hz,
                "h={h}: cluster {:?} ℓ={} spread {spread} Hz: {group:?}",
                m.family,
                m.degree
            );
            errs.push((mean - m.frequency_hz).abs() / m.frequency_hz);
            start += m.multiplicity;
        }
        println!(
            "h = {h}: relative frequency errors per cluster {:?}",
            errs.iter().map(|e| format!("{e:.3e}")).collect::<Vec<_>>()
        );
        errors.push(errs);
    }
    for (k, m) in clusters.iter().enumerate() {
        let (e1, e2) = (errors[1][k], errors[2][k]);
        let order = (e1 / e2).ln() / (sizes[1] / sizes[2]).ln();
        println!(
            "{:?} ℓ={} n={}: {:.4} Hz, finest error {:.2e}, observed order {order:.2}",
            m.family, m.degree, m.overtone, m.frequency_hz, e2
        );
        assert!(e2 < 2e-4, "finest mesh error {e2:e} too large for {m:?}");
        assert!(
            order > 3.0,
            "observed convergence order {order} below 3 for {m:?} (errors {e1:e} → {e2:e})"
        );
    }
}
