//! Scheduled sampling: the frames the recurrence reads replaced by the
//! model's own predictions, in rounds, step by step or in the fused
//! rollout; and the fed speed loss.

use super::vrnn::Scan;
use super::*;

/// What feeding back to every depth reads ([`Vrnn::fed_in_sequence`]): the
/// real frames `[B, T, input]`, their features, the posterior's noise and
/// the prior's (`[B, T, Z]`), the mask `[B, T]`, the bone lengths and the
/// condition's rows (over time).
pub(super) struct Feed<'a> {
    pub(super) x: &'a Tensor,
    pub(super) feat: &'a Tensor,
    pub(super) eps: &'a Tensor,
    pub(super) e: &'a Tensor,
    pub(super) mask: &'a Tensor,
    pub(super) lengths: Option<&'a Tensor>,
    pub(super) bias: Option<&'a Bias>,
}

impl Vrnn {
    /// The prior's noise: `eps` at the sampling temperature where rollouts
    /// are drawn at it ([`Parts::rollouts_at_temperature`]), else as is.
    pub(super) fn prior_noise(&self, eps: &Tensor) -> Result<Tensor> {
        match self.config.parts.temperature {
            Some(tau) if self.config.parts.rollouts_at_temperature => eps * tau,
            _ => Ok(eps.clone()),
        }
    }

    /// Each step's one-step prediction drawn from the prior `p` (given the
    /// recurrence's states `h`) with the noise `e`, and decoded, as sampling
    /// makes a frame; the first step is the noise alone (N(0, I)).
    pub(super) fn prior_decoded(
        &self,
        p: &Tensor,
        h: &Tensor,
        e: &Tensor,
        lengths: Option<&Tensor>,
        bias: Option<&Bias>,
    ) -> Result<Tensor> {
        let t = e.dim(1)?;
        let z = draw(p, e, self.config.latent)?;
        let z = if t > 1 {
            Tensor::cat(&[&e.narrow(1, 0, 1)?, &z.narrow(1, 1, t - 1)?], 1)?
        } else {
            e.clone()
        };
        Ok(self.decode(&z, h, lengths, bias)?.0)
    }

    /// Scheduled sampling: `x` with the frames where `mask: [B, T]` is 1
    /// replaced by the model's own one-step prediction, as sampling makes
    /// it (latent drawn from the prior, `N(0, I)` at the first step, with
    /// the same noise; the whole decoder). The state comes from the real
    /// frames in the first round, and from the previous round's frames in
    /// each later one ([`Parts::feed_rounds`]; with 0, to every depth in one
    /// pass: [`Vrnn::fed_in_sequence`]). Training calls it on detached
    /// weights, so no gradient flows through the replacement, but with
    /// [`Parts::rollout_gradient`] on its own. With the recurrence that read
    /// the fed frames where the pass gives it (the fused pass with its
    /// gradient), so the loss need not run it again.
    pub(super) fn fed_back(&self, i: &Feed) -> Result<(Tensor, Option<Scan>)> {
        if self.config.parts.rounds() == 0 {
            // A gradient through the rollout ([`Parts::rollout_gradient`])
            // takes the fused pass with its backward.
            return match (blocks::fused(i.x), self.config.parts.rollout_gradient) {
                (true, false) => Ok((self.fed_fused(i)?, None)),
                (true, true) => self.fed_fused_grad(i).map(|(f, s)| (f, Some(s))),
                (false, _) => Ok((self.fed_in_sequence(i)?, None)),
            };
        }
        let mut fed = self.feed_round(i, None)?.detach();
        for _ in 1..self.config.parts.rounds() {
            fed = self.feed_round(i, Some(&fed))?.detach();
        }
        Ok((fed, None))
    }

    /// One round of feeding back: the recurrence reads `fed` (the real
    /// frames when None), and each masked frame is replaced by the frame
    /// the prior's draw decodes to from the state before it.
    pub(super) fn feed_round(&self, i: &Feed, fed: Option<&Tensor>) -> Result<Tensor> {
        let s = self.scan(i.feat, fed, i.eps, i.bias)?;
        let prior = stacked(&self.prior[0], &self.prior[1])?;
        let p = plus(prior.forward(&s.h, Act::None)?, i.bias.map(|b| &b.prior))?;
        let own = self.prior_decoded(&p, &s.h, i.e, i.lengths, i.bias)?;
        let m = i.mask.unsqueeze(D::Minus1)?.broadcast_as(i.x.shape())?;
        i.x + ((own - i.x)? * &m)?
    }

