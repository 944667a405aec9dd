//! From a recording and a solved model to the catalogue's [`Evidence`]: the serial, pure parts
//! of the `diagnose` job ([`crate::cli`]'s `diagnose`).
//!
//! # Observed modes
//!
//! [`observed_modes`] turns an extraction ([`crate::analysis::extract`]) into
//! [`ObservedMode`]s: frequency f [Hz], decay rate d [1/s] and per-channel amplitude a_c, each with
//! its standard deviation, keeping the modes at or above `min_snr_db`. For the pitch-glide
//! signature the same channels are extracted again on an early and a late stretch of the span
//! (`early`, `late`); a mode takes the early (late) frequency of the early (late) mode that
//! is its *mutual* nearest neighbour in frequency within `glide_match` (relative; default 1 %).
//! A σ-based gate would reject exactly the glides it is meant to find (σ_f / f ~ 10⁻⁵, glides
//! 10⁻³), and mutual nearness keeps a close pair from swapping its halves.
//!
//! Only measurements enter: a mode whose σ_f (or, when it decays, σ_d) is not positive and
//! finite is left out, and a channel whose σ_a is not is taken as one that does not hold the
//! mode (a_c = 0, the catalogue's convention). The extraction reports an infinite σ where its
//! covariance says nothing (a band model near singular); the catalogue refuses such inputs, and
//! one such amplitude on a bar (generator 2's seed 223 case 002) aborted a whole diagnosis.
//!
//! When the extraction went through the chirp-aware stage ([`crate::analysis::extract::glide`]),
//! every mode that came out as one component carries its fitted relative glide at the onset,
//! g ± σ_g ([`ObservedMode::glide`]); the catalogue then uses that instead of early and late
//! frequencies (the CLI no longer extracts the two windows).
//!
//! # Residual envelopes
//!
//! [`residual_envelopes`]: r_c = s_c − Σ_k Im(a_kc e^(−d_k t) e^(i(2π f_k t + φ_kc))) (the
//! extraction's modes resynthesised per channel, [`crate::audio::synth`]), its Hann-windowed
//! STFT (frame N, hop H), and per band b and frame j the energy E_bj = Σ_c Σ_{k ∈ b} |R_c[j,k]|²
//! [signal units²]; only frames whose window lies inside the span count (t_j = j H / f_s ≥
//! N/2 f_s, no zero padding). The noise floor per band is the mean of the same energy over the
//! pre-roll's full frames (the recording before the strike).
//!
//! # Simulated modes
//!
//! [`simulated_modes`] gives each mode of the solve its features: the drive |φ_k(x_s)·n|
//! [kg^(−½)] at the strike, the support weight w_k = S_k / max_j S_j with S_k = Σ_{i ∈ support}
//! (φ_k(x_i)·n)² (the mode's squared motion at the support nodes along the support direction
//! n; mass-normalised, so relative to its modal mass of 1), the mass weight the same over a
//! candidate added-mass region with the whole motion |φ_k(x_i)|² (or 0: none), a
//! near-degenerate cluster id (neighbours within `cluster_rtol` in frequency, chained), and
//! optionally |acoustic transfer| per microphone.
//!
//! Why the support counts only the motion along n ([`Motion`]): a resting object is held by
//! the contact's normal force; a pad's or a table's resistance to sliding is a fraction of its
//! resistance to pressing (a rubber pad's shear modulus is a third of its Young's modulus, and
//! its shape makes it stiffer still in compression), while a lumped mass resists motion in
//! every direction alike. Counted in full, the two members of a tube's degenerate bending
//! pair (one moving the underside up and down, the other sideways) carry the same support
//! weight, so a support could not predict the split it makes.
//!
//! # Where on the object
//!
//! [`localise_frequency_residuals`]: for a candidate region at surface vertex v, a mass there
//! lowers ln f_k by ½ μ w_k(v) (w_k(v) = |φ_k(v)|² / max_j |φ_j(v)|²). The weighted regression
//! (with intercept: the global scale absorbs a uniform shift) of the standardised ln f
//! residuals z_k on −½ w_k(v) has slope μ̂(v) and z-score ζ(v) = μ̂ / σ(μ̂); the map of ζ over the
//! surface shows where the modes whose frequencies came out low move, and its maximum is the
//! candidate added-mass region. Because the region is *chosen* from the data, the catalogue
//! charges the point variant for it ([`super::catalogue::CatalogueSettings`]'s
//! `mass_region_search_params`).
//!
//! [`localise_decay_residuals`]: the same for a support. Where the object rests is a property
//! of the recording session, not of the mesh: a bowl stands on its foot ring, but a plate or
//! a tube lies on a strip, a pad or two points anywhere on its underside. A support at vertex
//! v adds Δd_k = γ w_k(v) to the decay rates, so the standardised ln d residuals are regressed
//! on +w_k(v) (γ̂(v) ≥ 0 for a passive support) over the candidate vertices a support can
//! touch (outward normal within 60° of the support direction); the charge is
//! `support_region_search_params`.

use crate::analysis::extract::ModalExtraction;
use crate::analysis::MeasuredMode;
use crate::audio::stft::StftPlan;
use crate::diagnose::catalogue::{
    weighted_regression, ObservedMode, ResidualEnvelopes, SimulatedMode,
};
use crate::numerics::nearest_sorted;

/// Everything that can be wrong with the input of this module.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum EvidenceError {
    #[error("{what}: {got} values, expected {expected}")]
    LengthMismatch {
        what: &'static str,
        got: usize,
        expected: usize,
    },
    #[error("{0}")]
    Invalid(String),
}

/// Settings of [`observed_modes`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ObservedOptions {
    /// Modes below this SNR (dB, the extraction's) are left out.
    pub min_snr_db: f64,
    /// Largest relative frequency difference of a mode and its early / late counterpart.
    pub glide_match: f64,
}

