//! The line-spectrum match with a candidate added mass: E, ν, mass m and its site together.
//!
//! A mass attached to the object (a label, a glue spot, a weight) lowers the modes that move
//! where it sits, and on a symmetric object it splits every degenerate pair: the member with an
//! antinode at the mass falls, the one with a node there stays. The plain line-spectrum match
//! ([`super::material::line_spectrum_start`]) can only scale and re-shape the unloaded pattern
//! with E and ν, so a few per cent of mass pulls ν far off (the blind diagnosis benchmark:
//! ν 0.40 for a true 0.35, 0.17 for 0.155, match distance ~10⁻² against ~10⁻⁵ on clean cases),
//! and everything matched downstream is then wrong.
//!
//! Here the mass is part of the model. With the unloaded modes of the reduced basis at ν
//! (θ_k for E/ρ = 1, mass-normalised shapes φ_k for ρ = 1) as a Ritz basis, a lumped mass
//! m_v [kg] on each of the |R| surface vertices of a region R adds Σ_{v∈R} m_v P_v to the mass
//! matrix ρM₁, so in modal coordinates x = Φy
//!
//! (E/ρ) diag(θ) y = ω² (I + α G_R) y,   G_R = Σ_{v∈R} Φ_vᵀΦ_v,   α = m_v/ρ [m³]
//!
//! (Φ_v the 3 × n values of the modes at vertex v). Its eigenvalues θ'_k (with E/ρ = 1) give
//! the loaded frequencies ln f'_k = ½ ln θ'_k + ½ ln(E/ρ) − ln 2π, and the loaded drive at the
//! strike is (Σ_j y_jk s_j)² with s_j = φ_j(x_s)·n.
//!
//! **The Ritz basis.** Two things the band's modes alone get wrong, both measured on the bowl
//! (set2 case 012 of the diagnosis benchmark, 9.6 % of the body's mass on three vertices,
//! against the full solve with that mass):
//! * *Rigid recoil.* A mass moves the body's centre of mass, so each loaded elastic mode
//!   carries some rigid motion. Elastic modes alone forbid it, which is a constraint and no
//!   Ritz bound: the first loaded mode came out 1157 Hz against the full 1203.5 Hz. The
//!   basis therefore holds the six rigid motions R (M₁-orthonormal, K R = 0); their loaded
//!   values are 0 and are dropped.
//! * *Local flexibility.* The band's modes lack the deformation right under a concentrated
//!   mass: with R, the modes alone gave 3048 Hz for 2870, 8723 for 7457 (+17 %). The
//!   [`Enrichment`] adds the region's attachment vectors, static responses to unit loads there
//!   and their next Krylov terms (two blocks of three): errors 0.05 % at the first mode,
//!   ≤ 0.7 % to 7.5 kHz, ≤ 1.2 % at 10 kHz.
//!
//! With R (and A) in the basis the loaded Ritz values are upper bounds of the full solve's.
//!
//! **The search** minimises the plain match's distance (mean capped nearest-line distance,
//! both ways: every target line to any partial, every partial that should be heard to a
//! target line; [`super::material::line_spectrum_start`]) over ν, the site, the mass and the scale (E): a
//! coarse pass over ν, a subset of candidate regions and a ladder of mass fractions (0.5–16 %
//! of the body's mass), with E searched in a window around the plain match's; then
//! ([`loaded_line_candidates`]) the best coarse regions at distinct sites, each refined by a
//! fine pass (ν ± 0.01 by 0.001, the regions next to it, the mass ± 15 %). The Ritz model's
//! error grows with the mass and away from the ν of the attachment vectors, and a search over
//! ~10⁵ configurations finds the places where it errs in its favour (case 012: Ritz distance
//! 9.4·10⁻³ at 13.7 % and ν = 0.08, 1.8·10⁻² by the full solve), so the caller checks each
//! candidate with a full solve ([`scale_fit`]) and believes only that (the `diagnose` job:
//! at most half the plain distance).
//!
//! **Re-anchoring.** The coarse pass's attachment vectors are solved at one ν, the plain
//! match's (its *anchor*), and a mass pulls the plain match's ν far off: on case 012 the plain
//! ν is 0.354 against a true 0.188. Away from the anchor the enriched model loses accuracy, the
//! fine pass near the true site settled at ν 0.14 and 0.08 (full-solve distances 1.4·10⁻² and
//! 1.6·10⁻², against 1.9·10⁻² without a mass), and the mass was not carried. With the anchor
//! at the true ν instead, the same search found 10.5 % at ν 0.158, 24 mm from the true site,
//! with a full-solve distance of 4.9·10⁻³, and the catalogue accepted the mass. So after its
//! first fine pass each candidate is refined again, up to `reanchor_rounds` times, with the
//! attachment vectors solved at the ν it reached (rounded to `anchor_step`), over ν ±
//! `reanchor_window`; a round's best is judged by that round's model only, since a model
//! anchored elsewhere is less accurate, not comparable. The rounds stop when ν stays within one
//! anchor step.
//!
//! **Splits against shifts.** A mass splits degenerate pairs, but so does any asymmetry of
//! the object, and the line distance forgives a split by half its width: a model that only
//! splits its pairs where the recording's are split cuts the distance too. What a mass does
//! that no splitting does is move the pairs' centres and the lone modes by its own pattern.
//! [`split_free_fit`] measures that part: both sides' split pairs (neighbours within the
//! catalogue's pair tolerance, `max_pair_split`) merged into one line each, then the same
//! scale search.
//! The `diagnose` job compares the loaded and the plain model on it.
//!
//! **Sharing the work.** The coarse pass and every fine pass are grids over ν whose points are
//! independent, so the processes of a job ([`Share`]) each take every `parts`-th ν step and the
//! results are gathered and combined so that every process ends with the answer one process
//! alone finds, bit for bit: per region (coarse) or per pass (fine) the smallest distance wins
//! and a tie goes to the earlier ν step, as it does in the single loop, where only a strictly
//! smaller distance replaces the best. The attachment vectors a pass needs are asked for by
//! every process, in the single loop's order, before the grid is shared out, because forming
//! them is collective. Measured on the bowl (set-1 case 012, 53.6k DOF): the search part is
//! run once per process instead of in full on every one.