    /// [`Vrnn::fed_back`] to every depth (`feed_rounds` 0): one pass in
    /// time order, each fed frame predicted from a state that read every
    /// earlier fed frame, as sampling would make it. It gives what rounds
    /// give once there are as many rounds as fed frames in a window, at the
    /// cost of one. `eps`: the posterior's noise, `e`: the prior's.
    pub(super) fn fed_in_sequence(&self, i: &Feed) -> Result<Tensor> {
        let (c, x, lengths) = (&self.config, i.x, i.lengths);
        let t = x.dim(1)?;
        // Everything time-major, so a step's rows are one contiguous slice.
        let steps = |v: &Tensor| v.transpose(0, 1)?.contiguous();
        let (xs, fs, eq, ep) = (steps(x)?, steps(i.feat)?, steps(i.eps)?, steps(i.e)?);
        let ms = steps(&i.mask.unsqueeze(D::Minus1)?)?;
        let ls = lengths.map(steps).transpose()?;
        // The condition's rows, one per sequence (and per step with the
        // control).
        let per_frame = i.bias.is_some_and(Bias::per_frame);
        let bias = i.bias.map(|b| b.at_step(0)).transpose()?;
        let st = Steps::new(self)?;
        let (rho, rho_out) = (c.parts.latent_filter, c.parts.output_filter);
        let mut h = Tensor::zeros((x.dim(0)?, c.hidden), DType::F32, x.device())?;
        let mut cell = h.clone();
        let (mut zf, mut of, mut prev): (Option<Tensor>, Option<Tensor>, Option<Tensor>) =
            (None, None, None);
        let mut fed = Vec::with_capacity(t);
        for step in 0..t {
            let stepped = match i.bias.filter(|_| per_frame && step > 0) {
                Some(b) => Some(b.at_step(step)?),
                None => None,
            };
            let b = stepped.as_ref().or(bias.as_ref());
            let (xt, ft) = (xs.get(step)?, fs.get(step)?);
            // The posterior reads the real frame; its z goes to the LSTM.
            let zq = draw(&st.posterior(&ft, &h, b)?, &eq.get(step)?, c.latent)?;
            // The prior's draw makes the own frame (its noise alone at first).
            let zp = st.prior_draw(&h, ep.get(step)?, step == 0, b)?;
            let zd = step_filter(&zf, zp, rho)?;
            let o = step_filter(&of, self.decode_raw(&zd, &h, b)?, rho_out)?;
            let l = ls.as_ref().map(|l| l.get(step)).transpose()?;
            let mut own = self.finish(&o, l.as_ref())?;
            if let Some(logits) = self.contact_logits(&o)? {
                own = self.lock_step(prev.as_ref(), &own, &logits)?;
            }
            let xf = (&xt + (&own - &xt)?.broadcast_mul(&ms.get(step)?)?)?;
            (h, cell) = st.advance((&self.features(&xf)?, &zq), &h, &cell, b)?;
            (zf, of, prev) = (Some(zd), Some(o), Some(own));
            fed.push(xf);
        }
        Tensor::stack(&fed, 1)
    }

    /// One frame `x: [B, input]` through the foot lock, given its contact
    /// logits: grounded, then locked against the frame before it where
    /// there is one (`prev`). As it is without a body.
    pub(super) fn lock_step(
        &self,
        prev: Option<&Tensor>,
        x: &Tensor,
        logits: &Tensor,
    ) -> Result<Tensor> {
        let Some(body) = &self.config.body else {
            return Ok(x.clone());
        };
        let one = |t: &Tensor| t.unsqueeze(1);
        let g = ground(&one(x)?, &one(logits)?, &body.stats())?;
        match prev {
            Some(p) => lock(&one(p)?, &g, &one(logits)?, &body.stats())?,
            None => g,
        }
        .squeeze(1)
    }

    /// The model's weights as [`rollout::fed`] reads them.
    pub(super) fn rollout_net(&self, lengths: Option<&Tensor>) -> Result<rollout::Net> {
        let c = &self.config;
        let v = |t: &Tensor| t.flatten_all()?.to_vec1::<f32>();
        let dense = |l: &Lin| -> Result<rollout::Dense> {
            let (out, inp) = l.w.dims2()?;
            Ok(rollout::Dense {
                w: v(&l.w)?,
                b: v(&l.b)?,
                inp,
                out,
            })
        };
        let body = c.body.as_ref();
        Ok(rollout::Net {
            hidden: c.hidden,
            latent: c.latent,
            input: c.input,
            phi: [dense(&self.phi_x[0])?, dense(&self.phi_x[1])?],
            encoder: dense(&stacked(&self.encoder[0], &self.encoder[1])?)?,
            prior: dense(&stacked(&self.prior[0], &self.prior[1])?)?,
            decoder: [
                dense(&self.decoder[0])?,
                dense(&self.decoder[1])?,
                dense(&self.decoder[2])?,
            ],
            w_ih: v(&self.w_ih)?,
            w_hh: v(&self.w_hh)?,
            b_gates: v(&(&self.b_ih + &self.b_hh)?)?,
            rho: c.parts.latent_filter as f32,
            rho_out: c.parts.output_filter as f32,
            lock: body
                .filter(|_| contacts(c) > 0)
                .map(|b| FootLockOp::new(&b.stats())),
            place: body
                .filter(|_| c.parts.skeleton && lengths.is_some())
                .map(|b| PlaceOp {
                    mean: b.mean.clone(),
                    std: b.std.clone(),
                }),
        })
    }

