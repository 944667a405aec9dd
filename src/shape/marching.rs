//! Marching tetrahedra: a differentiable tet mesh of the region {s > 0} of values s given at
//! the vertices of a background grid, for shape optimisation (thickness, morphing, geometry).
//!
//! # Background grid
//!
//! [`BackgroundGrid`]: `cells[k]` cells of size `spacing[k]` per axis from `origin`; vertex
//! (i, j, k) has index v = i + (n_x+1)·(j + (n_y+1)·k) and rest position
//! X_v = origin + (i h_x, j h_y, k h_z). Every cell is split into the same 6 Kuhn
//! (Freudenthal) tets along its (0,0,0)–(1,1,1) diagonal (those of [`crate::mesh::box_mesh`]), so
//! the faces of neighbouring cells match and every background tet is positively oriented at
//! rest. Background tet e is Kuhn tet e mod 6 of cell ⌊e/6⌋ (cells numbered like vertices).
//! [`BackgroundGrid::covering`] puts cubic cells around a bounding box.
//!
//! Optional learned offsets θ_v (3 per vertex, in metres) move the vertices to
//!
//! ```text
//! x_v = X_v + δ_v,   δ_{v,k} = clamp(θ_{v,k}, −b_k, b_k),   b_k = f·h_k,  0 ≤ f ≤ ½
//! ```
//!
//! (f = [`MarchingOptions::max_offset_fraction`], at most half a cell, default an eighth).
//! The clamp is differentiated as dδ/dθ = 1 for |θ| ≤ b (bound included: the one-sided
//! derivative from inside, so a parameter that an optimiser projects onto the bound still
//! gets a gradient and can come back) and 0 for |θ| > b.
//!
//! Why an eighth by default: the successive edge vectors x₁ − x₀, x₂ − x₁, x₃ − x₂ of a Kuhn
//! tet are the columns of h·P (P a permutation, up to the corner order) plus differences of
//! two offsets, so det = h³ det P · det(I + E) with every |E_ij| ≤ 2f. When
//! the row sums 6f < 1, the eigenvalues of I + E lie in the disc |z − 1| ≤ 6f, hence
//! det(I + E) ≥ (1 − 6f)³ > 0: for f < 1/6 no background tet can invert, and with f = 1/8
//! each keeps at least 1/64 of its rest volume. Above 1/6 background tets can turn inverted
//! or flat (in a test, random offsets clamped at half a cell inverted 568 of the 2832 inside
//! or cut background tets); the pieces cut from them fail the volume guard below and are dropped and counted
//! ([`MarchingReport::inverted_background_tets`]), but their neighbours then overlap in
//! space, so such a mesh is only combinatorially valid.
//!
//! # Local refinement
//!
//! [`BackgroundGrid::refined`] bisects the Kuhn tets where a predicate of their corners and
//! field values asks for it ([`super::refine`]: longest-edge bisection, conforming, every tet
//! positively oriented, marked tets refined to Kuhn tets of h/2^L). The structured vertices
//! keep their indices; the edge midpoints follow them, with the field's value taken from the
//! continuous field where the caller has one. Marching, snapping, the volume guard (against
//! the smallest rest tet, h_x h_y h_z/(6·2^g) after g bisections) and the gradients work on
//! the refined tets and edges unchanged; learned vertex offsets are refused on a refined grid
//! (the bound below is for Kuhn tets of one size).
//!
//! # Marching tetrahedra
//!
//! Values s_v > 0 are inside (the SDF convention of [`super::sdf`]). Inside each background
//! tet s is linear, so its inside part {s > 0} is a convex polytope whose vertices are the
//! tet's positive and zero corners and the crossings on its edges (i, j) with s_i > 0 > s_j:
//!
//! ```text
//! x_ij = x_i + t (x_j − x_i),   t = s_i / (s_i − s_j) ∈ (0, 1)
//! ```
//!
//! A crossing is keyed by its grid edge (its two grid vertices, the lower index first and t
//! measured from it), so the tets on both sides of a face share it and the mesh is
//! conforming. With p positive, z zero and m negative corners:
//!
//! | p, z, m | inside part | tets |
//! |---|---|---|
//! | p = 0 | nothing (a zero face at most) | 0 |
//! | m = 0 | the whole tet (zero corners included) | 1 |
//! | 1, any, ≥ 1 | tet: the positive corner, the zero corners, the crossings | 1 |
//! | 2, 1, 1 | pyramid: apex the zero corner, base quad P₀ P₁ x₁ x₀ | 2 |
//! | 2, 0, 2 | prism: triangles P₀ x₀₀ x₀₁ and P₁ x₁₀ x₁₁ | 3 |
//! | 3, 0, 1 | prism: triangles P₀ P₁ P₂ and x₀ x₁ x₂ | 3 |
//!
//! Quadrilateral faces are cut by the diagonal through their smallest vertex in a global
//! order of the output vertices (grid vertex v ↦ (v, v), crossing on edge (a < b) ↦ (a, b),
//! compared lexicographically). The two tets sharing a face see the same quad and make the
//! same cut, and prisms are split into three tets consistently with their three quad
//! diagonals as in Dompierre, Labbé, Vallet & Camarero, "How to subdivide pyramids, prisms
//! and hexahedra into tetrahedra" (IMR 1999): rotate the prism so the smallest vertex is
//! bottom corner 0; the opposite quad's diagonal picks one of two splits. Each sub-tet is
//! oriented by the sign of its barycentric determinant in the parent (the fraction of the
//! parent's rest volume it covers), so it has the orientation of its background tet.
//! Zero values therefore need no special treatment beyond the table: a zero corner is a
//! vertex of the inside part and never a crossing.
//!
//! The result is the inside of the piecewise-linear interpolant, clipped to the grid box
//! (grow the box, e.g. with [`BackgroundGrid::covering`]'s margin, to keep the surface off
//! it). It resolves what the grid resolves: a wall thinner than a grid edge (up to √3 h
//! long) can fall between two outside samples and get holes, and under-resolved features
//! can touch along zero edges; the mesh is still conforming with positive volumes, but its
//! surface may then not be a 2-manifold of the expected topology.
//!
//! # Sliver guard
//!
//! 1. **Snapping.** A crossing very close to a grid vertex would make needle tets. Before
//!    marching, every vertex v whose value is tiny against a sign change on one of its grid
//!    edges, |s_v| ≤ τ |s_v − s_w| for some edge (v, w) with s_v s_w < 0 (i.e. the crossing
//!    would sit at t < τ from v; τ = [`MarchingOptions::snap_fraction`]), is set to exactly
//!    0, so the surface passes through the grid vertex. The decision uses the unsnapped
//!    values for all vertices at once (order-independent), so every remaining crossing has
//!    τ ≤ t ≤ 1 − τ. This is differentiable almost everywhere: inside the snapping band the
//!    vertex does not depend on s_v (derivative 0) and its edges have no crossings; the band
//!    edge is a jump of at most τ times an edge length in the geometry, like any change of
//!    the sign pattern. Counted in [`MarchingReport::snapped_vertices`]. With τ = 0.05 (the
//!    default) the smallest piece of a rest grid tet is about τ³ ≈ 1.3e-4 of it (measured:
//!    1.4e-4 on spot at 64 and 128 cells); with τ = 0.01 pieces of 1e-6 occur, and from 64
//!    cells per axis on the zero-volume rule below (ε_D D³ is 5.6e-6 of a grid tet at 64
//!    cells, 4.4e-5 at 128) drops them by the hundred (spot: 119 at 64 cells, 2022 at 128;
//!    none with τ = 0.05).
//! 2. **Volume.** Every sub-tet whose volume V ≤ max(ε_D D³, φ h_x h_y h_z / 6) is dropped,
//!    with D the diagonal of the background grid, ε_D =
//!    [`crate::mesh::ZERO_VOLUME_RELATIVE_TOLERANCE`] and φ = [`MarchingOptions::min_volume_fraction`].
//!    The output mesh fits inside the grid, so its own diagonal is at most D and every kept
//!    tet passes the mesh module's zero-volume rule. Dropping a tet keeps the mesh conforming
//!    (its faces become boundary faces of the neighbours). Counted in
//!    [`MarchingReport::dropped_small_tets`] and `dropped_inverted_tets`.
//!
//! # Largest component
//!
//! Kept tets are grouped into face-connected pieces (union–find over shared faces) and only
//! the piece of largest volume is kept (ties: the one holding the lowest background tet),
//! unless [`MarchingOptions::keep_largest_component`] is off.
//!
//! # Gradients
//!
//! [`MarchedMesh::vjp`] maps dL/dx at the output vertices (3 per vertex, the layout of the
//! crate's node fields) to dL/ds at the grid values and dL/dθ at the raw offsets. With
//! x = x_a + t (x_b − x_a) and t = s_a / (s_a − s_b):
//!
//! ```text
//! ∂t/∂s_a = −s_b / (s_a − s_b)²,   ∂t/∂s_b = s_a / (s_a − s_b)²,   ∂x/∂t = x_b − x_a
//! ∂x/∂x_a = (1 − t) I,   ∂x/∂x_b = t I,   ∂x_v/∂θ_v = diag(dδ/dθ)
//! ```
//!
//! and a grid vertex kept as an output vertex has x = x_v. The sign pattern (hence the
//! connectivity, the snapping and the kept component) is piecewise constant in s and θ and
//! has no derivative. If the values themselves depend on the vertex positions (an SDF
//! evaluated at the displaced vertices), the caller adds ∇s_v · dL/ds_v to dL/dθ_v.
//! [`linear_node_gradient`](crate::mesh::linear_node_gradient) maps a gradient on a lifted P2 mesh
//! back to these P1 vertices first.
//!
//! # Implicit functions for the shape tasks
//!
//! * [`shell`]: a hollow body of relative thickness t is {0 < s ≤ t·max s}; marching
//!   g = min(s, t·S − s) with S = max_v s_v gives that set (up to its inner wall itself). Its vector–Jacobian
//!   product: ∂g_v/∂s_v = 1 where s_v ≤ t S − s_v (ties take this branch) and −1 elsewhere;
//!   on the second branch ∂g_v/∂t = S and ∂g_v/∂S = t, and S is differentiated through its
//!   argmax (the lowest index among equal maxima), ∂S/∂s_v = [v = argmax].
//!   [`shell_of_depth`] takes S from the caller instead (the deepest point of the continuous
//!   signed distance: the largest *sample* falls short of it by up to ~h√3/2, which on a
//!   coarse grid changed t·S by 20 % on spot), and then S is a constant.
//! * [`morph`]: m = c·A + (1 − c)·B, ∂m/∂A = c, ∂m/∂B = 1 − c, ∂m/∂c = A − B.

