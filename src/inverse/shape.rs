//! Shape from sound: the one-parameter fits built on the forward chain of [`crate::shape`]
//! (the spectrum of the body an implicit field encloses and its gradient, issue 7): the relative
//! thickness of a hollow body and the weight of a morph between two shapes.
//!
//! # Thickness
//!
//! A hollow body of relative thickness t is the set 0 < s ≤ t·S of the solid's signed distance
//! s, with S the depth of the solid's deepest point (the radius of its largest inscribed ball,
//! [`SignedDistance::deepest_point`], [`reference_depth`]). Marched as
//! g = min(s, t·S − s) ([`crate::shape::shell_of_depth`]); dg/dt = S on the inner branch.
//! S is taken from the continuous distance, once per surface, not from the grid samples: the
//! largest sample misses S by up to h√3/2, and t·S with the sampled maximum moved the inner
//! wall by a different amount on every grid (spot: 11.42 mm at 14 cells, 13.95 at 20, 13.21 at
//! 32 against S = 14.217 mm), a bias of up to 20 % in t between the fit and a finer target
//! grid — the main reason the first fits missed by 0.13.
//!
//! # Morphing
//!
//! m = c·A + (1 − c)·B of two signed distances on one grid ([`crate::shape::morph`]);
//! dm/dc = A − B, through [`crate::shape::morph_vjp`]. c = 1 is shape A, c = 0 shape B.
//!
//! # Loss
//!
//! With the first n target eigenvalues λ*_k in ascending order, the modes are compared in
//! ascending order, in groups G: the target's near-degenerate clusters (neighbours within a
//! relative gap of `cluster_rtol`, default 1e-2) form one group, every other mode its own. A
//! group is compared by its mean log-eigenvalue, so two modes that swap places inside a cluster
//! as p moves leave the loss smooth:
//!
//! ```text
//!   r_G = mean_{k∈G} ln λ_k − mean_{k∈G} ln λ*_k,      L(p) = Σ_G |G| r_G²
//!   J_G = mean_{k∈G} (dλ_k/dp) / λ_k,                 dL/dp = 2 Σ_G |G| r_G J_G
//! ```
//!
//! and the Gauss–Newton step is Δp = −Σ|G| J_G r_G / Σ|G| J_G².
//!
//! # Free stiffness scale
//!
//! With `free_scale` ([`ShapeFitSettings::free_scale`], `--free-scale`) a common offset α of
//! every ln λ_k — a stiffness factor e^α, the same as an unknown Young's modulus — is profiled
//! out: with weights w_G = |G|,
//!
//! ```text
//!   ᾱ = Σ w_G r_G / Σ w_G,   J̄ = Σ w_G J_G / Σ w_G
//!   L(p) = Σ_G w_G (r_G − ᾱ)²,   dL/dp = 2 Σ_G w_G (r_G − ᾱ)(J_G − J̄)
//! ```
//!
//! (no dᾱ/dp term: ∂L/∂α = 0 at the profiled α) and the Gauss–Newton step uses the centred
//! J_G − J̄. Why: a marched body on a coarse grid is stiffer than on a finer one, by a
//! different amount for every mode but with a large common part. Measured on spot (t* = 0.7,
//! target on 40 cells, model on 28, 12 modes): at the model's t = 0.7 every ln(λ/λ*) is
//! positive, +0.029 … +0.083, and one mode (a thin feature's, solid whatever t) sits at
//! +0.044 for every t ∈ [0.55, 0.75], pure grid bias. The plain loss's minimum on that grid is
//! at t = 0.575, the free-scale loss's at t = 0.645. The spectrum's level then no longer
//! informs t, only its shape: a body whose modes all scale alike with p (a thin shell's bending
//! modes with its thickness) loses its information (the step is 0). In the full fit it did not
//! pay: spot, t* = 0.7, levels 20/28/32/36 against 40 cells, 2 ranks, seed 1 gave per-level
//! answers 0.574/0.639/0.686/0.7185 (plain loss: 0.480/0.571/0.628/0.677), so the common part
//! is only a third of the grid bias, the finest level overshoots, and the line through the
//! levels lands on 0.746 (error 0.046, against 0.012 with the plain loss). The option is
//! therefore off by default; it remains for targets whose material is not known exactly.
//!
//! # The one-parameter search
//!
//! L(p) is piecewise smooth: every change of the marching topology (a grid value changing sign,
//! a vertex snapped) is a small jump, and L can have several minima (the frog/turtle morph at
//! 16 cells: L = 1.57, 0.051, 0.52, 0.21, 0.44 at c = 0.2, 0.4, …, 1). A local Gauss–Newton
//! from a random start (the first version) stopped on the wrong side of such features or at a
//! bound, and with t near its lower bound the wall fell between the grid samples and the mesh
//! vanished (the "empty field" failure on bob: every value snapped, nothing kept). The search
//! is therefore global first:
//!
//! 1. **Scan** (coarsest level): L at `scan_points` evenly spaced p in the bounds. Points whose
//!    body cannot be meshed or solved are recorded as failed and skipped.
//! 2. **Refine** (every level): a safeguarded Newton iteration on dL/dp = 0. A bracket [a, b]
//!    shrinks with the sign of dL/dp at every evaluated point (after the scan: the best point's
//!    neighbours, if their slopes point at it); the next point is the Gauss–Newton step (with
//!    the secant curvature of dL/dp through the nearest evaluated point on the minimum's other
//!    side where that is larger: far from the target, the residuals' own curvature makes
//!    plain Gauss–Newton overshoot), capped
//!    at the scan spacing (coarsest level) or `refine_window` (finer levels), and halfway to
//!    the bracket's end if it would leave the bracket. Stops when the bracket or the step is
//!    below `tolerance`, after `max_refinements`. The best point seen is the level's answer; a
//!    finer level starts from the coarser level's answer.
//!
//! # Grid bias and its extrapolation
//!
//! The fit compares a model on a coarse grid with a target from a finer one, and the
//! spectrum of a marched body converges slowly in the grid spacing h. Measured on spot (target
//! at 40 cells on a randomly shifted grid, each level's own best t):
//!
//! | cells (h mm) | 20 (3.69) | 24 (3.02) | 28 (2.55) | 32 (2.21) | 36 (1.95) | target 40 (1.75) |
//! |---|---|---|---|---|---|---|
//! | t* = 0.5 | 0.4147 | 0.4329 | 0.4509 | 0.4745 | 0.4906 | 0.5 |
//! | t* = 0.7 | 0.4780 | 0.5253 | 0.5683 | 0.6238 | 0.6706 | 0.7 |
//!
//! The bias is close to linear in h − h* (0.04–0.07 per mm at t = 0.5, 0.11–0.16 at t = 0.7).
//! Its sources, measured: (1) the reference depth (fixed above); (2) thin features that span a
//! few cells — the *solid* spot's sixth mode moves 33349 → 32115 → 30975 Hz at 16/20/28
//! cells, while a solid analytic sphere converges as h² (frequency errors +0.68/+0.33/+0.20 %
//! against Lamb at 12/16/20 cells, all from the volume lost by interpolating a concave
//! distance) and a hollow analytic sphere likewise (its first cluster 34829/34183/33955/
//! 33860 Hz at h = 7.5/5/3.75/3 mm); (3) the low modes of a thick shell hardly depend on t
//! (spot: d ln f₁/dt ≈ 0.15 for t ∈ [0.5, 0.7]), so a 1 % frequency bias is 0.02–0.07 in t.
//! Putting every crossing on the exact zero of the continuous field along its edge
//! ([`refine_crossings`]) halves the hollow analytic sphere's error but leaves spot's
//! (first mode at 28/40 cells: 11278/11113 Hz exact, 11301 (32)/11190 Hz linear), and the
//! alignment of the grid alone moves spot's modes by 0.1–0.5 % at 28 cells (four shifts).
//! A single grid coarser than the target therefore cannot reach 0.005 in t.
//! How much of the grid dependence is the finite-element error of P2 on the marched body and
//! how much the body itself: splitting every tet of the 20-cell spot shell into eight (the same
//! polyhedral body, `shape_probe --subdivide`) lowers its first eight frequencies by 0.5–1.1 %
//! (t = 0.5; 0.4–0.9 % at t = 0.7), while the 28-cell grid lowers them by 1.0–5.8 %. So the
//! body the marching makes of the field is most of the grid dependence — all but the first
//! mode's — and a better element alone would not remove it.
//!
//! With two or more levels (spacings h_ℓ, answers p_ℓ), [`ShapeFit`] also reports the
//! least-squares line p(h) = α + β h through the finest `extrapolation_levels` (default 3)
//! answers evaluated at the target's spacing h*, clamped to the bounds
//! ([`ShapeFit::extrapolated`]); [`ShapeFitSettings::extrapolate`] (default) makes it the
//! answer. On the table above the line through 28/32/36 cells gives 0.5047 and 0.7047. h* is
//! the grid spacing of a synthesised target, and 0 for a measured object, where the line has
//! much farther to go (from ~2 mm to 0) and is correspondingly less certain. The levels must be
//! in the range where the answers move steadily with h: on a 60 × 40 × 30 mm box at 12 and 14
//! cells (a wall of one to two cells) the line overshoots by 0.045.
//!
//! **The floor the target's own grid sets.** A fit on the target's own spacing (40 cells,
//! the centred grid) against a 40-cell target on a randomly shifted grid differs from it in
//! nothing but the grid's alignment. On spot (2 ranks, `shape_benchmark thickness --levels
//! 20,40 --target-cells 40 --no-extrapolate`, seeds 1 and 2) it gave t = 0.4959 and 0.4968
//! for t* = 0.5, 0.6910 and 0.7014 for t* = 0.7: errors 0.0041, 0.0032, 0.0090, 0.0014, mean
//! 0.0044. That is the difference of two independent alignments, so one 40-cell target
//! carries about 1/√2 of it, 0.002–0.006 in t, by itself — the size of the 0.005 goal — and
//! no fit can average away the alignment of the one target it is given. The fit's levels add
//! their own alignment noise, which the line through them carries to h* amplified (for 28/32/36
//! cells to 40, about 1.3 × a level's).
//!
//! **Replicas.** The fit levels' own alignment noise can be averaged: with `replicas` K
//! (the CLI's `--replicas`, [`replica_shift`]) every level after the first is fitted on K grids
//! of its spacing moved by r/K of a cell along the diagonal, each a level of its own, the
//! line goes through all K answers per spacing, and the finest level's answer (the answer
//! without the line) is the mean of the finest spacing's K answers ([`ShapeFit::finest_parameter`]). The oloid shows why (2 ranks, seed 1, levels
//! 20/28/32/36 against 40 cells): its answers alternate with the alignment — at t* = 0.5 the
//! centred grids gave 0.5088/0.5100/0.4942 and the half-cell-shifted ones 0.4844/0.4897/0.5110
//! at 28/32/36 cells — so one alignment per spacing put the line 0.007–0.024 off (mean error
//! 0.0128 over t* = 0.3 … 0.7), and with K = 2 the mean error fell to 0.0030 (max 0.0063), at
//! 2.6 × the fit time (391 s mean, on a machine shared with builds; 152 s with K = 1). It
//! cannot remove the target's own alignment (above), nor a bias that is not linear in h (the
//! turtle at t* = 0.7: levels 0.398/0.482/0.526/0.591, line 0.621). On spot, whose bias
//! curves, it did not pay: on the same two targets (t* = 0.5 and 0.7, seed 1) K = 1 missed by
//! 0.0046 and 0.0045, K = 2 by 0.0001 and 0.0124 (the shifted 32- and 36-cell grids answered
//! 0.608 and 0.649 against the centred 0.624 and 0.671 at t* = 0.7, tilting the line). So K
//! stays 1 by default: it is the remedy for a body whose answers alternate with the grid's
//! alignment, not for curvature in h.
//!
//! # Refinement near the walls (thickness)
//!
//! The turtle's high-t targets were put down (stop 32) to its cavity not being resolved. The
//! cavity is not what moves: refining the background grid only near the inner walls
//! ([`refine_near_wall`]: longest-edge bisection of the Kuhn tets, [`crate::shape::refine`])
//! moves the turtle's first 16 frequencies at t = 0.7 on 28 cells by 0.00–0.08 % with one
//! halving and 0.00–0.11 % with two (`wall_probe --where inner`,
//! `out/bench_shape/wall_probe/turtle28_quick.txt`), while another alignment of the same grid
//! moves them by up to 4.2 % (mode 1) and 3.5 % (modes 10–11). The turtle (185 vertices, 366
//! faces) has flippers 1.4–2.8 mm thick at z ≈ −32 mm (ray casting along the inward normals),
//! one to one and a half 28-cell spacings (2.53 mm): the outer wall is what the grid's
//! alignment changes.
//!
//! So the refinement ([`ShapeLevel::near_wall`], `wall_refinement` in [`ShapeFitSettings`],
//! the CLI's `--wall-refinement L`) bisects the tets that reach the outer wall s = 0 or the
//! inner walls of t ∈ [p₀ − w, p₀ + w] around a level's start p₀ (`wall_band` w, default
//! 0.05), and only where the samples miss the signed distance: some edge midpoint m of the
//! tet with |s(m) − (s_a + s_b)/2| > ε ℓ (`wall_tolerance` ε, default 0.05; ℓ the tet's
//! longest edge; a smooth wall of radius R gives at most ℓ/8R, a crease, ridge or thin
//! feature much more) — [`refine_unresolved`]. Marked tets become Kuhn tets of h/2^L; the
//! closure refines their neighbours as far as conformity needs. New vertices take the
//! continuous distance. The first (scanned) level is never refined; a synthesised target is
//! refined the same way around its true t, so it stays finer than the fit. The chain to t is
//! the curved shell's. Against central differences (`tests/mpi_sensitivity.rs`,
//! `examples/wall_chain_probe.rs`, hollow triangulated ellipsoid, 12 cells) the straight body
//! on a refined grid meets 1e-9 as on a plain one; the curved body missed by 1.2e-4 to 6.0e-4
//! of λ_k/t (1e-9 on the plain grid), the same with h = 1e-5 and 1e-6, until stop 35 traced
//! it: the mid-edge nodes' directions of move are central differences of the signed distance,
//! and on the refined grid (vertices on the ellipsoid's symmetry planes, where its triangulated
//! distance has creases) many stencils straddle a crease, so the direction turns fast as the
//! corners move — 9.9e-3 of a node's velocity at the worst nodes, unaccounted for. (The earlier
//! attempt to add the turn took its Hessian by central differences of step δ too, which across a
//! crease is no better; it flipped the error's sign.) With the turn from the exact gradient
//! (above, "Curved boundary") the refined grid's error is 4.9e-7 to 5.4e-6 and the check's bar
//! 1e-4 as on the plain grid. A randomly shifted plain grid showed the same defect (the chain's
//! weight on the curved nodes off by 1.8e-2 against their motion, now 1.5e-5); the centred plain
//! grid of the MPI check happened to have no straddled stencil on its inner wall.
//!
//! Measured on the turtle (28 cells, 16 modes, t = 0.7, the centred grid and two random
//! shifts, 2 ranks, `wall_probe --where both --tolerance 0.05`,
//! `out/bench_shape/wall_probe/turtle28_both_tol005.txt`):
//!
//! | L | background tets | body tets | P2 nodes | solve | alignment spread, modes 9–16 (mean) | as t |
//! |---|---|---|---|---|---|---|
//! | 0 | 84 672 | 29 000 | 50 000 | 14–18 s | 1.88 % | 0.148 |
//! | 1 | 214 000 | 115 000 | 190 000 | 55–69 s | 0.55 % | 0.058 |
//!
//! ("as t": the spreads read through d ln f_k/dt between t = 0.70 and 0.75 as a Gauss–Newton
//! step, Σ|s_k| δ_k / Σ s_k².) One halving takes 3.4× out of the alignment spread of the modes
//! that carry t (modes 9–16: d ln f/dt 0.04–0.19), at 4× the tets and solve time. The
//! flippers' own modes (1–3) keep theirs (4.3 %, 2.0 %, 2.3 %); they hardly depend on t
//! (|d ln f/dt| ≤ 0.015), so they add a constant to the loss, not a bias to its minimum.
//! Refining the whole outer band (ε = 0) costs 144 000 body tets for the same frequencies
//! (within 0.02 %); two halvings there ran the 24 GB machine out of memory in MUMPS. On spot
//! (28 cells, 8 modes, t = 0.7, three alignments, `spot28_both_tol005.txt`) one halving
//! takes the mean alignment spread from 0.38 % to 0.15 % and its reading as t from 0.025 to
//! 0.013, at 3.1× the tets and 3.3–3.9× the solve time; the refined frequencies sit 0.3–1.0 %
//! below the plain ones, the plain grid's bias.
//!
//! In a fit (turtle, t* = 0.7, levels 20/28, 16 modes, a 36-cell target of seed 2 refined
//! like the fit, 2 ranks, `out/bench_shape/wall_ab/`): without refinement the 28-cell level
//! answered 0.5956 (error −0.104, loss 3.4e-2, 254 s, 2.7 GB); with one halving 0.6410
//! (error −0.059, loss 2.9e-3, 721 s, 9.3 GB at most, the refined target's solve). The
//! loss at the answer falls 11×, the error by 43 %; the 5-minute goal is out of reach this
//! way (five 28-cell evaluations at 64–85 s each). The option is off by default: it buys
//! accuracy on thin features at several times the time.
//!
//! E, ν and ρ are known here (the material fit is a separate problem). Every rank runs the same
//! search on the same numbers (eigenvalues and gradients are broadcast from rank 0), so the
//! decisions agree across ranks.

