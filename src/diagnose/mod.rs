//! Diagnosis of model mismatch between a simulation and a recording of the same strike.
//!
//! The first question is what the recording really contains, with error bars, before anything
//! is compared with a model: [`crate::analysis::extract`] measures every mode of a
//! multi-microphone recording (frequency, decay rate, and per microphone amplitude and phase),
//! each with its standard deviation; this module compares those modes with the simulation.
//!
//! | module      | what it does |
//! |-------------|--------------|
//! | [`catalogue`] | the candidate effects (signature, detector, compact model, fit), the baseline fit with profiled model-error floors, greedy selection by ΔBIC with a held-out check, the report |
//! | [`evidence`] | from a recording and a solved model to the catalogue's evidence: observed modes with early/late frequencies, residual envelopes per band against the pre-roll floor, simulated-mode features (drive, support and mass-region weights with degenerate clusters turned to the region's principal directions, symmetry clusters by axial profile), the object map of where low-frequency residuals point |
//! | `inject`    | (tests and the non-default feature `bench-generators` only) the blind benchmark's generator: concealed effects injected with more faithful models than the detectors use (Zener damping, sector perturbation, support springs and dashpots, Hertz pulse, room response, multipole radiation, added mass, amplitude-dependent glide), sealed labels and the detection scorer |

pub mod catalogue;
pub mod evidence;
#[cfg(any(test, feature = "bench-generators"))]
pub mod inject;
