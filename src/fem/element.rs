//! Element matrices for P1 (tet4) and P2 (tet10) linear elasticity.
//!
//! For one element with shape functions N_a and physical gradients G_a = ∇N_a,
//! everything follows from two per-pair quantities, accumulated once:
//!
//! * m_ab = ∫ N_a N_b dV                     (scalar)
//! * S_ab = ∫ G_a G_bᵀ dV                    (3×3, S_ba = S_abᵀ)
//!
//! and the 3×3 blocks of the interleaved matrices (dof = 3·node + component) are
//!
//! * mass block (a,b) = m_ab · I
//! * K_λ block (a,b) = S_ab                  (from ∫(∇·u)(∇·v))
//! * K_μ block (a,b) = tr(S_ab) · I + S_abᵀ  (from ∫2 ε(u):ε(v))
//!
//! so only the upper triangle of node pairs is integrated and the rest is
//! mirrored, which also makes the outputs exactly (bitwise) symmetric.
//!
//! Two evaluation paths:
//! * **affine** (every P1 element, and P2 elements whose mid-edge nodes sit at
//!   the edge midpoints): J is constant, so the mass is det J times a reference
//!   mass precomputed once, and the stiffness, a degree-2 polynomial for P2
//!   (degree 0 for P1), uses the 4-point (1-point) rule. Both are exact.
//! * **isoparametric** (curved P2, or any explicit rule): J, det J and J⁻¹
//!   are evaluated at every quadrature point from all nodes.

use super::quadrature::{tet_rule, QuadratureRule};
use super::shape::{grad_into, shape_into, P2_EDGES};

/// Dense element matrices, row-major `dofs × dofs`, dof = 3·local_node + component.
///
/// The physical matrices are `ρ · mass` and `K = λ · k_lambda + μ · k_mu`
/// (λ, μ Lamé parameters), so derivatives with respect to material parameters
/// are the same matrices with other coefficients (see [`ElementMatrices::stiffness`]).
#[derive(Clone, Debug, PartialEq)]
pub struct ElementMatrices {
    pub dofs: usize,
    /// M₁: ∫ N_a N_b δ_kl dV (unit density).
    pub mass: Vec<f64>,
    /// ∫ (∇·u)(∇·v) dV.
    pub k_lambda: Vec<f64>,
    /// ∫ 2 ε(u):ε(v) dV.
    pub k_mu: Vec<f64>,
}

impl ElementMatrices {
    /// Zero matrices for an element with `nodes` nodes (dofs = 3·nodes).
    pub fn zeros(nodes: usize) -> Self {
        let n = 3 * nodes;
        ElementMatrices {
            dofs: n,
            mass: vec![0.0; n * n],
            k_lambda: vec![0.0; n * n],
            k_mu: vec![0.0; n * n],
        }
    }

    /// Number of element nodes (dofs / 3).
    pub fn nodes(&self) -> usize {
        self.dofs / 3
    }

    /// c_λ · K_λ + c_μ · K_μ. With (λ, μ) this is the stiffness K; with
    /// `Material::dlame_dE()` it is ∂K/∂E, with `dlame_dnu()` it is ∂K/∂ν.
    pub fn stiffness(&self, c_lambda: f64, c_mu: f64) -> Vec<f64> {
        let mut out = vec![0.0; self.dofs * self.dofs];
        self.stiffness_into(c_lambda, c_mu, &mut out);
        out
    }

    /// Allocation-free form of [`ElementMatrices::stiffness`]; `out.len()` must be dofs².
    pub fn stiffness_into(&self, c_lambda: f64, c_mu: f64, out: &mut [f64]) {
        assert_eq!(
            out.len(),
            self.k_lambda.len(),
            "stiffness_into: wrong output length"
        );
        for ((o, &kl), &km) in out.iter_mut().zip(&self.k_lambda).zip(&self.k_mu) {
            *o = c_lambda * kl + c_mu * km;
        }
    }

    fn resize(&mut self, nodes: usize) {
        let n = 3 * nodes;
        self.dofs = n;
        for v in [&mut self.mass, &mut self.k_lambda, &mut self.k_mu] {
            if v.len() != n * n {
                v.clear();
                v.resize(n * n, 0.0);
            }
        }
    }
}

/// Element-level failures. The caller adds the element id.
#[derive(thiserror::Error, Debug, Clone, PartialEq)]
pub enum ElementError {
    #[error(
        "Jacobian determinant {det} ≤ 0 at reference point ({}, {}, {}): element is inverted, degenerate or too strongly curved",
        point[0], point[1], point[2]
    )]
    NonPositiveJacobian { det: f64, point: [f64; 3] },
    #[error("unsupported tetrahedron node count {0}: expected 4 (P1) or 10 (P2)")]
    BadNodeCount(usize),
}

