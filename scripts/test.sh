#!/usr/bin/env bash
# The test command: installs what is missing, then runs the whole suite (unit tests, element and
# finite-difference checks, analytic convergence, 1-rank vs 2-rank equality, end-to-end CLI runs).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
source scripts/mpi-env.sh
# Every HDF5 file we write goes to a temporary name and is renamed into place, so HDF5's own
# flock()-based file locking adds nothing; with many test threads writing and reopening files it
# once failed an open with EAGAIN ("unable to lock file", io::tests, cause not yet found).
export HDF5_USE_FILE_LOCKING=FALSE
# The house style is enforced: unformatted code fails the suite before anything is built.
cargo fmt --check
# bench-generators: the benchmark generator (src/diagnose/inject.rs) and the tests that use it.
cargo test --release --locked --features bench-generators "$@"
