//! The spectrum of the body an implicit field encloses, and its exact gradient with respect to
//! the field: the forward chain of shape from sound (issue 7). The fits built on it (thickness,
//! morph) are in [`crate::inverse::shape`]; the fields themselves in [`super::field`].
//!
//! # The chain
//!
//! A field s_i on the vertices of a background tet grid ([`BackgroundGrid`], positive inside)
//! is meshed by marching tetrahedra ([`crate::shape::march`]); the P1 mesh is lifted to P2
//! ([`lift_to_quadratic`]); M, K_λ, K_μ are assembled and the first `n` elastic modes solved
//! (shift-invert Krylov–Schur, as everywhere else). For each mode
//!
//! ```text
//!   dλ_k/ds_i = Σ_v (dλ_k/dx_v) · (dx_v/ds_i)
//! ```
//!
//! where dλ_k/dx_v [rad²/(s²·m)] is the node-position sensitivity of the P2 mesh
//! ([`node_gradients`], cluster means for near-degenerate modes) carried back to the P1 corners
//! (mid-edge nodes are edge midpoints, [`linear_node_gradient`]) and dx_v/ds_i is the marching
//! Jacobian (a crossing x = x_a + t (x_b − x_a), t = s_a/(s_a − s_b), moves with s_a and s_b
//! only; [`crate::shape::MarchedMesh::vjp`]). Grid vertices that are mesh corners do not move
//! with s. The topology (which tets exist) is piecewise constant in s, so the gradient is that of
//! the current mesh; it is exact between topology changes.
//!
//! # Curved boundary (thickness)
//!
//! Everything above describes the body marched from the grid samples alone: crossings linearly
//! interpolated, P2 edges straight. The thickness fit knows more: the continuous signed
//! distance s of the solid, so the shell's continuous field g(x) = min(s(x), t·S − s(x)) can be
//! evaluated anywhere. By default ([`ShapeFamily::Thickness`] with `surface`, the CLI's
//! default; `--straight-boundary` for the samples alone) the body is meshed by
//! [`curved_shell`]: the marching's topology from the samples, every crossing moved onto the
//! zero of g along its grid edge ([`refine_crossings`]), and every mid-edge node of a boundary
//! edge moved onto it along ∇g ([`super::curve_boundary`]; a move that would fold a tet is undone,
//! spot at 20 cells: 8394 boundary edges, 7275 moved, 254 without a root within half an edge —
//! edges from the outer to the inner wall — and 865 undone). The P2 surface then interpolates
//! the true one at six points per face instead of approximating it by chords.
//!
//! dλ_k/dt follows the moves: a node on g(x; t) = 0 that moves along a direction d has
//! dx = d · (−∇g·dx₀ − ∂g/∂t dt)/(∇g·d) + (the turn of d), with ∂g/∂t = S on the inner wall and
//! 0 on the outer; for a crossing d is its grid edge and x₀ fixed, for a mid-edge node d is the
//! central difference D g (step δ = 1e-3 of its edge) at the midpoint x₀ of its corners, so the
//! rest of its gradient goes to the corners projected along d, and d turns as x₀ moves with
//! them: ∂D_i/∂x₀_j = (∂_j g(x₀ + δ e_i) − ∂_j g(x₀ − δ e_i))/(2δ). ∇g at the roots and in that
//! turn is the signed distance's exact gradient ([`SignedDistance::gradient`], (x − c)/|x − c|
//! with c the nearest surface point); a central difference would blend the two sides of the
//! distance's creases inside a triangulated surface (inside a convex polyhedron s is the least
//! distance to the face planes, piecewise linear), and where D's stencil straddles a crease, d
//! turns quickly with x₀ (until stop 35 the chain ignored that turn, which a signed
//! distance's smooth walls would not have had: below, "Refinement near the walls"). Nodes left
//! linear go through the marching's chain as before. Against central differences of
//! re-meshed, re-solved spectra on a triangulated ellipsoid shell the relative error is 2e-8
//! (`tests/mpi_sensitivity.rs`), and the chain's weight on every class of node against the
//! nodes' own motion is checked serially (`curved_shell_chain_follows_the_nodes_on_plain_and_refined_grids`).
//! The body and its chain are the field's, not the shell's ([`curved_body`], [`FieldWeights`]):
//! the geometry task meshes its network field the same way ([`curved_field_spectrum`]), where
//! the network is smooth and the central differences serve.
//!
//! Measured (`shape_probe --curved`, ceramic, 2 ranks):
//!
//! * hollow analytic ball (R = 50 mm, t = 0.5), mean of its first five-fold cluster at 16/20/24
//!   cells: straight 20427/20348/20304 Hz, exact crossings alone 20330/20291/20265, curved
//!   20281/20256/20222. The exact-crossing series (with 32 cells: 20238) extrapolates in h² to
//!   about 20210 Hz, so the error falls from +217/+138/+94 Hz to +71/+46/+12 Hz.
//! * spot at t = 0.5 and 0.7 on the centred grid and one randomly shifted grid per size, first
//!   eight frequencies: from 20 to 28 cells they move by −6.5 … −1.0 % straight and −2.7 …
//!   −0.6 % curved; from 28 to 36 by −4.5 … −1.1 % and −1.5 … −0.4 %; from 36 to 40 by
//!   −0.89 … −0.11 % and −0.17 … +0.18 %. The two alignments differ at 36 cells by up to 0.47 %
//!   straight and 0.24 % curved. So the curved body at 36 cells is as close to the 40-cell
//!   body as the grids' alignment lets one tell, and the curved body at 20 cells is about where
//!   the straight one is at 36.
//!
//! That is why a curved-boundary fit answers with its finest level by default
//! ([`ShapeFamily::extrapolates_by_default`]; `extrapolate` in [`ShapeFitSettings`], the CLI's
//! `--extrapolate`, overrides): the line in h has no bias left to remove between 36 and 40
//! cells, only the levels' alignment noise to amplify. Seed 1, levels 20/28/32/36, 40-cell
//! target, 2 ranks, t* = 0.3 … 0.7 (`out/bench_shape/curved/`), mean absolute error of the
//! finest level / of the line (straight boundary, stop 27: line):
//!
//! | shape | finest level | line | straight, line |
//! |---|---|---|---|
//! | spot | 0.0012 (max 0.0038) | 0.0087 | 0.0072 |
//! | bob | 0.0024 (max 0.0043) | 0.0042 | 0.0055 |
//! | oloid | 0.0085 | 0.0097 | 0.0128 |
//! | turtle | 0.0234 | 0.0184 | 0.0273 |
//!
//! The choice of the finest level rests on the probe above, but was made after the spot fits
//! had been seen. What the curved boundary does not fix: the oloid's answer alternates with
//! the grid's alignment at its sharp rim (the centred 36-cell grid answers 0.010–0.015 below
//! the 28- and 32-cell ones on every target), and the turtle's cavity at t ≥ 0.6 spans a cell
//! or two (levels 0.43/0.50/0.57/0.61 for t* = 0.7). Cost: the signed-distance queries add
//! 0.3–2.4 s of meshing and 0.2–1.5 s of gradient per evaluation (0.02 and 0.25 s straight) to
//! a 2–26 s solve; 180–370 s per fit (mean 213–272 s per shape, two spot fits and one bob fit
//! shared the machine with builds).
//!
//! **Second seed, replicas of the finest level.** The oloid's alternation averages out over
//! two grids of the finest spacing; the middle levels only start the next one, so
//! [`replica_levels`] replicates the finest level alone when the answer is the finest level's,
//! and the 32-cell level, which served only the line, is gone. Seed 2, levels 20/28/36 with two
//! 36-cell grids, 40-cell target, 2 ranks (`out/bench_shape/seed2/`), finest-level mean / line
//! through all four levels:
//!
//! | shape | finest level (max) | line | s per fit (max) |
//! |---|---|---|---|
//! | oloid | 0.0019 (0.0046) | 0.0025 | 238 (298) |
//! | spot | 0.0046 (0.0118) | 0.0018 | 217 (278) |
//! | bob | 0.0028 (0.0046) | 0.0093 | 219 (254) |
//!
//! Every fit took under 300 s. Neither answer wins on both seeds: spot's finest level was the
//! better one on seed 1 (0.0012 against 0.0087) and the worse on seed 2, where at t* = 0.6 and
//! 0.7 both 36-cell grids sit 0.006–0.018 below t* while the levels still climb (0.588/0.654/
//! 0.688 at t* = 0.7): at high t spot is not converged at 36 cells, and the probe's 36 → 40
//! change above (±0.18 %) understated that.
//!
//! **With the exact-gradient chain** (stop 35, "Curved boundary" above; `seed2_exactgrad/`,
//! `seed2_turtle16_exactgrad/`, same targets): the oloid's five answers and spot's first three
//! repeat to four digits (oloid t* = 0.6: 0.5983 against 0.5980), and the turtle's five
//! (16 modes) to within 2e-4. The chain's old error, a few 1e-4 of λ/t on straddled stencils,
//! did not steer the search on these bodies; the fix is one of correctness, not of accuracy
//! here. It adds 6 gradient queries per curved node (meshing at 36 cells 1.95 s against 1.76 s
//! per turtle evaluation).
//!
//! **The turtle needs more modes.** Its first eight modes hardly see the cavity at high t:
//! from t = 0.65 to 0.8 they move by under 1.2 % in λ (36 cells), while its first mode, a thin
//! feature's, sits 7 % below the 40-cell target's at every t (`shape_probe --scan`), so the
//! 8-mode loss changes by 1.5 % over that range and its minimum goes wherever the grids'
//! alignment puts it. Modes 9–20 move by 1.5–13 % from t = 0.6 to 0.8. With 16 modes (seed 2,
//! same levels and replicas, `out/bench_shape/seed2_turtle16/`): t* = 0.3 … 0.7 → errors
//! 0.0059, 0.0025, 0.0030, 0.0015, 0.0473 (8 modes, seed 1: 0.0027, 0.0014, 0.0104, 0.0101,
//! 0.0923), mean 0.0120; 266–462 s per fit (43.7 s per 36-cell evaluation against 28.8 with 8
//! modes). At t* = 0.7 the levels still climb (0.55/0.60/0.65): its cavity is not resolved by
//! 36 cells whatever the modes. The default stays at 8 modes (`--modes`).
//!
//! **Where the thickness fit stands at high t on the turtle** (stop 31, `shape_probe --curved
//! --modes 16`, no fit): its first frequencies at t = 0.6 on 20/28/36/44 cells are 7422/6343/
//! 6101/5978 Hz (mode 1), 15414/14406/14084/13656 (mode 3), 42783/41429/39987/39443 (mode
//! 10): the first 16 still 0.6–3 % apart between 36 and 44 cells, which is as much as
//! t = 0.6 → 0.7 moves modes 9–16 (0.9–4 % at 28 cells). So no fit level at or below 36 cells can place t* = 0.7 against a
//! 40-cell target; the cheaper solve that would allow a finer level was not found either
//! (Debian's MUMPS: block low-rank, `-st_mat_mumps_icntl_35 1|2`, 43–47 s against 39 s, and it
//! let three rigid modes through; orderings AMD/AMF/QAMD 54–120 s against PORD's 39 s).
//!
//! **The turtle's floor at t* = 0.7** (stop 32, `out/bench_shape/floor_turtle/`): fitted on
//! the target's own spacing (40 cells, the centred grid, 16 modes) against 40-cell targets on
//! shifted grids, the answers were 0.6234 (seed 2) and 0.6319 (seed 3) for t* = 0.7 and 0.5978
//! for t* = 0.6. The bodies differ only in the grid's alignment, so at t* = 0.7 the alignment
//! alone moves the answer by 0.07–0.08, more than any fit level's error (the 36-cell levels of
//! seed 2: 0.047). A second fit alignment (half a cell along the diagonal) answered 0.6612 on
//! the seed-2 target: the fit's own alignments disagree by 0.038, and their mean (0.6423) is no
//! closer.
//! The information is not in the target: the alignment moves the spectrum more than t does.
//! (Stop 32 put this down to the cavity — at t = 0.7 the points deeper than 0.7 S = 11.0 mm,
//! at most 2 × 4.7 mm across — but refining the grid at the inner wall moves the frequencies by
//! under 0.11 %; the alignment acts on the thin flippers of the outer wall: "Refinement near
//! the walls" below.) The Gauss–Newton information Σ|G|J_G² at the 36-cell answer is 0.76 at t* = 0.7, against 5.2
//! at 0.6 and 74 at 0.3. At t* = 0.6 the floor is 0.002, and the fits' errors there (0.0015
//! with 16 modes) are as small. So no fit on grids of this spacing can meet 0.005 at t* = 0.7
//! on the turtle; a target on a finer grid would be needed, and the fit would have to follow it.
//! Nothing in the search was tuned to this case.
//!
//! **Where an evaluation's time goes, and the rigid motions** (stop 33). The solve is 85–90 %
//! of an evaluation (turtle, 36 cells: 39.5 of 43.7 s); in it, MUMPS's Cholesky factorisation
//! and about 70 shift-invert triangular solves (turtle t = 0.6, 28 cells: 5.2 s and 10.0 s of
//! 17.7 s, `-log_view`). The body is one free piece, so its six rigid motions are known exactly
//! and are deflated ([`eigen::solve_modes_deflated`]): SLEPc looks for 20 vectors instead of 26.
//! Side by side on the same matrices (`shape_probe --curved --ab-deflation 3`, turtle t = 0.6,
//! 16 modes, 2 ranks, `out/bench_shape/deflation_ab/`) it took 0.944 × the plain solve's time
//! at 28 cells and 1.000 × at 36; with `-eps_ncv 52` and 46 for both, 0.965 and 0.970. Single
//! rounds scattered from 0.87 to 1.08 on this machine, so the gain is a few per cent at most,
//! not the 12 % that asking for 20 instead of 26 eigenpairs (rigid modes still in) suggested.
//! What it does buy: no rigid motion can leak into the elastic modes (block low-rank MUMPS let
//! three through), and a deflated vector that is not a rigid motion is refused.
//!
use super::{BackgroundGrid, MarchingOptions, MarchingReport, SignedDistance};
use crate::assembly;
use crate::eigen::sensitivity::{node_gradients, ClusterTreatment};
use crate::eigen::{self, EigenConfig, ModeRequest};
use crate::fem::Material;
use crate::mesh;
use crate::mesh::{lift_to_quadratic, linear_node_gradient, TetMesh};
use crate::petsc::{collective, Petsc};
use std::ops::Range;

