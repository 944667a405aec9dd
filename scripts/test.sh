#!/usr/bin/env bash
# The test command: installs what is missing, then runs the whole suite (unit tests, element and
# finite-difference checks, analytic convergence, 1-rank vs 2-rank equality, end-to-end CLI runs).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
source scripts/mpi-env.sh
cargo test --release --locked "$@"
