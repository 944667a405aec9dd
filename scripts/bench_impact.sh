#!/usr/bin/env bash
# Synthetic benchmark of impact localisation (issue 8): random strikes on the bowl, plate and mug,
# rendered through the acoustic transfer with noise, located with and without the microphone
# positions (examples/impact_benchmark.rs, module docs). Writes out/bench_impact/seed<S>.md.
#
#   scripts/bench_impact.sh [--seed 1] [--strikes 20] [--snr-db 40] [--mics 4] [--np 2] [MESH...]
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/mpi-env.sh
seed=1; strikes=20; snr=40; mics=4; np=2; meshes=()
while [ $# -gt 0 ]; do
  case "$1" in
    --seed) seed="$2"; shift 2 ;;
    --strikes) strikes="$2"; shift 2 ;;
    --snr-db) snr="$2"; shift 2 ;;
    --mics) mics="$2"; shift 2 ;;
    --np) np="$2"; shift 2 ;;
    -*) echo "unknown option $1" >&2; exit 2 ;;
    *) meshes+=("$1"); shift ;;
  esac
done
cargo build --release --features bench-generators --example impact_benchmark 2>&1 | tail -n 1
mkdir -p out/bench_impact
out="out/bench_impact/seed${seed}.md"
mpirun -np "$np" target/release/examples/impact_benchmark --seed "$seed" --strikes "$strikes" --snr-db "$snr" --mics "$mics" "${meshes[@]}" > "$out.tmp"
mv "$out.tmp" "$out"
cat "$out"
