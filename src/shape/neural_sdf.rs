//! A signed-distance field represented by a small multilayer perceptron (issue 7, task 3), with
//! its hand-written backpropagation. Pure and serial: every rank evaluates the same network on
//! the same points and gets the same numbers.
//!
//! # The field
//!
//! With the box centre c [m] and half its longest side ℓ [m], a point x [m] is mapped to
//! u = (x − c)/ℓ (the box becomes a subset of [−1, 1]³, isotropically, so distances keep their
//! ratios) and encoded as
//!
//! ```text
//!   γ(u) = ( u₁, u₂, u₃,  sin(2^l π u_d), cos(2^l π u_d)  for l = 0 … L−1, d = 1, 2, 3 )
//! ```
//!
//! (3 + 6L features, L = `octaves`). Hidden layers z_j = W_j a_{j−1} + b_j,
//! a_j = softplus(z_j) = ln(1 + e^{z_j}), a_0 = γ(u); the output y = w_out·a_J + b_out is
//! dimensionless and the field is
//!
//! ```text
//!   s(x) = ℓ · y(u(x))     [m],   so ∇_x s = ∇_u y
//! ```
//!
//! A network that is a distance in u-units is then a distance in metres, and one learning rate
//! suits every body size. Positive inside (the convention of [`crate::shape::sdf`] and of the
//! marching).
//!
//! # Choices
//!
//! * **Softplus**, not ReLU: the marching moves crossings with s, and the eigenvalue gradient
//!   is only useful if s (hence the surface) is smooth in θ and x; softplus is C^∞ with
//!   derivative the logistic function σ(z) = 1/(1 + e^{−z}) ∈ (0, 1), so gradients neither
//!   vanish nor explode through 2–3 layers. A SIREN (sin activations) needs a careful
//!   frequency-dependent initialisation and readily fits sub-voxel ripples that the coarse
//!   voxels cannot contradict; a smooth activation on a few octaves is the stronger prior here.
//! * **A few octaves** (default 3): the finest feature has period 2^{1−L}·2ℓ, a quarter of the
//!   box at L = 3, i.e. about four voxels of a 16³ voxelisation and five cells of a 20-cell fit
//!   grid — what the grid can mesh. More octaves let the pre-fit copy the voxels' staircase.
//! * **The raw u** among the features lets the network represent a plane or a large ball with
//!   few units; the sines and cosines add detail.
//!
//! # Backpropagation
//!
//! For dL/ds_p given at points x_p, dL/dy_p = ℓ dL/ds_p and, layer by layer from the top,
//!
//! ```text
//!   ∂L/∂w_out += δ a_J,  ∂L/∂b_out += δ,  g_J = δ w_out                     (δ = dL/dy_p)
//!   e_j = g_j ⊙ σ(z_j),  ∂L/∂W_j += e_j a_{j−1}ᵀ,  ∂L/∂b_j += e_j,  g_{j−1} = W_jᵀ e_j
//! ```
//!
//! summed over the points ([`NeuralSdf::vjp`]). The encoding has no parameters.
//!
//! # Parameters
//!
//! One flat vector θ, layer by layer (hidden layers first, then the output), each layer's
//! weights row-major (W[i][k] multiplies input k of output i) followed by its biases
//! ([`NeuralSdf::parameters`], [`NeuralSdf::from_parameters`]); the architecture is the
//! serialisable [`NeuralSdfConfig`]. The seeded initialisation ([`NeuralSdf::new`]) draws every
//! weight uniformly in ±√(6/(n_in + n_out)) (Glorot) from splitmix64 and sets the biases to 0.

use crate::random::SplitMix64;
use std::f64::consts::PI;

/// Why a network could not be built or evaluated.
#[derive(Debug, thiserror::Error)]
pub enum NeuralSdfError {
    #[error("neural SDF: {0}")]
    Invalid(String),
}

/// The architecture and placement of a network (everything but θ).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NeuralSdfConfig {
    /// c [m]: the centre of the box the network covers.
    pub centre: [f64; 3],
    /// ℓ [m]: half the longest side of that box.
    pub length: f64,
    /// L: octaves of the positional encoding (0 = the raw coordinates only).
    pub octaves: usize,
    /// Width of each hidden layer (at least one layer).
    pub hidden: Vec<usize>,
}

