use super::*;
use std::sync::atomic::{AtomicUsize, Ordering};

/// A fresh directory under the system temp dir, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> TempDir {
        static COUNTER: AtomicUsize = AtomicUsize::new(0);
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let dir =
            std::env::temp_dir().join(format!("diffsound-io-{tag}-{}-{n}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }
    fn path(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
    fn entries(&self) -> Vec<String> {
        let mut names: Vec<String> = fs::read_dir(&self.0)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = fs::remove_dir_all(&self.0);
    }
}

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
fn xdmf_sidecar_references_the_h5_by_name_and_slabs_fit() {
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
    assert!(xml.contains(&format!(">2 0 0 1 1 1 1 {n} 3<")));
    assert!(xml.contains(&format!(r#"Dimensions="3 {n} 3""#)));
    assert!(xml.contains(r#"<Information Name="material" Value="steel &amp; &lt;co&gt;"/>"#));
    assert_eq!(xml.matches("<Attribute ").count(), 3);
    check_xdmf_with_python(&dir.path("results.xdmf"));
    check_with_paraview(&dir.path("results.xdmf"), &fx);
}

/// Parses the sidecar with Python's xml.etree and, where h5py is importable,
/// checks every HDF DataItem's Dimensions against the real dataset and every
/// HyperSlab against its source. Skipped (with a note) without python3.
fn check_xdmf_with_python(xdmf: &Path) {
    const SCRIPT: &str = r#"
import sys, os, xml.etree.ElementTree as ET
path = sys.argv[1]
root = ET.parse(path).getroot()
assert root.tag == "Xdmf" and root.get("Version") == "3.0", root.attrib
grids = root.findall("./Domain/Grid")
assert len(grids) == 1
grid = grids[0]
topo = grid.find("Topology")
assert topo.get("TopologyType") in ("Tetrahedron", "Tetrahedron_10")
dims = lambda e: [int(x) for x in e.get("Dimensions").split()]
try:
    import h5py
except ImportError:
    h5py = None
    print("note: h5py not importable, dataset dimensions not checked")
def check_hdf(item):
    fname, dset = item.text.strip().split(":", 1)
    assert os.sep not in fname, fname
    if h5py:
        with h5py.File(os.path.join(os.path.dirname(path), fname), "r") as f:
            assert list(f[dset].shape) == dims(item), (dset, f[dset].shape, dims(item))
    return dims(item)
n_elem = int(topo.get("NumberOfElements"))
assert check_hdf(topo.find("DataItem"))[0] == n_elem
n_nodes = check_hdf(grid.find("Geometry/DataItem"))[0]
attrs = grid.findall("Attribute")
for k, a in enumerate(attrs):
    assert a.get("Center") == "Node" and a.get("AttributeType") == "Vector"
    slab = a.find("DataItem")
    assert slab.get("ItemType") == "HyperSlab"
    sel, src = slab.findall("DataItem")
    start, stride, count = [[int(x) for x in row] for row in zip(*[iter(sel.text.split())] * 3)]
    assert dims(sel) == [3, 3]
    src_dims = check_hdf(src)
    assert start == [k, 0, 0] and stride == [1, 1, 1] and count == [1, n_nodes, 3], (start, stride, count)
    assert dims(slab) == [n_nodes, 3] == count[1:]
    assert all(s + c <= d for s, c, d in zip(start, count, src_dims))
print("xdmf ok", len(attrs), "modes")
"#;
    // Debian's python3 carries python3-h5py; a pyenv shim in PATH may not.
    let candidates = ["/usr/bin/python3", "python3"];
    for python in candidates {
        match std::process::Command::new(python)
            .arg("-c")
            .arg(SCRIPT)
            .arg(xdmf)
            .output()
        {
            Ok(out) => {
                let text = format!(
                    "{}{}",
                    String::from_utf8_lossy(&out.stdout),
                    String::from_utf8_lossy(&out.stderr)
                );
                assert!(out.status.success(), "python XDMF check failed:\n{text}");
                eprintln!("{python}: {}", text.trim());
                return;
            }
            Err(_) => continue,
        }
    }
    eprintln!("note: python3 not found; XDMF XML not parsed independently");
}

/// Loads the sidecar with ParaView's "XDMF Reader" through `pvbatch` (if
/// installed) and checks cell type, sizes and every mode array against the
/// fixture. Skipped with a note when ParaView is absent (as on CI).
fn check_with_paraview(xdmf: &Path, fx: &Fixture) {
    const SCRIPT: &str = r#"
import sys, json
from paraview import simple as pv, servermanager as sm
r = pv.XDMFReader(FileNames=[sys.argv[1]])
r.UpdatePipeline()
ds = sm.Fetch(r)
if ds.IsA("vtkMultiBlockDataSet"):
    ds = ds.GetBlock(0)
pd = ds.GetPointData()
arrays = []
for i in range(pd.GetNumberOfArrays()):
    a = pd.GetArray(i)
    arrays.append([pd.GetArrayName(i), a.GetNumberOfComponents(),
                   [a.GetComponent(t, c) for t in range(a.GetNumberOfTuples()) for c in range(3)]])
# VTK's own view of each cell edge: ends 0 and 1, mid-edge node 2 (quadratic).
worst = 0.0
for i in range(ds.GetNumberOfCells()):
    cell = ds.GetCell(i)
    for e in range(cell.GetNumberOfEdges()):
        edge = cell.GetEdge(e)
        if edge.GetNumberOfPoints() == 3:
            p, q, m = (edge.GetPoints().GetPoint(j) for j in range(3))
            worst = max(worst, max(abs(m[c] - 0.5 * (p[c] + q[c])) for c in range(3)))
print("PVRESULT " + json.dumps({"points": ds.GetNumberOfPoints(), "edge_mid_error": worst,
    "cell_types": sorted({ds.GetCellType(i) for i in range(ds.GetNumberOfCells())}),
    "cells": ds.GetNumberOfCells(), "arrays": arrays}))
"#;
    let script = xdmf.with_extension("pvcheck.py");
    fs::write(&script, SCRIPT).unwrap();
    let out = match std::process::Command::new("pvbatch").arg(&script).arg(xdmf).output() {
        Ok(out) => out,
        Err(_) => {
            eprintln!("note: pvbatch (ParaView) not found; sidecar not loaded in ParaView");
            return;
        }
    };
    let stdout = String::from_utf8_lossy(&out.stdout);
    let line = stdout.lines().find_map(|l| l.strip_prefix("PVRESULT ")).unwrap_or_else(|| {
        panic!("pvbatch gave no result:\n{stdout}\n{}", String::from_utf8_lossy(&out.stderr))
    });
    let v: serde_json::Value = serde_json::from_str(line).unwrap();
    // VTK_TETRA = 10, VTK_QUADRATIC_TETRA = 24.
    let cell_type = if fx.nodes_per_tet == 10 { 24 } else { 10 };
    assert_eq!(v["cell_types"], serde_json::json!([cell_type]));
    assert_eq!(v["points"], fx.nodes.len());
    assert_eq!(v["cells"], fx.connectivity.len() / fx.nodes_per_tet);
    // A wrong Gmsh→VTK permutation would put mid-edge nodes off their edges.
    assert!(v["edge_mid_error"].as_f64().unwrap() < 1e-12, "{v}");
    let arrays = v["arrays"].as_array().unwrap();
    assert_eq!(arrays.len(), fx.shapes.len(), "one point array per mode");
    for (k, a) in arrays.iter().enumerate() {
        assert_eq!(a[0].as_str().unwrap(), format!("mode_{k:03} ({:.1} Hz)", fx.frequencies[k]));
        assert_eq!(a[1], 3);
        let values: Vec<f64> = a[2].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
        assert_eq!(values, fx.shapes[k], "mode {k} as ParaView sees it");
    }
    eprintln!("pvbatch: XDMF Reader loaded {} modes on cell type {cell_type}", arrays.len());
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
    check_xdmf_with_python(&dir.path("lin.xdmf"));
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
