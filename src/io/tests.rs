use super::*;
use crate::io::test_support::TempDir;

/// Owned data behind a `ModesFile`: two tet10s sharing the face (1,2,3),
/// built straight from corner coordinates with Gmsh's mid-edge convention.
struct Fixture {
    nodes: Vec<[f64; 3]>,
    connectivity: Vec<usize>,
    nodes_per_tet: usize,
    eigenvalues: Vec<f64>,
    frequencies: Vec<f64>,
    shapes: Vec<Vec<f64>>,
    residuals: Vec<f64>,
    rigid: Vec<f64>,
    /// Node fields, sorted by name.
    fields: Vec<NodeFieldData>,
    /// Sorted by path.
    extras: Vec<ExtraDataset>,
}

/// Gmsh tet10 mid-edge pairs, local nodes 4..9.
const GMSH_EDGES: [(usize, usize); 6] = [(0, 1), (1, 2), (0, 2), (0, 3), (2, 3), (1, 3)];
/// VTK_QUADRATIC_TETRA mid-edge pairs, local nodes 4..9 (vtkQuadraticTetra.h).
const VTK_EDGES: [(usize, usize); 6] = [(0, 1), (1, 2), (2, 0), (0, 3), (1, 3), (2, 3)];

fn fixture(quadratic: bool) -> Fixture {
    let mut nodes = vec![
        [0.0, 0.0, 0.0],
        [0.1, 0.0, 0.0],
        [0.0, 0.1, 0.0],
        [0.0, 0.0, 0.1],
        [0.1, 0.1, 0.1],
    ];
    let corners = [[0usize, 1, 2, 3], [1, 2, 3, 4]];
    let mut connectivity = Vec::new();
    let mut edge_node = std::collections::HashMap::new();
    for tet in corners {
        connectivity.extend_from_slice(&tet);
        if quadratic {
            for (a, b) in GMSH_EDGES {
                let key = (tet[a].min(tet[b]), tet[a].max(tet[b]));
                let id = *edge_node.entry(key).or_insert_with(|| {
                    let (p, q) = (nodes[key.0], nodes[key.1]);
                    nodes.push([
                        (p[0] + q[0]) / 2.0,
                        (p[1] + q[1]) / 2.0,
                        (p[2] + q[2]) / 2.0,
                    ]);
                    nodes.len() - 1
                });
                connectivity.push(id);
            }
        }
    }
    let n = nodes.len();
    let eigenvalues = vec![4.0e6, 9.0e6, 2.5e7];
    let frequencies: Vec<f64> = eigenvalues
        .iter()
        .map(|l: &f64| l.sqrt() / (2.0 * std::f64::consts::PI))
        .collect();
    let shapes = (0..eigenvalues.len())
        .map(|k| (0..3 * n).map(|i| (k * 1000 + i) as f64 * 0.5).collect())
        .collect();
    Fixture {
        nodes,
        connectivity,
        nodes_per_tet: if quadratic { 10 } else { 4 },
        eigenvalues,
        frequencies,
        shapes,
        residuals: vec![1e-12, 2e-12, 3e-11],
        rigid: vec![1e-6, -2e-6, 3e-7, 0.0, 1e-7, -1e-7],
        fields: vec![
            NodeFieldData {
                name: "d_lambda_dx_mode_001".into(),
                kind: FieldKind::Vector,
                data: (0..3 * n).map(|i| -1.5e9 + i as f64 * 0.25).collect(),
                units: "rad²/s²/m".into(),
            },
            NodeFieldData {
                name: "marker".into(),
                kind: FieldKind::Vector,
                data: (0..3 * n)
                    .map(|i| (i % 3) as f64 + (i / 3) as f64 * 10.0)
                    .collect(),
                units: String::new(),
            },
            // A signed scalar: one value per node, not three equal components.
            NodeFieldData {
                name: "z_ratio".into(),
                kind: FieldKind::Scalar,
                data: (0..n).map(|i| -(i as f64) * 0.5).collect(),
                units: "1 (a ≤ 0 ratio)".into(),
            },
        ],
        extras: vec![
            ExtraDataset {
                path: "/a-b/x".into(),
                shape: vec![],
                data: vec![42.0],
                attrs: vec![],
                integer: false,
            },
            ExtraDataset {
                path: "/a/deep/nested/cube".into(),
                shape: vec![2, 2, 2],
                data: (0..8).map(|i| i as f64 - 3.5).collect(),
                attrs: vec![("note".into(), "x & <y> ünï".into())],
                integer: false,
            },
            ExtraDataset {
                path: "/root_level".into(),
                shape: vec![2],
                data: vec![f64::MIN_POSITIVE, -0.0],
                attrs: vec![],
                integer: false,
            },
            ExtraDataset {
                path: "/sensitivities/d_eigenvalue_d_density".into(),
                shape: vec![3],
                data: vec![-510.0, -1146.5, -3184.7],
                attrs: vec![("units".into(), "rad²/s² per kg/m³".into())],
                integer: false,
            },
            ExtraDataset {
                path: "/sensitivities/d_eigenvalue_d_youngs".into(),
                shape: vec![3],
                data: vec![2.0e-5, 4.5e-5, 1.25e-4],
                attrs: vec![
                    ("method".into(), "adjoint".into()),
                    ("units".into(), "rad²/s²/Pa".into()),
                ],
                integer: false,
            },
            ExtraDataset {
                path: "/sensitivities/empty".into(),
                shape: vec![0, 3],
                data: vec![],
                attrs: vec![("units".into(), "m".into())],
                integer: false,
            },
            ExtraDataset {
                path: "/sensitivities/ranges".into(),
                shape: vec![2, 2],
                data: vec![0.0, 2.0, 5.0, 7.0],
                attrs: vec![],
                integer: true,
            },
        ],
    }
}

