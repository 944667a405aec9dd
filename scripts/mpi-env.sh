# Sourced by the scripts: environment for running MPI jobs here.
# - mpirun refuses to run as root unless told it is intended (containers, CI).
# - One BLAS thread per rank: MPI ranks already use every core, and OpenBLAS threads would fight them.
if [ "$(id -u)" = 0 ]; then
  export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
fi
export OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}"
# - OpenBLAS's kernels named from the CPU's flags. OpenBLAS picks them from the CPU's model
#   number, and on a virtual CPU it does not know (this machine's "Intel(R) Xeon(R) Processor",
#   with AVX-512) it falls back to its generic Prescott kernels: one rank's dgemm of order 1000
#   ran at 9.4 GFLOP/s with them, 46 with SkylakeX's, 32 with Haswell's. MUMPS's solves and
#   PETSc's dense products go through it (a tube's loaded match: 8 factorisations in 5.7–6.2 s
#   instead of 8.5–9.0). A value already set is kept.
if [ -z "${OPENBLAS_CORETYPE:-}" ] && [ -r /proc/cpuinfo ]; then
  _ds_flags=" $(grep -m1 '^flags' /proc/cpuinfo | cut -d: -f2) "
  _ds_has() { case "$_ds_flags" in *" $1 "*) return 0 ;; *) return 1 ;; esac; }
  if _ds_has avx512f && _ds_has avx512dq && _ds_has avx512bw && _ds_has avx512vl; then
    export OPENBLAS_CORETYPE=SkylakeX
  elif _ds_has avx2 && _ds_has fma; then
    export OPENBLAS_CORETYPE=Haswell
  fi
  unset -f _ds_has
  unset _ds_flags
fi
# - No binding of each rank to one core: Open MPI binds 2 ranks to a core each by default, and
#   a rank's threads (the glide stage's hypotheses, the catalogue's pole readings) then share
#   that core while the other rank sleeps (`collective::quiet_barrier`). Unbound, a plate in a
#   room (generator 2, seed 439 case 006) took 131 s instead of 143 (fit microphones' extraction
#   74 s instead of 84–89). A value already set is kept.
export OMPI_MCA_hwloc_base_binding_policy="${OMPI_MCA_hwloc_base_binding_policy:-none}"
# Quiet OpenMPI's complaints about missing high-speed interconnects on a plain machine.
export OMPI_MCA_btl="${OMPI_MCA_btl:-self,vader}"
