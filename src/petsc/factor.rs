//! MUMPS factorisations: the one path every direct solve in diffsound takes.
//!
//! Every factor the code makes — the shift-invert factor of the eigen-solve (SLEPc's ST, options
//! prefix `st_`), the inertia counts that prove the mode count, the attachment solver of the
//! reduced basis and the shape fits' solves — goes through this module, so they share one set of
//! defaults, one set of user overrides and one recovery.
//!
//! **User overrides.** MUMPS's controls are PETSc options: `-mat_mumps_icntl_N V` and
//! `-mat_mumps_cntl_N V`. [`share_mumps_options`] (called once at start-up) copies each one the
//! user gave in either spelling, unprefixed or with the eigen-solve's `-st_` prefix, to the other,
//! so one option reaches every factorisation; a control given in both spellings keeps each.
//!
//! **Workspace recovery.** MUMPS sizes its workspace from the analysis's estimate plus
//! ICNTL(14) per cent. Numerical pivoting of an indefinite or badly scaled symmetric matrix
//! (K − τM inside the spectrum; a thin plate's K, whose bending and membrane stiffnesses differ by
//! (L/t)²) delays pivots beyond that estimate, and on several ranks the estimate is rougher still.
//! MUMPS then stops with INFOG(1) = −8, −9, −11, −12, −14, −17 or −20. We factor again with
//! ICNTL(14) doubled (at least 60 %), up to [`MAX_WORKSPACE_RETRIES`] times, and remember the
//! raised value for the rest of the run ([`learned_workspace_percent`]), so a sequence of similar
//! factorisations pays the failure once. PETSc's MUMPS interface skips a numerical factorisation
//! while INFOG(1) < 0 is left from a previous one, so each retry redoes the analysis on a fresh
//! factor. −13 (an allocation the system refused) and −19 (a user cap ICNTL(23) too small) are not
//! retried: they end with the memory MUMPS asked for and the option to change.
//!
//! **What INFOG(12) guarantees.** For a symmetric matrix factored as LDLᵀ (MUMPS SYM = 2, which
//! PETSc uses for Cholesky on AIJ) INFOG(12) counts the negative pivots of D, which by Sylvester's
//! law is the number of negative eigenvalues — on several ranks only when (a) the factorisation
//! succeeded: after a failed one INFOG(12) holds the count of the pivots eliminated before the
//! failure, a smaller number with no error raised unless the caller looks (this is what made the
//! inertia proof miscount on two ranks); (b) the root front is not factored by ScaLAPACK, whose
//! LU gives no inertia (ICNTL(13) = 1); (c) no pivot was flagged null by ICNTL(24) (INFOG(28)
//! counts those; their sign is undetermined). [`MumpsCholesky::inertia`] refuses a count unless all
//! three hold; the eigen module cross-checks the count against pairs proven by their residuals.

use super::error::{check, Result};
use super::{sys, Mat, Petsc, PetscError, Vector};
use std::sync::atomic::{AtomicI32, Ordering};

/// Testing hook for the workspace recovery: with the PETSc option `-diffsound_fault_workspace
/// WHAT`, the first attempt of every factorisation whose name contains WHAT (e.g. `inertia`) is
/// reported as INFOG(1) = −9, as MUMPS reports a workspace run short. Whether MUMPS really runs
/// short at a given ICNTL(14) depends on its dynamic scheduling on several ranks, so a test of the
/// recovery cannot rely on it; the factorisation itself and its retry are real. Every rank reads
/// the same option, so the retry stays collective.
pub const FAULT_WORKSPACE_OPTION: &str = "-diffsound_fault_workspace";

fn injected_workspace_fault(petsc: &Petsc, what: &str) -> Result<bool> {
    Ok(petsc
        .option_value(FAULT_WORKSPACE_OPTION)?
        .is_some_and(|w| !w.is_empty() && what.contains(w.as_str())))
}

/// How many times a factorisation is repeated with a larger workspace before giving up.
pub const MAX_WORKSPACE_RETRIES: usize = 4;

/// The smallest ICNTL(14) a retry uses [%].
const FIRST_RETRY_PERCENT: i32 = 60;

