//! SLEPc eigensolver handle and borrowed views of its spectral transformation and linear solver.

use super::error::{check, Result};
use super::{from_cstr, sys, to_petsc_int, Mat, Petsc, Vector};
use std::marker::PhantomData;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EpsWhich {
    /// Eigenvalues closest to the target (shift-invert).
    TargetMagnitude,
    /// Every eigenvalue in the interval set with [`Eps::set_interval`] (spectrum slicing).
    All,
    /// The smallest (algebraic) eigenvalues, for preconditioned solvers such as LOBPCG.
    SmallestReal,
}

pub struct Eps<'p> {
    raw: sys::EPS,
    _runtime: PhantomData<&'p Petsc>,
}

/// The spectral transformation owned by an [`Eps`].
pub struct St<'e> {
    raw: sys::ST,
    _eps: PhantomData<&'e ()>,
}

/// The preconditioner (here: the factorisation) inside the ST's KSP.
pub struct Pc<'e> {
    raw: sys::PC,
    _eps: PhantomData<&'e ()>,
}

impl<'p> Eps<'p> {
    pub fn new(petsc: &'p Petsc) -> Result<Self> {
        let mut raw: sys::EPS = std::ptr::null_mut();
        // SAFETY: creation on the world communicator.
        unsafe { check(sys::EPSCreate(petsc.comm(), &mut raw), "EPSCreate")? };
        Ok(Eps {
            raw,
            _runtime: PhantomData,
        })
    }

    /// Sets the generalised Hermitian definite problem `A x = λ B x`.
    pub fn set_operators_ghep(&mut self, a: &Mat<'p>, b: &Mat<'p>) -> Result<()> {
        // SAFETY: EPS takes references to the matrices; they outlive it because both borrow 'p
        // and the caller keeps them alive while solving (enforced by `solve` taking them again
        // would be heavier; callers in crate::eigen hold them across the solve).
        unsafe {
            check(
                sys::EPSSetOperators(self.raw, a.raw(), b.raw()),
                "EPSSetOperators",
            )?;
            check(
                sys::EPSSetProblemType(self.raw, sys::EPSProblemType_EPS_GHEP),
                "EPSSetProblemType",
            )
        }
    }

    pub fn set_type(&mut self, name: &[u8]) -> Result<()> {
        // SAFETY: `name` is one of the NUL-terminated constants from sys.
        unsafe { check(sys::EPSSetType(self.raw, name.as_ptr() as _), "EPSSetType") }
    }

    pub fn set_which(&mut self, which: EpsWhich) -> Result<()> {
        let w = match which {
            EpsWhich::TargetMagnitude => sys::EPSWhich_EPS_TARGET_MAGNITUDE,
            EpsWhich::All => sys::EPSWhich_EPS_ALL,
            EpsWhich::SmallestReal => sys::EPSWhich_EPS_SMALLEST_REAL,
        };
        // SAFETY: plain setter.
        unsafe {
            check(
                sys::EPSSetWhichEigenpairs(self.raw, w),
                "EPSSetWhichEigenpairs",
            )
        }
    }

    pub fn set_target(&mut self, target: f64) -> Result<()> {
        // SAFETY: plain setter.
        unsafe { check(sys::EPSSetTarget(self.raw, target), "EPSSetTarget") }
    }

    pub fn set_interval(&mut self, lower: f64, upper: f64) -> Result<()> {
        // SAFETY: plain setter.
        unsafe {
            check(
                sys::EPSSetInterval(self.raw, lower, upper),
                "EPSSetInterval",
            )
        }
    }

    /// Number of eigenpairs wanted; `ncv`/`mpd` left to SLEPc when `None`.
    pub fn set_dimensions(
        &mut self,
        nev: usize,
        ncv: Option<usize>,
        mpd: Option<usize>,
    ) -> Result<()> {
        let decide = sys::PETSC_DECIDE;
        let ncv = ncv.map(to_petsc_int).transpose()?.unwrap_or(decide);
        let mpd = mpd.map(to_petsc_int).transpose()?.unwrap_or(decide);
        // SAFETY: plain setter.
        unsafe {
            check(
                sys::EPSSetDimensions(self.raw, to_petsc_int(nev)?, ncv, mpd),
                "EPSSetDimensions",
            )
        }
    }