use crate::eigen;
use crate::fem::Material;
use crate::mesh;
use crate::petsc::Petsc;
use crate::shape::spectrum::modes_of_mesh;
use crate::shape::{
    self, curved_shell, curved_shell_spectrum, shape_modes, shape_spectrum, BackgroundGrid,
    MarchingOptions, SampledField, ShapeError, ShapeModes, ShapeSpectrum, SignedDistance,
    StepTimings,
};
use std::ops::Range;
use std::sync::Arc;

/// Shift of replica `r` of `replicas` grids of one spacing, in cells: r/K along every axis,
/// wrapped into [−½, ½) (K = 2: the centred grid and the one moved by half a cell along the
/// diagonal, whose vertices sit at the centred grid's cell centres).
pub fn replica_shift(r: usize, replicas: usize) -> [f64; 3] {
    let k = replicas.max(1) as f64;
    let mut s = (r % replicas.max(1)) as f64 / k;
    if s >= 0.5 {
        s -= 1.0;
    }
    [s; 3]
}

/// The fit levels with `replicas` K grids per spacing: (cells, replica r) coarse to fine, the
/// first spacing once (it is scanned, and a replica would only repeat the scan's role), every
/// later one K times in a row (`every_level`, for an answer from the line through the levels)
/// or only the finest (for an answer from the finest spacing alone: a replica of a middle
/// spacing would only be a start for the next); r goes to [`replica_shift`]`(r, K)`.
pub fn replica_levels(cells: &[usize], replicas: usize, every_level: bool) -> Vec<(usize, usize)> {
    let last = cells.len().saturating_sub(1);
    cells
        .iter()
        .enumerate()
        .flat_map(|(i, &c)| {
            (0..if i == 0 || (!every_level && i != last) {
                1
            } else {
                replicas.max(1)
            })
                .map(move |r| (c, r))
        })
        .collect()
}

