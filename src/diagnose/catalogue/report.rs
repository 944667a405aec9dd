//! The report of [`super::diagnose`] (serde; parent module docs, "Report").

use serde::{Deserialize, Serialize};

use super::{Quantity, Role};

/// A fitted parameter with its standard deviation (from the inverse of JᵀJ of the
/// standardised residuals).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FittedParam {
    pub name: String,
    pub unit: String,
    pub value: f64,
    /// None when the data do not determine it.
    pub sigma: Option<f64>,
}

impl FittedParam {
    pub fn new(
        name: impl Into<String>,
        unit: impl Into<String>,
        value: f64,
        sigma: f64,
    ) -> FittedParam {
        FittedParam {
            name: name.into(),
            unit: unit.into(),
            value,
            sigma: sigma.is_finite().then_some(sigma),
        }
    }
}

/// Model-error floors τ (standard deviations, in the units of each quantity).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Floors {
    pub ln_frequency: f64,
    pub ln_decay: f64,
    /// Per mode and channel: the mix between microphones.
    pub ln_amplitude: f64,
    /// Per mode, common to its channels: the mode's level.
    pub ln_amplitude_level: f64,
    pub glide: f64,
    /// Of a split pair's ln d_u − ln d_l, on top of the fixed
    /// [`super::model::DECAY_SPLIT_MODEL_FLOOR`] (absent from reports written before it).
    #[serde(default)]
    pub decay_split: f64,
}

/// One fitted model: parameters, floors, likelihood and criterion.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelSummary {
    /// "effect (variant)" for every term on top of the baseline.
    pub effects: Vec<String>,
    pub params: Vec<FittedParam>,
    pub floors: Floors,
    pub minus_two_log_likelihood: f64,
    pub n_observations: usize,
    /// Free parameters plus one per profiled floor.
    pub n_parameters: usize,
    pub bic: f64,
    /// Held-out error (RMS standardised residual) with the baseline's floors as the yardstick.
    pub held_out_error: Option<f64>,
}

/// An observed ↔ simulated match.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MatchedPair {
    pub observed: usize,
    pub simulated: Vec<usize>,
    pub role: Role,
    pub cluster: usize,
    /// Observed undamped frequency, Hz.
    pub observed_hz: f64,
    /// Simulated frequency times the matching scale, Hz.
    pub simulated_hz: f64,
}

/// A recorded pole that belongs to a matched partial (matching step 5).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExtraPole {
    pub observed: usize,
    pub observed_hz: f64,
    /// The matched recorded mode it sits beside, and its frequency.
    pub beside: usize,
    pub beside_hz: f64,
    pub cluster: usize,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MatchingReport {
    /// Global frequency scale s of the matching (the baseline refits it).
    pub scale: f64,
    pub pairs: Vec<MatchedPair>,
    pub unmatched_observed: Vec<usize>,
    pub unmatched_simulated: Vec<usize>,
    /// Extra poles of matched partials (matching step 5): recorded modes within the largest
    /// pair split of a matched mode of the same simulated cluster, which carry no rows.
    #[serde(default)]
    pub extra_poles: Vec<ExtraPole>,
    /// Held-out modes matched (with the fit's scale), and those left over.
    pub held_out_matched: Option<usize>,
    pub held_out_unmatched: Option<Vec<usize>>,
    /// The modes whose decay and level rows were set aside as the room's (parent docs, "A room
    /// holds up the fast modes"); None without an established room.
    #[serde(default)]
    pub room_held: Option<RoomHeld>,
}

/// Matched modes that decay at least as fast as an established room: their poles are the
/// room's tail as much as theirs, so only their frequencies count.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RoomHeld {
    /// The slowest amplitude decay rate the room's fit allows, ln(10³)/(T60 + 2σ_T60), 1/s:
    /// modes at least this fast are held.
    pub room_decay_rate: f64,
    /// Observed frequencies of the fit table's modes set aside, Hz.
    pub frequencies_hz: Vec<f64>,
    /// How many of the held-out table's modes were set aside.
    pub held_out_modes: usize,
}