impl Default for ObservedOptions {
    fn default() -> Self {
        ObservedOptions {
            min_snr_db: 20.0,
            glide_match: 0.01,
        }
    }
}

/// For each of `from` (sorted), the index in `to` (sorted) of its mutual nearest neighbour within
/// `rtol` (relative), if any.
pub fn mutual_nearest(from: &[f64], to: &[f64], rtol: f64) -> Vec<Option<usize>> {
    from.iter()
        .map(|&x| {
            let j = nearest_sorted(to, x)?;
            let back = nearest_sorted(from, to[j])?;
            let close = (to[j] - x).abs() <= rtol * x.abs();
            (close && from[back] == x).then_some(j)
        })
        .collect()
}

/// The extraction's modes as catalogue observations (module docs). `early` / `late` are
/// extractions of the same channels on the first / second half of the span.
pub fn observed_modes(
    full: &ModalExtraction,
    early: Option<&ModalExtraction>,
    late: Option<&ModalExtraction>,
    options: &ObservedOptions,
) -> Vec<ObservedMode> {
    let kept: Vec<_> = full
        .modes
        .iter()
        .filter(|m| m.snr() >= options.min_snr_db && m.frequency_hz > 0.0 && measured(m))
        .collect();
    let freqs: Vec<f64> = kept.iter().map(|m| m.frequency_hz).collect();
    let half = |ex: Option<&ModalExtraction>| -> Vec<Option<(f64, f64)>> {
        match ex {
            None => vec![None; kept.len()],
            Some(ex) => {
                let other: Vec<_> = ex
                    .modes
                    .iter()
                    .filter(|m| m.snr() >= options.min_snr_db && m.frequency_hz > 0.0)
                    .collect();
                let of: Vec<f64> = other.iter().map(|m| m.frequency_hz).collect();
                mutual_nearest(&freqs, &of, options.glide_match)
                    .into_iter()
                    .map(|j| j.map(|j| (other[j].frequency_hz, other[j].sd().frequency_hz)))
                    .collect()
            }
        }
    };
    let (e, l) = (half(early), half(late));
    kept.iter()
        .enumerate()
        .map(|(i, m)| {
            // A channel without a measured amplitude is one without the mode.
            let (amplitudes, sigma_amplitudes) = m
                .amplitudes
                .iter()
                .zip(&m.sd().amplitudes)
                .map(|(&a, &s)| if positive(s) { (a, s) } else { (0.0, 0.0) })
                .unzip();
            ObservedMode {
                frequency_hz: m.frequency_hz,
                sigma_frequency_hz: m.sd().frequency_hz,
                decay_rate: m.decay_rate,
                sigma_decay_rate: m.sd().decay_rate,
                amplitudes,
                sigma_amplitudes,
                early_frequency_hz: e[i],
                late_frequency_hz: l[i],
                glide: m.glide.as_ref().map(|g| (g.glide, g.glide_sd)),
            }
        })
        .collect()
}

fn positive(x: f64) -> bool {
    x > 0.0 && x.is_finite()
}

/// Whether the extraction measured the mode's frequency (and its decay rate, when it decays):
/// module docs, "Observed modes".
fn measured(m: &MeasuredMode) -> bool {
    m.sd.as_ref().is_some_and(|sd| {
        positive(sd.frequency_hz) && (m.decay_rate <= 0.0 || positive(sd.decay_rate))
    })
}

/// Settings of [`residual_envelopes`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EnvelopeOptions {
    /// Band edges, Hz (increasing; bands above Nyquist are dropped).
    pub band_edges_hz: Vec<f64>,
    /// STFT frame and hop, samples.
    pub frame: usize,
    pub hop: usize,
}

impl Default for EnvelopeOptions {
    fn default() -> Self {
        EnvelopeOptions {
            band_edges_hz: vec![250.0, 500.0, 1000.0, 2000.0, 4000.0, 8000.0, 16000.0],
            frame: 1024,
            hop: 384,
        }
    }
}

/// Band energies of one set of channels: [band][frame] and the frame centres (samples), full
/// frames only.
fn band_energies(
    channels: &[Vec<f64>],
    plan: &StftPlan,
    bins: &[std::ops::Range<usize>],
    frame: usize,
) -> (Vec<Vec<f64>>, Vec<usize>) {
    let len = channels.first().map_or(0, Vec::len);
    let hop = plan.hop();
    // Frame t covers [tH − N/2, tH + N/2): full when tH ≥ N/2 and tH + N/2 ≤ len.
    let frames: Vec<usize> = (0..plan.n_frames(len))
        .filter(|&t| t * hop >= frame / 2 && t * hop + frame / 2 <= len)
        .collect();
    let mut energy = vec![vec![0.0; frames.len()]; bins.len()];
    for x in channels {
        let spec = plan.forward(x);
        for (j, &t) in frames.iter().enumerate() {
            let row = spec.frame(t);
            for (b, r) in bins.iter().enumerate() {
                energy[b][j] += row[r.clone()].iter().map(|v| v * v).sum::<f64>();
            }
        }
    }
    (energy, frames.iter().map(|&t| t * hop).collect())
}

