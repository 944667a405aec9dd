//! Reader tests on gmsh fixtures, the shared meshes, hand-written and
//! corrupted files. Unit tests of single functions live next to them.

use std::path::{Path, PathBuf};

use super::*;

// ---------------------------------------------------------------- paths

/// Repository root. The module lives in `<root>/src/mesh/`; `file!()` is
/// absolute when the module is included by `#[path]` from another crate and
/// relative (to the package root, `CARGO_MANIFEST_DIR`) in the main crate.
fn repo_root() -> PathBuf {
    let here = Path::new(file!());
    match here.ancestors().nth(3) {
        Some(root) if here.is_absolute() => root.to_path_buf(),
        _ => PathBuf::from(env!("CARGO_MANIFEST_DIR")),
    }
}

pub(super) fn fixture(name: &str) -> PathBuf {
    repo_root().join("tests/data/mesh").join(name)
}

/// The shared data directory: `$DIFFSOUND_SHARED`, else `../shared` next to
/// the repository, else `/work/shared`. `None` (and a note) if absent.
pub(crate) fn shared_file(relative: &str) -> Option<PathBuf> {
    let candidates: Vec<PathBuf> = match std::env::var_os("DIFFSOUND_SHARED") {
        Some(dir) => vec![PathBuf::from(dir)],
        None => vec![repo_root().join("../shared"), PathBuf::from("/work/shared")],
    };
    let found = candidates
        .iter()
        .map(|dir| dir.join(relative))
        .find(|p| p.is_file());
    if found.is_none() {
        eprintln!("note: skipping, {relative} not found in {candidates:?} (set DIFFSOUND_SHARED)");
    }
    found
}

// ---------------------------------------------------------------- helpers

fn read_str(text: &str) -> Result<MeshRead, MeshError> {
    read_mesh_from_bytes(
        text.as_bytes(),
        Path::new("inline.msh"),
        &ReadOptions::default(),
    )
}

fn read_fixture(name: &str) -> MeshRead {
    read_mesh(&fixture(name), &ReadOptions::default()).unwrap_or_else(|e| panic!("{name}: {e}"))
}

fn assert_close(a: [f64; 3], b: [f64; 3], tol: f64, what: &str) {
    for k in 0..3 {
        assert!((a[k] - b[k]).abs() <= tol, "{what}: {a:?} vs {b:?}");
    }
}

fn midpoint(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        0.5 * (a[0] + b[0]),
        0.5 * (a[1] + b[1]),
        0.5 * (a[2] + b[2]),
    ]
}

fn unique_edge_count(m: &TetMesh) -> usize {
    let mut edges: Vec<(usize, usize)> = (0..m.n_tets())
        .flat_map(|e| {
            let t = m.tet(e);
            TET10_EDGES.map(|(a, b)| (t[a].min(t[b]), t[a].max(t[b])))
        })
        .collect();
    edges.sort_unstable();
    edges.dedup();
    edges.len()
}

fn face_normal(m: &TetMesh, f: [usize; 3]) -> [f64; 3] {
    let [a, b, c] = f.map(|n| m.nodes[n]);
    cross(sub(b, a), sub(c, a))
}

/// Two-tet ASCII MSH 2.2 file: a unit corner tet and a mirrored one sharing
/// face (1,2,3), with sparse tags, an unused node and a triangle and a point.
const SPARSE_22: &str = "$MeshFormat
2.2 0 8
$EndMeshFormat
$PhysicalNames
1
3 1 \"solid\"
$EndPhysicalNames
$Nodes
6
10 0 0 0
20 1 0 0
30 0 1 0
1000000 0 0 1
7 5 5 5
40 1 1 1
$EndNodes
$Elements
4
1 15 2 0 1 7
2 2 2 0 1 10 20 30
5 4 2 1 1 10 20 30 1000000
9 4 2 1 1 20 40 30 1000000
$EndElements
$Comments
anything $Nodes here is skipped
$EndComments
";

// ------------------------------------------------------ gmsh fixtures

const FORMATS: [&str; 4] = ["msh22_ascii", "msh22_bin", "msh41_ascii", "msh41_bin"];

#[test]
fn four_formats_read_identically() {
    for shape in ["cube", "sphere"] {
        for kind in ["tet4", "tet10"] {
            let reads: Vec<MeshRead> = FORMATS
                .iter()
                .map(|f| read_fixture(&format!("{shape}_{kind}_{f}.msh")))
                .collect();
            let reference = &reads[0].mesh;
            let order = if kind == "tet4" {
                ElementOrder::Linear
            } else {
                ElementOrder::Quadratic
            };
            assert_eq!(reference.order, order);
            assert!(reference.n_tets() > 50, "{shape} {kind}");
            for (read, format) in reads.iter().zip(FORMATS) {
                let m = &read.mesh;
                assert_eq!(
                    m.connectivity, reference.connectivity,
                    "{shape} {kind} {format}"
                );
                assert_eq!(m.n_nodes(), reference.n_nodes(), "{shape} {kind} {format}");
                // gmsh writes ASCII with 16 significant digits, binary exactly.
                for (a, b) in m.nodes.iter().zip(&reference.nodes) {
                    assert_close(*a, *b, 1e-15, &format!("{shape} {kind} {format}"));
                }
                // gmsh saves lower-dimensional elements too: one summary line.
                assert!(
                    read.warnings
                        .iter()
                        .any(|w| w.starts_with("ignored ") && w.contains("triangles")),
                    "{:?}",
                    read.warnings
                );
                assert_eq!(m.connected_components(), 1);
            }
        }
    }
}

