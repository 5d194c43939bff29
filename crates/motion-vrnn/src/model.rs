//! The VRNN of Murakami & Ikuzawa (section 4.2), after Chung et al. (2015).
//!
//! Per time step, with `h` the LSTM state before the step:
//! - features `x'' = relu(W2 relu(W1 x))` (58 → 48 → 32);
//! - prior `N(μp, σp)` from `h` (`σ = sigmoid(·)`), `N(0, I)` at the first step;
//! - posterior `N(μz, σz)` from `[x'', h]`; `z = μz + σz ⊙ ε`;
//! - decoder `x̃ = W5 relu(W4 relu(W3 [z, h]))` (→ 32 → 48 → 58);
//! - LSTM input `[x'', z]`, hidden 32, `h0 = c0 = 0`.
//!
//! Loss per step: `‖x̃ − x‖² + KL(N(μz,σz) ‖ N(μp,σp))`, summed over time and
//! averaged over the batch. Standard deviations are clamped to at least
//! [`SIGMA_MIN`] so the logs stay finite.

use crate::fused;
use candle_core::{DType, Device, Result, Tensor, D};
use candle_nn::rnn::{LSTMConfig, LSTMState, LSTM, RNN};
use candle_nn::{linear, Linear, Module, VarBuilder};
use serde::{Deserialize, Serialize};

/// Lower bound on every standard deviation (guards `log σ` and `1/σ²`).
pub const SIGMA_MIN: f64 = 1e-4;

/// Every size of the model.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Config {
    /// Features per frame.
    pub input: usize,
    /// Feature-extractor layer sizes.
    pub extractor: [usize; 2],
    /// LSTM hidden size.
    pub hidden: usize,
    /// Latent size.
    pub latent: usize,
    /// Decoder hidden sizes (ψ, then the next layer).
    pub decoder: [usize; 2],
}

impl Default for Config {
    /// The paper's sizes.
    fn default() -> Self {
        Config {
            input: 58,
            extractor: [48, 32],
            hidden: 32,
            latent: 8,
            decoder: [32, 48],
        }
    }
}

/// A Gaussian head: mean and sigmoid standard deviation.
#[derive(Clone, Debug)]
struct Gaussian {
    mean: Linear,
    std: Linear,
}

impl Gaussian {
    fn new(input: usize, latent: usize, vb: VarBuilder) -> Result<Self> {
        Ok(Gaussian {
            mean: linear(input, latent, vb.pp("mean"))?,
            std: linear(input, latent, vb.pp("std"))?,
        })
    }

    fn forward(&self, x: &Tensor) -> Result<(Tensor, Tensor)> {
        let mu = self.mean.forward(x)?;
        let sigma = candle_nn::ops::sigmoid(&self.std.forward(x)?)?.clamp(SIGMA_MIN, 1.0)?;
        Ok((mu, sigma))
    }
}

/// The model.
#[derive(Clone, Debug)]
pub struct Vrnn {
    config: Config,
    phi_x: [Linear; 2],
    prior: Gaussian,
    encoder: Gaussian,
    decoder: [Linear; 3],
    rnn: LSTM,
    /// Every parameter in [`fused::param_layout`] order.
    params: Vec<Tensor>,
}

/// Losses of a batch: summed over time, averaged over the batch (scalars).
#[derive(Clone, Debug)]
pub struct Losses {
    /// Squared reconstruction error.
    pub recon: Tensor,
    /// KL(posterior ‖ prior).
    pub kl: Tensor,
}

impl Vrnn {
    /// Build the model; variables are created through `vb`.
    pub fn new(config: &Config, vb: VarBuilder) -> Result<Self> {
        let c = config;
        let [e1, e2] = c.extractor;
        let [d1, d2] = c.decoder;
        let params = |vb: &VarBuilder| -> Result<Vec<Tensor>> {
            fused::param_layout(c)
                .into_iter()
                .map(|(name, shape)| vb.get(shape, &name))
                .collect()
        };
        Ok(Vrnn {
            config: c.clone(),
            phi_x: [
                linear(c.input, e1, vb.pp("phi_x.0"))?,
                linear(e1, e2, vb.pp("phi_x.1"))?,
            ],
            prior: Gaussian::new(c.hidden, c.latent, vb.pp("prior"))?,
            encoder: Gaussian::new(e2 + c.hidden, c.latent, vb.pp("encoder"))?,
            decoder: [
                linear(c.latent + c.hidden, d1, vb.pp("decoder.0"))?,
                linear(d1, d2, vb.pp("decoder.1"))?,
                linear(d2, c.input, vb.pp("decoder.2"))?,
            ],
            rnn: candle_nn::rnn::lstm(
                e2 + c.latent,
                c.hidden,
                LSTMConfig::default(),
                vb.pp("rnn"),
            )?,
            params: params(&vb)?,
        })
    }

