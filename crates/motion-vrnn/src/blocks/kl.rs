//! The Gaussian KL term of the VRNN.

use super::kernels::{dsigma, sigma};
use super::{fused, slice, tensor, with_values};
use candle_core::{CpuStorage, CustomOp2, Layout, Result, Shape, Tensor, D};

/// `Σ KL(N(μq, σq) ‖ N(μp, σp))` over every window, step and latent
/// dimension (a scalar). `q: [B, T, 2Z]` holds `[μq | σq]` (σ already
/// activated), `p: [B, T, 2Z]` holds `[μp | logit σp]` with
/// `σp = sigmoid(·)` clamped to `[SIGMA_MIN, 1]`. At `t = 0` the prior is
/// `N(0, I)` and `p` is not read.
pub fn gaussian_kl(q: &Tensor, p: &Tensor) -> Result<Tensor> {
    let (_, t, z2) = q.dims3()?;
    if q.shape() != p.shape() || z2 % 2 != 0 {
        candle_core::bail!("gaussian_kl: q {:?}, p {:?}", q.shape(), p.shape());
    }
    if fused(q) {
        return q.contiguous()?.apply_op2(&p.contiguous()?, KlOp);
    }
    let z = z2 / 2;
    let (mq, sq) = (q.narrow(D::Minus1, 0, z)?, q.narrow(D::Minus1, z, z)?);
    let first = kl_standard(&mq.narrow(1, 0, 1)?, &sq.narrow(1, 0, 1)?)?;
    let mut total = first.flatten_all()?.sum(0)?;
    if t > 1 {
        let mp = p.narrow(1, 1, t - 1)?.narrow(D::Minus1, 0, z)?;
        let sp = candle_nn::ops::sigmoid(&p.narrow(1, 1, t - 1)?.narrow(D::Minus1, z, z)?)?
            .clamp(super::kernels::SIGMA_MIN, 1.0)?;
        let rest = kl_gaussians(&mq.narrow(1, 1, t - 1)?, &sq.narrow(1, 1, t - 1)?, &mp, &sp)?;
        total = (total + rest.flatten_all()?.sum(0)?)?;
    }
    Ok(total)
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

/// The fused [`gaussian_kl`].
struct KlOp;

/// Visit every `(row, step, k)` with `(μq, σq)` and, after the first step,
/// `(μp, σp)`.
fn each(
    q: &[f32],
    p: &[f32],
    t: usize,
    z: usize,
    mut f: impl FnMut(usize, f32, f32, Option<(f32, f32)>),
) {
    let z2 = 2 * z;
    for (r, qr) in q.chunks_exact(z2).enumerate() {
        let pr = &p[r * z2..(r + 1) * z2];
        for k in 0..z {
            let prior = (r % t != 0).then(|| (pr[k], sigma(pr[z + k])));
            f(r * z2 + k, qr[k], qr[z + k], prior);
        }
    }
}

impl CustomOp2 for KlOp {
    fn name(&self) -> &'static str {
        "gaussian-kl"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let _time = crate::blocks::timing::span(self.name(), false);
        let (q, p) = (slice(s1, l1, "q")?, slice(s2, l2, "p")?);
        let (_, t, z2) = l1.shape().dims3()?;
        let mut kl = 0.0f64;
        each(q, p, t, z2 / 2, |_, mu, s, prior| {
            let v = match prior {
                None => -s.ln() + 0.5 * (s * s + mu * mu) - 0.5,
                Some((mp, sp)) => {
                    let dm = mu - mp;
                    sp.ln() - s.ln() + (s * s + dm * dm) / (2.0 * sp * sp) - 0.5
                }
            };
            kl += v as f64;
        });
        Ok((CpuStorage::F32(vec![kl as f32]), Shape::from(())))
    }

    fn bwd(
        &self,
        q: &Tensor,
        p: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let _time = crate::blocks::timing::span(self.name(), true);
        let gk = grad.to_scalar::<f32>()?;
        let (_, t, z2) = q.dims3()?;
        let z = z2 / 2;
        let n = q.elem_count();
        let (mut dq, mut dp) = (vec![0.0f32; n], vec![0.0f32; n]);
        with_values(q, |qv| {
            with_values(p, |pv| {
                each(qv, pv, t, z, |i, mu, s, prior| match prior {
                    None => {
                        dq[i] = gk * mu;
                        dq[i + z] = gk * (s - 1.0 / s);
                    }
                    Some((mp, sp)) => {
                        let dm = mu - mp;
                        let isp2 = 1.0 / (sp * sp);
                        dq[i] = gk * dm * isp2;
                        dq[i + z] = gk * (s * isp2 - 1.0 / s);
                        dp[i] = -gk * dm * isp2;
                        dp[i + z] = gk * (1.0 / sp - (s * s + dm * dm) * isp2 / sp) * dsigma(sp);
                    }
                });
                Ok(())
            })
        })?;
        Ok((
            Some(tensor(dq, q.dims(), q)?),
            Some(tensor(dp, p.dims(), p)?),
        ))
    }
}
