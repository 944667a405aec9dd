//! Shape from sound: the spectrum of the body an implicit field encloses, its exact gradient
//! with respect to the field, and the one-parameter fits built on it (issue 7): the relative
//! thickness of a hollow body and the weight of a morph between two shapes.
//!
//! # The chain
//!
//! A field s_i on the vertices of a background tet grid ([`BackgroundGrid`], positive inside)
//! is meshed by marching tetrahedra ([`crate::mesh::march`]); the P1 mesh is lifted to P2
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
//! only; [`crate::mesh::MarchedMesh::vjp`]). Grid vertices that are mesh corners do not move
//! with s. The topology (which tets exist) is piecewise constant in s, so the gradient is that of
//! the current mesh; it is exact between topology changes.
//!
//! # Shapes, units and alignment
//!
//! Surfaces (OBJ, or the boundary of a Gmsh tet mesh, [`read_surface`]) are placed by
//! [`normalise_surface`]: the bounding box is centred on the origin and scaled uniformly to a
//! bounding-box diagonal D (the benchmarks use D = 0.1 m), so every shape has the same size and
//! frequency range and two shapes to be morphed overlap around the origin with their own
//! orientation. The signed distance s [m] ([`SignedDistance`], positive inside) is sampled on a
//! grid of cubic cells whose longest axis has N cells ([`SampledField::of_sdf`], one cell of
//! margin; for a morph, one grid over the union of both boxes).
//!
//! # Thickness
//!
//! A hollow body of relative thickness t is the set 0 < s ≤ t·S of the solid's signed distance
//! s, with S the depth of the solid's deepest point (the radius of its largest inscribed ball,
//! [`SignedDistance::deepest_point`], [`reference_depth`]). Marched as
//! g = min(s, t·S − s) ([`crate::mesh::shell_of_depth`]); dg/dt = S on the inner branch.
//! S is taken from the continuous distance, once per surface, not from the grid samples: the
//! largest sample misses S by up to h√3/2, and t·S with the sampled maximum moved the inner
//! wall by a different amount on every grid (spot: 11.42 mm at 14 cells, 13.95 at 20, 13.21 at
//! 32 against S = 14.217 mm), a bias of up to 20 % in t between the fit and a finer target
//! grid — the main reason the first fits missed by 0.13.
//!
//! # Morphing
//!
//! m = c·A + (1 − c)·B of two signed distances on one grid ([`crate::mesh::morph`]);
//! dm/dc = A − B, through [`crate::mesh::morph_vjp`]. c = 1 is shape A, c = 0 shape B.
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
//! # Curved boundary (thickness)
//!
//! Everything above describes the body marched from the grid samples alone: crossings linearly
//! interpolated, P2 edges straight. The thickness fit knows more: the continuous signed
//! distance s of the solid, so the shell's continuous field g(x) = min(s(x), t·S − s(x)) can be
//! evaluated anywhere. By default ([`ShapeFamily::Thickness`] with `surface`, the CLI's
//! default; `--straight-boundary` for the samples alone) the body is meshed by
//! [`curved_shell`]: the marching's topology from the samples, every crossing moved onto the
//! zero of g along its grid edge ([`refine_crossings`]), and every mid-edge node of a boundary
//! edge moved onto it along ∇g ([`mesh::curve_boundary`]; a move that would fold a tet is undone,
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
//! # Refinement near the walls (thickness)
//!
//! The turtle's high-t targets were put down (stop 32) to its cavity not being resolved. The
//! cavity is not what moves: refining the background grid only near the inner walls
//! ([`refine_near_wall`]: longest-edge bisection of the Kuhn tets, [`crate::mesh::refine`])
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

use crate::assembly;
use crate::eigen::sensitivity::{node_gradients, ClusterTreatment};
use crate::eigen::{self, EigenConfig, ModeRequest};
use crate::fem::Material;
use crate::mesh::{
    self, lift_to_quadratic, linear_node_gradient, BackgroundGrid, MarchingOptions, MarchingReport,
    SignedDistance, TetMesh, TriangleSurface,
};
use crate::petsc::{collective, Petsc};
use std::ops::Range;
use std::path::Path;
use std::sync::Arc;

