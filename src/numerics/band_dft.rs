//! The DFT of a complex sequence at a band of bins and at their mirrors, cheaper than the
//! whole FFT when the band is narrow.
//!
//! # Equations
//!
//! For x[n], n = 0 … N − 1, and X[k] = Σₙ x[n] W^(kn), W = e^(−2πi/N) (unscaled), write
//! N = P Q and n = pQ + q (p < P, q < Q): decimation in time by Q gives
//!
//! X[k] = Σ_q W^(kq) A_q[k mod P],   A_q[r] = Σ_p x[pQ + q] e^(−2πi r p / P),
//!
//! so Q FFTs of length P (the phases x[q], x[Q + q], …) and, per wanted bin, a sum of Q
//! terms. The mirror bin N − k has the twiddles W^((N−k)q) = conj W^(kq) and the residue
//! (P − k mod P) mod P, from the same A_q. The cost is about N log₂P for the short FFTs and
//! 2MQ complex products for M bins and their mirrors, against N log₂N for the whole FFT; the
//! best P is near 2M ln 2 (a divisor of N).
//!
//! # Why
//!
//! The glide stage ([`crate::analysis::extract::glide`]) fits a gliding mode on a band of a
//! few hundred bins of a transform of up to 48 000 samples, and transforms four sequences per
//! evaluation (the mode and its three derivatives), hundreds of evaluations per group: the
//! whole FFTs were about 40 % of the stage on a room recording (generator 2's seed 433, case
//! 023).
//!
//! # Accuracy
//!
//! The twiddles are exact per product (the exponent kq reduced mod N before sin/cos), and each
//! bin sums Q rounded terms: the difference from the whole FFT is rounding, ~10⁻¹⁵ relative to
//! the sequence's norm (tested below 10⁻¹²).

use std::f64::consts::PI;
use std::sync::Arc;

use rustfft::num_complex::Complex64 as C64;
use rustfft::{Fft, FftPlanner};

/// The short transforms' lengths P tried, best first where the cost model ties: rustfft's
/// fastest lengths here, 2ᵃ·3·5 and a few others with factors 2, 3 and 5 (powers of two alone,
/// and lengths with a factor 19 or 23, ran up to twice as slow per element).
const FAST_LENGTHS: [usize; 13] = [
    960, 480, 1200, 1000, 800, 600, 1600, 400, 900, 300, 240, 1920, 120,
];
/// At least this many phases Q.
const MIN_PHASES: usize = 8;
/// One complex product of the combination against one element of one FFT pass, in the cost
/// model N log₂P + w·2MQ (the combination reads the phases strided by P). Measured on this
/// machine (rustfft 6, AVX), the decimated transform against the whole FFT: N = 36 480 (960·38)
/// and M = 150, 0.48 at P = 480 and 960, 0.63 at P = 120; N = 48 000, M = 167, 0.59–0.76 at
/// P = 480–1600; N = 22 080, M = 300, 0.49 at P = 960; N = 9600, M = 80, 0.75–0.87.
const COMBINE_WEIGHT: f64 = 4.0;

/// A plan for the DFT at `bins` and their mirrors of sequences of length N (module docs).
pub struct BandDft {
    n: usize,
    p: usize,
    q: usize,
    fft: Arc<dyn Fft<f64>>,
    bins: Vec<usize>,
    /// W^(k_j q), row q, column j (the bins inner: the combination runs over q outside).
    twiddles: Vec<C64>,
    /// k_j mod P and (P − k_j mod P) mod P.
    residues: Vec<(usize, usize)>,
}

impl BandDft {
    /// The plan for sequences of length `n` at `bins` (each below `n`), or None when no
    /// factorisation N = P Q with P one of [`FAST_LENGTHS`] is cheaper than the whole FFT by
    /// the cost model N log₂P + w·2MQ ([`COMBINE_WEIGHT`]) against N log₂N.
    pub fn plan(planner: &mut FftPlanner<f64>, n: usize, bins: &[usize]) -> Option<BandDft> {
        if bins.is_empty() || bins.iter().any(|&k| k >= n) || n < 4 {
            return None;
        }
        let m = bins.len() as f64;
        let nf = n as f64;
        let cost = |p: usize| nf * (p as f64).log2() + COMBINE_WEIGHT * 2.0 * m * (n / p) as f64;
        let p = FAST_LENGTHS
            .into_iter()
            .filter(|&p| n % p == 0 && n / p >= MIN_PHASES)
            .min_by(|&a, &b| cost(a).total_cmp(&cost(b)))?;
        if cost(p) >= nf * nf.log2() {
            return None;
        }
        let q = n / p;
        let twiddles = (0..q)
            .flat_map(|qq| {
                bins.iter().map(move |&k| {
                    // kq mod N exactly in integers (k, q < N ≤ 2⁵³), then one sin/cos.
                    let e = ((k as u128 * qq as u128) % n as u128) as f64;
                    C64::from_polar(1.0, -2.0 * PI * e / nf)
                })
            })
            .collect();
        let residues = bins
            .iter()
            .map(|&k| {
                let r = k % p;
                (r, (p - r) % p)
            })
            .collect();
        Some(BandDft {
            n,
            p,
            q,
            fft: planner.plan_fft_forward(p),
            bins: bins.to_vec(),
            twiddles,
            residues,
        })
    }