/// Why a shape evaluation or fit failed.
#[derive(Debug, thiserror::Error)]
pub enum ShapeError {
    #[error("meshing: {0}")]
    Marching(#[from] super::MarchingError),
    #[error("{0}")]
    Surface(#[from] super::SurfaceError),
    #[error("the field encloses no body (every value ≤ 0)")]
    Empty,
    #[error("{0}")]
    Solver(String),
    #[error("{0}")]
    Invalid(String),
}

/// Seconds spent in each part of one evaluation.
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct StepTimings {
    pub meshing: f64,
    pub assembly: f64,
    pub solve: f64,
    pub gradient: f64,
}

impl StepTimings {
    pub fn total(&self) -> f64 {
        self.meshing + self.assembly + self.solve + self.gradient
    }
}

/// The spectrum of the body inside a field, and optionally its gradient.
#[derive(Clone, Debug)]
pub struct ShapeSpectrum {
    /// First `n` elastic eigenvalues, ascending [rad²/s²]; rank 0's, on every rank.
    pub eigenvalues: Vec<f64>,
    /// dλ_k/ds_i per mode k and grid vertex i [rad²/s² per unit of s]; on every rank.
    pub gradient: Option<Vec<Vec<f64>>>,
    /// Near-degenerate clusters among the first `n` modes (index ranges): their members carry
    /// the cluster-mean gradient.
    pub clusters: Vec<Range<usize>>,
    pub report: MarchingReport,
    pub tets: usize,
    pub p2_nodes: usize,
    /// Volume of the marched body [m³].
    pub volume: f64,
    pub timings: StepTimings,
}

/// Meshes the field, solves the first `n_modes` elastic modes, and (if asked) their gradients
/// with respect to the field values. Collective: every rank passes the same field.
pub fn shape_spectrum(
    petsc: &Petsc,
    grid: &BackgroundGrid,
    values: &[f64],
    options: &MarchingOptions,
    material: &Material,
    n_modes: usize,
    with_gradient: bool,
) -> Result<ShapeSpectrum, ShapeError> {
    if values.iter().all(|v| *v <= 0.0) {
        return Err(ShapeError::Empty);
    }
    let mut timings = StepTimings::default();
    let t = std::time::Instant::now();
    let marched = super::march(grid, values, None, options)?;
    let linear = &marched.mesh;
    let quadratic = lift_to_quadratic(linear);
    timings.meshing = t.elapsed().as_secs_f64();
    // dλ_k/ds_i: through the P1 corners and the marching.
    let to_samples = |per_node: &[Vec<f64>]| -> Result<Vec<f64>, ShapeError> {
        let mut flat = Vec::with_capacity(per_node.len() * grid.n_vertices());
        for g in per_node {
            let corners = linear_node_gradient(linear, &quadratic, g)
                .map_err(|e| ShapeError::Solver(e.to_string()))?;
            flat.extend(marched.vjp(&corners)?.values);
        }
        Ok(flat)
    };
    let carry = with_gradient.then_some(Carry {
        len: grid.n_vertices(),
        map: &to_samples,
    });
    let (eigenvalues, clusters, gradient) =
        solve_and_carry(petsc, &quadratic, material, n_modes, &mut timings, carry)?;
    Ok(ShapeSpectrum {
        eigenvalues,
        gradient,
        clusters,
        report: marched.report.clone(),
        tets: linear.n_tets(),
        p2_nodes: quadratic.n_nodes(),
        volume: linear.volume(),
        timings,
    })
}

/// How rank 0's node gradients of the first n modes (3 per P2 node each) become numbers of the
/// field: `len` per mode, mode after mode.
struct Carry<'a> {
    len: usize,
    map: &'a ModeMap<'a>,
}

/// Maps the modes' node fields to the carried field.
type ModeMap<'a> = dyn Fn(&[Vec<f64>]) -> Result<Vec<f64>, ShapeError> + 'a;

/// What every spectrum of a meshed body shares: assembles and solves `quadratic`, gives every
/// rank rank 0's first `n_modes` eigenvalues and their clusters and, with `carry`, carries rank
/// 0's node gradients to the field there (only rank 0 holds them) and shares the rows, one per
/// mode. Adds the assembly, solve and gradient times to `timings`. Collective.
#[allow(clippy::type_complexity)]
fn solve_and_carry(
    petsc: &Petsc,
    quadratic: &TetMesh,
    material: &Material,
    n_modes: usize,
    timings: &mut StepTimings,
    carry: Option<Carry>,
) -> Result<(Vec<f64>, Vec<Range<usize>>, Option<Vec<Vec<f64>>>), ShapeError> {
    let (assembled, modes) = assemble_and_solve(petsc, quadratic, material, n_modes, timings)?;
    let mut eigenvalues: Vec<f64> = modes.eigenvalues[..n_modes].to_vec();
    collective::broadcast_slice(petsc, &mut eigenvalues);
    let clusters = modes
        .clusters
        .iter()
        .filter(|r| r.start < n_modes)
        .map(|r| r.start..r.end.min(n_modes))
        .collect();
    let rows = match carry {
        Some(carry) => {
            let clock = std::time::Instant::now();
            let per_node = node_gradients(
                petsc,
                quadratic,
                &assembled.layout,
                &modes,
                material,
                ClusterTreatment::Mean,
            )
            .map_err(|e| ShapeError::Solver(e.to_string()))?;
            // Only rank 0 carries; its failure must reach the ranks waiting for its rows.
            let carried = per_node
                .map(|per_node| (carry.map)(&per_node[..n_modes]).map_err(|e| e.to_string()));
            let flat = collective::share_from_root(petsc, carried, n_modes * carry.len)
                .map_err(ShapeError::Solver)?;
            timings.gradient = clock.elapsed().as_secs_f64();
            Some(flat.chunks(carry.len.max(1)).map(<[f64]>::to_vec).collect())
        }
        None => None,
    };
    Ok((eigenvalues, clusters, rows))
}

/// A crossing vertex moved onto the zero of the continuous field along its grid edge.
#[derive(Clone, Copy, Debug)]
pub struct ExactCrossing {
    /// Node index in the marched mesh.
    pub node: usize,
    /// The point [m].
    pub position: [f64; 3],
    /// x_b − x_a [m].
    pub edge: [f64; 3],
    /// df/du at the root, u the fraction along the edge (from the root finder's last bracket).
    pub slope: f64,
}

/// Moves every crossing of `marched` from the linear estimate to the zero of the continuous
/// field `f` along its grid edge (Illinois regula falsi on u ∈ (0, 1), to |Δu| ≤ 1e-9, the
/// root kept at least `margin` from either end so that no piece degenerates). A crossing whose
/// move would invert or flatten a tet keeps its linear position. Returns the moved linear mesh,
/// the moved crossings and how many were kept linear.
pub fn refine_crossings(
    marched: &super::MarchedMesh,
    grid: &BackgroundGrid,
    f: &dyn Fn([f64; 3]) -> f64,
    gradient: Option<super::FieldGradient>,
    margin: f64,
) -> (TetMesh, Vec<ExactCrossing>, usize) {
    let mut out = marched.mesh.clone();
    let mut moved = Vec::new();
    for (node, origin) in marched.origins.iter().enumerate() {
        let super::VertexOrigin::Crossing { a, b, t } = *origin else {
            continue;
        };
        let (xa, xb) = (grid.vertex_position(a), grid.vertex_position(b));
        let edge = [0, 1, 2].map(|d| xb[d] - xa[d]);
        let at = |u: f64| f([0, 1, 2].map(|d| xa[d] + u * edge[d]));
        let (mut u0, mut f0, mut u1, mut f1) = (0.0, at(0.0), 1.0, at(1.0));
        if !(f0 * f1 < 0.0) {
            continue;
        }
        // Illinois: regula falsi that halves the stale end's value.
        let mut u = t;
        let mut fu = at(u);
        let mut side = 0;
        for _ in 0..40 {
            if fu == 0.0 || (u1 - u0) <= 1e-9 {
                break;
            }
            if fu * f0 > 0.0 {
                (u0, f0) = (u, fu);
                if side == -1 {
                    f1 *= 0.5;
                }
                side = -1;
            } else {
                (u1, f1) = (u, fu);
                if side == 1 {
                    f0 *= 0.5;
                }
                side = 1;
            }
            u = (u0 * f1 - u1 * f0) / (f1 - f0);
            fu = at(u);
        }
        let u = u.clamp(margin, 1.0 - margin);
        let position = [0, 1, 2].map(|d| xa[d] + u * edge[d]);
        let slope = match gradient.and_then(|g| g(position)) {
            Some(g) => (0..3).map(|d| g[d] * edge[d]).sum(),
            None => {
                let h = 1e-4;
                (at((u + h).min(1.0)) - at((u - h).max(0.0)))
                    / ((u + h).min(1.0) - (u - h).max(0.0))
            }
        };
        out.nodes[node] = position;
        moved.push(ExactCrossing {
            node,
            position,
            edge,
            slope,
        });
    }
    // Undo the moves around any tet that lost its orientation.
    let mut kept_linear = 0;
    let tol = mesh::ZERO_VOLUME_RELATIVE_TOLERANCE * {
        let (lo, hi) = marched.mesh.bounding_box();
        (0..3)
            .map(|d| (hi[d] - lo[d]).powi(2))
            .sum::<f64>()
            .sqrt()
            .powi(3)
    };
    let mut revert = vec![false; out.nodes.len()];
    for e in 0..out.n_tets() {
        if out.corner_volume(e) <= tol {
            for &n in out.tet(e) {
                revert[n] = true;
            }
        }
    }
    if revert.iter().any(|&r| r) {
        moved.retain(|c| {
            if revert[c.node] {
                out.nodes[c.node] = marched.mesh.nodes[c.node];
                kept_linear += 1;
                false
            } else {
                true
            }
        });
    }
    (out, moved, kept_linear)
}

/// A body marched from field samples with its crossings on the zero of the continuous field f
/// along their grid edges and its boundary mid-edge nodes on f = 0 (module docs, "Curved
/// boundary"): the thickness fit's shell and the geometry task's network field both use it.
pub struct CurvedBody {
    /// The marching of the samples (topology, and the crossings' grid edges).
    pub marched: super::MarchedMesh,
    /// The linear mesh with exact crossings.
    pub linear: TetMesh,
    pub crossings: Vec<ExactCrossing>,
    /// Crossings left at the linear estimate (a move would have folded a tet).
    pub crossings_kept_linear: usize,
    /// The P2 mesh with its boundary mid-edge nodes on the surface.
    pub quadratic: TetMesh,
    pub curved: Vec<super::CurvedNode>,
    pub curving: super::CurvingReport,
    /// ∂D/∂p₀ (the central-difference Hessian of f) at every moved mid-edge node's midpoint,
    /// when asked for ([`curved_body`]): the direction of move also turns as p₀ moves.
    pub hessians: Option<Vec<[[f64; 3]; 3]>>,
}

/// Where one mode's gradient goes when f depends on a parameter p (module docs, "Curved
/// boundary"): dλ/dp = Σ_i grid_i ∂s_i/∂p + Σ_c crossings_c ∂f(x_c)/∂p + Σ_m curved_m ∂f(x_m)/∂p,
/// with s_i the samples (they still move the crossings kept linear) and x_c, x_m the moved
/// crossings and mid-edge nodes ([`CurvedBody::moved_points`], in that order), plus the turn
/// of each mid-edge node's direction of move: Σ_m Σ_d turns_m,d (∂f(p₀_m + δ e_d)/∂p −
/// ∂f(p₀_m − δ e_d)/∂p)/(2δ) ([`super::CurvedNode`]'s docs; [`CurvedBody::turn_points`]).
#[derive(Clone, Debug)]
pub struct FieldWeights {
    pub grid: Vec<f64>,
    pub crossings: Vec<f64>,
    pub curved: Vec<f64>,
    /// b = u (I − n nᵀ) T/|D f(p₀)| per moved mid-edge node.
    pub turns: Vec<[f64; 3]>,
}

/// Marches `values` on `grid`, moves every crossing onto the zero of `f` along its grid edge
/// ([`refine_crossings`]) and every boundary mid-edge node onto it along ∇f
/// ([`super::curve_boundary`]). With `hessians`, also ∂D/∂p₀ at every moved mid-edge node
/// ([`CurvedBody::field_weights`]): 6 evaluations of the exact `gradient` per node, or 13 more
/// of f without it. A signed distance needs it where a difference stencil straddles one of its
/// creases (module docs, "Curved boundary"); a general field's direction turns with the field
/// too (the geometry task's network: 0.3 % of Σ G·dx/dp on a wavy field without it). `gradient`,
/// f's exact gradient where known, also serves ∇f at the crossings and the curved nodes' roots.
pub fn curved_body(
    grid: &BackgroundGrid,
    values: &[f64],
    f: &dyn Fn([f64; 3]) -> f64,
    gradient: Option<super::FieldGradient>,
    options: &MarchingOptions,
    hessians: bool,
) -> Result<CurvedBody, ShapeError> {
    if values.iter().all(|v| *v <= 0.0) {
        return Err(ShapeError::Empty);
    }
    let marched = super::march(grid, values, None, options)?;
    let (linear, crossings, crossings_kept_linear) =
        refine_crossings(&marched, grid, f, gradient, 0.01);
    let straight = lift_to_quadratic(&linear);
    let (quadratic, curved, curving) = super::curve_boundary(
        &straight,
        f,
        gradient,
        CURVE_MAX_FRACTION,
        CURVE_MIN_JACOBIAN_RATIO,
    );
    let hessians = hessians.then(|| {
        curved
            .iter()
            .map(|c| difference_hessian(f, gradient, c.origin, c.difference_step))
            .collect()
    });
    Ok(CurvedBody {
        marched,
        linear,
        crossings,
        crossings_kept_linear,
        quadratic,
        curved,
        curving,
        hessians,
    })
}

/// ∂D_d/∂p_e of the central difference D_d(p) = (f(p + δ e_d) − f(p − δ e_d))/(2δ) at p:
/// with the exact gradient, (∂_e f(p + δ e_d) − ∂_e f(p − δ e_d))/(2δ), exact also where a
/// crease of f passes between the stencil's points; otherwise by central differences of step
/// δ again (symmetric).
fn difference_hessian(
    f: &dyn Fn([f64; 3]) -> f64,
    gradient: Option<super::FieldGradient>,
    p: [f64; 3],
    step: f64,
) -> [[f64; 3]; 3] {
    if let Some(gradient) = gradient {
        let at = |d: usize, sign: f64| {
            let mut q = p;
            q[d] += sign * step;
            gradient(q)
        };
        let mut h = [[0.0; 3]; 3];
        let mut exact = true;
        for (d, row) in h.iter_mut().enumerate() {
            match (at(d, 1.0), at(d, -1.0)) {
                (Some(plus), Some(minus)) => {
                    *row = [0, 1, 2].map(|e| (plus[e] - minus[e]) / (2.0 * step))
                }
                _ => exact = false,
            }
        }
        if exact {
            return h;
        }
    }
    let at = |moves: &[(usize, f64)]| {
        let mut q = p;
        for &(d, s) in moves {
            q[d] += s * step;
        }
        f(q)
    };
    let centre = at(&[]);
    let mut h = [[0.0; 3]; 3];
    // Index loops: the symmetric 3×3 fill reads as the formula.
    #[allow(clippy::needless_range_loop)]
    for d in 0..3 {
        // D_d at p ± δ e_d differs by (f(p + 2δ e_d) − 2 f(p) + f(p − 2δ e_d))/(2δ).
        h[d][d] = (at(&[(d, 2.0)]) - 2.0 * centre + at(&[(d, -2.0)])) / (4.0 * step * step);
        for e in d + 1..3 {
            let v = (at(&[(d, 1.0), (e, 1.0)])
                - at(&[(d, 1.0), (e, -1.0)])
                - at(&[(d, -1.0), (e, 1.0)])
                + at(&[(d, -1.0), (e, -1.0)]))
                / (4.0 * step * step);
            h[d][e] = v;
            h[e][d] = v;
        }
    }
    h
}

/// A boundary mid-edge node moves at most this fraction of its edge's length.
const CURVE_MAX_FRACTION: f64 = 0.5;
/// A curved tet keeps det J at least this fraction of its straight det J everywhere.
const CURVE_MIN_JACOBIAN_RATIO: f64 = 0.05;

impl CurvedBody {
    /// The moved crossings, then the moved mid-edge nodes: where [`FieldWeights`] apply.
    pub fn moved_points(&self) -> Vec<[f64; 3]> {
        self.crossings
            .iter()
            .map(|c| c.position)
            .chain(self.curved.iter().map(|c| c.position))
            .collect()
    }