use std::collections::HashMap;
use std::fmt;

use crate::mesh::{
    signed_tet_volume, DisjointSets, ElementOrder, TetMesh, KUHN_TETS,
    ZERO_VOLUME_RELATIVE_TOLERANCE,
};

#[cfg(test)]
mod tests;

/// Everything that can go wrong building a grid, marching or taking a gradient.
#[derive(thiserror::Error, Debug, Clone, PartialEq)]
pub enum MarchingError {
    #[error("invalid background grid: {message}")]
    BadGrid { message: String },
    #[error("{what} has {found} entries, expected {expected}")]
    LengthMismatch {
        what: &'static str,
        expected: usize,
        found: usize,
    },
    #[error("{what}[{index}] = {value} is not finite")]
    NonFinite {
        what: &'static str,
        index: usize,
        value: f64,
    },
    #[error("invalid marching option: {message}")]
    BadOption { message: String },
    #[error("no grid value is positive, so nothing is inside (positive means inside)")]
    NothingInside,
    #[error("every inside tetrahedron was dropped by the volume guard ({report})")]
    NothingKept { report: MarchingReport },
    #[error("shell thickness {thickness} must be finite and positive")]
    BadThickness { thickness: f64 },
}

// ------------------------------------------------------------------ grid

/// A box of `cells[0] × cells[1] × cells[2]` cells, 6 Kuhn tets each (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct BackgroundGrid {
    origin: [f64; 3],
    spacing: [f64; 3],
    cells: [usize; 3],
    /// Local refinement ([`BackgroundGrid::refined`]): the tets, the vertices beyond the
    /// structured ones and the edges replace the structured grid's.
    refinement: Option<std::sync::Arc<GridRefinement>>,
}

/// The tets of a locally refined grid (module docs, "Local refinement").
#[derive(Clone, Debug, PartialEq)]
struct GridRefinement {
    /// Vertices after the structured grid's (index n_structured + i): edge midpoints.
    extra: Vec<[f64; 3]>,
    tets: Vec<[usize; 4]>,
    edges: Vec<(usize, usize)>,
    /// The most bisections of any tet (each halves its volume).
    max_generation: u8,
}

