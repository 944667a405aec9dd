#!/usr/bin/python3
"""Reference free-body modal solve in dolfinx (Debian's python3-dolfinx 0.5.2).

Solves the same problem as `diffsound modes`: P2 (10-node, straight-sided)
vector Lagrange elements on a tet4 Gmsh mesh, isotropic linear elasticity,

    a(u, v) = ∫ σ(u) : ε(v) dx,   m(u, v) = ∫ ρ u · v dx,   K φ = ω² M φ,

with no boundary conditions (free body: six zero eigenvalues), solved by SLEPc
Krylov–Schur with shift-and-invert and a MUMPS Cholesky factorisation. All
solver settings come from the PETSc options given after `--`, so that the
benchmark can hand both programs exactly the same list.

With `--path iterative --shift SIGMA` it solves instead as `diffsound modes
--solver iterative --preconditioner gamg` does, without any factor: SLEPc's
generalised Davidson for the N smallest eigenvalues in the M-orthogonal
complement of the six rigid motions (the deflation space), preconditioned by
one GAMG V-cycle (plain aggregation) on P = K - SIGMA M with the rigid motions
as P's near-null space, relative residual tolerance 1e-8. Options after `--`
still override.

Run under MPI, with Debian's python:

    OPENBLAS_NUM_THREADS=1 mpirun --allow-run-as-root -np 2 /usr/bin/python3 \\
        scripts/bench/dolfinx_modes.py --mesh bowl.msh --youngs 72e9 \\
        --poisson 0.19 --density 2700 --modes 20 --out result.json -- \\
        -eps_target -1e3 -st_type sinvert ...

Writes one JSON file (rank 0) with timings, peak memory and eigenvalues; the
field names match diffsound's `--timings-json` so the two can be compared.
"""

import argparse
import json
import os
import resource
import sys
import time


def parse_args(argv):
    if "--" in argv:
        i = argv.index("--")
        ours, petsc = argv[:i], argv[i + 1:]
    else:
        ours, petsc = argv, []
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--mesh", required=True, help="Gmsh .msh file with 4-node tets (metres)")
    p.add_argument("--youngs", type=float, required=True, help="Young's modulus [Pa]")
    p.add_argument("--poisson", type=float, required=True, help="Poisson ratio [-]")
    p.add_argument("--density", type=float, required=True, help="density [kg/m^3]")
    p.add_argument("--modes", type=int, default=20, help="number of elastic modes N (nev = N + 6)")
    p.add_argument("--out", required=True, help="JSON output path")
    p.add_argument("--path", choices=["direct", "iterative"], default="direct",
                   help="direct: the options given (shift-invert + MUMPS); iterative: GD + GAMG")
    p.add_argument("--shift", type=float, default=None,
                   help="sigma of P = K - sigma M for the iterative path [rad^2/s^2]")
    return p.parse_args(ours), petsc


ARGS, PETSC_ARGS = parse_args(sys.argv[1:])

# PETSc must see the options before dolfinx initialises it.
import petsc4py  # noqa: E402

petsc4py.init([sys.argv[0]] + PETSC_ARGS)
from petsc4py import PETSc  # noqa: E402
from slepc4py import SLEPc  # noqa: E402
from mpi4py import MPI  # noqa: E402
import numpy as np  # noqa: E402
import ufl  # noqa: E402
import dolfinx  # noqa: E402
import dolfinx.fem.petsc  # noqa: E402

COMM = MPI.COMM_WORLD
RANK = COMM.rank


def wall():
    COMM.Barrier()
    return time.perf_counter()


def read_tet_mesh(path):
    """Reads nodes and 4-node tets on rank 0 with the gmsh module; every other
    rank contributes nothing and dolfinx distributes the mesh."""
    if RANK == 0:
        import gmsh

        gmsh.initialize(["gmsh", "-v", "0"])
        gmsh.open(path)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        coords = np.asarray(coords, dtype=np.float64).reshape(-1, 3)
        types, _, nodes = gmsh.model.mesh.getElements(dim=3)
        tets = [np.asarray(n) for t, n in zip(types, nodes) if t == 4]
        others = [t for t in types if t != 4]
        gmsh.finalize()
        if not tets or others:
            raise SystemExit(f"{path}: expected only 4-node tets, got element types {list(types)}")
        tets = np.concatenate(tets).reshape(-1, 4)
        # Map gmsh node tags to 0-based rows, keeping only nodes used by tets.
        index = np.full(int(tags.max()) + 1, -1, dtype=np.int64)
        index[tags.astype(np.int64)] = np.arange(len(tags))
        cells = index[tets.astype(np.int64)]
        used = np.unique(cells)
        remap = np.full(len(tags), -1, dtype=np.int64)
        remap[used] = np.arange(len(used))
        cells = remap[cells]
        x = coords[used]
    else:
        cells = np.empty((0, 4), dtype=np.int64)
        x = np.empty((0, 3), dtype=np.float64)
    domain = ufl.Mesh(ufl.VectorElement("Lagrange", ufl.tetrahedron, 1))
    return dolfinx.mesh.create_mesh(COMM, cells, x, domain)


