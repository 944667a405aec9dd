//! Diagnostic (issue 7): dλ_k/dt of the hollow triangulated ellipsoid of `tests/mpi_sensitivity.rs`
//! (12 cells, t = 0.45, 8 modes) on the plain grid and on the grid refined once near the inner
//! walls of t ∈ [0.40, 0.50], for the curved and the straight body, against central differences
//! with h = 1e-5 and 1e-6, per mode (relative to λ_k/t; clusters are not averaged here).
//!
//!   mpirun -np 2 target/release/examples/wall_chain_probe
use diffsound::fem::Material;
use diffsound::inverse::shape::{reference_depth, refine_near_wall, ShapeFamily};
use diffsound::mesh;
use diffsound::petsc::Petsc;

fn ellipsoid_surface(axes: [f64; 3], rings: usize) -> mesh::TriangleSurface {
    let segments = 2 * rings;
    let mut vertices = vec![[0.0, 0.0, axes[2]]];
    for i in 1..rings {
        let theta = std::f64::consts::PI * i as f64 / rings as f64;
        for j in 0..segments {
            let phi = 2.0 * std::f64::consts::PI * j as f64 / segments as f64;
            vertices.push([axes[0] * theta.sin() * phi.cos(), axes[1] * theta.sin() * phi.sin(), axes[2] * theta.cos()]);
        }
    }
    vertices.push([0.0, 0.0, -axes[2]]);
    let south = vertices.len() - 1;
    let ring = |i: usize, j: usize| 1 + (i - 1) * segments + j % segments;
    let mut triangles = Vec::new();
    for j in 0..segments {
        triangles.push([0, ring(1, j), ring(1, j + 1)]);
        triangles.push([south, ring(rings - 1, j + 1), ring(rings - 1, j)]);
    }
    for i in 1..rings - 1 {
        for j in 0..segments {
            triangles.push([ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)]);
            triangles.push([ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)]);
        }
    }
    mesh::TriangleSurface { vertices, triangles }
}

fn main() {
    let universe = mpi::initialize().unwrap();
    let petsc = Petsc::initialize(universe, "probe", &[]).unwrap();
    let surface = ellipsoid_surface([0.05, 0.04, 0.03], 24);
    let sdf = std::sync::Arc::new(mesh::SignedDistance::new(&surface).unwrap());
    let depth = reference_depth(&sdf, &surface).unwrap();
    let grid0 = mesh::BackgroundGrid::covering([-0.05, -0.04, -0.03], [0.05, 0.04, 0.03], 12, 1.0).unwrap();
    let solid0 = sdf.evaluate(&grid0.vertex_positions());
    let options = mesh::MarchingOptions::default();
    let material = Material::preset("ceramic").unwrap();
    let n = 8;
    let t0 = 0.45;
    for refined in [false, true] {
        let (grid, solid) = if refined { refine_near_wall(&grid0, &solid0, &sdf, depth, (0.40, 0.50), 1).unwrap() } else { (grid0.clone(), solid0.clone()) };
        for curved in [true, false] {
            let family = ShapeFamily::Thickness { solid: solid.clone(), depth, surface: curved.then(|| sdf.clone()) };
            let (base, d) = family.spectrum(&petsc, &grid, t0, &options, &material, n, true).unwrap();
            let d = d.unwrap();
            for h in [1e-5, 1e-6] {
                let (p, _) = family.spectrum(&petsc, &grid, t0 + h, &options, &material, n, false).unwrap();
                let (m, _) = family.spectrum(&petsc, &grid, t0 - h, &options, &material, n, false).unwrap();
                let rows: Vec<String> = (0..n).map(|k| format!("{:+.2e}", (d[k] - (p.eigenvalues[k] - m.eigenvalues[k]) / (2.0 * h)) / (base.eigenvalues[k] / t0))).collect();
                if petsc.rank() == 0 {
                    println!("refined {refined} curved {curved} h {h:e}: tets {} clusters {:?} λ {:?}\n   rel err {}", base.tets, base.clusters, base.eigenvalues.iter().map(|l| format!("{:.4e}", l)).collect::<Vec<_>>(), rows.join(" "));
                }
            }
        }
    }
}
