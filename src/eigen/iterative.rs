//! The iterative eigen path: no factor of K − σM is ever formed.
//!
//! **Why.** Shift-invert needs a sparse Cholesky factor, and on a solid 3-D body its fill grows
//! much faster than the matrix (a free sphere of 165k P2 DOF: 4.3 GB and 300 s on 2 ranks with
//! MUMPS, against 1.5 s to assemble). The matrices themselves grow linearly, so a solver that
//! only multiplies by K and M and applies a preconditioner scales to meshes whose factor would
//! not fit.
//!
//! **What.** SLEPc's generalised Davidson (GD) for the smallest eigenvalues of K φ = λ M φ in
//! the M-orthogonal complement of the six rigid motions (handed over as the deflation space,
//! [`super::rigid_body_vectors`]), each new search direction preconditioned by one multigrid
//! cycle: on a P2 mesh by default the P2 → P1 p-multigrid ("Preconditioners" below), otherwise
//! one V-cycle of PETSc's smoothed-aggregation algebraic multigrid (GAMG) on
//!
//! ```text
//!   P = K − σ M      (σ < 0, the same default shift as the direct path: P is positive definite)
//! ```
//!
//! with the rigid motions as P's near-null space, which is what makes aggregation multigrid work
//! for elasticity (its coarse spaces then reproduce rotations, not only translations). P is built
//! here, not by SLEPc, because the near-null space must be attached to the matrix the multigrid
//! sees. The aggregation is plain (`-st_pc_gamg_agg_nsmooths 0`): on the 34,716-DOF sphere,
//! smoothing the prolongator once (PETSc's default) took the same 66 s but twice the
//! multigrid's memory (140 MB against 65 MB), and that memory decides how large a mesh fits.
//!
//! **Preconditioners** ([`IterativePreconditioner`], `--preconditioner`, config `[solver]
//! preconditioner`). `auto` (the default) is `pmg` on a P2 mesh and `gamg` on a P1 one. `gamg` is
//! the V-cycle above. `pmg` and `pmg-mumps` are a two-level p-multigrid ([`super::pmg`],
//! [`crate::petsc::multigrid`]): the fine level is P itself, smoothed by [`PMG_SMOOTHING_STEPS`]
//! Chebyshev–Jacobi steps before and after the coarse correction; the coarse level is the P1
//! field on the mesh's vertices, interpolated into P2 by Π (vertex nodes copy their vertex,
//! mid-edge nodes average the edge's two ends), with the Galerkin operator A_c = Πᵀ P Π. `pmg`
//! solves A_c by conjugate gradients preconditioned with GAMG (the rigid motions at the vertices
//! as its near-null space) to a relative residual of 10⁻² ([`crate::petsc::multigrid::COARSE_RTOL`]),
//! `pmg-mumps` by a MUMPS Cholesky factor (A_c is positive definite, and about an eighth of P's
//! size). The smoother is a fixed polynomial in D⁻¹P; the CG coarse solve is not a fixed linear
//! map (it stops on a residual), which GD tolerates: it adds each preconditioned residual to its
//! search space and takes the pairs by Rayleigh–Ritz there, so the preconditioner decides only
//! how good each new direction is, not which pairs come out.
//!
//! Measured on free spheres (ceramic, 20 modes, 2 ranks, the machine otherwise idle), GD
//! iterations as `--timings-json` counts them, solve seconds, peak RSS summed over the ranks:
//!
//! | DOF | gamg | pmg, one GAMG V-cycle on the P1 level | pmg (CG to 10⁻² on the P1 level) | pmg-mumps |
//! |---|---|---|---|---|
//! | 34,716 | 1,805 (30.6 s) | 1,026 (18.9 s) | 462 (9.8 s) | 462 (10.5 s) |
//! | 164,955 | 2,016 (166.5 s, 1.11 GB) | – | 426 (45.6 s, 0.92 GB) | 413 (50 s, 1.24 GB) |
//! | 1,001,565 | – | – | 334 (310 s, 6.1 GB with P formed) | – |
//! | 3,100,218 | – | – | 326 (1,140 s, 15.6 GB; 331 and 18.8 GB with P formed) | – |
//!
//! The one-V-cycle coarse solve was `pmg` until 2026-12-04; it is the weak part of that cycle
//! (GD needs twice the iterations), and CG to 10⁻² on the P1 level does as well as the exact
//! factor (10⁻¹: 504 iterations, 10⁻³: 468, at 34,716 DOF) without the factor's memory, which at
//! 1.07M DOF was 4.3 GB of `pmg-mumps`' 9.3 GB. Against MUMPS the eigenvalues agree to the
//! path's tolerance (`tests/solver_iterative.rs`: < 10⁻⁸ relative).
//!
//! Why GD and not LOBPCG, measured on a free sphere of 34,716 P2 DOF on 2 ranks (20 modes, the
//! direct path 27 s): GD 71 s; SLEPc's LOBPCG converged 13 of the 20 in its first 242
//! iterations and then stalled past 300 s, with block size 8 too; GD with blocks of 4 took
//! over 200 s; Jacobi–Davidson with 10 GMRES steps 95 s. `-eps_type` after `--` chooses another.
//!
//! **Tolerance.** The residual ‖Kx − λMx‖ is formed in floating point, where it cannot fall
//! much below ε·‖K‖‖x‖; relative to λ‖Mx‖ that floor is ε·λ_max/λ, 10⁻⁹–10⁻⁸ on a fine P2 mesh.
//! The default tolerance of this path is therefore [`ITERATIVE_TOLERANCE`] = 10⁻⁸ on the relative
//! residual, not the direct path's 10⁻¹⁰ on the transformed problem. The eigenvalue error is
//! quadratic in the residual (≲ ‖r‖²/gap), so 10⁻⁸ still gives eigenvalues to ~10⁻¹⁴ relative
//! wherever the modes are separated by more than ~10⁻²; within a near-degenerate cluster each
//! eigenvalue is still within ‖r‖ of the cluster (Bauer–Fike for the pencil).
//!
//! **Completeness without a factor (weaker than the inertia proof).** Sylvester's law needs a
//! factorisation, which this path exists to avoid. What it does instead: after the solve, a
//! *probe* runs the same preconditioned solver for the lowest eigenvalue of the M-orthogonal
//! complement of everything returned (rigid motions and all elastic modes kept), from a random
//! start. If no mode below the last kept one λ_N was missed, the lowest eigenvalue of that
//! complement is λ_{N+1} ≥ λ_N; a probe that converges below λ_N·(1 − 10·tol) has found a missed
//! mode, and the solve is repeated with more vectors. The probe is not a proof: it can converge
//! to an eigenvalue above a missed one if its random start has almost no component along the
//! missed mode (for a random start in n ≥ 10⁵ dimensions the chance is negligible, but it is not
//! zero), and it cannot say anything about modes GD has not converged to. The verdict is
//! reported as `consistent` (never `complete`), with the probe's eigenvalue, so a reader can tell
//! the two paths' guarantees apart.
//!
//! **Memory.** Per rank: K and M (one AIJ matrix each, block size 3); for `gamg` also P and its
//! multigrid hierarchy (the coarse operators, together about a third of P on 3-D elasticity); for
//! the p-multigrid Π (about 6 nonzeros per fine row), the coarse operator (an eighth of the rows,
//! about half the nonzeros per row) and its GAMG hierarchy, but no P: its smoother works on K
//! ([`Preconditioner`]); and GD's search basis (up to `ncv` vectors). On the 164,955-DOF sphere
//! the p-multigrid's peak was 0.92 GB summed over 2 ranks with K on the fine level, 1.08 GB with
//! P formed (426 and 425 GD iterations).