use nalgebra::{DMatrix, DVector, SymmetricEigen};
use std::rc::Rc;

use crate::eigen::reduced::AttachmentProjections;
use crate::numerics::spectral_weights::eigen_with_weights;

#[cfg(test)]
use super::material::capped_nearest;

/// Why the loaded line match could not run.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum LoadedMatchError {
    #[error("the loaded line match needs the target's mode frequencies")]
    NoTargetModes,
    #[error("the loaded line match needs at least one candidate region")]
    NoRegion,
    #[error("density {density}, volume {volume} and E {youngs} must be positive")]
    Scales {
        density: f64,
        volume: f64,
        youngs: f64,
    },
    #[error("the loaded line match found no candidate")]
    NoCandidate,
}
use super::material::{line_distance, LinePattern, AUDIBLE_FRACTION};

/// The unloaded Ritz modes at one ν, as the search needs them.
#[derive(Clone, Debug)]
pub struct ModesAtPoisson {
    /// θ_k for E/ρ = 1 [rad²/s² per Pa·m³/kg], ascending, all > 0.
    pub theta: Vec<f64>,
    /// s_k = φ_k(x_s)·n at the strike (ρ = 1 mass-normalisation).
    pub strike: Vec<f64>,
    /// Mode values at the candidate vertices: row 3i + c is component c at candidate vertex i,
    /// column k mode k (ρ = 1 mass-normalisation).
    pub values: DMatrix<f64>,
    /// For an [`Enrichment`]: the Lamé factors (a(ν), b(ν)) of
    /// [`crate::eigen::reduced::lame_unit`] and the modes' whitened coordinates Z (reduced
    /// dimension × modes). Unused (may be empty) without one.
    pub lame: (f64, f64),
    pub coefficients: DMatrix<f64>,
    /// The six rigid-body motions, M₁-orthonormal (ρ = 1), at the candidate vertices (rows as
    /// `values`) and their drive at the strike; may have no columns. The Ritz basis must hold
    /// them: a mass moves the body's centre of mass, so the loaded elastic modes carry rigid
    /// recoil, and a basis of elastic modes alone forbids it. That is a constraint, not a
    /// Ritz bound on the elastic values: on the bowl a 9.6 % mass on three vertices then came
    /// out 5 % *below* the full solve at the first mode (the recoil raises it).
    pub rigid: DMatrix<f64>,
    pub rigid_strike: Vec<f64>,
}

/// Extra Ritz vectors for one candidate region: the static responses A to unit loads at the
/// region (one per direction), whose local flexibility the band's modes lack. Without them a
/// mass of a few per cent on five vertices shifts the upper modes 1.5–5 % too little (the
/// diagnosis benchmark, against full solves), and the search buys the missing shift with a
/// mass several times too large at the wrong site. With them the Ritz basis is [Φ(ν), A] and
///
/// K_r = [diag θ, Zᵀ(aC_λ + bC_μ); ·, aS_λ + bS_μ],  M_r = [I, ZᵀC_M; ·, S_M] + α U_Rᵀ U_R
///
/// (C_• = Wᵀ Vᵀ K_• A and S_• = Aᵀ K_• A from [`AttachmentProjections`], U_R = [Φ_R, A_R] the
/// values at the region's vertices); the lowest n Ritz values are kept.
#[derive(Clone, Debug)]
pub struct Enrichment {
    pub projections: AttachmentProjections,
    /// Values of the extra vectors at the region's vertices, rows 3i + c in the order of the
    /// region's list (attachments as columns).
    pub region_values: DMatrix<f64>,
    /// Their drive at the strike (weighted as [`ModesAtPoisson::strike`]).
    pub strike: Vec<f64>,
}

