//! Times the serial parts of assembly on the bundled bowl (P2): pattern, kernels, CSR scatter.
//! Run: cargo run --release --example profile_assembly
fn main() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/bowl/bowl.msh");
    let m = diffsound::mesh::read_mesh(&path, &Default::default())
        .expect("bowl mesh")
        .mesh;
    let m = diffsound::mesh::lift_to_quadratic(&m);
    let p = diffsound::assembly::partition_nodes(&m.nodes, 1);
    for _ in 0..3 {
        let t = std::time::Instant::now();
        let pat = diffsound::assembly::local_pattern(&m, &p, 0);
        let t_pattern = t.elapsed();
        let t = std::time::Instant::now();
        let c = diffsound::assembly::assemble_local_csr(&m, &p, 0).expect("assembly");
        println!(
            "pattern {:?}, full local CSR {:?} ({} elements, {} nonzeros)",
            t_pattern,
            t.elapsed(),
            pat.elements.len(),
            c.cols.len()
        );
    }
}
