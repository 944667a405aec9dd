//! A stand-alone linear solver: factor `A` and read its inertia ([`inertia`]), or factor a
//! symmetric positive definite `A` once and solve with it many times ([`CholeskySolver`]).

use super::error::{check, Result};
use super::{sys, Mat, Petsc, PetscError, Vector};
use std::marker::PhantomData;

pub struct Ksp<'p> {
    raw: sys::KSP,
    _runtime: PhantomData<&'p Petsc>,
}

impl<'p> Ksp<'p> {
    pub fn new(petsc: &'p Petsc) -> Result<Self> {
        let mut raw: sys::KSP = std::ptr::null_mut();
        // SAFETY: creation on the world communicator.
        unsafe { check(sys::KSPCreate(petsc.comm(), &mut raw), "KSPCreate")? };
        Ok(Ksp { raw, _runtime: PhantomData })
    }

    pub fn raw(&self) -> sys::KSP {
        self.raw
    }
}

impl Drop for Ksp<'_> {
    fn drop(&mut self) {
        // SAFETY: we own the handle.
        unsafe {
            sys::KSPDestroy(&mut self.raw);
        }
    }
}

/// A symmetric positive definite matrix factored once by MUMPS Cholesky (KSPPREONLY + PCCHOLESKY):
/// each [`CholeskySolver::solve`] is two triangular solves. Collective.
pub struct CholeskySolver<'p> {
    ksp: Ksp<'p>,
}

impl<'p> CholeskySolver<'p> {
    /// Factors `a` (which must stay assembled and unchanged while the solver lives; PETSc keeps
    /// its own reference). A zero or negative pivot is an error with MUMPS's message.
    pub fn factor(petsc: &'p Petsc, a: &Mat<'p>) -> Result<Self> {
        let ksp = Ksp::new(petsc)?;
        // SAFETY: handles created here, destroyed by `ksp`'s Drop; PETSc references `a`.
        unsafe {
            check(sys::KSPSetOperators(ksp.raw, a.raw(), a.raw()), "KSPSetOperators")?;
            check(sys::KSPSetType(ksp.raw, sys::KSPPREONLY.as_ptr() as _), "KSPSetType")?;
            // Factorisation failures become KSPSolve errors instead of a silent NaN solution.
            check(sys::KSPSetErrorIfNotConverged(ksp.raw, sys::PetscBool_PETSC_TRUE), "KSPSetErrorIfNotConverged")?;
            let mut pc: sys::PC = std::ptr::null_mut();
            check(sys::KSPGetPC(ksp.raw, &mut pc), "KSPGetPC")?;
            check(sys::PCSetType(pc, sys::PCCHOLESKY.as_ptr() as _), "PCSetType")?;
            check(sys::PCFactorSetMatSolverType(pc, sys::MATSOLVERMUMPS.as_ptr() as _), "PCFactorSetMatSolverType")?;
            check(sys::KSPSetUp(ksp.raw), "KSPSetUp")?;
        }
        Ok(CholeskySolver { ksp })
    }

    /// x = A⁻¹ b.
    pub fn solve(&self, b: &Vector<'p>, x: &mut Vector<'p>) -> Result<()> {
        // SAFETY: vectors with the operator's layout; PETSc checks the sizes.
        unsafe { check(sys::KSPSolve(self.ksp.raw, b.raw(), x.raw()), "KSPSolve")? };
        let mut reason: sys::KSPConvergedReason = 0;
        // SAFETY: query only.
        unsafe { check(sys::KSPGetConvergedReason(self.ksp.raw, &mut reason), "KSPGetConvergedReason")? };
        if reason < 0 {
            return Err(PetscError::other(format!("the Cholesky solve failed (KSPConvergedReason {reason})")));
        }
        Ok(())
    }
}

/// Sylvester inertia of a symmetric matrix: how many eigenvalues are negative, zero and positive.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Inertia {
    pub negative: usize,
    pub zero: usize,
    pub positive: usize,
}

/// Factors the symmetric matrix `a` with MUMPS Cholesky (LDLᵀ) and returns its inertia.
///
/// By Sylvester's law, for `a = K − σM` with M positive definite the count of negative
/// eigenvalues of `a` equals the number of generalised eigenvalues of (K, M) below σ. That is how
/// we prove no mode was missed. In parallel MUMPS only reports the inertia when ICNTL(13) = 1
/// (no ScaLAPACK on the root front), so we set it.
pub fn inertia<'p>(petsc: &'p Petsc, a: &Mat<'p>) -> Result<Inertia> {
    let ksp = Ksp::new(petsc)?;
    // SAFETY: handles created here, destroyed by `ksp`'s Drop; `a` outlives the call.
    unsafe {
        check(sys::KSPSetOperators(ksp.raw, a.raw(), a.raw()), "KSPSetOperators")?;
        check(sys::KSPSetType(ksp.raw, sys::KSPPREONLY.as_ptr() as _), "KSPSetType")?;
        let mut pc: sys::PC = std::ptr::null_mut();
        check(sys::KSPGetPC(ksp.raw, &mut pc), "KSPGetPC")?;
        check(sys::PCSetType(pc, sys::PCCHOLESKY.as_ptr() as _), "PCSetType")?;
        check(sys::PCFactorSetMatSolverType(pc, sys::MATSOLVERMUMPS.as_ptr() as _), "PCFactorSetMatSolverType")?;
        check(sys::PCFactorSetUpMatSolverType(pc), "PCFactorSetUpMatSolverType")?;
        let mut factor: sys::Mat = std::ptr::null_mut();
        check(sys::PCFactorGetMatrix(pc, &mut factor), "PCFactorGetMatrix")?;
        check(sys::MatMumpsSetIcntl(factor, 13, 1), "MatMumpsSetIcntl(13)")?;
        // PETSc only returns MUMPS inertia with null-pivot detection on.
        check(sys::MatMumpsSetIcntl(factor, 24, 1), "MatMumpsSetIcntl(24)")?;
        check(sys::KSPSetUp(ksp.raw), "KSPSetUp")?;
        let (mut neg, mut zero, mut pos) = (0, 0, 0);
        check(sys::MatGetInertia(factor, &mut neg, &mut zero, &mut pos), "MatGetInertia")?;
        Ok(Inertia { negative: neg as usize, zero: zero as usize, positive: pos as usize })
    }
}