/// The largest ICNTL(14) the workspace has needed so far in this run (0: none raised yet).
static LEARNED_ICNTL14: AtomicI32 = AtomicI32::new(0);

/// The ICNTL(14) that a retry raised for this run, if any: later factorisations start there.
pub fn learned_workspace_percent() -> Option<i32> {
    match LEARNED_ICNTL14.load(Ordering::Relaxed) {
        0 => None,
        v => Some(v),
    }
}

pub fn learn_workspace_percent(v: i32) {
    LEARNED_ICNTL14.fetch_max(v, Ordering::Relaxed);
}

/// The ICNTL(14) of the retry after one that failed at `current` per cent.
pub fn next_workspace_percent(current: i32) -> i32 {
    (2 * current.max(1)).max(FIRST_RETRY_PERCENT)
}

/// What MUMPS reported about one factorisation (global values, the same on every rank).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MumpsStatus {
    /// INFOG(1): 0 success, < 0 error, > 0 warning.
    pub infog1: i32,
    /// INFOG(2): the error's detail (for −9 the missing workspace entries; for −13 the
    /// allocation that failed, in entries, or in millions of entries if negative).
    pub infog2: i32,
    /// ICNTL(14) in force [%].
    pub icntl14: i32,
    /// ICNTL(13) in force (1: no ScaLAPACK on the root front).
    pub icntl13: i32,
    /// ICNTL(24) in force (1: null-pivot detection).
    pub icntl24: i32,
    /// INFOG(12): negative pivots.
    pub negative_pivots: i64,
    /// INFOG(28): null pivots flagged by ICNTL(24).
    pub null_pivots: i64,
    /// INFOG(16)/(17): the analysis's estimate of the in-core factorisation memory [MB], the
    /// largest rank's and the sum over ranks.
    pub estimate_mb_max: i32,
    pub estimate_mb_sum: i32,
    /// INFOG(18)/(19): memory the factorisation allocated [MB], largest rank and sum.
    pub allocated_mb_max: i32,
    pub allocated_mb_sum: i32,
}

impl MumpsStatus {
    /// Reads the status of a MUMPS factor matrix (collective-free queries of stored values).
    pub(crate) fn read(factor: sys::Mat) -> Result<MumpsStatus> {
        let infog = |i: i32| -> Result<i32> {
            let mut v: sys::PetscInt = 0;
            // SAFETY: query of a stored MUMPS value on a MUMPS factor matrix.
            unsafe { check(sys::MatMumpsGetInfog(factor, i, &mut v), "MatMumpsGetInfog")? };
            Ok(v)
        };
        let icntl = |i: i32| -> Result<i32> {
            let mut v: sys::PetscInt = 0;
            // SAFETY: as above.
            unsafe { check(sys::MatMumpsGetIcntl(factor, i, &mut v), "MatMumpsGetIcntl")? };
            Ok(v)
        };
        Ok(MumpsStatus {
            infog1: infog(1)?,
            infog2: infog(2)?,
            icntl14: icntl(14)?,
            icntl13: icntl(13)?,
            icntl24: icntl(24)?,
            negative_pivots: infog(12)? as i64,
            null_pivots: infog(28)? as i64,
            estimate_mb_max: infog(16)?,
            estimate_mb_sum: infog(17)?,
            allocated_mb_max: infog(18)?,
            allocated_mb_sum: infog(19)?,
        })
    }

    pub fn failure(&self) -> Option<MumpsFailure> {
        MumpsFailure::of(self.infog1)
    }
}

/// The classes of MUMPS error that call for different remedies.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MumpsFailure {
    /// −8, −9, −11, −12, −14, −17, −20: a work array sized from ICNTL(14) was too small.
    Workspace,
    /// −13: the system refused an allocation.
    Allocation,
    /// −19: the user's cap ICNTL(23) on the working memory was too small.
    MemoryCap,
    /// −10: numerically singular.
    Singular,
    /// Anything else.
    Other,
}