fn modes_file(fx: &Fixture) -> ModesFile<'_> {
    ModesFile {
        nodes: &fx.nodes,
        connectivity: &fx.connectivity,
        nodes_per_tet: fx.nodes_per_tet,
        material: MaterialRecord {
            name: "steel & <co>".into(),
            youngs_modulus: 200e9,
            poisson_ratio: 0.3,
            density: 7850.0,
            rayleigh_alpha: 5.0,
            rayleigh_beta: 1e-8,
        },
        eigenvalues: &fx.eigenvalues,
        frequencies_hz: &fx.frequencies,
        mode_shapes: &fx.shapes,
        residual_norms: &fx.residuals,
        rigid_eigenvalues: &fx.rigid,
        solver: vec![
            ("eps_type".into(), "krylovschur".into()),
            ("-st_pc_factor_mat_solver_type".into(), "mumps".into()),
        ],
        n_ranks: 4,
        element_order: if fx.nodes_per_tet == 10 { 2 } else { 1 },
        timings: vec![
            ("assembly".into(), 1.5),
            ("solve".into(), 12.25),
            ("total".into(), 14.0),
        ],
        provenance: vec![
            ("mesh".into(), "/data/bowl.msh".into()),
            ("units".into(), "m".into()),
            ("version".into(), "0.1.0 ünïcode".into()),
        ],
        extra_datasets: fx.extras.clone(),
        node_fields: fx
            .fields
            .iter()
            .map(|f| NodeField {
                name: f.name.clone(),
                kind: f.kind,
                data: &f.data,
                units: f.units.clone(),
            })
            .collect(),
    }
}

fn sorted<T: Clone + Ord>(v: &[(String, T)]) -> Vec<(String, T)> {
    let mut v = v.to_vec();
    v.sort();
    v
}

#[test]
fn tet10_round_trip_reads_back_everything() {
    let dir = TempDir::new("roundtrip");
    let fx = fixture(true);
    let f = modes_file(&fx);
    let path = dir.path("bowl.h5");
    write_modes(&path, &f).unwrap();
    assert_eq!(
        dir.entries(),
        ["bowl.h5", "bowl.xdmf"],
        "no temporaries left behind"
    );

    let s = read_modes(&path).unwrap();
    assert_eq!(
        (
            s.n_nodes,
            s.n_tets,
            s.n_modes,
            s.nodes_per_tet,
            s.element_order
        ),
        (fx.nodes.len(), 2, 3, 10, 2)
    );
    assert_eq!(s.nodes, fx.nodes);
    assert_eq!(s.connectivity, fx.connectivity);
    assert_eq!(s.material, f.material);
    assert_eq!(s.eigenvalues, fx.eigenvalues);
    assert_eq!(s.frequencies_hz, fx.frequencies);
    assert_eq!(s.mode_shapes, fx.shapes);
    assert_eq!(s.residual_norms, fx.residuals);
    assert_eq!(s.rigid_eigenvalues, fx.rigid);
    assert_eq!(s.n_ranks, 4);
    // HDF5 lists attributes by name, so compare as sets.
    assert_eq!(sorted(&s.solver), sorted(&f.solver));
    assert_eq!(s.timings.len(), 3);
    for (k, v) in &f.timings {
        assert!(s.timings.contains(&(k.clone(), *v)), "timing {k}");
    }
    assert_eq!(sorted(&s.provenance), sorted(&f.provenance));
    assert_eq!(s.node_fields, fx.fields);
    assert_eq!(s.extra_datasets, fx.extras);
}

#[test]
fn files_without_node_fields_or_extras_read_back_empty() {
    let dir = TempDir::new("noextras");
    let fx = fixture(true);
    let mut f = modes_file(&fx);
    f.node_fields.clear();
    f.extra_datasets.clear();
    let path = dir.path("plain.h5");
    write_modes(&path, &f).unwrap();
    let xml = fs::read_to_string(dir.path("plain.xdmf")).unwrap();
    assert!(!xml.contains("node_fields"));
    {
        let file = hdf5::File::open_rw(&path).unwrap();
        let mut top = file.member_names().unwrap();
        top.sort();
        assert_eq!(
            top,
            [
                "material",
                "mesh",
                "modes",
                "provenance",
                "solver",
                "timings"
            ]
        );
        // Exactly what a format-2 writer produced.
        file.attr("format_version")
            .unwrap()
            .write_scalar(&2u64)
            .unwrap();
    }
    let s = read_modes(&path).unwrap();
    assert_eq!(s.mode_shapes, fx.shapes);
    assert!(s.node_fields.is_empty() && s.extra_datasets.is_empty());
}