/// The reduced loaded problem K y = θ' (M + αG) y for one ν and one region, kept in the
/// eigenbasis of the unloaded pencil so that each mass α costs one symmetric eigenproblem.
///
/// With K V = M V Θ₀ and VᵀMV = I (one Cholesky factorisation and one eigenproblem per region
/// and ν), the loaded problem is Θ₀ ŷ = θ' (I + α Ĝ) ŷ with Ĝ = VᵀGV = WᵀW, W = U_R V, of rank
/// r ≤ 3|R|. Writing Ĝ = Q D Qᵀ (Q orthonormal, from the r × r eigenproblem of WWᵀ),
///
/// S(α) = (I + αĜ)^(−½) = I + Q E Qᵀ,   E = diag((1 + α d_i)^(−½) − 1),
///
/// and θ' are the eigenvalues of C(α) = S Θ₀ S = Θ₀ + B E Qᵀ + Q E Bᵀ + Q (E T E) Qᵀ
/// (B = Θ₀Q, T = QᵀΘ₀Q), formed in O(n²r); for an eigenvector v of C, y = V S v and the drive
/// is sᵀy = (Vᵀs + Q E Qᵀ Vᵀs)·v. The same values as a Cholesky factorisation of M + αG per
/// α (test `loaded_drives_match_a_cholesky_solve_per_mass`), without its triangular solves
/// (12 % of the search's samples on generator 2's seed 41 case 015, the eigenproblems 28 %).
/// Measured: the search a few per cent faster; the attachment solves dominate it.
///
/// Each α needs the eigenvalues of C and the drive's weight on each eigenvector, not the
/// eigenvectors: [`eigen_with_weights`] carries the drive vector through the reduction instead
/// of forming them. Measured on generator 2's seed 47 case 014 (a cup, 933 regions), back to
/// back with the build before it: the Ritz search (the loaded match less its attachment solves
/// and full solves) 98 s → 66 s, the same candidates and distances to the printed digits.
struct RegionProblem {
    /// Θ₀ (ascending) and Vᵀs; empty when M is not positive definite.
    theta: DVector<f64>,
    strike: DVector<f64>,
    /// Q, B = Θ₀Q, T = QᵀΘ₀Q, d and Qᵀ(Vᵀs).
    q: DMatrix<f64>,
    b: DMatrix<f64>,
    t: DMatrix<f64>,
    d: Vec<f64>,
    q_strike: DVector<f64>,
    /// Loaded values below this are rigid-body traces (see `solve`).
    floor: f64,
    /// Ritz values kept (the unloaded basis's count).
    keep: usize,
}

impl RegionProblem {
    /// A problem with no values (M not positive definite): `solve` returns none.
    fn empty(floor: f64, keep: usize) -> Self {
        RegionProblem {
            theta: DVector::zeros(0),
            strike: DVector::zeros(0),
            q: DMatrix::zeros(0, 0),
            b: DMatrix::zeros(0, 0),
            t: DMatrix::zeros(0, 0),
            d: Vec::new(),
            q_strike: DVector::zeros(0),
            floor,
            keep,
        }
    }

    /// The basis [Φ(ν), A, R]: the modes, the region's attachment vectors if given, and the
    /// rigid-body motions (K R = 0; R M₁-orthogonal to Φ and A, M₁-orthonormal). `None` if
    /// the pieces do not fit together.
    fn new(modes: &ModesAtPoisson, region: &[usize], extra: Option<&Enrichment>) -> Option<Self> {
        let n = modes.theta.len();
        let na = extra.map_or(0, |e| e.projections.self_mass.ncols());
        let nr = modes.rigid.ncols();
        if modes.strike.len() != n
            || modes.values.ncols() != n
            || (nr > 0
                && (modes.rigid.nrows() != modes.values.nrows() || modes.rigid_strike.len() != nr))
        {
            return None;
        }
        let size = n + na + nr;
        let mut stiffness = DMatrix::zeros(size, size);
        let mut mass = DMatrix::identity(size, size);
        for k in 0..n {
            stiffness[(k, k)] = modes.theta[k];
        }
        let mut at_region = DMatrix::zeros(3 * region.len(), size);
        for (i, &v) in region.iter().enumerate() {
            for c in 0..3 {
                at_region
                    .view_mut((3 * i + c, 0), (1, n))
                    .copy_from(&modes.values.row(3 * v + c));
                if nr > 0 {
                    at_region
                        .view_mut((3 * i + c, n + na), (1, nr))
                        .copy_from(&modes.rigid.row(3 * v + c));
                }
            }
        }
        let mut strike: Vec<f64> = modes.strike.clone();
        if let Some(extra) = extra {
            let p = &extra.projections;
            let z = &modes.coefficients;
            if z.ncols() != n
                || z.nrows() != p.cross_mass.nrows()
                || extra.region_values.nrows() != 3 * region.len()
                || extra.region_values.ncols() != na
                || extra.strike.len() != na
            {
                return None;
            }
            let (a, b) = modes.lame;
            let cross_k = z.transpose() * (&p.cross_lambda * a + &p.cross_mu * b);
            let cross_m = z.transpose() * &p.cross_mass;
            stiffness.view_mut((0, n), (n, na)).copy_from(&cross_k);
            stiffness
                .view_mut((n, 0), (na, n))
                .copy_from(&cross_k.transpose());
            stiffness
                .view_mut((n, n), (na, na))
                .copy_from(&(&p.self_lambda * a + &p.self_mu * b));
            mass.view_mut((0, n), (n, na)).copy_from(&cross_m);
            mass.view_mut((n, 0), (na, n))
                .copy_from(&cross_m.transpose());
            mass.view_mut((n, n), (na, na)).copy_from(&p.self_mass);
            at_region
                .view_mut((0, n), (3 * region.len(), na))
                .copy_from(&extra.region_values);
            strike.extend_from_slice(&extra.strike);
        }
        strike.extend_from_slice(&modes.rigid_strike[..nr]);
        // Rigid-body traces the extra vectors might still carry would sit near 0, far below any
        // elastic loaded value (a mass of 16 % lowers none by more than a few times): values
        // under 10⁻⁶ of the largest diagonal entry of K are dropped.
        let floor = 1e-6 * stiffness.diagonal().iter().fold(0.0_f64, |m, v| m.max(*v));
        let empty = || RegionProblem::empty(floor, n);
        // M = LLᵀ; L⁻¹ K L⁻ᵀ = U Θ₀ Uᵀ, V = L⁻ᵀU.
        let Some(chol) = mass.cholesky() else {
            return Some(empty());
        };
        let l = chol.l();
        let Some(left) = l.solve_lower_triangular(&stiffness) else {
            return Some(empty());
        };
        let Some(reduced) = l.solve_lower_triangular(&left.transpose()) else {
            return Some(empty());
        };
        let eig = SymmetricEigen::new((&reduced + reduced.transpose()) * 0.5);
        let Some(v) = l.transpose().solve_upper_triangular(&eig.eigenvectors) else {
            return Some(empty());
        };
        let theta = eig.eigenvalues;
        let strike = v.transpose() * DVector::from_vec(strike);
        // Ĝ = WᵀW = Q D Qᵀ from WWᵀ = P D Pᵀ: Q = WᵀP D^(−½) for the nonzero d.
        let w = &at_region * &v;
        let small = SymmetricEigen::new(&w * w.transpose());
        let top = small.eigenvalues.iter().fold(0.0_f64, |m, x| m.max(*x));
        let kept: Vec<usize> = (0..small.eigenvalues.len())
            .filter(|&i| small.eigenvalues[i] > 1e-14 * top)
            .collect();
        let d: Vec<f64> = kept.iter().map(|&i| small.eigenvalues[i]).collect();
        let mut q = DMatrix::zeros(size, kept.len());
        for (j, &i) in kept.iter().enumerate() {
            let column = w.transpose() * small.eigenvectors.column(i) / d[j].sqrt();
            q.set_column(j, &column);
        }
        let b = DMatrix::from_fn(size, kept.len(), |i, j| theta[i] * q[(i, j)]);
        let t = q.transpose() * &b;
        let q_strike = q.transpose() * &strike;
        Some(RegionProblem {
            theta,
            strike,
            q,
            b,
            t,
            d,
            q_strike,
            floor,
            keep: n,
        })
    }