impl MumpsFailure {
    pub fn of(infog1: i32) -> Option<MumpsFailure> {
        Some(match infog1 {
            0.. => return None,
            -8 | -9 | -11 | -12 | -14 | -17 | -20 => MumpsFailure::Workspace,
            -13 => MumpsFailure::Allocation,
            -19 => MumpsFailure::MemoryCap,
            -10 => MumpsFailure::Singular,
            _ => MumpsFailure::Other,
        })
    }
}

/// Megabytes that an INFOG(2) of an allocation failure (−13) stands for: entries of 8 bytes, or
/// millions of entries when negative.
pub fn allocation_mb(infog2: i32) -> f64 {
    let entries = if infog2 < 0 {
        -(infog2 as f64) * 1e6
    } else {
        infog2 as f64
    };
    entries * 8.0 / 1e6
}

/// One try at a factorisation: the workspace it had and what MUMPS said.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FactorAttempt {
    /// True when this try repeats the one before it after a workspace failure.
    pub retry: bool,
    pub icntl14: i32,
    pub infog1: i32,
    pub infog2: i32,
}

/// Every try of a sequence of factorisations, for logs and the output file's `/solver`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FactorLog {
    pub attempts: Vec<FactorAttempt>,
}

impl FactorLog {
    /// Records a try; it is a retry when this log already holds one (a log per factorisation).
    pub fn record(&mut self, icntl14: i32, infog1: i32, infog2: i32) {
        self.attempts.push(FactorAttempt {
            retry: !self.attempts.is_empty(),
            icntl14,
            infog1,
            infog2,
        });
    }

    /// Tries that repeated a failed one.
    pub fn retries(&self) -> usize {
        self.attempts.iter().filter(|a| a.retry).count()
    }

    /// `"20%:-9 60%:ok, 60%:ok"`: the tries of each factorisation, factorisations apart by commas.
    pub fn describe(&self) -> String {
        let mut out = String::new();
        for (i, a) in self.attempts.iter().enumerate() {
            if i > 0 {
                out.push_str(if a.retry { " " } else { ", " });
            }
            out.push_str(&if a.infog1 >= 0 {
                format!("{}%:ok", a.icntl14)
            } else {
                format!("{}%:{}", a.icntl14, a.infog1)
            });
        }
        out
    }

    /// One log line per retry taken, naming `what` was factored.
    pub fn retry_notes(&self, what: &str) -> Vec<String> {
        self.attempts
            .windows(2)
            .filter(|w| w[1].retry)
            .map(|w| {
                format!(
                    "MUMPS workspace too small for the {what} (INFOG(1) = {}, ICNTL(14) = {} %): factored again with ICNTL(14) = {} %",
                    w[0].infog1, w[0].icntl14, w[1].icntl14
                )
            })
            .collect()
    }
}

/// A factorisation that could not be made.
#[derive(Debug, Clone, thiserror::Error)]
pub enum FactorError {
    #[error("{0}")]
    Petsc(#[from] PetscError),
    #[error(
        "MUMPS ran out of workspace factoring the {what} (INFOG(1) = {infog1}) even after {retries} retries up to ICNTL(14) = {last_percent} %; \
         its analysis estimated {estimate_mb_max} MB on the largest rank ({estimate_mb_sum} MB in all). \
         Set a larger percentage with the PETSc option -mat_mumps_icntl_14 (after --), or use a coarser mesh"
    )]
    Workspace {
        what: String,
        infog1: i32,
        retries: usize,
        last_percent: i32,
        estimate_mb_max: i32,
        estimate_mb_sum: i32,
    },
    #[error(
        "MUMPS could not allocate memory factoring the {what} (INFOG(1) = -13): it asked for about {requested_mb:.0} MB on one rank (entries of 8 bytes), \
         with an estimate of {estimate_mb_max} MB on the largest rank ({estimate_mb_sum} MB in all). \
         Use fewer ranks per machine, a coarser mesh, or MUMPS's block low-rank factorisation (-mat_mumps_icntl_35 1)"
    )]
    Allocation {
        what: String,
        requested_mb: f64,
        estimate_mb_max: i32,
        estimate_mb_sum: i32,
    },
    #[error(
        "MUMPS's working memory cap ICNTL(23) is too small for the {what} (INFOG(1) = -19; estimate {estimate_mb_max} MB on the largest rank): \
         raise or remove -mat_mumps_icntl_23"
    )]
    MemoryCap { what: String, estimate_mb_max: i32 },
    #[error("the {what} is numerically singular (MUMPS INFOG(1) = -10)")]
    Singular { what: String },
    #[error("MUMPS failed factoring the {what}: INFOG(1) = {infog1}, INFOG(2) = {infog2} (see the MUMPS users' guide, section on error diagnostics)")]
    Mumps {
        what: String,
        infog1: i32,
        infog2: i32,
    },
}