impl NeuralSdfConfig {
    /// A network over the box [lo, hi] (c its centre, ℓ half its longest side).
    pub fn for_box(
        lo: [f64; 3],
        hi: [f64; 3],
        octaves: usize,
        hidden: Vec<usize>,
    ) -> Result<NeuralSdfConfig, NeuralSdfError> {
        let longest = (0..3)
            .map(|d| hi[d] - lo[d])
            .fold(f64::NEG_INFINITY, f64::max);
        let config = NeuralSdfConfig {
            centre: [0, 1, 2].map(|d| 0.5 * (lo[d] + hi[d])),
            length: 0.5 * longest,
            octaves,
            hidden,
        };
        config.validate()?;
        Ok(config)
    }

    /// Checks sizes and numbers.
    pub fn validate(&self) -> Result<(), NeuralSdfError> {
        let bad = |m: String| Err(NeuralSdfError::Invalid(m));
        if !(self.length.is_finite() && self.length > 0.0) {
            return bad(format!(
                "the box's half-length ℓ must be positive, got {}",
                self.length
            ));
        }
        if self.centre.iter().any(|c| !c.is_finite()) {
            return bad(format!("the box centre {:?} is not finite", self.centre));
        }
        if self.octaves > 12 {
            return bad(format!(
                "at most 12 octaves (2^12 π is finer than any grid here), got {}",
                self.octaves
            ));
        }
        if self.hidden.is_empty() || self.hidden.iter().any(|&w| !(1..=1024).contains(&w)) {
            return bad(format!(
                "hidden layers must be one or more widths in 1..=1024, got {:?}",
                self.hidden
            ));
        }
        Ok(())
    }

    /// 3 + 6L.
    pub fn n_features(&self) -> usize {
        3 + 6 * self.octaves
    }

    /// (n_in, n_out) of every layer, the output layer last.
    fn layer_shapes(&self) -> Vec<(usize, usize)> {
        let mut shapes = Vec::with_capacity(self.hidden.len() + 1);
        let mut n_in = self.n_features();
        for &w in &self.hidden {
            shapes.push((n_in, w));
            n_in = w;
        }
        shapes.push((n_in, 1));
        shapes
    }

    /// Length of θ.
    pub fn n_parameters(&self) -> usize {
        self.layer_shapes().iter().map(|(i, o)| i * o + o).sum()
    }
}

/// Where a layer's weights and biases sit in θ.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Layer {
    n_in: usize,
    n_out: usize,
    weights: usize,
    biases: usize,
}

/// The network: architecture, parameters θ and their layout.
#[derive(Clone, Debug, PartialEq)]
pub struct NeuralSdf {
    config: NeuralSdfConfig,
    parameters: Vec<f64>,
    layers: Vec<Layer>,
}

/// softplus(z) = ln(1 + e^z), without overflow.
fn softplus(z: f64) -> f64 {
    z.max(0.0) + (-z.abs()).exp().ln_1p()
}

/// d softplus/dz = 1/(1 + e^{−z}).
fn logistic(z: f64) -> f64 {
    if z >= 0.0 {
        1.0 / (1.0 + (-z).exp())
    } else {
        let e = z.exp();
        e / (1.0 + e)
    }
}

/// The activations of one forward pass, kept for the backward pass.
struct Trace {
    /// a_0 = γ(u), a_1, …, a_J.
    activations: Vec<Vec<f64>>,
    /// z_1, …, z_J.
    pre: Vec<Vec<f64>>,
}

impl NeuralSdf {
    /// A network with the seeded Glorot initialisation (module docs).
    pub fn new(config: NeuralSdfConfig, seed: u64) -> Result<NeuralSdf, NeuralSdfError> {
        config.validate()?;
        let layers = Self::layout(&config);
        let mut parameters = vec![0.0; config.n_parameters()];
        let mut rng = SplitMix64::new(seed);
        for l in &layers {
            let limit = (6.0 / (l.n_in + l.n_out) as f64).sqrt();
            for w in &mut parameters[l.weights..l.weights + l.n_in * l.n_out] {
                *w = rng.uniform(-limit, limit);
            }
        }
        Ok(NeuralSdf {
            config,
            parameters,
            layers,
        })
    }

    /// A network with the given θ (e.g. read back from a result file).
    pub fn from_parameters(
        config: NeuralSdfConfig,
        parameters: Vec<f64>,
    ) -> Result<NeuralSdf, NeuralSdfError> {
        config.validate()?;
        let layers = Self::layout(&config);
        let mut net = NeuralSdf {
            config,
            parameters: Vec::new(),
            layers,
        };
        net.set_parameters(&parameters)?;
        Ok(net)
    }

    fn layout(config: &NeuralSdfConfig) -> Vec<Layer> {
        let mut offset = 0;
        config
            .layer_shapes()
            .into_iter()
            .map(|(n_in, n_out)| {
                let layer = Layer {
                    n_in,
                    n_out,
                    weights: offset,
                    biases: offset + n_in * n_out,
                };
                offset += n_in * n_out + n_out;
                layer
            })
            .collect()
    }

