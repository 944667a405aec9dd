//! The PETSc/SLEPc runtime guard.
//!
//! Order matters (stack note 7): MPI is initialised by rsmpi first, `PETSC_COMM_WORLD` is set to
//! its world communicator, then `SlepcInitialize` runs; on drop `SlepcFinalize` runs before the
//! MPI universe is dropped (which finalises MPI). PETSc does not finalise an MPI it did not start.

use super::error::{check, record_error, Result};
use super::{cstring, sys};
use mpi::environment::Universe;
use mpi::raw::AsRaw;
use mpi::topology::{Communicator, SimpleCommunicator};
use std::ffi::CString;
use std::os::raw::c_char;

pub struct Petsc {
    // Field order is drop order: the argv PETSc saw must outlive SlepcFinalize, and the
    // universe (MPI_Finalize) goes last.
    _argv_storage: Vec<CString>,
    _argv_ptrs: Vec<*mut c_char>,
    world: SimpleCommunicator,
    universe: Universe,
    /// Options this code set itself (defaults, shared MUMPS spellings, scoped overrides): left
    /// out of the warning about options nobody used.
    ours: std::sync::Mutex<std::collections::BTreeSet<String>>,
}

impl Petsc {
    /// Initialises SLEPc (and PETSc) on the universe's world communicator.
    ///
    /// `petsc_args` are PETSc/SLEPc options (`-eps_nev 30`, `-st_type sinvert`, …). They are
    /// read after `.petscrc` and `PETSC_OPTIONS`, so the command line wins; solver objects call
    /// `XSetFromOptions` after our code defaults, so these options override the defaults.
    pub fn initialize(universe: Universe, program: &str, petsc_args: &[String]) -> Result<Petsc> {
        let world = universe.world();
        let mut argv_storage: Vec<CString> = std::iter::once(program)
            .chain(petsc_args.iter().map(String::as_str))
            .map(cstring)
            .collect();
        let mut argv_ptrs: Vec<*mut c_char> = argv_storage
            .iter_mut()
            .map(|s| s.as_ptr() as *mut c_char)
            .collect();
        argv_ptrs.push(std::ptr::null_mut());
        let mut argc = (argv_ptrs.len() - 1) as i32;
        let mut argv = argv_ptrs.as_mut_ptr();
        // SAFETY: MPI is initialised (we hold the universe); argv lives in `self` for the whole run.
        unsafe {
            sys::PETSC_COMM_WORLD = world.as_raw();
            check(
                sys::SlepcInitialize(&mut argc, &mut argv, std::ptr::null(), std::ptr::null()),
                "SlepcInitialize",
            )?;
            check(
                sys::PetscPushErrorHandler(Some(record_error), std::ptr::null_mut()),
                "PetscPushErrorHandler",
            )?;
        }
        let petsc = Petsc {
            _argv_storage: argv_storage,
            _argv_ptrs: argv_ptrs,
            world,
            universe,
            ours: Default::default(),
        };
        if petsc.rank() == 0 {
            for token in stray_tokens(petsc_args) {
                eprintln!("warning: '{token}' after -- is not a PETSc option (options start with '-') and is ignored");
            }
        }
        super::factor::share_mumps_options(&petsc)?;
        Ok(petsc)
    }

    pub fn world(&self) -> &SimpleCommunicator {
        &self.world
    }

    pub fn universe(&self) -> &Universe {
        &self.universe
    }

    pub fn rank(&self) -> usize {
        self.world.rank() as usize
    }

    pub fn size(&self) -> usize {
        self.world.size() as usize
    }

    pub(crate) fn comm(&self) -> mpi::ffi::MPI_Comm {
        self.world.as_raw()
    }

    /// True if the user gave `name` (e.g. `-eps_tol`) in any options source.
    pub fn option_given(&self, name: &str) -> Result<bool> {
        let name = cstring(name);
        let mut found: sys::PetscBool = 0;
        // SAFETY: plain query of the global options database.
        unsafe {
            check(
                sys::PetscOptionsHasName(
                    std::ptr::null_mut(),
                    std::ptr::null(),
                    name.as_ptr(),
                    &mut found,
                ),
                "PetscOptionsHasName",
            )?
        };
        Ok(found != 0)
    }