#[test]
fn cube_fixture_geometry() {
    let read = read_fixture("cube_tet4_msh41_bin.msh");
    let m = &read.mesh;
    assert!((m.volume() - 1.0).abs() < 1e-12);
    assert_eq!(m.bounding_box(), ([0.0; 3], [1.0; 3]));
    assert!((0..m.n_tets()).all(|e| m.corner_volume(e) > 0.0));
    let area: f64 = m
        .boundary_faces()
        .iter()
        .map(|&f| 0.5 * norm(face_normal(m, f)))
        .sum();
    assert!((area - 6.0).abs() < 1e-12);
    for f in m.boundary_faces() {
        let centroid =
            [0, 1, 2].map(|k| (m.nodes[f[0]][k] + m.nodes[f[1]][k] + m.nodes[f[2]][k]) / 3.0);
        assert!(dot(face_normal(m, f), sub(centroid, [0.5; 3])) > 0.0);
    }
    // every cube vertex lies on the boundary
    let surface = m.surface_vertices();
    assert!(surface.windows(2).all(|w| w[0] < w[1]));
    for corner in [[0.0; 3], [1.0; 3]] {
        assert!(surface.iter().any(|&v| m.nodes[v] == corner));
    }
}

/// The second moment of volume is exact on straight tets: a box of sides a, b, c has its
/// centroid at the middle and C = diag(a², b², c²)/12, whatever the tets and however the box
/// sits; a hole in it is taken out.
#[test]
fn volume_moments_of_a_box_are_exact() {
    let size = [0.3, 0.2, 0.05];
    let mut m = box_mesh([3, 2, 2], size);
    let shift = [1.0, -2.0, 0.5];
    for x in &mut m.nodes {
        *x = [x[0] + shift[0], x[1] + shift[1], x[2] + shift[2]];
    }
    let (c, moments) = m.volume_moments().expect("a volume");
    for r in 0..3 {
        assert!((c[r] - (shift[r] + 0.5 * size[r])).abs() < 1e-12, "{c:?}");
        for col in 0..3 {
            let want = if r == col {
                size[r] * size[r] / 12.0
            } else {
                0.0
            };
            assert!((moments[r][col] - want).abs() < 1e-12, "{moments:?}");
        }
    }
    let empty = TetMesh {
        nodes: vec![],
        connectivity: vec![],
        order: ElementOrder::Linear,
    };
    assert!(empty.volume_moments().is_none());
}

/// Pins down the 10-node order: on a straight-sided mesh written by gmsh,
/// node 4+k must be the midpoint of the corner pair TET10_EDGES[k].
#[test]
fn gmsh_tet10_order_matches_tet10_edges() {
    for format in FORMATS {
        let m = read_fixture(&format!("cube_tet10_{format}.msh")).mesh;
        for e in 0..m.n_tets() {
            let x = m.tet_coords(e);
            for (k, &(a, b)) in TET10_EDGES.iter().enumerate() {
                assert_close(
                    x[4 + k],
                    midpoint(x[a], x[b]),
                    1e-12,
                    &format!("{format} tet {e} node {}", 4 + k),
                );
            }
        }
    }
    // Curved sphere: mid nodes of boundary edges sit on the sphere itself.
    let m = read_fixture("sphere_tet10_msh41_bin.msh").mesh;
    let on_sphere = |p: [f64; 3]| (norm(p) - 0.5).abs() < 1e-9;
    let mut curved = 0;
    for e in 0..m.n_tets() {
        let x = m.tet_coords(e);
        for (k, &(a, b)) in TET10_EDGES.iter().enumerate() {
            let straight = midpoint(x[a], x[b]);
            if on_sphere(x[a]) && on_sphere(x[b]) && on_sphere(x[4 + k]) {
                curved += 1;
            } else {
                assert_close(x[4 + k], straight, 1e-12, "interior mid node");
            }
        }
    }
    assert!(curved > 0);
}

#[test]
fn lift_of_gmsh_tet4_cube() {
    let m = read_fixture("cube_tet4_msh22_ascii.msh").mesh;
    let q = lift_to_quadratic(&m);
    assert_eq!(q.n_nodes(), m.n_nodes() + unique_edge_count(&m));
    assert!((q.volume() - m.volume()).abs() < 1e-14);
    for e in 0..q.n_tets() {
        let x = q.tet_coords(e);
        for (k, &(a, b)) in TET10_EDGES.iter().enumerate() {
            assert_eq!(x[4 + k], midpoint(x[a], x[b]));
        }
    }
    assert_eq!(to_linear(&q), m);
    // gmsh's own P2 version of the same mesh has the same node count
    let gmsh_p2 = read_fixture("cube_tet10_msh22_ascii.msh").mesh;
    assert_eq!(gmsh_p2.n_nodes(), q.n_nodes());
    assert_eq!(to_linear(&gmsh_p2), m);
}

