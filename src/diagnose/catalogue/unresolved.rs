//! How far one pole's decay rate can sit from the object's damping when it stands for an
//! unresolved cluster (parent docs, "An unresolved cluster's decay").
//!
//! Two modes of one cluster, split by 2δ \[rad/s\] and both decaying at d \[1/s\], sum at a
//! microphone to
//!
//! x(t) = e^(−dt) (a₁ e^(i(ω̄ + δ)t) + a₂ e^(iφ) e^(i(ω̄ − δ)t)),
//!
//! a₂/a₁ = ρ the members' amplitude ratio and φ their relative phase at that microphone. When
//! the recording does not resolve them (δ below the linewidth, about d), the extraction
//! fits one pole c e^((−d' + iω')t) to it. The least-squares pole over t ≥ 0 maximises
//!
//! J(d', ω') = |⟨x, e⟩|² / ‖e‖² = 2d' |Σ_m a_m / (d + d' − i(ω_m − ω'))|²,
//!
//! and d' ≠ d: in phase (φ = 0) the beat's first fall adds to the decay (d' > d); in
//! opposition the sum starts small and grows before it decays, and d' < d. With δ/d = 0.44
//! and ρ = 1 (a tube's pair at 8.48 kHz split by 12.5 Hz, decaying at 90 1/s), ln(d'/d) runs
//! from −0.97 to +0.17 over φ; with ρ = 0.25 from −0.20 to +0.10; with δ/d = 0.1 and ρ = 0.5,
//! from −0.14 to +0.01.
//!
//! The phase is the microphone's (each mode radiates with its own sign and delay) and the
//! amplitude ratio is the drives' ratio times a radiation ratio nobody knows, so the model
//! does not predict d' from the cluster; it predicts how far d' can sit from d. [`decay_bias`]
//! is the root mean square of ln(d'/d) over φ uniform on [0, π] (−φ mirrors φ), each φ
//! weighted by the strength J of the pole it leaves: a mix that cancels the members leaves
//! little to extract, and its pole is unlikely to be the one measured. The model's rows take
//! it as the σ of that pole's ln d beyond the extraction's own
//! ([`super::model::ModeTable::build`]).

/// Phases φ over [0, π] that [`decay_bias`] averages over (midpoints).
const PHASES: usize = 12;
/// Points of the coarse grid in ln d' (over [d/8, 8d]) and in ω' (over the members' span
/// widened by d on either side), then of the fine grid around the coarse optimum.
const COARSE_DECAY: usize = 97;
const COARSE_FREQUENCY: usize = 49;
const FINE: usize = 21;
/// Below this δ/d the members are one mode to the extraction: no bias.
const MIN_RELATIVE_SPLIT: f64 = 1e-3;

/// J(d', ω') of the module docs for members at `offsets` (ω_m − ω̄, rad/s) with complex
/// amplitudes `(re, im)`, decaying at `d`.
fn strength(offsets: &[f64], amplitudes: &[(f64, f64)], d: f64, dp: f64, wp: f64) -> f64 {
    let (mut re, mut im) = (0.0, 0.0);
    for (&w, &(ar, ai)) in offsets.iter().zip(amplitudes) {
        // a / (p + iq), p = d + d', q = −(ω_m − ω').
        let (p, q) = (d + dp, wp - w);
        let den = p * p + q * q;
        re += (ar * p + ai * q) / den;
        im += (ai * p - ar * q) / den;
    }
    2.0 * dp * (re * re + im * im)
}

/// The least-squares single pole's (d', J) for members at `offsets` with complex amplitudes,
/// all decaying at `d` (module docs): a grid in (ln d', ω'), refined once around its best.
fn best_pole(offsets: &[f64], amplitudes: &[(f64, f64)], d: f64) -> (f64, f64) {
    let span = offsets.iter().fold(0.0_f64, |m, w| m.max(w.abs())) + d;
    let (ln_lo, ln_hi) = ((d / 8.0).ln(), (8.0 * d).ln());
    let step_d = (ln_hi - ln_lo) / (COARSE_DECAY - 1) as f64;
    let step_w = 2.0 * span / (COARSE_FREQUENCY - 1) as f64;
    let mut best = (f64::NEG_INFINITY, 0.0, 0.0);
    for i in 0..COARSE_DECAY {
        let ln_dp = ln_lo + step_d * i as f64;
        for j in 0..COARSE_FREQUENCY {
            let wp = -span + step_w * j as f64;
            let s = strength(offsets, amplitudes, d, ln_dp.exp(), wp);
            if s > best.0 {
                best = (s, ln_dp, wp);
            }
        }
    }
    let (_, c_d, c_w) = best;
    for i in 0..FINE {
        let ln_dp = c_d + step_d * (2.0 * i as f64 / (FINE - 1) as f64 - 1.0);
        for j in 0..FINE {
            let wp = c_w + step_w * (2.0 * j as f64 / (FINE - 1) as f64 - 1.0);
            let s = strength(offsets, amplitudes, d, ln_dp.exp(), wp);
            if s > best.0 {
                best = (s, ln_dp, wp);
            }
        }
    }
    (best.1.exp(), best.0)
}