def mumps_info(pc):
    """Selected MUMPS statistics of the factorisation (sums over ranks)."""
    try:
        f = pc.getFactorMatrix()
        return {
            "infog16_max_est_mb": int(f.getMumpsInfog(16)),
            "infog17_sum_est_mb": int(f.getMumpsInfog(17)),
            "infog21_max_used_mb": int(f.getMumpsInfog(21)),
            "infog22_sum_used_mb": int(f.getMumpsInfog(22)),
            "infog9_factor_entries": int(f.getMumpsInfog(9)),
            # BLR: entries after compression, estimated in-core / OOC sizes
            "infog35_blr_factor_entries": int(f.getMumpsInfog(35)),
            "infog37_blr_sum_est_mb": int(f.getMumpsInfog(37)),
            "infog39_blr_ooc_sum_est_mb": int(f.getMumpsInfog(39)),
            "infog7_ordering": int(f.getMumpsInfog(7)),
            "rinfog3_flops": float(f.getMumpsRinfog(3)),
            "icntl35_blr": int(f.getMumpsIcntl(35)),
            "icntl22_ooc": int(f.getMumpsIcntl(22)),
            "cntl7_blr_eps": float(f.getMumpsCntl(7)),
        }
    except Exception as exc:  # not MUMPS, or petsc4py without these calls
        return {"error": str(exc)}


def main():
    t_start = wall()
    E, nu, rho = ARGS.youngs, ARGS.poisson, ARGS.density
    mu = E / (2.0 * (1.0 + nu))
    lmbda = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))

    t0 = wall()
    mesh = read_tet_mesh(ARGS.mesh)
    t_mesh = wall() - t0

    t0 = wall()
    V = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 2))
    t_space = wall() - t0
    ndof = V.dofmap.index_map.size_global * V.dofmap.index_map_bs

    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)

    def eps(w):
        return ufl.sym(ufl.grad(w))

    def sigma(w):
        return 2.0 * mu * eps(w) + lmbda * ufl.tr(eps(w)) * ufl.Identity(3)

    t0 = wall()
    a_form = dolfinx.fem.form(ufl.inner(sigma(u), eps(v)) * ufl.dx)
    m_form = dolfinx.fem.form(rho * ufl.inner(u, v) * ufl.dx)
    t_compile = wall() - t0

    t0 = wall()
    K = dolfinx.fem.petsc.assemble_matrix(a_form)
    K.assemble()
    M = dolfinx.fem.petsc.assemble_matrix(m_form)
    M.assemble()
    for A in (K, M):
        A.setOption(PETSc.Mat.Option.SYMMETRIC, True)
    t_assemble = wall() - t0

    n_modes = ARGS.modes
    times = (t_mesh, t_compile, t_space, t_assemble)
    if ARGS.path == "iterative":
        return solve_iterative(V, K, M, ndof, mesh, t_start, times)
    nev = n_modes + 6
    t0 = wall()
    eps_solver = SLEPc.EPS().create(COMM)
    eps_solver.setOperators(K, M)
    # Defaults equal to the benchmark's settings; the command line overrides.
    eps_solver.setProblemType(SLEPc.EPS.ProblemType.GHEP)
    eps_solver.setType(SLEPc.EPS.Type.KRYLOVSCHUR)
    eps_solver.setDimensions(nev=nev)
    eps_solver.setTolerances(tol=1e-10)
    eps_solver.setWhichEigenpairs(SLEPc.EPS.Which.TARGET_MAGNITUDE)
    st = eps_solver.getST()
    st.setType(SLEPc.ST.Type.SINVERT)
    ksp = st.getKSP()
    ksp.setType(PETSc.KSP.Type.PREONLY)
    pc = ksp.getPC()
    pc.setType(PETSc.PC.Type.CHOLESKY)
    pc.setFactorSolverType("mumps")
    eps_solver.setFromOptions()
    eps_solver.solve()
    t_solve = wall() - t0
    t_total = wall() - t_start

    nconv, vals, errs = sorted_pairs(eps_solver)
    want = min(nev, nconv)
    rigid = vals[:6].tolist()
    elastic = vals[6:want].tolist()
    finish(eps_solver, mesh, ndof, times, t_solve, t_total, nev, int(nconv), rigid, elastic,
           # relative residuals of the elastic pairs (the rigid ones have
           # eigenvalues ~0, so their relative error is meaningless)
           float(errs[6:want].max()) if want > 6 else None,
           {"mumps": mumps_info(pc)})


def sorted_pairs(eps_solver):
    """The converged count, eigenvalues ascending and their relative errors."""
    nconv = eps_solver.getConverged()
    vals = np.array([eps_solver.getEigenvalue(i).real for i in range(nconv)])
    errs = np.array([eps_solver.computeError(i) for i in range(nconv)])
    order = np.argsort(vals)
    return nconv, vals[order], errs[order]