use super::pmg::TwoLevel;
use super::{collect, RawPairs, SolveFailure};
use crate::petsc::multigrid::{self, CoarseSolve};
use crate::petsc::{self, Eps, EpsWhich, Mat, NonzeroPattern, Petsc, Vector};

/// Default relative residual tolerance of the iterative path (module docs, "Tolerance").
pub const ITERATIVE_TOLERANCE: f64 = 1e-8;

/// The preconditioner GD applies to each new direction (module docs, "Preconditioners").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum IterativePreconditioner {
    /// The p-multigrid with the CG coarse solve where the mesh's P1 → P2 interpolation is given
    /// (a P2 mesh), GAMG otherwise.
    #[default]
    Auto,
    /// One V-cycle of GAMG (plain aggregation) on P = K − σM.
    Gamg,
    /// One V-cycle of the two-level P2 → P1 multigrid ([`super::pmg`]) with this coarse solve.
    PMultigrid(CoarseSolve),
}

impl IterativePreconditioner {
    pub fn word(self) -> &'static str {
        match self {
            IterativePreconditioner::Auto => "auto",
            IterativePreconditioner::Gamg => "gamg",
            IterativePreconditioner::PMultigrid(CoarseSolve::GamgCg) => "pmg",
            IterativePreconditioner::PMultigrid(CoarseSolve::MumpsCholesky) => "pmg-mumps",
        }
    }
}