    pub fn set_tolerances(&mut self, tol: f64, max_it: Option<usize>) -> Result<()> {
        let max_it = max_it
            .map(to_petsc_int)
            .transpose()?
            .unwrap_or(sys::PETSC_DEFAULT);
        // SAFETY: plain setter.
        unsafe {
            check(
                sys::EPSSetTolerances(self.raw, tol, max_it),
                "EPSSetTolerances",
            )
        }
    }

    /// Purification costs one extra solve per eigenvector; off by default (stack notes).
    pub fn set_purify(&mut self, purify: bool) -> Result<()> {
        // SAFETY: plain setter.
        unsafe {
            check(
                sys::EPSSetPurify(self.raw, purify as sys::PetscBool),
                "EPSSetPurify",
            )
        }
    }

    /// Restricts the solve to the complement (in the B-inner product of the GHEP) of the space
    /// the `vectors` span, which must be invariant (known eigenvectors, such as a free body's
    /// rigid motions). SLEPc orthonormalises them itself and holds its own references until the
    /// next solve, so they need not outlive this call; they apply to one `solve` only.
    pub fn set_deflation_space<'v>(
        &mut self,
        vectors: impl IntoIterator<Item = &'v Vector<'p>>,
    ) -> Result<()>
    where
        'p: 'v,
    {
        let mut raw: Vec<sys::Vec> = vectors.into_iter().map(|v| v.raw()).collect();
        // SAFETY: `raw` holds live Vec handles of the operators' layout; SLEPc references them.
        unsafe {
            check(
                sys::EPSSetDeflationSpace(self.raw, to_petsc_int(raw.len())?, raw.as_mut_ptr()),
                "EPSSetDeflationSpace",
            )
        }
    }

    pub fn st(&self) -> Result<St<'_>> {
        let mut raw: sys::ST = std::ptr::null_mut();
        // SAFETY: borrowed handle owned by the EPS.
        unsafe { check(sys::EPSGetST(self.raw, &mut raw), "EPSGetST")? };
        Ok(St {
            raw,
            _eps: PhantomData,
        })
    }

    /// Applies `-eps_*`, `-st_*` options: call after the code defaults so users can override them.
    pub fn set_from_options(&mut self) -> Result<()> {
        // SAFETY: reads the global options database.
        unsafe { check(sys::EPSSetFromOptions(self.raw), "EPSSetFromOptions") }
    }

    pub fn set_up(&mut self) -> Result<()> {
        // SAFETY: collective.
        unsafe { check(sys::EPSSetUp(self.raw), "EPSSetUp") }
    }

    pub fn solve(&mut self) -> Result<()> {
        // SAFETY: collective; operators were set and are alive.
        unsafe { check(sys::EPSSolve(self.raw), "EPSSolve") }
    }

    /// [`Eps::solve`], calling `report(iterations, converged)` at most once every `every` from
    /// SLEPc's monitor hook (on every rank; the caller decides who prints). The hook is removed
    /// before this returns, user monitors (`-eps_monitor`) included.
    pub fn solve_reporting(
        &mut self,
        every: std::time::Duration,
        report: &mut dyn FnMut(usize, usize),
    ) -> Result<()> {
        struct Hook<'r> {
            report: &'r mut dyn FnMut(usize, usize),
            every: std::time::Duration,
            last: std::time::Instant,
        }
        unsafe extern "C" fn monitor(
            _eps: sys::EPS,
            its: sys::PetscInt,
            nconv: sys::PetscInt,
            _eigr: *mut sys::PetscScalar,
            _eigi: *mut sys::PetscScalar,
            _errest: *mut sys::PetscReal,
            _nest: sys::PetscInt,
            ctx: *mut std::os::raw::c_void,
        ) -> sys::PetscErrorCode {
            // SAFETY: ctx is the `Hook` below, alive for the whole EPSSolve that calls this.
            let hook = unsafe { &mut *(ctx as *mut Hook<'_>) };
            if hook.last.elapsed() >= hook.every {
                hook.last = std::time::Instant::now();
                // A panic must not unwind into C; a failed report is only a lost progress line.
                let report = &mut hook.report;
                let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                    report(its.max(0) as usize, nconv.max(0) as usize)
                }));
            }
            0
        }
        let mut hook = Hook {
            report,
            every,
            last: std::time::Instant::now(),
        };
        // SAFETY: the context outlives the solve; the monitor is cancelled before `hook` drops.
        unsafe {
            check(
                sys::EPSMonitorSet(
                    self.raw,
                    Some(monitor),
                    &mut hook as *mut Hook<'_> as *mut std::os::raw::c_void,
                    None,
                ),
                "EPSMonitorSet",
            )?;
            let solved = check(sys::EPSSolve(self.raw), "EPSSolve");
            let cancelled = check(sys::EPSMonitorCancel(self.raw), "EPSMonitorCancel");
            solved.and(cancelled)
        }
    }

    pub fn converged(&self) -> Result<usize> {
        let mut n = 0;
        // SAFETY: query only.
        unsafe { check(sys::EPSGetConverged(self.raw, &mut n), "EPSGetConverged")? };
        Ok(n as usize)
    }

    /// Eigenvalue `i` and its eigenvector written into `x`.
    pub fn eigenpair(&self, i: usize, x: &mut Vector<'p>) -> Result<f64> {
        let (mut kr, mut ki) = (0.0, 0.0);
        // SAFETY: `x` has the operator's layout; imaginary part is not requested (real GHEP).
        unsafe {
            check(
                sys::EPSGetEigenpair(
                    self.raw,
                    to_petsc_int(i)?,
                    &mut kr,
                    &mut ki,
                    x.raw(),
                    std::ptr::null_mut(),
                ),
                "EPSGetEigenpair",
            )?
        };
        Ok(kr)
    }

    /// Relative residual ‖A x − λ B x‖ / (|λ| ‖x‖) of pair `i`.
    pub fn relative_error(&self, i: usize) -> Result<f64> {
        let mut e = 0.0;
        // SAFETY: query only (collective).
        unsafe {
            check(
                sys::EPSComputeError(
                    self.raw,
                    to_petsc_int(i)?,
                    sys::EPSErrorType_EPS_ERROR_RELATIVE,
                    &mut e,
                ),
                "EPSComputeError",
            )?
        };
        Ok(e)
    }

    pub fn iterations(&self) -> Result<usize> {
        let mut n = 0;
        // SAFETY: query only.
        unsafe {
            check(
                sys::EPSGetIterationNumber(self.raw, &mut n),
                "EPSGetIterationNumber",
            )?
        };
        Ok(n as usize)
    }

    pub fn type_name(&self) -> Result<String> {
        let mut t: sys::EPSType = std::ptr::null();
        // SAFETY: PETSc returns a pointer to its own static string.
        unsafe {
            check(sys::EPSGetType(self.raw, &mut t), "EPSGetType")?;
            Ok(from_cstr(t))
        }
    }

    pub fn tolerances(&self) -> Result<(f64, usize)> {
        let (mut tol, mut it) = (0.0, 0);
        // SAFETY: query only.
        unsafe {
            check(
                sys::EPSGetTolerances(self.raw, &mut tol, &mut it),
                "EPSGetTolerances",
            )?
        };
        Ok((tol, it as usize))
    }

    /// (nev, ncv, mpd) actually in force after set-up.
    pub fn dimensions(&self) -> Result<(usize, usize, usize)> {
        let (mut nev, mut ncv, mut mpd) = (0, 0, 0);
        // SAFETY: query only.
        unsafe {
            check(
                sys::EPSGetDimensions(self.raw, &mut nev, &mut ncv, &mut mpd),
                "EPSGetDimensions",
            )?
        };
        Ok((nev as usize, ncv as usize, mpd as usize))
    }

    pub fn target(&self) -> Result<f64> {
        let mut t = 0.0;
        // SAFETY: query only.
        unsafe { check(sys::EPSGetTarget(self.raw, &mut t), "EPSGetTarget")? };
        Ok(t)
    }

    pub fn interval(&self) -> Result<(f64, f64)> {
        let (mut a, mut b) = (0.0, 0.0);
        // SAFETY: query only.
        unsafe {
            check(
                sys::EPSGetInterval(self.raw, &mut a, &mut b),
                "EPSGetInterval",
            )?
        };
        Ok((a, b))
    }

    /// SLEPc's converged reason code (positive: converged; negative: diverged).
    pub fn converged_reason(&self) -> Result<i32> {
        let mut r: sys::EPSConvergedReason = 0;
        // SAFETY: query only.
        unsafe {
            check(
                sys::EPSGetConvergedReason(self.raw, &mut r),
                "EPSGetConvergedReason",
            )?
        };
        Ok(r as i32)
    }
}