/// Whether a fit answers with the line through its levels' answers (else with the finest
/// level's): `extrapolate` if given, else off for the curved thickness body, whose finest level
/// is already within the grids' alignment spread of a finer target, and on for every other
/// body (module docs, "Curved boundary"). The fit, [`replica_levels`]' callers and the CLI all
/// decide through this one rule.
pub fn answers_with_line(extrapolate: Option<bool>, curved_thickness: bool) -> bool {
    extrapolate.unwrap_or(!curved_thickness)
}

/// How many of [`replica_levels`]' entries the extrapolation line goes through so that it
/// spans `spacings` spacings with all their replicas.
pub fn replica_line_levels(spacings: usize, replicas: usize, every_level: bool) -> usize {
    if every_level {
        spacings * replicas.max(1)
    } else {
        spacings + replicas.max(1) - 1
    }
}

// ------------------------------------------------------------------ one-parameter families

/// A one-parameter family of fields on one grid (module docs).
#[derive(Clone, Debug)]
pub enum ShapeFamily {
    /// g = min(s, t·S − s): the hollow version of the solid `solid` (samples of its signed
    /// distance) with reference depth S = `depth` [m]; the parameter is t. With `surface` (the
    /// continuous signed distance the samples came from) the body is meshed with exact
    /// crossings and a curved boundary ([`curved_shell`]); without, from the samples alone.
    Thickness {
        solid: Vec<f64>,
        depth: f64,
        surface: Option<std::sync::Arc<SignedDistance>>,
    },
    /// m = c·A + (1 − c)·B; the parameter is c.
    Morph { a: Vec<f64>, b: Vec<f64> },
}

/// What a field needs to carry a gradient back to its parameter.
enum Built {
    Shell(shape::Shell),
    Morph(f64),
}