/// Default quadrature for an element type.
///
/// * P1 (4 nodes): degree 2, so the mass (degree 2) is exact; stiffness is constant.
/// * P2 straight: degree 4: mass N_a N_b is degree 4, stiffness G_a G_b degree 2; both exact.
/// * P2 curved: degree 8. The isoparametric map is quadratic, so det J is a
///   cubic and mass × det J a degree-7 polynomial (exact here). The stiffness
///   integrand (adj J ∇N)(adj J ∇N)ᵀ / det J is rational: no rule is exact;
///   its numerator is degree 6, so degree 8 captures the leading terms of its
///   expansion with margin (the collapsed rule used is in fact exact to 9).
///
/// Any node count other than 10 gets the P1 rule.
pub fn default_rule(nodes_per_tet: usize, curved: bool) -> QuadratureRule {
    match (nodes_per_tet, curved) {
        (10, false) => tet_rule(4),
        (10, true) => tet_rule(CURVED_DEGREE),
        _ => tet_rule(2),
    }
}

const CURVED_DEGREE: usize = 8;

/// True if a P2 element's mid-edge nodes are off the straight-edge midpoints by
/// more than 1e-14 × edge length (then its geometry map is not affine).
///
/// The bar sits at rounding level on purpose: the straight path ignores any
/// mid-node offset, so a looser bar (it was 1e-10) would make the assembled
/// matrices a non-smooth function of node positions, and a finite difference
/// of eigenvalues over a smooth node displacement (what shape optimisation
/// does) would see a jump of that size. Midpoints made by `lift_to_quadratic`
/// are computed with this same formula and so stay exactly straight.
/// P1 elements (and any other node count) are never curved.
pub fn is_curved(coords: &[[f64; 3]]) -> bool {
    if coords.len() != 10 {
        return false;
    }
    P2_EDGES.iter().enumerate().any(|(e, &(i, j))| {
        let (a, b, m) = (coords[i], coords[j], coords[4 + e]);
        let mut off2 = 0.0;
        let mut len2 = 0.0;
        for d in 0..3 {
            let o = m[d] - 0.5 * (a[d] + b[d]);
            off2 += o * o;
            len2 += (b[d] - a[d]) * (b[d] - a[d]);
        }
        off2 > 1e-28 * len2
    })
}

/// Element matrices with the given rule, isoparametric evaluation at every point.
/// `coords.len()` must be 4 (P1) or 10 (P2). For the assembly loop prefer
/// [`ElementKernel`], which precomputes the shape tables once.
pub fn element_matrices(
    coords: &[[f64; 3]],
    quad: &QuadratureRule,
) -> Result<ElementMatrices, ElementError> {
    ElementKernel::with_rule(coords.len(), quad)?.matrices(coords)
}

/// Volume ∫ det J dξ of an element (4 or 10 nodes) with the given rule
/// (exact for degree ≥ 3, since det J is at most cubic).
pub fn element_volume(coords: &[[f64; 3]], quad: &QuadratureRule) -> Result<f64, ElementError> {
    ElementKernel::with_rule(coords.len(), quad)?.volume(coords)
}

/// Shape values and reference gradients tabulated at the points of one rule
/// (shared with [`super::sensitivity`]).
#[derive(Clone, Debug)]
pub(super) struct Tables {
    pub(super) points: Vec<[f64; 3]>,
    pub(super) weights: Vec<f64>,
    /// `shape[q * nodes + a]`
    pub(super) shape: Vec<f64>,
    /// `grad[q * nodes + a]`, d/dξ, d/dη, d/dζ
    pub(super) grad: Vec<[f64; 3]>,
}

impl Tables {
    pub(super) fn new(nodes: usize, rule: &QuadratureRule) -> Self {
        let nq = rule.weights.len();
        let mut shape = vec![0.0; nq * nodes];
        let mut grad = vec![[0.0; 3]; nq * nodes];
        for (q, &p) in rule.points.iter().enumerate() {
            shape_into(nodes, p, &mut shape[q * nodes..(q + 1) * nodes]);
            grad_into(nodes, p, &mut grad[q * nodes..(q + 1) * nodes]);
        }
        Tables {
            points: rule.points.clone(),
            weights: rule.weights.clone(),
            shape,
            grad,
        }
    }
}

/// Upper-triangle pair count for 10 nodes; P1 uses the first 10 slots.
const MAX_PAIRS: usize = 55;

