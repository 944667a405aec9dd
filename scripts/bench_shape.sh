#!/usr/bin/env bash
# Shape-from-sound benchmark (issue 7): task 1 (thickness of a hollow body, t* in
# {0.3, …, 0.7}) on four shapes and task 2 (morph weight, c* in {0, 0.2, …, 1}) on two pairs,
# each target rendered on a finer, randomly shifted grid (the seed) and fitted back by
# examples/shape_benchmark, on each number of MPI ranks asked for. Writes one markdown table and
# one JSON file (every fit with its history) per task and rank count to OUT_DIR,
# OUT_DIR/README.md listing what ran, and OUT_DIR/summary.md (scripts/bench_shape_summary.py:
# errors per shape, time per evaluation split by stage at each grid level, totals).
#
#   scripts/bench_shape.sh [--ranks "2 1"] [--seed 1] [--task thickness|morph|both]
#
# Environment: OUT_DIR (default out/bench_shape), SHARED (shared data directory, default
# /work/shared if present, else ../shared), THICKNESS_SHAPES / MORPH_PAIRS to override the
# inputs, THICKNESS_LEVELS (20,28,36) / THICKNESS_TARGET (40), MORPH_LEVELS (16,20,24,28) /
# MORPH_TARGET (32), REPLICAS (grids per replicated level, default 1: the finest level when the
# answer is the finest level's, as for the curved thickness body, else every level after the
# first), THICKNESS_MODES / MORPH_MODES (compared modes, default 8). Runs at nice 5 (the machine is shared).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/mpi-env.sh
ranks="2 1"
seed=1
task=both
while [ $# -gt 0 ]; do
  case "$1" in
    --ranks) ranks="$2"; shift 2 ;;
    --seed) seed="$2"; shift 2 ;;
    --task) task="$2"; shift 2 ;;
    *) echo "usage: $0 [--ranks \"2 1\"] [--seed S] [--task thickness|morph|both]" >&2; exit 2 ;;
  esac
done
shared="${SHARED:-}"
if [ -z "$shared" ]; then
  if [ -d /work/shared/data/meshes ]; then shared=/work/shared; else shared=../shared; fi
fi
m="$shared/data/meshes"
read -r -a thickness_shapes <<< "${THICKNESS_SHAPES:-$m/spot_surf.obj $m/bob_surf.obj $m/oloid_surf.obj $m/turtle.obj}"
read -r -a morph_pairs <<< "${MORPH_PAIRS:-$m/frog.obj:$m/turtle.obj $m/spot_surf.obj:$m/bob_surf.obj}"
OUT_DIR="${OUT_DIR:-out/bench_shape}"
mkdir -p "$OUT_DIR"
CARGO_BUILD_JOBS="${CARGO_BUILD_JOBS:-1}" cargo build --release --example shape_benchmark 2>&1 | tail -n 1
bench=target/release/examples/shape_benchmark
{
  echo "# Shape benchmark runs"
  echo
  echo "seed $seed, ranks: $ranks, started $(date -u +%Y-%m-%dT%H:%MZ) on $(nproc) cores (load average $(cut -d' ' -f1-3 /proc/loadavg))"
} > "$OUT_DIR/README.md"
for np in $ranks; do
  if [ "$task" = thickness ] || [ "$task" = both ]; then
    name="thickness_np$np"
    nice -n 5 mpirun -np "$np" "$bench" thickness --levels "${THICKNESS_LEVELS:-20,28,36}" --target-cells "${THICKNESS_TARGET:-40}" --replicas "${REPLICAS:-1}" \
      --modes "${THICKNESS_MODES:-8}" --seed "$seed" --json "$OUT_DIR/$name.json" "${thickness_shapes[@]}" 2> "$OUT_DIR/$name.log" | tee "$OUT_DIR/$name.md"
    echo "- $name: ${thickness_shapes[*]} → $name.md, $name.json, $name.log (finished $(date -u +%H:%MZ))" >> "$OUT_DIR/README.md"
  fi
  if [ "$task" = morph ] || [ "$task" = both ]; then
    name="morph_np$np"
    nice -n 5 mpirun -np "$np" "$bench" morph --levels "${MORPH_LEVELS:-16,20,24,28}" --target-cells "${MORPH_TARGET:-32}" --replicas "${REPLICAS:-1}" \
      --modes "${MORPH_MODES:-8}" --seed "$seed" --json "$OUT_DIR/$name.json" "${morph_pairs[@]}" 2> "$OUT_DIR/$name.log" | tee "$OUT_DIR/$name.md"
    echo "- $name: ${morph_pairs[*]} → $name.md, $name.json, $name.log (finished $(date -u +%H:%MZ))" >> "$OUT_DIR/README.md"
  fi
done
python3 scripts/bench_shape_summary.py "$OUT_DIR"/*_np*.json > "$OUT_DIR/summary.md" && cat "$OUT_DIR/summary.md"
echo "wrote $OUT_DIR" >&2
