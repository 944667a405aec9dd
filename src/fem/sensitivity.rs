//! Shape sensitivities: exact derivatives of element energies with respect to
//! node positions, element by element, without forming ∂K/∂x.
//!
//! # What is computed
//!
//! For a mode φ of K φ = λ M φ (eigenvalue λ = ω² in rad²/s², M-normalised,
//! φᵀ M φ = 1) the derivative of λ with respect to node coordinate x_{j,d} is
//!
//! ```text
//! dλ/dx_{j,d} = Σ_e φ_eᵀ (∂K_e/∂x_{j,d} − λ ∂M_e/∂x_{j,d}) φ_e,
//! K_e = λ_L K_λ,e + μ K_μ,e,   M_e = ρ M₁,e
//! ```
//!
//! (λ_L, μ Lamé parameters in Pa, ρ density in kg/m³, matrices as in
//! [`super::element`]). Per element this is the gradient, at fixed φ_e and λ,
//! of the scalar
//!
//! ```text
//! s_e(x) = φ_eᵀ (λ_L K_λ(x) + μ K_μ(x) − λ ρ M₁(x)) φ_e
//! ```
//!
//! with respect to the element's node coordinates x_a (4 or 10 nodes, m).
//! [`SensitivityKernel`] returns g_e ∈ ℝ^{nodes×3}, g_e[a][d] = ∂s_e/∂x_{a,d};
//! the caller scatters g_e onto global nodes and sums. Units: with φ
//! M-normalised (φ in kg^-½), s_e is in rad²/s² and g_e in rad²/(s²·m).
//!
//! # Derivation (per quadrature point, weight w)
//!
//! With reference gradients ∇_ξN_a, J = Σ_a x_a ⊗ ∇_ξN_a, D = det J,
//! physical gradients G_a = J⁻ᵀ ∇_ξN_a, displacement gradient
//! H = Σ_a u_a ⊗ G_a (u_a the node-a block of φ_e) and v = Σ_a N_a u_a:
//!
//! ```text
//! s_e = Σ_q w D [ ψ(H) − λ ρ |v|² ],   ψ(H) = λ_L (tr H)² + μ (H:H + H:Hᵀ)
//! ```
//!
//! (ψ = 2 × strain-energy density, since φᵀK_μφ = ∫ 2 ε:ε and ε:ε summed over
//! the symmetric part gives ½(H:H + H:Hᵀ)). Only J depends on x:
//! H = H_ξ J⁻¹ with the x-independent H_ξ = Σ_a u_a ⊗ ∇_ξN_a, and v does not
//! depend on x at all. Using d(det J) = det J · tr(J⁻¹ dJ) and
//! d(J⁻¹) = −J⁻¹ dJ J⁻¹, so dH = −H dJ J⁻¹:
//!
//! ```text
//! d(D ψ) = D [ ψ J⁻ᵀ − Hᵀ P J⁻ᵀ ] : dJ,   P = ∂ψ/∂H = 2 λ_L tr(H) I + 2 μ (H + Hᵀ)
//! d(D |v|²) = D |v|² J⁻ᵀ : dJ
//! ```
//!
//! i.e. ∂(integrand)/∂J = w D Σ J⁻ᵀ with the (Eshelby-type) tensor
//! Σ = (ψ − λ ρ |v|²) I − Hᵀ P. Since ∂J/∂x_{a,d} = e_d ⊗ ∇_ξN_a,
//!
//! ```text
//! ∂s_e/∂x_a = Σ_q w D Σ G_a          (a 3-vector per node)
//! ```
//!
//! Per point and mode this costs three passes over the nodes (H, v, Σ G_a):
//! ~21·nodes multiply-adds, against ~4.5·nodes² for the element matrices, and
//! the geometry (J, D, J⁻ᵀ, G_a) is shared by all modes of a batch.
//!
//! Identities (used as tests): Σ_a ∂s_e/∂x_a = 0 (translation; Σ_a ∇_ξN_a = 0);
//! Euler for x → t·x (K ∝ t, M ∝ t³): Σ_a x_a·g_a = φᵀKφ − 3 λ φᵀMφ; rotation:
//! s_e is invariant only if φ_e rotates with the element, so
//! Σ_a x_a × g_a + Σ_a u_a × r_a = 0 with r = 2 (K − λM) φ_e. Summed over a
//! mesh with an exact eigenpair the r-terms cancel (K φ = λ M φ), so the
//! global gradient is orthogonal to rigid rotations and translations.
//!
//! # Quadrature: the exact derivative of what assembly computes
//!
//! [`SensitivityKernel`] mirrors [`ElementKernel`]'s rule selection:
//!
//! * `new(4, _)`: P1, J constant; 4-point degree-2 rule. Value exact (as
//!   the element matrices), derivative integrand of degree 2, exact.
//! * `new(10, false)`, element straight ([`is_curved`] false): J is the affine
//!   Jacobian of the corners (as in assembly), integrated with the 14-point
//!   degree-5 rule. The value is exact; the derivative integrand — including
//!   the derivative with respect to mid-edge nodes, which curves the element —
//!   has degree ≤ 5, so it is exact too. It equals the derivative of the
//!   curved branch that assembly uses once a node moves (the degree-8 rule
//!   also integrates this first variation exactly), so the assembled matrices
//!   are differentiable there and this is their derivative.
//! * `new(10, false)`, element curved: isoparametric with the curved default
//!   rule (degree 8), exactly like assembly: the gradient is the exact
//!   derivative of the quadrature approximation assembly computes.
//! * `new(10, true)` / `with_rule(n, rule)`: isoparametric with that rule.
//!
//! Global use: a node shared by several elements receives the sum of their
//! g_e rows; if a shape parametrisation keeps mid-edge nodes at edge
//! midpoints, apply the chain rule (corner += ½ × each adjacent mid-node row).
//!
//! [`ElementKernel`]: super::element::ElementKernel
//! [`is_curved`]: super::element::is_curved