/// Energy envelopes of recording − modal resynthesis per band (module docs). `post`: the
/// channels from the strike on (the extraction's channels, same order); `pre`: the same
/// channels before the strike (may be short or empty: then the floor estimate is 0).
pub fn residual_envelopes(
    post: &[Vec<f64>],
    pre: &[Vec<f64>],
    extraction: &ModalExtraction,
    options: &EnvelopeOptions,
) -> Result<ResidualEnvelopes, EvidenceError> {
    let fs = extraction.sample_rate;
    let n_channels = extraction
        .modes
        .first()
        .map_or(post.len(), |m| m.amplitudes.len());
    if post.len() != n_channels || post.is_empty() {
        return Err(EvidenceError::LengthMismatch {
            what: "channels after the strike",
            got: post.len(),
            expected: n_channels,
        });
    }
    if !pre.is_empty() && pre.len() != post.len() {
        return Err(EvidenceError::LengthMismatch {
            what: "pre-roll channels",
            got: pre.len(),
            expected: post.len(),
        });
    }
    if options.frame < 16
        || !options.frame.is_power_of_two() && options.frame % 2 != 0
        || options.hop == 0
    {
        return Err(EvidenceError::Invalid(format!(
            "envelope frame {} / hop {} invalid: the frame must be even and ≥ 16, the hop positive",
            options.frame, options.hop
        )));
    }
    let edges: Vec<f64> = options
        .band_edges_hz
        .iter()
        .copied()
        .filter(|&e| e < 0.5 * fs)
        .collect();
    if edges.len() < 2 || edges.windows(2).any(|w| !(w[1] > w[0])) || edges[0] < 0.0 {
        return Err(EvidenceError::Invalid(format!(
            "band edges {:?} must be ≥ 2 increasing values below Nyquist {} Hz",
            options.band_edges_hz,
            0.5 * fs
        )));
    }
    let plan = StftPlan::new(options.frame, options.hop)
        .map_err(|e| EvidenceError::Invalid(e.to_string()))?;
    let df = fs / options.frame as f64;
    let bins: Vec<std::ops::Range<usize>> = edges
        .windows(2)
        .map(|w| ((w[0] / df).ceil() as usize)..((w[1] / df).ceil() as usize))
        .collect();
    let n = post[0].len();
    let residual: Vec<Vec<f64>> = post
        .iter()
        .enumerate()
        .map(|(c, x)| {
            // Gliding modes glide ([`ModalExtraction::render_channel`]): a glide left in the
            // residual would read as early excess energy (reverb).
            let model = extraction.render_channel(c, n);
            x.iter().zip(&model).map(|(a, b)| a - b).collect()
        })
        .collect();
    let (energy, centres) = band_energies(&residual, &plan, &bins, options.frame);
    if centres.len() < 8 {
        return Err(EvidenceError::Invalid(format!(
            "{} samples after the strike give {} full frames of {}; at least 8 needed",
            n,
            centres.len(),
            options.frame
        )));
    }
    let noise_floor_estimate = if pre.is_empty() || pre[0].len() < options.frame {
        vec![0.0; bins.len()]
    } else {
        let (e, c) = band_energies(pre, &plan, &bins, options.frame);
        e.iter()
            .map(|band| band.iter().sum::<f64>() / c.len().max(1) as f64)
            .collect()
    };
    Ok(ResidualEnvelopes {
        times_s: centres.iter().map(|&s| s as f64 / fs).collect(),
        band_edges_hz: edges,
        energy,
        noise_floor_estimate,
        frames_per_window: options.frame as f64 / options.hop as f64,
    })
}

/// Cluster ids in frequency order: walking the modes by increasing frequency, mode k joins its
/// lower neighbour j's cluster when `joins(j, k)`, else opens the next id.
fn chain_clusters(frequencies_hz: &[f64], joins: impl Fn(usize, usize) -> bool) -> Vec<usize> {
    let mut order: Vec<usize> = (0..frequencies_hz.len()).collect();
    order.sort_by(|&a, &b| frequencies_hz[a].total_cmp(&frequencies_hz[b]));
    let mut ids = vec![0; frequencies_hz.len()];
    let mut id = 0;
    for (pos, &k) in order.iter().enumerate() {
        if pos > 0 && !joins(order[pos - 1], k) {
            id += 1;
        }
        ids[k] = id;
    }
    ids
}

/// Whether two frequencies lie within `rtol` (relative to the larger).
fn within(a: f64, b: f64, rtol: f64) -> bool {
    (a - b).abs() <= rtol * a.abs().max(b.abs())
}

/// Clusters of near-degenerate modes: ids such that neighbours (in sorted frequency) within
/// `rtol` share one; ids count up from 0 in frequency order.
pub fn cluster_ids(frequencies_hz: &[f64], rtol: f64) -> Vec<usize> {
    chain_clusters(frequencies_hz, |j, k| {
        within(frequencies_hz[j], frequencies_hz[k], rtol)
    })
}

/// The axis of a body's rotational symmetry from its second moment of volume `moments`
/// ([`crate::mesh::TetMesh::volume_moments`], \[m²\]): a body of revolution (or one with a
/// square's symmetry about an axis) has two equal eigenvalues, and the axis is the eigenvector of
/// the third. Of the three eigenvectors, the one whose two companions' eigenvalues lie closest,
/// relative to their sum; a unit vector. A cup or a bowl standing on its base, a plate lying on
/// a table and a tube lying on its side all get their own axis; the support's direction, the
/// axis used before, is that axis only for the first three. About the vertical, generator 2's
/// tube (0.28 m along x, lying on a table) had its pairs, 0.1 % apart in the mesh, left as lone
/// modes: their axial profiles about the vertical differ.
pub fn symmetry_axis(moments: [[f64; 3]; 3]) -> [f64; 3] {
    let m = nalgebra::Matrix3::from_fn(|r, c| 0.5 * (moments[r][c] + moments[c][r]));
    let eig = nalgebra::SymmetricEigen::new(m);
    let l = eig.eigenvalues;
    let gap = |i: usize| {
        let (a, b) = (l[(i + 1) % 3], l[(i + 2) % 3]);
        (a - b).abs() / (a.abs() + b.abs()).max(f64::MIN_POSITIVE)
    };
    let best = (0..3)
        .min_by(|&a, &b| gap(a).total_cmp(&gap(b)))
        .unwrap_or(2);
    let v = eig.eigenvectors.column(best);
    let norm = v.norm();
    if norm > 0.0 && norm.is_finite() {
        [v[0] / norm, v[1] / norm, v[2] / norm]
    } else {
        [0.0, 0.0, 1.0]
    }
}

