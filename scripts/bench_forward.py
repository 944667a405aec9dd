#!/usr/bin/env python3
"""Side-by-side forward benchmark: diffsound vs dolfinx on the same meshes.

Both programs solve the same free-body P2 elasticity eigenproblem
K φ = ω² M φ (10-node straight-sided tets lifted from the same tet4 mesh,
no boundary conditions) with the same SLEPc/MUMPS settings, handed to both as
the same explicit PETSc option list:

    Krylov–Schur, GHEP, shift-and-invert at the target σ (nearest first),
    preonly + MUMPS Cholesky, nev = N + 6 (N elastic + 6 rigid), tol 1e-10,
    σ = −0.01 μ / (ρ L²) with L the bounding-box diagonal of the mesh,
    and for large meshes MUMPS out-of-core (see LOWMEM_OPTIONS below).

Per mesh size it prints ndof, assembly / solve / total time, peak memory
(RSS summed over ranks), diffsound/dolfinx ratios and the largest relative
difference between the two sets of elastic eigenvalues, and writes
out/bench/forward.json. It only measures; it never asserts a time.

Usage (any python3; the dolfinx side runs under Debian's /usr/bin/python3):

    python3 scripts/bench_forward.py [--sizes bowl,300k,1m] [--modes 20]
        [--programs dolfinx,diffsound] [--np 2] [--lowmem auto|on|off]
        [--path direct|iterative] [--preconditioner auto|gamg|pmg|pmg-mumps]

With --path iterative neither side forms a factor: dolfinx runs SLEPc's
generalised Davidson preconditioned by GAMG with the rigid motions as
near-null space and deflation space (scripts/bench/dolfinx_modes.py
--path iterative), diffsound its `--solver iterative` with the chosen
preconditioner (default auto: the P2 -> P1 p-multigrid); both to a relative
residual of 1e-8, without diffsound's completeness probe. The report goes to
CACHE/forward_iterative.json.

Sizes (meshes are generated once with gmsh and cached under out/bench/):
    bowl   the shared bowl, shared/data/bowl/bowl.msh      (  53,574 P2 DOF)
    300k   the bowl refined once with `gmsh -refine`       ( 355,365 P2 DOF)
    1m     scripts/bench/thick_bowl.geo at clmax 1.3 mm    (~1,085,000 P2 DOF)
    100k   scripts/bench/thick_bowl.geo at clmax 3.0 mm    (~  112,000 P2 DOF)
    sphere165k, sphere1m, sphere3m   tests/data/analytic/sphere.geo at clmax
           40, 21.5 and 14.6 mm (~165k, ~1.0M, ~3.1M P2 DOF; straight-sided)

Needs: gmsh, openmpi-bin, python3-dolfinx and python3-gmsh (apt), and for the diffsound
side a release build (`cargo build --release`); a missing program is
reported and skipped.
"""

import argparse
import datetime
import json
import math
import os
import platform
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BENCH_DIR = ROOT / "scripts" / "bench"
SYS_PYTHON = os.environ.get("BENCH_PYTHON", "/usr/bin/python3")

# Ceramic, as in the project's examples.
YOUNGS, POISSON, DENSITY = 72e9, 0.19, 2700.0

SIZES = {
    "bowl": {"recipe": "shared", "desc": "shared bowl (3007 nodes, 8840 tets)", "timeout": 600},
    "100k": {"recipe": "geo", "geo": "thick_bowl.geo", "clmax": 0.003,
             "file": "thick_bowl_h3.0mm.msh", "desc": "thick_bowl.geo, clmax 3.0 mm", "timeout": 900},
    "300k": {"recipe": "refine", "base": "bowl", "file": "bowl_refined1.msh",
             "desc": "bowl refined once (gmsh -refine)", "timeout": 1200},
    "1m": {"recipe": "geo", "geo": "thick_bowl.geo", "clmax": 0.0013,
           "file": "thick_bowl_h1.3mm.msh", "desc": "thick_bowl.geo, clmax 1.3 mm", "timeout": 2400},
    # Free solid spheres of radius 0.5 m (tests/data/analytic/sphere.geo), straight-sided tet4
    # meshes lifted to P2 by both programs; for the iterative path (--path iterative).
    "sphere165k": {"recipe": "geo", "geo": "../../tests/data/analytic/sphere.geo", "clmax": 0.04,
                   "file": "sphere_h40mm.msh", "desc": "sphere.geo, clmax 40 mm", "timeout": 3600},
    "sphere1m": {"recipe": "geo", "geo": "../../tests/data/analytic/sphere.geo", "clmax": 0.0215,
                 "file": "sphere_h21.5mm.msh", "desc": "sphere.geo, clmax 21.5 mm", "timeout": 7200},
    "sphere3m": {"recipe": "geo", "geo": "../../tests/data/analytic/sphere.geo", "clmax": 0.0146,
                 "file": "sphere_h14.6mm.msh", "desc": "sphere.geo, clmax 14.6 mm", "timeout": 10800},
}