use super::element::{
    affine_jacobian, check_nodes, default_rule, det3, inv_transpose, is_curved, is_positive,
    jacobian, matvec, ElementError, Tables,
};
use super::material::Material;
use super::quadrature::{tet_rule, QuadratureRule};

/// Material coefficients of s_e: Lamé λ_L and μ (Pa), density ρ (kg/m³).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ElasticCoefficients {
    /// Lamé's first parameter λ_L, Pa (multiplies K_λ).
    pub lambda: f64,
    /// Shear modulus μ, Pa (multiplies K_μ).
    pub mu: f64,
    /// Density ρ, kg/m³ (M = ρ M₁).
    pub rho: f64,
}

impl ElasticCoefficients {
    /// Coefficients of an isotropic material.
    pub fn from_material(m: &Material) -> Self {
        let (lambda, mu) = m.lame();
        ElasticCoefficients {
            lambda,
            mu,
            rho: m.density,
        }
    }
}

/// The two quadratic forms of one mode on one element, by-products of the
/// gradient: `stiffness = φ_eᵀ K_e φ_e`, `mass = φ_eᵀ (ρ M₁) φ_e`, so
/// s_e = stiffness − λ · mass. Summed over a mesh for an M-normalised mode,
/// Σ stiffness = λ and Σ mass = 1.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ModeEnergy {
    pub stiffness: f64,
    pub mass: f64,
}

impl ModeEnergy {
    /// s_e = stiffness − eigenvalue · mass.
    pub fn value(&self, eigenvalue: f64) -> f64 {
        self.stiffness - eigenvalue * self.mass
    }
}

#[derive(Clone, Debug)]
enum Path {
    /// Straight elements: corner (affine) Jacobian with `straight`; P2
    /// elements that are curved use `curved` isoparametrically.
    Auto {
        straight: Tables,
        curved: Option<Tables>,
    },
    /// Isoparametric with one rule for every element.
    Iso(Tables),
}

/// Precomputed per-element gradient kernel for ∂s_e/∂x; construct it like
/// the [`ElementKernel`](super::element::ElementKernel) used for assembly
/// (same arguments ⇒ same quadrature ⇒ exact derivative of the assembled
/// quantity). Pure and serial; `gradient_into`/`gradients_into` do not allocate.
#[derive(Clone, Debug)]
pub struct SensitivityKernel {
    nodes: usize,
    path: Path,
}

impl SensitivityKernel {
    /// Mirror of `ElementKernel::new`: `nodes_per_tet` ∈ {4, 10}; `curved`
    /// forces the degree-8 isoparametric path for P2. Panics on other counts.
    pub fn new(nodes_per_tet: usize, curved: bool) -> Self {
        Self::try_new(nodes_per_tet, curved)
            .unwrap_or_else(|e| panic!("SensitivityKernel::new: {e}"))
    }

    /// Fallible form of [`SensitivityKernel::new`].
    pub fn try_new(nodes_per_tet: usize, curved: bool) -> Result<Self, ElementError> {
        check_nodes(nodes_per_tet)?;
        if nodes_per_tet == 10 && curved {
            return Self::with_rule(10, &default_rule(10, true));
        }
        // Rules exact for the value and for its first variation on straight
        // elements: P1 degree 2 (mass), P2 degree 5 (mass variation dD·N_aN_b).
        let straight_rule = if nodes_per_tet == 4 {
            tet_rule(2)
        } else {
            tet_rule(5)
        };
        Ok(SensitivityKernel {
            nodes: nodes_per_tet,
            path: Path::Auto {
                straight: Tables::new(nodes_per_tet, &straight_rule),
                curved: (nodes_per_tet == 10).then(|| Tables::new(10, &default_rule(10, true))),
            },
        })
    }

