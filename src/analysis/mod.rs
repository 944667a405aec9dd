//! Recording analysis: what a recording contains, before anything is compared with a model.
//!
//! | module        | what it does |
//! |---------------|--------------|
//! | [`recording`] | loading a multi-microphone recording: rate conversion, onset, trim, gain |
//! | [`onset`]     | the strike's onset sample in a recording |
//! | [`mode`]      | [`MeasuredMode`], the one type every stage returns a measured mode as |
//! | [`estimate`]  | high-resolution modal estimates (f, d, amplitudes) straight from a recording: sub-band ESPRIT, one operation per file |
//! | [`extract`]   | modal parameters with uncertainties: the estimates refined by variable-projection Levenberg–Marquardt, Gauss–Newton covariance; then the chirp-aware stage [`extract::glide`]: each mode or cluster of poles refitted as gliding modes f(t) = f₀(1 + g e^(−2dt)) on a band of DFT bins, kept where the BIC prefers them, g ± σ_g per mode |
//!
//! The damping fit ([`crate::inverse::damping`]), the impact localisation
//! ([`crate::inverse::impact`]) and the diagnosis ([`crate::diagnose`]) start from these
//! measurements.

pub mod estimate;
pub mod extract;
pub mod mode;
pub mod onset;
pub mod recording;

pub use extract::{extract_modes, BandFit, ExtractError, ExtractOptions, ModalExtraction};
pub use mode::{MeasuredMode, ModeSd, ModeVerdict, RefinedFrom, Refinement, Verdict};