impl ShapeFamily {
    /// The parameter's name, for messages and files.
    pub fn parameter_name(&self) -> &'static str {
        match self {
            ShapeFamily::Thickness { .. } => "thickness",
            ShapeFamily::Morph { .. } => "morph weight c",
        }
    }

    /// The field at parameter `p`.
    pub fn field(&self, p: f64) -> Result<Vec<f64>, ShapeError> {
        Ok(self.build(p)?.0)
    }

    fn build(&self, p: f64) -> Result<(Vec<f64>, Built), ShapeError> {
        match self {
            ShapeFamily::Thickness { solid, depth, .. } => {
                let shell = shape::shell_of_depth(solid, p, *depth)?;
                Ok((shell.values.clone(), Built::Shell(shell)))
            }
            ShapeFamily::Morph { a, b } => Ok((shape::morph(a, b, p)?, Built::Morph(p))),
        }
    }

    /// dλ/dp from dλ/d(field) through the built field.
    fn derivative(&self, built: &Built, d_field: &[f64]) -> Result<f64, ShapeError> {
        match (self, built) {
            (_, Built::Shell(shell)) => Ok(shell.vjp(d_field)?.thickness),
            (ShapeFamily::Morph { a, b }, Built::Morph(c)) => {
                Ok(shape::morph_vjp(a, b, *c, d_field)?.c)
            }
            (ShapeFamily::Thickness { .. }, Built::Morph(_)) => {
                unreachable!("a thickness family builds a shell")
            }
        }
    }

    /// The spectrum at parameter `p` on `grid` and, if asked, dλ_k/dp. Collective.
    #[allow(clippy::too_many_arguments)]
    pub fn spectrum(
        &self,
        petsc: &Petsc,
        grid: &BackgroundGrid,
        p: f64,
        options: &MarchingOptions,
        material: &Material,
        n_modes: usize,
        with_gradient: bool,
    ) -> Result<(ShapeSpectrum, Option<Vec<f64>>), ShapeError> {
        if let ShapeFamily::Thickness {
            solid,
            depth,
            surface: Some(sdf),
        } = self
        {
            return curved_shell_spectrum(
                petsc,
                grid,
                solid,
                sdf,
                *depth,
                p,
                options,
                material,
                n_modes,
                with_gradient,
            );
        }
        let (values, built) = self.build(p)?;
        let spectrum = shape_spectrum(
            petsc,
            grid,
            &values,
            options,
            material,
            n_modes,
            with_gradient,
        )?;
        let derivative = match &spectrum.gradient {
            Some(gradient) => Some(
                gradient
                    .iter()
                    .map(|g| self.derivative(&built, g))
                    .collect::<Result<Vec<f64>, ShapeError>>()?,
            ),
            None => None,
        };
        Ok((spectrum, derivative))
    }

    /// Whether a fit over several levels answers with the extrapolation unless told otherwise
    /// ([`answers_with_line`] with nothing said).
    pub fn extrapolates_by_default(&self) -> bool {
        answers_with_line(None, self.is_curved_thickness())
    }

    /// The thickness body meshed with exact crossings and a curved boundary ([`curved_shell`]).
    pub fn is_curved_thickness(&self) -> bool {
        matches!(
            self,
            ShapeFamily::Thickness {
                surface: Some(_),
                ..
            }
        )
    }

    /// The modes and mesh of the body at parameter `p` (for writing it). Collective.
    pub fn modes(
        &self,
        petsc: &Petsc,
        grid: &BackgroundGrid,
        p: f64,
        options: &MarchingOptions,
        material: &Material,
        n_modes: usize,
    ) -> Result<ShapeModes, ShapeError> {
        if let ShapeFamily::Thickness {
            solid,
            depth,
            surface: Some(sdf),
        } = self
        {
            let body = curved_shell(grid, solid, sdf, *depth, p, options)?;
            return modes_of_mesh(
                petsc,
                body.body.quadratic,
                body.body.marched.report.clone(),
                material,
                n_modes,
            );
        }
        shape_modes(petsc, grid, &self.field(p)?, options, material, n_modes)
    }

    fn n_values(&self) -> usize {
        match self {
            ShapeFamily::Thickness { solid, .. } => solid.len(),
            ShapeFamily::Morph { a, .. } => a.len(),
        }
    }
}

/// One resolution of a fit: a grid and the family sampled on it.
#[derive(Clone, Debug)]
pub struct ShapeLevel {
    pub grid: BackgroundGrid,
    pub family: ShapeFamily,
}

/// More halvings than this near the walls would not fit in memory on any grid worth it.
pub const MAX_WALL_REFINEMENT: usize = 3;

/// The grid refined `levels` times near the inner wall of every shell with t ∈ `t_range`
/// (module docs, "Refinement near the walls"): [`refine_near_depths`] with the one band
/// [t_lo·S, t_hi·S].
pub fn refine_near_wall(
    grid: &BackgroundGrid,
    solid: &[f64],
    sdf: &SignedDistance,
    depth: f64,
    t_range: (f64, f64),
    levels: usize,
) -> Result<(BackgroundGrid, Vec<f64>), ShapeError> {
    let (t_lo, t_hi) = t_range;
    if !(t_lo.is_finite() && t_hi.is_finite() && t_lo <= t_hi) {
        return Err(ShapeError::Invalid(format!(
            "wall refinement range ({t_lo}, {t_hi}) must be finite and ordered"
        )));
    }
    refine_near_depths(grid, solid, sdf, &[(t_lo * depth, t_hi * depth)], levels)
}

/// The grid refined `levels` times where the solid's signed distance s takes a value in one
/// of the `bands` [s_lo, s_hi] [m]: a tet whose samples s_v, widened by its longest edge ℓ (s
/// is 1-Lipschitz, so s inside the tet lies in [min s_v − ℓ, max s_v + ℓ]), reach into a band
/// is bisected until it is a Kuhn tet of h/2^levels. New vertices take the continuous distance.
/// Returns the grid and the solid's samples on it.
pub fn refine_near_depths(
    grid: &BackgroundGrid,
    solid: &[f64],
    sdf: &SignedDistance,
    bands: &[(f64, f64)],
    levels: usize,
) -> Result<(BackgroundGrid, Vec<f64>), ShapeError> {
    refine_unresolved(grid, solid, sdf, bands, levels, 0.0)
}

/// [`refine_near_depths`], but only tets where the samples do not resolve s: some edge (a, b)
/// whose midpoint value misses the corners' mean by more than `tolerance` times the tet's
/// longest edge, |s(m) − (s_a + s_b)/2| > tolerance·ℓ (a crease, a ridge, a thin feature or a
/// tight curvature: a smooth wall of radius R gives ℓ/(8R) at most). 0 refines the whole band.
pub fn refine_unresolved(
    grid: &BackgroundGrid,
    solid: &[f64],
    sdf: &SignedDistance,
    bands: &[(f64, f64)],
    levels: usize,
    tolerance: f64,
) -> Result<(BackgroundGrid, Vec<f64>), ShapeError> {
    if !(tolerance.is_finite() && tolerance >= 0.0) {
        return Err(ShapeError::Invalid(format!(
            "the resolution tolerance must be ≥ 0, got {tolerance}"
        )));
    }
    if bands
        .iter()
        .any(|&(a, b)| !(a.is_finite() && b.is_finite() && a <= b))
    {
        return Err(ShapeError::Invalid(format!(
            "refinement bands {bands:?} must be finite and ordered"
        )));
    }
    if levels > MAX_WALL_REFINEMENT {
        return Err(ShapeError::Invalid(format!(
            "wall refinement must lie in 0..={MAX_WALL_REFINEMENT}, got {levels}"
        )));
    }
    let field = |x: [f64; 3]| sdf.signed_distance(x);
    let marked = |v: &crate::shape::refine::TetView| {
        let (lo, hi) = v
            .values
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            });
        let in_band = bands.iter().any(|&(band_lo, band_hi)| {
            lo - v.longest_edge <= band_hi && hi + v.longest_edge >= band_lo
        });
        in_band
            && (tolerance == 0.0
                || mesh::TET10_EDGES.iter().any(|&(a, b)| {
                    let m = [0, 1, 2].map(|d| 0.5 * (v.corners[a][d] + v.corners[b][d]));
                    (sdf.signed_distance(m) - 0.5 * (v.values[a] + v.values[b])).abs()
                        > tolerance * v.longest_edge
                }))
    };
    Ok(grid.refined(levels, solid, &field, &marked)?)
}

