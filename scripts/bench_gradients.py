#!/usr/bin/env python3
"""Cost of the full node-position gradient of the first N modes, relative to one assembly and
one eigen-solve (issue 3's benchmark).

Runs `diffsound modes --modes N --node-gradients --no-verify` on each mesh (2 ranks by default)
and prints, per mesh: DOF, assembly s, solve s, node-gradient s, material-sensitivity s, and the
ratios gradient/assembly and gradient/solve. Measures only; asserts nothing.

    python3 scripts/bench_gradients.py                      # the bundled bowl
    python3 scripts/bench_gradients.py --mesh out/bench/thick_bowl_h1.3mm.msh --ooc   # ~1.1M DOF
"""
import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mesh", action="append", help="mesh file (repeatable); default: the bundled bowl")
    ap.add_argument("--modes", type=int, default=50)
    ap.add_argument("--np", type=int, default=2)
    ap.add_argument("--ooc", action="store_true", help="MUMPS out-of-core (needed above ~600k DOF on 24 GB)")
    ap.add_argument("--out", default=str(ROOT / "out/bench/gradients"))
    args = ap.parse_args()
    meshes = args.mesh or [str(ROOT / "examples/bowl/bowl.msh")]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    binary = ROOT / "target/release/diffsound"
    if not binary.exists():
        sys.exit("build first: cargo build --release")
    rows = []
    for mesh in meshes:
        stem = Path(mesh).stem
        timings = out / f"{stem}.json"
        cmd = ["mpirun", "-np", str(args.np), str(binary), "modes", "--mesh", mesh, "--modes", str(args.modes),
               "--node-gradients", "--no-verify", "--out", str(out / f"{stem}.h5"), "--timings-json", str(timings)]
        if args.ooc:
            ooc = out / "mumps_ooc"
            ooc.mkdir(exist_ok=True)
            env["MUMPS_OOC_TMPDIR"] = str(ooc)
            cmd[1:1] = ["-x", "MUMPS_OOC_TMPDIR"]
            cmd += ["--", "-st_mat_mumps_icntl_22", "1"]
        print("running:", " ".join(cmd), flush=True)
        subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL)
        t = json.loads(timings.read_text())
        rows.append((stem, t["ndof"], t["assembly_s"], t["solve_s"], t["node_gradients_s"], t["material_sensitivities_s"]))
    print(f"\n{'mesh':<22}{'DOF':>11}{'assembly s':>12}{'solve s':>10}{'grad s':>9}{'material s':>12}{'grad/asm':>10}{'grad/solve':>12}")
    for stem, ndof, asm, solve, grad, mat in rows:
        print(f"{stem:<22}{ndof:>11,}{asm:>12.2f}{solve:>10.2f}{grad:>9.2f}{mat:>12.2f}{grad / asm:>10.2f}{grad / solve:>12.3f}")


if __name__ == "__main__":
    main()