    /// The lowest `keep` loaded Ritz values θ' ascending with their drives (Σ_j y_j s_j)²;
    /// empty if M + αG is not positive definite (or, never seen, the QL iteration fails).
    fn solve(&self, alpha: f64) -> Vec<(f64, f64)> {
        let size = self.theta.len();
        if size == 0 || self.d.iter().any(|&d| !(1.0 + alpha * d > 0.0)) {
            return Vec::new();
        }
        let e: Vec<f64> = self
            .d
            .iter()
            .map(|&d| 1.0 / (1.0 + alpha * d).sqrt() - 1.0)
            .collect();
        let r = e.len();
        // C = Θ₀ + B E Qᵀ + Q E Bᵀ + Q (E T E) Qᵀ.
        let be = DMatrix::from_fn(size, r, |i, j| self.b[(i, j)] * e[j]);
        let ete = DMatrix::from_fn(r, r, |i, j| e[i] * self.t[(i, j)] * e[j]);
        let mut c = &be * self.q.transpose();
        let ct = c.transpose();
        c += ct;
        c += &self.q * (ete * self.q.transpose());
        for i in 0..size {
            c[(i, i)] += self.theta[i];
        }
        let c = (&c + c.transpose()) * 0.5;
        let qe = DVector::from_fn(r, |j, _| e[j] * self.q_strike[j]);
        let drive_vector = &self.strike + &self.q * qe;
        // Only each eigenvector's drive is needed, not the eigenvector: the eigenvalues with
        // the drive's weight on each (ascending), 1.4-2 times faster than a full decomposition
        // at this size (60 × 60: 0.31-0.33 ms against 0.43-0.69 ms, one core, back to back).
        let Ok(pairs) = eigen_with_weights(&c, &drive_vector) else {
            return Vec::new();
        };
        let mut out: Vec<(f64, f64)> = pairs.into_iter().filter(|p| p.0 > self.floor).collect();
        out.truncate(self.keep);
        out
    }
}

/// Loaded Ritz values θ'_k ascending and their drive weights (Σ_j y_jk s_j)², for a lumped
/// mass α = m_v/ρ [m³] on each vertex of `region` (indices into the candidate vertices).
/// The modes (and the rigid motions, if `modes` has them) form the basis. Empty if `modes` is
/// inconsistent.
pub fn loaded_modes(modes: &ModesAtPoisson, region: &[usize], alpha: f64) -> Vec<(f64, f64)> {
    RegionProblem::new(modes, region, None)
        .map(|p| p.solve(alpha))
        .unwrap_or_default()
}

/// As [`loaded_modes`], in the basis enriched by the region's attachment vectors
/// ([`Enrichment`]); `None` if the enrichment does not fit the modes.
pub fn loaded_modes_enriched(
    modes: &ModesAtPoisson,
    region: &[usize],
    extra: &Enrichment,
    alpha: f64,
) -> Option<Vec<(f64, f64)>> {
    RegionProblem::new(modes, region, Some(extra)).map(|p| p.solve(alpha))
}

/// G_R = Σ_{v∈R} Φ_vᵀΦ_v over the candidate vertices `region`.
pub fn region_gram(modes: &ModesAtPoisson, region: &[usize]) -> DMatrix<f64> {
    let n = modes.theta.len();
    let mut g = DMatrix::zeros(n, n);
    for &v in region {
        for c in 0..3 {
            let row = modes.values.row(3 * v + c);
            g += row.transpose() * row;
        }
    }
    g
}