    /// The model's sizes.
    pub fn config(&self) -> &Config {
        &self.config
    }

    fn features(&self, x: &Tensor) -> Result<Tensor> {
        let h = self.phi_x[0].forward(x)?.relu()?;
        self.phi_x[1].forward(&h)?.relu()
    }

    /// Decode `z` given the LSTM output `h` (the mean of `p(x | z, h)`).
    pub fn decode(&self, z: &Tensor, h: &Tensor) -> Result<Tensor> {
        let a = self.decoder[0]
            .forward(&Tensor::cat(&[z, h], D::Minus1)?)?
            .relu()?;
        let b = self.decoder[1].forward(&a)?.relu()?;
        self.decoder[2].forward(&b)
    }

    /// Losses of a batch `x: [B, T, input]` with reparameterisation noise
    /// `eps: [T, B, latent]`.
    pub fn forward(&self, x: &Tensor, eps: &Tensor) -> Result<Losses> {
        let (b, t, _) = x.dims3()?;
        let mut state: LSTMState = self.rnn.zero_state(b)?;
        let mut recon = Tensor::zeros(b, DType::F32, x.device())?;
        let mut kl = Tensor::zeros(b, DType::F32, x.device())?;
        for step in 0..t {
            // Slicing inputs (not parameters) keeps the backward pass linear in T.
            let xt = x.narrow(1, step, 1)?.squeeze(1)?;
            let et = eps.get(step)?;
            let h = state.h().clone();
            let feat = self.features(&xt)?;
            let (mu_z, sigma_z) = self
                .encoder
                .forward(&Tensor::cat(&[&feat, &h], D::Minus1)?)?;
            let z = (&mu_z + (&sigma_z * &et)?)?;
            let x_hat = self.decode(&z, &h)?;
            recon = (recon + (x_hat - &xt)?.sqr()?.sum(D::Minus1)?)?;
            let step_kl = if step == 0 {
                kl_standard(&mu_z, &sigma_z)?
            } else {
                let (mu_p, sigma_p) = self.prior.forward(&h)?;
                kl_gaussians(&mu_z, &sigma_z, &mu_p, &sigma_p)?
            };
            kl = (kl + step_kl)?;
            state = self
                .rnn
                .step(&Tensor::cat(&[&feat, &z], D::Minus1)?, &state)?;
        }
        Ok(Losses {
            recon: recon.mean(0)?,
            kl: kl.mean(0)?,
        })
    }

    /// Reconstruct real windows `x: [B, T, input]`: encode each step with the
    /// posterior mean (`z = μz`, no noise), decode it (the decoder mean) and
    /// feed the real frame to the recurrence. Returns `[B, T, input]`.
    pub fn reconstruct(&self, x: &Tensor) -> Result<Tensor> {
        let (b, t, _) = x.dims3()?;
        let mut state: LSTMState = self.rnn.zero_state(b)?;
        let mut frames = Vec::with_capacity(t);
        for step in 0..t {
            let xt = x.narrow(1, step, 1)?.squeeze(1)?;
            let h = state.h().clone();
            let feat = self.features(&xt)?;
            let (mu_z, _) = self
                .encoder
                .forward(&Tensor::cat(&[&feat, &h], D::Minus1)?)?;
            frames.push(self.decode(&mu_z, &h)?);
            state = self
                .rnn
                .step(&Tensor::cat(&[&feat, &mu_z], D::Minus1)?, &state)?;
        }
        Tensor::stack(&frames, 1)
    }