impl BackgroundGrid {
    /// A grid from its lowest corner, cell sizes (> 0, finite) and cell counts (≥ 1).
    pub fn new(
        origin: [f64; 3],
        spacing: [f64; 3],
        cells: [usize; 3],
    ) -> Result<Self, MarchingError> {
        let bad = |message: String| Err(MarchingError::BadGrid { message });
        if origin.iter().any(|c| !c.is_finite()) {
            return bad(format!("origin {origin:?} is not finite"));
        }
        if spacing.iter().any(|h| !(h.is_finite() && *h > 0.0)) {
            return bad(format!(
                "cell sizes {spacing:?} must be finite and positive"
            ));
        }
        if cells.contains(&0) {
            return bad(format!("cell counts {cells:?} must all be at least 1"));
        }
        let vertices = cells
            .iter()
            .try_fold(1usize, |acc, &n| acc.checked_mul(n.checked_add(1)?));
        if vertices.is_none_or(|v| v.checked_mul(6).is_none()) {
            return bad(format!("cell counts {cells:?} are too large"));
        }
        Ok(BackgroundGrid {
            origin,
            spacing,
            cells,
            refinement: None,
        })
    }

    /// Cubic cells around the box `[lo, hi]`, grown by `margin_cells` cells on every side:
    /// the longest axis gets exactly `resolution` cells of size
    /// h = L_max / (resolution − 2·margin_cells), the others the fewest cells of size h that
    /// cover their side plus the margins, and the grid is centred on the box.
    pub fn covering(
        lo: [f64; 3],
        hi: [f64; 3],
        resolution: usize,
        margin_cells: f64,
    ) -> Result<Self, MarchingError> {
        let bad = |message: String| Err(MarchingError::BadGrid { message });
        if lo.iter().chain(&hi).any(|c| !c.is_finite()) || (0..3).any(|k| hi[k] < lo[k]) {
            return bad(format!("box {lo:?}..{hi:?} is not a finite box"));
        }
        if !(margin_cells.is_finite()
            && margin_cells >= 0.0
            && (resolution as f64) > 2.0 * margin_cells)
        {
            return bad(format!(
                "resolution {resolution} must exceed twice the margin of {margin_cells} cells (margin ≥ 0)"
            ));
        }
        let sides = [0, 1, 2].map(|k| hi[k] - lo[k]);
        let longest = sides.iter().fold(0.0f64, |a, &b| a.max(b));
        if longest <= 0.0 {
            return bad(format!("box {lo:?}..{hi:?} has no extent"));
        }
        let h = longest / (resolution as f64 - 2.0 * margin_cells);
        let cells = [0, 1, 2].map(|k| {
            // A hair of slack so that the longest axis gets `resolution`, not one more.
            let needed = sides[k] / h + 2.0 * margin_cells;
            ((needed - 1e-9).ceil() as usize).max(1)
        });
        let origin = [0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k]) - 0.5 * cells[k] as f64 * h);
        Self::new(origin, [h; 3], cells)
    }

    pub fn origin(&self) -> [f64; 3] {
        self.origin
    }

    /// Cell sizes h_k.
    pub fn spacing(&self) -> [f64; 3] {
        self.spacing
    }

    pub fn cells(&self) -> [usize; 3] {
        self.cells
    }

    /// Vertices per axis, cells + 1.
    pub fn vertex_counts(&self) -> [usize; 3] {
        self.cells.map(|n| n + 1)
    }

    /// Vertices: the structured grid's, then a refinement's midpoints.
    pub fn n_vertices(&self) -> usize {
        self.n_structured_vertices() + self.refinement.as_ref().map_or(0, |r| r.extra.len())
    }

    fn n_structured_vertices(&self) -> usize {
        self.vertex_counts().iter().product()
    }

    /// Background tets: 6 per cell, or a refinement's.
    pub fn n_tets(&self) -> usize {
        match &self.refinement {
            Some(r) => r.tets.len(),
            None => 6 * self.cells.iter().product::<usize>(),
        }
    }

    /// Whether the grid was refined locally ([`BackgroundGrid::refined`]).
    pub fn is_refined(&self) -> bool {
        self.refinement.is_some()
    }

    /// The rest volume of the smallest background tet: h_x h_y h_z / 6, halved by every
    /// bisection of a refinement.
    pub fn smallest_rest_tet_volume(&self) -> f64 {
        let generations = self.refinement.as_ref().map_or(0, |r| r.max_generation);
        self.spacing.iter().product::<f64>() / 6.0 / 2f64.powi(generations as i32)
    }

    /// The grid refined by bisection where `marked` holds (module docs, "Local refinement";
    /// [`super::refine::refine_marked`]): marked tets are bisected until they are Kuhn tets of
    /// h/2^`levels`, and their neighbours as far as conformity needs. `values` are the field at
    /// the structured vertices, `field` gives it at the new ones; returns the refined grid and
    /// the field at all its vertices. The structured vertices keep their indices.
    pub fn refined(
        &self,
        levels: usize,
        values: &[f64],
        field: &dyn Fn([f64; 3]) -> f64,
        marked: &dyn Fn(&super::refine::TetView) -> bool,
    ) -> Result<(BackgroundGrid, Vec<f64>), MarchingError> {
        if self.refinement.is_some() {
            return Err(MarchingError::BadGrid {
                message: "the grid is refined already; refine the structured grid once".into(),
            });
        }
        if levels > 40 {
            return Err(MarchingError::BadGrid {
                message: format!("{levels} refinement levels: at most 40"),
            });
        }
        check_finite("values", values, self.n_vertices())?;
        let tets: Vec<[usize; 4]> = (0..self.n_tets()).map(|e| self.tet(e)).collect();
        let r = super::refine::refine_marked(
            self.vertex_positions(),
            values.to_vec(),
            &tets,
            levels,
            field,
            marked,
        );
        let n = self.n_structured_vertices();
        let max_generation = r.generations.iter().copied().max().unwrap_or(0);
        let refinement = GridRefinement {
            extra: r.positions[n..].to_vec(),
            tets: r.tets,
            edges: r.edges,
            max_generation,
        };
        let mut grid = self.clone();
        grid.refinement = Some(std::sync::Arc::new(refinement));
        Ok((grid, r.values))
    }

    /// Index of vertex (i, j, k).
    pub fn vertex_index(&self, i: usize, j: usize, k: usize) -> usize {
        let [nx, ny, _] = self.vertex_counts();
        i + nx * (j + ny * k)
    }

    /// Rest position X_v.
    pub fn vertex_position(&self, v: usize) -> [f64; 3] {
        let n = self.n_structured_vertices();
        if v >= n {
            if let Some(r) = &self.refinement {
                return r.extra[v - n];
            }
        }
        let [nx, ny, _] = self.vertex_counts();
        let ijk = [v % nx, (v / nx) % ny, v / (nx * ny)];
        [0, 1, 2].map(|d| self.origin[d] + ijk[d] as f64 * self.spacing[d])
    }

    /// All rest positions, in vertex order (x fastest): neighbours follow each other, which
    /// suits [`super::SignedDistance::evaluate`].
    pub fn vertex_positions(&self) -> Vec<[f64; 3]> {
        (0..self.n_vertices())
            .map(|v| self.vertex_position(v))
            .collect()
    }

    /// The 4 grid vertices of background tet `e`, positively oriented at rest.
    pub fn tet(&self, e: usize) -> [usize; 4] {
        if let Some(r) = &self.refinement {
            return r.tets[e];
        }
        let [cx, cy, _] = self.cells;
        let cell = e / 6;
        let (i, j, k) = (cell % cx, (cell / cx) % cy, cell / (cx * cy));
        KUHN_TETS[e % 6].map(|[di, dj, dk]| self.vertex_index(i + di, j + dj, k + dk))
    }

    /// Offset bounds b_k = fraction·h_k.
    pub fn offset_bound(&self, max_offset_fraction: f64) -> [f64; 3] {
        self.spacing.map(|h| max_offset_fraction * h)
    }

    /// Displaced positions x_v = X_v + clamp(θ_v, −b, b) (module docs); `offsets` holds 3
    /// values per vertex, or `None` for the rest positions.
    pub fn displaced_positions(
        &self,
        offsets: Option<&[f64]>,
        max_offset_fraction: f64,
    ) -> Result<Vec<[f64; 3]>, MarchingError> {
        check_offset_fraction(max_offset_fraction)?;
        let mut x = self.vertex_positions();
        if let Some(theta) = offsets {
            if self.refinement.is_some() {
                // The bound that keeps every background tet positive holds for Kuhn tets of
                // one size (module docs), not for a refinement's mix of sizes.
                return Err(MarchingError::BadGrid {
                    message: "vertex offsets are not supported on a locally refined grid".into(),
                });
            }
            check_finite("offsets", theta, 3 * self.n_vertices())?;
            let b = self.offset_bound(max_offset_fraction);
            for (v, p) in x.iter_mut().enumerate() {
                for k in 0..3 {
                    p[k] += theta[3 * v + k].clamp(-b[k], b[k]);
                }
            }
        }
        Ok(x)
    }

    /// The background grid itself as a linear mesh (rest or displaced positions).
    pub fn to_mesh(
        &self,
        offsets: Option<&[f64]>,
        max_offset_fraction: f64,
    ) -> Result<TetMesh, MarchingError> {
        let nodes = self.displaced_positions(offsets, max_offset_fraction)?;
        let connectivity = (0..self.n_tets()).flat_map(|e| self.tet(e)).collect();
        Ok(TetMesh {
            nodes,
            connectivity,
            order: ElementOrder::Linear,
        })
    }

    /// The grid edges as vertex pairs (v, v + offset) for the 7 offsets in {0,1}³ \ {0}: every
    /// edge of a Kuhn tet is one of them, and each appears once.
    fn for_each_edge(&self, mut f: impl FnMut(usize, usize)) {
        if let Some(r) = &self.refinement {
            for &(v, w) in &r.edges {
                f(v, w);
            }
            return;
        }
        let [nx, ny, nz] = self.vertex_counts();
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let v = self.vertex_index(i, j, k);
                    for d in 1..8usize {
                        let (di, dj, dk) = (d & 1, (d >> 1) & 1, (d >> 2) & 1);
                        if i + di < nx && j + dj < ny && k + dk < nz {
                            f(v, self.vertex_index(i + di, j + dj, k + dk));
                        }
                    }
                }
            }
        }
    }
}