impl ShapeLevel {
    /// This level with its grid refined `levels` times near both walls where the samples do
    /// not resolve the signed distance ([`refine_unresolved`] with `tolerance`, 0 for the whole
    /// bands): the outer wall s = 0 and the inner walls of t ∈ [p₀ − w, p₀ + w]. `None` for a
    /// family other than the curved thickness body, or with `levels` = 0.
    pub fn near_wall(
        &self,
        p0: f64,
        w: f64,
        levels: usize,
        tolerance: f64,
    ) -> Result<Option<ShapeLevel>, ShapeError> {
        let ShapeFamily::Thickness {
            solid,
            depth,
            surface: Some(sdf),
        } = &self.family
        else {
            return Ok(None);
        };
        if levels == 0 {
            return Ok(None);
        }
        if !(p0.is_finite() && w.is_finite() && w > 0.0) {
            return Err(ShapeError::Invalid(format!(
                "wall refinement around {p0} ± {w}: both must be finite, w > 0"
            )));
        }
        let bands = [(0.0, 0.0), ((p0 - w) * depth, (p0 + w) * depth)];
        let (grid, solid) = refine_unresolved(&self.grid, solid, sdf, &bands, levels, tolerance)?;
        Ok(Some(ShapeLevel {
            grid,
            family: ShapeFamily::Thickness {
                solid,
                depth: *depth,
                surface: Some(Arc::clone(sdf)),
            },
        }))
    }

    /// Cell size h [m] (of the structured grid, before any refinement).
    pub fn spacing(&self) -> f64 {
        self.grid.spacing()[0]
    }

    /// Cells along the longest axis.
    pub fn cells(&self) -> usize {
        self.grid.cells().into_iter().max().unwrap_or(0)
    }
}

// ------------------------------------------------------------------ loss

/// The target eigenvalues and the groups they are compared in (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct SpectrumTarget {
    /// Ascending [rad²/s²].
    pub eigenvalues: Vec<f64>,
    /// Index ranges covering 0..n in order: a near-degenerate cluster, or one mode.
    pub groups: Vec<Range<usize>>,
}

impl SpectrumTarget {
    /// Sorts the eigenvalues and groups neighbours closer than `cluster_rtol` (relative gap).
    pub fn new(mut eigenvalues: Vec<f64>, cluster_rtol: f64) -> Result<SpectrumTarget, ShapeError> {
        if eigenvalues.is_empty() {
            return Err(ShapeError::Invalid("no target eigenvalues".into()));
        }
        if let Some(bad) = eigenvalues.iter().find(|v| !(v.is_finite() && **v > 0.0)) {
            return Err(ShapeError::Invalid(format!(
                "target eigenvalues must be positive numbers, got {bad}"
            )));
        }
        if !(cluster_rtol.is_finite() && cluster_rtol >= 0.0) {
            return Err(ShapeError::Invalid(format!(
                "cluster_rtol must be ≥ 0, got {cluster_rtol}"
            )));
        }
        eigenvalues.sort_by(f64::total_cmp);
        let clusters = eigen::find_clusters(&eigenvalues, cluster_rtol);
        let mut groups = Vec::new();
        let mut k = 0;
        for c in clusters {
            groups.extend((k..c.start).map(|j| j..j + 1));
            k = c.end;
            groups.push(c);
        }
        groups.extend((k..eigenvalues.len()).map(|j| j..j + 1));
        Ok(SpectrumTarget {
            eigenvalues,
            groups,
        })
    }

    pub fn len(&self) -> usize {
        self.eigenvalues.len()
    }

    pub fn is_empty(&self) -> bool {
        self.eigenvalues.is_empty()
    }
}

/// The loss at one parameter value (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct LossPoint {
    pub loss: f64,
    /// dL/dp.
    pub gradient: f64,
    /// The Gauss–Newton step Δp (0 if the spectrum does not move with p).
    pub step: f64,
    /// With a free stiffness scale: the profiled offset ᾱ = ln(λ/λ*) common to every mode
    /// (e^ᾱ is the stiffness factor that best aligns the model with the target); else 0.
    pub log_scale: f64,
}

/// L, dL/dp and the Gauss–Newton step from the model's eigenvalues and their derivatives
/// dλ_k/dp (same length as the target). With `free_scale`, a common offset of every
/// ln λ_k (a stiffness factor, module docs "Free stiffness scale") is profiled out.
pub fn spectrum_loss(
    eigenvalues: &[f64],
    d_eigenvalues: &[f64],
    target: &SpectrumTarget,
    free_scale: bool,
) -> Result<LossPoint, ShapeError> {
    let n = target.len();
    if eigenvalues.len() < n || d_eigenvalues.len() < n {
        return Err(ShapeError::Invalid(format!(
            "{} model eigenvalues and {} derivatives for {n} targets",
            eigenvalues.len(),
            d_eigenvalues.len()
        )));
    }
    // Per group: weight |G|, residual r_G and sensitivity J_G.
    let groups: Vec<(f64, f64, f64)> = target
        .groups
        .iter()
        .map(|g| {
            let size = g.len() as f64;
            let r = g
                .clone()
                .map(|k| (eigenvalues[k] / target.eigenvalues[k]).ln())
                .sum::<f64>()
                / size;
            let j = g
                .clone()
                .map(|k| d_eigenvalues[k] / eigenvalues[k])
                .sum::<f64>()
                / size;
            (size, r, j)
        })
        .collect();
    let (log_scale, mean_j) = if free_scale {
        let w: f64 = groups.iter().map(|g| g.0).sum();
        (
            groups.iter().map(|g| g.0 * g.1).sum::<f64>() / w,
            groups.iter().map(|g| g.0 * g.2).sum::<f64>() / w,
        )
    } else {
        (0.0, 0.0)
    };
    let (mut loss, mut gradient, mut jtj, mut jtr) = (0.0, 0.0, 0.0, 0.0);
    for &(size, r, j) in &groups {
        // Profiling the offset leaves the residual and the sensitivity centred (the derivative
        // of the profiled loss needs no dᾱ/dp term: ∂L/∂ᾱ = 0 at the optimum).
        let (r, j) = (r - log_scale, j - mean_j);
        loss += size * r * r;
        gradient += 2.0 * size * r * j;
        jtj += size * j * j;
        jtr += size * j * r;
    }
    let step = if jtj > 0.0 { -jtr / jtj } else { 0.0 };
    Ok(LossPoint {
        loss,
        gradient,
        step,
        log_scale,
    })
}

// ------------------------------------------------------------------ the fit

/// Settings of [`fit_shape`] (module docs).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ShapeFitSettings {
    /// Modes compared (default 8).
    pub modes: usize,
    /// The parameter stays in [lo, hi].
    pub bounds: (f64, f64),
    /// Evenly spaced L evaluations over the bounds on the coarsest level (default 9).
    pub scan_points: usize,
    /// Most refinement evaluations per level (default 8).
    pub max_refinements: usize,
    /// Stop refining when the bracket or the step is below this (default 1e-3).
    pub tolerance: f64,
    /// The longest single step on a finer level, which starts from the coarser level's answer
    /// (default 0.05; on the coarsest level the scan spacing).
    pub refine_window: f64,
    /// Relative gap below which target modes form one group (default 1e-2).
    pub cluster_rtol: f64,
    /// With two or more levels, answer with the line through the levels' answers evaluated at
    /// the target's grid spacing. None (default): the family's default
    /// ([`ShapeFamily::extrapolates_by_default`]: on, except for the curved thickness body).
    pub extrapolate: Option<bool>,
    /// The line is fitted to this many of the finest levels (default 3, at least 2).
    pub extrapolation_levels: usize,
    /// Profile a stiffness factor common to every mode out of the loss (module docs, "Free
    /// stiffness scale"; default false).
    pub free_scale: bool,
    /// Curved thickness body: halvings of the grid near the inner wall on every level after
    /// the first (module docs, "Refinement near the walls"; default 0, none).
    pub wall_refinement: usize,
    /// The thickness range [p₀ − w, p₀ + w] around a level's start p₀ whose inner walls the
    /// refinement covers (default 0.05).
    pub wall_band: f64,
    /// Only tets where the samples miss the signed distance at an edge midpoint by more than
    /// this fraction of the tet's longest edge are refined ([`refine_unresolved`]; default
    /// 0.05; 0 refines the whole bands).
    pub wall_tolerance: f64,
}