    /// The bins this plan transforms at.
    pub fn bins(&self) -> &[usize] {
        &self.bins
    }

    /// (X[k], X[(N − k) mod N]) for each planned bin k, unscaled, into `out`; `x` has length
    /// N. `work` and `scratch` are reused between calls (their contents are overwritten).
    pub fn transform(
        &self,
        x: &[C64],
        work: &mut Vec<C64>,
        scratch: &mut Vec<C64>,
        out: &mut Vec<(C64, C64)>,
    ) {
        assert_eq!(x.len(), self.n, "BandDft::transform: sequence length");
        let (p, q) = (self.p, self.q);
        // The phases, each contiguous: work[qq P + pp] = x[pp Q + qq].
        work.resize(self.n, C64::new(0.0, 0.0));
        for (pp, row) in x.chunks_exact(q).enumerate() {
            for (qq, &v) in row.iter().enumerate() {
                work[qq * p + pp] = v;
            }
        }
        scratch.resize(self.fft.get_inplace_scratch_len(), C64::new(0.0, 0.0));
        // Q transforms of length P at once (the buffer in chunks of P).
        self.fft.process_with_scratch(work, scratch);
        let m = self.bins.len();
        out.clear();
        out.resize(m, (C64::new(0.0, 0.0), C64::new(0.0, 0.0)));
        for (phase, tw) in work.chunks_exact(p).zip(self.twiddles.chunks_exact(m)) {
            for ((acc, &(r, r_mirror)), &w) in out.iter_mut().zip(&self.residues).zip(tw) {
                acc.0 += w * phase[r];
                acc.1 += w.conj() * phase[r_mirror];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A reproducible random sequence, parts uniform in [−½, ½).
    fn sequence(n: usize, seed: u64) -> Vec<C64> {
        let mut rng = crate::random::SplitMix64::new(seed);
        (0..n)
            .map(|_| C64::new(rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5)))
            .collect()
    }

    #[test]
    fn the_band_and_its_mirror_match_the_whole_fft() {
        let mut planner = FftPlanner::new();
        // Lengths of the glide stage (whole blocks of 960, with awkward factors 19 and 23)
        // and the whole second at 48 kHz; bands at the bottom, in the middle and at Nyquist.
        for (n, lo, hi) in [
            (960 * 19, 1, 160),
            (960 * 23, 5000, 5300),
            (48_000, 23_800, 23_999),
            (960 * 38, 12_000, 12_150),
        ] {
            let bins: Vec<usize> = (lo..=hi).collect();
            let plan = BandDft::plan(&mut planner, n, &bins).expect("a narrow band pays");
            assert_eq!(plan.n, n);
            let x = sequence(n, n as u64);
            let mut full = x.clone();
            planner.plan_fft_forward(n).process(&mut full);
            let (mut work, mut scratch, mut out) = (vec![], vec![], vec![]);
            // Twice through the same buffers: nothing of the first call may leak.
            plan.transform(&sequence(n, 7), &mut work, &mut scratch, &mut out);
            plan.transform(&x, &mut work, &mut scratch, &mut out);
            let scale = (n as f64).sqrt();
            let worst = bins
                .iter()
                .zip(&out)
                .map(|(&k, &(a, b))| {
                    ((a - full[k]).norm() / scale).max((b - full[(n - k) % n]).norm() / scale)
                })
                .fold(0.0, f64::max);
            assert!(worst < 1e-12, "N = {n}, bins {lo}–{hi}: {worst:e}");
        }
    }

    #[test]
    fn a_wide_band_or_an_awkward_length_keeps_the_whole_fft() {
        let mut planner = FftPlanner::new();
        // Every bin: no factorisation can beat the FFT.
        let all: Vec<usize> = (0..960).collect();
        assert!(BandDft::plan(&mut planner, 960, &all).is_none());
        // A prime length has no factorisation at all, nor has 44 100 ± 1 one of the fast
        // lengths.
        assert!(BandDft::plan(&mut planner, 9973, &[10, 11, 12]).is_none());
        assert!(BandDft::plan(&mut planner, 44_101, &[10, 11, 12]).is_none());
        // One second at 48 kHz, and at 44.1 kHz, for a band of 167 bins.
        let band: Vec<usize> = (1000..1167).collect();
        for n in [48_000, 44_100] {
            let plan = BandDft::plan(&mut planner, n, &band).expect("pays");
            assert!(n % plan.p == 0 && FAST_LENGTHS.contains(&plan.p));
        }
        // Bad input: no bins, or a bin past the end.
        assert!(BandDft::plan(&mut planner, 9600, &[]).is_none());
        assert!(BandDft::plan(&mut planner, 9600, &[9600]).is_none());
    }
}