// ------------------------------------------------------------------ options and report

/// Settings of [`march`].
#[derive(Clone, Debug, PartialEq)]
pub struct MarchingOptions {
    /// τ: a value is snapped to 0 when a crossing on one of its edges would lie closer than
    /// τ (as a fraction of the edge) to it; 0 turns snapping off. In [0, ½). Default 0.05
    /// (module docs, sliver guard).
    pub snap_fraction: f64,
    /// φ: sub-tets smaller than φ·h_x h_y h_z / 6 (a fraction of a rest background tet) are
    /// dropped, besides the zero-volume rule. In [0, 1). Default 1e-9, far below what the
    /// default snapping leaves (~1e-4): only a stricter quality bar needs it.
    pub min_volume_fraction: f64,
    /// f: offsets are clamped to ±f·h per axis. In [0, ½]. Default ⅛, below the 1/6 that
    /// guarantees no background tet inverts (module docs).
    pub max_offset_fraction: f64,
    /// Keep only the face-connected piece of largest volume. Default true.
    pub keep_largest_component: bool,
}

impl Default for MarchingOptions {
    fn default() -> Self {
        MarchingOptions {
            snap_fraction: 0.05,
            min_volume_fraction: 1e-9,
            max_offset_fraction: 0.125,
            keep_largest_component: true,
        }
    }
}

/// What [`march`] did, for the user and for tests.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MarchingReport {
    /// Background tets with no negative corner and at least one positive one, kept whole.
    pub inside_tets: usize,
    /// Background tets cut by the surface.
    pub cut_tets: usize,
    /// Grid values set to 0 by the snapping rule.
    pub snapped_vertices: usize,
    /// Inside or cut background tets whose displaced volume is ≤ 0.
    pub inverted_background_tets: usize,
    /// Sub-tets dropped with 0 < V ≤ the volume threshold.
    pub dropped_small_tets: usize,
    /// Sub-tets dropped with V ≤ 0 (only from displaced, inverted background tets).
    pub dropped_inverted_tets: usize,
    /// Face-connected pieces before the largest was selected.
    pub components: usize,
    /// Tets and volume of the pieces that were dropped.
    pub dropped_component_tets: usize,
    pub dropped_component_volume: f64,
    /// The volume threshold of the guard and the smallest kept volume.
    pub volume_threshold: f64,
    pub min_tet_volume: f64,
}

impl fmt::Display for MarchingReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} whole and {} cut background tets, {} values snapped to the surface, \
             {} inverted background tets, {} small and {} inverted sub-tets dropped \
             (threshold {:.3e}), {} pieces ({} tets, volume {:.3e} dropped), smallest tet {:.3e}",
            self.inside_tets,
            self.cut_tets,
            self.snapped_vertices,
            self.inverted_background_tets,
            self.dropped_small_tets,
            self.dropped_inverted_tets,
            self.volume_threshold,
            self.components,
            self.dropped_component_tets,
            self.dropped_component_volume,
            self.min_tet_volume
        )
    }
}