/// Search settings.
#[derive(Clone, Debug)]
pub struct LoadedMatchSettings {
    /// Mass fractions of the body tried in the coarse pass.
    pub mass_fractions: Vec<f64>,
    /// ν range, and the coarse pass's step in it.
    pub poisson_bounds: (f64, f64),
    pub coarse_poisson_step: f64,
    /// Window of the scale c = ½ ln(E/ρ) − ln 2π around the plain match's, (below, above): a
    /// mass only lowers frequencies, so E is found higher than the plain match put it.
    pub shift_window: (f64, f64),
    /// The cap of the capped distance (ln f), as the plain match's.
    pub cap: f64,
    /// A partial quieter than this fraction of the loudest one in the compared band need not
    /// be recorded ([`LinePattern::heard`]).
    pub audible: f64,
    /// Re-anchored fine rounds per candidate (module docs, "Re-anchoring"): at most this many,
    /// each over ν ± `reanchor_window` by `reanchor_step`, with the attachment vectors solved
    /// at the previous round's ν rounded to `anchor_step`. 0 turns re-anchoring off.
    pub reanchor_rounds: usize,
    pub reanchor_window: f64,
    pub reanchor_step: f64,
    pub anchor_step: f64,
    /// Regions a re-anchored round tries: the first this many of the fine neighbourhood
    /// (nearest first). Each costs an attachment solve per anchor, which dominates the search.
    pub reanchor_regions: usize,
}

impl Default for LoadedMatchSettings {
    fn default() -> Self {
        LoadedMatchSettings {
            mass_fractions: vec![
                0.005, 0.0075, 0.01, 0.015, 0.02, 0.03, 0.04, 0.05, 0.065, 0.08, 0.10, 0.13, 0.16,
            ],
            poisson_bounds: (0.0, 0.49),
            coarse_poisson_step: 0.01,
            shift_window: (0.05, 0.15),
            cap: 0.02,
            audible: AUDIBLE_FRACTION,
            reanchor_rounds: 3,
            reanchor_window: 0.03,
            reanchor_step: 0.002,
            anchor_step: 0.005,
            reanchor_regions: 24,
        }
    }
}

/// The best loaded match.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct LoadedMatch {
    pub youngs: f64,
    pub poisson: f64,
    /// Total added mass [kg] (spread evenly over the region's vertices).
    pub mass_kg: f64,
    /// Index of the best region in the caller's list.
    pub region: usize,
    pub distance: f64,
    pub evaluations: usize,
    /// The ν at which the answer's attachment vectors were solved (module docs,
    /// "Re-anchoring").
    pub anchor_poisson: f64,
}

/// How the search's ν grid is shared among the processes of a job (module docs, "Sharing the
/// work"). Every process runs the search with its own `part`; all must pass the same problem.
pub trait Share {
    /// This process's part and the number of parts: it evaluates the ν steps i with
    /// i mod parts = part.
    fn part(&self) -> (usize, usize);
    /// Every part's `local` (the same length on every part), concatenated in part order.
    /// Collective.
    fn gather(&self, local: &[f64]) -> Vec<f64>;
}

/// One process does the whole search.
pub struct Alone;

impl Share for Alone {
    fn part(&self) -> (usize, usize) {
        (0, 1)
    }
    fn gather(&self, local: &[f64]) -> Vec<f64> {
        local.to_vec()
    }
}

/// A point of the search: (distance, scale c, ν, region, mass fraction).
type Point = (f64, f64, f64, usize, f64);

/// The best of `parts` per-slot bests gathered from every part, each slot's entry followed by
/// the ν step it was found at: the smallest distance, then the earliest step (module docs,
/// "Sharing the work"). `gathered` holds `parts` blocks of `slots` × 6 numbers.
fn combine_parts(gathered: &[f64], slots: usize) -> Vec<(Point, usize)> {
    let parts = gathered.len() / (6 * slots).max(1);
    (0..slots)
        .map(|slot| {
            let mut best: Option<(Point, usize)> = None;
            for part in 0..parts {
                let e = &gathered[6 * (part * slots + slot)..6 * (part * slots + slot) + 6];
                let point = (e[0], e[1], e[2], e[3] as usize, e[4]);
                let step = e[5] as usize;
                let better = match best {
                    None => true,
                    // A part's best is only ever replaced by a smaller distance, so none is NaN.
                    Some((b, b_step)) => point.0 < b.0 || (point.0 == b.0 && step < b_step),
                };
                if better {
                    best = Some((point, step));
                }
            }
            best.expect("at least one part")
        })
        .collect()
}

/// `point` found at ν step `step` as six numbers for [`combine_parts`].
fn encode(point: &Point, step: usize, out: &mut Vec<f64>) {
    out.extend_from_slice(&[
        point.0,
        point.1,
        point.2,
        point.3 as f64,
        point.4,
        step as f64,
    ]);
}

/// The problem: target line frequencies, the body, and the candidate regions.
pub struct LoadedMatchProblem<'a> {
    /// ln of the target's mode frequencies [ln Hz].
    pub target_ln_f: &'a [f64],
    /// Simulated partials above this (ln Hz) are not compared (band limit).
    pub ceiling_ln_f: f64,
    pub density: f64,
    /// Body volume [m³] (its mass is ρV).
    pub volume: f64,
    /// Candidate regions: indices into the candidate vertices of [`ModesAtPoisson::values`].
    pub regions: &'a [Vec<usize>],
    /// Regions tried in the coarse pass (indices into `regions`).
    pub coarse: &'a [usize],
    /// Regions tried in the fine pass around region r (indices into `regions`, r included),
    /// nearest first.
    pub neighbours: &'a dyn Fn(usize) -> Vec<usize>,
    /// E of the plain match [Pa]: the centre of the scale window.
    pub plain_youngs: f64,
    /// The attachment enrichment of region r with its vectors solved at the anchor ν
    /// ([`Enrichment`]), if the caller has one; without it (or where it gives `None`) the
    /// region's problem uses the modes alone.
    pub enrichment: Option<&'a dyn Fn(usize, f64) -> Option<Rc<Enrichment>>>,
    /// The anchor ν of the coarse pass and the first fine pass (the plain match's ν).
    pub anchor_poisson: f64,
}