    /// Mirror of `ElementKernel::with_rule`: isoparametric with `rule` for every element.
    pub fn with_rule(nodes_per_tet: usize, rule: &QuadratureRule) -> Result<Self, ElementError> {
        check_nodes(nodes_per_tet)?;
        Ok(SensitivityKernel {
            nodes: nodes_per_tet,
            path: Path::Iso(Tables::new(nodes_per_tet, rule)),
        })
    }

    /// Node count this kernel was built for.
    pub fn nodes_per_tet(&self) -> usize {
        self.nodes
    }

    /// Gradient of s_e for one mode. `phi_e`: the element's slice of the mode
    /// (length 3·nodes, dof = 3·local_node + component); `eigenvalue` λ in
    /// rad²/s². Writes `grad[a] = ∂s_e/∂x_a` (`grad.len()` = nodes) and returns
    /// the two quadratic forms. Panics on slice-length mismatches.
    pub fn gradient_into(
        &self,
        coords: &[[f64; 3]],
        phi_e: &[f64],
        eigenvalue: f64,
        coef: ElasticCoefficients,
        grad: &mut [[f64; 3]],
    ) -> Result<ModeEnergy, ElementError> {
        let mut e = [ModeEnergy::default()];
        self.gradients_into(
            coords,
            phi_e,
            std::slice::from_ref(&eigenvalue),
            coef,
            grad,
            Some(&mut e),
        )?;
        Ok(e[0])
    }

    /// Batched gradient for m = `eigenvalues.len()` modes sharing the
    /// geometry work. `phi_e` is m × 3·nodes, mode-major (mode k at
    /// `phi_e[k·3·nodes..]`); `grad` is m × nodes (mode k at `grad[k·nodes..]`);
    /// `energies`, if given, has length m. Results are bitwise identical to m
    /// calls of [`SensitivityKernel::gradient_into`]. Panics on length mismatches;
    /// on error the outputs are unspecified.
    pub fn gradients_into(
        &self,
        coords: &[[f64; 3]],
        phi_e: &[f64],
        eigenvalues: &[f64],
        coef: ElasticCoefficients,
        grad: &mut [[f64; 3]],
        mut energies: Option<&mut [ModeEnergy]>,
    ) -> Result<(), ElementError> {
        if coords.len() != self.nodes {
            return Err(ElementError::BadNodeCount(coords.len()));
        }
        let m = eigenvalues.len();
        assert_eq!(
            phi_e.len(),
            3 * self.nodes * m,
            "gradients_into: phi_e must hold 3·nodes values per mode"
        );
        assert_eq!(
            grad.len(),
            self.nodes * m,
            "gradients_into: grad must hold nodes rows per mode"
        );
        grad.fill([0.0; 3]);
        if let Some(e) = energies.as_deref_mut() {
            assert_eq!(
                e.len(),
                m,
                "gradients_into: energies must hold one entry per mode"
            );
            e.fill(ModeEnergy::default());
        }
        let modes = Modes {
            phi: phi_e,
            eig: eigenvalues,
            coef,
        };
        let (tables, affine) = match &self.path {
            Path::Iso(t) => (t, false),
            Path::Auto { straight, curved } => match curved {
                Some(c) if is_curved(coords) => (c, false),
                _ => (straight, true),
            },
        };
        match self.nodes {
            4 => accumulate::<4>(coords, tables, affine, &modes, grad, energies),
            _ => accumulate::<10>(coords, tables, affine, &modes, grad, energies),
        }
    }
}

struct Modes<'a> {
    phi: &'a [f64],
    eig: &'a [f64],
    coef: ElasticCoefficients,
}