# Above this many DOF the factorisation runs out of core by default.
# Measured with dolfinx on this 2-core / 24 GB machine, 1.085M DOF thick bowl,
# 26 pairs: in-core MUMPS peaks at 18.3 GB summed RSS (factor 1.19e9
# entries, 4.7e12 flops, solve 388 s), too close to 24 GB on a shared
# machine; with ICNTL(22)=1 (factors on disk under MUMPS_OOC_TMPDIR, about
# 9 GB, served from the page cache) the peak RSS is 8.5-9.0 GB, the solve
# 470-530 s, and the eigenvalues match the in-core run to 3e-12. Block
# low-rank (-st_mat_mumps_icntl_35 2 -st_mat_mumps_cntl_7 1e-8) compressed
# the factors by only ~7 % at 355k DOF and moved eigenvalues by 2e-6, so it
# is not used. Note the "st_" prefix: without it MUMPS options are ignored.
LOWMEM_NDOF = 600_000
LOWMEM_OPTIONS = ["-st_mat_mumps_icntl_22", "1"]


def log(msg):
    print(msg, flush=True)


def find_shared_bowl(cli_path):
    candidates = [cli_path] if cli_path else []
    candidates += [ROOT.parent / "shared" / "data" / "bowl" / "bowl.msh",
                   Path("/work/shared/data/bowl/bowl.msh")]
    for c in candidates:
        if c and Path(c).is_file():
            return Path(c).resolve()
    raise SystemExit("bowl.msh not found; pass --bowl PATH")


def run_quiet(cmd, **kw):
    r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, **kw)
    if r.returncode != 0:
        raise SystemExit(f"command failed ({r.returncode}): {' '.join(map(str, cmd))}\n{r.stdout[-3000:]}")
    return r.stdout


def ensure_mesh(name, args, cache):
    """Returns the path of the mesh for a size, generating it if needed."""
    spec = SIZES[name]
    if spec["recipe"] == "shared":
        return find_shared_bowl(args.bowl)
    out = cache / spec["file"]
    if out.is_file():
        return out
    tmp = out.with_suffix(".tmp.msh")
    t0 = time.perf_counter()
    if spec["recipe"] == "refine":
        base = ensure_mesh(spec["base"], args, cache)
        run_quiet(["gmsh", str(base), "-refine", "-format", "msh2", "-bin", "-o", str(tmp), "-v", "2"])
    elif spec["recipe"] == "geo":
        run_quiet(["gmsh", "-3", "-nt", "1", "-clmax", str(spec["clmax"]), "-format", "msh2", "-bin",
                   "-o", str(tmp), "-v", "2", str(BENCH_DIR / spec["geo"])])
    os.replace(tmp, out)
    log(f"  meshed {name}: {out.name} in {time.perf_counter() - t0:.1f} s")
    return out


def mesh_info(path, cache):
    """Vertex/edge counts, P2 DOF and bounding box (cached per mesh file)."""
    st = path.stat()
    key = f"{path}:{st.st_size}:{int(st.st_mtime)}"
    info_file = cache / (path.name + ".info.json")
    if info_file.is_file():
        cached = json.loads(info_file.read_text())
        if cached.get("key") == key:
            return cached
    out = run_quiet([SYS_PYTHON, str(BENCH_DIR / "mesh_info.py"), str(path)])
    info = json.loads(out.strip().splitlines()[-1])
    info["key"] = key
    info_file.write_text(json.dumps(info))
    return info