#[test]
fn sphere_vertex_normals_point_outward() {
    let m = read_fixture("sphere_tet4_msh22_bin.msh").mesh;
    let normals = m.vertex_normals();
    assert_eq!(
        normals.iter().map(|(v, _)| *v).collect::<Vec<_>>(),
        m.surface_vertices()
    );
    for (v, n) in normals {
        assert!((norm(n) - 1.0).abs() < 1e-12);
        let radial = m.nodes[v].map(|c| c / 0.5);
        assert!(dot(n, radial) > 0.9, "vertex {v}: {n:?}");
    }
    // the sphere file has $PhysicalNames and only physical elements
    let read = read_fixture("sphere_tet4_msh41_ascii.msh");
    assert_eq!(read.warnings.len(), 1, "{:?}", read.warnings);
}

// ---------------------------------------------------------- shared meshes

#[test]
fn bowl_reads_and_lifts() {
    let Some(path) = shared_file("data/bowl/bowl.msh") else {
        return;
    };
    let read = read_mesh(&path, &ReadOptions::default()).unwrap();
    let m = &read.mesh;
    assert_eq!(
        (m.n_nodes(), m.n_tets(), m.order),
        (3007, 8840, ElementOrder::Linear)
    );
    let (lo, hi) = m.bounding_box();
    let extent = sub(hi, lo);
    assert!(
        (extent[0] - 0.115).abs() < 0.005 && (extent[1] - 0.115).abs() < 0.005,
        "{extent:?}"
    );
    assert!((extent[2] - 0.062).abs() < 0.005, "{extent:?}");
    assert!((m.volume() - 1.0e-4).abs() < 0.1e-4, "{}", m.volume());
    assert_eq!(m.connected_components(), 1);
    let q = lift_to_quadratic(m);
    assert_eq!(q.n_nodes(), 3007 + unique_edge_count(m));
    assert!((q.volume() - m.volume()).abs() < 1e-15);
    assert_eq!(&to_linear(&q), m);
    // outward normals: the bowl's surface encloses positive volume
    // (divergence theorem: V = 1/3 * sum over faces of centroid . area normal)
    let enclosed: f64 = m
        .boundary_faces()
        .iter()
        .map(|&f| {
            let centroid =
                [0, 1, 2].map(|k| (m.nodes[f[0]][k] + m.nodes[f[1]][k] + m.nodes[f[2]][k]) / 3.0);
            dot(centroid, face_normal(m, f)) / 6.0
        })
        .sum();
    assert!(
        (enclosed - m.volume()).abs() < 1e-9 * m.volume().abs().max(1e-300) + 1e-18,
        "{enclosed}"
    );
    // unit scaling
    let mm = read_mesh(
        &path,
        &ReadOptions {
            unit_scale: parse_unit("mm").unwrap(),
            ..Default::default()
        },
    )
    .unwrap();
    assert!((mm.mesh.volume() - 1e-9 * m.volume()).abs() < 1e-12 * 1e-9 * m.volume());
}

#[test]
fn other_shared_meshes() {
    for (name, nodes, tets) in [
        ("spot", 3358, 12156),
        ("bob", 4037, 14576),
        ("oloid", 1166, 4581),
    ] {
        let Some(path) = shared_file(&format!("data/meshes/{name}.msh")) else {
            continue;
        };
        let read = read_mesh(&path, &ReadOptions::default()).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            (read.mesh.n_nodes(), read.mesh.n_tets()),
            (nodes, tets),
            "{name}"
        );
        assert!(read.mesh.volume() > 0.0);
    }
}

// -------------------------------------------------- hand-written files

#[test]
fn sparse_tags_unused_nodes_and_skipped_sections() {
    let read = read_str(SPARSE_22).unwrap();
    let m = &read.mesh;
    assert_eq!(m.n_nodes(), 5, "node 7 is only used by a point element");
    assert_eq!(m.nodes[3], [0.0, 0.0, 1.0]);
    assert_eq!(m.nodes[4], [1.0, 1.0, 1.0]);
    assert_eq!(m.connectivity, vec![0, 1, 2, 3, 1, 4, 2, 3]);
    assert_eq!(m.corner_volume(0), 1.0 / 6.0);
    assert!(read
        .warnings
        .iter()
        .any(|w| w == "ignored 2 elements of other types (2: 1 triangles, 15: 1 points)"));
    assert!(read
        .warnings
        .iter()
        .any(|w| w.starts_with("1 nodes are not used")));
    assert_eq!(m.boundary_faces().len(), 6);
}

#[test]
fn msh41_ascii_with_parametric_nodes_and_unknown_element_type() {
    let text = "$MeshFormat
4.1 0 8
$EndMeshFormat
$Entities
1 0 0 1
5 0 0 0 0
1 0 0 0 1 1 1 0 0
$EndEntities
$Nodes
2 5 3 90
0 5 0 1
90
0 0 1
3 1 1 4
3
5
6
8
0 0 0 0.1 0.2 0.3
1 0 0 0 0 0
0 1 0 0 0 0
2 2 2 0 0 0
$EndNodes
$Elements
3 3 1 3
0 5 999 1
1 90
3 1 4 1
2 3 5 6 90
0 5 15 1
3 8
$EndElements
";
    let read = read_str(text).unwrap();
    assert_eq!(read.mesh.n_nodes(), 4);
    assert_eq!(read.mesh.connectivity, vec![1, 2, 3, 0]);
    assert_eq!(read.mesh.nodes[0], [0.0, 0.0, 1.0]);
    assert!(read
        .warnings
        .iter()
        .any(|w| w.contains("999: 1 elements of unknown type") && w.contains("15: 1 points")));
    assert!(read
        .warnings
        .iter()
        .any(|w| w.starts_with("1 nodes are not used")));
}

