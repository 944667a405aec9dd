#!/usr/bin/env bash
# Synthetic benchmark of the material fit (issue 5): builds examples/material_benchmark and runs
# it single-process on the given meshes (default: the bowl, spot, bob, oloid and the two solids
# of examples/solids), writing the markdown tables and a JSON file with every fit and its loss
# history.
#
#   scripts/bench_material.sh [--seeds 1,2,3] [--variants p2-learned,...] [--max-steps N] [MESH...]
#
# Environment: OUT (markdown, default out/bench_material.md), JSON (default next to OUT with
# .json), SHARED (shared data directory, default /work/shared if present, else ../shared).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/mpi-env.sh
opts=()
meshes=()
while [ $# -gt 0 ]; do
  case "$1" in
    --seeds|--variants|--max-steps|--modes) opts+=("$1" "$2"); shift 2 ;;
    *) meshes+=("$1"); shift ;;
  esac
done
if [ ${#meshes[@]} -eq 0 ]; then
  shared="${SHARED:-}"
  if [ -z "$shared" ]; then
    if [ -d /work/shared/data/meshes ]; then shared=/work/shared; else shared=../shared; fi
  fi
  meshes=(examples/bowl/bowl.msh "$shared"/data/meshes/{spot,bob,oloid}.msh examples/solids/{plate,mug}.msh)
fi
OUT="${OUT:-out/bench_material.md}"
JSON="${JSON:-${OUT%.md}.json}"
mkdir -p "$(dirname "$OUT")" "$(dirname "$JSON")"
cargo build --release --examples 2>&1 | tail -n 1
# One rank: the benchmark times a single process (the machine's other core stays free).
./target/release/examples/material_benchmark "${opts[@]}" --json "$JSON" "${meshes[@]}" | tee "$OUT"
echo "wrote $OUT and $JSON" >&2