impl Drop for Eps<'_> {
    fn drop(&mut self) {
        // SAFETY: we own the handle.
        unsafe {
            sys::EPSDestroy(&mut self.raw);
        }
    }
}

impl St<'_> {
    pub fn set_type(&self, name: &[u8]) -> Result<()> {
        // SAFETY: NUL-terminated constant.
        unsafe { check(sys::STSetType(self.raw, name.as_ptr() as _), "STSetType") }
    }

    /// K and M share one sparsity pattern, so K − σM needs no symbolic merge.
    pub fn set_same_nonzero_pattern(&self) -> Result<()> {
        // SAFETY: plain setter.
        unsafe {
            check(
                sys::STSetMatStructure(self.raw, sys::MatStructure_SAME_NONZERO_PATTERN),
                "STSetMatStructure",
            )
        }
    }

    pub fn type_name(&self) -> Result<String> {
        let mut t: sys::STType = std::ptr::null();
        // SAFETY: static string.
        unsafe {
            check(sys::STGetType(self.raw, &mut t), "STGetType")?;
            Ok(from_cstr(t))
        }
    }

    /// Sets the inner solve to a direct factorisation: KSP `preonly`, PC `factor` with `solver`.
    pub fn use_direct_solver(&self, factor: &[u8], solver: &[u8]) -> Result<()> {
        let pc = self.pc()?;
        // SAFETY: borrowed KSP/PC handles owned by the ST.
        unsafe {
            let mut ksp: sys::KSP = std::ptr::null_mut();
            check(sys::STGetKSP(self.raw, &mut ksp), "STGetKSP")?;
            check(
                sys::KSPSetType(ksp, sys::KSPPREONLY.as_ptr() as _),
                "KSPSetType",
            )?;
            check(sys::PCSetType(pc.raw, factor.as_ptr() as _), "PCSetType")?;
            check(
                sys::PCFactorSetMatSolverType(pc.raw, solver.as_ptr() as _),
                "PCFactorSetMatSolverType",
            )
        }
    }

    /// Sets the inner solve to an iterative one: KSP `ksp_type` with PC `pc_type`.
    pub fn use_iterative_solver(&self, ksp_type: &[u8], pc_type: &[u8]) -> Result<()> {
        let pc = self.pc()?;
        // SAFETY: borrowed KSP/PC handles owned by the ST; NUL-terminated constants.
        unsafe {
            let mut ksp: sys::KSP = std::ptr::null_mut();
            check(sys::STGetKSP(self.raw, &mut ksp), "STGetKSP")?;
            check(sys::KSPSetType(ksp, ksp_type.as_ptr() as _), "KSPSetType")?;
            check(sys::PCSetType(pc.raw, pc_type.as_ptr() as _), "PCSetType")
        }
    }

    /// The matrix the ST's preconditioner is built from, instead of A − σB (which SLEPc would
    /// form itself, without the near-null space a multigrid needs). SLEPc takes a reference.
    pub fn set_preconditioner_mat<'p>(&self, p: &Mat<'p>) -> Result<()> {
        // SAFETY: live matrix of the operators' layout; SLEPc references it.
        unsafe {
            check(
                sys::STSetPreconditionerMat(self.raw, p.raw()),
                "STSetPreconditionerMat",
            )
        }
    }

    /// The number of prolongator smoothing steps of the ST's GAMG preconditioner (0: plain
    /// aggregation). Call after the PC type is set to GAMG.
    pub fn set_gamg_smoothing_steps(&self, steps: usize) -> Result<()> {
        let pc = self.pc()?;
        // SAFETY: borrowed PC handle; a no-op on PCs other than GAMG.
        unsafe {
            check(
                sys::PCGAMGSetNSmooths(pc.raw, to_petsc_int(steps)?),
                "PCGAMGSetNSmooths",
            )
        }
    }

    /// Sets up the ST's linear solver now (for a multigrid: builds its hierarchy), instead of
    /// at its first application.
    pub fn set_up_solver(&self) -> Result<()> {
        // SAFETY: borrowed KSP owned by the ST, whose operators EPSSetUp has set.
        unsafe {
            let mut ksp: sys::KSP = std::ptr::null_mut();
            check(sys::STGetKSP(self.raw, &mut ksp), "STGetKSP")?;
            check(sys::KSPSetUp(ksp), "KSPSetUp")
        }
    }

    pub fn pc(&self) -> Result<Pc<'_>> {
        // SAFETY: borrowed handles.
        unsafe {
            let mut ksp: sys::KSP = std::ptr::null_mut();
            check(sys::STGetKSP(self.raw, &mut ksp), "STGetKSP")?;
            let mut pc: sys::PC = std::ptr::null_mut();
            check(sys::KSPGetPC(ksp, &mut pc), "KSPGetPC")?;
            Ok(Pc {
                raw: pc,
                _eps: PhantomData,
            })
        }
    }

    /// (KSP type, PC type, factor solver type) in force.
    pub fn solver_description(&self) -> Result<(String, String, String)> {
        // SAFETY: borrowed handles and static strings.
        unsafe {
            let mut ksp: sys::KSP = std::ptr::null_mut();
            check(sys::STGetKSP(self.raw, &mut ksp), "STGetKSP")?;
            let mut kt: sys::KSPType = std::ptr::null();
            check(sys::KSPGetType(ksp, &mut kt), "KSPGetType")?;
            let pc = self.pc()?;
            let mut pt: sys::PCType = std::ptr::null();
            check(sys::PCGetType(pc.raw, &mut pt), "PCGetType")?;
            let mut st: sys::MatSolverType = std::ptr::null();
            // Not every PC has a factor solver type; an error here just means "none".
            let solver = if sys::PCFactorGetMatSolverType(pc.raw, &mut st) == 0 {
                from_cstr(st)
            } else {
                super::error::discard_recorded();
                String::new()
            };
            Ok((from_cstr(kt), from_cstr(pt), solver))
        }
    }
}

impl Pc<'_> {
    pub fn raw(&self) -> sys::PC {
        self.raw
    }

    /// MUMPS's status of this PC's factor, when it has one made by MUMPS.
    pub fn mumps_status(&self) -> Option<super::factor::MumpsStatus> {
        let mut factor: sys::Mat = std::ptr::null_mut();
        // SAFETY: borrowed factor handle; the queries fail harmlessly on a non-MUMPS factor.
        unsafe {
            if sys::PCFactorGetMatrix(self.raw, &mut factor) != 0 || factor.is_null() {
                super::error::discard_recorded();
                return None;
            }
        }
        // A failed query's messages are taken by its `check`, so nothing is left recorded.
        super::factor::MumpsStatus::read(factor).ok()
    }
}
