"""Reads an XDMF sidecar written by diffsound the way a Python user would, and checks it.

    python3 tests/python/check_sidecar.py FILE.xdmf [NAME=scalar|NAME=vector ...]

meshio must read it (tetra10 or tetra cells, every Attribute a point field); each node field
named on the command line must be there with one value per node (scalar, a 1-D array) or
three (vector); every point field must equal its dataset in the HDF5 file, read with h5py;
the XML holds no <Information> and exactly one DataItem per Attribute. Exits non-zero with a
message on the first failure; prints one summary line per array on success. Used by the unit
tests of src/io and the CLI tests (tests/common), with Debian's python3-meshio and
python3-h5py (scripts/install-deps.sh installs them).
"""
import os
import sys
import xml.etree.ElementTree as ET

try:
    import h5py
    import meshio
    import numpy as np
except ImportError as e:
    sys.exit(f"{e}: the Python readers are missing; run scripts/install-deps.sh "
             "(python3-meshio, python3-h5py)")

xdmf = sys.argv[1]
expected = dict(a.split("=", 1) for a in sys.argv[2:])
h5_dir = os.path.dirname(xdmf)

# The XML: no element meshio cannot take.
root = ET.parse(xdmf).getroot()
assert not root.findall(".//Information"), "an <Information> element: meshio refuses it"
grid = root.find("./Domain/Grid")
for a in grid.findall("Attribute"):
    assert len(list(a)) == 1 and a[0].tag == "DataItem", f"{a.get('Name')}: one DataItem"
    dims = a[0].get("Dimensions").split()
    kind = a.get("AttributeType")
    assert (kind, len(dims)) in (("Scalar", 1), ("Vector", 2)), (a.get("Name"), kind, dims)
h5_name = grid.find("Geometry/DataItem").text.strip().split(":", 1)[0]
assert os.sep not in h5_name, f"the HDF5 file is named by its file name only: {h5_name}"

mesh = meshio.read(xdmf)
with h5py.File(os.path.join(h5_dir, h5_name), "r") as f:
    nodes = f["/mesh/nodes"][()]
    n = len(nodes)
    assert mesh.points.shape == (n, 3) and np.array_equal(mesh.points, nodes)
    (block,) = mesh.cells
    assert block.type in ("tetra10", "tetra"), block.type
    tets = f["/mesh/tets_vtk"][()]
    assert block.data.shape == tets.shape and np.array_equal(block.data, tets)
    assert f["/mesh/nodes"].attrs["units"] == "m"
    print(f"meshio: {block.type} {block.data.shape}, points {mesh.points.shape}")
    shapes = f["/modes/shapes"]
    modes = sorted(k for k in mesh.point_data if k.startswith("mode_"))
    assert len(modes) == shapes.shape[0], (len(modes), shapes.shape)
    for k, name in enumerate(modes):
        v = mesh.point_data[name]
        assert name.startswith("mode_%03d " % k) or name.startswith("mode_%04d " % k), name
        assert v.shape == (n, 3) and np.array_equal(v, shapes[k]), (name, v.shape)
    print(f"meshio: {len(modes)} modes, each {(n, 3)} float64")
    fields = {k: v for k, v in mesh.point_data.items() if not k.startswith("mode_")}
    assert set(fields) == set(expected), f"node fields {sorted(fields)}, expected {sorted(expected)}"
    for name, v in sorted(fields.items()):
        ds = f["/node_fields/" + name]
        want = (n,) if expected[name] == "scalar" else (n, 3)
        assert v.shape == want == ds.shape, (name, v.shape, want, ds.shape)
        assert np.array_equal(v, ds[()]), name
        units = ds.attrs["units"]
        span = f"[{v.min():.3g}, {v.max():.3g}]" if v.size else "[]"
        print(f"meshio: {name} {v.shape} {v.dtype} in {span}, h5py units {units!r}")
print("sidecar ok:", os.path.basename(xdmf))