    pub fn config(&self) -> &NeuralSdfConfig {
        &self.config
    }

    /// θ (layout in the module docs).
    pub fn parameters(&self) -> &[f64] {
        &self.parameters
    }

    pub fn n_parameters(&self) -> usize {
        self.config.n_parameters()
    }

    /// Replaces θ; its length must match the architecture and every entry be finite.
    pub fn set_parameters(&mut self, parameters: &[f64]) -> Result<(), NeuralSdfError> {
        let n = self.config.n_parameters();
        if parameters.len() != n {
            return Err(NeuralSdfError::Invalid(format!(
                "{} parameters for a network of {n}",
                parameters.len()
            )));
        }
        if let Some(i) = parameters.iter().position(|p| !p.is_finite()) {
            return Err(NeuralSdfError::Invalid(format!(
                "parameter {i} is {}",
                parameters[i]
            )));
        }
        self.parameters = parameters.to_vec();
        Ok(())
    }

    /// γ(u(x)) (module docs).
    pub fn encode(&self, x: [f64; 3]) -> Vec<f64> {
        let u = [0, 1, 2].map(|d| (x[d] - self.config.centre[d]) / self.config.length);
        let mut f = Vec::with_capacity(self.config.n_features());
        f.extend_from_slice(&u);
        for l in 0..self.config.octaves {
            let w = (1u64 << l) as f64 * PI;
            for ud in u {
                let (sn, cs) = (w * ud).sin_cos();
                f.push(sn);
                f.push(cs);
            }
        }
        f
    }

    /// The forward pass at x: y (dimensionless) and, if asked, the trace for backpropagation.
    fn forward(&self, x: [f64; 3], keep: bool) -> (f64, Option<Trace>) {
        let mut a = self.encode(x);
        let mut trace = keep.then(|| Trace {
            activations: Vec::with_capacity(self.layers.len()),
            pre: Vec::with_capacity(self.layers.len()),
        });
        let (hidden, output) = self.layers.split_at(self.layers.len() - 1);
        for l in hidden {
            let w = &self.parameters[l.weights..l.weights + l.n_in * l.n_out];
            let b = &self.parameters[l.biases..l.biases + l.n_out];
            let z: Vec<f64> = (0..l.n_out)
                .map(|i| {
                    b[i] + w[i * l.n_in..(i + 1) * l.n_in]
                        .iter()
                        .zip(&a)
                        .map(|(wi, ai)| wi * ai)
                        .sum::<f64>()
                })
                .collect();
            let next: Vec<f64> = z.iter().map(|&zi| softplus(zi)).collect();
            if let Some(t) = trace.as_mut() {
                t.activations.push(std::mem::replace(&mut a, next));
                t.pre.push(z);
            } else {
                a = next;
            }
        }
        let o = output[0];
        let y = self.parameters[o.biases]
            + self.parameters[o.weights..o.weights + o.n_in]
                .iter()
                .zip(&a)
                .map(|(w, ai)| w * ai)
                .sum::<f64>();
        if let Some(t) = trace.as_mut() {
            t.activations.push(a);
        }
        (y, trace)
    }

    /// s(x) [m].
    pub fn value(&self, x: [f64; 3]) -> f64 {
        self.config.length * self.forward(x, false).0
    }

    /// s at every point [m].
    pub fn values(&self, points: &[[f64; 3]]) -> Vec<f64> {
        points.iter().map(|&x| self.value(x)).collect()
    }

    /// dL/dθ = Σ_p (dL/ds_p) ∂s_p/∂θ for `d_values` = dL/ds at `points` (module docs).
    pub fn vjp(&self, points: &[[f64; 3]], d_values: &[f64]) -> Result<Vec<f64>, NeuralSdfError> {
        Ok(self
            .vjp_rows(points, &[d_values])?
            .pop()
            .expect("one row in, one gradient out"))
    }