#[test]
fn several_pieces_are_a_warning() {
    let a = box_mesh([1, 1, 1], [1.0, 1.0, 1.0]);
    let mut two = a.clone();
    let offset = two.n_nodes();
    two.nodes
        .extend(a.nodes.iter().map(|p| [p[0] + 3.0, p[1], p[2]]));
    two.connectivity
        .extend(a.connectivity.iter().map(|n| n + offset));
    assert_eq!(two.connected_components(), 2);
    let path = std::env::temp_dir().join(format!(
        "diffsound_mesh_two_pieces_{}.msh",
        std::process::id()
    ));
    write_msh22_ascii(&two, &path).unwrap();
    let read = read_mesh(&path, &ReadOptions::default()).unwrap();
    std::fs::remove_file(&path).ok();
    assert_eq!(read.mesh, two);
    assert!(
        read.warnings
            .iter()
            .any(|w| w.contains("2 connected pieces")),
        "{:?}",
        read.warnings
    );
}

#[test]
fn writer_round_trips_exactly() {
    let mut linear = box_mesh([2, 3, 2], [0.1, 0.07, 0.3]);
    linear.nodes[5][0] += 1e-3 / 3.0; // a value that needs 17 digits
    for m in [linear.clone(), lift_to_quadratic(&linear)] {
        let path = std::env::temp_dir().join(format!(
            "diffsound_mesh_roundtrip_{}_{}.msh",
            std::process::id(),
            m.nodes_per_tet()
        ));
        write_msh22_ascii(&m, &path).unwrap();
        let read = read_mesh(&path, &ReadOptions::default()).unwrap();
        std::fs::remove_file(&path).ok();
        assert_eq!(read.mesh, m);
        assert!(read.warnings.is_empty(), "{:?}", read.warnings);
    }
}

#[test]
fn box_mesh_boundary_normals_point_away_from_centre() {
    let size = [2.0, 1.0, 0.5];
    let m = box_mesh([4, 3, 2], size);
    let centre = size.map(|s| s / 2.0);
    for f in m.boundary_faces() {
        let centroid =
            [0, 1, 2].map(|k| (m.nodes[f[0]][k] + m.nodes[f[1]][k] + m.nodes[f[2]][k]) / 3.0);
        assert!(
            dot(face_normal(&m, f), sub(centroid, centre)) > 0.0,
            "face {f:?}"
        );
    }
    // a vertex in the middle of the z = 0 face has normal -z
    let normals = m.vertex_normals();
    let (_, n) = normals
        .iter()
        .find(|(v, _)| m.nodes[*v] == [1.0, 1.0 / 3.0, 0.0])
        .unwrap();
    assert_close(*n, [0.0, 0.0, -1.0], 1e-12, "bottom normal");
    // interior nodes are not surface vertices: 5*4*3 nodes, 3*2*1 inside
    assert_eq!(m.surface_vertices().len(), 5 * 4 * 3 - 3 * 2);
    // faces of reversed tets are reversed too, so they still point outward
    let mut flipped = m.clone();
    for e in 0..flipped.n_tets() {
        flipped.connectivity.swap(4 * e + 1, 4 * e + 2);
    }
    assert_eq!(flipped.boundary_faces().len(), m.boundary_faces().len());
    for f in flipped.boundary_faces() {
        let centroid =
            [0, 1, 2].map(|k| (m.nodes[f[0]][k] + m.nodes[f[1]][k] + m.nodes[f[2]][k]) / 3.0);
        assert!(
            dot(face_normal(&flipped, f), sub(centroid, centre)) > 0.0,
            "flipped face {f:?}"
        );
    }
}

#[test]
fn parse_unit_names_and_numbers() {
    assert_eq!(parse_unit("m").unwrap(), 1.0);
    assert_eq!(parse_unit("cm").unwrap(), 0.01);
    assert_eq!(parse_unit("mm").unwrap(), 1e-3);
    assert_eq!(parse_unit("um").unwrap(), 1e-6);
    assert_eq!(parse_unit("in").unwrap(), 0.0254);
    assert_eq!(parse_unit("ft").unwrap(), 0.3048);
    assert_eq!(parse_unit(" 0.1 ").unwrap(), 0.1);
    for bad in ["", "km", "-1", "0", "nan", "inf", "1e400"] {
        assert!(
            matches!(parse_unit(bad), Err(MeshError::BadUnit { .. })),
            "{bad}"
        );
    }
    let opts = ReadOptions {
        unit_scale: 0.0,
        fix_inverted: false,
    };
    assert!(matches!(
        read_mesh_from_bytes(SPARSE_22.as_bytes(), Path::new("x"), &opts),
        Err(MeshError::BadOption { .. })
    ));
}