    /// A mode's P2 node gradient `node_gradient` (3 per node, [rad²/(s²·m)]) carried to the
    /// field: a node on f(x; p) = 0 moved along a fixed direction d has
    /// dx = d·(−∇f·dx₀ − ∂f/∂p dp)/(∇f·d). For a crossing d is its grid edge and x₀ a fixed grid
    /// vertex; for a mid-edge node d is its direction of move and x₀ the midpoint of its
    /// corners, so the rest of its gradient, G − (G·d/∇f·d) ∇f, goes to the corners. Corners
    /// that are crossings kept linear go through the marching to the samples.
    pub fn field_weights(&self, node_gradient: &[f64]) -> Result<FieldWeights, ShapeError> {
        let mut g = node_gradient.to_vec();
        let mut curved = Vec::with_capacity(self.curved.len());
        let mut turns = Vec::with_capacity(self.curved.len());
        for (m, c) in self.curved.iter().enumerate() {
            let gm = [g[3 * c.node], g[3 * c.node + 1], g[3 * c.node + 2]];
            let along = (0..3).map(|d| gm[d] * c.direction[d]).sum::<f64>() / c.slope;
            curved.push(-along);
            let rest = [0, 1, 2].map(|d| gm[d] - along * c.gradient[d]);
            let normal: f64 = (0..3).map(|d| rest[d] * c.direction[d]).sum();
            let turn = [0, 1, 2]
                .map(|d| c.offset * (rest[d] - normal * c.direction[d]) / c.origin_gradient_norm);
            // The turn as p₀ moves: b·(∂D/∂p₀) dp₀ goes to p₀ with the rest.
            let to_origin = match &self.hessians {
                Some(h) => {
                    let h = &h[m];
                    [0, 1, 2].map(|e| rest[e] + (0..3).map(|d| turn[d] * h[d][e]).sum::<f64>())
                }
                None => rest,
            };
            turns.push(turn);
            for d in 0..3 {
                g[3 * c.node + d] = to_origin[d];
            }
        }
        let mut corners = linear_node_gradient(&self.linear, &self.quadratic, &g)
            .map_err(|e| ShapeError::Solver(e.to_string()))?;
        let mut crossings = Vec::with_capacity(self.crossings.len());
        for c in &self.crossings {
            let gc = &mut corners[3 * c.node..3 * c.node + 3];
            let along: f64 = (0..3).map(|d| gc[d] * c.edge[d]).sum();
            crossings.push(-along / c.slope);
            gc.iter_mut().for_each(|x| *x = 0.0);
        }
        let back = self.marched.vjp(&corners)?;
        Ok(FieldWeights {
            grid: back.values,
            crossings,
            curved,
            turns,
        })
    }

