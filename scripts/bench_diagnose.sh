#!/usr/bin/env bash
# Blind benchmark of the mismatch diagnosis (issue 6, section 5): generate cases with concealed
# effects (examples/diagnose_generate.rs), diagnose every case with `diffsound diagnose` (which
# sees only the audio, the mesh and the metadata), then unseal the labels and score
# (examples/diagnose_score.rs).
#
#   scripts/bench_diagnose.sh [--cases 30] [--seed 101] [--mics 6] [--mesh examples/bowl/bowl.msh]
#                             [--np 2] [--out out/bench_diagnose] [--skip-generate] [--bin PATH]
#
# --bin diagnoses with a given (frozen) diffsound binary instead of this tree's build, so a blind
# run is not disturbed by development in the same tree (the generator and the scorer are still
# built from this tree).
# The generator and the diagnosis run under mpirun with --np ranks. Existing diagnosis.json files
# are kept (delete them to re-run a case); each case's log is case_XXX/diagnosis.log.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/mpi-env.sh
cases=30; seed=101; mics=6; mesh=examples/bowl/bowl.msh; np=2; out=out/bench_diagnose; generate=1; bin=""
while [ $# -gt 0 ]; do
  case "$1" in
    --cases) cases="$2"; shift 2 ;;
    --seed) seed="$2"; shift 2 ;;
    --mics) mics="$2"; shift 2 ;;
    --mesh) mesh="$2"; shift 2 ;;
    --np) np="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    --skip-generate) generate=0; shift ;;
    --bin) bin="$2"; shift 2 ;;
    *) echo "unknown option $1" >&2; exit 2 ;;
  esac
done
if [ -z "$bin" ]; then
  cargo build --release --features bench-generators --bin diffsound --example diagnose_generate --example diagnose_score 2>&1 | tail -n 1
  bin=target/release/diffsound
else
  cargo build --release --features bench-generators --example diagnose_generate --example diagnose_score 2>&1 | tail -n 1
fi
mkdir -p "$out"
if [ "$generate" = 1 ]; then
  mpirun -np "$np" target/release/examples/diagnose_generate --out "$out" --cases "$cases" --seed "$seed" --mics "$mics" --mesh "$mesh" 2> "$out/generate.log"
  tail -n 1 "$out/generate.log" >&2
fi
start=$(date +%s)
for meta in "$out"/case_*/metadata.toml; do
  dir=$(dirname "$meta")
  if [ -f "$dir/diagnosis.json" ]; then continue; fi
  t0=$(date +%s)
  if mpirun -np "$np" "$bin" diagnose --case "$meta" --out "$dir/diagnosis.h5" -v > "$dir/diagnosis.log" 2>&1; then
    echo "$(basename "$dir"): $(grep -c ACCEPTED "$dir/diagnosis.log") effect(s) accepted, $(( $(date +%s) - t0 )) s" >&2
  else
    echo "$(basename "$dir"): diagnosis FAILED (see $dir/diagnosis.log)" >&2
  fi
done
echo "diagnosis of all cases: $(( $(date +%s) - start )) s" >&2
target/release/examples/diagnose_score --cases "$out" --out "$out/score.json" | tee "$out/score.md"