// ------------------------------------------------------------- bad input

fn expect_err(text: &str) -> MeshError {
    match read_str(text) {
        Ok(read) => panic!("expected an error, read {} tets", read.mesh.n_tets()),
        Err(err) => {
            let message = err.to_string();
            assert!(
                message.starts_with("inline.msh") || matches!(err, MeshError::BadUnit { .. }),
                "{message}"
            );
            err
        }
    }
}

#[test]
fn missing_sections_and_versions() {
    assert!(matches!(
        expect_err(""),
        MeshError::MissingSection {
            section: "MeshFormat",
            ..
        }
    ));
    assert!(matches!(
        expect_err("$Nodes\n0\n$EndNodes\n"),
        MeshError::MissingSection {
            section: "MeshFormat",
            ..
        }
    ));
    assert!(matches!(
        expect_err("hello\n"),
        MeshError::MissingSection {
            section: "MeshFormat",
            ..
        }
    ));
    for version in ["3.0", "4", "4.0", "1.0", "x"] {
        let err = expect_err(&format!("$MeshFormat\n{version} 0 8\n$EndMeshFormat\n"));
        assert!(
            matches!(
                err,
                MeshError::UnsupportedVersion {
                    location: Location::Line(2),
                    ..
                }
            ),
            "{version}: {err}"
        );
    }
    let no_nodes = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n";
    assert!(matches!(
        expect_err(no_nodes),
        MeshError::MissingSection {
            section: "Nodes",
            ..
        }
    ));
    let no_elements = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n1\n1 0 0 0\n$EndNodes\n";
    assert!(matches!(
        expect_err(no_elements),
        MeshError::MissingSection {
            section: "Elements",
            ..
        }
    ));
    let elements_first = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Elements\n0\n$EndElements\n";
    assert!(matches!(
        expect_err(elements_first),
        MeshError::Syntax {
            location: Location::Line(4),
            ..
        }
    ));
    let data_size = "$MeshFormat\n2.2 0 4\n$EndMeshFormat\n";
    assert!(matches!(
        expect_err(data_size),
        MeshError::Syntax {
            location: Location::Line(2),
            ..
        }
    ));
}

#[test]
fn bad_records_name_their_line() {
    let bad_number = SPARSE_22.replace("30 0 1 0", "30 0 one 0");
    let err = expect_err(&bad_number);
    assert!(
        matches!(
            err,
            MeshError::Syntax {
                location: Location::Line(12),
                ..
            }
        ),
        "{err}"
    );
    assert!(
        err.to_string()
            .contains("inline.msh: line 12: expected a number"),
        "{err}"
    );

    let short_record = SPARSE_22.replace("30 0 1 0", "30 0 1");
    assert!(matches!(
        expect_err(&short_record),
        MeshError::Syntax {
            location: Location::Line(12),
            ..
        }
    ));

    let long_record =
        SPARSE_22.replace("5 4 2 1 1 10 20 30 1000000", "5 4 2 1 1 10 20 30 1000000 7");
    assert!(matches!(
        expect_err(&long_record),
        MeshError::Syntax {
            location: Location::Line(21),
            ..
        }
    ));

    let unknown = SPARSE_22.replace("9 4 2 1 1 20 40 30 1000000", "9 4 2 1 1 20 41 30 1000000");
    let err = expect_err(&unknown);
    assert!(
        matches!(
            err,
            MeshError::UnknownNode {
                element_tag: 9,
                node_tag: 41,
                location: Location::Line(22),
                ..
            }
        ),
        "{err}"
    );

    for value in ["nan", "inf", "-inf", "1e999"] {
        let text = SPARSE_22.replace("40 1 1 1", &format!("40 1 {value} 1"));
        let err = expect_err(&text);
        assert!(
            matches!(
                err,
                MeshError::NonFiniteCoordinate {
                    node_tag: 40,
                    location: Location::Line(15),
                    ..
                }
            ),
            "{err}"
        );
    }

    let duplicate = SPARSE_22.replace("7 5 5 5", "20 5 5 5");
    assert!(matches!(
        expect_err(&duplicate),
        MeshError::DuplicateNode {
            node_tag: 20,
            location: Location::Line(14),
            ..
        }
    ));

    let count = SPARSE_22.replace("$Nodes\n6", "$Nodes\n7");
    assert!(matches!(expect_err(&count), MeshError::Syntax { .. }));

    let truncated = &SPARSE_22[..SPARSE_22.find("9 4 2").unwrap()];
    let err = expect_err(truncated);
    assert!(
        matches!(
            err,
            MeshError::Truncated {
                location: Location::Line(22),
                ..
            }
        ),
        "{err}"
    );

    let unclosed = &SPARSE_22[..SPARSE_22.find("$EndComments").unwrap()];
    assert!(matches!(expect_err(unclosed), MeshError::Truncated { .. }));
}