/// An effect the selection accepted.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AcceptedEffect {
    pub name: String,
    pub signature: String,
    pub variant: String,
    /// What the detector saw.
    pub detector: String,
    /// Greedy step at which it entered (0 = first).
    pub step: usize,
    pub n_params: usize,
    /// Improvement of the criterion when it entered (−2 ln L gain minus n_params · ln n).
    pub delta_bic: f64,
    pub held_out_before: Option<f64>,
    pub held_out_after: Option<f64>,
    /// Held-out Σz² before minus after: the held-out likelihood gain × 2 (parent docs,
    /// "Selection"; must exceed `min_held_out_gain`).
    #[serde(default)]
    pub held_out_gain: Option<f64>,
    /// Its parameters in the final model (all accepted effects fitted together).
    pub params: Vec<FittedParam>,
}

/// Why a candidate was not accepted.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Rejection {
    /// The data cannot carry the effect (too few modes, channels, no envelopes, …).
    NotEnoughData,
    /// The detector's screen saw nothing worth a fit.
    DetectorFoundNothing,
    /// The fit did not beat the criterion's threshold.
    DeltaBicTooSmall,
    /// ΔBIC passed but the held-out error did not fall by the minimum gain (or its RMS rose).
    HeldOutDidNotImprove,
    /// ΔBIC passed but the held-out data cannot test the effect (it changes nothing there).
    HeldOutCannotTest,
    /// ΔBIC passed but there is no held-out data and settings require it.
    NoHeldOutData,
    /// The fit gave a non-finite likelihood.
    FitFailed,
    /// The fit improves the likelihood, but the fitted effect lacks a property its physics
    /// requires (e.g. a "reverberant" excess confined to a single band); the detail says which.
    SignatureMissing,
    /// Accepted at its greedy step, but once the effects accepted after it were in the model
    /// it no longer paid its way (its last-in ΔBIC or held-out gain failed the rule): the
    /// others explain what it had explained (parent docs, "Selection").
    RedundantGivenOthers,
    /// Acceptable, but it reads the same rows as another acceptable effect of the same round
    /// and did not beat that one's ΔBIC by the threshold (parent docs, "Selection").
    NotBetterThanRival,
}

impl Rejection {
    /// The reason in words, for people (the JSON keeps the snake_case name).
    pub fn describe(self) -> &'static str {
        match self {
            Rejection::NotEnoughData => "not enough data to test it",
            Rejection::DetectorFoundNothing => "its detector found nothing",
            Rejection::DeltaBicTooSmall => "ΔBIC below the threshold",
            // Also when the RMS fell a little (seed 41 case 007: 1.384 → 1.358, Σz² gain 1.9):
            // "did not fall" alone was untrue there.
            Rejection::HeldOutDidNotImprove => {
                "the held-out error did not fall by the minimum gain"
            }
            Rejection::HeldOutCannotTest => "the held-out data cannot test it",
            Rejection::NoHeldOutData => "no held-out data",
            Rejection::FitFailed => "the fit failed",
            Rejection::SignatureMissing => "its physical signature is missing",
            Rejection::RedundantGivenOthers => "redundant once the later effects were in the model",
            Rejection::NotBetterThanRival => {
                "another effect reads the same rows about as well, and it did not beat that one by the threshold"
            }
        }
    }
}

impl std::fmt::Display for Rejection {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.describe())
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RejectedEffect {
    pub name: String,
    pub signature: String,
    pub reason: Rejection,
    pub detail: String,
    /// Detector statistic (its meaning is in `detail`).
    pub statistic: Option<f64>,
    pub variant: Option<String>,
    pub n_params: Option<usize>,
    pub delta_bic: Option<f64>,
    pub held_out_before: Option<f64>,
    pub held_out_after: Option<f64>,
    #[serde(default)]
    pub held_out_gain: Option<f64>,
}