    /// Sets an option only when the user has not given it: our defaults for settings that are
    /// reachable only through the options database (MUMPS ICNTLs, for instance).
    pub fn set_default_option(&self, name: &str, value: &str) -> Result<()> {
        if self.option_given(name)? {
            return Ok(());
        }
        self.mark_ours(name);
        let (n, v) = (cstring(name), cstring(value));
        // SAFETY: PETSc copies both strings.
        unsafe {
            check(
                sys::PetscOptionsSetValue(std::ptr::null_mut(), n.as_ptr(), v.as_ptr()),
                "PetscOptionsSetValue",
            )
        }
    }

    /// Sets an option in the global database (replacing any value).
    pub fn set_option(&self, name: &str, value: &str) -> Result<()> {
        self.mark_ours(name);
        let (n, v) = (cstring(name), cstring(value));
        // SAFETY: PETSc copies both strings.
        unsafe {
            check(
                sys::PetscOptionsSetValue(std::ptr::null_mut(), n.as_ptr(), v.as_ptr()),
                "PetscOptionsSetValue",
            )
        }
    }

    /// Removes an option from the global database.
    pub fn clear_option(&self, name: &str) -> Result<()> {
        let n = cstring(name);
        // SAFETY: PETSc only reads the string.
        unsafe {
            check(
                sys::PetscOptionsClearValue(std::ptr::null_mut(), n.as_ptr()),
                "PetscOptionsClearValue",
            )
        }
    }

    /// The value of a string option, if given.
    pub fn option_value(&self, name: &str) -> Result<Option<String>> {
        let name = cstring(name);
        let mut buf = vec![0 as c_char; 512];
        let mut found: sys::PetscBool = 0;
        // SAFETY: buffer length is passed; PETSc NUL-terminates.
        unsafe {
            check(
                sys::PetscOptionsGetString(
                    std::ptr::null_mut(),
                    std::ptr::null(),
                    name.as_ptr(),
                    buf.as_mut_ptr(),
                    buf.len(),
                    &mut found,
                ),
                "PetscOptionsGetString",
            )?;
            Ok(if found != 0 {
                Some(super::from_cstr(buf.as_ptr()))
            } else {
                None
            })
        }
    }

    fn mark_ours(&self, name: &str) {
        self.ours
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .insert(name.trim_start_matches('-').to_string());
    }

    /// The options the user gave that no PETSc object has read so far (PETSc's
    /// `-options_left` list), less the ones this code set; a MUMPS control counts as used when
    /// its other spelling (`-st_…` or plain) was. Meaningful at the end of a job.
    pub fn unused_user_options(&self) -> Vec<String> {
        let mut names: Vec<String> = Vec::new();
        // SAFETY: PETSc allocates the arrays and frees them in the matching Restore call.
        unsafe {
            let mut n: sys::PetscInt = 0;
            let mut raw_names: *mut *mut c_char = std::ptr::null_mut();
            let mut raw_values: *mut *mut c_char = std::ptr::null_mut();
            if sys::PetscOptionsLeftGet(
                std::ptr::null_mut(),
                &mut n,
                &mut raw_names,
                &mut raw_values,
            ) != 0
            {
                super::error::discard_recorded();
                return names;
            }
            for i in 0..n.max(0) as usize {
                let name = super::from_cstr(*raw_names.add(i));
                let value = super::from_cstr(*raw_values.add(i));
                let name = name.trim_start_matches('-').to_string();
                names.push(if value.is_empty() {
                    name
                } else {
                    format!("{name} {value}")
                });
            }
            sys::PetscOptionsLeftRestore(
                std::ptr::null_mut(),
                &mut n,
                &mut raw_names,
                &mut raw_values,
            );
        }
        let ours = self.ours.lock().unwrap_or_else(|p| p.into_inner()).clone();
        let key = |entry: &str| entry.split(' ').next().unwrap_or("").to_string();
        let unused: std::collections::BTreeSet<String> = names.iter().map(|e| key(e)).collect();
        names
            .into_iter()
            .filter(|e| {
                let k = key(e);
                let mirror = if let Some(plain) = k.strip_prefix("st_") {
                    plain.to_string()
                } else {
                    format!("st_{k}")
                };
                let mirrored_use = k.contains("mat_mumps_") && !unused.contains(&mirror);
                !ours.contains(&k) && !mirrored_use
            })
            .map(|e| format!("-{e}"))
            .collect()
    }

