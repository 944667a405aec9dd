# Sourced by the scripts: environment for running MPI jobs here.
# - mpirun refuses to run as root unless told it is intended (containers, CI).
# - One BLAS thread per rank: MPI ranks already use every core, and OpenBLAS threads would fight them.
if [ "$(id -u)" = 0 ]; then
  export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
fi
export OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}"
# Quiet OpenMPI's complaints about missing high-speed interconnects on a plain machine.
export OMPI_MCA_btl="${OMPI_MCA_btl:-self,vader}"
