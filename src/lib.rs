//! diffsound: physics-based modal sound.
//!
//! The crate is laid out as the pipeline it implements:
//!
//! | stage      | module       | what it does |
//! |------------|--------------|--------------|
//! | mesh       | [`mesh`]     | reads Gmsh tet meshes, validates, lifts P1 to P2, straightens, locates, writes, generates |
//! | fem        | [`fem`]      | pure, serial element kernels: mass, Lamé-split stiffness, materials |
//! | assembly   | [`assembly`] | node partition, exact preallocation, distributed PETSc matrices |
//! | eigen      | [`eigen`]    | SLEPc shift-invert Krylov–Schur on MUMPS (direct) or generalised Davidson with a P2 → P1 or algebraic multigrid (iterative, no factor), rigid-mode removal, spectrum slicing |
//! | shape      | [`shape`]    | differentiable shapes: surfaces, signed distances, marching tetrahedra, the spectrum of the body inside a field and its gradient |
//! | audio      | [`audio`]    | damped-sinusoid synthesis and WAV I/O |
//! | analysis   | [`analysis`] | recording analysis: onset, trim and gain, modal estimates and extraction with uncertainties, glides |
//! | inverse    | [`inverse`]  | damping and material fits from recordings; shape fits (thickness, morph, geometry) from eigenvalues |
//! | diagnose   | [`diagnose`] | simulation–recording mismatch: modal parameters with uncertainties |
//! | workflow   | [`workflow`] | the jobs: each command as a `Job` in and a `Report` out, progress as a callback |
//! | io         | [`io`]       | HDF5 results with an XDMF sidecar, written atomically; the TOML configuration files |
//!
//! [`petsc`] is the one thin unsafe boundary: raw bindgen bindings under safe RAII handles.
//! [`numerics`] holds the small numerical tools the stages share (3-vectors, median, golden section, Levenberg–Marquardt).
//! [`cli`] is the `diffsound` command line (arguments merged with the configuration files, printing); [`random`] the seeded generator every stage shares.

// Comparisons are written `!(x > 0.0)` on purpose throughout: a NaN fails every ordered
// comparison, so the negated form refuses NaN where `x <= 0.0` would let it through. Clippy's
// suggestion (`partial_cmp` matches) says the same thing at three times the length.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod analysis;
pub mod assembly;
pub mod audio;
pub mod cli;
pub mod diagnose;
pub mod eigen;
pub mod fem;
pub mod inverse;
pub mod io;
pub mod mesh;
pub mod numerics;
pub mod petsc;
pub mod random;
pub mod shape;
#[cfg(test)]
mod testing;
pub mod workflow;