/// Where a mode moves, in a frame that a rotation about `axis` (through `centre`) leaves
/// unchanged: its squared motion |φ(x_i)|² binned by height along the axis and by distance from
/// it (`bins` × `bins` cells over the nodes' extent), normalised to sum 1. The two members of a
/// pair that is degenerate by rotational symmetry are rotated copies of each other and have the
/// same profile; two unrelated modes that merely happen to lie close in frequency do not.
pub fn axial_profile(
    shape: &[f64],
    nodes: &[[f64; 3]],
    centre: [f64; 3],
    axis: [f64; 3],
    bins: usize,
) -> Vec<f64> {
    let coords: Vec<(f64, f64)> = nodes
        .iter()
        .map(|x| {
            let r = [x[0] - centre[0], x[1] - centre[1], x[2] - centre[2]];
            let h = r[0] * axis[0] + r[1] * axis[1] + r[2] * axis[2];
            let rho2 = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2] - h * h).max(0.0);
            (h, rho2.sqrt())
        })
        .collect();
    let (h_lo, h_hi) = coords
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), c| {
            (a.min(c.0), b.max(c.0))
        });
    let r_hi = coords.iter().fold(0.0_f64, |m, c| m.max(c.1));
    let cell = |v: f64, lo: f64, hi: f64| {
        (((v - lo) / (hi - lo).max(1e-300) * bins as f64) as usize).min(bins - 1)
    };
    let mut out = vec![0.0; bins * bins];
    for (i, &(h, rho)) in coords.iter().enumerate() {
        out[cell(h, h_lo, h_hi) * bins + cell(rho, 0.0, r_hi)] += node_energy(shape, i);
    }
    let total: f64 = out.iter().sum();
    if total > 0.0 {
        out.iter_mut().for_each(|v| *v /= total);
    }
    out
}

/// Clusters of modes degenerate by symmetry: neighbours (in sorted frequency) within `rtol`
/// whose [`axial_profile`]s differ by at most `max_profile_distance` in L1 (out of 2) are
/// chained into one cluster; ids count up from 0 in frequency order.
pub fn symmetric_cluster_ids(
    frequencies_hz: &[f64],
    profiles: &[Vec<f64>],
    rtol: f64,
    max_profile_distance: f64,
) -> Vec<usize> {
    chain_clusters(frequencies_hz, |j, k| {
        within(frequencies_hz[j], frequencies_hz[k], rtol)
            && profiles[k]
                .iter()
                .zip(&profiles[j])
                .map(|(a, b)| (a - b).abs())
                .sum::<f64>()
                <= max_profile_distance
    })
}

/// Which part of the motion at a region a perturbation there feels (module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Motion {
    /// All of it, |φ(x_i)|²: a lumped mass.
    Full,
    /// Only along a direction n (any length; normalised here), (φ(x_i)·n̂)²: a support's
    /// contact, which reacts along its normal.
    Along([f64; 3]),
}