impl FactorError {
    /// The error for a factorisation that ended with `status` and will not be retried.
    pub fn from_status(what: &str, status: &MumpsStatus, log: &FactorLog) -> FactorError {
        let what = what.to_string();
        match status.failure() {
            Some(MumpsFailure::Workspace) => FactorError::Workspace {
                what,
                infog1: status.infog1,
                retries: log.retries(),
                last_percent: status.icntl14,
                estimate_mb_max: status.estimate_mb_max,
                estimate_mb_sum: status.estimate_mb_sum,
            },
            Some(MumpsFailure::Allocation) => FactorError::Allocation {
                what,
                requested_mb: allocation_mb(status.infog2),
                estimate_mb_max: status.estimate_mb_max,
                estimate_mb_sum: status.estimate_mb_sum,
            },
            Some(MumpsFailure::MemoryCap) => FactorError::MemoryCap {
                what,
                estimate_mb_max: status.estimate_mb_max,
            },
            Some(MumpsFailure::Singular) => FactorError::Singular { what },
            _ => FactorError::Mumps {
                what,
                infog1: status.infog1,
                infog2: status.infog2,
            },
        }
    }
}

impl From<FactorError> for PetscError {
    fn from(e: FactorError) -> PetscError {
        match e {
            FactorError::Petsc(p) => p,
            other => PetscError::other(other.to_string()),
        }
    }
}

/// MUMPS's INFOG(1) and INFO(2) as PETSc's error text quotes them ("INFOG(1)=-9, INFO(2)=68907"),
/// for failures inside SLEPc whose factor we cannot reach.
pub fn mumps_code_in(error: &PetscError) -> Option<(i32, i32)> {
    let text = &error.message;
    let number_after = |key: &str| -> Option<i32> {
        let start = text.find(key)? + key.len();
        let digits: String = text[start..]
            .chars()
            .take_while(|c| c.is_ascii_digit() || *c == '-')
            .collect();
        digits.parse().ok()
    };
    let infog1 = number_after("INFOG(1)=")?;
    Some((infog1, number_after("INFO(2)=").unwrap_or(0)))
}

/// Right-hand sides per multiple-right-hand-side solve of a [`FactorUse::Solve`] factor, and
/// MUMPS's blocking of them (ICNTL(27); a user's `-mat_mumps_icntl_27` still wins): the
/// attachment solves of the diagnosis's loaded line match come in chunks of this many columns
/// (`eigen::reduced`). One pass over the factor per chunk instead of six (MUMPS's default
/// blocks 32): on the 37.6k-DOF glass tube of generator 2's seed 431 case 010, 2 ranks, the
/// 40 chunks' MatMatSolve took 33.5 s against 40.1 s.
pub const SOLVE_RHS_BLOCK: usize = 192;

/// What the factor is for: a solve, or a solve and an exact inertia.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FactorUse {
    Solve,
    Inertia,
}

/// A symmetric matrix factored by MUMPS (LDLᵀ), made through the one factor path: user options,
/// the run's learned workspace, and the workspace retries. Collective.
pub struct MumpsCholesky<'p> {
    raw: sys::Mat,
    status: MumpsStatus,
    log: FactorLog,
    _runtime: std::marker::PhantomData<&'p Petsc>,
}