#[test]
fn node_fields_and_extras_are_stored_as_documented() {
    let dir = TempDir::new("extras");
    let fx = fixture(false);
    let path = dir.path("e.h5");
    write_modes(&path, &modes_file(&fx)).unwrap();
    let n = fx.nodes.len();
    let file = hdf5::File::open(&path).unwrap();
    let v: u64 = file.attr("format_version").unwrap().read_scalar().unwrap();
    assert_eq!(v, FORMAT_VERSION);
    for field in &fx.fields {
        let name = &field.name;
        let ds = file.dataset(&format!("/node_fields/{name}")).unwrap();
        let shape = match field.kind {
            FieldKind::Scalar => vec![n],
            FieldKind::Vector => vec![n, 3],
        };
        assert_eq!(ds.shape(), shape, "{name}");
        assert_eq!(ds.read_raw::<f64>().unwrap(), field.data, "{name}");
        let u: VarLenUnicode = ds.attr("units").unwrap().read_scalar().unwrap();
        assert_eq!(u.as_str(), field.units);
    }
    // Every dataset of the fixed layout says its units.
    for (dataset, units) in [
        ("/mesh/nodes", "m"),
        ("/mesh/tets", ""),
        ("/mesh/tets_vtk", ""),
        ("/modes/eigenvalues", "rad^2/s^2"),
        ("/modes/frequencies", "Hz"),
        ("/modes/shapes", "kg^-1/2"),
        ("/modes/by_mode/mode_000", "kg^-1/2"),
        ("/modes/residual_norms", "1"),
        ("/modes/rigid_eigenvalues", "rad^2/s^2"),
    ] {
        let u: VarLenUnicode = file
            .dataset(dataset)
            .unwrap()
            .attr("units")
            .unwrap()
            .read_scalar()
            .unwrap();
        assert_eq!(u.as_str(), units, "{dataset}");
    }
    for e in &fx.extras {
        let ds = file.dataset(&e.path).unwrap();
        assert_eq!(ds.shape(), e.shape, "{}", e.path);
        if !e.data.is_empty() {
            assert_eq!(ds.read_raw::<f64>().unwrap(), e.data, "{}", e.path);
        }
    }
    assert!(file.dataset("/a-b/x").unwrap().is_scalar());
    let units: VarLenUnicode = file
        .dataset("/sensitivities/d_eigenvalue_d_youngs")
        .unwrap()
        .attr("units")
        .unwrap()
        .read_scalar()
        .unwrap();
    assert_eq!(units.as_str(), "rad²/s²/Pa");
}

#[test]
fn file_layout_matches_the_documented_table() {
    let dir = TempDir::new("layout");
    let fx = fixture(true);
    let path = dir.path("m.h5");
    write_modes(&path, &modes_file(&fx)).unwrap();
    let file = hdf5::File::open(&path).unwrap();
    let n = fx.nodes.len();
    for (name, shape) in [
        ("/mesh/nodes", vec![n, 3]),
        ("/mesh/tets", vec![2, 10]),
        ("/mesh/tets_vtk", vec![2, 10]),
        ("/modes/eigenvalues", vec![3]),
        ("/modes/frequencies", vec![3]),
        ("/modes/shapes", vec![3, n, 3]),
        ("/modes/residual_norms", vec![3]),
        ("/modes/rigid_eigenvalues", vec![6]),
    ] {
        assert_eq!(file.dataset(name).unwrap().shape(), shape, "{name}");
    }
    let shapes = file
        .dataset("/modes/shapes")
        .unwrap()
        .read_raw::<f64>()
        .unwrap();
    // [k, node, component] row-major == mode k's node-major vector.
    assert_eq!(shapes[(3 * n) + 3 * 2 + 1], fx.shapes[1][3 * 2 + 1]);
    let order: u32 = file
        .dataset("/mesh/tets")
        .unwrap()
        .attr("element_order")
        .unwrap()
        .read_scalar()
        .unwrap();
    assert_eq!(order, 2);
    let n_ranks: u64 = file
        .group("solver")
        .unwrap()
        .attr("n_ranks")
        .unwrap()
        .read_scalar()
        .unwrap();
    assert_eq!(n_ranks, 4);
    let e: f64 = file
        .group("material")
        .unwrap()
        .attr("youngs_modulus")
        .unwrap()
        .read_scalar()
        .unwrap();
    assert_eq!(e, 200e9);
}

#[test]
fn tets_vtk_swaps_local_nodes_8_and_9_and_matches_vtk_edges() {
    let gmsh: Vec<usize> = (0..10).collect();
    assert_eq!(
        gmsh_to_vtk_connectivity(&gmsh, 10),
        [0, 1, 2, 3, 4, 5, 6, 7, 9, 8]
    );
    assert_eq!(gmsh_to_vtk_connectivity(&[3, 1, 2, 0], 4), [3, 1, 2, 0]);

    // Geometric check on the stored dataset: each VTK mid-edge node must sit
    // at the midpoint of VTK's edge for that slot.
    let dir = TempDir::new("perm");
    let fx = fixture(true);
    let path = dir.path("m.h5");
    write_modes(&path, &modes_file(&fx)).unwrap();
    let file = hdf5::File::open(&path).unwrap();
    let vtk: Vec<u64> = file.dataset("/mesh/tets_vtk").unwrap().read_raw().unwrap();
    for tet in vtk.chunks_exact(10) {
        for (slot, (a, b)) in VTK_EDGES.iter().enumerate() {
            let (p, q, m) = (
                fx.nodes[tet[*a] as usize],
                fx.nodes[tet[*b] as usize],
                fx.nodes[tet[4 + slot] as usize],
            );
            for c in 0..3 {
                assert!(
                    (m[c] - 0.5 * (p[c] + q[c])).abs() < 1e-15,
                    "slot {} is not on edge {a}-{b}",
                    4 + slot
                );
            }
        }
    }
}

