#!/usr/bin/env bash
# Installs what diffsound needs on a fresh Debian 12 machine, and nothing twice.
# Idempotent: when every package is already present it returns in well under a second.
set -euo pipefail

APT_PACKAGES=(
  petsc-dev slepc-dev            # PETSc 3.18 / SLEPc 3.18 with MUMPS, OpenMPI, HDF5 (openmpi flavour)
  libclang-dev pkg-config        # bindgen in build.rs
  libhdf5-openmpi-dev            # HDF5 output through hdf5-metno
  openmpi-bin libopenmpi-dev     # mpirun
  libopenblas0                   # fast BLAS for MUMPS (switches the Debian alternatives)
  gmsh                           # meshing of test solids and refinement for benchmarks
  python3-h5py python3-meshio    # the tests read every output as a Python user would (README)
  python3-numpy
)

missing=()
for p in "${APT_PACKAGES[@]}"; do
  [[ "$p" == \#* ]] && continue
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if ((${#missing[@]})); then
  echo "[install-deps] installing: ${missing[*]}"
  SUDO=""
  if [ "$(id -u)" != 0 ]; then SUDO="sudo"; fi
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
else
  echo "[install-deps] system packages present"
fi

if ! command -v cargo >/dev/null 2>&1; then
  echo "[install-deps] error: cargo not found; install a Rust toolchain (rustup) first" >&2
  exit 1
fi
