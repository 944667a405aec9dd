//! The transfer of every mode of a solve to a set of microphones, the loop the jobs share: each
//! mode's normal surface displacement φ·n at the quadrature points, a multipole fit at its
//! angular frequency ω = √λ (parent module docs), and the fit evaluated at the microphones, or
//! its direction average at an assumed distance when their positions are unknown.
//!
//! A microphone inside the source sphere of a fit (the sphere around the expansion centre that
//! holds the surface) is refused: the series diverges there.

use super::{fit_multipoles, MultipoleSettings, RadiationError, SurfaceQuadrature};
use crate::mesh::TetMesh;
use crate::numerics::{norm, sub};
use rustfft::num_complex::Complex64;

/// Where the sound is wanted.
#[derive(Clone, Copy, Debug)]
pub enum Listeners<'a> {
    /// Microphone positions [m].
    At(&'a [[f64; 3]]),
    /// `count` microphones at unknown places, all taken at `distance_m` from the centre (raised
    /// to just outside the source sphere if it is inside).
    Unknown { count: usize, distance_m: f64 },
}

/// What [`mode_transfers`] returns.
#[derive(Clone, Debug)]
pub struct ModeTransfers {
    /// Pressure per unit modal amplitude, `[mode][microphone]`.
    pub values: Vec<Vec<Complex64>>,
    /// The largest relative boundary residual of the fits.
    pub worst_residual: f64,
}

/// The transfer of each mode (`eigenvalues` λ [1/s²], `shapes` node-major on `mesh`) to
/// `listeners`, with the default multipole settings.
pub fn mode_transfers(
    mesh: &TetMesh,
    eigenvalues: &[f64],
    shapes: &[Vec<f64>],
    listeners: Listeners,
) -> Result<ModeTransfers, RadiationError> {
    let quadrature = SurfaceQuadrature::new(mesh)?;
    let mut values = Vec::with_capacity(shapes.len());
    let mut worst_residual = 0.0f64;
    for (shape, &lambda) in shapes.iter().zip(eigenvalues) {
        let un = quadrature.normal_displacement(shape)?;
        let fit = fit_multipoles(
            quadrature.samples(),
            &un,
            lambda.sqrt(),
            &MultipoleSettings::default(),
        )?;
        worst_residual = worst_residual.max(fit.residual);
        let row = match listeners {
            Listeners::At(positions) => {
                let nearest = positions
                    .iter()
                    .map(|x| norm(sub(*x, fit.centre)))
                    .fold(f64::INFINITY, f64::min);
                if nearest <= fit.source_radius {
                    return Err(RadiationError::InsideSources {
                        distance_m: nearest,
                        source_radius_m: fit.source_radius,
                    });
                }
                fit.transfer(positions)?
            }
            Listeners::Unknown { count, distance_m } => {
                fit.transfer_unknown_positions(count, distance_m.max(1.01 * fit.source_radius))?
            }
        };
        values.push(row);
    }
    Ok(ModeTransfers {
        values,
        worst_residual,
    })
}