#[test]
fn element_sets_that_are_rejected() {
    let only_triangles = SPARSE_22
        .replace("5 4 2 1 1", "5 2 2 1 1")
        .replace("9 4 2 1 1 20 40 30 1000000", "9 2 2 1 1 20 40 30");
    let only_triangles = only_triangles.replace("5 2 2 1 1 10 20 30 1000000", "5 2 2 1 1 10 20 30");
    let err = expect_err(&only_triangles);
    assert!(matches!(err, MeshError::NoTetrahedra { .. }), "{err}");
    assert!(err.to_string().contains("2: 3 triangles"), "{err}");

    let mixed = SPARSE_22.replace(
        "9 4 2 1 1 20 40 30 1000000",
        "9 11 2 1 1 20 40 30 1000000 10 10 10 10 10 10",
    );
    let err = expect_err(&mixed);
    assert!(
        matches!(
            err,
            MeshError::MixedOrder {
                n_tet4: 1,
                first_tet4: 5,
                n_tet10: 1,
                first_tet10: 9,
                ..
            }
        ),
        "{err}"
    );
}

#[test]
fn inverted_and_flat_tets() {
    // element 9 with corners 1 and 2 swapped is inverted
    let inverted = SPARSE_22.replace("9 4 2 1 1 20 40 30 1000000", "9 4 2 1 1 20 30 40 1000000");
    let err = expect_err(&inverted);
    match &err {
        MeshError::BadVolume {
            n_inverted: 1,
            n_degenerate: 0,
            examples,
            ..
        } => {
            assert_eq!(examples[0].element_tag, 9);
            assert!((examples[0].volume + 1.0 / 3.0).abs() < 1e-15);
        }
        other => panic!("{other}"),
    }
    assert!(
        err.to_string().contains("element 9 (V = -3.333e-1 m^3)"),
        "{err}"
    );
    let opts = ReadOptions {
        fix_inverted: true,
        ..Default::default()
    };
    let read = read_mesh_from_bytes(inverted.as_bytes(), Path::new("inline.msh"), &opts).unwrap();
    assert!((0..read.mesh.n_tets()).all(|e| read.mesh.corner_volume(e) > 0.0));
    assert!(
        read.warnings
            .iter()
            .any(|w| w.starts_with("flipped 1 inverted")),
        "{:?}",
        read.warnings
    );

    // a flat tet (all four corners in z = 0) is an error even with fixing on
    let flat = SPARSE_22.replace("1000000 0 0 1", "1000000 0.2 0.2 0");
    let err = read_mesh_from_bytes(flat.as_bytes(), Path::new("inline.msh"), &opts).unwrap_err();
    assert!(
        matches!(
            err,
            MeshError::BadVolume {
                n_inverted: 0,
                n_degenerate: 1,
                ..
            }
        ),
        "{err}"
    );

    // 10-node tets: flipping keeps each mid node on its edge
    let mut q = lift_to_quadratic(&box_mesh([1, 1, 2], [1.0, 1.0, 1.0]));
    for e in [1, 4, 7] {
        let t = &mut q.connectivity[10 * e..10 * e + 10];
        // reverse orientation by swapping corners 1, 2 and their edges
        t.swap(1, 2);
        t.swap(4, 6);
        t.swap(8, 9);
    }
    let path = std::env::temp_dir().join(format!(
        "diffsound_mesh_inverted10_{}.msh",
        std::process::id()
    ));
    write_msh22_ascii(&q, &path).unwrap();
    let strict = read_mesh(&path, &ReadOptions::default());
    let fixed = read_mesh(&path, &opts);
    std::fs::remove_file(&path).ok();
    assert!(matches!(
        strict,
        Err(MeshError::BadVolume { n_inverted: 3, .. })
    ));
    let fixed = fixed.unwrap().mesh;
    for e in 0..fixed.n_tets() {
        assert!(fixed.corner_volume(e) > 0.0);
        let x = fixed.tet_coords(e);
        for (k, &(a, b)) in TET10_EDGES.iter().enumerate() {
            assert_eq!(x[4 + k], midpoint(x[a], x[b]));
        }
    }
}

// ------------------------------------------------ binary files built here

