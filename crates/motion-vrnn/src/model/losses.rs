//! [`MotionModel`] for [`Vrnn`]: the training losses and reconstruction.

use super::*;

/// The frames a window's pace is read from: its first [`PACE_FRAMES`], the
/// context generation reads its pace from, so that training asks for the
/// pace sampling asks for.
fn context_of(x: &Tensor) -> Result<Tensor> {
    x.narrow(1, 0, x.dim(1)?.min(PACE_FRAMES))
}

impl MotionModel for Vrnn {
    fn config(&self) -> &Config {
        &self.config
    }

    fn losses(
        &self,
        x: &Tensor,
        eps: &Tensor,
        feed: Option<&Tensor>,
        cond: Option<&Tensor>,
    ) -> Result<Losses> {
        let (x, ctl) = self.split_control(x)?;
        let x = &x;
        let b = x.dim(0)? as f64;
        let eps = eps.transpose(0, 1)?.contiguous()?;
        let lengths = self.window_bones(x)?;
        let feat = self.features(x)?;
        let bias = self
            .bias(cond, Some(&context_of(x)?), ctl.as_ref())?
            .map(|b| b.over_time())
            .transpose()?;
        let bias = bias.as_ref();
        let (fed, scan) = match feed {
            Some(mask) => {
                // The prior's draws at the sampling temperature where asked;
                // the posterior's noise as is.
                let e = self.prior_noise(&eps)?;
                let i = Feed {
                    x,
                    feat: &feat,
                    eps: &eps,
                    e: &e,
                    mask,
                    lengths: lengths.as_ref(),
                    bias,
                };
                let (fed, scan) = if self.config.parts.rollout_gradient {
                    self.fed_back(&i)?
                } else {
                    let (b, detached) = (bias.map(Bias::detached), feat.detach());
                    let fed = self.detached().fed_back(&Feed {
                        feat: &detached,
                        bias: b.as_ref(),
                        ..i
                    })?;
                    (fed.0, None)
                };
                (Some(fed), scan)
            }
            None => (None, None),
        };
        // The recurrence that read the fed frames: the fused rollout's own
        // where it gives it, else run here.
        let s = match scan {
            Some(s) => s,
            None => self.scan(&feat, fed.as_ref(), &eps, bias)?,
        };
        let p = stacked(&self.prior[0], &self.prior[1])?.forward(&s.h, Act::None)?;
        let p = plus(p, bias.map(|b| &b.prior))?;
        let kl = gaussian_kl(&s.q, &p)?;
        let (x_hat, logits) = self.decode(&s.z, &s.h, lengths.as_ref(), bias)?;
        let recon = squared_error(&x_hat, x)?;
        let mut extra = Tensor::zeros((), DType::F32, x.device())?;
        if let (Some(body), w) = (&self.config.body, self.config.parts.feet) {
            if w > 0.0 {
                extra = (extra + (feet::foot_slide(&x_hat, x, &body.stats())? * (w / b))?)?;
            }
        }
        if let (Some(body), Some(l)) = (&self.config.body, &logits) {
            extra = (extra + (feet::contact_loss(l, x, &body.stats())? / b)?)?;
        }
        if let Some(w) = self.config.parts.root_weight {
            let root = |t: &Tensor| t.narrow(2, ROOT_FEATURES.start, ROOT_FEATURES.len());
            extra = (extra + (squared_error(&root(&x_hat)?, &root(x)?)? * ((w - 1.0) / b))?)?;
        }
        if let (Some(w), Some(fed), Some(mask), Some(body)) =
            (self.config.parts.fed_speed, &fed, feed, &self.config.body)
        {
            extra = (extra + (fed_speed_loss(fed, x, mask, &body.stats())? * (w / b))?)?;
        }
        Ok(Losses {
            recon: (recon / b)?,
            kl: (kl / b)?,
            extra,
        })
    }

    fn reconstruct(&self, x: &Tensor, cond: Option<&Tensor>) -> Result<Tensor> {
        let (x, ctl) = self.split_control(x)?;
        let x = &x;
        let (b, t, _) = x.dims3()?;
        let zero = Tensor::zeros((b, t, self.config.latent), DType::F32, x.device())?;
        let bias = self
            .bias(cond, Some(&context_of(x)?), ctl.as_ref())?
            .map(|b| b.over_time())
            .transpose()?;
        // With ε = 0 the posterior sample is its mean.
        let s = self.scan(&self.features(x)?, None, &zero, bias.as_ref())?;
        let lengths = self.window_bones(x)?;
        Ok(self.decode(&s.z, &s.h, lengths.as_ref(), bias.as_ref())?.0)
    }

    fn sample(
        &self,
        eps: &Tensor,
        start: Option<&Tensor>,
        cond: Option<&Tensor>,
    ) -> Result<Tensor> {
        self.generate(eps, start, cond, &mut |_, _| Ok(None))
    }

    fn steer(
        &self,
        eps: &Tensor,
        start: Option<&Tensor>,
        cond: Option<&Tensor>,
        control: &mut Control,
    ) -> Result<Tensor> {
        self.generate(eps, start, cond, control)
    }
}