    /// The fused pass's inputs ([`rollout::RolloutOp`]) and the
    /// condition's rows packed as it reads them.
    pub(super) fn rollout_op(&self, i: &Feed) -> Result<(rollout::RolloutOp, Tensor)> {
        let (b, t, _) = i.x.dims3()?;
        let v = |t: &Tensor| t.flatten_all()?.to_vec1::<f32>();
        let (cond, widths) = match i.bias {
            Some(bias) => {
                let parts = [&bias.pre, &bias.prior, &bias.decoder];
                let widths = parts.map(|p| p.dim(D::Minus1).unwrap_or(0));
                // Rows per frame: the tensor the parts are slices of.
                let cond = match &bias.all {
                    Some(all) => all.clone(),
                    None => Tensor::cat(&parts, D::Minus1)?,
                };
                (cond, Some(widths))
            }
            None => (Tensor::zeros(1, DType::F32, i.x.device())?, None),
        };
        let op = rollout::RolloutOp {
            net: self.rollout_net(i.lengths)?,
            b,
            t,
            x: v(i.x)?,
            eps: v(i.eps)?,
            e: v(i.e)?,
            mask: v(i.mask)?,
            lengths: i.lengths.map(v).transpose()?,
            cond: widths,
            tape: std::sync::Mutex::new(None),
        };
        Ok((op, cond.contiguous()?))
    }

    /// [`Vrnn::fed_in_sequence`] as one fused block ([`rollout::fed`]).
    pub(super) fn fed_fused(&self, i: &Feed) -> Result<Tensor> {
        let v = |t: &Tensor| t.flatten_all()?.to_vec1::<f32>();
        let (op, cond) = self.rollout_op(i)?;
        let out = op.fed(&v(i.feat)?, &v(&cond)?);
        Tensor::from_vec(out, i.x.shape(), i.x.device())
    }

    /// [`Vrnn::fed_fused`] with the gradient through the fed frames
    /// ([`rollout::RolloutOp`]): of the real frames' features, every weight
    /// and the condition's rows; and the recurrence that read them, as
    /// [`Vrnn::scan`] of the fed frames gives it.
    pub(super) fn fed_fused_grad(&self, i: &Feed) -> Result<(Tensor, Scan)> {
        let flat = |l: &Lin| -> Result<[Tensor; 2]> { Ok([l.w.flatten_all()?, l.b.clone()]) };
        let mut w = Vec::new();
        for l in [
            &self.phi_x[0],
            &self.phi_x[1],
            &stacked(&self.encoder[0], &self.encoder[1])?,
            &stacked(&self.prior[0], &self.prior[1])?,
            &self.decoder[0],
            &self.decoder[1],
            &self.decoder[2],
        ] {
            w.extend(flat(l)?);
        }
        w.extend([
            self.w_ih.flatten_all()?,
            self.w_hh.flatten_all()?,
            (&self.b_ih + &self.b_hh)?,
        ]);
        let w = Tensor::cat(&w, 0)?;
        let (op, cond) = self.rollout_op(i)?;
        let out = i.feat.contiguous()?.apply_op3(&w, &cond, op)?;
        let c = &self.config;
        let (f, h, z) = (c.input, c.hidden, c.latent);
        let part = |from: usize, n: usize| out.narrow(D::Minus1, from, n);
        let scan = Scan {
            h: part(f, h)?,
            q: part(f + h, 2 * z)?,
            z: part(f + h + 2 * z, z)?,
        };
        Ok((part(0, f)?, scan))
    }
}

/// Added to a window's mean speed before [`fed_speed_loss`] takes its
/// logarithm (CMU units a frame; about 0.008 m/s): standing windows are
/// compared without the logarithm of nothing.
pub const FED_SPEED_FLOOR: f64 = 0.005;

/// The fed speed loss of the frames the recurrence read, `fed: [B, T, F]`
/// (real frames where `mask: [B, T]` is 1 replaced by the model's own),
/// against the real `x` (normalised features, `body`'s statistics): per
/// window, the mean over its fed frames of the root's horizontal speed
/// `√(vx² + vz²)` (CMU units a frame), and the real frames' mean at the
/// same frames; the squared difference of their logarithms (each plus
/// [`FED_SPEED_FLOOR`]), so a standing window a third too fast counts as
/// much as a running one, summed and scaled by `T` (so it weighs like a
/// per-frame error). Zero for a window with no fed frame.
pub fn fed_speed_loss(
    fed: &Tensor,
    x: &Tensor,
    mask: &Tensor,
    body: &feet::Stats,
) -> Result<Tensor> {
    let t = fed.dim(1)?;
    let m = mask.unsqueeze(2)?;
    let count = (m.sum_keepdim(1)? + 1e-6)?;
    let speed = |a: &Tensor| -> Result<Tensor> {
        frame_speed(a, body, 1e-8)?
            .broadcast_mul(&m)?
            .sum_keepdim(1)?
            .broadcast_div(&count)
    };
    let log = |a: &Tensor| (speed(a)? + FED_SPEED_FLOOR)?.log();
    (log(fed)? - log(x)?)?.sqr()?.sum_all()? * t as f64
}
