//! Experiment: the modes of a body with a lumped mass on some of its vertices, by a full solve
//! (the reference a Ritz model of the mass is judged against).
//!
//! `mass_probe MESH E NU RHO MASS_KG FMAX_HZ NODE...`: prints the elastic frequencies up to
//! FMAX without the mass and with MASS_KG spread evenly over the nodes (original numbering,
//! three components each), one line per mode.
use diffsound::assembly;
use diffsound::eigen::{self, EigenConfig, ModeRequest};
use diffsound::fem::Material;
use diffsound::mesh;
use diffsound::petsc::Petsc;

fn main() {
    let universe = mpi::initialize().expect("MPI");
    let petsc = Petsc::initialize(universe, "mass_probe", &[]).expect("PETSc");
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 8 {
        eprintln!("usage: mass_probe MESH E NU RHO MASS_KG FMAX_HZ NODE...");
        std::process::exit(2);
    }
    let num = |i: usize| -> f64 { args[i].parse().expect("a number") };
    let (youngs, poisson, density, mass_kg, fmax) = (num(2), num(3), num(4), num(5), num(6));
    let nodes: Vec<usize> = args[7..]
        .iter()
        .map(|s| s.parse().expect("a node index"))
        .collect();
    let read = mesh::read_mesh(std::path::Path::new(&args[1]), &Default::default()).expect("mesh");
    let m = mesh::lift_to_quadratic(&read.mesh);
    let asm = assembly::assemble(&petsc, &m).expect("assembly");
    let (lo, hi) = m.bounding_box();
    let size = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
    let material = Material {
        youngs_modulus: youngs,
        poisson_ratio: poisson,
        density,
        rayleigh_alpha: 0.0,
        rayleigh_beta: 0.0,
    };
    let scale = eigen::spectrum_scale(material.lame_mu(), density, size);
    let solve = |with_mass: bool| -> Vec<f64> {
        let (k, mut mm) = asm.operators(&material).expect("operators");
        if with_mass {
            let per = mass_kg / nodes.len() as f64;
            assembly::add_nodal_diagonal(&petsc, &mut mm, &asm.layout, &nodes, [per; 3])
                .expect("mass");
            mm.set_symmetric().expect("symmetric");
        }
        let cfg = EigenConfig::new(ModeRequest::UpTo { f_max_hz: fmax }, scale);
        let modes = eigen::solve_modes(&petsc, &k, &mm, &cfg).expect("modes");
        modes
            .eigenvalues
            .iter()
            .map(|&l| eigen::frequency_hz(l))
            .collect()
    };
    let free = solve(false);
    let loaded = solve(true);
    if petsc.rank() == 0 {
        println!("# body mass {:.6} kg", density * m.volume());
        for k in 0..free.len().max(loaded.len()) {
            let f = free.get(k).copied().unwrap_or(f64::NAN);
            let l = loaded.get(k).copied().unwrap_or(f64::NAN);
            println!("{k} {f:.3} {l:.3}");
        }
    }
}