/// Runs the search (module docs). `modes_at(ν)` gives the unloaded Ritz modes.
pub fn loaded_line_match(
    problem: &LoadedMatchProblem,
    modes_at: &dyn Fn(f64) -> ModesAtPoisson,
    settings: &LoadedMatchSettings,
) -> Result<LoadedMatch, LoadedMatchError> {
    loaded_line_candidates(problem, modes_at, settings, 1, &Alone)?
        .into_iter()
        .next()
        .ok_or(LoadedMatchError::NoCandidate)
}

/// The search's `candidates` best answers at distinct sites, best first: the best coarse
/// regions, each outside the fine neighbourhood of a better one, each refined by its own fine
/// pass. A caller that can afford full solves checks them ([`scale_fit`]): the Ritz model's
/// error grows with the mass and away from the attachment vectors' ν, and a search over
/// thousands of configurations finds the places where it errs in its favour.
pub fn loaded_line_candidates(
    problem: &LoadedMatchProblem,
    modes_at: &dyn Fn(f64) -> ModesAtPoisson,
    settings: &LoadedMatchSettings,
    candidates: usize,
    share: &dyn Share,
) -> Result<Vec<LoadedMatch>, LoadedMatchError> {
    let mut target: Vec<f64> = problem
        .target_ln_f
        .iter()
        .copied()
        .filter(|x| x.is_finite())
        .collect();
    if target.is_empty() {
        return Err(LoadedMatchError::NoTargetModes);
    }
    if problem.regions.is_empty() || problem.coarse.is_empty() {
        return Err(LoadedMatchError::NoRegion);
    }
    if !(problem.density > 0.0 && problem.volume > 0.0 && problem.plain_youngs > 0.0) {
        return Err(LoadedMatchError::Scales {
            density: problem.density,
            volume: problem.volume,
            youngs: problem.plain_youngs,
        });
    }
    target.sort_by(f64::total_cmp);
    let two_pi_ln = (2.0 * std::f64::consts::PI).ln();
    let c_plain = 0.5 * (problem.plain_youngs / problem.density).ln() - two_pi_ln;
    let cap = settings.cap;
    let ceiling = problem.ceiling_ln_f;
    let distance =
        |u: &LinePattern, c: f64| line_distance(&target, u, c, ceiling, cap, settings.audible);
    let pattern = |loaded: &[(f64, f64)]| LinePattern::new(loaded.iter().copied());
    // Best scale for a pattern over c_plain − below … c_plain + above, by `step`, then ten
    // times finer around the best.
    let best_shift =
        |u: &LinePattern, centre: f64, below: f64, above: f64, step: f64| -> (f64, f64, usize) {
            let mut best = (f64::INFINITY, centre);
            let n = ((below + above) / step).ceil() as usize;
            let mut evals = 0;
            for i in 0..=n {
                let c = centre - below + i as f64 * step;
                let d = distance(u, c);
                evals += 1;
                if d < best.0 {
                    best = (d, c);
                }
            }
            let c0 = best.1;
            for i in -10..=10 {
                let c = c0 + i as f64 * step / 10.0;
                let d = distance(u, c);
                evals += 1;
                if d < best.0 {
                    best = (d, c);
                }
            }
            (best.0, best.1, evals)
        };
    let body_mass = problem.density * problem.volume;
    let alpha_of = |fraction: f64, region: usize| {
        fraction * problem.volume / problem.regions[region].len().max(1) as f64
    };
    let region_problem = |modes: &ModesAtPoisson, r: usize, anchor: f64| -> Option<RegionProblem> {
        let region = &problem.regions[r];
        let extra = problem.enrichment.and_then(|enrich| enrich(r, anchor));
        extra
            .and_then(|extra| RegionProblem::new(modes, region, Some(&extra)))
            .or_else(|| RegionProblem::new(modes, region, None))
    };

    let (part, parts) = share.part();
    let parts = parts.max(1);
    // The attachment vectors every pass needs, asked for by every part in the single loop's
    // order before the ν grid is shared out: forming them is collective.
    let prefetch = |regions: &[usize], anchor: f64| {
        if let Some(enrich) = problem.enrichment {
            for &r in regions {
                let _ = enrich(r, anchor);
            }
        }
    };

    // The best (distance, c, ν, region, fraction) of each coarse region, for the candidates,
    // with the ν step it was found at (this part's steps only, then combined).
    let mut per_region: Vec<(Point, usize)> = problem
        .coarse
        .iter()
        .map(|&r| {
            (
                (f64::INFINITY, c_plain, settings.poisson_bounds.0, r, 0.0),
                usize::MAX,
            )
        })
        .collect();
    let evaluations = std::cell::Cell::new(0usize);
    let (lo, hi) = settings.poisson_bounds;
    let n_nu = ((hi - lo) / settings.coarse_poisson_step.max(1e-4))
        .ceil()
        .max(1.0) as usize;
    prefetch(problem.coarse, problem.anchor_poisson);
    for i in (0..=n_nu).filter(|i| i % parts == part) {
        let nu = lo + (hi - lo) * i as f64 / n_nu as f64;
        let modes = modes_at(nu);
        for (slot, &r) in problem.coarse.iter().enumerate() {
            let Some(reduced) = region_problem(&modes, r, problem.anchor_poisson) else {
                continue;
            };
            for &fraction in &settings.mass_fractions {
                let u = pattern(&reduced.solve(alpha_of(fraction, r)));
                let (d, c, e) = best_shift(
                    &u,
                    c_plain,
                    settings.shift_window.0,
                    settings.shift_window.1,
                    1e-3,
                );
                evaluations.set(evaluations.get() + e);
                if d < per_region[slot].0 .0 {
                    per_region[slot] = ((d, c, nu, r, fraction), i);
                }
            }
        }
    }
    let mut local = Vec::with_capacity(6 * per_region.len());
    for (point, step) in &per_region {
        encode(point, *step, &mut local);
    }
    let mut per_region: Vec<Point> = combine_parts(&share.gather(&local), per_region.len())
        .into_iter()
        .map(|(point, _)| point)
        .collect();
    // Candidates: the best coarse regions, each outside the fine neighbourhoods of those
    // already taken; a fine pass around each (ν ± 0.01 by 0.001, the neighbouring regions,
    // the mass ± 15 %).
    per_region.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut seeds: Vec<Point> = Vec::new();
    let mut covered: Vec<usize> = Vec::new();
    for cand in per_region.iter().filter(|c| c.0.is_finite()) {
        if seeds.len() >= candidates.max(1) {
            break;
        }
        if covered.contains(&cand.3) {
            continue;
        }
        covered.extend((problem.neighbours)(cand.3));
        seeds.push(*cand);
    }
    // One fine pass around `from` with the attachment vectors at `anchor`: ν ± `half` by
    // `step`, the first `limit` regions next to `from`'s, the mass ± 15 %.
    let fine_pass = |from: Point, anchor: f64, half: f64, step: f64, keep: bool, limit: usize| {
        let (_, c0, nu0, r0, fraction0) = from;
        let mut regions = (problem.neighbours)(r0);
        regions.truncate(limit.max(1));
        prefetch(&regions, anchor);
        let steps = (half / step).round() as i64;
        // This part's best over its ν steps, then the best of all parts.
        let mut local: (Point, usize) = ((f64::INFINITY, c0, nu0, r0, fraction0), usize::MAX);
        for (index, j) in (-steps..=steps).enumerate() {
            if index % parts != part {
                continue;
            }
            let nu = (nu0 + j as f64 * step).clamp(lo, hi);
            let modes = modes_at(nu);
            for &r in &regions {
                let Some(reduced) = region_problem(&modes, r, anchor) else {
                    continue;
                };
                for s in -3..=3 {
                    let fraction = fraction0 * (1.0 + 0.05 * s as f64);
                    let u = pattern(&reduced.solve(alpha_of(fraction, r)));
                    let (d, c, e) = best_shift(&u, c0, 0.005, 0.005, 2e-4);
                    evaluations.set(evaluations.get() + e);
                    if d < local.0 .0 {
                        local = ((d, c, nu, r, fraction), index);
                    }
                }
            }
        }
        let mut encoded = Vec::with_capacity(6);
        encode(&local.0, local.1, &mut encoded);
        let (grid, _) = combine_parts(&share.gather(&encoded), 1)[0];
        // With `keep`, `from` itself stands (its distance is by the same model) unless a grid
        // point is strictly better; otherwise only this pass's points compete.
        let best = if keep && !(grid.0 < from.0) {
            from
        } else {
            grid
        };
        if best.0.is_finite() {
            best
        } else {
            from
        }
    };
    let snap = |nu: f64| {
        if settings.anchor_step > 0.0 {
            (nu / settings.anchor_step).round() * settings.anchor_step
        } else {
            nu
        }
    };
    let mut out = Vec::with_capacity(seeds.len());
    for seed in seeds {
        let mut best = fine_pass(seed, problem.anchor_poisson, 0.01, 0.001, true, usize::MAX);
        let mut anchor = problem.anchor_poisson;
        if problem.enrichment.is_some() {
            for _ in 0..settings.reanchor_rounds {
                let next = snap(best.2);
                if (next - anchor).abs() < 0.5 * settings.anchor_step.max(1e-12) {
                    break;
                }
                anchor = next;
                best = fine_pass(
                    best,
                    anchor,
                    settings.reanchor_window,
                    settings.reanchor_step,
                    false,
                    settings.reanchor_regions,
                );
            }
        }
        let (d, c, nu, r, fraction) = best;
        out.push(LoadedMatch {
            youngs: problem.density * (2.0 * (c + two_pi_ln)).exp(),
            poisson: nu,
            mass_kg: fraction * body_mass,
            region: r,
            distance: d,
            evaluations: 0,
            anchor_poisson: anchor,
        });
    }
    // Every part's evaluations, the same total on every part.
    let total: f64 = share.gather(&[evaluations.get() as f64]).iter().sum();
    for found in &mut out {
        found.evaluations = total as usize;
    }
    out.sort_by(|a, b| a.distance.total_cmp(&b.distance));
    Ok(out)
}