/// Why a shape evaluation or fit failed.
#[derive(Debug, thiserror::Error)]
pub enum ShapeError {
    #[error("meshing: {0}")]
    Marching(#[from] mesh::MarchingError),
    #[error("{0}")]
    Surface(#[from] mesh::SurfaceError),
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
    let marched = mesh::march(grid, values, None, options)?;
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
    map: &'a dyn Fn(&[Vec<f64>]) -> Result<Vec<f64>, ShapeError>,
}

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
    marched: &mesh::MarchedMesh,
    grid: &BackgroundGrid,
    f: &dyn Fn([f64; 3]) -> f64,
    gradient: Option<mesh::FieldGradient>,
    margin: f64,
) -> (TetMesh, Vec<ExactCrossing>, usize) {
    let mut out = marched.mesh.clone();
    let mut moved = Vec::new();
    for (node, origin) in marched.origins.iter().enumerate() {
        let mesh::VertexOrigin::Crossing { a, b, t } = *origin else {
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
    pub marched: mesh::MarchedMesh,
    /// The linear mesh with exact crossings.
    pub linear: TetMesh,
    pub crossings: Vec<ExactCrossing>,
    /// Crossings left at the linear estimate (a move would have folded a tet).
    pub crossings_kept_linear: usize,
    /// The P2 mesh with its boundary mid-edge nodes on the surface.
    pub quadratic: TetMesh,
    pub curved: Vec<mesh::CurvedNode>,
    pub curving: mesh::CurvingReport,
    /// ∂D/∂p₀ (the central-difference Hessian of f) at every moved mid-edge node's midpoint,
    /// when asked for ([`curved_body`]): the direction of move also turns as p₀ moves.
    pub hessians: Option<Vec<[[f64; 3]; 3]>>,
}

/// Where one mode's gradient goes when f depends on a parameter p (module docs, "Curved
/// boundary"): dλ/dp = Σ_i grid_i ∂s_i/∂p + Σ_c crossings_c ∂f(x_c)/∂p + Σ_m curved_m ∂f(x_m)/∂p,
/// with s_i the samples (they still move the crossings kept linear) and x_c, x_m the moved
/// crossings and mid-edge nodes ([`CurvedBody::moved_points`], in that order), plus the turn
/// of each mid-edge node's direction of move: Σ_m Σ_d turns_m,d (∂f(p₀_m + δ e_d)/∂p −
/// ∂f(p₀_m − δ e_d)/∂p)/(2δ) ([`mesh::CurvedNode`]'s docs; [`CurvedBody::turn_points`]).
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
/// ([`mesh::curve_boundary`]). With `hessians`, also ∂D/∂p₀ at every moved mid-edge node
/// ([`CurvedBody::field_weights`]): 6 evaluations of the exact `gradient` per node, or 13 more
/// of f without it. A signed distance needs it where a difference stencil straddles one of its
/// creases (module docs, "Curved boundary"); a general field's direction turns with the field
/// too (the geometry task's network: 0.3 % of Σ G·dx/dp on a wavy field without it). `gradient`,
/// f's exact gradient where known, also serves ∇f at the crossings and the curved nodes' roots.
pub fn curved_body(
    grid: &BackgroundGrid,
    values: &[f64],
    f: &dyn Fn([f64; 3]) -> f64,
    gradient: Option<mesh::FieldGradient>,
    options: &MarchingOptions,
    hessians: bool,
) -> Result<CurvedBody, ShapeError> {
    if values.iter().all(|v| *v <= 0.0) {
        return Err(ShapeError::Empty);
    }
    let marched = mesh::march(grid, values, None, options)?;
    let (linear, crossings, crossings_kept_linear) =
        refine_crossings(&marched, grid, f, gradient, 0.01);
    let straight = lift_to_quadratic(&linear);
    let (quadratic, curved, curving) = mesh::curve_boundary(
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
    gradient: Option<mesh::FieldGradient>,
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
    pub shell: mesh::Shell,
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
    let shell = mesh::shell_of_depth(solid, t, depth)?;
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
    fn thickness_derivatives(
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
    let marched = mesh::march(grid, values, None, options)?;
    modes_of_mesh(
        petsc,
        lift_to_quadratic(&marched.mesh),
        marched.report.clone(),
        material,
        n_modes,
    )
}

fn modes_of_mesh(
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

// ------------------------------------------------------------------ surfaces and fields

/// A closed triangle surface from an OBJ file, or the boundary of a Gmsh tet mesh (`.msh`),
/// with the reader's warnings.
pub fn read_surface(path: &Path) -> Result<(TriangleSurface, Vec<String>), ShapeError> {
    let is_msh = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("msh"));
    if is_msh {
        let read = mesh::read_mesh(path, &mesh::ReadOptions::default())
            .map_err(|e| ShapeError::Invalid(e.to_string()))?;
        Ok((
            TriangleSurface::from_mesh_boundary(&read.mesh),
            read.warnings,
        ))
    } else {
        let read = mesh::read_obj(path)?;
        Ok((read.surface, read.warnings))
    }
}

/// Centres the surface's bounding box on the origin and scales it uniformly to a bounding-box
/// diagonal of `diagonal` (module docs). Returns the scale factor applied.
pub fn normalise_surface(surface: &mut TriangleSurface, diagonal: f64) -> Result<f64, ShapeError> {
    if !(diagonal.is_finite() && diagonal > 0.0) {
        return Err(ShapeError::Invalid(format!(
            "the bounding-box diagonal must be positive, got {diagonal}"
        )));
    }
    let (lo, hi) = surface.bounding_box();
    let current = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
    if !(current.is_finite() && current > 0.0) {
        return Err(ShapeError::Invalid(
            "the surface has no extent (all its vertices coincide)".into(),
        ));
    }
    let scale = diagonal / current;
    let centre = [0, 1, 2].map(|d| 0.5 * (lo[d] + hi[d]));
    for v in &mut surface.vertices {
        for d in 0..3 {
            v[d] = (v[d] - centre[d]) * scale;
        }
    }
    Ok(scale)
}

/// A signed distance sampled at the vertices of a background grid.
#[derive(Clone, Debug)]
pub struct SampledField {
    pub grid: BackgroundGrid,
    pub values: Vec<f64>,
}

impl SampledField {
    /// Samples `sdf` on the grid of cubic cells with `cells` along the longest axis of the box
    /// [lo, hi] plus one cell of margin ([`BackgroundGrid::covering`]).
    pub fn of_sdf(
        sdf: &SignedDistance,
        lo: [f64; 3],
        hi: [f64; 3],
        cells: usize,
    ) -> Result<SampledField, ShapeError> {
        SampledField::of_sdf_shifted(sdf, lo, hi, cells, [0.0; 3])
    }

    /// [`SampledField::of_sdf`] on the grid moved by `shift` cells along the axes
    /// ([`shifted_covering`]): the same spacing, another alignment of the vertices with the
    /// surface (a replica level, module docs "Grid bias and its extrapolation").
    pub fn of_sdf_shifted(
        sdf: &SignedDistance,
        lo: [f64; 3],
        hi: [f64; 3],
        cells: usize,
        shift: [f64; 3],
    ) -> Result<SampledField, ShapeError> {
        if cells < 4 {
            return Err(ShapeError::Invalid(format!(
                "a grid needs at least 4 cells along its longest axis, got {cells}"
            )));
        }
        let grid = shifted_covering(lo, hi, cells, shift)?;
        let values = sdf.evaluate(&grid.vertex_positions());
        if !values.iter().any(|&v| v > 0.0) {
            return Err(ShapeError::Invalid(format!(
                "no vertex of the {cells}-cell grid lies inside the surface: is it closed?"
            )));
        }
        Ok(SampledField { grid, values })
    }

    /// Cell size h [m] (cubic cells).
    pub fn spacing(&self) -> f64 {
        self.grid.spacing()[0]
    }

    /// Cells along the longest axis.
    pub fn cells(&self) -> usize {
        self.grid.cells().into_iter().max().unwrap_or(0)
    }
}

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

/// [`BackgroundGrid::covering`] with one cell of margin, moved by `shift` cells along the axes
/// (each in [−½, ½], so the box stays inside): the same spacing, vertices that do not line up
/// with the centred grid's (a target grid of 40 cells would otherwise contain every vertex of a
/// 20-cell fit grid).
pub fn shifted_covering(
    lo: [f64; 3],
    hi: [f64; 3],
    cells: usize,
    shift: [f64; 3],
) -> Result<BackgroundGrid, ShapeError> {
    if shift.iter().any(|s| !(s.abs() <= 0.5)) {
        return Err(ShapeError::Invalid(format!(
            "grid shift {shift:?} must lie in [−½, ½] cells"
        )));
    }
    let base = BackgroundGrid::covering(lo, hi, cells, 1.0)?;
    let h = base.spacing();
    Ok(BackgroundGrid::new(
        [0, 1, 2].map(|d| base.origin()[d] + shift[d] * h[d]),
        h,
        base.cells(),
    )?)
}

/// The box [lo, hi] of the union of the bounding boxes of `surfaces`.
pub fn union_box(surfaces: &[&TriangleSurface]) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for s in surfaces {
        let (a, b) = s.bounding_box();
        for d in 0..3 {
            lo[d] = lo[d].min(a[d]);
            hi[d] = hi[d].max(b[d]);
        }
    }
    (lo, hi)
}

/// Grid cells of the sampling that seeds [`reference_depth`].
const DEPTH_SEED_CELLS: usize = 32;

/// S, the depth of the deepest point of the solid (module docs): the pattern search of
/// [`SignedDistance::deepest_point`] from the 16 deepest vertices of a 32-cell sampling, to a
/// step of 1e-7 of the bounding-box diagonal. Depends on the surface only, so the fit and any
/// target use the same S.
pub fn reference_depth(sdf: &SignedDistance, surface: &TriangleSurface) -> Result<f64, ShapeError> {
    let (lo, hi) = surface.bounding_box();
    let seed = SampledField::of_sdf(sdf, lo, hi, DEPTH_SEED_CELLS)?;
    let mut order: Vec<usize> = (0..seed.values.len())
        .filter(|&v| seed.values[v] > 0.0)
        .collect();
    order.sort_by(|&a, &b| seed.values[b].total_cmp(&seed.values[a]));
    let starts: Vec<[f64; 3]> = order
        .iter()
        .take(16)
        .map(|&v| seed.grid.vertex_position(v))
        .collect();
    let diagonal = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
    let (_, depth) = sdf.deepest_point(&starts, seed.spacing(), 1e-7 * diagonal);
    if !(depth > 0.0) {
        return Err(ShapeError::Invalid(
            "the surface encloses no inside point".into(),
        ));
    }
    Ok(depth)
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
    Shell(mesh::Shell),
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
                let shell = mesh::shell_of_depth(solid, p, *depth)?;
                Ok((shell.values.clone(), Built::Shell(shell)))
            }
            ShapeFamily::Morph { a, b } => Ok((mesh::morph(a, b, p)?, Built::Morph(p))),
        }
    }

    /// dλ/dp from dλ/d(field) through the built field.
    fn derivative(&self, built: &Built, d_field: &[f64]) -> Result<f64, ShapeError> {
        match (self, built) {
            (_, Built::Shell(shell)) => Ok(shell.vjp(d_field)?.thickness),
            (ShapeFamily::Morph { a, b }, Built::Morph(c)) => {
                Ok(mesh::morph_vjp(a, b, *c, d_field)?.c)
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
    let marked = |v: &mesh::refine::TetView| {
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
    let (mut below, mut above): (Option<(f64, f64)>, Option<(f64, f64)>) = (None, None);
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