// ------------------------------------------------------------------ output

/// Where an output vertex comes from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum VertexOrigin {
    /// Grid vertex `vertex` (inside or snapped onto the surface).
    Grid { vertex: usize },
    /// The crossing x_a + t (x_b − x_a) on grid edge (a, b), a < b, t = s_a / (s_a − s_b).
    Crossing { a: usize, b: usize, t: f64 },
}

/// Per-crossing data of the vector–Jacobian product.
#[derive(Clone, Copy, Debug)]
struct CrossingJacobian {
    dt_dsa: f64,
    dt_dsb: f64,
    /// x_b − x_a.
    edge: [f64; 3],
}

/// A marched mesh, the origin of its vertices and what its gradient needs.
#[derive(Clone, Debug)]
pub struct MarchedMesh {
    /// Linear tets, all positively oriented above the zero-volume rule.
    pub mesh: TetMesh,
    /// One entry per mesh node.
    pub origins: Vec<VertexOrigin>,
    pub report: MarchingReport,
    n_grid_vertices: usize,
    /// Aligned with `origins`; unused for grid vertices.
    jacobians: Vec<CrossingJacobian>,
    /// The raw offsets and their bound, if offsets were given.
    offsets: Option<(Vec<f64>, [f64; 3])>,
}

/// dL/ds per grid value and dL/dθ per raw offset (3 per grid vertex).
#[derive(Clone, Debug, PartialEq)]
pub struct MarchingGradient {
    pub values: Vec<f64>,
    pub offsets: Vec<f64>,
}

impl MarchedMesh {
    /// Vector–Jacobian product (module docs): `d_loss_d_nodes` holds dL/dx, 3 per mesh node.
    pub fn vjp(&self, d_loss_d_nodes: &[f64]) -> Result<MarchingGradient, MarchingError> {
        check_finite("d_loss_d_nodes", d_loss_d_nodes, 3 * self.mesh.n_nodes())?;
        let mut values = vec![0.0; self.n_grid_vertices];
        let mut offsets = vec![0.0; 3 * self.n_grid_vertices];
        let active = |v: usize, k: usize| match &self.offsets {
            Some((theta, bound)) => theta[3 * v + k].abs() <= bound[k],
            None => true,
        };
        let mut add_offset = |v: usize, weight: f64, g: [f64; 3]| {
            for k in 0..3 {
                if active(v, k) {
                    offsets[3 * v + k] += weight * g[k];
                }
            }
        };
        for (n, origin) in self.origins.iter().enumerate() {
            let g = [0, 1, 2].map(|k| d_loss_d_nodes[3 * n + k]);
            match *origin {
                VertexOrigin::Grid { vertex } => add_offset(vertex, 1.0, g),
                VertexOrigin::Crossing { a, b, t } => {
                    let jac = &self.jacobians[n];
                    let d_t = g[0] * jac.edge[0] + g[1] * jac.edge[1] + g[2] * jac.edge[2];
                    values[a] += d_t * jac.dt_dsa;
                    values[b] += d_t * jac.dt_dsb;
                    add_offset(a, 1.0 - t, g);
                    add_offset(b, t, g);
                }
            }
        }
        Ok(MarchingGradient { values, offsets })
    }

    /// Number of grid vertices the gradient refers to.
    pub fn n_grid_vertices(&self) -> usize {
        self.n_grid_vertices
    }
}

// ------------------------------------------------------------------ marching

/// A point of a sub-tet in its background tet: corner k, or the crossing on local edge
/// (i, j) with s_i > 0 > s_j.
#[derive(Clone, Copy, Debug)]
enum Local {
    Corner(usize),
    Crossing(usize, usize),
}

/// Meshes {s > 0} (module docs). `values`: one per grid vertex; `offsets`: 3 per grid vertex
/// (raw θ, clamped inside), or `None`.
pub fn march(
    grid: &BackgroundGrid,
    values: &[f64],
    offsets: Option<&[f64]>,
    options: &MarchingOptions,
) -> Result<MarchedMesh, MarchingError> {
    check_options(options)?;
    let n_grid = grid.n_vertices();
    check_finite("values", values, n_grid)?;
    let positions = grid.displaced_positions(offsets, options.max_offset_fraction)?;
    if !values.iter().any(|&s| s > 0.0) {
        return Err(MarchingError::NothingInside);
    }
    let mut report = MarchingReport::default();
    let s = snap(grid, values, options.snap_fraction, &mut report);

    let h = grid.spacing();
    let extent = [0, 1, 2].map(|k| grid.cells()[k] as f64 * h[k]);
    let diagonal = (extent[0] * extent[0] + extent[1] * extent[1] + extent[2] * extent[2]).sqrt();
    let rest_tet_volume = grid.smallest_rest_tet_volume();
    let threshold = (ZERO_VOLUME_RELATIVE_TOLERANCE * diagonal.powi(3))
        .max(options.min_volume_fraction * rest_tet_volume);
    report.volume_threshold = threshold;

    let mut builder = Builder {
        positions: &positions,
        values: &s,
        grid_node: vec![usize::MAX; n_grid],
        crossing_node: HashMap::new(),
        origins: Vec::new(),
        jacobians: Vec::new(),
        nodes: Vec::new(),
    };
    // Kept sub-tets (output node ids) with their volumes and background tets.
    let mut tets: Vec<[usize; 4]> = Vec::new();
    let mut volumes: Vec<f64> = Vec::new();
    let mut pieces: Vec<[Local; 4]> = Vec::with_capacity(3);
    for e in 0..grid.n_tets() {
        let g = grid.tet(e);
        let sv = g.map(|v| s[v]);
        if !sv.iter().any(|&x| x > 0.0) {
            continue;
        }
        if inside_pieces(&g, &sv, &mut pieces) {
            report.inside_tets += 1;
        } else {
            report.cut_tets += 1;
        }
        let parent_volume = signed_tet_volume(
            positions[g[0]],
            positions[g[1]],
            positions[g[2]],
            positions[g[3]],
        );
        if parent_volume <= 0.0 {
            report.inverted_background_tets += 1;
        }
        for piece in &pieces {
            let ids = piece.map(|p| builder.node(&g, p));
            let x = ids.map(|n| builder.nodes[n]);
            let volume = signed_tet_volume(x[0], x[1], x[2], x[3]);
            if volume <= 0.0 {
                report.dropped_inverted_tets += 1;
            } else if volume <= threshold {
                report.dropped_small_tets += 1;
            } else {
                tets.push(ids);
                volumes.push(volume);
            }
        }
    }
    if tets.is_empty() {
        return Err(MarchingError::NothingKept { report });
    }

    let keep = select_component(&tets, &volumes, options.keep_largest_component, &mut report);

    // Compact the nodes in order of first use by a kept tet.
    let mut new_index = vec![usize::MAX; builder.nodes.len()];
    let mut nodes = Vec::new();
    let mut origins = Vec::new();
    let mut jacobians = Vec::new();
    let mut connectivity = Vec::with_capacity(4 * keep.len());
    report.min_tet_volume = f64::INFINITY;
    for &e in &keep {
        report.min_tet_volume = report.min_tet_volume.min(volumes[e]);
        for n in tets[e] {
            if new_index[n] == usize::MAX {
                new_index[n] = nodes.len();
                nodes.push(builder.nodes[n]);
                origins.push(builder.origins[n]);
                jacobians.push(builder.jacobians[n]);
            }
            connectivity.push(new_index[n]);
        }
    }
    let offsets = offsets.map(|theta| {
        (
            theta.to_vec(),
            grid.offset_bound(options.max_offset_fraction),
        )
    });
    Ok(MarchedMesh {
        mesh: TetMesh {
            nodes,
            connectivity,
            order: ElementOrder::Linear,
        },
        origins,
        report,
        n_grid_vertices: n_grid,
        jacobians,
        offsets,
    })
}