def target_shift(diagonal):
    mu = YOUNGS / (2.0 * (1.0 + POISSON))
    return -0.01 * mu / (DENSITY * diagonal ** 2)


def petsc_options(n_modes, sigma, lowmem):
    opts = [
        "-eps_type", "krylovschur", "-eps_gen_hermitian",
        "-eps_nev", str(n_modes + 6), "-eps_tol", "1e-10",
        "-eps_target", f"{sigma:.17g}", "-eps_target_magnitude",
        "-st_type", "sinvert", "-st_ksp_type", "preonly",
        "-st_pc_type", "cholesky", "-st_pc_factor_mat_solver_type", "mumps",
    ]
    if lowmem:
        opts += LOWMEM_OPTIONS
    return opts


def mpirun_prefix(np_, env_names):
    cmd = ["mpirun", "--allow-run-as-root", "-np", str(np_)]
    for name in env_names:
        cmd += ["-x", name]
    return cmd


def run_program(prog, size, mesh, sigma, opts, args, runs_dir, timeout, ooc_dir):
    """Runs one program on one mesh; returns its timings JSON (plus wall_s)
    or a dict with an "error"."""
    tag = f"{size}_{prog}" + ("_iterative" if args.path == "iterative" else "")
    result_json = runs_dir / f"{tag}.json"
    log_file = runs_dir / f"{tag}.log"
    if result_json.exists():
        result_json.unlink()
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MUMPS_OOC_TMPDIR=str(ooc_dir))
    env_names = ["OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MUMPS_OOC_TMPDIR"]
    material = ["--youngs", repr(YOUNGS), "--poisson", repr(POISSON), "--density", repr(DENSITY)]
    h5 = None
    iterative = args.path == "iterative"
    if prog == "dolfinx":
        path = ["--path", "iterative", f"--shift={sigma:.17g}"] if iterative else []
        cmd = mpirun_prefix(args.np, env_names) + [
            SYS_PYTHON, str(BENCH_DIR / "dolfinx_modes.py"), "--mesh", str(mesh), *material,
            "--modes", str(args.modes), *path, "--out", str(result_json), "--", *opts]
    else:
        binary = Path(args.diffsound)
        if not binary.is_file():
            return {"error": f"binary not found: {binary} (run `cargo build --release`)", "skipped": True}
        h5 = runs_dir / f"{tag}.h5"
        # --no-verify: skip diffsound's extra inertia (mode-count) check, which
        # the dolfinx side does not do; --diffsound-verify puts it back.
        verify = [] if args.diffsound_verify else ["--no-verify"]
        # The iterative path keeps its own tolerance (1e-8 on the relative residual, as the
        # dolfinx side's); --no-verify there skips the completeness probe.
        solver = (["--solver", "iterative", "--preconditioner", args.preconditioner] if iterative
                  else ["--solver", "direct", "--tol", "1e-10"])
        cmd = mpirun_prefix(args.np, env_names) + [
            str(binary), "modes", "--mesh", str(mesh), "--units", "m", "--order", "2", *material,
            "--modes", str(args.modes), *solver, "--shift", f"{sigma:.17g}", *verify,
            "--out", str(h5), "--timings-json", str(result_json), "--", *opts]
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    with open(log_file, "w") as lf:
        lf.write(" ".join(cmd) + "\n\n")
        lf.flush()
        proc = subprocess.Popen(cmd, stdout=lf, stderr=subprocess.STDOUT, env=env, cwd=ROOT,
                                start_new_session=True)
        try:
            rc = proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            # end the whole process group we started (mpirun and its ranks)
            os.killpg(proc.pid, signal.SIGTERM)
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
            return {"error": f"timed out after {timeout} s", "log": str(log_file)}
    wall = time.perf_counter() - t0
    if h5 is not None and h5.exists() and not args.keep_h5:
        h5.unlink()
    if rc != 0 or not result_json.is_file():
        tail = log_file.read_text(errors="replace")[-1500:]
        return {"error": f"exit code {rc}", "log": str(log_file), "log_tail": tail}
    res = json.loads(result_json.read_text())
    res["wall_s"] = wall
    res["loadavg_1min_at_start"] = load
    return res