fn accumulate<const N: usize>(
    coords: &[[f64; 3]],
    t: &Tables,
    affine: bool,
    modes: &Modes<'_>,
    grad: &mut [[f64; 3]],
    mut energies: Option<&mut [ModeEnergy]>,
) -> Result<(), ElementError> {
    let x: &[[f64; 3]; N] = coords.try_into().expect("node count checked");
    let affine_geom = if affine {
        let j = affine_jacobian(x);
        let det = det3(&j);
        if !is_positive(det) {
            return Err(ElementError::NonPositiveJacobian {
                det,
                point: [0.25; 3],
            });
        }
        Some((inv_transpose(&j, det), det))
    } else {
        None
    };
    let ndof = 3 * N;
    let rho = modes.coef.rho;
    for (q, &w) in t.weights.iter().enumerate() {
        let gref: &[[f64; 3]; N] = t.grad[q * N..(q + 1) * N].try_into().unwrap();
        let shape: &[f64; N] = t.shape[q * N..(q + 1) * N].try_into().unwrap();
        let (jit, det) = match affine_geom {
            Some(g) => g,
            None => {
                let j = jacobian(x, gref);
                let det = det3(&j);
                if !is_positive(det) {
                    return Err(ElementError::NonPositiveJacobian {
                        det,
                        point: t.points[q],
                    });
                }
                (inv_transpose(&j, det), det)
            }
        };
        let mut g = [[0.0; 3]; N];
        for (ga, gr) in g.iter_mut().zip(gref) {
            *ga = matvec(&jit, gr);
        }
        let wd = w * det;
        for (k, &eig) in modes.eig.iter().enumerate() {
            let u: &[f64] = &modes.phi[k * ndof..(k + 1) * ndof];
            let out: &mut [[f64; 3]; N] = (&mut grad[k * N..(k + 1) * N]).try_into().unwrap();
            let (psi, vv) = point_mode::<N>(&g, shape, wd, u, eig, &modes.coef, out);
            if let Some(e) = energies.as_deref_mut() {
                e[k].stiffness += wd * psi;
                e[k].mass += rho * wd * vv;
            }
        }
    }
    Ok(())
}

