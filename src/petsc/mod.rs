//! The one unsafe boundary: raw PETSc/SLEPc bindings ([`sys`]) under safe RAII handles.
//!
//! Everything above this module uses [`Petsc`] (the runtime guard), [`Mat`], [`Vector`],
//! [`Eps`], [`MumpsCholesky`] (the one factorisation path, module [`factor`]) and the borrowed
//! [`St`]/[`Pc`] views. Every PETSc error code becomes a
//! [`PetscError`] that carries PETSc's own message (captured by an error handler that we push at
//! start-up) and the name of the call that failed.
//!
//! Handles borrow the runtime (`'p`), so none can outlive `SlepcFinalize`. The runtime owns the
//! MPI universe and finalises PETSc/SLEPc before MPI (stack note 7).

pub mod collective;
mod dense;
mod eps;
mod error;
pub mod factor;
mod mat;
pub mod multigrid;
mod runtime;
pub mod sys;
mod vector;
pub mod watchdog;

pub use dense::Dense;
pub use eps::{Eps, EpsWhich, Pc, St};
pub use error::{PetscError, Result};
pub use factor::{FactorError, FactorLog, FactorUse, Inertia, MumpsCholesky};
pub use mat::{Mat, NonzeroPattern};
pub use runtime::{pin_blas_threads, Petsc};
pub use vector::Vector;

/// PETSc's index type (32-bit in Debian's build).
pub type PetscInt = sys::PetscInt;

/// Converts a Rust string into the NUL-terminated form PETSc expects.
pub(crate) fn cstring(s: &str) -> std::ffi::CString {
    std::ffi::CString::new(s.replace('\0', "")).expect("NUL bytes were removed")
}

/// Reads a C string owned by PETSc (a type name, say) into an owned `String`.
pub(crate) unsafe fn from_cstr(p: *const std::os::raw::c_char) -> String {
    if p.is_null() {
        String::new()
    } else {
        std::ffi::CStr::from_ptr(p).to_string_lossy().into_owned()
    }
}

/// Converts a usize count or index to `PetscInt`, failing loudly instead of wrapping: Debian's
/// PETSc uses 32-bit indices, so a system with more than 2³¹ DOFs cannot be represented.
pub fn to_petsc_int(n: usize) -> Result<PetscInt> {
    PetscInt::try_from(n)
        .map_err(|_| PetscError::other(format!("index {n} does not fit PETSc's 32-bit PetscInt")))
}