def finish(eps_solver, mesh, ndof, times, t_solve, t_total, nev, nconv, rigid, elastic, max_err, extra):
    """Gathers the peak memory and writes the JSON report (rank 0), atomically."""
    t_mesh, t_compile, t_space, t_assemble = times
    peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux
    per_rank = COMM.gather(peak_kb / 1024.0, root=0)
    peak_sum = COMM.allreduce(peak_kb, op=MPI.SUM) / 1024.0
    if RANK != 0:
        return
    out = {
        "program": "dolfinx",
        "dolfinx_version": dolfinx.__version__,
        "path": ARGS.path,
        "mesh": os.path.abspath(ARGS.mesh),
        "ndof": int(ndof),
        "n_vertices": int(mesh.topology.index_map(0).size_global),
        "n_cells": int(mesh.topology.index_map(3).size_global),
        "n_ranks": COMM.size,
        "mesh_s": t_mesh,
        "compile_s": t_compile,
        "space_s": t_space,
        "assemble_s": t_assemble,
        # comparable to diffsound's assembly: dof numbering + matrices
        "assembly_s": t_space + t_assemble,
        "solve_s": t_solve,
        "total_s": t_total,
        "peak_rss_mb": peak_sum,
        "peak_rss_mb_per_rank": per_rank,
        "nconv": nconv,
        "nev": nev,
        "its": int(eps_solver.getIterationNumber()),
        "max_rel_error": max_err,
        "rigid_eigenvalues": rigid,
        "eigenvalues": elastic,
        "frequencies_hz": [float(np.sqrt(max(x, 0.0)) / (2 * np.pi)) for x in elastic],
        "petsc_options": PETSC_ARGS,
        **extra,
    }
    tmp = ARGS.out + ".tmp"
    with open(tmp, "w") as f:
        json.dump(out, f, indent=1)
    os.replace(tmp, ARGS.out)
    print(
        f"[dolfinx] {ARGS.path} ndof={ndof} assembly={t_space + t_assemble:.2f}s (compile {t_compile:.2f}s) "
        f"solve={t_solve:.2f}s its={out['its']} peak={peak_sum:.0f}MB nconv={nconv}",
        flush=True,
    )


def rigid_motions(V, K):
    """The six rigid motions (three translations, three rotations about the
    centroid) as PETSc vectors with K's layout, orthonormalised (Euclidean)."""
    x = V.tabulate_dof_coordinates()
    n_owned = V.dofmap.index_map.size_local
    x = x[:n_owned]
    centre = COMM.allreduce(x.sum(axis=0), op=MPI.SUM) / COMM.allreduce(len(x), op=MPI.SUM)
    x = x - centre
    vecs = []
    for i in range(6):
        v = K.createVecRight()
        a = v.getArray().reshape(-1, 3)
        a[:] = 0.0
        if i < 3:
            a[:, i] = 1.0
        else:
            axis = np.zeros(3)
            axis[i - 3] = 1.0
            a[:] = np.cross(axis, x)
        v.setArray(a.ravel())
        vecs.append(v)
    basis = []
    for v in vecs:
        for _ in range(2):
            for q in basis:
                v.axpy(-v.dot(q), q)
        v.scale(1.0 / v.norm())
        basis.append(v)
    return basis


def solve_iterative(V, K, M, ndof, mesh, t_start, times):
    if ARGS.shift is None:
        raise SystemExit("--path iterative needs --shift")
    sigma = ARGS.shift
    n_modes = ARGS.modes
    t0 = wall()
    rigid = rigid_motions(V, K)
    P = K.copy()
    P.axpy(-sigma, M, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
    P.setOption(PETSc.Mat.Option.SYMMETRIC, True)
    P.setNearNullSpace(PETSc.NullSpace().create(vectors=rigid, comm=COMM))
    eps_solver = SLEPc.EPS().create(COMM)
    eps_solver.setOperators(K, M)
    eps_solver.setProblemType(SLEPc.EPS.ProblemType.GHEP)
    eps_solver.setType(SLEPc.EPS.Type.GD)
    eps_solver.setDimensions(nev=n_modes)
    eps_solver.setTolerances(tol=1e-8, max_it=20000)
    eps_solver.setWhichEigenpairs(SLEPc.EPS.Which.SMALLEST_REAL)
    eps_solver.setTarget(sigma)
    eps_solver.setDeflationSpace(rigid)
    st = eps_solver.getST()
    st.setType(SLEPc.ST.Type.PRECOND)
    st.setPreconditionerMat(P)
    ksp = st.getKSP()
    ksp.setType(PETSc.KSP.Type.PREONLY)
    pc = ksp.getPC()
    pc.setType(PETSc.PC.Type.GAMG)
    pc.setGAMGSmooths(0)
    eps_solver.setFromOptions()
    eps_solver.solve()
    t_solve = wall() - t0
    t_total = wall() - t_start
    nconv, vals, errs = sorted_pairs(eps_solver)
    vals, errs = vals[:n_modes], errs[:n_modes]
    finish(eps_solver, mesh, ndof, times, t_solve, t_total, n_modes, int(nconv), [],
           vals.tolist(), float(errs.max()) if len(errs) else None, {})


if __name__ == "__main__":
    main()