/// Binary MSH file of `m` with node tags `tag_of(i)`, one point element in
/// front of the tets, either MSH 2.2 or 4.1 (with a binary `$Entities`), in
/// either byte order.
fn binary_msh(m: &TetMesh, v41: bool, big_endian: bool, tag_of: &dyn Fn(usize) -> u64) -> Vec<u8> {
    let mut out = Vec::new();
    let i32b = |out: &mut Vec<u8>, v: i32| {
        out.extend(if big_endian {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        })
    };
    let u64b = |out: &mut Vec<u8>, v: u64| {
        out.extend(if big_endian {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        })
    };
    let f64b = |out: &mut Vec<u8>, v: f64| u64b(out, v.to_bits());
    let element_type = if m.order == ElementOrder::Linear {
        4
    } else {
        11
    };
    out.extend(format!("$MeshFormat\n{} 1 8\n", if v41 { "4.1" } else { "2.2" }).bytes());
    i32b(&mut out, 1);
    out.extend(b"\n$EndMeshFormat\n");
    if v41 {
        out.extend(b"$Entities\n");
        for count in [1, 0, 0, 1] {
            u64b(&mut out, count);
        }
        i32b(&mut out, 1);
        for c in [0.0, 0.0, 0.0] {
            f64b(&mut out, c);
        }
        u64b(&mut out, 0);
        i32b(&mut out, 1);
        for c in [0.0, 0.0, 0.0, 1.0, 1.0, 1.0] {
            f64b(&mut out, c);
        }
        u64b(&mut out, 1);
        i32b(&mut out, 7);
        u64b(&mut out, 0);
        out.extend(b"\n$EndEntities\n$Nodes\n");
        let n = m.n_nodes() as u64;
        let tags: Vec<u64> = (0..m.n_nodes()).map(tag_of).collect();
        for v in [
            1,
            n,
            *tags.iter().min().unwrap(),
            *tags.iter().max().unwrap(),
        ] {
            u64b(&mut out, v);
        }
        for v in [3, 1, 0] {
            i32b(&mut out, v);
        }
        u64b(&mut out, n);
        for &t in &tags {
            u64b(&mut out, t);
        }
        for p in &m.nodes {
            for &c in p {
                f64b(&mut out, c);
            }
        }
        out.extend(b"\n$EndNodes\n$Elements\n");
        let n_tets = m.n_tets() as u64;
        for v in [2, n_tets + 1, 1, n_tets + 1] {
            u64b(&mut out, v);
        }
        for v in [0, 1, 15] {
            i32b(&mut out, v);
        }
        u64b(&mut out, 1);
        u64b(&mut out, n_tets + 1);
        u64b(&mut out, tag_of(0));
        for v in [3, 1, element_type] {
            i32b(&mut out, v);
        }
        u64b(&mut out, n_tets);
        for e in 0..m.n_tets() {
            u64b(&mut out, e as u64 + 1);
            for &node in m.tet(e) {
                u64b(&mut out, tag_of(node));
            }
        }
        out.extend(b"\n$EndElements\n");
    } else {
        out.extend(format!("$Nodes\n{}\n", m.n_nodes()).bytes());
        for (i, p) in m.nodes.iter().enumerate() {
            i32b(&mut out, tag_of(i) as i32);
            for &c in p {
                f64b(&mut out, c);
            }
        }
        out.extend(format!("\n$EndNodes\n$Elements\n{}\n", m.n_tets() + 1).bytes());
        for v in [15, 1, 2, 1_000_000, 0, 1, tag_of(0) as i32] {
            i32b(&mut out, v);
        }
        for v in [element_type, m.n_tets() as i32, 2] {
            i32b(&mut out, v);
        }
        for e in 0..m.n_tets() {
            for v in [e as i32 + 1, 1, 1] {
                i32b(&mut out, v);
            }
            for &node in m.tet(e) {
                i32b(&mut out, tag_of(node) as i32);
            }
        }
        out.extend(b"\n$EndElements\n");
    }
    out
}

#[test]
fn binary_sparse_tags_both_versions_both_byte_orders() {
    let m = lift_to_quadratic(&box_mesh([2, 2, 1], [1.0, 2.0, 3.0]));
    // tags that include bytes looking like whitespace and '$' right after
    // the count line, and a huge gap that forces the hashed tag map
    let tag_of = |i: usize| {
        if i == 0 {
            10
        } else if i == 1 {
            36
        } else {
            5_000_000 + 7 * i as u64
        }
    };
    for v41 in [false, true] {
        for big_endian in [false, true] {
            let bytes = binary_msh(&m, v41, big_endian, &tag_of);
            let read =
                read_mesh_from_bytes(&bytes, Path::new("built.msh"), &ReadOptions::default())
                    .unwrap_or_else(|e| panic!("v41={v41} be={big_endian}: {e}"));
            assert_eq!(read.mesh, m, "v41={v41} be={big_endian}");
            assert_eq!(
                read.warnings,
                vec!["ignored 1 elements of other types (15: 1 points)".to_string()]
            );
        }
    }
    // A binary $Entities the reader cannot walk (a wrong count) is still
    // skipped, by searching for $EndEntities.
    let mut bytes = binary_msh(&m, true, false, &tag_of);
    let entities_at = bytes.windows(10).position(|w| w == b"$Entities\n").unwrap() + 10;
    bytes[entities_at] = 200;
    let read =
        read_mesh_from_bytes(&bytes, Path::new("built.msh"), &ReadOptions::default()).unwrap();
    assert_eq!(read.mesh, m);
}