impl IterativePreconditioner {
    /// `Auto` made concrete: the p-multigrid with the CG coarse solve when a coarse space is
    /// given, GAMG otherwise; the other choices stay.
    pub fn resolve(self, have_coarse_space: bool) -> Self {
        match self {
            IterativePreconditioner::Auto if have_coarse_space => {
                IterativePreconditioner::PMultigrid(CoarseSolve::GamgCg)
            }
            IterativePreconditioner::Auto => IterativePreconditioner::Gamg,
            p => p,
        }
    }
}

impl std::str::FromStr for IterativePreconditioner {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "auto" => Ok(IterativePreconditioner::Auto),
            "gamg" => Ok(IterativePreconditioner::Gamg),
            "pmg" => Ok(IterativePreconditioner::PMultigrid(CoarseSolve::GamgCg)),
            "pmg-mumps" => Ok(IterativePreconditioner::PMultigrid(
                CoarseSolve::MumpsCholesky,
            )),
            other => Err(format!(
                "unknown iterative preconditioner {other:?}: use auto, gamg, pmg or pmg-mumps"
            )),
        }
    }
}

/// Chebyshev–Jacobi steps before and after the p-multigrid's coarse correction
/// (`-st_mg_levels_ksp_max_it` overrides).
pub const PMG_SMOOTHING_STEPS: usize = 2;

/// What GD's preconditioner is built from. For GAMG: P = K − σM with the rigid motions as its
/// near-null space. For the p-multigrid: the interpolation and the coarse operator
/// A_c = Πᵀ (K − σM) Π, while the fine level's smoother works on K itself (`matrix` is `None`):
/// a smoother only damps the high-frequency error, where σM (σ ≈ −10⁻²·μ/(ρL²)) is some 10⁻⁶ of
/// K, and the rigid motions that make K singular are the coarse level's and GD's deflation's
/// business. Not forming P saves one fine matrix, a third of the memory of K and M together
/// (3.2 GB at 3.1M DOF).
pub(super) struct Preconditioner<'p, 'a> {
    matrix: Option<Mat<'p>>,
    two_level: Option<CoarseLevel<'p, 'a>>,
    /// Seconds spent forming the coarse operator (counted in the set-up time).
    build_seconds: f64,
}

struct CoarseLevel<'p, 'a> {
    interpolation: &'a Mat<'p>,
    operator: Mat<'p>,
    solve: CoarseSolve,
}

impl<'p> Preconditioner<'p, '_> {
    pub(super) fn word(&self) -> &'static str {
        match &self.two_level {
            None => IterativePreconditioner::Gamg.word(),
            Some(c) => IterativePreconditioner::PMultigrid(c.solve).word(),
        }
    }

    /// The fine-level matrix the preconditioner works on: P, or K itself for the p-multigrid.
    fn fine<'m>(&'m self, k: &'m Mat<'p>) -> &'m Mat<'p> {
        self.matrix.as_ref().unwrap_or(k)
    }
}

