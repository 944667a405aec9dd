//! Step 5's acoustic transfer: each mode's sound to the microphones, by a multipole fit of
//! its surface motion ([`crate::audio::radiation`]), or |T| = 1 with `transfer = "none"`.

use super::{Job, TransferChoice};
use crate::audio::radiation::{fit_multipoles, MultipoleSettings, SurfaceQuadrature};
use crate::mesh::TetMesh;
use crate::workflow::Progress;
use rustfft::num_complex::Complex64;
use std::time::Instant;

/// The transfer of every mode to every microphone, `[mode][microphone]`, or none (|T| = 1).
pub enum TransferValues {
    None,
    Complex(Vec<Vec<Complex64>>),
}

/// The acoustic transfer of every mode to every microphone (module docs of [`super`], step 5).
pub fn transfers(
    job: &Job,
    mesh: &TetMesh,
    eigenvalues: &[f64],
    shapes: &[Vec<f64>],
    n_mics: usize,
    progress: &Progress,
) -> Result<(TransferValues, String), String> {
    if job.transfer == TransferChoice::None {
        return Ok((
            TransferValues::None,
            "none: |T| = 1, signal taken as surface acceleration".into(),
        ));
    }
    let t = Instant::now();
    let quadrature = SurfaceQuadrature::new(mesh).map_err(|e| format!("radiation: {e}"))?;
    let mut out = Vec::with_capacity(shapes.len());
    let mut worst_residual = 0.0f64;
    for (shape, &lambda) in shapes.iter().zip(eigenvalues) {
        let un = quadrature
            .normal_displacement(shape)
            .map_err(|e| format!("radiation: {e}"))?;
        let fit = fit_multipoles(
            quadrature.samples(),
            &un,
            lambda.sqrt(),
            &MultipoleSettings::default(),
        )
        .map_err(|e| format!("radiation: {e}"))?;
        worst_residual = worst_residual.max(fit.residual);
        let row = match &job.microphones {
            Some(mics) => {
                let nearest = mics
                    .iter()
                    .map(|x| {
                        (0..3)
                            .map(|d| (x[d] - fit.centre[d]).powi(2))
                            .sum::<f64>()
                            .sqrt()
                    })
                    .fold(f64::INFINITY, f64::min);
                if nearest <= fit.source_radius {
                    return Err(format!("a microphone {nearest:.3} m from the radiation fit's centre lies inside its source sphere ({:.3} m); the transfer there is not defined", fit.source_radius));
                }
                fit.transfer(mics).map_err(|e| e.to_string())?
            }
            None => fit
                .transfer_unknown_positions(
                    n_mics,
                    job.assumed_distance_m.max(1.01 * fit.source_radius),
                )
                .map_err(|e| e.to_string())?,
        };
        out.push(row);
    }
    let note = match &job.microphones {
        Some(_) => format!("multipole transfer to the given microphone positions (largest boundary residual ε = {worst_residual:.2})"),
        None => format!("microphone positions unknown: direction-averaged multipole transfer at {} m (largest boundary residual ε = {worst_residual:.2}); right on average over directions, not for any one microphone", job.assumed_distance_m),
    };
    progress.say(format!(
        "acoustic transfer of {} modes in {:.1} s: {note}",
        shapes.len(),
        t.elapsed().as_secs_f64()
    ));
    Ok((TransferValues::Complex(out), note))
}