/// One quadrature point, one mode: adds w D Σ G_a to `out[a]`; returns (ψ, |v|²).
#[inline(always)]
fn point_mode<const N: usize>(
    g: &[[f64; 3]; N],
    shape: &[f64; N],
    wd: f64,
    u: &[f64],
    eig: f64,
    c: &ElasticCoefficients,
    out: &mut [[f64; 3]; N],
) -> (f64, f64) {
    let u: &[f64] = &u[..3 * N];
    // H_kl = Σ_a u_a,k G_a,l ; v = Σ_a N_a u_a
    let mut h = [[0.0; 3]; 3];
    let mut v = [0.0; 3];
    for a in 0..N {
        let ua = [u[3 * a], u[3 * a + 1], u[3 * a + 2]];
        let ga = g[a];
        for k in 0..3 {
            v[k] += shape[a] * ua[k];
            for l in 0..3 {
                h[k][l] += ua[k] * ga[l];
            }
        }
    }
    let tr = h[0][0] + h[1][1] + h[2][2];
    let mut hh = 0.0; // H:H + H:Hᵀ
    let mut p = [[0.0; 3]; 3]; // P = 2 λ_L tr(H) I + 2 μ (H + Hᵀ)
    for k in 0..3 {
        for l in 0..3 {
            hh += h[k][l] * (h[k][l] + h[l][k]);
            p[k][l] = 2.0 * c.mu * (h[k][l] + h[l][k]);
        }
        p[k][k] += 2.0 * c.lambda * tr;
    }
    let psi = c.lambda * tr * tr + c.mu * hh;
    let vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    // w D Σ, Σ = (ψ − λ ρ |v|²) I − Hᵀ P
    let diag = psi - eig * c.rho * vv;
    let mut s = [[0.0; 3]; 3];
    for k in 0..3 {
        for l in 0..3 {
            let htp = h[0][k] * p[0][l] + h[1][k] * p[1][l] + h[2][k] * p[2][l];
            s[k][l] = wd * (if k == l { diag } else { 0.0 } - htp);
        }
    }
    for (o, ga) in out.iter_mut().zip(g) {
        let d = matvec(&s, ga);
        o[0] += d[0];
        o[1] += d[1];
        o[2] += d[2];
    }
    (psi, vv)
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use crate::fem::element::{ElementKernel, ElementMatrices};
    use crate::fem::shape::{P1_NODES, P2_EDGES, P2_NODES};

    use crate::fem::element::tests::{random_rotation, Rng};

    /// Random well-shaped map x = L·(R S ξ + t): rotation, anisotropic scale,
    /// mild shear, translation, overall length `len` (m).
    fn random_affine(rng: &mut Rng, len: f64) -> impl Fn([f64; 3]) -> [f64; 3] {
        let r = random_rotation(rng);
        let mut s = [[0.0; 3]; 3];
        for i in 0..3 {
            s[i][i] = rng.uniform(0.5, 2.0);
            for j in i + 1..3 {
                s[i][j] = rng.uniform(-0.3, 0.3);
            }
        }
        let t = [
            rng.uniform(-5.0, 5.0),
            rng.uniform(-5.0, 5.0),
            rng.uniform(-5.0, 5.0),
        ];
        move |x: [f64; 3]| {
            let mut y = [0.0; 3];
            for i in 0..3 {
                let mut acc = t[i];
                for k in 0..3 {
                    for j in 0..3 {
                        acc += r[i][k] * s[k][j] * x[j];
                    }
                }
                y[i] = len * acc;
            }
            y
        }
    }

    #[derive(Clone, Copy, Debug)]
    enum Kind {
        P1,
        P2Straight,
        P2Curved,
    }

    /// Random element of the given kind; curved elements go through a
    /// quadratic map plus random mid-node offsets (~5 % of the size).
    fn element(rng: &mut Rng, kind: Kind, len: f64) -> Vec<[f64; 3]> {
        let map = random_affine(rng, len);
        match kind {
            Kind::P1 => P1_NODES.iter().map(|&x| map(x)).collect(),
            Kind::P2Straight => P2_NODES.iter().map(|&x| map(x)).collect(),
            Kind::P2Curved => {
                let (a, b) = (rng.uniform(-0.25, 0.25), rng.uniform(-0.25, 0.25));
                let mut c: Vec<[f64; 3]> = P2_NODES
                    .iter()
                    .map(|&x| map([x[0] * (1.0 + a * x[0]), x[1] * (1.0 + b * x[1]), x[2]]))
                    .collect();
                for node in c.iter_mut().skip(4) {
                    for v in node.iter_mut() {
                        *v += 0.05 * len * rng.uniform(-1.0, 1.0);
                    }
                }
                assert!(is_curved(&c));
                c
            }
        }
    }

    fn steel() -> ElasticCoefficients {
        ElasticCoefficients::from_material(&Material::preset("steel").expect("steel preset"))
    }

    fn quad_form(a: &[f64], x: &[f64]) -> f64 {
        let n = x.len();
        (0..n)
            .map(|i| x[i] * (0..n).map(|j| a[i * n + j] * x[j]).sum::<f64>())
            .sum()
    }

    /// (φᵀKφ, φᵀρM₁φ) from the assembly kernel.
    fn energies_ref(em: &ElementMatrices, phi: &[f64], c: &ElasticCoefficients) -> ModeEnergy {
        ModeEnergy {
            stiffness: c.lambda * quad_form(&em.k_lambda, phi) + c.mu * quad_form(&em.k_mu, phi),
            mass: c.rho * quad_form(&em.mass, phi),
        }
    }

    fn random_phi(rng: &mut Rng, n: usize) -> Vec<f64> {
        (0..n).map(|_| rng.uniform(-1.0, 1.0)).collect()
    }

    /// An eigenvalue at which both parts of s_e are of similar size.
    fn eigenvalue_for(e: &ModeEnergy) -> f64 {
        0.6 * e.stiffness / e.mass
    }

    fn norm(g: &[[f64; 3]]) -> f64 {
        g.iter().flatten().map(|v| v * v).sum::<f64>().sqrt()
    }

    fn size(coords: &[[f64; 3]]) -> f64 {
        let mut h: f64 = 0.0;
        for i in 0..4 {
            for j in 0..i {
                let d: f64 = (0..3).map(|k| (coords[i][k] - coords[j][k]).powi(2)).sum();
                h = h.max(d.sqrt());
            }
        }
        h
    }

    /// (kernel pair, element kind) combinations: the default assembly
    /// kernels plus forced-curved and explicit-rule kernels.
    fn cases() -> Vec<(&'static str, SensitivityKernel, ElementKernel, Kind)> {
        vec![
            (
                "P1",
                SensitivityKernel::new(4, false),
                ElementKernel::new(4, false),
                Kind::P1,
            ),
            (
                "P2 straight",
                SensitivityKernel::new(10, false),
                ElementKernel::new(10, false),
                Kind::P2Straight,
            ),
            (
                "P2 curved",
                SensitivityKernel::new(10, false),
                ElementKernel::new(10, false),
                Kind::P2Curved,
            ),
            (
                "P2 straight, forced curved rule",
                SensitivityKernel::new(10, true),
                ElementKernel::new(10, true),
                Kind::P2Straight,
            ),
            (
                "P2 curved, degree-6 rule",
                SensitivityKernel::with_rule(10, &tet_rule(6)).unwrap(),
                ElementKernel::with_rule(10, &tet_rule(6)).unwrap(),
                Kind::P2Curved,
            ),
            (
                "P1, degree-3 rule",
                SensitivityKernel::with_rule(4, &tet_rule(3)).unwrap(),
                ElementKernel::with_rule(4, &tet_rule(3)).unwrap(),
                Kind::P1,
            ),
        ]
    }

    #[test]
    fn energies_match_element_matrices() {
        let mut rng = Rng(11);
        let c = steel();
        for (name, sk, ek, kind) in cases() {
            for _ in 0..5 {
                let x = element(&mut rng, kind, 1e-2);
                let phi = random_phi(&mut rng, 3 * x.len());
                let want = energies_ref(&ek.matrices(&x).unwrap(), &phi, &c);
                let mut g = vec![[0.0; 3]; x.len()];
                let got = sk.gradient_into(&x, &phi, 1.0, c, &mut g).unwrap();
                for (a, b, what) in [
                    (got.stiffness, want.stiffness, "stiffness"),
                    (got.mass, want.mass, "mass"),
                ] {
                    assert!(
                        (a - b).abs() <= 1e-12 * b.abs(),
                        "{name} {what}: {a} vs {b}"
                    );
                }
            }
        }
    }

    /// Central differences of s_e (evaluated with the assembly kernel's
    /// matrices) over every coordinate. Step h = 1e-6 × (longest corner edge):
    /// truncation O(h²) ~ 1e-12 relative, rounding ~ ε/1e-6 ~ 1e-10 relative,
    /// so agreement is required to 1e-6 × ‖g‖ (observed ~1e-9).
    #[test]
    fn gradient_matches_central_differences() {
        let mut rng = Rng(7);
        let c = steel();
        let mut worst: f64 = 0.0;
        for (name, sk, ek, kind) in cases() {
            for &len in &[1.0, 1e-3] {
                let x = element(&mut rng, kind, len);
                let n = x.len();
                let m = 3;
                let phi: Vec<f64> = random_phi(&mut rng, 3 * n * m);
                let em = ek.matrices(&x).unwrap();
                let eig: Vec<f64> = (0..m)
                    .map(|k| {
                        eigenvalue_for(&energies_ref(&em, &phi[3 * n * k..3 * n * (k + 1)], &c))
                    })
                    .collect();
                let mut g = vec![[0.0; 3]; n * m];
                sk.gradients_into(&x, &phi, &eig, c, &mut g, None).unwrap();
                let h = 1e-6 * size(&x);
                for k in 0..m {
                    let pk = &phi[3 * n * k..3 * n * (k + 1)];
                    let gk = &g[n * k..n * (k + 1)];
                    let gn = norm(gk);
                    let s = |y: &[[f64; 3]]| {
                        energies_ref(&ek.matrices(y).unwrap(), pk, &c).value(eig[k])
                    };
                    for a in 0..n {
                        for d in 0..3 {
                            let mut xp = x.clone();
                            let mut xm = x.clone();
                            xp[a][d] += h;
                            xm[a][d] -= h;
                            let fd = (s(&xp) - s(&xm)) / (2.0 * h);
                            let err = (fd - gk[a][d]).abs() / gn;
                            worst = worst.max(err);
                            assert!(
                                err <= 1e-6,
                                "{name} (len {len}) mode {k} node {a} dir {d}: fd {fd} vs {} (rel {err:.2e})",
                                gk[a][d]
                            );
                        }
                    }
                }
            }
        }
        println!("worst FD mismatch relative to ‖g‖: {worst:.2e}");
    }

    #[test]
    fn batched_equals_single_bitwise() {
        let mut rng = Rng(3);
        let c = steel();
        for (_, sk, _, kind) in cases() {
            let x = element(&mut rng, kind, 0.01);
            let n = x.len();
            let m = 7;
            let phi = random_phi(&mut rng, 3 * n * m);
            let eig: Vec<f64> = (0..m).map(|_| rng.uniform(0.0, 1e9)).collect();
            let mut g = vec![[0.0; 3]; n * m];
            let mut e = vec![ModeEnergy::default(); m];
            sk.gradients_into(&x, &phi, &eig, c, &mut g, Some(&mut e))
                .unwrap();
            for k in 0..m {
                let mut g1 = vec![[1.0; 3]; n];
                let e1 = sk
                    .gradient_into(&x, &phi[3 * n * k..3 * n * (k + 1)], eig[k], c, &mut g1)
                    .unwrap();
                assert_eq!(e1, e[k]);
                assert_eq!(g1[..], g[n * k..n * (k + 1)]);
            }
        }
    }

    /// Σ_a g_a = 0 (translation) and Σ_a (x_a × g_a + u_a × r_a) = 0 with
    /// r = 2 (K − λM) φ_e (rotation of element and mode together).
    #[test]
    fn translation_and_rotation_identities() {
        let mut rng = Rng(5);
        let c = steel();
        for (name, sk, ek, kind) in cases() {
            for _ in 0..3 {
                let x = element(&mut rng, kind, 0.02);
                let n = x.len();
                let phi = random_phi(&mut rng, 3 * n);
                let em = ek.matrices(&x).unwrap();
                let eig = eigenvalue_for(&energies_ref(&em, &phi, &c));
                let mut g = vec![[0.0; 3]; n];
                sk.gradient_into(&x, &phi, eig, c, &mut g).unwrap();
                let scale_t: f64 = g
                    .iter()
                    .map(|v| v.iter().map(|a| a.abs()).sum::<f64>())
                    .sum();
                for d in 0..3 {
                    let s: f64 = g.iter().map(|v| v[d]).sum();
                    assert!(s.abs() <= 1e-12 * scale_t, "{name}: Σ g[{d}] = {s:e}");
                }
                // r = 2 (λ_L K_λ + μ K_μ − λ ρ M₁) φ
                let nd = 3 * n;
                let r: Vec<f64> = (0..nd)
                    .map(|i| {
                        2.0 * (0..nd)
                            .map(|j| {
                                (c.lambda * em.k_lambda[i * nd + j] + c.mu * em.k_mu[i * nd + j]
                                    - eig * c.rho * em.mass[i * nd + j])
                                    * phi[j]
                            })
                            .sum::<f64>()
                    })
                    .collect();
                let cross = |p: [f64; 3], q: [f64; 3]| {
                    [
                        p[1] * q[2] - p[2] * q[1],
                        p[2] * q[0] - p[0] * q[2],
                        p[0] * q[1] - p[1] * q[0],
                    ]
                };
                let mut tot = [0.0; 3];
                let mut scale_r = 0.0;
                let mut only_x = [0.0; 3];
                for a in 0..n {
                    let u = [phi[3 * a], phi[3 * a + 1], phi[3 * a + 2]];
                    let ra = [r[3 * a], r[3 * a + 1], r[3 * a + 2]];
                    let (c1, c2) = (cross(x[a], g[a]), cross(u, ra));
                    for d in 0..3 {
                        tot[d] += c1[d] + c2[d];
                        only_x[d] += c1[d];
                        scale_r += c1[d].abs() + c2[d].abs();
                    }
                }
                for d in 0..3 {
                    assert!(
                        tot[d].abs() <= 1e-11 * scale_r,
                        "{name}: rotation residual {tot:?}"
                    );
                }
                // The φ-rotation term matters: Σ x × g alone is not zero.
                assert!(only_x.iter().map(|v| v.abs()).sum::<f64>() > 1e-6 * scale_r);
            }
        }
    }

    /// s_e(t·x) = t·φᵀKφ − t³·λφᵀMφ, so Σ_a x_a·g_a = φᵀKφ − 3λ φᵀMφ (Euler).
    #[test]
    fn euler_scaling_identity() {
        let mut rng = Rng(9);
        let c = steel();
        for (name, sk, ek, kind) in cases() {
            for _ in 0..3 {
                let x = element(&mut rng, kind, 0.05);
                let n = x.len();
                let phi = random_phi(&mut rng, 3 * n);
                let e = energies_ref(&ek.matrices(&x).unwrap(), &phi, &c);
                let eig = eigenvalue_for(&e);
                // The homogeneity degrees themselves (assembly kernel, t = 1.7).
                let t = 1.7;
                let xs: Vec<[f64; 3]> = x.iter().map(|p| p.map(|v| t * v)).collect();
                let es = energies_ref(&ek.matrices(&xs).unwrap(), &phi, &c);
                assert!((es.stiffness - t * e.stiffness).abs() <= 1e-12 * es.stiffness);
                assert!((es.mass - t.powi(3) * e.mass).abs() <= 1e-12 * es.mass);

                let mut g = vec![[0.0; 3]; n];
                sk.gradient_into(&x, &phi, eig, c, &mut g).unwrap();
                let lhs: f64 = x
                    .iter()
                    .zip(&g)
                    .map(|(p, q)| p[0] * q[0] + p[1] * q[1] + p[2] * q[2])
                    .sum();
                let rhs = e.stiffness - 3.0 * eig * e.mass;
                let scale = e.stiffness + 3.0 * eig * e.mass;
                assert!(
                    (lhs - rhs).abs() <= 1e-10 * scale,
                    "{name}: Σ x·g = {lhs:e}, expected {rhs:e}"
                );
            }
        }
    }

    /// Straight P2: moving a mid-edge node (which curves the element) has a
    /// non-zero first-order effect, and keeping mid-nodes at midpoints reduces
    /// the gradient to that of the corner-only (P1-geometry) element.
    #[test]
    fn straight_p2_mid_nodes_and_chain_rule() {
        let mut rng = Rng(13);
        let c = steel();
        let sk = SensitivityKernel::new(10, false);
        let x = element(&mut rng, Kind::P2Straight, 0.01);
        let phi = random_phi(&mut rng, 30);
        let mut g = vec![[0.0; 3]; 10];
        sk.gradient_into(&x, &phi, 1e7, c, &mut g).unwrap();
        assert!(norm(&g[4..]) > 1e-3 * norm(&g));
        // Total derivative for midpoint-following mid-nodes vs FD of the
        // straight element moved corner by corner (mid-nodes recomputed).
        let ek = ElementKernel::new(10, false);
        let s = |y: &[[f64; 3]]| energies_ref(&ek.matrices(y).unwrap(), &phi, &c).value(1e7);
        let h = 1e-6 * size(&x);
        let mut total = [[0.0; 3]; 4];
        for (e, &(i, j)) in P2_EDGES.iter().enumerate() {
            for d in 0..3 {
                total[i][d] += 0.5 * g[4 + e][d];
                total[j][d] += 0.5 * g[4 + e][d];
            }
        }
        for a in 0..4 {
            for d in 0..3 {
                total[a][d] += g[a][d];
                let moved = |dx: f64| {
                    let mut y = x.clone();
                    y[a][d] += dx;
                    for (e, &(i, j)) in P2_EDGES.iter().enumerate() {
                        y[4 + e] = [0, 1, 2].map(|k| 0.5 * (y[i][k] + y[j][k]));
                    }
                    y
                };
                let fd = (s(&moved(h)) - s(&moved(-h))) / (2.0 * h);
                assert!(
                    (fd - total[a][d]).abs() <= 1e-6 * norm(&g),
                    "{fd} vs {}",
                    total[a][d]
                );
            }
        }
    }

    #[test]
    fn errors() {
        let c = steel();
        let sk = SensitivityKernel::new(10, false);
        let mut g = vec![[0.0; 3]; 10];
        let phi = vec![0.0; 30];
        // Inverted (mirror corners 1 and 2).
        let mut x = P2_NODES.to_vec();
        x.swap(1, 2);
        x.swap(4, 6);
        x.swap(9, 8);
        assert!(matches!(
            sk.gradient_into(&x, &phi, 0.0, c, &mut g),
            Err(ElementError::NonPositiveJacobian { .. })
        ));
        assert!(matches!(
            sk.gradient_into(&P1_NODES, &phi[..12], 0.0, c, &mut g[..4]),
            Err(ElementError::BadNodeCount(4))
        ));
        assert!(SensitivityKernel::try_new(6, false).is_err());
    }

    #[test]
    #[should_panic(expected = "phi_e")]
    fn wrong_phi_length_panics() {
        let mut g = vec![[0.0; 3]; 10];
        let _ = SensitivityKernel::new(10, false).gradient_into(
            &P2_NODES,
            &[0.0; 29],
            0.0,
            steel(),
            &mut g,
        );
    }

    /// Timing; `cargo test --release --lib -- --ignored --nocapture bench_sensitivity`.
    #[test]
    #[ignore]
    fn bench_sensitivity() {
        use std::hint::black_box;
        use std::time::Instant;
        let mut rng = Rng(1);
        let c = steel();
        let time = |iters: usize, f: &mut dyn FnMut()| {
            for _ in 0..iters / 100 + 1 {
                f();
            }
            let t0 = Instant::now();
            for _ in 0..iters {
                f();
            }
            t0.elapsed().as_secs_f64() / iters as f64
        };
        for (name, kind, iters) in [
            ("P1", Kind::P1, 400_000),
            ("P2 straight", Kind::P2Straight, 100_000),
            ("P2 curved (125 pts)", Kind::P2Curved, 10_000),
        ] {
            let x = element(&mut rng, kind, 0.01);
            let n = x.len();
            let ek = ElementKernel::new(n, false);
            let sk = SensitivityKernel::new(n, false);
            let mut em = ElementMatrices::zeros(n);
            let t_mat = time(iters, &mut || {
                ek.matrices_into(black_box(&x), &mut em).unwrap();
                black_box(&em);
            });
            let phi = random_phi(&mut rng, 3 * n * 50);
            let eig: Vec<f64> = (0..50).map(|_| rng.uniform(1e6, 1e9)).collect();
            let mut g = vec![[0.0; 3]; n * 50];
            let t1 = time(iters, &mut || {
                sk.gradient_into(black_box(&x), &phi[..3 * n], eig[0], c, &mut g[..n])
                    .unwrap();
                black_box(&g);
            });
            let t50 = time(iters / 20, &mut || {
                sk.gradients_into(black_box(&x), &phi, &eig, c, &mut g, None)
                    .unwrap();
                black_box(&g);
            });
            println!(
                "{name}: matrices_into {:.3} µs; gradient 1 mode {:.3} µs ({:.2}×); 50 modes {:.2} µs ({:.1}×, {:.3} µs/mode)",
                t_mat * 1e6,
                t1 * 1e6,
                t1 / t_mat,
                t50 * 1e6,
                t50 / t_mat,
                t50 * 1e6 / 50.0
            );
        }
    }
}