/// The line match of a given loaded spectrum (θ'_k for E/ρ = 1 with their drives, e.g. from a
/// full solve): its distance and E at the best scale within `window` (ln f, below and above)
/// of `youngs_centre`, with the search's cap and audibility.
pub fn scale_fit(
    target_ln_f: &[f64],
    ceiling_ln_f: f64,
    loaded: &[(f64, f64)],
    density: f64,
    youngs_centre: f64,
    window: f64,
    settings: &LoadedMatchSettings,
) -> (f64, f64) {
    let mut target: Vec<f64> = target_ln_f
        .iter()
        .copied()
        .filter(|x| x.is_finite())
        .collect();
    target.sort_by(f64::total_cmp);
    let u = LinePattern::new(loaded.iter().copied());
    let two_pi_ln = (2.0 * std::f64::consts::PI).ln();
    let centre = 0.5 * (youngs_centre / density).ln() - two_pi_ln;
    let mut best = (f64::INFINITY, centre);
    for step in [1e-3, 1e-4] {
        let (lo, n) = if step > 5e-4 {
            (centre - window, (2.0 * window / step).ceil() as i64)
        } else {
            (best.1 - 1e-3, 20)
        };
        for i in 0..=n {
            let c = lo + i as f64 * step;
            let d = line_distance(&target, &u, c, ceiling_ln_f, settings.cap, settings.audible);
            if d < best.0 {
                best = (d, c);
            }
        }
    }
    (best.0, density * (2.0 * (best.1 + two_pi_ln)).exp())
}