/// The snapping rule of the module docs, on the unsnapped values of all vertices at once.
fn snap(grid: &BackgroundGrid, values: &[f64], tau: f64, report: &mut MarchingReport) -> Vec<f64> {
    let mut snapped = vec![false; values.len()];
    if tau > 0.0 {
        grid.for_each_edge(|v, w| {
            let (sv, sw) = (values[v], values[w]);
            if sv * sw < 0.0 {
                let jump = (sv - sw).abs();
                if sv.abs() <= tau * jump {
                    snapped[v] = true;
                }
                if sw.abs() <= tau * jump {
                    snapped[w] = true;
                }
            }
        });
    }
    report.snapped_vertices = snapped.iter().filter(|&&b| b).count();
    values
        .iter()
        .zip(&snapped)
        .map(|(&s, &b)| if b { 0.0 } else { s })
        .collect()
}

/// Output nodes created so far, shared between background tets by grid vertex or edge.
struct Builder<'a> {
    positions: &'a [[f64; 3]],
    values: &'a [f64],
    grid_node: Vec<usize>,
    crossing_node: HashMap<(usize, usize), usize>,
    origins: Vec<VertexOrigin>,
    jacobians: Vec<CrossingJacobian>,
    nodes: Vec<[f64; 3]>,
}

impl Builder<'_> {
    fn node(&mut self, g: &[usize; 4], p: Local) -> usize {
        match p {
            Local::Corner(k) => {
                let v = g[k];
                if self.grid_node[v] == usize::MAX {
                    self.grid_node[v] = self.nodes.len();
                    self.nodes.push(self.positions[v]);
                    self.origins.push(VertexOrigin::Grid { vertex: v });
                    self.jacobians.push(CrossingJacobian {
                        dt_dsa: 0.0,
                        dt_dsb: 0.0,
                        edge: [0.0; 3],
                    });
                }
                self.grid_node[v]
            }
            Local::Crossing(i, j) => {
                let (a, b) = (g[i].min(g[j]), g[i].max(g[j]));
                if let Some(&n) = self.crossing_node.get(&(a, b)) {
                    return n;
                }
                let (sa, sb) = (self.values[a], self.values[b]);
                let denominator = sa - sb;
                let t = sa / denominator;
                let (xa, xb) = (self.positions[a], self.positions[b]);
                let edge = [0, 1, 2].map(|k| xb[k] - xa[k]);
                let n = self.nodes.len();
                self.nodes.push([0, 1, 2].map(|k| xa[k] + t * edge[k]));
                self.origins.push(VertexOrigin::Crossing { a, b, t });
                self.jacobians.push(CrossingJacobian {
                    dt_dsa: -sb / (denominator * denominator),
                    dt_dsb: sa / (denominator * denominator),
                    edge,
                });
                self.crossing_node.insert((a, b), n);
                n
            }
        }
    }
}

/// Global order key of a local point (module docs): (v, v) for a corner, (a, b) a < b for a
/// crossing.
fn key(g: &[usize; 4], p: Local) -> (usize, usize) {
    match p {
        Local::Corner(k) => (g[k], g[k]),
        Local::Crossing(i, j) => (g[i].min(g[j]), g[i].max(g[j])),
    }
}

/// The oriented sub-tets of the inside part of a background tet with grid vertices `g` and
/// values `sv` (some positive) into `out` (cleared first). Returns true if the tet is kept
/// whole.
fn inside_pieces(g: &[usize; 4], sv: &[f64; 4], out: &mut Vec<[Local; 4]>) -> bool {
    out.clear();
    if !sv.iter().any(|&x| x < 0.0) {
        out.push([0, 1, 2, 3].map(Local::Corner));
        return true;
    }
    split(g, sv, out);
    for piece in out.iter_mut() {
        if barycentric_det(piece, sv) < 0.0 {
            piece.swap(1, 2);
        }
    }
    false
}

/// Splits a cut tet (some corner > 0, some < 0) into sub-tets of its inside part (table in
/// the module docs), unoriented.
fn split(g: &[usize; 4], sv: &[f64; 4], out: &mut Vec<[Local; 4]>) {
    let plus: Vec<usize> = (0..4).filter(|&k| sv[k] > 0.0).collect();
    let zero: Vec<usize> = (0..4).filter(|&k| sv[k] == 0.0).collect();
    let minus: Vec<usize> = (0..4).filter(|&k| sv[k] < 0.0).collect();
    match (plus.len(), zero.len(), minus.len()) {
        (1, _, _) => {
            let p = plus[0];
            let mut pts = vec![Local::Corner(p)];
            pts.extend(zero.iter().map(|&z| Local::Corner(z)));
            pts.extend(minus.iter().map(|&m| Local::Crossing(p, m)));
            out.push([pts[0], pts[1], pts[2], pts[3]]);
        }
        (2, 1, 1) => {
            let (p0, p1, m) = (plus[0], plus[1], minus[0]);
            let quad = [
                Local::Corner(p0),
                Local::Corner(p1),
                Local::Crossing(p1, m),
                Local::Crossing(p0, m),
            ];
            pyramid(g, Local::Corner(zero[0]), quad, out);
        }
        (2, 0, 2) => {
            let (p0, p1, m0, m1) = (plus[0], plus[1], minus[0], minus[1]);
            let bottom = [
                Local::Corner(p0),
                Local::Crossing(p0, m0),
                Local::Crossing(p0, m1),
            ];
            let top = [
                Local::Corner(p1),
                Local::Crossing(p1, m0),
                Local::Crossing(p1, m1),
            ];
            prism(g, bottom, top, out);
        }
        (3, 0, 1) => {
            let m = minus[0];
            let bottom = plus.iter().map(|&p| Local::Corner(p)).collect::<Vec<_>>();
            let top = plus
                .iter()
                .map(|&p| Local::Crossing(p, m))
                .collect::<Vec<_>>();
            prism(
                g,
                [bottom[0], bottom[1], bottom[2]],
                [top[0], top[1], top[2]],
                out,
            );
        }
        // p ≥ 1 and m ≥ 1 leave exactly the cases above.
        _ => unreachable!("split called on a tet that is not cut: {sv:?}"),
    }
}

