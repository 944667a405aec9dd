//! Step 5's acoustic transfer: each mode's sound to the microphones, by a multipole fit of
//! its surface motion ([`crate::audio::radiation`]), or |T| = 1 with `transfer = "none"`.

use super::{Job, TransferChoice};
use crate::audio::radiation::{mode_transfers, Listeners, ModeTransfers};
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
    let listeners = match &job.microphones {
        Some(mics) => Listeners::At(mics),
        None => Listeners::Unknown {
            count: n_mics,
            distance_m: job.assumed_distance_m,
        },
    };
    let ModeTransfers {
        values: out,
        worst_residual,
    } = mode_transfers(mesh, eigenvalues, shapes, listeners)
        .map_err(|e| format!("radiation: {e}"))?;
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