    /// [`Self::vjp`] for several rows of dL/ds at the same points at once: one forward pass
    /// per point serves every row (the geometry task backpropagates a dozen eigenvalue groups
    /// through the same points).
    pub fn vjp_rows<R: AsRef<[f64]>>(
        &self,
        points: &[[f64; 3]],
        rows: &[R],
    ) -> Result<Vec<Vec<f64>>, NeuralSdfError> {
        let rows: Vec<&[f64]> = rows.iter().map(AsRef::as_ref).collect();
        for (r, d_values) in rows.iter().enumerate() {
            if points.len() != d_values.len() {
                return Err(NeuralSdfError::Invalid(format!(
                    "{} points and {} values of dL/ds in row {r}",
                    points.len(),
                    d_values.len()
                )));
            }
            if let Some(i) = d_values.iter().position(|v| !v.is_finite()) {
                return Err(NeuralSdfError::Invalid(format!(
                    "dL/ds at point {i} of row {r} is {}",
                    d_values[i]
                )));
            }
        }
        let mut grads = vec![vec![0.0; self.parameters.len()]; rows.len()];
        for (p, &x) in points.iter().enumerate() {
            if rows.iter().all(|r| r[p] == 0.0) {
                continue;
            }
            let (_, trace) = self.forward(x, true);
            let trace = trace.expect("kept");
            for (row, grad) in rows.iter().zip(grads.iter_mut()) {
                if row[p] != 0.0 {
                    self.backward(&trace, self.config.length * row[p], grad);
                }
            }
        }
        Ok(grads)
    }

    /// Adds dy/dθ · `d_output` to `grad` along the forward pass `trace`.
    fn backward(&self, trace: &Trace, d_output: f64, grad: &mut [f64]) {
        let mut delta = vec![d_output];
        // From the output layer down: delta holds dL/dz of the current layer (the output
        // layer is linear, so its dL/dz is dL/dy).
        for (j, l) in self.layers.iter().enumerate().rev() {
            let input = &trace.activations[j];
            for i in 0..l.n_out {
                let row = l.weights + i * l.n_in;
                for k in 0..l.n_in {
                    grad[row + k] += delta[i] * input[k];
                }
                grad[l.biases + i] += delta[i];
            }
            if j == 0 {
                break;
            }
            let z = &trace.pre[j - 1];
            let mut below = vec![0.0; l.n_in];
            for (i, &d) in delta.iter().enumerate().take(l.n_out) {
                let row = &self.parameters[l.weights + i * l.n_in..l.weights + (i + 1) * l.n_in];
                for k in 0..l.n_in {
                    below[k] += row[k] * d;
                }
            }
            for k in 0..l.n_in {
                below[k] *= logistic(z[k]);
            }
            delta = below;
        }
    }

