#!/usr/bin/python3
"""Prints size facts of a 4-node-tet Gmsh mesh as JSON (needs numpy and the
gmsh module: run with Debian's /usr/bin/python3).

    /usr/bin/python3 scripts/bench/mesh_info.py MESH.msh

Output: {"n_vertices", "n_cells", "n_edges", "p2_dofs", "bbox_min",
"bbox_max", "diagonal"}, where p2_dofs = 3 (vertices + edges) is the size of
the P2 vector space built on the mesh (straight-sided 10-node tets).
"""

import json
import sys

import gmsh
import numpy as np


def mesh_info(path):
    gmsh.initialize(["gmsh", "-v", "0"])
    try:
        gmsh.open(path)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        coords = np.asarray(coords).reshape(-1, 3)
        types, _, nodes = gmsh.model.mesh.getElements(dim=3)
    finally:
        gmsh.finalize()
    tets = np.concatenate([np.asarray(n) for t, n in zip(types, nodes) if t == 4]).reshape(-1, 4)
    used = np.unique(tets)
    index = np.full(int(tags.max()) + 1, -1, dtype=np.int64)
    index[tags.astype(np.int64)] = np.arange(len(tags))
    x = coords[index[used.astype(np.int64)]]
    a = tets[:, [0, 0, 0, 1, 1, 2]].reshape(-1)
    b = tets[:, [1, 2, 3, 2, 3, 3]].reshape(-1)
    lo, hi = np.minimum(a, b).astype(np.int64), np.maximum(a, b).astype(np.int64)
    key = lo * (int(used.max()) + 1) + hi
    n_edges = int(np.unique(key).size)
    bmin, bmax = x.min(axis=0), x.max(axis=0)
    return {
        "n_vertices": int(used.size),
        "n_cells": int(tets.shape[0]),
        "n_edges": n_edges,
        "p2_dofs": 3 * (int(used.size) + n_edges),
        "bbox_min": bmin.tolist(),
        "bbox_max": bmax.tolist(),
        "diagonal": float(np.linalg.norm(bmax - bmin)),
    }


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    print(json.dumps(mesh_info(sys.argv[1])))