impl RejectedEffect {
    /// An effect these data could not test at all ([`Rejection::NotEnoughData`]), with why.
    pub fn not_enough_data(name: &str, signature: &str, detail: String) -> RejectedEffect {
        RejectedEffect {
            name: name.into(),
            signature: signature.into(),
            reason: Rejection::NotEnoughData,
            detail,
            statistic: None,
            variant: None,
            n_params: None,
            delta_bic: None,
            held_out_before: None,
            held_out_after: None,
            held_out_gain: None,
        }
    }
}

impl CatalogueReport {
    /// The effects the recordings given could not test (too few microphones, modes or
    /// envelopes for the effect, or a held-out set it changes nothing in), with why: a
    /// verdict of "not found" on these would claim more than the data holds.
    pub fn untested(&self) -> Vec<&RejectedEffect> {
        self.rejected
            .iter()
            .filter(|r| {
                matches!(
                    r.reason,
                    Rejection::NotEnoughData
                        | Rejection::HeldOutCannotTest
                        | Rejection::NoHeldOutData
                )
            })
            .collect()
    }
}

/// A residual nothing in the final model explains.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct UnexplainedMode {
    /// Index into the fit's observed modes.
    pub observed: usize,
    pub frequency_hz: f64,
    pub quantity: Option<Quantity>,
    pub channel: Option<usize>,
    /// Standardised residual with the floor re-profiled without this mode.
    pub z: Option<f64>,
    pub reason: String,
}

/// Standardised residuals of one mode.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ZScores {
    pub ln_frequency: f64,
    pub ln_decay: Option<f64>,
    pub ln_amplitude: Vec<Option<f64>>,
    pub glide: Option<f64>,
}

/// Per matched mode: z-scores under the baseline and under the final model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModeResidualRow {
    pub observed: usize,
    pub frequency_hz: f64,
    pub simulated: Vec<usize>,
    pub role: Role,
    pub before: ZScores,
    pub after: ZScores,
    /// What the baseline and the final model predict for this mode.
    pub predicted_before: PredictedMode,
    pub predicted_after: PredictedMode,
}

/// A model's prediction of one matched mode, in the observation's units.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PredictedMode {
    /// Undamped frequency f₀, Hz.
    pub frequency_hz: f64,
    /// Decay rate d, 1/s.
    pub decay_rate: f64,
    /// Amplitude per fit channel (0 where the model predicts none), units of the recording.
    pub amplitudes: Vec<f64>,
}

/// Noise floor per band: the pre-roll estimate and the floor fitted to the residual
/// envelopes (with the reverberant excess removed when that effect was accepted).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NoiseFloorReport {
    pub band_edges_hz: Vec<f64>,
    pub pre_roll: Vec<f64>,
    pub fitted: Vec<f64>,
    /// 10 log10(fitted / pre-roll) per band; well above 0 dB is stationary residual energy
    /// (hum, a missed partial) rather than noise.
    pub excess_db: Vec<f64>,
}

impl NoiseFloorReport {
    pub fn new(band_edges_hz: Vec<f64>, pre_roll: Vec<f64>, fitted: Vec<f64>) -> NoiseFloorReport {
        let excess_db = fitted
            .iter()
            .zip(&pre_roll)
            .map(|(f, p)| 10.0 * (f / p).log10())
            .collect();
        NoiseFloorReport {
            band_edges_hz,
            pre_roll,
            fitted,
            excess_db,
        }
    }
}

/// Everything [`super::diagnose`] found.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CatalogueReport {
    pub delta_bic_threshold: f64,
    pub matching: MatchingReport,
    pub baseline: ModelSummary,
    pub final_model: ModelSummary,
    pub accepted: Vec<AcceptedEffect>,
    pub rejected: Vec<RejectedEffect>,
    pub unexplained: Vec<UnexplainedMode>,
    pub residuals: Vec<ModeResidualRow>,
    pub noise: Option<NoiseFloorReport>,
}