#[derive(Clone, Debug)]
enum Path {
    /// Constant Jacobian from the corners; `mass_ref[p] = ∫_ref N_a N_b` per pair,
    /// `stiff` the rule for the stiffness. For P2, `curved` handles elements
    /// that turn out to be curved.
    Affine {
        stiff: Tables,
        mass_ref: Box<[f64; MAX_PAIRS]>,
        curved: Option<Tables>,
    },
    Iso(Tables),
}

/// Precomputed element integrator for one element type, reused across elements.
///
/// * `new(4, _)`: P1, exact, affine.
/// * `new(10, false)`: P2 "auto": straight elements take the exact affine path
///   (4-point stiffness, precomputed mass); elements for which [`is_curved`]
///   holds are integrated isoparametrically with the curved default rule.
///   This is the kernel to use for a mesh that mixes straight and curved elements.
/// * `new(10, true)`: always isoparametric with the curved rule (degree 8).
/// * `with_rule(n, rule)`: always isoparametric with the given rule.
#[derive(Clone, Debug)]
pub struct ElementKernel {
    nodes: usize,
    path: Path,
}

impl ElementKernel {
    /// Kernel for `nodes_per_tet` ∈ {4, 10}. Panics on any other count
    /// (a programming error); use [`ElementKernel::try_new`] to get an error instead.
    pub fn new(nodes_per_tet: usize, curved: bool) -> Self {
        Self::try_new(nodes_per_tet, curved).unwrap_or_else(|e| panic!("ElementKernel::new: {e}"))
    }

    /// Fallible form of [`ElementKernel::new`].
    pub fn try_new(nodes_per_tet: usize, curved: bool) -> Result<Self, ElementError> {
        check_nodes(nodes_per_tet)?;
        if nodes_per_tet == 10 && curved {
            return Self::with_rule(10, &default_rule(10, true));
        }
        // Affine path: stiffness integrand has degree 2(p−1); mass reference
        // integrals with a rule exact for degree 2p.
        let (stiff_rule, mass_rule) = if nodes_per_tet == 4 {
            (tet_rule(0), tet_rule(2))
        } else {
            (tet_rule(2), tet_rule(4))
        };
        let stiff = Tables::new(nodes_per_tet, &stiff_rule);
        let mt = Tables::new(nodes_per_tet, &mass_rule);
        let mut mass_ref = [0.0; MAX_PAIRS];
        for (q, &w) in mt.weights.iter().enumerate() {
            let n = &mt.shape[q * nodes_per_tet..(q + 1) * nodes_per_tet];
            let mut p = 0;
            for a in 0..nodes_per_tet {
                for b in a..nodes_per_tet {
                    mass_ref[p] += w * n[a] * n[b];
                    p += 1;
                }
            }
        }
        let curved = (nodes_per_tet == 10).then(|| Tables::new(10, &default_rule(10, true)));
        Ok(ElementKernel {
            nodes: nodes_per_tet,
            path: Path::Affine {
                stiff,
                mass_ref: Box::new(mass_ref),
                curved,
            },
        })
    }

    /// Kernel that integrates isoparametrically with `rule` (for every element).
    pub fn with_rule(nodes_per_tet: usize, rule: &QuadratureRule) -> Result<Self, ElementError> {
        check_nodes(nodes_per_tet)?;
        Ok(ElementKernel {
            nodes: nodes_per_tet,
            path: Path::Iso(Tables::new(nodes_per_tet, rule)),
        })
    }

    /// Node count this kernel was built for.
    pub fn nodes_per_tet(&self) -> usize {
        self.nodes
    }

    /// Element matrices (allocating). See [`ElementKernel::matrices_into`].
    pub fn matrices(&self, coords: &[[f64; 3]]) -> Result<ElementMatrices, ElementError> {
        let mut out = ElementMatrices::zeros(self.nodes);
        self.matrices_into(coords, &mut out)?;
        Ok(out)
    }

    /// Element matrices into `out`, reusing its buffers (no allocation once
    /// `out` has the right size). On error `out` is left unspecified.
    pub fn matrices_into(
        &self,
        coords: &[[f64; 3]],
        out: &mut ElementMatrices,
    ) -> Result<(), ElementError> {
        if coords.len() != self.nodes {
            return Err(ElementError::BadNodeCount(coords.len()));
        }
        let mut acc = Acc::new();
        match (&self.path, self.nodes) {
            (Path::Iso(t), 4) => acc.iso::<4>(coords, t)?,
            (Path::Iso(t), _) => acc.iso::<10>(coords, t)?,
            (
                Path::Affine {
                    stiff, mass_ref, ..
                },
                4,
            ) => acc.affine::<4>(coords, stiff, mass_ref)?,
            (
                Path::Affine {
                    stiff,
                    mass_ref,
                    curved,
                },
                _,
            ) => {
                if is_curved(coords) {
                    acc.iso::<10>(
                        coords,
                        curved.as_ref().expect("P2 kernel has curved tables"),
                    )?
                } else {
                    acc.affine::<10>(coords, stiff, mass_ref)?
                }
            }
        }
        out.resize(self.nodes);
        acc.scatter(self.nodes, out);
        Ok(())
    }

