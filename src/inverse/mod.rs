//! Inverse problems: recover damping, material, shape and strike from recordings by analysis
//! by synthesis, with the exact gradients of the forward chain.
//!
//! | module       | what it does |
//! |--------------|--------------|
//! | [`damping`]  | stage 1 of the material fit: many free modes + filtered noise fitted to a recording, real modes → damping curve d(f) and Rayleigh α, β |
//! | [`optim`]    | Adam with bounds, the optimiser the fits share |
//! | [`material`] | stage 2 of the material fit: E and ν by the hybrid transport→spectral schedule |
//! | [`loaded_match`] | the line-spectrum match with a candidate added mass: E, ν, the mass and its site together (Ritz in the unloaded modes) |
//! | [`impact`]   | where the object was struck: mode amplitudes with known poles, forward amplitudes per surface vertex, likelihood map over the surface, strength, top candidates, geodesics and symmetry orbits |
//! | [`geometry`] | geometry from a coarse voxel constraint: voxelisation, MLP pre-fit, refinement by eigenvalues |
//! | [`shape`]    | shape from sound: the thickness and morph fits on the forward chain of [`crate::shape`] (scan, safeguarded Gauss–Newton per grid level, extrapolation in the grid spacing) |

pub mod damping;
pub mod geometry;
pub mod impact;
pub mod loaded_match;
pub mod material;
pub mod optim;
pub mod shape;