/// GAMG's preconditioning matrix P = K − σM with the rigid motions as its near-null space, or
/// for the p-multigrid the coarse operator Πᵀ (K − σM) Π, formed as Πᵀ K Π − σ Πᵀ M Π on the
/// coarse level, with the coarse rigid motions as its near-null space.
pub(super) fn preconditioner<'p, 'a>(
    petsc: &'p Petsc,
    k: &Mat<'p>,
    m: &Mat<'p>,
    shift: f64,
    rigid: &[Vector<'p>],
    choice: IterativePreconditioner,
    two_level: Option<&'a TwoLevel<'p>>,
) -> Result<Preconditioner<'p, 'a>, super::EigenError> {
    let t0 = std::time::Instant::now();
    let (matrix, two_level) = match (choice.resolve(two_level.is_some()), two_level) {
        (IterativePreconditioner::Gamg | IterativePreconditioner::Auto, _) => {
            let mut p = k.duplicate()?;
            p.axpy(-shift, m, NonzeroPattern::Same)?;
            p.set_symmetric()?;
            p.set_near_null_space(petsc, rigid)?;
            (Some(p), None)
        }
        (IterativePreconditioner::PMultigrid(solve), Some(t)) => {
            let mut operator = k.ptap(&t.interpolation, 2.0)?;
            {
                let coarse_mass = m.ptap(&t.interpolation, 2.0)?;
                // K and M share one pattern, so their Galerkin products do too.
                operator.axpy(-shift, &coarse_mass, NonzeroPattern::Same)?;
            }
            operator.set_symmetric()?;
            operator.set_near_null_space(petsc, &t.coarse_rigid)?;
            (
                None,
                Some(CoarseLevel {
                    interpolation: &t.interpolation,
                    operator,
                    solve,
                }),
            )
        }
        (IterativePreconditioner::PMultigrid(_), None) => {
            return Err(super::EigenError::BadRequest(
                "the p-multigrid preconditioner needs the mesh's P1 → P2 interpolation (a P2 mesh); use --preconditioner gamg".into(),
            ))
        }
    };
    Ok(Preconditioner {
        matrix,
        two_level,
        build_seconds: t0.elapsed().as_secs_f64(),
    })
}

/// GD for the `nev` smallest eigenpairs of (K, M) in the complement of `deflate`, preconditioned
/// by `precond`; the seconds spent building the multigrid are returned beside the pairs. Every
/// choice can be overridden by options (`-eps_*`, `-st_*`), which are read after these defaults.
#[allow(clippy::too_many_arguments)]
pub(super) fn solve_preconditioned<'p>(
    petsc: &'p Petsc,
    k: &Mat<'p>,
    m: &Mat<'p>,
    precond: &Preconditioner<'p, '_>,
    shift: f64,
    nev: usize,
    tolerance: f64,
    deflate: &[&Vector<'p>],
    progress: &Report<'_>,
) -> Result<RawPairs<'p>, SolveFailure> {
    let mut eps = Eps::new(petsc)?;
    eps.set_operators_ghep(k, m)?;
    eps.set_type(petsc::sys::EPSGD)?;
    eps.set_tolerances(tolerance, Some(MAX_ITERATIONS))?;
    eps.set_which(EpsWhich::SmallestReal)?;
    eps.set_target(shift)?;
    {
        let st = eps.st()?;
        st.set_type(petsc::sys::STPRECOND)?;
        st.set_preconditioner_mat(precond.fine(k))?;
        match &precond.two_level {
            None => {
                st.use_iterative_solver(petsc::sys::KSPPREONLY, petsc::sys::PCGAMG)?;
                st.set_gamg_smoothing_steps(0)?;
            }
            Some(c) => {
                st.use_iterative_solver(petsc::sys::KSPPREONLY, petsc::sys::PCMG)?;
                multigrid::use_two_level(
                    &st,
                    c.interpolation,
                    &c.operator,
                    c.solve,
                    PMG_SMOOTHING_STEPS,
                )?;
            }
        }
    }
    eps.set_dimensions(nev, None, None)?;
    if !deflate.is_empty() {
        eps.set_deflation_space(deflate.iter().copied())?;
    }
    eps.set_from_options()?;
    // Set up first, multigrid included, so that its time is told apart from the iterations'.
    let t0 = std::time::Instant::now();
    eps.set_up()?;
    eps.st()?.set_up_solver()?;
    let setup_seconds = t0.elapsed().as_secs_f64() + precond.build_seconds;
    let setup_rss = petsc.peak_rss_bytes();
    eps.solve_reporting(REPORT_EVERY, &mut |its, converged| {
        (progress.say)(&format!(
            "{}: GD iteration {its}, {} of {nev} pairs converged",
            progress.what,
            converged.min(nev)
        ))
    })?;
    let wanted = eps.dimensions()?.0;
    let mut pairs = collect(&eps, k, m, wanted)?;
    pairs.settings.push((
        "preconditioner_setup_s".into(),
        format!("{setup_seconds:.3}"),
    ));
    pairs
        .settings
        .push(("iterative_preconditioner".into(), precond.word().into()));
    pairs.preconditioner_setup = Some(super::PreconditionerSetup {
        seconds: setup_seconds,
        peak_rss_bytes: setup_rss,
    });
    Ok(pairs)
}

/// Where a long solve says how far it has come: `say` receives a line naming `what` is solved.
pub struct Report<'a> {
    pub what: &'a str,
    pub say: &'a dyn Fn(&str),
}

/// A progress line from a running solve at most this often.
const REPORT_EVERY: std::time::Duration = std::time::Duration::from_secs(30);

/// GD's iteration cap (one preconditioned direction per iteration): the free sphere of 35k DOF
/// took 1,158 for 20 modes at 10⁻⁸; a solve that needs more is reported as not converged.
const MAX_ITERATIONS: usize = 20_000;