    /// Version strings of the PETSc and SLEPc libraries we run on.
    pub fn versions(&self) -> (String, String) {
        let mut p = vec![0 as c_char; 256];
        let mut s = vec![0 as c_char; 256];
        // SAFETY: buffers are sized as passed.
        unsafe {
            sys::PetscGetVersion(p.as_mut_ptr(), p.len());
            sys::SlepcGetVersion(s.as_mut_ptr(), s.len());
            (super::from_cstr(p.as_ptr()), super::from_cstr(s.as_ptr()))
        }
    }

    /// Peak resident memory of this process (Linux `VmHWM`), in bytes; 0 if unavailable.
    pub fn peak_rss_bytes(&self) -> f64 {
        let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
        status
            .lines()
            .find_map(|l| l.strip_prefix("VmHWM:"))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
            .map_or(0.0, |kb| kb * 1024.0)
    }
}

/// Tokens after `--` that PETSc ignores: words that neither start an option (`-name`) nor follow
/// one as its value. Numbers (`-1e30`) are values, not names.
fn stray_tokens(args: &[String]) -> Vec<String> {
    let mut stray = Vec::new();
    let mut after_name = false;
    for token in args {
        let is_name = token.starts_with('-') && token.parse::<f64>().is_err() && token.len() > 1;
        if is_name {
            after_name = true;
        } else if after_name {
            after_name = false;
        } else {
            stray.push(token.clone());
        }
    }
    stray
}

impl Drop for Petsc {
    fn drop(&mut self) {
        // A misspelled option is otherwise ignored in silence.
        let unused = self.unused_user_options();
        if self.rank() == 0 && !unused.is_empty() {
            eprintln!("warning: PETSc option(s) given but never used (misspelled, or for a solver this job does not run): {}", unused.join(", "));
        }
        // SAFETY: every handle borrows `self`, so all were destroyed before this runs.
        unsafe {
            sys::SlepcFinalize();
        }
    }
}

/// MUMPS calls BLAS, and OpenBLAS starts one thread per core at library load: under MPI every
/// rank would then fight the others for the same cores. OpenBLAS reads `OPENBLAS_NUM_THREADS`
/// only when it is loaded, so if the user has not chosen a value we set 1 and re-execute
/// ourselves once (before MPI starts, so mpirun is unaffected).
pub fn pin_blas_threads() {
    const VAR: &str = "OPENBLAS_NUM_THREADS";
    if std::env::var_os(VAR).is_some() {
        return;
    }
    std::env::set_var(VAR, "1");
    if let Ok(exe) = std::env::current_exe() {
        use std::os::unix::process::CommandExt;
        let err = std::process::Command::new(exe)
            .args(std::env::args_os().skip(1))
            .exec();
        // exec only returns on failure; carry on with the threads OpenBLAS already started.
        eprintln!("warning: could not re-execute with {VAR}=1 ({err}); BLAS threads may compete with MPI ranks");
    }
}

#[cfg(test)]
mod tests {
    use super::stray_tokens;

    #[test]
    fn words_that_are_neither_options_nor_their_values_are_stray() {
        let args = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        assert_eq!(
            stray_tokens(&args(&["-eps_ncv", "80", "-eps_view"])),
            Vec::<String>::new()
        );
        assert_eq!(
            stray_tokens(&args(&["notanoption"])),
            vec!["notanoption".to_string()]
        );
        assert_eq!(
            stray_tokens(&args(&["-foo_bar", "1", "extra"])),
            vec!["extra".to_string()]
        );
        assert_eq!(
            stray_tokens(&args(&["-st_shift", "-1e30"])),
            Vec::<String>::new(),
            "a negative number is a value"
        );
    }
}
