//! A two-level multigrid (PETSc's PCMG) set up from an interpolation and a coarse operator that
//! the caller built: the thin layer under the iterative eigen path's p-multigrid
//! (`crate::eigen::pmg`).
//!
//! The levels are PETSc's: level 1 is the fine level, whose operator PCMG takes from the PC it
//! belongs to; level 0 is the coarse level, whose operator is given here (`PC_MG_GALERKIN_NONE`:
//! the caller forms Πᵀ P Π itself, so that it can attach a near-null space to it before a coarse
//! algebraic multigrid sees it). One multiplicative V-cycle:
//!
//! ```text
//!   x ← S(b)                        ν steps of the smoother from x = 0
//!   x ← x + Π A_c⁻¹ Πᵀ (b − P x)    coarse correction (A_c⁻¹: a few CG steps or a factor)
//!   x ← x + S(b − P x)              ν steps again
//! ```
//!
//! With the same symmetric smoother before and after and an exact coarse solve (the factor), the
//! cycle is a symmetric operator, and positive definite when the smoother is convergent in the
//! energy norm. The CG coarse solve ([`CoarseSolve::GamgCg`]) stops at a relative residual of
//! [`COARSE_RTOL`], so the cycle is then a slightly different map for every right-hand side: a
//! Krylov method that needs one fixed preconditioner (CG) would not accept it, but the generalised
//! Davidson eigen-solver that uses it only adds each preconditioned residual to its search space
//! and extracts the pairs by Rayleigh–Ritz there, so an inexact coarse solve costs it nothing but
//! the direction's quality (measured in `crate::eigen::iterative`).
//! The smoother is Chebyshev on the Jacobi-preconditioned operator D⁻¹P, over [0.1·λ̂, 1.1·λ̂]
//! with λ̂ PETSc's estimate of D⁻¹P's largest eigenvalue (a few Krylov steps at set-up), the
//! interval PETSc's own multigrid uses; Chebyshev is a fixed polynomial in D⁻¹P, so it stays the
//! same linear map at every application.
//!
//! Every option can still be changed after these defaults, with the PC's prefix:
//! `-st_mg_levels_ksp_max_it`, `-st_mg_levels_pc_type`, `-st_mg_coarse_pc_type`, … .

use super::error::{check, Result};
use super::{sys, to_petsc_int, Mat, St};

/// Relative residual at which the CG coarse solve stops (`-st_mg_coarse_ksp_rtol` overrides). On
/// the free sphere of 34,716 DOF, GD needed 504, 462 and 468 iterations for 20 modes at 10⁻¹,
/// 10⁻² and 10⁻³, and 462 with the exact factor: 10⁻² is as good as exact.
pub const COARSE_RTOL: f64 = 1e-2;

/// Most CG steps of the coarse solve (`-st_mg_coarse_ksp_max_it` overrides).
pub const COARSE_MAX_STEPS: usize = 50;

/// How the coarse level is solved.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CoarseSolve {
    /// Conjugate gradients on the coarse operator, preconditioned by one V-cycle of GAMG (plain
    /// aggregation; the operator must carry its near-null space), to a relative residual of
    /// [`COARSE_RTOL`] or at most [`COARSE_MAX_STEPS`] steps.
    GamgCg,
    /// An exact Cholesky factor of the coarse operator by MUMPS (it must be positive definite).
    MumpsCholesky,
}

