//! Finite-element stage: element matrices for linear elasticity on P1 (tet4)
//! and P2 (tet10) tetrahedra. Serial, pure functions; assembly and the
//! eigen-solve live elsewhere.
//!
//! # Weak form (SI units: m, Pa, kg/m³, s)
//!
//! For displacement u and test function v on the body Ω,
//!
//! * kinetic term: ρ ∫_Ω u·v dV            → mass matrix M = ρ M₁
//! * elastic term: ∫_Ω σ(u):ε(v) dV = λ ∫_Ω (∇·u)(∇·v) dV + 2μ ∫_Ω ε(u):ε(v) dV
//!   → stiffness K = λ K_λ + μ K_μ
//!
//! with ε(u) = ½(∇u + ∇uᵀ), σ = λ tr(ε) I + 2μ ε and the Lamé parameters
//! λ = Eν/((1+ν)(1−2ν)), μ = E/(2(1+ν)) in Pa. Free vibration gives the
//! generalized eigenproblem K φ = ω² M φ; eigenvalues ω² are in rad²/s²
//! (frequency f = ω / 2π Hz). A free body has six zero eigenvalues (rigid
//! translations and rotations), which every element matrix here reproduces.
//!
//! Keeping K_λ and K_μ separate (rather than K for one material) makes K
//! linear in (λ, μ): ∂K/∂E = (∂λ/∂E) K_λ + (∂μ/∂E) K_μ, and likewise for ν,
//! at no extra integration cost (sensitivities, material fits).
//!
//! # Elements and the isoparametric map
//!
//! Reference tetrahedron: corners (0,0,0), (1,0,0), (0,1,0), (0,0,1), volume 1/6.
//! Node order is Gmsh's: corners 0..3, then mid-edge nodes 4:(0,1) 5:(1,2)
//! 6:(0,2) 7:(0,3) 8:(2,3) 9:(1,3). Element dofs are interleaved,
//! dof = 3·local_node + component, and element matrices are dense row-major.
//!
//! Geometry is isoparametric: x(ξ) = Σ_a N_a(ξ) x_a with the element's own
//! shape functions, so a tet10 whose mid-edge nodes lie on a curved surface is
//! integrated as curved. Gradients are ∇N_a = J⁻ᵀ ∇_ξ N_a with J = ∂x/∂ξ and
//! dV = det J dξ; det J ≤ 0 at a quadrature point is an error (inverted element).
//!
//! # Quadrature and why
//!
//! * P1: J is constant, stiffness is constant, mass is degree 2 → exact.
//! * P2 with straight edges: J constant; the mass integrand N_a N_b is degree 4,
//!   the stiffness ∇N_a·∇N_b degree 2 → both exact (degree-4 rule for the
//!   general path; the fast path uses a precomputed reference mass and a
//!   4-point degree-2 rule for stiffness).
//! * P2 curved: det J is cubic, so mass × det J is degree 7; the stiffness
//!   integrand is rational (adj J appears squared over det J) and no rule is
//!   exact. Degree 8 (collapsed Gauss–Jacobi, exact to 9) integrates the mass
//!   exactly and the stiffness to well below discretisation error for
//!   reasonably shaped curved elements.
//!
//! All rules have positive weights and interior points (see [`quadrature`]).
//!
//! Use [`ElementKernel`] in assembly loops: it tabulates shape values and
//! gradients once per rule and writes into a reused [`ElementMatrices`].

pub mod element;
pub mod material;
pub mod quadrature;
pub mod sensitivity;
pub mod shape;

pub use element::{
    default_rule, element_matrices, element_volume, is_curved, ElementError, ElementKernel,
    ElementMatrices,
};
pub use material::{Material, MaterialError};
pub use quadrature::{tet_rule, QuadratureRule};
pub use sensitivity::{ElasticCoefficients, ModeEnergy, SensitivityKernel};
pub use shape::{p1_grad_ref, p1_shape, p2_grad_ref, p2_shape, P1_NODES, P2_EDGES, P2_NODES};