/// The probe of the complement (module docs, "Completeness without a factor").
#[derive(Clone, Debug)]
pub struct ProbeCheck {
    /// The last kept elastic eigenvalue λ_N [rad²/s²].
    pub last_kept: f64,
    /// The lowest eigenvalue the probe found in the complement of every returned pair, or None
    /// when the probe did not converge.
    pub lowest_in_complement: Option<f64>,
    /// Vectors the probe was orthogonal to (rigid + elastic).
    pub complement_of: usize,
    pub verdict: ProbeVerdict,
    pub seconds: f64,
}

#[derive(Clone, Debug, PartialEq)]
pub enum ProbeVerdict {
    /// The complement's lowest eigenvalue lies at or above λ_N: nothing below was seen missing.
    Consistent,
    /// The complement holds an eigenvalue below λ_N: a mode was missed.
    Missed,
    /// The probe did not converge; the text says why.
    Inconclusive(String),
}

impl ProbeVerdict {
    pub fn word(&self) -> &'static str {
        match self {
            ProbeVerdict::Consistent => "consistent",
            ProbeVerdict::Missed => "missed",
            ProbeVerdict::Inconclusive(_) => "inconclusive",
        }
    }
}

/// Runs the probe: the lowest eigenpair of (K, M) M-orthogonal to `rigid` and `kept`.
#[allow(clippy::too_many_arguments)]
pub(super) fn probe<'p>(
    petsc: &'p Petsc,
    k: &Mat<'p>,
    m: &Mat<'p>,
    precond: &Preconditioner<'p, '_>,
    shift: f64,
    tolerance: f64,
    rigid: &[Vector<'p>],
    kept: &[Vector<'p>],
    last_kept: f64,
    say: &dyn Fn(&str),
) -> Result<ProbeCheck, SolveFailure> {
    let t0 = std::time::Instant::now();
    // The deflation space is handed over by reference: no copy of the returned vectors.
    let space: Vec<&Vector<'p>> = rigid.iter().chain(kept).collect();
    // One eigenpair, to a looser tolerance: the probe needs its eigenvalue to ~10⁻⁶, which a
    // residual of 10⁻⁴ gives (quadratic error).
    let probe_tol = (tolerance * 1e4).min(1e-4);
    let report = Report {
        what: "completeness probe",
        say,
    };
    let outcome = solve_preconditioned(petsc, k, m, precond, shift, 1, probe_tol, &space, &report);
    let (lowest, verdict) = match outcome {
        Ok(pairs) => match pairs.values.iter().copied().reduce(f64::min) {
            Some(l) if l < last_kept * (1.0 - 10.0 * tolerance.max(1e-10)) => {
                (Some(l), ProbeVerdict::Missed)
            }
            Some(l) => (Some(l), ProbeVerdict::Consistent),
            None => (
                None,
                ProbeVerdict::Inconclusive("the probe converged to no eigenpair".into()),
            ),
        },
        Err(SolveFailure::Other(super::EigenError::NotConverged { .. })) => (
            None,
            ProbeVerdict::Inconclusive(format!(
                "the probe did not converge in {MAX_ITERATIONS} iterations"
            )),
        ),
        Err(e) => return Err(e),
    };
    Ok(ProbeCheck {
        last_kept,
        lowest_in_complement: lowest,
        complement_of: space.len(),
        verdict,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auto_takes_the_p_multigrid_only_where_a_coarse_space_exists() {
        let auto: IterativePreconditioner = "auto".parse().unwrap();
        assert_eq!(auto, IterativePreconditioner::default());
        assert_eq!(
            auto.resolve(true),
            IterativePreconditioner::PMultigrid(CoarseSolve::GamgCg)
        );
        assert_eq!(auto.resolve(true).word(), "pmg");
        assert_eq!(auto.resolve(false), IterativePreconditioner::Gamg);
        // A named choice is kept whether or not a coarse space exists (the solve refuses the
        // p-multigrid without one, with the reason).
        for word in ["gamg", "pmg", "pmg-mumps"] {
            let p: IterativePreconditioner = word.parse().unwrap();
            assert_eq!(p.resolve(false), p);
            assert_eq!(p.resolve(true), p);
            assert_eq!(p.word(), word);
        }
        let err = "amg".parse::<IterativePreconditioner>().unwrap_err();
        assert!(err.contains("auto, gamg, pmg or pmg-mumps"), "{err}");
    }
}