impl Motion {
    /// The components' weights: φ(x_i)ᵀ P φ(x_j) with P = I (full) or n̂n̂ᵀ.
    fn projector(self) -> [[f64; 3]; 3] {
        match self {
            Motion::Full => [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            Motion::Along(n) => {
                let norm2: f64 = n.iter().map(|c| c * c).sum();
                let inv = if norm2 > 0.0 { 1.0 / norm2 } else { 0.0 };
                std::array::from_fn(|r| std::array::from_fn(|c| n[r] * n[c] * inv))
            }
        }
    }
}

/// φ_a(x_i)ᵀ P φ_b(x_i) of two mode shapes (node-major x, y, z) at node i.
fn node_product(a: &[f64], b: &[f64], i: usize, p: &[[f64; 3]; 3]) -> f64 {
    (0..3)
        .map(|r| a[3 * i + r] * (0..3).map(|c| p[r][c] * b[3 * i + c]).sum::<f64>())
        .sum()
}

/// |φ(x_i)|² of a mode shape (node-major x, y, z) at node i.
fn node_energy(shape: &[f64], i: usize) -> f64 {
    shape[3 * i..3 * i + 3].iter().map(|v| v * v).sum()
}

/// Squared motion Σ_{i ∈ nodes} |φ(x_i)|² of a mode shape (node-major x, y, z).
pub fn region_energy(shape: &[f64], nodes: &[usize]) -> f64 {
    nodes.iter().map(|&i| node_energy(shape, i)).sum()
}

/// Region energies of the simulated modes with every near-degenerate cluster turned to the
/// region's principal directions. Within a cluster the solver's basis is arbitrary (any
/// rotation of a degenerate pair is as good), but a perturbation localised in the region (a
/// mass, a spring) acts on the cluster through the matrix A_ab = Σ_{i ∈ region} φ_a(x_i)·φ_b(x_i)
/// (a, b members), and first-order degenerate perturbation theory splits the cluster along A's
/// eigenvectors with shifts ∝ its eigenvalues. So each member gets one eigenvalue of A: the
/// largest to the lowest-frequency member when the perturbation lowers frequencies (a mass,
/// `lowers_frequency`), to the highest otherwise (a spring). `motion` says which part of the
/// motion the perturbation feels (A_ab = Σ φ_a(x_i)ᵀ P φ_b(x_i), [`Motion`]). Outside clusters
/// this is the region's energy A_kk. `clusters` as from [`cluster_ids`].
pub fn cluster_region_energies(
    shapes: &[Vec<f64>],
    frequencies_hz: &[f64],
    clusters: &[usize],
    region: &[usize],
    motion: Motion,
    lowers_frequency: bool,
) -> Vec<f64> {
    let p = motion.projector();
    let energy =
        |a: &[f64], b: &[f64]| -> f64 { region.iter().map(|&i| node_product(a, b, i, &p)).sum() };
    let mut out: Vec<f64> = shapes.iter().map(|s| energy(s, s)).collect();
    let listed = &clusters[..clusters.len().min(shapes.len())];
    for mut ks in crate::inverse::impact::cluster_members(listed)
        .into_iter()
        .filter(|ks| ks.len() > 1)
    {
        ks.sort_by(|&a, &b| frequencies_hz[a].total_cmp(&frequencies_hz[b]));
        let m = ks.len();
        let a = nalgebra::DMatrix::from_fn(m, m, |r, c| energy(&shapes[ks[r]], &shapes[ks[c]]));
        let mut values: Vec<f64> = a
            .symmetric_eigen()
            .eigenvalues
            .iter()
            .map(|v| v.max(0.0))
            .collect();
        values.sort_by(|x, y| {
            if lowers_frequency {
                y.total_cmp(x)
            } else {
                x.total_cmp(y)
            }
        });
        for (k, v) in ks.into_iter().zip(values) {
            out[k] = v;
        }
    }
    out
}

/// Divides by the largest value (all zero stays zero).
fn normalised(values: &[f64]) -> Vec<f64> {
    let top = values.iter().fold(0.0_f64, |m, v| m.max(*v));
    if top > 0.0 {
        values.iter().map(|v| v / top).collect()
    } else {
        vec![0.0; values.len()]
    }
}

/// The catalogue's simulated modes (module docs): `drive[k]` = |φ_k(x_s)·n|,
/// `support_energy[k]` and `mass_energy[k]` region energies ([`region_energy`]; `None`: no
/// candidate region), `transfer[k]` |p_k| per microphone.
pub fn simulated_modes(
    frequencies_hz: &[f64],
    drive: &[f64],
    support_energy: &[f64],
    mass_energy: Option<&[f64]>,
    transfer: Option<&[Vec<f64>]>,
    clusters: &[usize],
) -> Result<Vec<SimulatedMode>, EvidenceError> {
    let k = frequencies_hz.len();
    let check = |what: &'static str, got: usize| {
        if got == k {
            Ok(())
        } else {
            Err(EvidenceError::LengthMismatch {
                what,
                got,
                expected: k,
            })
        }
    };
    check("drives", drive.len())?;
    check("support energies", support_energy.len())?;
    if let Some(m) = mass_energy {
        check("mass-region energies", m.len())?;
    }
    if let Some(t) = transfer {
        check("transfers", t.len())?;
    }
    let support = normalised(support_energy);
    let mass = mass_energy.map_or(vec![0.0; k], normalised);
    check("cluster ids", clusters.len())?;
    Ok((0..k)
        .map(|i| SimulatedMode {
            frequency_hz: frequencies_hz[i],
            drive: drive[i].abs(),
            support_weight: support[i],
            mass_weight: mass[i],
            cluster: clusters[i],
            transfer: transfer.map(|t| t[i].clone()),
            match_frequency_hz: None,
            ln_f_per_poisson: None,
        })
        .collect())
}

/// The map ζ(v) over candidate vertices (module docs): `vertex_energy[v][k]` = |φ_k(v)|² for
/// the simulated modes, `residuals` = (simulated mode indices sharing the observation, z of its
/// ln f residual). Returns (μ̂(v), ζ(v)) per vertex.
pub fn localise_frequency_residuals(
    vertex_energy: &[Vec<f64>],
    residuals: &[(Vec<usize>, f64)],
) -> Vec<(f64, f64)> {
    localise(vertex_energy, residuals, -0.5)
}

/// The support's map over candidate vertices (module docs): as
/// [`localise_frequency_residuals`], with `residuals` the z of each observation's ln d
/// residual, regressed on +w. Returns (γ̂(v) in units of the residuals' σ, ζ(v)) per vertex.
pub fn localise_decay_residuals(
    vertex_energy: &[Vec<f64>],
    residuals: &[(Vec<usize>, f64)],
) -> Vec<(f64, f64)> {
    localise(vertex_energy, residuals, 1.0)
}