impl Default for ShapeFitSettings {
    fn default() -> Self {
        ShapeFitSettings {
            modes: 8,
            bounds: (0.1, 0.95),
            scan_points: 9,
            max_refinements: 8,
            tolerance: 1e-3,
            refine_window: 0.05,
            cluster_rtol: 1e-2,
            extrapolate: None,
            extrapolation_levels: 3,
            free_scale: false,
            wall_refinement: 0,
            wall_band: 0.05,
            wall_tolerance: 0.05,
        }
    }
}

impl ShapeFitSettings {
    /// Settings for a morph weight c ∈ [0, 1].
    pub fn morph() -> Self {
        ShapeFitSettings {
            bounds: (0.0, 1.0),
            scan_points: 6,
            ..Default::default()
        }
    }

    pub fn validate(&self) -> Result<(), ShapeError> {
        let (lo, hi) = self.bounds;
        let bad = |m: String| Err(ShapeError::Invalid(m));
        if !(lo.is_finite() && hi.is_finite() && lo < hi) {
            return bad(format!(
                "the bounds ({lo}, {hi}) must be finite with lo < hi"
            ));
        }
        if self.modes == 0 || self.modes > 200 {
            return bad(format!("modes must lie in 1..=200, got {}", self.modes));
        }
        if self.scan_points < 2 {
            return bad(format!(
                "scan_points must be at least 2, got {}",
                self.scan_points
            ));
        }
        if !(self.tolerance > 0.0 && self.tolerance < hi - lo) {
            return bad(format!(
                "tolerance must lie in (0, hi − lo), got {}",
                self.tolerance
            ));
        }
        if !(self.refine_window > 0.0 && self.refine_window.is_finite()) {
            return bad(format!(
                "refine_window must be positive, got {}",
                self.refine_window
            ));
        }
        if !(self.cluster_rtol.is_finite() && self.cluster_rtol >= 0.0) {
            return bad(format!(
                "cluster_rtol must be ≥ 0, got {}",
                self.cluster_rtol
            ));
        }
        if self.extrapolation_levels < 2 {
            return bad(format!(
                "extrapolation_levels must be at least 2, got {}",
                self.extrapolation_levels
            ));
        }
        if self.wall_refinement > MAX_WALL_REFINEMENT {
            return bad(format!(
                "wall_refinement must lie in 0..={MAX_WALL_REFINEMENT}, got {}",
                self.wall_refinement
            ));
        }
        if !(self.wall_band.is_finite() && self.wall_band > 0.0) {
            return bad(format!(
                "wall_band must be positive, got {}",
                self.wall_band
            ));
        }
        if !(self.wall_tolerance.is_finite() && self.wall_tolerance >= 0.0) {
            return bad(format!(
                "wall_tolerance must be ≥ 0, got {}",
                self.wall_tolerance
            ));
        }
        Ok(())
    }
}

/// Scan or refinement.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum SearchPhase {
    Scan,
    Refine,
}

/// One evaluation of the loss.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct FitEvaluation {
    /// 0-based level (grid) index.
    pub level: usize,
    pub cells: usize,
    pub phase: SearchPhase,
    pub parameter: f64,
    /// NaN if the body could not be meshed or solved (`failure` says why).
    pub loss: f64,
    pub gradient: f64,
    pub step: f64,
    pub tets: usize,
    pub p2_nodes: usize,
    pub timings: StepTimings,
    pub failure: Option<String>,
}

/// The answer of one level.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct LevelResult {
    pub cells: usize,
    /// h [m].
    pub spacing: f64,
    pub parameter: f64,
    pub loss: f64,
    /// The profiled ln stiffness factor at the answer ([`LossPoint::log_scale`]; 0 without
    /// a free scale).
    pub log_scale: f64,
    /// Model eigenvalues at the level's answer [rad²/s²].
    pub eigenvalues: Vec<f64>,
    pub evaluations: usize,
    pub seconds: f64,
    /// The start p₀ around which the level's grid was refined near the inner wall
    /// ([`ShapeLevel::near_wall`] with the fit's `wall_band` and `wall_refinement`), if it was.
    #[serde(default)]
    pub wall_centre: Option<f64>,
    /// Background tets of the level's grid (after any refinement).
    #[serde(default)]
    pub grid_tets: usize,
}

/// The result of [`fit_shape`].
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ShapeFit {
    /// The answer: the extrapolated value if asked for and available, else the finest
    /// level's (with grid replicas, the mean of the finest spacing's replicas).
    pub parameter: f64,
    /// Per level, coarse to fine.
    pub levels: Vec<LevelResult>,
    /// The line through the finest `extrapolation_levels` levels' answers at the target
    /// spacing (module docs), clamped to the bounds; `None` with one level or no target
    /// spacing.
    pub extrapolated: Option<f64>,
    /// Whether `parameter` is `extrapolated` ([`ShapeFitSettings::extrapolate`]).
    pub extrapolation_used: bool,
    /// The target's grid spacing h* [m] used for the extrapolation (0: continuous).
    pub target_spacing: Option<f64>,
    /// Every evaluation, in order.
    pub history: Vec<FitEvaluation>,
    pub seconds: f64,
}

impl ShapeFit {
    /// The finest spacing's answer (the mean over its replicas, if any).
    pub fn finest_parameter(&self) -> f64 {
        finest_mean(&self.levels)
    }

    /// Seconds per evaluation on average, split like [`StepTimings`], over the evaluations of
    /// `level` that produced a body.
    pub fn mean_timings(&self, level: usize) -> StepTimings {
        let e: Vec<&FitEvaluation> = self
            .history
            .iter()
            .filter(|h| h.level == level && h.failure.is_none())
            .collect();
        let n = e.len().max(1) as f64;
        StepTimings {
            meshing: e.iter().map(|h| h.timings.meshing).sum::<f64>() / n,
            assembly: e.iter().map(|h| h.timings.assembly).sum::<f64>() / n,
            solve: e.iter().map(|h| h.timings.solve).sum::<f64>() / n,
            gradient: e.iter().map(|h| h.timings.gradient).sum::<f64>() / n,
        }
    }
}

/// A successful evaluation: the parameter, the loss there and what the caller keeps with it.
#[derive(Clone, Debug)]
struct Point<T> {
    p: f64,
    loss: LossPoint,
    data: T,
}

/// Where a level's search starts: a scan of the whole range, or a coarser level's answer.
#[derive(Clone, Copy, Debug)]
enum SearchStart {
    Scan,
    From(f64),
}

/// Why a level's search found nothing.
#[derive(Clone, Copy, Debug, PartialEq)]
enum SearchFailure {
    /// No scan point could be evaluated.
    NothingScanned,
    /// The coarser answer could not be evaluated on this level.
    StartFailed,
}

