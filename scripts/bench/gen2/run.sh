#!/usr/bin/env bash
# Generator 2's benchmark of the mismatch diagnosis: make the cases (generate.py), diagnose each
# as a user would (`diffsound diagnose --mesh M --recording ... --density RHO --strike-vertex N`,
# the material left to the tool unless the case is a uniform-shift control), then unseal the
# labels and score (score.py).
#
#   bash scripts/bench/gen2/run.sh [--cases 24] [--seed 7] [--np 2] [--out out/gen2] [--bin PATH]
#                                  [--effect NAME|clean] [--object plate|tube|cup|bar]
#
# --bin runs a given (frozen) diffsound binary instead of building target/release/diffsound, so a
# blind run is not disturbed by development in the same tree. --effect and --object make a
# focused calibration set (every case with that effect, or clean, on that object); a blind run
# leaves them unset.
set -euo pipefail
cd "$(dirname "$0")/../../.."
source scripts/mpi-env.sh
cases=24; seed=7; np=2; out=out/gen2; bin=""; focus=()
while [ $# -gt 0 ]; do
  case "$1" in
    --cases) cases="$2"; shift 2 ;;
    --seed) seed="$2"; shift 2 ;;
    --np) np="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    --bin) bin="$2"; shift 2 ;;
    --effect|--object) focus+=("$1" "$2"); shift 2 ;;
    *) echo "unknown option $1" >&2; exit 2 ;;
  esac
done
# Debian's Python and its NumPy and h5py (a pyenv or venv python3 earlier on PATH may lack them).
PY=/usr/bin/python3
"$PY" -c "import numpy, h5py" 2>/dev/null || apt-get install -y python3-numpy python3-h5py
# The added-mass cases are solved in full by examples/mass_probe (the generator's side, built
# from this tree even when --bin names a frozen diffsound).
cargo build --release --example mass_probe 2>&1 | tail -n 1
if [ -z "$bin" ]; then
  cargo build --release --bin diffsound 2>&1 | tail -n 1
  bin=target/release/diffsound
fi
mkdir -p "$out"
[ -d "$out/labels" ] && [ "$(ls "$out"/labels | wc -l)" -ge "$cases" ] || "$PY" scripts/bench/gen2/generate.py --out "$out" --cases "$cases" --seed "$seed" --np "$np" --bin "$bin" "${focus[@]}"
for dir in "$out"/case_*; do
  [ -f "$dir/diagnosis.json" ] && continue
  mapfile -t args < <("$PY" -c "import json,sys; print('\n'.join(json.load(open(sys.argv[1]))))" "$dir/args.json")
  t0=$(date +%s)
  if mpirun -np "$np" "$bin" diagnose "${args[@]}" --out "$dir/diagnosis.h5" -v > "$dir/diagnosis.log" 2>&1; then
    echo $(( $(date +%s) - t0 )) > "$dir/seconds"
    echo "$(basename "$dir"): $(grep -c ACCEPTED "$dir/diagnosis.log" || true) accepted, $(cat "$dir/seconds") s" >&2
  else
    echo "$(basename "$dir"): diagnosis FAILED (see $dir/diagnosis.log)" >&2
  fi
done
"$PY" scripts/bench/gen2/score.py "$out" | tee "$out/score.md"