/// Regression of `residuals` on `slope`·w_k(v) at every vertex (slope, z).
fn localise(
    vertex_energy: &[Vec<f64>],
    residuals: &[(Vec<usize>, f64)],
    slope: f64,
) -> Vec<(f64, f64)> {
    vertex_energy
        .iter()
        .map(|energy| {
            let top = residuals
                .iter()
                .flat_map(|r| r.0.iter())
                .map(|&k| energy.get(k).copied().unwrap_or(0.0))
                .fold(0.0_f64, f64::max);
            if top <= 0.0 {
                return (0.0, 0.0);
            }
            let points: Vec<(f64, f64, f64)> = residuals
                .iter()
                .filter(|r| !r.0.is_empty())
                .map(|(modes, z)| {
                    let w = modes
                        .iter()
                        .map(|&k| energy.get(k).copied().unwrap_or(0.0))
                        .sum::<f64>()
                        / modes.len() as f64
                        / top;
                    (slope * w, *z, 1.0)
                })
                .collect();
            // Standardised residuals have unit variance, so the regression's z is μ̂ / σ(μ̂).
            if points.len() < 3 {
                (0.0, 0.0)
            } else {
                weighted_regression(&points)
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::extract::{extract_modes, ExtractOptions};
    use crate::audio::synth::render_samples;
    use crate::audio::synth::ModalBank;
    use crate::diagnose::inject::SplitMix64;

    /// `bank` rendered at `fs` for `n` samples, with white noise of σ = `sigma` from `rng`.
    fn noisy(bank: &ModalBank, fs: f64, n: usize, sigma: f64, rng: &mut SplitMix64) -> Vec<f64> {
        render_samples(bank, fs, n)
            .iter()
            .map(|v| v + sigma * rng.normal())
            .collect()
    }

    #[test]
    fn mutual_nearest_pairs_and_refuses_far_or_shared() {
        let from = [100.0, 200.0, 200.5, 400.0];
        let to = [100.2, 200.4, 390.0];
        let m = mutual_nearest(&from, &to, 0.01);
        // 200.0's nearest is 200.4, whose nearest is 200.5: not mutual.
        assert_eq!(m, vec![Some(0), None, Some(1), None]);
    }

    #[test]
    fn clusters_chain_neighbours_within_tolerance() {
        let ids = cluster_ids(&[1000.0, 3000.0, 1002.0, 1004.5, 2000.0], 0.003);
        assert_eq!(ids, vec![0, 2, 0, 0, 1]);
    }

    #[test]
    fn simulated_features_normalise_and_check_lengths() {
        let s = simulated_modes(
            &[100.0, 100.1, 300.0],
            &[-2.0, 1.0, 0.5],
            &[1.0, 4.0, 0.0],
            None,
            None,
            &cluster_ids(&[100.0, 100.1, 300.0], 0.005),
        )
        .unwrap();
        assert_eq!(s[0].drive, 2.0);
        assert_eq!(
            s.iter().map(|m| m.support_weight).collect::<Vec<_>>(),
            vec![0.25, 1.0, 0.0]
        );
        assert_eq!(
            s.iter().map(|m| m.cluster).collect::<Vec<_>>(),
            vec![0, 0, 1]
        );
        assert!(s.iter().all(|m| m.mass_weight == 0.0));
        assert!(simulated_modes(&[1.0, 2.0], &[1.0], &[1.0, 1.0], None, None, &[0, 1]).is_err());
    }

    /// A degenerate pair in any rotated basis gets the same region energies: the eigenvalues of
    /// the region matrix, largest to the lower member for a mass.
    #[test]
    fn cluster_energies_do_not_depend_on_the_pair_basis() {
        // Two nodes; mode a moves node 0 in x, mode b moves node 1 in y (unit entries), plus a
        // third, separate mode.
        let a = vec![1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let b = vec![0.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        let c = vec![0.5, 0.5, 0.0, 0.0, 0.0, 0.0];
        let region = [0usize];
        let freqs = [100.0, 100.01, 300.0];
        let ids = cluster_ids(&freqs, 0.005);
        let plain = cluster_region_energies(
            &[a.clone(), b.clone(), c.clone()],
            &freqs,
            &ids,
            &region,
            Motion::Full,
            true,
        );
        assert_eq!(plain, vec![1.0, 0.0, 0.5]);
        for angle in [0.3_f64, 1.1, 2.5] {
            let (co, si) = (angle.cos(), angle.sin());
            let r1: Vec<f64> = a.iter().zip(&b).map(|(x, y)| co * x + si * y).collect();
            let r2: Vec<f64> = a.iter().zip(&b).map(|(x, y)| -si * x + co * y).collect();
            // The naive energies depend on the angle; the cluster ones do not.
            assert!((region_energy(&r1, &region) - co * co).abs() < 1e-12);
            let e = cluster_region_energies(
                &[r1, r2, c.clone()],
                &freqs,
                &ids,
                &region,
                Motion::Full,
                true,
            );
            assert!(
                (e[0] - 1.0).abs() < 1e-12 && e[1].abs() < 1e-12 && (e[2] - 0.5).abs() < 1e-12,
                "{e:?}"
            );
            let spring = cluster_region_energies(
                &[a.clone(), b.clone(), c.clone()],
                &freqs,
                &ids,
                &region,
                Motion::Full,
                false,
            );
            assert_eq!(spring, vec![0.0, 1.0, 0.5]);
        }
    }

    /// A support feels the motion along its direction only: a degenerate pair, one member
    /// moving the region along z, the other along y, is told apart by a support pressing along
    /// z (the upper member stiffened), while counted in full both carry the same weight.
    #[test]
    fn a_support_weighs_the_motion_along_its_direction() {
        let s = std::f64::consts::FRAC_1_SQRT_2;
        // Two nodes, both in the region; the pair given in a rotated basis.
        let vertical = [0.0, 0.0, 1.0, 0.0, 0.0, 1.0];
        let sideways = [0.0, 1.0, 0.0, 0.0, 1.0, 0.0];
        let r1: Vec<f64> = vertical
            .iter()
            .zip(&sideways)
            .map(|(a, b)| s * (a + b))
            .collect();
        let r2: Vec<f64> = vertical
            .iter()
            .zip(&sideways)
            .map(|(a, b)| s * (a - b))
            .collect();
        let lone = vec![0.3, 0.4, 0.0, 0.0, 0.0, 0.0];
        let shapes = [r1, r2, lone];
        let freqs = [500.0, 500.2, 900.0];
        let ids = cluster_ids(&freqs, 0.005);
        let region = [0usize, 1];
        let full = cluster_region_energies(&shapes, &freqs, &ids, &region, Motion::Full, false);
        assert!(
            (full[0] - 2.0).abs() < 1e-12 && (full[1] - 2.0).abs() < 1e-12,
            "{full:?}"
        );
        assert!((full[2] - 0.25).abs() < 1e-12);
        let down = Motion::Along([0.0, 0.0, -3.0]);
        let along = cluster_region_energies(&shapes, &freqs, &ids, &region, down, false);
        assert!(along[0].abs() < 1e-12, "{along:?}");
        assert!((along[1] - 2.0).abs() < 1e-12, "{along:?}");
        assert!(along[2].abs() < 1e-12, "{along:?}");
    }

    /// A rotated copy of a mode has its profile; a different mode close in frequency does not
    /// join its cluster.
    #[test]
    fn symmetric_clusters_need_alike_profiles() {
        // Four nodes on a ring about z at height 0, one on the axis at height 1.
        let nodes = [
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [-1.0, 0.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.0, 0.0, 1.0],
        ];
        let mode = |v: [f64; 5]| -> Vec<f64> { v.iter().flat_map(|&a| [a, 0.0, 0.0]).collect() };
        let a = mode([1.0, 0.0, -1.0, 0.0, 0.0]);
        let rotated = mode([0.0, 1.0, 0.0, -1.0, 0.0]);
        let other = mode([0.0, 0.0, 0.0, 0.0, 1.0]);
        let p: Vec<Vec<f64>> = [&a, &rotated, &other]
            .iter()
            .map(|s| axial_profile(s, &nodes, [0.0; 3], [0.0, 0.0, 1.0], 4))
            .collect();
        assert_eq!(p[0], p[1]);
        let ids = symmetric_cluster_ids(&[100.0, 100.1, 100.2], &p, 0.005, 0.2);
        assert_eq!(ids, vec![0, 0, 1]);
        assert_eq!(
            symmetric_cluster_ids(&[100.0, 100.1, 100.2], &p, 0.0001, 0.2),
            vec![0, 1, 2]
        );
    }

    /// The symmetry axis is the body's own: a bar lying along x, a square plate lying flat,
    /// and the same bar turned to lie along the diagonal of the xy plane.
    #[test]
    fn the_symmetry_axis_is_the_bodys_own() {
        let axis = |size: [f64; 3]| {
            let m = crate::mesh::box_mesh([6, 2, 2], size);
            symmetry_axis(m.volume_moments().expect("a volume").1)
        };
        let along = |a: [f64; 3], b: [f64; 3]| (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]).abs();
        assert!(along(axis([0.3, 0.02, 0.02]), [1.0, 0.0, 0.0]) > 1.0 - 1e-9);
        assert!(along(axis([0.2, 0.2, 0.01]), [0.0, 0.0, 1.0]) > 1.0 - 1e-9);
        // The bar's moments turned by 45° about z: C' = R C Rᵀ.
        let (a, b) = (0.3_f64 * 0.3 / 12.0, 0.02_f64 * 0.02 / 12.0);
        let h = 0.5 * (a + b);
        let d = 0.5 * (a - b);
        let turned = [[h, d, 0.0], [d, h, 0.0], [0.0, 0.0, b]];
        let r = std::f64::consts::FRAC_1_SQRT_2;
        assert!(along(symmetry_axis(turned), [r, r, 0.0]) > 1.0 - 1e-9);
    }

    #[test]
    fn localisation_peaks_where_the_low_modes_move() {
        // Three vertices, six modes; modes 0, 2, 4 move at vertex 1 and came out low (z < 0
        // means observed below predicted: a mass there would lower them).
        let energy = vec![
            vec![1.0, 1.0, 1.0, 1.0, 1.0, 1.0],
            vec![1.0, 0.0, 0.9, 0.1, 1.0, 0.0],
            vec![0.0, 1.0, 0.1, 0.9, 0.0, 1.0],
        ];
        let residuals: Vec<(Vec<usize>, f64)> = (0..6)
            .map(|k| (vec![k], if k % 2 == 0 { -3.0 } else { 0.5 }))
            .collect();
        let map = localise_frequency_residuals(&energy, &residuals);
        assert_eq!(
            map[0],
            (0.0, 0.0),
            "a vertex every mode moves at explains nothing"
        );
        assert!(map[1].0 > 0.0 && map[1].1 > 3.0, "{:?}", map[1]);
        assert!(map[2].0 < 0.0, "{:?}", map[2]);
    }

    /// The support's map: the modes that move at vertex 2 decay faster than the law (z > 0),
    /// so a support there (γ > 0) explains them; vertex 1's modes are the others.
    #[test]
    fn support_localisation_peaks_where_the_fast_decaying_modes_move() {
        let energy = vec![
            vec![1.0, 1.0, 1.0, 1.0, 1.0, 1.0],
            vec![1.0, 0.0, 0.9, 0.1, 1.0, 0.0],
            vec![0.0, 1.0, 0.1, 0.9, 0.0, 1.0],
        ];
        let residuals: Vec<(Vec<usize>, f64)> = (0..6)
            .map(|k| (vec![k], if k % 2 == 1 { 3.0 } else { -0.5 }))
            .collect();
        let map = localise_decay_residuals(&energy, &residuals);
        assert_eq!(map[0], (0.0, 0.0));
        assert!(map[2].0 > 0.0 && map[2].1 > 3.0, "{:?}", map[2]);
        assert!(map[1].0 < 0.0 && map[1].1 < 0.0, "{:?}", map[1]);
        // The same residuals read as frequencies point the other way (−½ w).
        let as_frequency = localise_frequency_residuals(&energy, &residuals);
        assert!((as_frequency[2].0 + 2.0 * map[2].0).abs() < 1e-9 * map[2].0.abs());
    }

    /// Residual envelopes: with the modes extracted well the residual is the noise, so its band
    /// energies after the strike match the pre-roll floor within the frame scatter; a modal tail
    /// left out of the model shows as excess in its band only.
    #[test]
    fn residual_envelopes_sit_on_the_floor_and_show_a_missing_mode() {
        let fs = 16000.0;
        let n = 16000;
        let bank = ModalBank {
            frequencies_hz: vec![700.0, 2300.0],
            decay_rates: vec![6.0, 9.0],
            amplitudes: vec![0.3, 0.2],
            phases: vec![0.3, -1.0],
        };
        let mut rng = SplitMix64::new(5);
        let sigma = 1e-4;
        let post: Vec<Vec<f64>> = vec![noisy(&bank, fs, n, sigma, &mut rng)];
        let pre: Vec<Vec<f64>> = vec![(0..8000).map(|_| sigma * rng.normal()).collect()];
        let ex = extract_modes(&post, fs, &ExtractOptions::default()).unwrap();
        assert_eq!(
            ex.modes.len(),
            2,
            "{:?}",
            ex.modes.iter().map(|m| m.frequency_hz).collect::<Vec<_>>()
        );
        let options = EnvelopeOptions {
            band_edges_hz: vec![250.0, 1000.0, 4000.0],
            frame: 512,
            hop: 256,
        };
        let env = residual_envelopes(&post, &pre, &ex, &options).unwrap();
        assert_eq!(env.energy.len(), 2);
        for b in 0..2 {
            let mean = env.energy[b].iter().sum::<f64>() / env.energy[b].len() as f64;
            let ratio = mean / env.noise_floor_estimate[b];
            assert!(
                (0.8..1.25).contains(&ratio),
                "band {b}: residual / floor = {ratio}"
            );
        }
        // Leave the 2300 Hz mode out of the model: band 1 (1–4 kHz) gains its decaying energy.
        let mut partial = ex.clone();
        partial.modes.retain(|m| m.frequency_hz < 1000.0);
        let env = residual_envelopes(&post, &pre, &partial, &options).unwrap();
        let first = env.energy[1][0] / env.noise_floor_estimate[1];
        let last = env.energy[1].last().unwrap() / env.noise_floor_estimate[1];
        assert!(
            first > 1e3 && first > 10.0 * last,
            "first {first}, last {last}"
        );
        let low = env.energy[0][0] / env.noise_floor_estimate[0];
        assert!(low < 3.0, "band 0 unaffected: {low}");
    }

    #[test]
    fn observed_modes_take_mutual_early_and_late_frequencies() {
        let fs = 16000.0;
        let n = 16000;
        let bank = ModalBank {
            frequencies_hz: vec![700.0, 2300.0],
            decay_rates: vec![3.0, 4.0],
            amplitudes: vec![0.3, 0.2],
            phases: vec![0.3, -1.0],
        };
        let mut rng = SplitMix64::new(9);
        let x = noisy(&bank, fs, n, 1e-5, &mut rng);
        let full = extract_modes(std::slice::from_ref(&x), fs, &ExtractOptions::default()).unwrap();
        let early = extract_modes(&[x[..n / 2].to_vec()], fs, &ExtractOptions::default()).unwrap();
        let late = extract_modes(&[x[n / 2..].to_vec()], fs, &ExtractOptions::default()).unwrap();
        let obs = observed_modes(
            &full,
            Some(&early),
            Some(&late),
            &ObservedOptions::default(),
        );
        assert_eq!(obs.len(), 2);
        for (o, f) in obs.iter().zip([700.0, 2300.0]) {
            let (fe, _) = o.early_frequency_hz.expect("early found");
            let (fl, _) = o.late_frequency_hz.expect("late found");
            assert!(
                (fe - f).abs() < 0.01 && (fl - f).abs() < 0.01,
                "{fe} {fl} vs {f}"
            );
            assert!(o.sigma_frequency_hz > 0.0 && o.amplitudes.len() == 1);
        }
        let strict = ObservedOptions {
            min_snr_db: 500.0,
            ..Default::default()
        };
        assert!(observed_modes(&full, None, None, &strict).is_empty());
    }

    /// An amplitude or a frequency the extraction could not measure (σ = 0 from a clamped
    /// covariance, or ∞) never reaches the catalogue as a measurement, which it would refuse.
    #[test]
    fn observed_modes_leave_out_what_was_not_measured() {
        let fs = 16000.0;
        let n = 16000;
        let bank = ModalBank {
            frequencies_hz: vec![700.0, 1500.0, 2300.0],
            decay_rates: vec![3.0, 5.0, 4.0],
            amplitudes: vec![0.3, 0.25, 0.2],
            phases: vec![0.3, 1.1, -1.0],
        };
        let mut rng = SplitMix64::new(11);
        let channels: Vec<Vec<f64>> = (0..2)
            .map(|_| noisy(&bank, fs, n, 1e-5, &mut rng))
            .collect();
        let clean = extract_modes(&channels, fs, &ExtractOptions::default()).unwrap();
        assert_eq!(clean.modes.len(), 3);
        let mut full = clean.clone();
        fn sd(k: usize, full: &mut ModalExtraction) -> &mut crate::analysis::ModeSd {
            full.modes[k].sd.as_mut().unwrap()
        }
        // Mode 0: channel 0's σ_a clamped to 0, channel 1's infinite.
        sd(0, &mut full).amplitudes = vec![0.0, f64::INFINITY];
        // Mode 1: no frequency uncertainty.
        sd(1, &mut full).frequency_hz = f64::NAN;
        // Mode 2: a decaying mode whose decay rate has no uncertainty.
        sd(2, &mut full).decay_rate = 0.0;
        let obs = observed_modes(&full, None, None, &ObservedOptions::default());
        assert_eq!(
            obs.len(),
            1,
            "only mode 0 has its frequency and decay measured"
        );
        let o = &obs[0];
        assert!((o.frequency_hz - 700.0).abs() < 0.01);
        assert_eq!(o.amplitudes, vec![0.0, 0.0]);
        assert_eq!(o.sigma_amplitudes, vec![0.0, 0.0]);
        // The untouched ones pass through.
        let all = observed_modes(&clean, None, None, &ObservedOptions::default());
        assert_eq!(all.len(), 3);
        assert!(all.iter().all(|o| o.amplitudes.iter().all(|&a| a > 0.0)
            && o.sigma_amplitudes.iter().all(|&s| s > 0.0 && s.is_finite())));
    }
}