#[test]
fn binary_errors_name_byte_offsets() {
    let m = box_mesh([1, 1, 1], [1.0, 1.0, 1.0]);
    let tag_of = |i: usize| i as u64 + 1;
    for v41 in [false, true] {
        let bytes = binary_msh(&m, v41, false, &tag_of);
        let cut = bytes.len() - 40;
        let err =
            read_mesh_from_bytes(&bytes[..cut], Path::new("cut.msh"), &ReadOptions::default())
                .unwrap_err();
        assert!(
            matches!(
                err,
                MeshError::Truncated {
                    location: Location::ByteOffset(_),
                    ..
                }
            ),
            "{err}"
        );
        assert!(
            err.to_string().starts_with("cut.msh: byte offset "),
            "{err}"
        );
        // point the last tet at a node tag that does not exist
        let mut bad = bytes.clone();
        let end = bad.len() - "\n$EndElements\n".len();
        let width = if v41 { 8 } else { 4 };
        bad[end - width] = 99;
        let err =
            read_mesh_from_bytes(&bad, Path::new("bad.msh"), &ReadOptions::default()).unwrap_err();
        match err {
            MeshError::UnknownNode {
                element_tag: 6,
                node_tag: 99,
                location: Location::ByteOffset(at),
                ..
            } => {
                assert_eq!(at, end - width)
            }
            other => panic!("{other}"),
        }
        // a NaN coordinate
        let mut nan = bytes.clone();
        let marker = if v41 {
            &b"$Nodes\n"[..]
        } else {
            &b"$Nodes\n8\n"[..]
        };
        let nodes_at = nan.windows(marker.len()).position(|w| w == marker).unwrap() + marker.len();
        let first_x = if v41 {
            nodes_at + 32 + 12 + 8 + 8 * 8
        } else {
            nodes_at + 4
        };
        nan[first_x..first_x + 8].copy_from_slice(&f64::NAN.to_le_bytes());
        let err =
            read_mesh_from_bytes(&nan, Path::new("nan.msh"), &ReadOptions::default()).unwrap_err();
        assert!(
            matches!(
                err,
                MeshError::NonFiniteCoordinate {
                    node_tag: 1,
                    location: Location::ByteOffset(_),
                    ..
                }
            ),
            "{err}"
        );
    }
}

// ------------------------------------------------------------ robustness

/// Deterministic pseudo-random numbers (64-bit LCG), enough for fuzzing.
struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        self.0 >> 33
    }
}

/// Feeds truncated and corrupted versions of `bytes` to the reader; any
/// outcome but a panic is fine.
fn fuzz(bytes: &[u8], rounds: usize, seed: u64) {
    let opts = ReadOptions::default();
    let name = Path::new("fuzz.msh");
    let mut rng = Lcg(seed);
    let step = (bytes.len() / rounds).max(1);
    for cut in (0..bytes.len())
        .step_by(step)
        .chain(bytes.len().saturating_sub(64)..bytes.len())
    {
        let _ = read_mesh_from_bytes(&bytes[..cut], name, &opts);
    }
    let mut corrupted = bytes.to_vec();
    for _ in 0..rounds {
        corrupted.copy_from_slice(bytes);
        for _ in 0..1 + rng.next() % 4 {
            let at = rng.next() as usize % corrupted.len();
            corrupted[at] = match rng.next() % 4 {
                0 => corrupted[at] ^ (1 << (rng.next() % 8)),
                1 => 0xff,
                2 => b'$',
                _ => rng.next() as u8,
            };
        }
        let _ = read_mesh_from_bytes(&corrupted, name, &opts);
    }
}

#[test]
fn corrupted_files_never_panic() {
    if let Some(path) = shared_file("data/bowl/bowl.msh") {
        fuzz(&std::fs::read(path).unwrap(), 300, 1);
    }
    for format in FORMATS {
        fuzz(
            &std::fs::read(fixture(&format!("sphere_tet10_{format}.msh"))).unwrap(),
            150,
            2,
        );
    }
    fuzz(SPARSE_22.as_bytes(), 200, 3);
    let m = box_mesh([1, 1, 1], [1.0, 1.0, 1.0]);
    fuzz(&binary_msh(&m, true, false, &|i| i as u64 + 1), 300, 4);
    fuzz(&binary_msh(&m, false, true, &|i| i as u64 + 1), 300, 5);
}

/// Speed check on a ~1M-node binary file; run with
/// `cargo test --release -- --ignored --nocapture million`.
#[test]
#[ignore]
fn million_node_binary_reads_fast() {
    let m = box_mesh([99, 99, 99], [1.0, 1.0, 1.0]);
    for v41 in [false, true] {
        let bytes = binary_msh(&m, v41, false, &|i| i as u64 + 1);
        let start = std::time::Instant::now();
        let read =
            read_mesh_from_bytes(&bytes, Path::new("big.msh"), &ReadOptions::default()).unwrap();
        let elapsed = start.elapsed();
        eprintln!(
            "v41={v41}: {} nodes, {} tets, {:.1} MB read in {elapsed:.2?}",
            read.mesh.n_nodes(),
            read.mesh.n_tets(),
            bytes.len() as f64 / 1e6
        );
        assert_eq!(read.mesh.n_nodes(), 1_000_000);
    }
}

/// A longer fuzz run; `cargo test --release -- --ignored long_fuzz`.
#[test]
#[ignore]
fn long_fuzz() {
    if let Some(path) = shared_file("data/bowl/bowl.msh") {
        fuzz(&std::fs::read(path).unwrap(), 20_000, 11);
    }
    for format in FORMATS {
        for kind in ["tet4", "tet10"] {
            fuzz(
                &std::fs::read(fixture(&format!("cube_{kind}_{format}.msh"))).unwrap(),
                20_000,
                12,
            );
        }
    }
    let m = lift_to_quadratic(&box_mesh([2, 1, 1], [1.0, 1.0, 1.0]));
    for (v41, big_endian) in [(false, false), (false, true), (true, false), (true, true)] {
        fuzz(
            &binary_msh(&m, v41, big_endian, &|i| 3 * i as u64 + 1),
            50_000,
            13,
        );
    }
}