/// The search on one level (module docs): `evaluate(p, phase)` is the loss at p, or `None`
/// where no body could be meshed and solved. Returns the best point seen.
fn search_level<T: Clone>(
    mut evaluate: impl FnMut(f64, SearchPhase) -> Option<Point<T>>,
    start: SearchStart,
    settings: &ShapeFitSettings,
) -> Result<Point<T>, SearchFailure> {
    let (lo, hi) = settings.bounds;
    // [a, b] holds the minimum as far as the signs of dL/dp seen so far tell; no step is
    // longer than `max_step`.
    let (mut a, mut b) = (lo, hi);
    let (start, max_step) = match start {
        SearchStart::Scan => {
            let n = settings.scan_points;
            let grid: Vec<f64> = (0..n)
                .map(|i| lo + (hi - lo) * i as f64 / (n - 1) as f64)
                .collect();
            let mut points: Vec<Option<Point<T>>> = Vec::with_capacity(n);
            for &p in &grid {
                points.push(evaluate(p, SearchPhase::Scan));
            }
            let i = (0..n).filter(|&i| points[i].is_some()).min_by(|&i, &j| {
                let (pi, pj) = (
                    points[i].as_ref().expect("some"),
                    points[j].as_ref().expect("some"),
                );
                pi.loss.loss.total_cmp(&pj.loss.loss)
            });
            let i = i.ok_or(SearchFailure::NothingScanned)?;
            // The neighbours bracket the minimum if their slopes point at the best point.
            if let Some(Some(left)) = i.checked_sub(1).map(|j| &points[j]) {
                if left.loss.gradient < 0.0 {
                    a = left.p;
                }
            }
            if let Some(Some(right)) = points.get(i + 1) {
                if right.loss.gradient > 0.0 {
                    b = right.p;
                }
            }
            (points[i].clone().expect("some"), (hi - lo) / (n - 1) as f64)
        }
        SearchStart::From(previous) => (
            evaluate(previous, SearchPhase::Refine).ok_or(SearchFailure::StartFailed)?,
            settings.refine_window,
        ),
    };
    // Safeguarded Newton on dL/dp = 0.
    let mut best = start.clone();
    let mut x = start;
    // The evaluated points nearest the minimum on either side: (p, dL/dp) with the largest p
    // where dL/dp < 0 and the smallest where dL/dp > 0.
    let mut below: Option<(f64, f64)> = None;
    let mut above: Option<(f64, f64)> = None;
    for _ in 0..settings.max_refinements {
        if x.loss.gradient > 0.0 {
            b = b.min(x.p);
            if above.is_none_or(|(p, _)| x.p < p) {
                above = Some((x.p, x.loss.gradient));
            }
        } else if x.loss.gradient < 0.0 {
            a = a.max(x.p);
            if below.is_none_or(|(p, _)| x.p > p) {
                below = Some((x.p, x.loss.gradient));
            }
        }
        if b - a < settings.tolerance {
            break;
        }
        // The Gauss–Newton step, capped; downhill by the slope if it gives none. Its curvature
        // Σ|G|J² leaves out the residuals' own Σ|G| r dJ/dp: with a target the level cannot
        // reach (loss 7e-4 at the oloid's 36-cell minimum) the true curvature was 1.6× larger
        // and the steps bounced across the minimum for seven evaluations. So where the secant
        // of dL/dp shows a larger curvature, the step uses that: the secant through the nearest
        // evaluated point on the minimum's other side (dL/dp of the other sign), which
        // interpolates the slope across the minimum. Not through the previous point on the same
        // side: that extrapolates from a farther, steeper part of the loss, and with
        // sensitivities that fall towards the minimum (a small cavity, the turtle at t* = 0.7 on
        // 36 cells) it cut each accurate Gauss–Newton step to a third — six evaluations, each
        // covering about half the remaining way.
        let mut step = if x.loss.step != 0.0 {
            x.loss.step
        } else {
            -x.loss.gradient.signum() * max_step
        };
        let other_side = if x.loss.gradient > 0.0 {
            below
        } else if x.loss.gradient < 0.0 {
            above
        } else {
            None
        };
        if let Some((p0, g0)) = other_side {
            let secant = (x.loss.gradient - g0) / (x.p - p0);
            let gauss_newton = if x.loss.step != 0.0 {
                -x.loss.gradient / x.loss.step
            } else {
                0.0
            };
            if secant.is_finite() && secant > gauss_newton {
                step = -x.loss.gradient / secant;
            }
        }
        let mut candidate = x.p + step.clamp(-max_step, max_step);
        if candidate <= a || candidate >= b {
            // Halfway to the bracket's end on the step's side.
            candidate = 0.5 * (x.p + if candidate <= a { a } else { b });
        }
        if (candidate - x.p).abs() < 0.5 * settings.tolerance {
            break;
        }
        match evaluate(candidate, SearchPhase::Refine) {
            Some(y) => {
                if y.loss.loss < best.loss.loss {
                    best = y.clone();
                }
                x = y;
            }
            // No body there: look on x's side of the candidate.
            None if candidate > x.p => b = candidate,
            None => a = candidate,
        }
    }
    Ok(best)
}

/// Fits the one parameter of `levels` (coarse to fine, all the same family kind) to the
/// target (module docs). `target_spacing` is the target's grid spacing h* [m] (Some(0.0) for a
/// measured target) for the extrapolation; `on_eval` sees every evaluation. Collective.
#[allow(clippy::too_many_arguments)]
pub fn fit_shape(
    petsc: &Petsc,
    levels: &[ShapeLevel],
    target: &SpectrumTarget,
    options: &MarchingOptions,
    material: &Material,
    settings: &ShapeFitSettings,
    target_spacing: Option<f64>,
    mut on_eval: impl FnMut(&FitEvaluation),
) -> Result<ShapeFit, ShapeError> {
    settings.validate()?;
    if levels.is_empty() {
        return Err(ShapeError::Invalid("no grid levels to fit on".into()));
    }
    for (i, l) in levels.iter().enumerate() {
        if l.family.n_values() != l.grid.n_vertices() {
            return Err(ShapeError::Invalid(format!(
                "level {i}: {} field values for a grid of {} vertices",
                l.family.n_values(),
                l.grid.n_vertices()
            )));
        }
    }
    if target.len() != settings.modes {
        return Err(ShapeError::Invalid(format!(
            "{} target eigenvalues for {} compared modes",
            target.len(),
            settings.modes
        )));
    }
    if let Some(h) = target_spacing {
        if !(h.is_finite() && h >= 0.0) {
            return Err(ShapeError::Invalid(format!(
                "the target's grid spacing must be ≥ 0, got {h}"
            )));
        }
    }
    let clock = std::time::Instant::now();
    let (lo, hi) = settings.bounds;
    let mut history: Vec<FitEvaluation> = Vec::new();
    let mut results: Vec<LevelResult> = Vec::new();
    for (index, level) in levels.iter().enumerate() {
        let level_clock = std::time::Instant::now();
        let first_eval = history.len();
        // Every level after the scanned one may be refined near the inner walls around its start.
        let wall_centre = (index > 0).then(|| results[index - 1].parameter);
        let refined = match wall_centre {
            Some(p0) => level.near_wall(
                p0,
                settings.wall_band,
                settings.wall_refinement,
                settings.wall_tolerance,
            )?,
            None => None,
        };
        let wall_centre = wall_centre.filter(|_| refined.is_some());
        let level = refined.as_ref().unwrap_or(level);
        let evaluate = |p: f64, phase: SearchPhase| -> Option<Point<Vec<f64>>> {
            let mut record = FitEvaluation {
                level: index,
                cells: level.cells(),
                phase,
                parameter: p,
                loss: f64::NAN,
                gradient: f64::NAN,
                step: f64::NAN,
                tets: 0,
                p2_nodes: 0,
                timings: StepTimings::default(),
                failure: None,
            };
            let point = match evaluate_point(petsc, level, p, target, options, material, settings) {
                Ok((point, spectrum)) => {
                    record.loss = point.loss.loss;
                    record.gradient = point.loss.gradient;
                    record.step = point.loss.step;
                    record.tets = spectrum.tets;
                    record.p2_nodes = spectrum.p2_nodes;
                    record.timings = spectrum.timings;
                    Some(point)
                }
                Err(e) => {
                    record.failure = Some(e.to_string());
                    None
                }
            };
            on_eval(&record);
            history.push(record);
            point
        };
        let start = if index == 0 {
            SearchStart::Scan
        } else {
            SearchStart::From(results[index - 1].parameter)
        };
        let best = search_level(evaluate, start, settings).map_err(|failure| {
            let name = level.family.parameter_name();
            let reasons: Vec<String> = history[first_eval..].iter().filter_map(|h| h.failure.as_ref().map(|f| format!("{name} = {:.4}: {f}", h.parameter))).collect();
            ShapeError::Invalid(match failure {
                SearchFailure::NothingScanned => format!("no {name} in [{lo}, {hi}] gave a body that could be meshed and solved on the {}-cell grid: {}", level.cells(), reasons.join("; ")),
                SearchFailure::StartFailed => format!("the {}-cell grid could not take the coarser grid's answer: {}", level.cells(), reasons.join("; ")),
            })
        })?;
        results.push(LevelResult {
            cells: level.cells(),
            spacing: level.spacing(),
            parameter: best.p,
            loss: best.loss.loss,
            log_scale: best.loss.log_scale,
            eigenvalues: best.data,
            evaluations: history.len() - first_eval,
            seconds: level_clock.elapsed().as_secs_f64(),
            wall_centre,
            grid_tets: level.grid.n_tets(),
        });
    }

    let extrapolated = match target_spacing {
        Some(h_target) if results.len() >= 2 => {
            let used = &results[results.len().saturating_sub(settings.extrapolation_levels)..];
            Some(
                extrapolate_line(
                    &used
                        .iter()
                        .map(|r| (r.spacing, r.parameter))
                        .collect::<Vec<_>>(),
                    h_target,
                )
                .clamp(lo, hi),
            )
        }
        _ => None,
    };
    let finest = finest_mean(&results);
    let extrapolate =
        answers_with_line(settings.extrapolate, levels[0].family.is_curved_thickness());
    let (parameter, extrapolation_used) = match extrapolated {
        Some(p) if extrapolate => (p, true),
        _ => (finest, false),
    };
    Ok(ShapeFit {
        parameter,
        levels: results,
        extrapolated,
        extrapolation_used,
        target_spacing,
        history,
        seconds: clock.elapsed().as_secs_f64(),
    })
}