    /// Element volume ∫ det J dξ (affine: det J / 6; curved: with the curved or given rule).
    pub fn volume(&self, coords: &[[f64; 3]]) -> Result<f64, ElementError> {
        if coords.len() != self.nodes {
            return Err(ElementError::BadNodeCount(coords.len()));
        }
        let tables = match &self.path {
            Path::Iso(t) => t,
            Path::Affine { curved, .. } => match curved {
                Some(t) if is_curved(coords) => t,
                _ => {
                    let j = affine_jacobian(coords);
                    let det = det3(&j);
                    if !is_positive(det) {
                        return Err(ElementError::NonPositiveJacobian {
                            det,
                            point: [0.25; 3],
                        });
                    }
                    return Ok(det / 6.0);
                }
            },
        };
        let n = self.nodes;
        let mut vol = 0.0;
        for (q, &w) in tables.weights.iter().enumerate() {
            let j = jacobian(coords, &tables.grad[q * n..(q + 1) * n]);
            let det = det3(&j);
            if !is_positive(det) {
                return Err(ElementError::NonPositiveJacobian {
                    det,
                    point: tables.points[q],
                });
            }
            vol += w * det;
        }
        Ok(vol)
    }
}

/// det > 0, written so that NaN (from NaN/infinite coordinates) is rejected too.
#[inline(always)]
pub(super) fn is_positive(det: f64) -> bool {
    det > 0.0
}

pub(super) fn check_nodes(n: usize) -> Result<(), ElementError> {
    if n == 4 || n == 10 {
        Ok(())
    } else {
        Err(ElementError::BadNodeCount(n))
    }
}

/// J[r][c] = ∂x_r/∂ξ_c = Σ_a x_a[r] ∂N_a/∂ξ_c.
#[inline(always)]
pub(crate) fn jacobian(coords: &[[f64; 3]], grad: &[[f64; 3]]) -> [[f64; 3]; 3] {
    let mut j = [[0.0; 3]; 3];
    for (x, g) in coords.iter().zip(grad) {
        for r in 0..3 {
            for c in 0..3 {
                j[r][c] += x[r] * g[c];
            }
        }
    }
    j
}

/// Jacobian of the affine map through the 4 corners (columns are edge vectors from corner 0).
#[inline(always)]
pub(crate) fn affine_jacobian(coords: &[[f64; 3]]) -> [[f64; 3]; 3] {
    let mut j = [[0.0; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            j[r][c] = coords[c + 1][r] - coords[0][r];
        }
    }
    j
}

#[inline(always)]
pub(crate) fn det3(j: &[[f64; 3]; 3]) -> f64 {
    j[0][0] * (j[1][1] * j[2][2] - j[1][2] * j[2][1])
        - j[0][1] * (j[1][0] * j[2][2] - j[1][2] * j[2][0])
        + j[0][2] * (j[1][0] * j[2][1] - j[1][1] * j[2][0])
}

/// J⁻ᵀ: maps reference gradients to physical ones, G = J⁻ᵀ g.
#[inline(always)]
pub(super) fn inv_transpose(j: &[[f64; 3]; 3], det: f64) -> [[f64; 3]; 3] {
    let id = 1.0 / det;
    // Cofactor matrix C (C[r][c] = cofactor of J[r][c]); J⁻ᵀ = C / det.
    [
        [
            (j[1][1] * j[2][2] - j[1][2] * j[2][1]) * id,
            (j[1][2] * j[2][0] - j[1][0] * j[2][2]) * id,
            (j[1][0] * j[2][1] - j[1][1] * j[2][0]) * id,
        ],
        [
            (j[0][2] * j[2][1] - j[0][1] * j[2][2]) * id,
            (j[0][0] * j[2][2] - j[0][2] * j[2][0]) * id,
            (j[0][1] * j[2][0] - j[0][0] * j[2][1]) * id,
        ],
        [
            (j[0][1] * j[1][2] - j[0][2] * j[1][1]) * id,
            (j[0][2] * j[1][0] - j[0][0] * j[1][2]) * id,
            (j[0][0] * j[1][1] - j[0][1] * j[1][0]) * id,
        ],
    ]
}