#[test]
fn xdmf_sidecar_references_the_h5_by_name_and_per_mode_datasets() {
    let dir = TempDir::new("xdmf");
    let fx = fixture(true);
    let path = dir.path("results.h5");
    write_modes(&path, &modes_file(&fx)).unwrap();
    let xml = fs::read_to_string(dir.path("results.xdmf")).unwrap();
    let n = fx.nodes.len();
    assert!(xml.contains(r#"<Xdmf Version="3.0">"#));
    assert!(xml.contains(r#"TopologyType="Tetrahedron_10" NumberOfElements="2""#));
    assert!(xml.contains(">results.h5:/mesh/tets_vtk<"));
    assert!(xml.contains(">results.h5:/mesh/nodes<"));
    assert!(
        !xml.contains(dir.0.to_str().unwrap()),
        "h5 must be referenced by file name only"
    );
    assert!(xml.contains(&format!("mode_001 ({:.1} Hz)", fx.frequencies[1])));
    assert!(xml.contains(&format!(
        r#"<DataItem Dimensions="{n} 3" NumberType="Float" Precision="8" Format="HDF">results.h5:/modes/by_mode/mode_002</DataItem>"#
    )));
    assert!(!xml.contains("HyperSlab"), "Xdmf3 readers drop HyperSlabs");
    // meshio refuses <Information>: the material's name and the units stay in the HDF5 file.
    assert!(!xml.contains("<Information"), "{xml}");
    assert!(xml.contains(&format!(
        r#"<DataItem Dimensions="{n} 3" NumberType="Float" Precision="8" Format="HDF">results.h5:/node_fields/d_lambda_dx_mode_001</DataItem>"#
    )));
    assert!(xml.contains(r#"<Attribute Name="marker" Center="Node" AttributeType="Vector">"#));
    // A scalar: one value per node, so ParaView colours by the value (sign included).
    assert!(xml.contains(r#"<Attribute Name="z_ratio" Center="Node" AttributeType="Scalar">"#));
    assert!(xml.contains(&format!(
        r#"<DataItem Dimensions="{n}" NumberType="Float" Precision="8" Format="HDF">results.h5:/node_fields/z_ratio</DataItem>"#
    )));
    assert_eq!(xml.matches("<Attribute ").count(), 3 + fx.fields.len());
    check_xdmf_with_python(&dir.path("results.xdmf"), &fx);
    check_with_paraview(&dir.path("results.xdmf"), &fx);
}

#[test]
fn by_mode_datasets_are_virtual_views_of_shapes() {
    let dir = TempDir::new("vds");
    let fx = fixture(true);
    let path = dir.path("v.h5");
    write_modes(&path, &modes_file(&fx)).unwrap();
    let n = fx.nodes.len();
    let file = hdf5::File::open(&path).unwrap();
    let by_mode = file.group("/modes/by_mode").unwrap();
    let mut names = by_mode.member_names().unwrap();
    names.sort();
    assert_eq!(names, ["mode_000", "mode_001", "mode_002"]);
    for (k, name) in names.iter().enumerate() {
        let ds = by_mode.dataset(name).unwrap();
        assert_eq!(ds.shape(), [n, 3], "{name}");
        assert_eq!(
            ds.layout(),
            hdf5::plist::dataset_create::Layout::Virtual,
            "{name}"
        );
        // The mapping itself (source file ".", dataset /modes/shapes) is
        // checked through h5py below: hdf5-metno 0.15's `get_virtual_map`
        // fails to parse the source slab ("Blocks can not overlap").
        assert_eq!(ds.read_raw::<f64>().unwrap(), fx.shapes[k], "{name}");
    }
    drop(file);
    check_by_mode_with_h5py(&path, 2);
}

#[test]
fn moved_pair_still_resolves_virtual_datasets() {
    let src = TempDir::new("move-src");
    let dst = TempDir::new("move-dst");
    let fx = fixture(true);
    write_modes(&src.path("bowl.h5"), &modes_file(&fx)).unwrap();
    // write_modes itself renamed `.bowl.h5.tmp.<pid>` into place; now move
    // the pair to another directory as a user would.
    for name in ["bowl.h5", "bowl.xdmf"] {
        fs::rename(src.path(name), dst.path(name)).unwrap();
    }
    assert!(src.entries().is_empty());
    let moved = dst.path("bowl.h5");
    let file = hdf5::File::open(&moved).unwrap();
    let m1: Vec<f64> = file
        .dataset("/modes/by_mode/mode_001")
        .unwrap()
        .read_raw()
        .unwrap();
    assert_eq!(m1, fx.shapes[1]);
    drop(file);
    check_by_mode_with_h5py(&moved, 1);
    check_xdmf_with_python(&dst.path("bowl.xdmf"), &fx);
    check_with_paraview(&dst.path("bowl.xdmf"), &fx);
}

#[test]
fn mode_names_are_zero_padded_to_fit_every_index() {
    assert_eq!(mode_index_width(0), 3);
    assert_eq!(mode_index_width(1), 3);
    assert_eq!(mode_index_width(1000), 3);
    assert_eq!(mode_index_width(1001), 4);
    assert_eq!(mode_name(7, 12), "mode_007");
    assert_eq!(mode_name(7, 12_000), "mode_00007");
}

#[test]
fn read_modes_accepts_format_version_1() {
    let dir = TempDir::new("v1");
    let fx = fixture(false);
    let path = dir.path("old.h5");
    write_modes(&path, &modes_file(&fx)).unwrap();
    {
        let file = hdf5::File::open_rw(&path).unwrap();
        file.attr("format_version")
            .unwrap()
            .write_scalar(&1u64)
            .unwrap();
        file.unlink("/modes/by_mode").unwrap();
    }
    assert_eq!(read_modes(&path).unwrap().mode_shapes, fx.shapes);
    {
        let file = hdf5::File::open_rw(&path).unwrap();
        file.attr("format_version")
            .unwrap()
            .write_scalar(&99u64)
            .unwrap();
    }
    let err = read_modes(&path).unwrap_err();
    assert!(matches!(err, IoError::BadLayout { .. }), "{err}");
}

/// Python interpreters to try: Debian's python3 carries python3-h5py; a
/// pyenv shim in PATH may not.
const PYTHONS: [&str; 2] = ["/usr/bin/python3", "python3"];

/// Runs `script` with `args` under the first Python that starts; asserts
/// success and returns its output, or `None` (with a note) without Python.
fn run_python(script: &str, args: &[&std::ffi::OsStr]) -> Option<String> {
    for python in PYTHONS {
        let Ok(out) = std::process::Command::new(python)
            .arg("-c")
            .arg(script)
            .args(args)
            .output()
        else {
            continue;
        };
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(out.status.success(), "{python} check failed:\n{text}");
        eprintln!("{python}: {}", text.trim());
        return Some(text);
    }
    eprintln!("note: python3 not found; check skipped");
    None
}

/// Reads `/modes/by_mode/mode_KKK` with h5py (independent HDF5 reader) and
/// compares it to `/modes/shapes[k]`. Skipped with a note without h5py.
fn check_by_mode_with_h5py(h5: &Path, k: usize) {
    const SCRIPT: &str = r#"
import sys
try:
    import h5py, numpy as np
except ImportError:
    print("note: h5py not importable, virtual dataset not read by h5py"); sys.exit(0)
path, k = sys.argv[1], int(sys.argv[2])
with h5py.File(path, "r") as f:
    ds = f["/modes/by_mode/mode_%03d" % k]
    assert ds.is_virtual
    (src,) = ds.virtual_sources()
    assert src.file_name == "." and src.dset_name == "/modes/shapes", src
    assert np.array_equal(ds[()], f["/modes/shapes"][k])
    print("h5py: mode_%03d == shapes[%d]" % (k, k), ds.shape)
"#;
    let k = k.to_string();
    run_python(SCRIPT, &[h5.as_os_str(), k.as_ref()]);
}

/// Reads the sidecar with meshio and h5py (`tests/python/check_sidecar.py`): tetra10 or
/// tetra cells, every mode and node field as a point array of the right shape (scalars
/// 1-D) equal to its dataset, no `<Information>`. meshio and h5py are project dependencies
/// (`scripts/install-deps.sh`): without them the check fails.
fn check_xdmf_with_python(xdmf: &Path, fx: &Fixture) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/check_sidecar.py");
    let python = std::env::var_os("DIFFSOUND_PYTHON").unwrap_or_else(|| "/usr/bin/python3".into());
    let out = std::process::Command::new(&python)
        .arg(&script)
        .arg(xdmf)
        .args(fx.fields.iter().map(|f| {
            let kind = match f.kind {
                FieldKind::Scalar => "scalar",
                FieldKind::Vector => "vector",
            };
            format!("{}={kind}", f.name)
        }))
        .output()
        .unwrap_or_else(|e| panic!("{}: {e}", python.to_string_lossy()));
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "meshio/h5py check failed:\n{text}");
    eprintln!("{}", text.trim());
}

/// Loads the sidecar in ParaView through `pvbatch` (if installed) with both
/// the reader ParaView picks for `.xdmf` by default (`OpenDataFile`, i.e.
/// `Xdmf3ReaderS`) and the legacy "XDMF Reader", and checks cell type, sizes
/// and every mode array against the fixture. Skipped with a note when
/// ParaView is absent (as on CI).
fn check_with_paraview(xdmf: &Path, fx: &Fixture) {
    const SCRIPT: &str = r#"
import sys, json
from paraview import simple as pv, servermanager as sm
def first_leaf(ds):
    while ds.IsA("vtkMultiBlockDataSet"):
        ds = ds.GetBlock(0)
    return ds
for label, make in (("default", lambda p: pv.OpenDataFile(p)),
                    ("legacy", lambda p: pv.XDMFReader(FileNames=[p]))):
    r = make(sys.argv[1])
    r.UpdatePipeline()
    ds = first_leaf(sm.Fetch(r))
    pd = ds.GetPointData()
    arrays = []
    for i in range(pd.GetNumberOfArrays()):
        a = pd.GetArray(i)
        k = a.GetNumberOfComponents()
        arrays.append([pd.GetArrayName(i), k,
                       [a.GetComponent(t, c) for t in range(a.GetNumberOfTuples()) for c in range(k)]])
    # VTK's own view of each cell edge: ends 0 and 1, mid-edge node 2 (quadratic).
    worst = 0.0
    for i in range(ds.GetNumberOfCells()):
        cell = ds.GetCell(i)
        for e in range(cell.GetNumberOfEdges()):
            edge = cell.GetEdge(e)
            if edge.GetNumberOfPoints() == 3:
                p, q, m = (edge.GetPoints().GetPoint(j) for j in range(3))
                worst = max(worst, max(abs(m[c] - 0.5 * (p[c] + q[c])) for c in range(3)))
    print("PVRESULT " + json.dumps({"label": label, "reader": r.GetXMLName(),
        "points": ds.GetNumberOfPoints(), "edge_mid_error": worst,
        "cell_types": sorted({ds.GetCellType(i) for i in range(ds.GetNumberOfCells())}),
        "cells": ds.GetNumberOfCells(), "arrays": arrays}))
    pv.Delete(r)
"#;
    let script = xdmf.with_extension("pvcheck.py");
    fs::write(&script, SCRIPT).unwrap();
    let out = std::process::Command::new("pvbatch")
        .arg(&script)
        .arg(xdmf)
        .output();
    let _ = fs::remove_file(&script);
    let out = match out {
        Ok(out) => out,
        Err(_) => {
            eprintln!("note: pvbatch (ParaView) not found; sidecar not loaded in ParaView");
            return;
        }
    };
    let stdout = String::from_utf8_lossy(&out.stdout);
    let results: Vec<serde_json::Value> = stdout
        .lines()
        .filter_map(|l| l.strip_prefix("PVRESULT "))
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(
        results.len(),
        2,
        "pvbatch gave {} of 2 results:\n{stdout}\n{}",
        results.len(),
        String::from_utf8_lossy(&out.stderr)
    );
    // VTK_TETRA = 10, VTK_QUADRATIC_TETRA = 24.
    let cell_type = if fx.nodes_per_tet == 10 { 24 } else { 10 };
    for v in &results {
        let reader = format!("{} ({})", v["label"], v["reader"]);
        assert_eq!(v["cell_types"], serde_json::json!([cell_type]), "{reader}");
        assert_eq!(v["points"], fx.nodes.len(), "{reader}");
        assert_eq!(
            v["cells"],
            fx.connectivity.len() / fx.nodes_per_tet,
            "{reader}"
        );
        // A wrong Gmsh→VTK permutation would put mid-edge nodes off their edges.
        assert!(
            v["edge_mid_error"].as_f64().unwrap() < 1e-12,
            "{reader}: {v}"
        );
        let mut arrays = v["arrays"].as_array().unwrap().clone();
        // Readers differ in array order; compare sorted by name.
        arrays.sort_by_key(|a| a[0].as_str().unwrap().to_owned());
        let mut expected: Vec<(String, usize, &Vec<f64>)> = fx
            .shapes
            .iter()
            .enumerate()
            .map(|(k, s)| (format!("mode_{k:03} ({:.1} Hz)", fx.frequencies[k]), 3, s))
            .chain(
                fx.fields
                    .iter()
                    .map(|f| (f.name.clone(), f.kind.components(), &f.data)),
            )
            .collect();
        expected.sort_by(|a, b| a.0.cmp(&b.0));
        assert_eq!(
            arrays.len(),
            expected.len(),
            "{reader}: one point array per mode and node field"
        );
        for (a, (name, components, want)) in arrays.iter().zip(&expected) {
            assert_eq!(a[0].as_str().unwrap(), name, "{reader}");
            assert_eq!(a[1], *components, "{reader}: {name}");
            let values: Vec<f64> = a[2]
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap())
                .collect();
            assert_eq!(&values, *want, "{reader}: {name} as ParaView sees it");
        }
        eprintln!(
            "pvbatch {reader}: {} modes + {} node fields on cell type {cell_type}",
            fx.shapes.len(),
            fx.fields.len()
        );
    }
    assert_eq!(results[0]["reader"], "Xdmf3ReaderS", "default .xdmf reader");
    assert_eq!(results[1]["reader"], "XdmfReader", "legacy \"XDMF Reader\"");
}

#[test]
fn tet4_uses_plain_tetrahedron_and_identity_order() {
    let dir = TempDir::new("tet4");
    let fx = fixture(false);
    let path = dir.path("lin.h5");
    write_modes(&path, &modes_file(&fx)).unwrap();
    let xml = fs::read_to_string(dir.path("lin.xdmf")).unwrap();
    assert!(xml.contains(r#"TopologyType="Tetrahedron" "#));
    let file = hdf5::File::open(&path).unwrap();
    let a: Vec<u64> = file.dataset("/mesh/tets").unwrap().read_raw().unwrap();
    let b: Vec<u64> = file.dataset("/mesh/tets_vtk").unwrap().read_raw().unwrap();
    assert_eq!(a, b);
    check_xdmf_with_python(&dir.path("lin.xdmf"), &fx);
    check_with_paraview(&dir.path("lin.xdmf"), &fx);
    assert_eq!(read_modes(&path).unwrap().element_order, 1);
}

#[test]
fn no_modes_and_no_rigid_modes_still_round_trip() {
    let dir = TempDir::new("empty");
    let fx = fixture(false);
    let mut f = modes_file(&fx);
    f.eigenvalues = &[];
    f.frequencies_hz = &[];
    f.mode_shapes = &[];
    f.residual_norms = &[];
    f.rigid_eigenvalues = &[];
    let path = dir.path("none.h5");
    write_modes(&path, &f).unwrap();
    let s = read_modes(&path).unwrap();
    assert_eq!(
        (s.n_modes, s.rigid_eigenvalues.len(), s.mode_shapes.len()),
        (0, 0, 0)
    );
}

#[test]
fn empty_mesh_with_a_mode_still_round_trips() {
    let dir = TempDir::new("nonodes");
    let fx = fixture(false);
    let mut f = modes_file(&fx);
    let empty_shape = vec![Vec::new()];
    f.nodes = &[];
    f.connectivity = &[];
    f.eigenvalues = &fx.eigenvalues[..1];
    f.frequencies_hz = &fx.frequencies[..1];
    f.residual_norms = &fx.residuals[..1];
    f.mode_shapes = &empty_shape;
    f.node_fields = vec![NodeField::vector("empty", &[], "m")];
    let path = dir.path("empty.h5");
    write_modes(&path, &f).unwrap();
    let s = read_modes(&path).unwrap();
    assert_eq!(
        s.node_fields,
        [NodeFieldData {
            name: "empty".into(),
            kind: FieldKind::Vector,
            data: Vec::new(),
            units: "m".into()
        }]
    );
    assert_eq!((s.n_nodes, s.n_modes, s.mode_shapes), (0, 1, empty_shape));
    let file = hdf5::File::open(&path).unwrap();
    assert_eq!(
        file.dataset("/modes/by_mode/mode_000").unwrap().shape(),
        [0, 3]
    );
}

#[test]
fn failing_writer_leaves_neither_final_nor_temporary_file() {
    let dir = TempDir::new("atomic");
    let path = dir.path("out.h5");
    let err = write_atomically(&path, |tmp| {
        fs::write(tmp, b"partial").unwrap();
        Err(IoError::InvalidInput {
            path: tmp.to_path_buf(),
            reason: "simulated failure".into(),
        })
    })
    .unwrap_err();
    assert!(err.to_string().contains("simulated failure"));
    assert!(dir.entries().is_empty(), "left behind: {:?}", dir.entries());

    // An existing file survives a failed rewrite untouched.
    fs::write(&path, b"old").unwrap();
    let _ = write_atomically(&path, |tmp| {
        fs::write(tmp, b"new but broken").unwrap();
        Err(IoError::InvalidInput {
            path: tmp.to_path_buf(),
            reason: "again".into(),
        })
    });
    assert_eq!(fs::read(&path).unwrap(), b"old");
    assert_eq!(dir.entries(), ["out.h5"]);

    // And the temporary sits next to the target with the documented name.
    write_atomically(&path, |tmp| {
        assert_eq!(tmp.parent(), path.parent());
        assert_eq!(
            tmp.file_name().unwrap().to_str().unwrap(),
            format!(".out.h5.tmp.{}", std::process::id())
        );
        fs::write(tmp, b"new").map_err(IoError::fs(tmp, "test"))
    })
    .unwrap();
    assert_eq!(fs::read(&path).unwrap(), b"new");
}

#[test]
fn inconsistent_input_is_refused_before_touching_disk() {
    fn extra(path: &str, shape: &[usize], len: usize) -> ExtraDataset {
        ExtraDataset {
            path: path.into(),
            shape: shape.to_vec(),
            data: vec![1.0; len],
            attrs: Vec::new(),
            integer: false,
        }
    }
    let dir = TempDir::new("invalid");
    let fx = fixture(true);
    let path = dir.path("bad.h5");
    let short = vec![vec![0.0; 5]; 3];
    // One lifetime for fixture and overrides, so `&short` may be stored.
    fn case<'a>(f: impl Fn(&mut ModesFile<'a>) + 'a) -> Box<dyn Fn(&mut ModesFile<'a>) + 'a> {
        Box::new(f)
    }
    let cases = vec![
        (case(|f| f.nodes_per_tet = 6), "nodes_per_tet"),
        (case(|f| f.element_order = 1), "element_order"),
        (case(|f| f.frequencies_hz = &[1.0]), "frequencies_hz"),
        (case(|f| f.mode_shapes = &short), "mode shape 0"),
        (
            case(|f| f.connectivity = &[0, 1, 2, 3, 4, 5, 6, 7, 8, 99]),
            "node 99",
        ),
        (
            case(|f| f.solver.push(("n_ranks".into(), "2".into()))),
            "reserved",
        ),
        (case(|f| f.timings.push(("solve".into(), 1.0))), "twice"),
        (
            case(|f| f.provenance.push((String::new(), "x".into()))),
            "empty",
        ),
        (
            case(|f| f.extra_datasets.push(extra("sens/x", &[1], 1))),
            "not absolute",
        ),
        (
            case(|f| f.extra_datasets.push(extra("/modes/x", &[1], 1))),
            "fixed layout",
        ),
        (
            case(|f| f.extra_datasets.push(extra("/mesh", &[1], 1))),
            "fixed layout",
        ),
        (
            case(|f| f.extra_datasets.push(extra("/node_fields/x", &[1], 1))),
            "/node_fields is reserved",
        ),
        (
            case(|f| f.extra_datasets.push(extra("/s//x", &[1], 1))),
            "component ''",
        ),
        (
            case(|f| f.extra_datasets.push(extra("/s/../x", &[1], 1))),
            "'..'",
        ),
        (
            case(|f| f.extra_datasets.push(extra("/s/", &[1], 1))),
            "component ''",
        ),
        (
            case(|f| f.extra_datasets.push(extra("/s/a b", &[1], 1))),
            "[A-Za-z0-9_.-]",
        ),
        (
            case(|f| f.extra_datasets.push(extra("/s/x", &[2, 3], 5))),
            "5 values but shape [2, 3]",
        ),
        (
            case(|f| f.extra_datasets.push(extra("/s/x", &[], 0))),
            "0 values but shape []",
        ),
        (
            case(|f| f.extra_datasets.push(extra("/s/x", &[usize::MAX, 2], 0))),
            "shape",
        ),
        (
            case(|f| {
                let e = f.extra_datasets[3].clone();
                f.extra_datasets.push(e)
            }),
            "'/sensitivities/d_eigenvalue_d_density' is given twice",
        ),
        (
            case(|f| {
                f.extra_datasets
                    .push(extra("/sensitivities/d_eigenvalue_d_youngs/sub", &[1], 1))
            }),
            "collides with another",
        ),
        (
            case(|f| f.extra_datasets.push(extra("/a/deep", &[1], 1))),
            "'/a/deep' collides with another",
        ),
        (
            case(|f| {
                let mut e = extra("/s/counts", &[2], 2);
                e.data[1] = 0.5;
                e.integer = true;
                f.extra_datasets.push(e)
            }),
            "not a whole number",
        ),
        (
            case(|f| f.extra_datasets[0].attrs.push((String::new(), "x".into()))),
            "empty attribute name",
        ),
        (
            case(|f| f.extra_datasets[4].attrs.push(("units".into(), "x".into()))),
            "'units' is given twice",
        ),
        (
            case(|f| f.extra_datasets[0].attrs.push(("k".into(), "a\0b".into()))),
            "NUL",
        ),
        (case(|f| f.node_fields[0].name.clear()), "empty name"),
        (case(|f| f.node_fields[0].name = "d-x".into()), "'d-x'"),
        (
            case(|f| f.node_fields[1].name = f.node_fields[0].name.clone()),
            "given twice",
        ),
        (
            case(|f| f.node_fields[1].data = &short[0]),
            "'marker' has length 5",
        ),
        (case(|f| f.node_fields[1].units = "\0".into()), "NUL"),
    ];
    for (mutate, needle) in cases {
        let mut f = modes_file(&fx);
        mutate(&mut f);
        let err = write_modes(&path, &f).unwrap_err();
        let msg = err.to_string();
        assert!(matches!(err, IoError::InvalidInput { .. }), "{msg}");
        assert!(msg.contains(needle) && msg.contains("bad.h5"), "{msg}");
        assert!(dir.entries().is_empty());
    }
}

#[test]
fn reading_garbage_or_missing_files_names_the_file() {
    let dir = TempDir::new("garbage");
    let missing = dir.path("missing.h5");
    let err = read_modes(&missing).unwrap_err();
    assert!(
        matches!(err, IoError::Fs { .. }) && err.to_string().contains("missing.h5"),
        "{err}"
    );

    let garbage = dir.path("garbage.h5");
    fs::write(&garbage, b"this is not HDF5").unwrap();
    let err = read_modes(&garbage).unwrap_err();
    assert!(
        matches!(err, IoError::Hdf5 { .. }) && err.to_string().contains("garbage.h5"),
        "{err}"
    );

    // A valid HDF5 file that is not ours.
    let foreign = dir.path("foreign.h5");
    {
        let f = hdf5::File::create(&foreign).unwrap();
        f.new_attr::<VarLenUnicode>()
            .create("format")
            .unwrap()
            .write_scalar(&"other".parse::<VarLenUnicode>().unwrap())
            .unwrap();
    }
    let err = read_modes(&foreign).unwrap_err();
    assert!(
        matches!(err, IoError::BadLayout { .. }) && err.to_string().contains("foreign.h5"),
        "{err}"
    );
}