    /// Index ranges of every parameter block in θ: (name, range), for checks and files.
    pub fn blocks(&self) -> Vec<(String, std::ops::Range<usize>)> {
        let last = self.layers.len() - 1;
        let mut out = Vec::new();
        for (j, l) in self.layers.iter().enumerate() {
            let name = if j == last {
                "output".to_string()
            } else {
                format!("hidden {j}")
            };
            out.push((
                format!("{name} weights"),
                l.weights..l.weights + l.n_in * l.n_out,
            ));
            out.push((format!("{name} biases"), l.biases..l.biases + l.n_out));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::Rng;

    fn net(seed: u64) -> NeuralSdf {
        let config =
            NeuralSdfConfig::for_box([-0.03, -0.02, -0.01], [0.05, 0.04, 0.02], 3, vec![16, 12])
                .unwrap();
        NeuralSdf::new(config, seed).unwrap()
    }

    #[test]
    fn vjp_matches_central_differences_for_every_parameter_block() {
        let mut net = net(7);
        // Biases of 0 would leave every softplus at the same point: perturb θ for a generic test.
        let mut rng = Rng(3);
        let theta: Vec<f64> = net
            .parameters()
            .iter()
            .map(|p| p + rng.uniform(-0.2, 0.2))
            .collect();
        net.set_parameters(&theta).unwrap();
        let points: Vec<[f64; 3]> = (0..9)
            .map(|_| {
                [
                    rng.uniform(-0.03, 0.05),
                    rng.uniform(-0.02, 0.04),
                    rng.uniform(-0.01, 0.02),
                ]
            })
            .collect();
        let weights = rng.uniform_vec(points.len(), -1.0, 1.0);
        let loss = |n: &NeuralSdf| {
            n.values(&points)
                .iter()
                .zip(&weights)
                .map(|(s, w)| s * w)
                .sum::<f64>()
        };
        let grad = net.vjp(&points, &weights).unwrap();
        let blocks = net.blocks();
        assert_eq!(blocks.len(), 6);
        for (name, range) in blocks {
            // Every entry of small blocks, a spread of entries of large ones.
            let stride = (range.len() / 12).max(1);
            for i in range.clone().step_by(stride) {
                let h = 1e-6;
                let mut p = theta.clone();
                p[i] += h;
                let mut plus = net.clone();
                plus.set_parameters(&p).unwrap();
                p[i] -= 2.0 * h;
                let mut minus = net.clone();
                minus.set_parameters(&p).unwrap();
                let fd = (loss(&plus) - loss(&minus)) / (2.0 * h);
                // Central differences: O(h²) truncation, rounding ~1e-16·|L|/h.
                assert!(
                    (fd - grad[i]).abs() <= 1e-7 * (1.0 + grad[i].abs()),
                    "{name} θ[{i}]: vjp {} vs FD {fd}",
                    grad[i]
                );
            }
        }
    }

    #[test]
    fn initialisation_is_seeded_and_parameters_round_trip() {
        let (a, b, c) = (net(11), net(11), net(12));
        assert_eq!(a.parameters(), b.parameters());
        assert_ne!(a.parameters(), c.parameters());
        // 21 features → 16 → 12 → 1.
        assert_eq!(a.n_parameters(), 21 * 16 + 16 + 16 * 12 + 12 + 12 + 1);
        let limit = (6.0f64 / (21 + 16) as f64).sqrt();
        assert!(a.parameters()[..21 * 16].iter().all(|w| w.abs() <= limit));
        let back = NeuralSdf::from_parameters(a.config().clone(), a.parameters().to_vec()).unwrap();
        let x = [0.01, 0.0, 0.005];
        assert_eq!(back.value(x), a.value(x));
        let json = serde_json::to_string(a.config()).unwrap();
        let config: NeuralSdfConfig = serde_json::from_str(&json).unwrap();
        assert_eq!(&config, a.config());
        assert!(NeuralSdf::from_parameters(config.clone(), vec![0.0; 3]).is_err());
        let mut nan = a.parameters().to_vec();
        nan[5] = f64::NAN;
        assert!(NeuralSdf::from_parameters(config, nan).is_err());
        assert!(NeuralSdfConfig::for_box([0.0; 3], [0.0; 3], 3, vec![8]).is_err());
        assert!(NeuralSdfConfig::for_box([0.0; 3], [1.0; 3], 3, vec![]).is_err());
        assert!(a.vjp(&[x], &[1.0, 2.0]).is_err());
        assert!(a.vjp_rows(&[x], &[vec![1.0], vec![1.0, 2.0]]).is_err());
        assert!(a.vjp_rows(&[x], &[vec![f64::NAN]]).is_err());
    }

    #[test]
    fn vjp_rows_equal_one_vjp_per_row() {
        let net = net(5);
        let mut rng = Rng(17);
        let points: Vec<[f64; 3]> = (0..40)
            .map(|_| {
                [
                    rng.uniform(-0.03, 0.05),
                    rng.uniform(-0.02, 0.04),
                    rng.uniform(-0.01, 0.02),
                ]
            })
            .collect();
        // Rows with zeros in different places, one all zero.
        let mut rows: Vec<Vec<f64>> = (0..4)
            .map(|_| rng.uniform_vec(points.len(), -1.0, 1.0))
            .collect();
        rows[1].iter_mut().step_by(3).for_each(|v| *v = 0.0);
        rows[2] = vec![0.0; points.len()];
        let together = net.vjp_rows(&points, &rows).unwrap();
        assert_eq!(together.len(), rows.len());
        for (row, grad) in rows.iter().zip(&together) {
            assert_eq!(&net.vjp(&points, row).unwrap(), grad);
        }
    }

    #[test]
    fn the_field_is_in_metres_and_the_encoding_is_periodic_in_octaves() {
        // With every hidden weight and bias 0, each hidden unit is softplus(0) = ln 2, so
        // y = b_out + Σ w_out ln 2 everywhere, and s = ℓ y in metres.
        let config = NeuralSdfConfig::for_box([0.0; 3], [0.2, 0.1, 0.1], 2, vec![4]).unwrap();
        assert!((config.length - 0.1).abs() < 1e-15);
        let mut theta = vec![0.0; config.n_parameters()];
        let n = theta.len();
        theta[n - 1] = 0.5; // b_out
        theta[n - 2] = 1.0; // one w_out
        let net = NeuralSdf::from_parameters(config, theta).unwrap();
        let s = net.value([0.3, -1.0, 7.0]);
        assert!((s - 0.1 * (0.5 + 2f64.ln())).abs() < 1e-15, "{s}");
        let f = net.encode([0.1 + 0.05, 0.05, 0.05]);
        assert_eq!(f.len(), 15);
        // u = (0.5, 0, 0): sin(π/2) = 1, cos(π/2) = 0; second octave sin(π) = 0, cos(π) = −1.
        assert!((f[0] - 0.5).abs() < 1e-15 && (f[3] - 1.0).abs() < 1e-15 && f[4].abs() < 1e-15);
        assert!(f[9].abs() < 1e-15 && (f[10] + 1.0).abs() < 1e-15);
    }
}
