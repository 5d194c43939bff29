//! A causal first-order low-pass filter over time, per channel:
//! `y_0 = x_0`, `y_t = ρ·y_{t−1} + √(1 − ρ²)·x_t`.
//!
//! With white-noise input of unit variance the output keeps unit variance
//! and becomes an AR(1) process with lag-one correlation ρ: a smooth random
//! signal. The models filter their latent sample this way before decoding,
//! so noise drawn independently per step cannot make the pose jump.

use super::{fused, slice, tensor, with_values};
use candle_core::{CpuStorage, CustomOp1, Layout, Result, Shape, Tensor};

/// The input gain `√(1 − ρ²)` for pole `ρ`.
pub fn gain(rho: f64) -> f64 {
    (1.0 - rho * rho).max(0.0).sqrt()
}

/// Filter `x: [B, T, C]` along `T` with pole `rho` in `[0, 1)`.
pub fn smooth(x: &Tensor, rho: f64) -> Result<Tensor> {
    let (_, t, _) = x.dims3()?;
    if !(0.0..1.0).contains(&rho) {
        candle_core::bail!("smooth: the pole must be in [0, 1), got {rho}");
    }
    if rho == 0.0 {
        return Ok(x.clone());
    }
    if fused(x) {
        return x.contiguous()?.apply_op1(SmoothOp { rho: rho as f32 });
    }
    let mut y = x.narrow(1, 0, 1)?;
    let mut rows = vec![y.clone()];
    for step in 1..t {
        y = step_reference(&y, &x.narrow(1, step, 1)?, rho)?;
        rows.push(y.clone());
    }
    Tensor::cat(&rows, 1)
}

/// One step of the filter, `ρ·prev + √(1 − ρ²)·x` (free-running generation).
pub fn step(prev: &Tensor, x: &Tensor, rho: f64) -> Result<Tensor> {
    step_reference(prev, x, rho)
}

fn step_reference(prev: &Tensor, x: &Tensor, rho: f64) -> Result<Tensor> {
    (prev * rho)? + (x * gain(rho))?
}

/// The fused [`smooth`].
struct SmoothOp {
    rho: f32,
}

impl SmoothOp {
    /// Run the filter (or, with `reverse`, its adjoint) over each window.
    fn run(&self, v: &[f32], t: usize, c: usize, reverse: bool) -> Vec<f32> {
        let k = gain(self.rho as f64) as f32;
        let mut y = vec![0.0f32; v.len()];
        for (w, out) in v.chunks_exact(t * c).zip(y.chunks_exact_mut(t * c)) {
            if !reverse {
                out[..c].copy_from_slice(&w[..c]);
                for s in 1..t {
                    for j in 0..c {
                        out[s * c + j] = self.rho * out[(s - 1) * c + j] + k * w[s * c + j];
                    }
                }
            } else {
                // y_t depends on x_t with weight k (1 at t = 0) and on
                // y_{t−1} with weight ρ: accumulate from the end.
                let mut acc = vec![0.0f32; c];
                for s in (0..t).rev() {
                    for j in 0..c {
                        acc[j] = w[s * c + j] + self.rho * acc[j];
                        out[s * c + j] = if s == 0 { acc[j] } else { k * acc[j] };
                    }
                }
            }
        }
        y
    }
}

impl CustomOp1 for SmoothOp {
    fn name(&self) -> &'static str {
        "smooth"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> Result<(CpuStorage, Shape)> {
        let _time = crate::blocks::timing::span(self.name(), false);
        let x = slice(s, l, "x")?;
        let (_, t, c) = l.shape().dims3()?;
        Ok((CpuStorage::F32(self.run(x, t, c, false)), l.shape().clone()))
    }

    fn bwd(&self, x: &Tensor, _res: &Tensor, grad: &Tensor) -> Result<Option<Tensor>> {
        let _time = crate::blocks::timing::span(self.name(), true);
        let (_, t, c) = x.dims3()?;
        let dx = with_values(grad, |g| Ok(self.run(g, t, c, true)))?;
        Ok(Some(tensor(dx, x.dims(), x)?))
    }
}
