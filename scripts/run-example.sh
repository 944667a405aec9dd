#!/usr/bin/env bash
# The main job on the bundled example: installs what is missing, builds, computes the bowl's
# modes on 2 MPI ranks (HDF5 + XDMF + a rendered strike in out/), then fits the bowl's damping
# and material to its eight recordings (out/bowl_fit.h5 and plots; about 3–4 minutes) and
# diagnoses what the model still misses (out/bowl_diagnosis.*; about 1 minute) and maps where
# the bowl was struck (out/bowl_impact.*; about 1 minute).
# FIT=0 skips the fit. Extra arguments go to the modes job.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
cargo build --release --locked 2>&1 | tail -n 2
mkdir -p out
source scripts/mpi-env.sh
mpirun -np "${NP:-2}" target/release/diffsound modes --config examples/bowl/bowl.toml --verbose "$@"
echo "results: out/bowl_modes.h5 (open out/bowl_modes.xdmf in ParaView), out/bowl_strike.wav"
if [ "${FIT:-1}" != 0 ]; then
  mpirun -np "${NP:-2}" target/release/diffsound fit-material --config examples/bowl/fit.toml --verbose
  echo "results: out/bowl_fit.h5, out/bowl_fit_{spectrogram,damping,loss,frequencies}.png"
  mpirun -np "${NP:-2}" target/release/diffsound diagnose --config examples/bowl/diagnose.toml --verbose
  echo "results: out/bowl_diagnosis.{h5,json}, out/bowl_diagnosis_map.xdmf (ParaView), out/bowl_diagnosis_{residuals,timefreq,envelopes}.png"
  mpirun -np "${NP:-2}" target/release/diffsound locate-impact --config examples/bowl/impact.toml --verbose
  echo "results: out/bowl_impact.{h5,json}, out/bowl_impact_map.xdmf (ParaView), out/bowl_impact_map.png"
fi