/// Merges the split pairs of `lines` (ln f, weight), sorted by ln f in place: two neighbours
/// at most `tolerance` apart (relative, ln(1 + tolerance) in ln f) become one line at their
/// mean ln f with the larger weight, the closer neighbour taken first where three are near
/// (module docs, "Splits against shifts"). A line is merged at most once: a pair has two
/// members.
pub fn merge_split_pairs(lines: &mut Vec<(f64, f64)>, tolerance: f64) {
    lines.retain(|l| l.0.is_finite());
    lines.sort_by(|a, b| a.0.total_cmp(&b.0));
    let gap = tolerance.max(0.0).ln_1p();
    let mut out = Vec::with_capacity(lines.len());
    let mut i = 0;
    while i < lines.len() {
        let near_next = i + 1 < lines.len() && lines[i + 1].0 - lines[i].0 <= gap;
        // The next line pairs with the one after it instead when that one is closer.
        let next_prefers_after =
            i + 2 < lines.len() && lines[i + 2].0 - lines[i + 1].0 < lines[i + 1].0 - lines[i].0;
        if near_next && !next_prefers_after {
            out.push((
                0.5 * (lines[i].0 + lines[i + 1].0),
                lines[i].1.max(lines[i + 1].1),
            ));
            i += 2;
        } else {
            out.push(lines[i]);
            i += 1;
        }
    }
    *lines = out;
}

/// The line match of `loaded` (θ'_k for E/ρ = 1 with their drives, as [`scale_fit`] takes
/// them) with the split pairs of both sides merged ([`merge_split_pairs`] within `tolerance`):
/// what a model leaves of the distance once every split is forgiven, so that cutting it is
/// more than explaining splits (module docs, "Splits against shifts"). Same scale search as
/// [`scale_fit`]; returns (distance, E).
#[allow(clippy::too_many_arguments)]
pub fn split_free_fit(
    target_ln_f: &[f64],
    ceiling_ln_f: f64,
    loaded: &[(f64, f64)],
    density: f64,
    youngs_centre: f64,
    window: f64,
    settings: &LoadedMatchSettings,
    tolerance: f64,
) -> (f64, f64) {
    let mut target: Vec<(f64, f64)> = target_ln_f.iter().map(|&x| (x, 1.0)).collect();
    merge_split_pairs(&mut target, tolerance);
    let target: Vec<f64> = target.into_iter().map(|l| l.0).collect();
    // θ = f² (2π)² ρ/E, so ln f is ½ ln θ up to the scale: merge on ½ ln θ, then back.
    let mut lines: Vec<(f64, f64)> = loaded
        .iter()
        .filter(|p| p.0 > 0.0)
        .map(|&(theta, w)| (0.5 * theta.ln(), w))
        .collect();
    merge_split_pairs(&mut lines, tolerance);
    let merged: Vec<(f64, f64)> = lines
        .into_iter()
        .map(|(half_ln, w)| ((2.0 * half_ln).exp(), w))
        .collect();
    scale_fit(
        &target,
        ceiling_ln_f,
        &merged,
        density,
        youngs_centre,
        window,
        settings,
    )
}

/// The least split-free distance ([`split_free_fit`]) of a plain model over ν: its spectrum at
/// each ν of `nus` (θ for E/ρ = 1 with their drives, from `spectrum_at`) matched with every
/// split pair merged, the scale searched within `window` of `youngs_centre`. Returns
/// (distance, ν); ν is the first of `nus` on ties. What a carried mass must beat to stand on
/// the lines' centres: the plain material at the ν that places them best, not at a ν chosen
/// with the splits weighed (module docs, "Splits against shifts").
#[allow(clippy::too_many_arguments)]
pub fn split_free_over_poisson(
    target_ln_f: &[f64],
    ceiling_ln_f: f64,
    spectrum_at: impl Fn(f64) -> Vec<(f64, f64)>,
    nus: &[f64],
    density: f64,
    youngs_centre: f64,
    window: f64,
    settings: &LoadedMatchSettings,
    tolerance: f64,
) -> (f64, f64) {
    let mut best = (f64::INFINITY, f64::NAN);
    for &nu in nus {
        let d = split_free_fit(
            target_ln_f,
            ceiling_ln_f,
            &spectrum_at(nu),
            density,
            youngs_centre,
            window,
            settings,
            tolerance,
        )
        .0;
        if d < best.0 {
            best = (d, nu);
        }
    }
    best
}

#[cfg(test)]
mod tests;
