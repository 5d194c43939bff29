//! Sampling ([`MotionModel::sample`]): frames drawn from the prior, each
//! fed back, after real start frames read through the posterior.

use super::*;

impl Vrnn {
    /// [`MotionModel::steer`]; [`MotionModel::sample`] with the control
    /// left free.
    pub(super) fn generate(
        &self,
        eps: &Tensor,
        start: Option<&Tensor>,
        cond: Option<&Tensor>,
        control: &mut Control,
    ) -> Result<Tensor> {
        let c = &self.config;
        let (t, b, _) = eps.dims3()?;
        let dev = eps.device();
        let start = start
            .map(|s| self.split_control(s))
            .transpose()?
            .map(|s| s.0);
        let start = start.as_ref();
        let rows = self.rows(cond, start)?;
        let bias = rows.as_ref().map(|e| self.split(e, None)).transpose()?;
        let free = Steps::new(self, bias.as_ref())?;
        let k = start.map_or(Ok(0), |s| s.dim(1))?;
        // Bone lengths: the start frames' own skeleton, else the training
        // set's mean skeleton.
        let bones = match start {
            Some(s) if k > 0 => self
                .window_bones(s)?
                .map(|l| l.narrow(1, 0, 1)?.squeeze(1))
                .transpose()?,
            _ => self.mean_bones(b, dev)?,
        };
        let (rho, rho_out) = (c.parts.latent_filter, c.parts.output_filter);
        let mut h = Tensor::zeros((b, c.hidden), DType::F32, dev)?;
        let mut cell = h.clone();
        let (mut zf, mut of): (Option<Tensor>, Option<Tensor>) = (None, None);
        let mut frames = Vec::with_capacity(t);
        // The last start frame's pose minus the decoder's ([`SEAM_FRAMES`]).
        let mut seam: Option<Tensor> = None;
        for step in 0..t {
            // The step's control, where one is asked: its rows join the
            // condition's for this step.
            let asked = control(step, &frames)?
                .map(|k| self.step_bias(rows.as_ref(), &k))
                .transpose()?;
            let steered = asked
                .as_ref()
                .map(|a| Steps::new(self, Some(a)))
                .transpose()?;
            let st = steered.as_ref().unwrap_or(&free);
            let e = eps.get(step)?;
            // A real start frame is read through the posterior; later frames
            // draw z from the prior (N(0, I) at the first step).
            let (real, z) = match start.filter(|_| step < k) {
                Some(s) => {
                    let x = s.narrow(1, step, 1)?.squeeze(1)?;
                    let feat = self.features(&x)?;
                    let z = draw(&st.posterior(&feat, &h)?, &e, c.latent)?;
                    (Some((x, feat)), z)
                }
                None => {
                    let e = match c.parts.temperature {
                        Some(tau) => (e * tau)?,
                        None => e,
                    };
                    (None, st.prior_draw(&h, e, step == 0)?)
                }
            };
            let zd = step_filter(&zf, z.clone(), rho)?;
            // The decoder runs on start frames too, so its output filter has
            // the history it has in training.
            let o = step_filter(&of, self.decode_raw(&zd, &h, st.bias)?, rho_out)?;
            let (x, feat) = match real {
                Some(r) => {
                    if step + 1 == k {
                        seam = Some(self.pose_offset(&r.0, &o)?);
                    }
                    r
                }
                None => {
                    let eased = match &seam {
                        Some(d) if step - k < SEAM_FRAMES => (&o + (d * seam_weight(step - k))?)?,
                        _ => o.clone(),
                    };
                    let mut x = self.finish(&eased, bones.as_ref())?;
                    if let (Some(prev), Some(l)) = (frames.last(), self.contact_logits(&o)?) {
                        let l = match c.parts.contact_sharpness {
                            Some(k) => (l * k)?,
                            None => l,
                        };
                        x = self.lock_step(Some(prev), &x, &l)?;
                    }
                    let feat = self.features(&x)?;
                    (x, feat)
                }
            };
            zf = Some(zd);
            of = Some(o);
            (h, cell) = st.advance(&feat, &z, &h, &cell)?;
            frames.push(x);
        }
        Tensor::stack(&frames, 1)
    }

    /// `x − o` over the pose features of a real frame `x: [B, input]` and
    /// the decoder's output `o: [B, ≥ input]` for it (zero on the root
    /// motion, the last three features, and on what `o` has beyond them).
    pub(super) fn pose_offset(&self, x: &Tensor, o: &Tensor) -> Result<Tensor> {
        let (b, width) = o.dims2()?;
        let pose = self.config.input.saturating_sub(3);
        let d = (x.narrow(1, 0, pose)? - o.narrow(1, 0, pose)?)?;
        let rest = Tensor::zeros((b, width - pose), DType::F32, o.device())?;
        Tensor::cat(&[&d, &rest], 1)
    }

    /// The mean skeleton for `b` sequences (sampling): `[b, 18]`.
    pub(super) fn mean_bones(&self, b: usize, device: &Device) -> Result<Option<Tensor>> {
        match self
            .config
            .body
            .as_ref()
            .filter(|_| self.config.parts.skeleton)
        {
            Some(body) => Tensor::new(body.bones.as_slice(), device)?
                .unsqueeze(0)?
                .broadcast_as((b, BONES))?
                .contiguous()
                .map(Some),
            None => Ok(None),
        }
    }
}

/// The weight of the seam's offset `t` frames after the start frames.
pub(super) fn seam_weight(t: usize) -> f64 {
    if t >= SEAM_FRAMES {
        return 0.0;
    }
    0.5 * (1.0 + (std::f64::consts::PI * t as f64 / SEAM_FRAMES as f64).cos())
}
