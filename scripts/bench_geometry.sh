#!/usr/bin/env bash
# Geometry-from-voxels benchmark (issue 7, task 3): bob, oloid and spot, each voxelised at 16³
# and at a coarser resolution (8³), an MLP signed distance pre-fitted to the voxels and refined
# by the first N eigenvalues of the true shape (target on a finer, randomly shifted grid; the
# seed), by examples/geometry_benchmark, on each number of MPI ranks asked for. Writes to OUT_DIR
# one markdown table per rank count (shape distances and frequency errors before/after, time per
# step split into meshing / assembly / solve / gradient / network, totals), its log, the JSON
# of every run with its history (results_np*.json), one PNG per case (voxels / before / after /
# true) and README.md listing what ran.
#
#   scripts/bench_geometry.sh [--ranks "2 1"] [--seed 1]
#
# Environment: OUT_DIR (default out/bench_geometry), SHARED (shared data directory, default
# /work/shared if present, else ../shared), SHAPES (surfaces), VOXELS (16,8), CELLS (fit grid,
# 16), TARGET_CELLS (28), MODES (12), STEPS (20), EXTRA (more flags for the benchmark, e.g.
# "--method adam --no-bias-correction" for the first version). Runs at nice 5 (the machine is shared).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/mpi-env.sh
ranks="2 1"
seed=1
while [ $# -gt 0 ]; do
  case "$1" in
    --ranks) ranks="$2"; shift 2 ;;
    --seed) seed="$2"; shift 2 ;;
    *) echo "usage: $0 [--ranks \"2 1\"] [--seed S]" >&2; exit 2 ;;
  esac
done
shared="${SHARED:-}"
if [ -z "$shared" ]; then
  if [ -d /work/shared/data/meshes ]; then shared=/work/shared; else shared=../shared; fi
fi
m="$shared/data/meshes"
read -r -a shapes <<< "${SHAPES:-$m/bob_surf.obj $m/oloid_surf.obj $m/spot_surf.obj}"
read -r -a extra <<< "${EXTRA:-}"
OUT_DIR="${OUT_DIR:-out/bench_geometry}"
mkdir -p "$OUT_DIR"
CARGO_BUILD_JOBS="${CARGO_BUILD_JOBS:-1}" cargo build --release --example geometry_benchmark 2>&1 | tail -n 1
bench=target/release/examples/geometry_benchmark
{
  echo "# Geometry benchmark runs"
  echo
  echo "seed $seed, ranks: $ranks, voxels ${VOXELS:-16,8}, fit grid ${CELLS:-16} cells, target ${TARGET_CELLS:-28} cells, ${MODES:-12} modes, ${STEPS:-20} steps, extra flags: ${EXTRA:-none}"
  echo "started $(date -u +%Y-%m-%dT%H:%MZ) on $(nproc) cores (load average $(cut -d' ' -f1-3 /proc/loadavg))"
  echo
} > "$OUT_DIR/README.md"
for np in $ranks; do
  name="geometry_np$np"
  nice -n 5 mpirun -np "$np" "$bench" --voxels "${VOXELS:-16,8}" --cells "${CELLS:-16}" --target-cells "${TARGET_CELLS:-28}" \
    --modes "${MODES:-12}" --steps "${STEPS:-20}" --seed "$seed" --out-dir "$OUT_DIR" -v "${extra[@]}" "${shapes[@]}" \
    2> "$OUT_DIR/$name.log" | tee "$OUT_DIR/$name.md"
  echo "- $name: ${shapes[*]} → $name.md, $name.log, results_np$np.json, *_vox*.png (finished $(date -u +%H:%MZ), load average $(cut -d' ' -f1-3 /proc/loadavg))" >> "$OUT_DIR/README.md"
done
echo "wrote $OUT_DIR" >&2