impl<'p> MumpsCholesky<'p> {
    /// Factors the symmetric matrix `a` (`what` names it in messages). With
    /// [`FactorUse::Inertia`] the factor is set up so that its inertia can be read (ICNTL(13) = 1,
    /// ICNTL(24) = 1). `a` need not outlive the factor.
    pub fn factor(
        petsc: &'p Petsc,
        a: &Mat<'p>,
        usage: FactorUse,
        what: &str,
    ) -> std::result::Result<Self, FactorError> {
        let mut log = FactorLog::default();
        let mut fault = injected_workspace_fault(petsc, what)?;
        let mut percent = learned_workspace_percent();
        loop {
            let mut raw: sys::Mat = std::ptr::null_mut();
            // SAFETY: creates a new factor matrix that this function or `Self` destroys.
            unsafe {
                check(
                    sys::MatGetFactor(
                        a.raw(),
                        sys::MATSOLVERMUMPS.as_ptr() as _,
                        sys::MatFactorType_MAT_FACTOR_CHOLESKY,
                        &mut raw,
                    ),
                    "MatGetFactor(MUMPS)",
                )?
            };
            // Owned from here on, so that every way out of this attempt destroys it.
            let mut factor = MumpsCholesky {
                raw,
                status: MumpsStatus::default(),
                log: FactorLog::default(),
                _runtime: std::marker::PhantomData,
            };
            // SAFETY: `raw` is a MUMPS factor of `a`; the calls set controls and factor.
            let numeric = unsafe {
                // A failed factorisation is read from MUMPS's status below, not raised.
                check(
                    sys::MatSetErrorIfFailure(a.raw(), sys::PetscBool_PETSC_FALSE),
                    "MatSetErrorIfFailure",
                )?;
                if usage == FactorUse::Solve {
                    // One pass over the factor per chunk of right-hand sides, where MUMPS's
                    // default blocks 32 columns a pass ([`SOLVE_RHS_BLOCK`]).
                    check(
                        sys::MatMumpsSetIcntl(raw, 27, SOLVE_RHS_BLOCK as sys::PetscInt),
                        "MatMumpsSetIcntl(27)",
                    )?;
                }
                if usage == FactorUse::Inertia {
                    // Values set before MUMPS starts; the options database may still change them,
                    // which `inertia` checks.
                    check(sys::MatMumpsSetIcntl(raw, 13, 1), "MatMumpsSetIcntl(13)")?;
                    check(sys::MatMumpsSetIcntl(raw, 24, 1), "MatMumpsSetIcntl(24)")?;
                }
                let mut info: sys::MatFactorInfo = std::mem::zeroed();
                check(
                    sys::MatFactorInfoInitialize(&mut info),
                    "MatFactorInfoInitialize",
                )?;
                // The analysis reads the user's -mat_mumps_* options; a retry's workspace is set
                // after it so that it wins over a user's ICNTL(14) that proved too small.
                check(
                    sys::MatCholeskyFactorSymbolic(raw, a.raw(), std::ptr::null_mut(), &info),
                    "MatCholeskyFactorSymbolic(MUMPS)",
                )?;
                if let Some(p) = percent {
                    let mut current: sys::PetscInt = 0;
                    check(
                        sys::MatMumpsGetIcntl(raw, 14, &mut current),
                        "MatMumpsGetIcntl(14)",
                    )?;
                    if p > current {
                        check(sys::MatMumpsSetIcntl(raw, 14, p), "MatMumpsSetIcntl(14)")?;
                    }
                }
                check(
                    sys::MatCholeskyFactorNumeric(raw, a.raw(), &info),
                    "MatCholeskyFactorNumeric(MUMPS)",
                )
            };
            let mut status = MumpsStatus::read(raw)?;
            if fault && status.infog1 == 0 {
                // The testing hook below: this attempt is reported as run short of workspace.
                fault = false;
                status.infog1 = -9;
                status.infog2 = 1;
            }
            // An error raised by PETSc despite the flag above still carries MUMPS's status.
            if let Err(e) = numeric {
                if status.infog1 >= 0 {
                    return Err(e.into());
                }
            }
            log.record(status.icntl14, status.infog1, status.infog2);
            match status.failure() {
                None => {
                    if log.retries() > 0 {
                        learn_workspace_percent(status.icntl14);
                    }
                    factor.status = status;
                    factor.log = log;
                    return Ok(factor);
                }
                Some(MumpsFailure::Workspace) if log.retries() < MAX_WORKSPACE_RETRIES => {
                    percent = Some(next_workspace_percent(status.icntl14));
                }
                Some(_) => return Err(FactorError::from_status(what, &status, &log)),
            }
        }
    }