def max_rel_diff(a, b):
    n = min(len(a), len(b))
    if n == 0:
        return None
    return max(abs(x - y) / abs(y) for x, y in zip(a[:n], b[:n]))


def fmt(x, spec=".2f"):
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    return format(x, spec)


def print_table(report):
    cols = ["size", "ndof", "program", "assembly s", "solve s", "total s", "wall s", "peak MB", "nconv"]
    widths = [6, 10, 16, 11, 10, 10, 9, 10, 6]
    line = "  ".join(c.rjust(w) if i else c.ljust(w) for i, (c, w) in enumerate(zip(cols, widths)))
    log("")
    log(line)
    log("-" * len(line))
    for size, entry in report["sizes"].items():
        ndof = entry["mesh_info"]["p2_dofs"]
        for prog, res in entry["results"].items():
            if "error" in res:
                row = [size, f"{ndof:,}", prog, "error: " + res["error"]]
                log("  ".join([row[0].ljust(6), row[1].rjust(10), row[2].rjust(16), "  " + row[3]]))
                continue
            vals = [size, f"{res.get('ndof', ndof):,}", prog, fmt(res.get("assembly_s")), fmt(res.get("solve_s")),
                    fmt(res.get("total_s")), fmt(res.get("wall_s"), ".1f"), fmt(res.get("peak_rss_mb"), ".0f"),
                    str(res.get("nconv", "-"))]
            log("  ".join(v.rjust(w) if i else v.ljust(w) for i, (v, w) in enumerate(zip(vals, widths))))
        r = entry.get("ratios")
        if r:
            vals = ["", "", "diffsound/dolfinx", fmt(r.get("assembly_s"), ".2f") + "x",
                    fmt(r.get("solve_s"), ".2f") + "x", fmt(r.get("total_s"), ".2f") + "x",
                    fmt(r.get("wall_s"), ".2f") + "x", fmt(r.get("peak_rss_mb"), ".2f") + "x", ""]
            log("  ".join(v.rjust(w) if i else v.ljust(w) for i, (v, w) in enumerate(zip(vals, widths))))
        if entry.get("max_rel_eig_diff") is not None:
            log(f"{'':6}  {'':10}  max relative eigenvalue difference over {entry['n_compared']} modes: "
                f"{entry['max_rel_eig_diff']:.2e}")
        for prog, res in entry["results"].items():
            if "frequencies_hz" in res and res["frequencies_hz"]:
                f = ", ".join(f"{x:.2f}" for x in res["frequencies_hz"][:4])
                log(f"{'':6}  {'':10}  {prog} lowest Hz: {f}")
    log("")


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--sizes", default="bowl,300k,1m", help=f"comma list of {','.join(SIZES)}")
    p.add_argument("--modes", type=int, default=20, help="elastic modes N (nev = N + 6)")
    p.add_argument("--programs", default="dolfinx,diffsound")
    p.add_argument("--np", type=int, default=2, help="MPI ranks")
    p.add_argument("--lowmem", choices=["auto", "on", "off"], default="auto",
                   help=f"MUMPS out-of-core: auto = above {LOWMEM_NDOF:,} DOF")
    p.add_argument("--diffsound", default=str(ROOT / "target" / "release" / "diffsound"))
    p.add_argument("--bowl", default=None, help="path of the shared bowl.msh")
    p.add_argument("--cache", default=str(ROOT / "out" / "bench"), help="mesh and result directory")
    p.add_argument("--out", default=None, help="report path (default CACHE/forward.json)")
    p.add_argument("--timeout-scale", type=float, default=1.0, help="multiplies the per-size time limits")
    p.add_argument("--keep-h5", action="store_true", help="keep diffsound's HDF5 outputs")
    p.add_argument("--path", choices=["direct", "iterative"], default="direct",
                   help="direct: shift-invert + MUMPS on both sides (the options above); iterative: "
                        "no factor, GD + GAMG on the dolfinx side, GD + --preconditioner on ours")
    p.add_argument("--preconditioner", default="auto",
                   help="diffsound's iterative preconditioner (auto, gamg, pmg, pmg-mumps)")
    p.add_argument("--diffsound-verify", action="store_true",
                   help="let diffsound run its inertia check (extra factorisation; off for a like-for-like run)")
    args = p.parse_args()

    sizes = [s.strip() for s in args.sizes.split(",") if s.strip()]
    for s in sizes:
        if s not in SIZES:
            raise SystemExit(f"unknown size {s!r}; known: {', '.join(SIZES)}")
    programs = [s.strip() for s in args.programs.split(",") if s.strip()]
    for prog in programs:
        if prog not in ("dolfinx", "diffsound"):
            raise SystemExit(f"unknown program {prog!r}")
    for tool in ("gmsh", "mpirun"):
        if shutil.which(tool) is None:
            raise SystemExit(f"{tool} not found (apt-get install gmsh openmpi-bin)")

    cache = Path(args.cache).resolve()
    runs_dir = cache / "runs"
    ooc_dir = cache / "mumps_ooc"
    for d in (cache, runs_dir, ooc_dir):
        d.mkdir(parents=True, exist_ok=True)
    default_out = "forward_iterative.json" if args.path == "iterative" else "forward.json"
    out_path = Path(args.out) if args.out else cache / default_out

    report = {
        "generated": datetime.datetime.now().isoformat(timespec="seconds"),
        "host": {"node": platform.node(), "cpus": os.cpu_count(), "python": sys.version.split()[0]},
        "material": {"youngs": YOUNGS, "poisson": POISSON, "density": DENSITY},
        "modes": args.modes,
        "n_ranks": args.np,
        "sizes": {},
    }
    t_all = time.perf_counter()
    for size in sizes:
        mesh = ensure_mesh(size, args, cache)
        info = mesh_info(mesh, cache)
        sigma = target_shift(info["diagonal"])
        lowmem = args.path == "direct" and (
            args.lowmem == "on" or (args.lowmem == "auto" and info["p2_dofs"] > LOWMEM_NDOF))
        opts = [] if args.path == "iterative" else petsc_options(args.modes, sigma, lowmem)
        entry = {"mesh": str(mesh), "desc": SIZES[size]["desc"], "mesh_info": info, "sigma": sigma,
                 "path": args.path, "preconditioner": args.preconditioner if args.path == "iterative" else None,
                 "lowmem": lowmem, "petsc_options": opts, "results": {}}
        report["sizes"][size] = entry
        timeout = SIZES[size]["timeout"] * args.timeout_scale
        for prog in programs:
            log(f"[{size}] {prog}: {info['p2_dofs']:,} DOF, sigma = {sigma:.4g}"
                f"{', out-of-core' if lowmem else ''} ...")
            res = run_program(prog, size, mesh, sigma, opts, args, runs_dir, timeout, ooc_dir)
            entry["results"][prog] = res
            if "error" in res:
                log(f"[{size}] {prog}: {res['error']}" + (f" (log: {res['log']})" if "log" in res else ""))
            else:
                its = res.get("its", res.get("iterations"))
                log(f"[{size}] {prog}: assembly {res['assembly_s']:.2f} s, solve {res['solve_s']:.2f} s, "
                    f"peak {res['peak_rss_mb']:.0f} MB" + (f", {its} iterations" if its is not None else ""))
            # write as we go, so a long run leaves partial results behind
            out_path.write_text(json.dumps(report, indent=1))
        a, b = entry["results"].get("diffsound", {}), entry["results"].get("dolfinx", {})
        if "error" not in a and "error" not in b and a and b:
            entry["ratios"] = {k: a[k] / b[k] for k in ("assembly_s", "solve_s", "total_s", "wall_s", "peak_rss_mb")
                               if isinstance(a.get(k), (int, float)) and b.get(k)}
            entry["max_rel_eig_diff"] = max_rel_diff(a.get("eigenvalues", []), b.get("eigenvalues", []))
            entry["n_compared"] = min(len(a.get("eigenvalues", [])), len(b.get("eigenvalues", [])))
            if a.get("ndof") != b.get("ndof"):
                entry["ndof_mismatch"] = [a.get("ndof"), b.get("ndof")]
    report["wall_s"] = time.perf_counter() - t_all
    out_path.write_text(json.dumps(report, indent=1))
    print_table(report)
    log(f"report: {out_path}  (benchmark wall time {report['wall_s'] / 60:.1f} min)")


if __name__ == "__main__":
    main()