    /// p₀ ± δ e_d for every moved mid-edge node, in the order of [`Self::turn_weights`].
    pub fn turn_points(&self) -> Vec<[f64; 3]> {
        let mut out = Vec::with_capacity(6 * self.curved.len());
        for c in &self.curved {
            for d in 0..3 {
                for sign in [1.0, -1.0] {
                    let mut p = c.origin;
                    p[d] += sign * c.difference_step;
                    out.push(p);
                }
            }
        }
        out
    }

    /// The weights ±b_d/(2δ) of `turns` at [`Self::turn_points`].
    pub fn turn_weights(&self, turns: &[[f64; 3]]) -> Vec<f64> {
        let mut out = Vec::with_capacity(6 * turns.len());
        for (c, b) in self.curved.iter().zip(turns) {
            for bd in b {
                let w = bd / (2.0 * c.difference_step);
                out.extend([w, -w]);
            }
        }
        out
    }
}

/// The body of a hollow shell 0 < s ≤ t·S meshed with its crossings on the continuous
/// field's zero and a curved P2 boundary (module docs, "Curved boundary").
pub struct CurvedShell {
    pub body: CurvedBody,
    pub shell: super::Shell,
}

/// Meshes the shell of relative thickness `t` of the solid whose signed distance is `sdf`
/// (sampled on `grid` as `solid`) with reference depth `depth` = S [m]: [`curved_body`] of
/// the samples of g = min(s, t·S − s) with the continuous g.
pub fn curved_shell(
    grid: &BackgroundGrid,
    solid: &[f64],
    sdf: &SignedDistance,
    depth: f64,
    t: f64,
    options: &MarchingOptions,
) -> Result<CurvedShell, ShapeError> {
    let shell = super::shell_of_depth(solid, t, depth)?;
    let wall = t * depth;
    let g = |x: [f64; 3]| {
        let s = sdf.signed_distance(x);
        s.min(wall - s)
    };
    // The exact gradient (central differences blend the two sides of the distance's creases),
    // for the roots and the turn of the mid-edge nodes' directions with their corners (module
    // docs, "Curved boundary"), except right on the outer wall s = 0, where the nearest point's
    // direction is lost in rounding: the roots there keep central differences.
    let dg = |x: [f64; 3]| {
        let (s, ds) = sdf.value_and_gradient(x);
        if s.abs() < 1e-6 * depth {
            return None;
        }
        ds.map(|ds| if s <= wall - s { ds } else { ds.map(|c| -c) })
    };
    let body = curved_body(grid, &shell.values, &g, Some(&dg), options, true)?;
    Ok(CurvedShell { body, shell })
}

impl CurvedShell {
    /// dλ/dt per mode from the P2 node gradients of every mode (rank 0's `per_node`, 3 per
    /// node): [`CurvedBody::field_weights`] with ∂g/∂t = S on the inner wall (s > t·S/2
    /// there) and 0 on the outer one, and the samples' share through the shell. The mid-edge
    /// nodes' directions turn with their corners (the body's Hessians), not with t directly:
    /// ∂g/∂t is the same at p₀ ± δ e_d, so the turn points carry no weight.
    pub(crate) fn thickness_derivatives(
        &self,
        sdf: &SignedDistance,
        depth: f64,
        per_node: &[Vec<f64>],
    ) -> Result<Vec<f64>, ShapeError> {
        let wall = self.shell.thickness * depth;
        let dg_dt: Vec<f64> = self
            .body
            .moved_points()
            .into_iter()
            .map(|x| {
                if sdf.signed_distance(x) > 0.5 * wall {
                    depth
                } else {
                    0.0
                }
            })
            .collect();
        let mut out = Vec::with_capacity(per_node.len());
        for g in per_node {
            let w = self.body.field_weights(g)?;
            let direct: f64 = w
                .crossings
                .iter()
                .chain(&w.curved)
                .zip(&dg_dt)
                .map(|(a, b)| a * b)
                .sum();
            out.push(direct + self.shell.vjp(&w.grid)?.thickness);
        }
        Ok(out)
    }
}

/// The spectrum of [`curved_shell`] and, if asked, dλ_k/dt. Collective.
#[allow(clippy::too_many_arguments)]
pub fn curved_shell_spectrum(
    petsc: &Petsc,
    grid: &BackgroundGrid,
    solid: &[f64],
    sdf: &SignedDistance,
    depth: f64,
    t: f64,
    options: &MarchingOptions,
    material: &Material,
    n_modes: usize,
    with_gradient: bool,
) -> Result<(ShapeSpectrum, Option<Vec<f64>>), ShapeError> {
    let mut timings = StepTimings::default();
    let clock = std::time::Instant::now();
    let shell = curved_shell(grid, solid, sdf, depth, t, options)?;
    timings.meshing = clock.elapsed().as_secs_f64();
    let to_thickness = |per_node: &[Vec<f64>]| shell.thickness_derivatives(sdf, depth, per_node);
    let carry = with_gradient.then_some(Carry {
        len: 1,
        map: &to_thickness,
    });
    let (eigenvalues, clusters, rows) = solve_and_carry(
        petsc,
        &shell.body.quadratic,
        material,
        n_modes,
        &mut timings,
        carry,
    )?;
    let derivative = rows.map(|rows| rows.into_iter().map(|r| r[0]).collect());
    Ok((
        body_spectrum(&shell.body, eigenvalues, clusters, timings),
        derivative,
    ))
}

fn body_spectrum(
    body: &CurvedBody,
    eigenvalues: Vec<f64>,
    clusters: Vec<Range<usize>>,
    timings: StepTimings,
) -> ShapeSpectrum {
    ShapeSpectrum {
        eigenvalues,
        gradient: None,
        clusters,
        report: body.marched.report.clone(),
        tets: body.linear.n_tets(),
        p2_nodes: body.quadratic.n_nodes(),
        volume: body.linear.volume(),
        timings,
    }
}

/// A spectrum's gradient with respect to a field given as weights at points: dλ_k/dp =
/// Σ_j per_mode[k][j] ∂f(points_j)/∂p for any parameter p of the field f (the network's
/// backpropagation at those points, for the geometry task).
#[derive(Clone, Debug)]
pub struct PointGradient {
    pub points: Vec<[f64; 3]>,
    pub per_mode: Vec<Vec<f64>>,
}

/// The spectrum of [`curved_body`] of the samples `values` of the continuous field `f` and,
/// if asked, its gradient as weights at the grid vertices, the moved points and the turn
/// points ([`PointGradient`]). Collective: every rank passes the same field.
#[allow(clippy::too_many_arguments)]
pub fn curved_field_spectrum(
    petsc: &Petsc,
    grid: &BackgroundGrid,
    values: &[f64],
    f: &dyn Fn([f64; 3]) -> f64,
    options: &MarchingOptions,
    material: &Material,
    n_modes: usize,
    with_gradient: bool,
) -> Result<(ShapeSpectrum, Option<PointGradient>), ShapeError> {
    let mut timings = StepTimings::default();
    let clock = std::time::Instant::now();
    // The Hessians serve the gradient alone.
    let body = curved_body(grid, values, f, None, options, with_gradient)?;
    timings.meshing = clock.elapsed().as_secs_f64();
    // Where the weights apply (the gradient alone needs them).
    let points: Vec<[f64; 3]> = if with_gradient {
        grid.vertex_positions()
            .into_iter()
            .chain(body.moved_points())
            .chain(body.turn_points())
            .collect()
    } else {
        Vec::new()
    };
    let to_points = |per_node: &[Vec<f64>]| -> Result<Vec<f64>, ShapeError> {
        let mut flat = Vec::with_capacity(per_node.len() * points.len());
        for g in per_node {
            let w = body.field_weights(g)?;
            flat.extend(w.grid.iter().chain(&w.crossings).chain(&w.curved));
            flat.extend(body.turn_weights(&w.turns));
        }
        Ok(flat)
    };
    let carry = with_gradient.then_some(Carry {
        len: points.len(),
        map: &to_points,
    });
    let (eigenvalues, clusters, rows) = solve_and_carry(
        petsc,
        &body.quadratic,
        material,
        n_modes,
        &mut timings,
        carry,
    )?;
    let gradient = rows.map(|per_mode| PointGradient { points, per_mode });
    Ok((
        body_spectrum(&body, eigenvalues, clusters, timings),
        gradient,
    ))
}

/// The modes of [`curved_body`] with their shapes (for writing a fitted body). Collective.
pub fn curved_field_modes(
    petsc: &Petsc,
    grid: &BackgroundGrid,
    values: &[f64],
    f: &dyn Fn([f64; 3]) -> f64,
    options: &MarchingOptions,
    material: &Material,
    n_modes: usize,
) -> Result<ShapeModes, ShapeError> {
    let body = curved_body(grid, values, f, None, options, false)?;
    modes_of_mesh(
        petsc,
        body.quadratic,
        body.marched.report.clone(),
        material,
        n_modes,
    )
}

/// Assembles the P2 mesh and solves its first `n_modes` elastic modes (the count proven by the
/// solver's cluster completion, not by an inertia check: that would be a second factorisation
/// per evaluation).
fn assemble_and_solve<'p>(
    petsc: &'p Petsc,
    quadratic: &TetMesh,
    material: &Material,
    n_modes: usize,
    timings: &mut StepTimings,
) -> Result<(assembly::Assembled<'p>, eigen::Modes<'p>), ShapeError> {
    // Marched meshes have slivers, and on two ranks MUMPS's workspace estimate fell short on
    // some of them (INFOG(1) = −9 on a hollow box at 14 cells): the solver's one factor path
    // factors again with a larger workspace and keeps it for the later evaluations
    // (`petsc::factor`).
    let t = std::time::Instant::now();
    let assembled =
        assembly::assemble(petsc, quadratic).map_err(|e| ShapeError::Solver(e.to_string()))?;
    let (k, m) = assembled
        .operators(material)
        .map_err(|e| ShapeError::Solver(e.to_string()))?;
    timings.assembly = t.elapsed().as_secs_f64();
    let t = std::time::Instant::now();
    let (lo, hi) = quadratic.bounding_box();
    let diagonal = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
    let mut cfg = EigenConfig::new(
        ModeRequest::FirstN(n_modes),
        eigen::spectrum_scale(material.lame_mu(), material.density, diagonal),
    );
    cfg.verify_count = false;
    // The marched body is one free piece (its largest component): its six rigid motions are
    // known; deflated, they cannot leak into the elastic modes (measured speed-up: a few per
    // cent at most, module docs).
    let rigid = eigen::rigid_body_vectors(&k, &assembled.layout, &quadratic.nodes)
        .map_err(|e| ShapeError::Solver(e.to_string()))?;
    let modes = eigen::solve_modes_deflated(petsc, &k, &m, &cfg, &rigid)
        .map_err(|e| ShapeError::Solver(e.to_string()))?;
    if modes.eigenvalues.len() < n_modes {
        return Err(ShapeError::Solver(format!(
            "the solve gave {} elastic modes, {n_modes} wanted",
            modes.eigenvalues.len()
        )));
    }
    timings.solve = t.elapsed().as_secs_f64();
    Ok((assembled, modes))
}