/// Two tets of the pyramid (apex, quad q0 q1 q2 q3), the quad cut through its smallest vertex.
fn pyramid(g: &[usize; 4], apex: Local, q: [Local; 4], out: &mut Vec<[Local; 4]>) {
    let smallest = (0..4).min_by_key(|&k| key(g, q[k])).unwrap_or(0);
    if smallest % 2 == 0 {
        out.push([apex, q[0], q[1], q[2]]);
        out.push([apex, q[0], q[2], q[3]]);
    } else {
        out.push([apex, q[1], q[2], q[3]]);
        out.push([apex, q[1], q[3], q[0]]);
    }
}

/// Three tets of the prism with triangles `bottom` and `top` (edges bottom[k]–top[k]),
/// consistent with the smallest-vertex diagonals of its three quads (Dompierre et al.).
fn prism(g: &[usize; 4], bottom: [Local; 3], top: [Local; 3], out: &mut Vec<[Local; 4]>) {
    let all = [bottom[0], bottom[1], bottom[2], top[0], top[1], top[2]];
    let smallest = (0..6).min_by_key(|&k| key(g, all[k])).unwrap_or(0);
    // Swap the triangles if needed, then rotate, so that the smallest vertex is b0.
    let (b, t) = if smallest < 3 {
        (bottom, top)
    } else {
        (top, bottom)
    };
    let r = smallest % 3;
    let b = [b[r], b[(r + 1) % 3], b[(r + 2) % 3]];
    let t = [t[r], t[(r + 1) % 3], t[(r + 2) % 3]];
    // The quads through b0 are cut from b0 (to t1 and t2); the quad b1 b2 t2 t1 decides.
    if key(g, b[1]).min(key(g, t[2])) < key(g, b[2]).min(key(g, t[1])) {
        out.push([b[0], b[1], b[2], t[2]]);
        out.push([b[0], b[1], t[2], t[1]]);
    } else {
        out.push([b[0], b[1], b[2], t[1]]);
        out.push([b[0], t[1], b[2], t[2]]);
    }
    out.push([b[0], t[1], t[2], t[0]]);
}

/// Barycentric coordinates of a local point in its background tet.
fn barycentric(sv: &[f64; 4], p: Local) -> [f64; 4] {
    let mut l = [0.0; 4];
    match p {
        Local::Corner(k) => l[k] = 1.0,
        Local::Crossing(i, j) => {
            let t = sv[i] / (sv[i] - sv[j]);
            l[i] = 1.0 - t;
            l[j] = t;
        }
    }
    l
}

/// det[λ₁ − λ₀, λ₂ − λ₀, λ₃ − λ₀] over barycentric components 1..3: the sub-tet's volume as
/// a fraction of its background tet's, signed by their relative orientation.
fn barycentric_det(piece: &[Local; 4], sv: &[f64; 4]) -> f64 {
    let l = piece.map(|p| barycentric(sv, p));
    let col = |k: usize| [l[k][1] - l[0][1], l[k][2] - l[0][2], l[k][3] - l[0][3]];
    crate::mesh::dot(col(1), crate::mesh::cross(col(2), col(3)))
}

/// Indices of the tets to keep: all, or those of the face-connected piece of largest volume.
fn select_component(
    tets: &[[usize; 4]],
    volumes: &[f64],
    largest_only: bool,
    report: &mut MarchingReport,
) -> Vec<usize> {
    let mut faces: Vec<([usize; 3], usize)> = Vec::with_capacity(4 * tets.len());
    for (e, t) in tets.iter().enumerate() {
        for skip in 0..4 {
            let mut f = [0usize; 3];
            let mut m = 0;
            for (k, &n) in t.iter().enumerate() {
                if k != skip {
                    f[m] = n;
                    m += 1;
                }
            }
            f.sort_unstable();
            faces.push((f, e));
        }
    }
    faces.sort_unstable();
    let mut sets = DisjointSets::new(tets.len());
    for pair in faces.windows(2) {
        if pair[0].0 == pair[1].0 {
            sets.union(pair[0].1, pair[1].1);
        }
    }
    let mut volume_of_root: HashMap<usize, (f64, usize)> = HashMap::new();
    let roots: Vec<usize> = (0..tets.len()).map(|e| sets.find(e)).collect();
    for (e, &r) in roots.iter().enumerate() {
        let entry = volume_of_root.entry(r).or_insert((0.0, e));
        entry.0 += volumes[e];
    }
    report.components = volume_of_root.len();
    if !largest_only || volume_of_root.len() == 1 {
        return (0..tets.len()).collect();
    }
    // Largest volume; ties go to the piece whose first tet comes first.
    let (&best, _) = volume_of_root
        .iter()
        .max_by(|(_, (va, fa)), (_, (vb, fb))| va.total_cmp(vb).then(fb.cmp(fa)))
        .expect("at least one tet");
    let keep: Vec<usize> = (0..tets.len()).filter(|&e| roots[e] == best).collect();
    report.dropped_component_tets = tets.len() - keep.len();
    report.dropped_component_volume = (0..tets.len())
        .filter(|&e| roots[e] != best)
        .map(|e| volumes[e])
        .sum();
    keep
}

fn check_finite(what: &'static str, x: &[f64], expected: usize) -> Result<(), MarchingError> {
    if x.len() != expected {
        return Err(MarchingError::LengthMismatch {
            what,
            expected,
            found: x.len(),
        });
    }
    match x.iter().position(|v| !v.is_finite()) {
        Some(index) => Err(MarchingError::NonFinite {
            what,
            index,
            value: x[index],
        }),
        None => Ok(()),
    }
}