/// The finest spacing's answer: with grid replicas, the mean over its K grids (their alignment
/// noise averages, as it does in the line). `levels` must not be empty.
fn finest_mean(levels: &[LevelResult]) -> f64 {
    let finest_spacing = levels.last().expect("at least one level").spacing;
    let group: Vec<f64> = levels
        .iter()
        .filter(|r| (r.spacing - finest_spacing).abs() <= 1e-9 * finest_spacing)
        .map(|r| r.parameter)
        .collect();
    group.iter().sum::<f64>() / group.len() as f64
}

/// The least-squares line y = α + β x through `points` (at least two distinct x), at `x`.
pub fn extrapolate_line(points: &[(f64, f64)], x: f64) -> f64 {
    let n = points.len() as f64;
    let mx = points.iter().map(|p| p.0).sum::<f64>() / n;
    let my = points.iter().map(|p| p.1).sum::<f64>() / n;
    let sxx: f64 = points.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = points.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    if sxx > 0.0 {
        my + sxy / sxx * (x - mx)
    } else {
        my
    }
}

/// The loss, its derivative and the Gauss–Newton step at parameter `p` on one level.
fn evaluate_point(
    petsc: &Petsc,
    level: &ShapeLevel,
    p: f64,
    target: &SpectrumTarget,
    options: &MarchingOptions,
    material: &Material,
    settings: &ShapeFitSettings,
) -> Result<(Point<Vec<f64>>, ShapeSpectrum), ShapeError> {
    let (spectrum, d_eigenvalues) = level.family.spectrum(
        petsc,
        &level.grid,
        p,
        options,
        material,
        settings.modes,
        true,
    )?;
    let d_eigenvalues = d_eigenvalues
        .ok_or_else(|| ShapeError::Solver("the spectrum came without its gradient".into()))?;
    let loss = spectrum_loss(
        &spectrum.eigenvalues,
        &d_eigenvalues,
        target,
        settings.free_scale,
    )?;
    Ok((
        Point {
            p,
            loss,
            data: spectrum.eigenvalues.clone(),
        },
        spectrum,
    ))
}

/// The thickness fit: `solids` are the solid's signed distance sampled on the levels' grids
/// (coarse to fine), `depth` its reference depth S ([`reference_depth`]), `surface` the
/// continuous signed distance for the curved boundary (None: the samples alone). Collective.
#[allow(clippy::too_many_arguments)]
pub fn fit_thickness(
    petsc: &Petsc,
    solids: &[SampledField],
    depth: f64,
    surface: Option<std::sync::Arc<SignedDistance>>,
    target: &SpectrumTarget,
    options: &MarchingOptions,
    material: &Material,
    settings: &ShapeFitSettings,
    target_spacing: Option<f64>,
    on_eval: impl FnMut(&FitEvaluation),
) -> Result<ShapeFit, ShapeError> {
    if !(depth.is_finite() && depth > 0.0) {
        return Err(ShapeError::Invalid(format!(
            "the reference depth S must be positive, got {depth}"
        )));
    }
    let (lo, hi) = settings.bounds;
    if !(lo > 0.0 && hi <= 1.0) {
        return Err(ShapeError::Invalid(format!(
            "thickness bounds ({lo}, {hi}) must lie in (0, 1]"
        )));
    }
    let levels: Vec<ShapeLevel> = solids
        .iter()
        .map(|s| ShapeLevel {
            grid: s.grid.clone(),
            family: ShapeFamily::Thickness {
                solid: s.values.clone(),
                depth,
                surface: surface.clone(),
            },
        })
        .collect();
    fit_shape(
        petsc,
        &levels,
        target,
        options,
        material,
        settings,
        target_spacing,
        on_eval,
    )
}

/// The morph fit: `pairs` hold shape A and shape B sampled on the same grid, per level (coarse
/// to fine); the field is c·A + (1 − c)·B. Collective.
#[allow(clippy::too_many_arguments)]
pub fn fit_morph(
    petsc: &Petsc,
    pairs: &[(SampledField, SampledField)],
    target: &SpectrumTarget,
    options: &MarchingOptions,
    material: &Material,
    settings: &ShapeFitSettings,
    target_spacing: Option<f64>,
    on_eval: impl FnMut(&FitEvaluation),
) -> Result<ShapeFit, ShapeError> {
    let mut levels = Vec::with_capacity(pairs.len());
    for (i, (a, b)) in pairs.iter().enumerate() {
        if a.grid != b.grid {
            return Err(ShapeError::Invalid(format!(
                "level {i}: the two shapes of a morph must be sampled on the same grid"
            )));
        }
        levels.push(ShapeLevel {
            grid: a.grid.clone(),
            family: ShapeFamily::Morph {
                a: a.values.clone(),
                b: b.values.clone(),
            },
        });
    }
    fit_shape(
        petsc,
        &levels,
        target,
        options,
        material,
        settings,
        target_spacing,
        on_eval,
    )
}

#[cfg(test)]
mod tests;
