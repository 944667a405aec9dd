//! Minimal Gmsh writer, for test fixtures and for handing meshes to gmsh.

use std::io::{BufWriter, Write};
use std::path::Path;

use super::{ElementOrder, TetMesh};

/// Writes `m` as a Gmsh MSH 2.2 ASCII file: node tags are index + 1, element
/// type 4 or 11 with two tags (physical 1, elementary 1). Coordinates are
/// written in metres with Rust's shortest round-trip formatting, so reading
/// the file back gives bit-identical values.
pub fn write_msh22_ascii(m: &TetMesh, path: &Path) -> std::io::Result<()> {
    let mut out = BufWriter::new(std::fs::File::create(path)?);
    writeln!(out, "$MeshFormat\n2.2 0 8\n$EndMeshFormat")?;
    writeln!(out, "$Nodes\n{}", m.n_nodes())?;
    for (i, [x, y, z]) in m.nodes.iter().enumerate() {
        writeln!(out, "{} {x:?} {y:?} {z:?}", i + 1)?;
    }
    writeln!(out, "$EndNodes")?;
    let element_type = match m.order {
        ElementOrder::Linear => 4,
        ElementOrder::Quadratic => 11,
    };
    writeln!(out, "$Elements\n{}", m.n_tets())?;
    for e in 0..m.n_tets() {
        write!(out, "{} {element_type} 2 1 1", e + 1)?;
        for &n in m.tet(e) {
            write!(out, " {}", n + 1)?;
        }
        writeln!(out)?;
    }
    writeln!(out, "$EndElements")?;
    out.flush()
}