    /// Every parameter flattened and concatenated in [`fused::param_layout`]
    /// order (differentiable).
    pub fn flat_params(&self) -> Result<Tensor> {
        let flat: Vec<Tensor> = self
            .params
            .iter()
            .map(|p| p.flatten_all())
            .collect::<Result<_>>()?;
        Tensor::cat(&flat, 0)
    }

    /// Losses of a batch, as [`Vrnn::forward`], through the fused kernel of
    /// [`fused`] on the CPU (autograd elsewhere). With `kl_weight`, the
    /// forward pass also prepares the gradient of `recon + kl_weight · kl`,
    /// which `backward` of exactly that sum then reuses; any other use of the
    /// losses stays correct but computes the gradient again.
    pub fn losses(&self, x: &Tensor, eps: &Tensor, kl_weight: Option<f64>) -> Result<Losses> {
        if !x.device().is_cpu() {
            return self.forward(x, eps);
        }
        let flat = self.flat_params()?;
        let op = fused::VrnnLoss::new(&self.config, kl_weight.map(|w| w as f32));
        let out = x.contiguous()?.apply_op3(&eps.contiguous()?, &flat, op)?;
        Ok(Losses {
            recon: out.get(0)?,
            kl: out.get(1)?,
        })
    }

    /// Sample `eps.len()` frames per sequence from the prior, feeding each
    /// decoded frame (the decoder mean) back as the next input.
    /// `eps: [T, B, latent]`; returns `[B, T, input]` (normalised units).
    pub fn sample(&self, eps: &Tensor) -> Result<Tensor> {
        let (t, b, _) = eps.dims3()?;
        if eps.device().is_cpu() {
            let w = self.flat_params()?.to_vec1::<f32>()?;
            let e = eps.flatten_all()?.to_vec1::<f32>()?;
            let out = fused::sample(&self.config, &w, &e, b, t);
            return Tensor::from_vec(out, (b, t, self.config.input), eps.device());
        }
        self.sample_autograd(eps)
    }

    /// [`Vrnn::sample`] through candle ops on any device (the reference for
    /// the fused CPU sampler).
    pub fn sample_autograd(&self, eps: &Tensor) -> Result<Tensor> {
        let (t, b, _) = eps.dims3()?;
        let mut state = self.rnn.zero_state(b)?;
        let mut frames = Vec::with_capacity(t);
        for step in 0..t {
            let h = state.h().clone();
            let et = eps.get(step)?;
            let z = if step == 0 {
                et
            } else {
                let (mu_p, sigma_p) = self.prior.forward(&h)?;
                (mu_p + (sigma_p * et)?)?
            };
            let x_hat = self.decode(&z, &h)?;
            let feat = self.features(&x_hat)?;
            state = self
                .rnn
                .step(&Tensor::cat(&[&feat, &z], D::Minus1)?, &state)?;
            frames.push(x_hat);
        }
        Tensor::stack(&frames, 1)
    }
}

/// `KL(N(μ, σ) ‖ N(0, 1))` summed over the last dimension.
pub fn kl_standard(mu: &Tensor, sigma: &Tensor) -> Result<Tensor> {
    // −log σ + (σ² + μ²)/2 − 1/2
    let v = ((sigma.sqr()? + mu.sqr()?)? * 0.5)?;
    ((v - sigma.log()?)? - 0.5)?.sum(D::Minus1)
}

/// `KL(N(μz, σz) ‖ N(μp, σp))` summed over the last dimension.
pub fn kl_gaussians(mu_z: &Tensor, s_z: &Tensor, mu_p: &Tensor, s_p: &Tensor) -> Result<Tensor> {
    // log σp − log σz + (σz² + (μz − μp)²) / (2 σp²) − 1/2
    let num = (s_z.sqr()? + (mu_z - mu_p)?.sqr()?)?;
    let frac = (num / (s_p.sqr()? * 2.0)?)?;
    (((s_p.log()? - s_z.log()?)? + frac)? - 0.5)?.sum(D::Minus1)
}

/// The device to train on: CUDA when built with `cuda` and one is present.
pub fn default_device() -> Device {
    Device::cuda_if_available(0).unwrap_or(Device::Cpu)
}