    pub fn status(&self) -> &MumpsStatus {
        &self.status
    }

    pub fn log(&self) -> &FactorLog {
        &self.log
    }

    /// x = A⁻¹ b.
    pub fn solve(&self, b: &Vector<'p>, x: &mut Vector<'p>) -> Result<()> {
        // SAFETY: vectors with the operator's layout; PETSc checks the sizes.
        unsafe { check(sys::MatSolve(self.raw, b.raw(), x.raw()), "MatSolve(MUMPS)") }
    }

    /// Solves for every column of `b` at once (MUMPS's multiple right-hand sides: the factor
    /// is read once per block of columns instead of once per column). Collective.
    pub fn solve_many(&self, b: &super::Dense<'p>, x: &mut super::Dense<'p>) -> Result<()> {
        // SAFETY: dense matrices with the operator's row layout and equal column counts; PETSc
        // checks the sizes.
        unsafe {
            check(
                sys::MatMatSolve(self.raw, b.raw(), x.raw()),
                "MatMatSolve(MUMPS)",
            )
        }
    }

    /// The Sylvester inertia of the factored matrix, refused unless MUMPS's count is exact on this
    /// many ranks (module docs: ICNTL(13) = 1 and ICNTL(24) = 1 in force). Null pivots are
    /// returned as `zero`; their sign is undetermined, so a caller proving a count treats
    /// `zero > 0` as inconclusive.
    pub fn inertia(&self, petsc: &Petsc) -> Result<Inertia> {
        if petsc.size() > 1 && (self.status.icntl13 != 1 || self.status.icntl24 != 1) {
            return Err(PetscError::other(format!(
                "MUMPS cannot count the inertia exactly with ICNTL(13) = {} and ICNTL(24) = {} on {} ranks (both must be 1); remove the -mat_mumps_icntl_13/24 options",
                self.status.icntl13,
                self.status.icntl24,
                petsc.size()
            )));
        }
        let (mut neg, mut zero, mut pos) = (0, 0, 0);
        // SAFETY: query of a successful factorisation.
        unsafe {
            check(
                sys::MatGetInertia(self.raw, &mut neg, &mut zero, &mut pos),
                "MatGetInertia",
            )?
        };
        Ok(Inertia {
            negative: neg as usize,
            zero: zero as usize,
            positive: pos as usize,
        })
    }
}

impl Drop for MumpsCholesky<'_> {
    fn drop(&mut self) {
        // SAFETY: we own the factor matrix.
        unsafe {
            sys::MatDestroy(&mut self.raw);
        }
    }
}

/// Sylvester inertia of a symmetric matrix: how many eigenvalues are negative, zero and positive.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Inertia {
    pub negative: usize,
    pub zero: usize,
    pub positive: usize,
}

/// Copies every MUMPS control the user gave in one spelling (`-mat_mumps_…` or
/// `-st_mat_mumps_…`) to the other, so that one option reaches every factorisation (module docs).
pub fn share_mumps_options(petsc: &Petsc) -> Result<()> {
    let names = (1..=40)
        .map(|i| format!("mat_mumps_icntl_{i}"))
        .chain((1..=7).map(|i| format!("mat_mumps_cntl_{i}")))
        .chain(["mat_mumps_ooc_tmpdir".to_string()]);
    for name in names {
        let (plain, st) = (format!("-{name}"), format!("-st_{name}"));
        match (petsc.option_value(&plain)?, petsc.option_value(&st)?) {
            (Some(v), None) => petsc.set_option(&st, &v)?,
            (None, Some(v)) => petsc.set_option(&plain, &v)?,
            _ => {}
        }
    }
    Ok(())
}

/// Sets a PETSc option for the life of the guard and restores what was there before.
pub struct ScopedOption<'p> {
    petsc: &'p Petsc,
    name: String,
    previous: Option<String>,
}

impl<'p> ScopedOption<'p> {
    pub fn set(petsc: &'p Petsc, name: &str, value: &str) -> Result<Self> {
        let previous = petsc.option_value(name)?;
        petsc.set_option(name, value)?;
        Ok(ScopedOption {
            petsc,
            name: name.to_string(),
            previous,
        })
    }
}

