//! Experiment: the modes of a body with lumped masses and point springs on some of its
//! vertices, by a full solve (the reference a Ritz model of them is judged against).
//!
//! `mass_probe MESH E NU RHO FMAX_HZ [mass KG NODE...] [spring K_T K_N NODE...] [out FILE.h5]`:
//! prints the elastic frequencies up to FMAX without and with the attachments, one line per
//! mode. `mass` spreads KG evenly over its nodes (original numbering, three components each);
//! `spring` puts K_T \[N/m\] along x and y and K_N along z on each of its nodes. With springs
//! the rigid motions become support modes, which are kept.
//!
//! `out` writes the attached body's modes (eigenvalues, mass-normalised shapes in the original
//! node order) to FILE.h5 in the modes schema of `diffsound modes` (`io::write_modes`), and
//! skips the free solve: generator 2 (`scripts/bench/gen2/generate.py`) draws its added-mass
//! cases from it, so that the mass it labels is the mass the recording carries.
use diffsound::assembly;
use diffsound::eigen::{self, EigenConfig, ModeRequest};
use diffsound::fem::Material;
use diffsound::io;
use diffsound::mesh;
use diffsound::petsc::Petsc;

/// Point masses (kg over nodes) and springs ([k_t, k_t, k_n] on each node).
#[derive(Default)]
struct Attachments {
    mass: Option<(f64, Vec<usize>)>,
    spring: Option<([f64; 3], Vec<usize>)>,
    out: Option<std::path::PathBuf>,
}

fn parse_attachments(args: &[String]) -> Result<Attachments, String> {
    let num = |s: &String| s.parse::<f64>().map_err(|_| format!("not a number: {s}"));
    let mut out = Attachments::default();
    let mut i = 0;
    while i < args.len() {
        let nodes_from = |j: usize| -> (Vec<usize>, usize) {
            let mut end = j;
            while end < args.len() && args[end].parse::<usize>().is_ok() {
                end += 1;
            }
            let nodes = args[j..end].iter().filter_map(|s| s.parse().ok()).collect();
            (nodes, end)
        };
        match args[i].as_str() {
            "mass" if i + 1 < args.len() => {
                let kg = num(&args[i + 1])?;
                let (nodes, end) = nodes_from(i + 2);
                if nodes.is_empty() {
                    return Err("`mass` needs at least one node".into());
                }
                out.mass = Some((kg, nodes));
                i = end;
            }
            "spring" if i + 2 < args.len() => {
                let (kt, kn) = (num(&args[i + 1])?, num(&args[i + 2])?);
                let (nodes, end) = nodes_from(i + 3);
                if nodes.is_empty() {
                    return Err("`spring` needs at least one node".into());
                }
                out.spring = Some(([kt, kt, kn], nodes));
                i = end;
            }
            "out" if i + 1 < args.len() => {
                out.out = Some(args[i + 1].clone().into());
                i += 2;
            }
            other => return Err(format!("unexpected argument {other}")),
        }
    }
    Ok(out)
}

fn main() {
    let universe = mpi::initialize().expect("MPI");
    let petsc = Petsc::initialize(universe, "mass_probe", &[]).expect("PETSc");
    let args: Vec<String> = std::env::args().collect();
    let usage =
        "usage: mass_probe MESH E NU RHO FMAX_HZ [mass KG NODE...] [spring K_T K_N NODE...] \
         [out FILE.h5]";
    if args.len() < 6 {
        eprintln!("{usage}");
        std::process::exit(2);
    }
    let parsed = (2..6)
        .map(|i| {
            args[i]
                .parse::<f64>()
                .map_err(|_| format!("not a number: {}", args[i]))
        })
        .collect::<Result<Vec<f64>, String>>()
        .and_then(|n| parse_attachments(&args[6..]).map(|a| (n, a)));
    let (youngs, poisson, density, fmax, attachments) = match parsed {
        Ok((n, a)) => (n[0], n[1], n[2], n[3], a),
        Err(e) => {
            eprintln!("{e}\n{usage}");
            std::process::exit(2);
        }
    };
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
    let solve = |attached: bool| -> eigen::Modes<'_> {
        let (mut k, mut mm) = asm.operators(&material).expect("operators");
        let mut expected_rigid = 6;
        if attached {
            if let Some((kg, nodes)) = &attachments.mass {
                let per = kg / nodes.len() as f64;
                assembly::add_nodal_diagonal(&petsc, &mut mm, &asm.layout, nodes, [per; 3])
                    .expect("mass");
            }
            if let Some((values, nodes)) = &attachments.spring {
                assembly::add_nodal_diagonal(&petsc, &mut k, &asm.layout, nodes, *values)
                    .expect("spring");
                expected_rigid = 0;
            }
            mm.set_symmetric().expect("symmetric");
            k.set_symmetric().expect("symmetric");
        }
        let mut cfg = EigenConfig::new(ModeRequest::UpTo { f_max_hz: fmax }, scale);
        cfg.expected_rigid = expected_rigid;
        eigen::solve_modes(&petsc, &k, &mm, &cfg).expect("modes")
    };
    let hz = |modes: &eigen::Modes<'_>| -> Vec<f64> {
        modes
            .eigenvalues
            .iter()
            .map(|&l| eigen::frequency_hz(l))
            .collect()
    };
    let attached_modes = solve(true);
    let attached = hz(&attached_modes);
    if let Some(path) = &attachments.out {
        // Collective gather, then rank 0 writes.
        let shapes = asm
            .layout
            .gather_original_order(&attached_modes.vectors)
            .expect("gather");
        if petsc.rank() == 0 {
            let mut provenance = vec![("mesh".to_string(), args[1].clone())];
            if let Some((kg, nodes)) = &attachments.mass {
                provenance.push(("attached_mass_kg".into(), kg.to_string()));
                provenance.push(("attached_mass_nodes".into(), format!("{nodes:?}")));
            }
            if let Some((values, nodes)) = &attachments.spring {
                provenance.push(("attached_springs_n_per_m".into(), format!("{values:?}")));
                provenance.push(("attached_spring_nodes".into(), format!("{nodes:?}")));
            }
            let file = io::ModesFile {
                nodes: &m.nodes,
                connectivity: &m.connectivity,
                nodes_per_tet: m.nodes_per_tet(),
                material: io::MaterialRecord::undamped("custom", youngs, poisson, density),
                eigenvalues: &attached_modes.eigenvalues,
                frequencies_hz: &attached,
                mode_shapes: &shapes,
                residual_norms: &attached_modes.residuals,
                rigid_eigenvalues: &attached_modes.rigid_eigenvalues,
                solver: Vec::new(),
                n_ranks: petsc.size(),
                element_order: 2,
                timings: Vec::new(),
                provenance,
                extra_datasets: Vec::new(),
                node_fields: Vec::new(),
            };
            if let Err(e) = io::write_modes(path, &file) {
                eprintln!("{e}");
                std::process::exit(1);
            }
            println!("# wrote {} ({} modes)", path.display(), attached.len());
        }
        return;
    }
    let free = hz(&solve(false));
    if petsc.rank() == 0 {
        println!("# body mass {:.6} kg", density * m.volume());
        for k in 0..free.len().max(attached.len()) {
            let f = free.get(k).copied().unwrap_or(f64::NAN);
            let a = attached.get(k).copied().unwrap_or(f64::NAN);
            println!("{k} {f:.3} {a:.3}");
        }
    }
}