fn check_offset_fraction(f: f64) -> Result<(), MarchingError> {
    if (0.0..=0.5).contains(&f) {
        Ok(())
    } else {
        Err(MarchingError::BadOption {
            message: format!("max_offset_fraction {f} must be in [0, 0.5]"),
        })
    }
}

fn check_options(o: &MarchingOptions) -> Result<(), MarchingError> {
    check_offset_fraction(o.max_offset_fraction)?;
    if !(0.0..0.5).contains(&o.snap_fraction) {
        return Err(MarchingError::BadOption {
            message: format!("snap_fraction {} must be in [0, 0.5)", o.snap_fraction),
        });
    }
    if !(0.0..1.0).contains(&o.min_volume_fraction) {
        return Err(MarchingError::BadOption {
            message: format!(
                "min_volume_fraction {} must be in [0, 1)",
                o.min_volume_fraction
            ),
        });
    }
    Ok(())
}

// ------------------------------------------------------------------ implicit functions

/// g = min(s, t·S − s), S = max s: the shell {0 < s < t·S} (module docs), with what its
/// vector–Jacobian product needs.
#[derive(Clone, Debug, PartialEq)]
pub struct Shell {
    /// g per grid vertex.
    pub values: Vec<f64>,
    pub thickness: f64,
    /// S = max s and the (lowest) index where it is reached.
    pub max_value: f64,
    pub argmax: usize,
    /// Per vertex: g = t·S − s (true) or g = s (false).
    inner_branch: Vec<bool>,
    /// S was given ([`shell_of_depth`]) rather than taken from the values: a constant then.
    given_max: bool,
}

/// dL/ds and dL/dt of [`Shell`].
#[derive(Clone, Debug, PartialEq)]
pub struct ShellGradient {
    pub values: Vec<f64>,
    pub thickness: f64,
}

/// The shell of relative thickness `thickness` (t > 0; t·S is the depth of the inner wall
/// below the surface, measured in s) of the body {s > 0}. Needs some s > 0.
pub fn shell(values: &[f64], thickness: f64) -> Result<Shell, MarchingError> {
    check_finite("values", values, values.len())?;
    if !(thickness.is_finite() && thickness > 0.0) {
        return Err(MarchingError::BadThickness { thickness });
    }
    let (argmax, max_value) =
        values
            .iter()
            .copied()
            .enumerate()
            .fold((0, f64::NEG_INFINITY), |(bi, bv), (i, v)| {
                if v > bv {
                    (i, v)
                } else {
                    (bi, bv)
                }
            });
    if values.is_empty() || max_value <= 0.0 {
        return Err(MarchingError::NothingInside);
    }
    let depth = thickness * max_value;
    let inner_branch: Vec<bool> = values.iter().map(|&s| s > depth - s).collect();
    let g = values
        .iter()
        .zip(&inner_branch)
        .map(|(&s, &inner)| if inner { depth - s } else { s })
        .collect();
    Ok(Shell {
        values: g,
        thickness,
        max_value,
        argmax,
        inner_branch,
        given_max: false,
    })
}

/// The shell of relative thickness `thickness` with a given reference depth S = `max_value`
/// (> 0) instead of the largest value: g = min(s, t·S − s). For a field sampled from a
/// continuous one whose maximum is known (the deepest point of a signed distance,
/// [`super::SignedDistance::deepest_point`]), so that t means the same on every grid. S is a
/// constant here: [`Shell::vjp`] has no argmax term. `argmax` is still the largest sample.
pub fn shell_of_depth(
    values: &[f64],
    thickness: f64,
    max_value: f64,
) -> Result<Shell, MarchingError> {
    if !(max_value.is_finite() && max_value > 0.0) {
        return Err(MarchingError::BadOption {
            message: format!("shell reference depth {max_value} must be finite and positive"),
        });
    }
    let mut sh = shell(values, thickness)?;
    let depth = thickness * max_value;
    for (v, (&s, inner)) in values.iter().zip(sh.inner_branch.iter_mut()).enumerate() {
        *inner = s > depth - s;
        sh.values[v] = if *inner { depth - s } else { s };
    }
    sh.max_value = max_value;
    sh.given_max = true;
    Ok(sh)
}

impl Shell {
    /// dL/ds and dL/dt from dL/dg (module docs).
    pub fn vjp(&self, d_loss_d_g: &[f64]) -> Result<ShellGradient, MarchingError> {
        check_finite("d_loss_d_g", d_loss_d_g, self.values.len())?;
        let mut d_values = vec![0.0; self.values.len()];
        let (mut d_thickness, mut d_max) = (0.0, 0.0);
        for (v, (&gbar, &inner)) in d_loss_d_g.iter().zip(&self.inner_branch).enumerate() {
            if inner {
                d_values[v] -= gbar;
                d_max += self.thickness * gbar;
                d_thickness += self.max_value * gbar;
            } else {
                d_values[v] += gbar;
            }
        }
        if !self.given_max {
            d_values[self.argmax] += d_max;
        }
        Ok(ShellGradient {
            values: d_values,
            thickness: d_thickness,
        })
    }
}

/// m = c·A + (1 − c)·B per grid vertex.
pub fn morph(a: &[f64], b: &[f64], c: f64) -> Result<Vec<f64>, MarchingError> {
    check_finite("a", a, a.len())?;
    check_finite("b", b, a.len())?;
    check_finite("c", &[c], 1)?;
    Ok(a.iter()
        .zip(b)
        .map(|(&x, &y)| c * x + (1.0 - c) * y)
        .collect())
}

/// dL/dA, dL/dB and dL/dc of [`morph`].
#[derive(Clone, Debug, PartialEq)]
pub struct MorphGradient {
    pub a: Vec<f64>,
    pub b: Vec<f64>,
    pub c: f64,
}

/// Vector–Jacobian product of [`morph`] from dL/dm.
pub fn morph_vjp(
    a: &[f64],
    b: &[f64],
    c: f64,
    d_loss_d_m: &[f64],
) -> Result<MorphGradient, MarchingError> {
    check_finite("a", a, a.len())?;
    check_finite("b", b, a.len())?;
    check_finite("d_loss_d_m", d_loss_d_m, a.len())?;
    check_finite("c", &[c], 1)?;
    Ok(MorphGradient {
        a: d_loss_d_m.iter().map(|&m| c * m).collect(),
        b: d_loss_d_m.iter().map(|&m| (1.0 - c) * m).collect(),
        c: d_loss_d_m
            .iter()
            .zip(a.iter().zip(b))
            .map(|(&m, (&x, &y))| m * (x - y))
            .sum(),
    })
}