impl Drop for ScopedOption<'_> {
    fn drop(&mut self) {
        let _ = match &self.previous {
            Some(v) => self.petsc.set_option(&self.name, v),
            None => self.petsc.clear_option(&self.name),
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn workspace_errors_are_told_from_the_others() {
        for code in [-8, -9, -11, -12, -14, -17, -20] {
            assert_eq!(
                MumpsFailure::of(code),
                Some(MumpsFailure::Workspace),
                "{code}"
            );
        }
        assert_eq!(MumpsFailure::of(-13), Some(MumpsFailure::Allocation));
        assert_eq!(MumpsFailure::of(-19), Some(MumpsFailure::MemoryCap));
        assert_eq!(MumpsFailure::of(-10), Some(MumpsFailure::Singular));
        assert_eq!(MumpsFailure::of(-6), Some(MumpsFailure::Other));
        assert_eq!(MumpsFailure::of(0), None);
        assert_eq!(MumpsFailure::of(2), None, "a warning is no failure");
    }

    #[test]
    fn the_workspace_ladder_doubles_from_sixty() {
        assert_eq!(next_workspace_percent(0), 60);
        assert_eq!(next_workspace_percent(20), 60);
        assert_eq!(next_workspace_percent(60), 120);
        assert_eq!(next_workspace_percent(240), 480);
    }

    #[test]
    fn allocation_sizes_read_both_units() {
        assert!((allocation_mb(1_000_000) - 8.0).abs() < 1e-12);
        assert!(
            (allocation_mb(-3) - 24.0).abs() < 1e-12,
            "negative: millions of entries"
        );
    }

    #[test]
    fn petsc_messages_give_up_their_mumps_codes() {
        let e = PetscError {
            code: 76,
            call: "EPSSolve".into(),
            message: "Error reported by MUMPS in numerical factorization phase: INFOG(1)=-9, INFO(2)=68907 [in MatFactorNumeric_MUMPS()]".into(),
        };
        assert_eq!(mumps_code_in(&e), Some((-9, 68907)));
        let analysis = PetscError {
            code: 76,
            call: "EPSSolve".into(),
            message: "Error reported by MUMPS in analysis phase: INFOG(1)=-6".into(),
        };
        assert_eq!(mumps_code_in(&analysis), Some((-6, 0)));
        assert_eq!(mumps_code_in(&PetscError::other("no MUMPS here")), None);
    }

    #[test]
    fn the_log_tells_retries_from_new_factorisations() {
        let a = |retry, icntl14, infog1| FactorAttempt {
            retry,
            icntl14,
            infog1,
            infog2: 0,
        };
        let log = FactorLog {
            attempts: vec![a(false, 20, -9), a(true, 60, 0), a(false, 60, 0)],
        };
        assert_eq!(log.retries(), 1);
        assert_eq!(log.describe(), "20%:-9 60%:ok, 60%:ok");
        let notes = log.retry_notes("test matrix");
        assert_eq!(notes.len(), 1, "{notes:?}");
        assert!(
            notes[0].contains("INFOG(1) = -9") && notes[0].contains("ICNTL(14) = 60 %"),
            "{}",
            notes[0]
        );
    }

    #[test]
    fn a_give_up_names_the_option_and_the_memory() {
        let status = MumpsStatus {
            infog1: -9,
            icntl14: 960,
            estimate_mb_max: 1234,
            estimate_mb_sum: 2400,
            ..MumpsStatus::default()
        };
        let text = FactorError::from_status("shift-invert matrix", &status, &FactorLog::default())
            .to_string();
        assert!(
            text.contains("-mat_mumps_icntl_14")
                && text.contains("1234 MB")
                && text.contains("960 %"),
            "{text}"
        );
        let status = MumpsStatus {
            infog1: -13,
            infog2: -5,
            ..MumpsStatus::default()
        };
        let text =
            FactorError::from_status("inertia matrix", &status, &FactorLog::default()).to_string();
        assert!(text.contains("40 MB") && text.contains("-13"), "{text}");
    }
}