#[inline(always)]
pub(super) fn matvec(m: &[[f64; 3]; 3], v: &[f64; 3]) -> [f64; 3] {
    [
        m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
        m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
        m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2],
    ]
}

/// Per-pair accumulators (upper triangle of node pairs, row by row).
struct Acc {
    s: [[f64; 9]; MAX_PAIRS],
    m: [f64; MAX_PAIRS],
}

impl Acc {
    #[inline(always)]
    fn new() -> Self {
        Acc {
            s: [[0.0; 9]; MAX_PAIRS],
            m: [0.0; MAX_PAIRS],
        }
    }

    /// S_ab += wd · G_a G_bᵀ for all a ≤ b.
    #[inline(always)]
    fn add_grad<const N: usize>(&mut self, g: &[[f64; 3]; N], wd: f64) {
        let mut p = 0;
        for a in 0..N {
            let ga = [g[a][0] * wd, g[a][1] * wd, g[a][2] * wd];
            for gb in &g[a..] {
                let s = &mut self.s[p];
                for k in 0..3 {
                    for l in 0..3 {
                        s[3 * k + l] += ga[k] * gb[l];
                    }
                }
                p += 1;
            }
        }
    }

    fn affine<const N: usize>(
        &mut self,
        coords: &[[f64; 3]],
        stiff: &Tables,
        mass_ref: &[f64; MAX_PAIRS],
    ) -> Result<(), ElementError> {
        let j = affine_jacobian(coords);
        let det = det3(&j);
        if !is_positive(det) {
            return Err(ElementError::NonPositiveJacobian {
                det,
                point: [0.25; 3],
            });
        }
        let jit = inv_transpose(&j, det);
        for (q, &w) in stiff.weights.iter().enumerate() {
            let mut g = [[0.0; 3]; N];
            for (ga, gr) in g.iter_mut().zip(&stiff.grad[q * N..(q + 1) * N]) {
                *ga = matvec(&jit, gr);
            }
            self.add_grad::<N>(&g, w * det);
        }
        let np = N * (N + 1) / 2;
        for (m, &r) in self.m[..np].iter_mut().zip(&mass_ref[..np]) {
            *m = det * r;
        }
        Ok(())
    }

    fn iso<const N: usize>(&mut self, coords: &[[f64; 3]], t: &Tables) -> Result<(), ElementError> {
        for (q, &w) in t.weights.iter().enumerate() {
            let gref = &t.grad[q * N..(q + 1) * N];
            let j = jacobian(coords, gref);
            let det = det3(&j);
            if !is_positive(det) {
                return Err(ElementError::NonPositiveJacobian {
                    det,
                    point: t.points[q],
                });
            }
            let jit = inv_transpose(&j, det);
            let mut g = [[0.0; 3]; N];
            for (ga, gr) in g.iter_mut().zip(gref) {
                *ga = matvec(&jit, gr);
            }
            let wd = w * det;
            self.add_grad::<N>(&g, wd);
            let n = &t.shape[q * N..(q + 1) * N];
            let mut p = 0;
            for a in 0..N {
                let na = n[a] * wd;
                for nb in &n[a..] {
                    self.m[p] += na * nb;
                    p += 1;
                }
            }
        }
        Ok(())
    }

    /// Expand pair quantities into the three dense matrices (both triangles).
    fn scatter(&self, nodes: usize, out: &mut ElementMatrices) {
        let n = 3 * nodes;
        let (mass, kl, km) = (&mut out.mass, &mut out.k_lambda, &mut out.k_mu);
        let mut p = 0;
        for a in 0..nodes {
            for b in a..nodes {
                let s = &self.s[p];
                let m = self.m[p];
                let tr = s[0] + s[4] + s[8];
                for k in 0..3 {
                    let i = 3 * a + k;
                    for l in 0..3 {
                        let jj = 3 * b + l;
                        let diag = k == l;
                        let vl = s[3 * k + l];
                        let vm = s[3 * l + k] + if diag { tr } else { 0.0 };
                        let vmass = if diag { m } else { 0.0 };
                        kl[i * n + jj] = vl;
                        kl[jj * n + i] = vl;
                        km[i * n + jj] = vm;
                        km[jj * n + i] = vm;
                        mass[i * n + jj] = vmass;
                        mass[jj * n + i] = vmass;
                    }
                }
                p += 1;
            }
        }
    }
}

#[cfg(test)]
pub(super) mod tests;
