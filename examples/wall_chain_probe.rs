//! Diagnostic (issue 7): dλ_k/dt of the hollow triangulated ellipsoid of `tests/mpi_sensitivity.rs`
//! (12 cells, t = 0.45, 8 modes) on the plain grid and on the grid refined once near the inner
//! walls of t ∈ [0.40, 0.50], for the curved and the straight body, against central differences
//! with h = 1e-5 and 1e-6, per mode (relative to λ_k/t; clusters are not averaged here).
//!
//!   mpirun -np 2 target/release/examples/wall_chain_probe
use diffsound::fem::Material;
use diffsound::inverse::shape::{refine_near_wall, ShapeFamily};
use diffsound::petsc::Petsc;
use diffsound::shape;
use diffsound::shape::reference_depth;

fn main() {
    let universe = mpi::initialize().unwrap();
    let petsc = Petsc::initialize(universe, "probe", &[]).unwrap();
    let surface = shape::TriangleSurface::ellipsoid([0.05, 0.04, 0.03], 24);
    let sdf = std::sync::Arc::new(shape::SignedDistance::new(&surface).unwrap());
    let depth = reference_depth(&sdf, &surface).unwrap();
    let grid0 = shape::BackgroundGrid::covering([-0.05, -0.04, -0.03], [0.05, 0.04, 0.03], 12, 1.0)
        .unwrap();
    let solid0 = sdf.evaluate(&grid0.vertex_positions());
    let options = shape::MarchingOptions::default();
    let material = Material::preset("ceramic").unwrap();
    let n = 8;
    let t0 = 0.45;
    for refined in [false, true] {
        let (grid, solid) = if refined {
            refine_near_wall(&grid0, &solid0, &sdf, depth, (0.40, 0.50), 1).unwrap()
        } else {
            (grid0.clone(), solid0.clone())
        };
        for curved in [true, false] {
            let family = ShapeFamily::Thickness {
                solid: solid.clone(),
                depth,
                surface: curved.then(|| sdf.clone()),
            };
            let (base, d) = family
                .spectrum(&petsc, &grid, t0, &options, &material, n, true)
                .unwrap();
            let d = d.unwrap();
            for h in [1e-5, 1e-6] {
                let (p, _) = family
                    .spectrum(&petsc, &grid, t0 + h, &options, &material, n, false)
                    .unwrap();
                let (m, _) = family
                    .spectrum(&petsc, &grid, t0 - h, &options, &material, n, false)
                    .unwrap();
                let rows: Vec<String> = (0..n)
                    .map(|k| {
                        format!(
                            "{:+.2e}",
                            (d[k] - (p.eigenvalues[k] - m.eigenvalues[k]) / (2.0 * h))
                                / (base.eigenvalues[k] / t0)
                        )
                    })
                    .collect();
                if petsc.rank() == 0 {
                    println!("refined {refined} curved {curved} h {h:e}: tets {} clusters {:?} λ {:?}\n   rel err {}", base.tets, base.clusters, base.eigenvalues.iter().map(|l| format!("{:.4e}", l)).collect::<Vec<_>>(), rows.join(" "));
                }
            }
        }
    }
}