/// Root mean square of ln(d'/d) (module docs) for two members split by `split_rad_s` = 2δ
/// \[rad/s\], decaying at `decay_rate` \[1/s\], with amplitude ratio `ratio` ∈ [0, 1] (the
/// weaker's over the stronger's): over the relative phase φ uniform on [0, π], each weighted by
/// the strength of the pole the mix leaves. 0 where the split or the ratio vanishes.
pub fn decay_bias(split_rad_s: f64, decay_rate: f64, ratio: f64) -> f64 {
    let delta = 0.5 * split_rad_s.abs();
    if !(decay_rate > 0.0) || !(ratio > 0.0) || !(delta > MIN_RELATIVE_SPLIT * decay_rate) {
        return 0.0;
    }
    let ratio = ratio.min(1.0);
    let offsets = [delta, -delta];
    let (mut sum, mut weight) = (0.0, 0.0);
    for k in 0..PHASES {
        let phi = std::f64::consts::PI * (k as f64 + 0.5) / PHASES as f64;
        let amplitudes = [(1.0, 0.0), (ratio * phi.cos(), ratio * phi.sin())];
        let (dp, j) = best_pole(&offsets, &amplitudes, decay_rate);
        let e = (dp / decay_rate).ln();
        sum += j * e * e;
        weight += j;
    }
    if weight > 0.0 {
        (sum / weight).sqrt()
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One member alone: the least-squares pole is that member, d' = d.
    #[test]
    fn one_member_is_its_own_pole() {
        let (dp, _) = best_pole(&[30.0], &[(1.0, 0.0)], 50.0);
        assert!((dp / 50.0 - 1.0).abs() < 5e-3, "{dp}");
        assert_eq!(decay_bias(60.0, 50.0, 0.0), 0.0);
        assert_eq!(decay_bias(0.0, 50.0, 1.0), 0.0);
    }

    /// The closed form against a direct least-squares fit on a sampled signal: in phase, the
    /// pole decays faster than its members; in opposition, slower.
    #[test]
    fn the_pole_follows_a_sampled_least_squares_fit() {
        let (d, delta) = (90.0, 39.0);
        for (phi, faster) in [(0.0, true), (std::f64::consts::PI, false)] {
            let amps = [(1.0, 0.0), (0.8 * f64::cos(phi), 0.8 * f64::sin(phi))];
            let (dp, _) = best_pole(&[delta, -delta], &amps, d);
            // Sampled: x(t) at 50 kHz over 12 decay times; the best d'' on a fine ln grid by
            // the projection |Σ x ē|² / Σ |e|², ω' scanned as well.
            let dt = 2e-5;
            let n = (12.0 / d / dt) as usize;
            let x: Vec<(f64, f64)> = (0..n)
                .map(|i| {
                    let t = i as f64 * dt;
                    let e = (-d * t).exp();
                    let (c1, s1) = ((delta * t).cos(), (delta * t).sin());
                    let (c2, s2) = ((-delta * t + phi).cos(), (-delta * t + phi).sin());
                    (e * (c1 + 0.8 * c2), e * (s1 + 0.8 * s2))
                })
                .collect();
            let mut best = (0.0, 0.0);
            for i in 0..120 {
                let dpp = d * (0.25 + 1.75 * i as f64 / 119.0);
                for j in 0..21 {
                    let wp = -delta + 2.0 * delta * j as f64 / 20.0;
                    let (mut re, mut im, mut norm) = (0.0, 0.0, 0.0);
                    for (i, &(xr, xi)) in x.iter().enumerate() {
                        let t = i as f64 * dt;
                        let e = (-dpp * t).exp();
                        let (c, s) = ((wp * t).cos() * e, (wp * t).sin() * e);
                        re += xr * c + xi * s;
                        im += xi * c - xr * s;
                        norm += e * e;
                    }
                    let v = (re * re + im * im) / norm;
                    if v > best.0 {
                        best = (v, dpp);
                    }
                }
            }
            assert!(
                (dp / best.1 - 1.0).abs() < 0.03,
                "φ = {phi}: closed form {dp}, sampled {}",
                best.1
            );
            assert_eq!(dp > d, faster, "φ = {phi}: d' = {dp}");
        }
    }

    /// The bias grows with the split against the linewidth and with the weaker member's share.
    #[test]
    fn the_bias_grows_with_the_split_and_the_weaker_share() {
        let d = 80.0;
        let narrow = decay_bias(2.0 * 0.05 * d, d, 0.5);
        let wide = decay_bias(2.0 * 0.5 * d, d, 0.5);
        assert!(narrow < 0.5 * wide, "{narrow} {wide}");
        let weak = decay_bias(2.0 * 0.44 * d, d, 0.1);
        let even = decay_bias(2.0 * 0.44 * d, d, 1.0);
        assert!(weak < 0.5 * even, "{weak} {even}");
        assert!(weak > 0.0 && even < 1.5, "{weak} {even}");
    }
}