/// Makes the ST's preconditioner a two-level multigrid: `interpolation` maps the coarse space
/// into the fine one, `coarse` is the coarse operator, `smoothing_steps` the Chebyshev–Jacobi
/// steps before and after the coarse correction. The ST's KSP must already have its operators
/// (or receive them from SLEPc at set-up): the fine level takes them from the PC.
pub fn use_two_level(
    st: &St<'_>,
    interpolation: &Mat<'_>,
    coarse: &Mat<'_>,
    coarse_solve: CoarseSolve,
    smoothing_steps: usize,
) -> Result<()> {
    let pc = st.pc()?.raw();
    let steps = to_petsc_int(smoothing_steps)?;
    // SAFETY: borrowed PC/KSP handles owned by the ST; the matrices are live, and PCMG takes its
    // own references to them (the caller may drop its handles after this call).
    unsafe {
        check(sys::PCSetType(pc, sys::PCMG.as_ptr() as _), "PCSetType(mg)")?;
        check(
            sys::PCMGSetLevels(pc, 2, std::ptr::null_mut()),
            "PCMGSetLevels",
        )?;
        check(
            sys::PCMGSetType(pc, sys::PCMGType_PC_MG_MULTIPLICATIVE),
            "PCMGSetType",
        )?;
        check(
            sys::PCMGSetCycleType(pc, sys::PCMGCycleType_PC_MG_CYCLE_V),
            "PCMGSetCycleType",
        )?;
        check(
            sys::PCMGSetGalerkin(pc, sys::PCMGGalerkinType_PC_MG_GALERKIN_NONE),
            "PCMGSetGalerkin",
        )?;
        check(
            sys::PCMGSetInterpolation(pc, 1, interpolation.raw()),
            "PCMGSetInterpolation",
        )?;

        let mut smoother: sys::KSP = std::ptr::null_mut();
        check(
            sys::PCMGGetSmoother(pc, 1, &mut smoother),
            "PCMGGetSmoother",
        )?;
        check(
            sys::KSPSetType(smoother, sys::KSPCHEBYSHEV.as_ptr() as _),
            "KSPSetType(chebyshev)",
        )?;
        check(
            sys::KSPChebyshevEstEigSet(smoother, 0.0, 0.1, 0.0, 1.1),
            "KSPChebyshevEstEigSet",
        )?;
        check(
            sys::KSPSetTolerances(
                smoother,
                sys::PETSC_DEFAULT as f64,
                sys::PETSC_DEFAULT as f64,
                sys::PETSC_DEFAULT as f64,
                steps,
            ),
            "KSPSetTolerances",
        )?;
        let mut smoother_pc: sys::PC = std::ptr::null_mut();
        check(sys::KSPGetPC(smoother, &mut smoother_pc), "KSPGetPC")?;
        check(
            sys::PCSetType(smoother_pc, sys::PCJACOBI.as_ptr() as _),
            "PCSetType(jacobi)",
        )?;

        let mut coarse_ksp: sys::KSP = std::ptr::null_mut();
        check(
            sys::PCMGGetCoarseSolve(pc, &mut coarse_ksp),
            "PCMGGetCoarseSolve",
        )?;
        check(
            sys::KSPSetOperators(coarse_ksp, coarse.raw(), coarse.raw()),
            "KSPSetOperators(coarse)",
        )?;
        let mut coarse_pc: sys::PC = std::ptr::null_mut();
        check(sys::KSPGetPC(coarse_ksp, &mut coarse_pc), "KSPGetPC")?;
        match coarse_solve {
            CoarseSolve::GamgCg => {
                check(
                    sys::KSPSetType(coarse_ksp, sys::KSPCG.as_ptr() as _),
                    "KSPSetType(cg)",
                )?;
                // Stopping short of the tolerance is not an error: the correction is still a
                // descent direction, and GD only needs a good one (module docs).
                check(
                    sys::KSPSetTolerances(
                        coarse_ksp,
                        COARSE_RTOL,
                        sys::PETSC_DEFAULT as f64,
                        sys::PETSC_DEFAULT as f64,
                        to_petsc_int(COARSE_MAX_STEPS)?,
                    ),
                    "KSPSetTolerances(coarse)",
                )?;
                check(
                    sys::PCSetType(coarse_pc, sys::PCGAMG.as_ptr() as _),
                    "PCSetType(gamg)",
                )?;
                check(sys::PCGAMGSetNSmooths(coarse_pc, 0), "PCGAMGSetNSmooths")?;
            }
            CoarseSolve::MumpsCholesky => {
                check(
                    sys::KSPSetType(coarse_ksp, sys::KSPPREONLY.as_ptr() as _),
                    "KSPSetType(preonly)",
                )?;
                check(
                    sys::PCSetType(coarse_pc, sys::PCCHOLESKY.as_ptr() as _),
                    "PCSetType(cholesky)",
                )?;
                check(
                    sys::PCFactorSetMatSolverType(coarse_pc, sys::MATSOLVERMUMPS.as_ptr() as _),
                    "PCFactorSetMatSolverType",
                )?;
            }
        }
    }
    Ok(())
}
