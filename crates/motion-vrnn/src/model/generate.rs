//! Sampling ([`MotionModel::sample`]): frames drawn from the prior, each
//! fed back, after real start frames read through the posterior.

use super::*;

/// Generation between two frames ([`Vrnn::generator`]): the recurrence's
/// state, the filters' last values, the seam and the last frame made. Each
/// [`Generator::next`] makes one frame per sequence and feeds it back.
/// It holds the model's weights detached from the graph: what it
/// makes keeps no graph, so a long motion holds only its state.
pub struct Generator {
    m: Vrnn,
    steps: Steps,
    /// The real start frames `[B, K, input]` (features only), if any.
    start: Option<Tensor>,
    /// The condition, paced ([`Config::paced`]), its rows
    /// ([`Vrnn::rows`]) and their parts.
    cond: Option<Tensor>,
    rows: Option<Tensor>,
    bias: Option<Bias>,
    /// Bone lengths `[B, 18]` the frames are placed with.
    bones: Option<Tensor>,
    h: Tensor,
    cell: Tensor,
    zf: Option<Tensor>,
    of: Option<Tensor>,
    /// The last start frame's pose minus the decoder's ([`SEAM_FRAMES`]).
    seam: Option<Tensor>,
    last: Option<Tensor>,
    step: usize,
}

impl Vrnn {
    /// A [`Generator`] of `batch` sequences, after the real frames `start:
    /// [B, K, input (+ CONTROL)]` (read through the posterior, their
    /// control ignored) and with the condition `cond` (`[B, ·]`, as
    /// [`MotionModel::sample`] takes it).
    pub fn generator(
        &self,
        start: Option<&Tensor>,
        cond: Option<&Tensor>,
        batch: usize,
    ) -> Result<Generator> {
        let dev = self.w_hh.device();
        let start = start
            .map(|s| self.split_control(s))
            .transpose()?
            .map(|s| s.0);
        // Bone lengths: the start frames' own skeleton, else the training
        // set's mean skeleton.
        let bones = match &start {
            Some(s) if s.dim(1)? > 0 => self
                .window_bones(s)?
                .map(|l| l.narrow(1, 0, 1)?.squeeze(1))
                .transpose()?,
            _ => self.mean_bones(batch, dev)?,
        };
        let h = Tensor::zeros((batch, self.config.hidden), DType::F32, dev)?;
        let m = self.detached();
        let mut g = Generator {
            steps: Steps::new(&m)?,
            m,
            start,
            cond: None,
            rows: None,
            bias: None,
            bones,
            cell: h.clone(),
            h,
            zf: None,
            of: None,
            seam: None,
            last: None,
            step: 0,
        };
        g.set_condition(cond)?;
        Ok(g)
    }

    /// [`MotionModel::steer`]; [`MotionModel::sample`] with the control
    /// left free.
    pub(super) fn generate(
        &self,
        eps: &Tensor,
        start: Option<&Tensor>,
        cond: Option<&Tensor>,
        control: &mut Control,
    ) -> Result<Tensor> {
        let (t, b, _) = eps.dims3()?;
        let mut g = self.generator(start, cond, b)?;
        let mut frames = Vec::with_capacity(t);
        for step in 0..t {
            let asked = control(step, &frames)?;
            frames.push(g.next(&eps.get(step)?, asked.as_ref())?);
        }
        Tensor::stack(&frames, 1)
    }
}

impl Generator {
    /// The index of the next frame (the start frames count).
    pub fn step(&self) -> usize {
        self.step
    }

    /// Asks for another condition from the next frame on (`[B, ·]` as
    /// [`Vrnn::generator`] takes it; its pace still read from the start
    /// frames).
    pub fn set_condition(&mut self, cond: Option<&Tensor>) -> Result<()> {
        self.cond = self.m.config.paced(cond, self.start.as_ref())?;
        self.rows = self.m.rows(self.cond.as_ref(), None)?;
        self.bias = self
            .rows
            .as_ref()
            .map(|e| self.m.split(e, None))
            .transpose()?;
        Ok(())
    }

    /// The next frame `[B, input]` (normalised) with noise `e: [B, latent]`
    /// and the control `ctl: [B, CONTROL]` asked for it (None: left free):
    /// a start frame while there are any, then a frame drawn from the prior.
    pub fn next(&mut self, e: &Tensor, ctl: Option<&Tensor>) -> Result<Tensor> {
        let (m, c, step) = (&self.m, &self.m.config, self.step);
        let k = self.start.as_ref().map_or(Ok(0), |s| s.dim(1))?;
        // A given control asks for its own pace ([`Config::control_pace`]).
        let asked = match (ctl, &self.cond) {
            (Some(ctl), Some(cond)) => {
                let rows = m.rows(Some(&c.control_pace(cond, ctl)?), None)?;
                Some(m.step_bias(rows.as_ref(), ctl)?)
            }
            (Some(ctl), _) => Some(m.step_bias(self.rows.as_ref(), ctl)?),
            (None, _) => None,
        };
        let (st, bias) = (&self.steps, asked.as_ref().or(self.bias.as_ref()));
        let (rho, rho_out) = (c.parts.latent_filter, c.parts.output_filter);
        // A real start frame is read through the posterior; later frames
        // draw z from the prior (N(0, I) at the first step).
        let (real, z) = match self.start.as_ref().filter(|_| step < k) {
            Some(s) => {
                let x = s.narrow(1, step, 1)?.squeeze(1)?;
                let feat = m.features(&x)?;
                let z = draw(&st.posterior(&feat, &self.h, bias)?, e, c.latent)?;
                (Some((x, feat)), z)
            }
            None => {
                let e = match c.parts.temperature {
                    Some(tau) => (e * tau)?,
                    None => e.clone(),
                };
                (None, st.prior_draw(&self.h, e, step == 0, bias)?)
            }
        };
        let zd = step_filter(&self.zf, z.clone(), rho)?;
        // The decoder runs on start frames too, so its output filter has
        // the history it has in training.
        let o = step_filter(&self.of, m.decode_raw(&zd, &self.h, bias)?, rho_out)?;
        let (x, feat) = match real {
            Some(r) => {
                if step + 1 == k {
                    self.seam = Some(m.pose_offset(&r.0, &o)?);
                }
                r
            }
            None => {
                let eased = match &self.seam {
                    Some(d) if step - k < SEAM_FRAMES => (&o + (d * seam_weight(step - k))?)?,
                    _ => o.clone(),
                };
                let mut x = m.finish(&eased, self.bones.as_ref())?;
                if let (Some(prev), Some(l)) = (self.last.as_ref(), m.contact_logits(&o)?) {
                    let l = match c.parts.contact_sharpness {
                        Some(k) => (l * k)?,
                        None => l,
                    };
                    x = m.lock_step(Some(prev), &x, &l)?;
                }
                let feat = m.features(&x)?;
                (x, feat)
            }
        };
        self.zf = Some(zd);
        self.of = Some(o);
        (self.h, self.cell) = st.advance((&feat, &z), &self.h, &self.cell, bias)?;
        self.last = Some(x.clone());
        self.step += 1;
        Ok(x)
    }
}

impl Vrnn {
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