/// The modes of the body inside a field, with the P2 mesh and mode shapes for output.
#[derive(Clone, Debug)]
pub struct ShapeModes {
    /// The P2 mesh of the body [m] (10-node tets, Gmsh order).
    pub mesh: TetMesh,
    /// Elastic eigenvalues, ascending [rad²/s²] (at least the `n` asked for; a cluster that
    /// straddles the n-th mode is completed).
    pub eigenvalues: Vec<f64>,
    /// Mass-normalised mode shapes, 3 per node (node-major x, y, z) in mesh order, the entry of
    /// largest magnitude positive; on rank 0 only (empty elsewhere).
    pub shapes: Vec<Vec<f64>>,
    pub residuals: Vec<f64>,
    pub rigid_eigenvalues: Vec<f64>,
    pub clusters: Vec<Range<usize>>,
    pub report: MarchingReport,
}

/// Meshes the field and solves the first `n_modes` modes with their shapes (for writing the
/// fitted body). Collective.
pub fn shape_modes(
    petsc: &Petsc,
    grid: &BackgroundGrid,
    values: &[f64],
    options: &MarchingOptions,
    material: &Material,
    n_modes: usize,
) -> Result<ShapeModes, ShapeError> {
    if values.iter().all(|v| *v <= 0.0) {
        return Err(ShapeError::Empty);
    }
    let marched = super::march(grid, values, None, options)?;
    modes_of_mesh(
        petsc,
        lift_to_quadratic(&marched.mesh),
        marched.report.clone(),
        material,
        n_modes,
    )
}

pub(crate) fn modes_of_mesh(
    petsc: &Petsc,
    quadratic: TetMesh,
    report: MarchingReport,
    material: &Material,
    n_modes: usize,
) -> Result<ShapeModes, ShapeError> {
    let mut timings = StepTimings::default();
    let (assembled, modes) =
        assemble_and_solve(petsc, &quadratic, material, n_modes, &mut timings)?;
    let mut shapes = assembled
        .layout
        .gather_original_order(&modes.vectors)
        .map_err(|e| ShapeError::Solver(e.to_string()))?;
    for s in &mut shapes {
        let largest = s
            .iter()
            .copied()
            .fold(0.0_f64, |m, x| if x.abs() > m.abs() { x } else { m });
        if largest < 0.0 {
            s.iter_mut().for_each(|x| *x = -*x);
        }
    }
    Ok(ShapeModes {
        eigenvalues: modes.eigenvalues.clone(),
        residuals: modes.residuals.clone(),
        rigid_eigenvalues: modes.rigid_eigenvalues.clone(),
        clusters: modes.clusters.clone(),
        shapes,
        report,
        mesh: quadratic,
    })
}
