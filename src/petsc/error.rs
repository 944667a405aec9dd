//! PETSc error codes as `Result`s that carry PETSc's own message.
//!
//! PETSc reports an error by calling the top handler on its error-handler stack once for the
//! place the error arose (`PETSC_ERROR_INITIAL`, with the message) and once per stack frame on the
//! way out (`PETSC_ERROR_REPEAT`). We push a handler that records those lines instead of printing
//! them, and [`check`] turns a non-zero code into a [`PetscError`] with the recorded text.

use super::sys;
use std::ffi::CStr;
use std::os::raw::{c_char, c_int, c_void};
use std::sync::Mutex;

/// Messages recorded by [`record_error`] since the last [`check`] that found an error.
static RECORDED: Mutex<Vec<String>> = Mutex::new(Vec::new());

#[derive(Debug, Clone)]
pub struct PetscError {
    /// PETSc error code (0 for errors raised on our side of the boundary).
    pub code: i32,
    /// The PETSc/SLEPc function we called.
    pub call: String,
    /// PETSc's message and the trace of functions it passed through.
    pub message: String,
}

impl PetscError {
    pub fn other(message: impl Into<String>) -> Self {
        PetscError {
            code: 0,
            call: String::new(),
            message: message.into(),
        }
    }
}

impl std::fmt::Display for PetscError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.call.is_empty() {
            write!(f, "{}", self.message)
        } else {
            write!(
                f,
                "{} failed (PETSc error {}): {}",
                self.call, self.code, self.message
            )
        }
    }
}

impl std::error::Error for PetscError {}

pub type Result<T> = std::result::Result<T, PetscError>;

/// Turns a PETSc error code into a `Result`, attaching the messages PETSc reported.
pub(crate) fn check(code: sys::PetscErrorCode, call: &str) -> Result<()> {
    if code == 0 {
        return Ok(());
    }
    let lines = std::mem::take(&mut *RECORDED.lock().unwrap_or_else(|p| p.into_inner()));
    let mut message = if lines.is_empty() {
        generic_text(code)
    } else {
        lines.join("; ")
    };
    if message.is_empty() {
        message = "unknown error".into();
    }
    Err(PetscError {
        code,
        call: call.to_string(),
        message,
    })
}

/// Drops the messages of a failure that the caller tolerates (a query answered "none"), so they
/// are not attached to the next real error.
pub(crate) fn discard_recorded() {
    RECORDED.lock().unwrap_or_else(|p| p.into_inner()).clear();
}

/// PETSc's fixed text for an error code, used when no handler message was recorded.
fn generic_text(code: sys::PetscErrorCode) -> String {
    let mut text: *const c_char = std::ptr::null();
    // SAFETY: PetscErrorMessage only writes a pointer to a static string.
    unsafe {
        sys::PetscErrorMessage(code as c_int, &mut text, std::ptr::null_mut());
        super::from_cstr(text)
    }
}

/// The handler pushed at start-up; PETSc calls it instead of printing.
pub(crate) unsafe extern "C" fn record_error(
    _comm: mpi::ffi::MPI_Comm,
    line: c_int,
    func: *const c_char,
    file: *const c_char,
    code: sys::PetscErrorCode,
    kind: sys::PetscErrorType,
    message: *const c_char,
    _ctx: *mut c_void,
) -> sys::PetscErrorCode {
    let text = |p: *const c_char| {
        if p.is_null() {
            String::new()
        } else {
            CStr::from_ptr(p).to_string_lossy().trim().to_string()
        }
    };
    let func = text(func);
    let file = text(file);
    let entry = if kind == sys::PetscErrorType_PETSC_ERROR_INITIAL {
        let msg = text(message);
        let msg = if msg.is_empty() {
            generic_text(code)
        } else {
            msg
        };
        format!("{msg} [in {func}() at {file}:{line}]")
    } else {
        format!("from {func}()")
    };
    let mut rec = RECORDED.lock().unwrap_or_else(|p| p.into_inner());
    // Bounded so that a loop of failing calls cannot grow it without limit.
    if rec.len() < 32 {
        rec.push(entry);
    }
    code
}
