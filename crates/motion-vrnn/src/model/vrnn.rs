//! [`Vrnn`]: its layers, `new(vb)`, the condition's rows, the recurrence
//! over whole sequences and the decoder.

use super::*;

/// A dense layer's parameters.
#[derive(Clone, Debug)]
pub(super) struct Lin {
    pub(super) w: Tensor,
    pub(super) b: Tensor,
}

impl Lin {
    pub(super) fn new(inp: usize, out: usize, vb: VarBuilder) -> Result<Self> {
        Ok(Lin {
            w: vb.get((out, inp), "weight")?,
            b: vb.get(out, "bias")?,
        })
    }

    pub(super) fn forward(&self, x: &Tensor, act: Act) -> Result<Tensor> {
        linear(x, &self.w, &self.b, act)
    }
}

/// Mean and standard-deviation heads of a Gaussian, applied as one layer
/// (`[μ | logit σ]`).
pub(super) fn stacked(mean: &Lin, std: &Lin) -> Result<Lin> {
    Ok(Lin {
        w: Tensor::cat(&[&mean.w, &std.w], 0)?,
        b: Tensor::cat(&[&mean.b, &std.b], 0)?,
    })
}

/// The model.
#[derive(Clone, Debug)]
pub struct Vrnn {
    pub(super) config: Config,
    pub(super) phi_x: [Lin; 2],
    pub(super) prior: [Lin; 2],
    pub(super) encoder: [Lin; 2],
    pub(super) decoder: [Lin; 3],
    pub(super) w_ih: Tensor,
    pub(super) w_hh: Tensor,
    pub(super) b_ih: Tensor,
    pub(super) b_hh: Tensor,
    /// The condition table `[categories + 1, 2Z + 4H + 2Z + d1]`: row 0 is
    /// "no category", row `k` the `k`-th of [`Config::categories`]; each row
    /// is added to the pre-activations of the posterior and the LSTM gates,
    /// of the prior and of the decoder's first layer ([`Bias`]). None in an
    /// unconditioned model.
    pub(super) cond: Option<Tensor>,
    /// The control's weights `[CONTROL, 2Z + 4H + 2Z + d1]` ([`Parts::control`]):
    /// each frame's control times them is added to that frame's rows of the
    /// condition ([`Vrnn::bias`]). None without the control.
    pub(super) control: Option<Tensor>,
}

/// One sequence's row of the condition table, cut into what it is added to
/// (`[B or 1, ·]` each; `[B, T, ·]` with the control).
#[derive(Clone)]
pub(super) struct Bias {
    /// The recurrence's per-row input: posterior `2Z`, then gates `4H`.
    pub(super) pre: Tensor,
    /// The prior's `[μ | logit σ]`.
    pub(super) prior: Tensor,
    /// The decoder's first layer, before its ReLU.
    pub(super) decoder: Tensor,
    /// With rows per frame, `pre`'s two parts (posterior, gates), so the
    /// recurrence adds each without slicing `pre`.
    pub(super) parts: Option<[Tensor; 2]>,
    /// With rows per frame, every part as it was made, one `[B, T, pre |
    /// prior | decoder]` tensor the other fields are slices of.
    pub(super) all: Option<Tensor>,
}

impl Bias {
    /// The same rows detached from the graph (for the feed rounds).
    pub(super) fn detached(&self) -> Bias {
        Bias {
            pre: self.pre.detach(),
            prior: self.prior.detach(),
            decoder: self.decoder.detach(),
            parts: self
                .parts
                .as_ref()
                .map(|p| p.each_ref().map(Tensor::detach)),
            all: self.all.as_ref().map(Tensor::detach),
        }
    }

    /// The same rows for sequences `[B, T, ·]` (`[B, 1, ·]`, or as they
    /// are where they are one per frame already: a model with the control).
    pub(super) fn over_time(&self) -> Result<Bias> {
        if self.per_frame() {
            return Ok(self.clone());
        }
        Ok(Bias {
            pre: self.pre.unsqueeze(1)?,
            prior: self.prior.unsqueeze(1)?,
            decoder: self.decoder.unsqueeze(1)?,
            parts: None,
            all: None,
        })
    }

    /// One row per frame (`[B, T, ·]`), not per sequence.
    pub(super) fn per_frame(&self) -> bool {
        self.pre.rank() == 3 && self.pre.dim(1).is_ok_and(|t| t > 1)
    }

    /// Step `t`'s rows of [`Bias::over_time`]'s, one per sequence.
    pub(super) fn at_step(&self, t: usize) -> Result<Bias> {
        let row = |v: &Tensor| {
            let k = if v.dim(1)? > 1 { t } else { 0 };
            v.narrow(1, k, 1)?.squeeze(1)
        };
        Ok(Bias {
            pre: row(&self.pre)?,
            prior: row(&self.prior)?,
            decoder: row(&self.decoder)?,
            parts: None,
            all: None,
        })
    }
}

/// `x` plus the bias where there is one.
pub(super) fn plus(x: Tensor, bias: Option<&Tensor>) -> Result<Tensor> {
    match bias {
        Some(b) => add_rows(&x, b, Act::None),
        None => Ok(x),
    }
}

/// What the recurrence gives per row.
pub(super) struct Scan {
    /// LSTM state before the step `[B, T, H]`.
    pub(super) h: Tensor,
    /// Posterior `[μ | σ]`, `[B, T, 2Z]`.
    pub(super) q: Tensor,
    /// Posterior sample `[B, T, Z]`.
    pub(super) z: Tensor,
}

impl Vrnn {
    /// Build the model; variables are created through `vb` (the names of
    /// PyTorch's `nn.Linear` and `nn.LSTM`).
    pub fn new(config: &Config, vb: VarBuilder) -> Result<Self> {
        let c = config;
        let [e1, e2] = c.extractor;
        let [d1, d2] = c.decoder;
        let needs_body = c.parts.skeleton || c.parts.feet > 0.0 || c.parts.foot_lock;
        if needs_body && (c.input != 1 + 3 * BONES + 3 || c.body.is_none()) {
            candle_core::bail!("the skeleton and feet parts need the 58 features and the training set's statistics (Config::fit_to)");
        }
        for (what, rho) in [
            ("latent_filter", c.parts.latent_filter),
            ("output_filter", c.parts.output_filter),
        ] {
            if !(0.0..1.0).contains(&rho) {
                candle_core::bail!("{what} must be in [0, 1), got {rho}");
            }
        }
        if !(0.0..=1.0).contains(&c.parts.self_feed) {
            candle_core::bail!("self_feed must be in [0, 1], got {}", c.parts.self_feed);
        }
        if c.parts.pace && (c.categories.is_empty() || PACE_FEATURES.iter().any(|&f| f >= c.input))
        {
            candle_core::bail!(
                "the pace part needs a model conditioned on the category and the 58 features"
            );
        }
        positive("kl_weight", c.parts.kl_weight)?;
        positive("temperature", c.parts.temperature)?;
        positive("fed speed weight", c.parts.fed_speed)?;
        positive("root weight", c.parts.root_weight)?;
        if c.parts.fed_speed.is_some() && c.body.is_none() {
            candle_core::bail!(
                "the fed speed loss needs the skeleton's statistics (a skeletal model)"
            );
        }
        if c.parts.control && (c.categories.is_empty() || c.body.is_none()) {
            candle_core::bail!(
                "the control needs a model conditioned on the category, with the training set's statistics"
            );
        }
        if c.parts.rollout_gradient && c.parts.rounds() != 0 {
            candle_core::bail!(
                "the gradient through the rollout needs feeding back to every depth (feed_rounds 0, the minute preset's)"
            );
        }
        let gaussian = |input: usize, vb: VarBuilder| -> Result<[Lin; 2]> {
            Ok([
                Lin::new(input, c.latent, vb.pp("mean"))?,
                Lin::new(input, c.latent, vb.pp("std"))?,
            ])
        };
        let rnn = vb.pp("rnn");
        let (h4, lstm_in) = (4 * c.hidden, e2 + c.latent);
        Ok(Vrnn {
            config: c.clone(),
            phi_x: [
                Lin::new(c.input, e1, vb.pp("phi_x.0"))?,
                Lin::new(e1, e2, vb.pp("phi_x.1"))?,
            ],
            prior: gaussian(c.hidden, vb.pp("prior"))?,
            encoder: gaussian(e2 + c.hidden, vb.pp("encoder"))?,
            decoder: [
                Lin::new(c.latent + c.hidden, d1, vb.pp("decoder.0"))?,
                Lin::new(d1, d2, vb.pp("decoder.1"))?,
                Lin::new(d2, c.input + contacts(c), vb.pp("decoder.2"))?,
            ],
            w_ih: rnn.get((h4, lstm_in), "weight_ih_l0")?,
            w_hh: rnn.get((h4, c.hidden), "weight_hh_l0")?,
            b_ih: rnn.get(h4, "bias_ih_l0")?,
            b_hh: rnn.get(h4, "bias_hh_l0")?,
            cond: match c.categories.len() {
                0 => None,
                n => Some(vb.get_with_hints(
                    (n + 1 + c.pace_columns(), 4 * c.latent + h4 + d1),
                    COND_WEIGHT,
                    candle_nn::Init::Const(0.0),
                )?),
            },
            control: match c.parts.control {
                false => None,
                true => Some(vb.get_with_hints(
                    (motion_steer::CONTROL, 4 * c.latent + h4 + d1),
                    CONTROL_WEIGHT,
                    candle_nn::Init::Const(0.0),
                )?),
            },
        })
    }

    /// The condition's bias rows for `cond` ([`Config::condition`]; None: row
    /// 0, "no category"), with the pace of `frames` where the model reads
    /// one ([`Config::paced`]), and with the control `ctl` where given
    /// ([`Vrnn::split`]); None for an unconditioned model.
    pub(super) fn bias(
        &self,
        cond: Option<&Tensor>,
        frames: Option<&Tensor>,
        ctl: Option<&Tensor>,
    ) -> Result<Option<Bias>> {
        self.rows(cond, frames)?
            .map(|e| self.split(&e, ctl))
            .transpose()
    }

    /// The condition's rows of [`Vrnn::bias`] as one `[B or 1, 2Z + 4H +
    /// 2Z + d1]` tensor, before they are cut into [`Bias`].
    pub(super) fn rows(
        &self,
        cond: Option<&Tensor>,
        frames: Option<&Tensor>,
    ) -> Result<Option<Tensor>> {
        let cond = self.config.paced(cond, frames)?;
        let cond = cond.as_ref();
        let Some(table) = &self.cond else {
            if cond.is_some() {
                candle_core::bail!("this model was trained without categories; train one with --condition category");
            }
            return Ok(None);
        };
        match cond {
            // The fused product: its backward sums over the rows in
            // blocks that do not depend on the CPU (`blocks::kernels::mm`),
            // where candle's `matmul` leaves that to the cache size.
            Some(w) => {
                let none = Tensor::zeros(table.dim(1)?, DType::F32, table.device())?;
                linear(w, &table.t()?, &none, Act::None).map(Some)
            }
            None => table.narrow(0, 0, 1).map(Some),
        }
    }

    /// The rows `e` ([`Vrnn::rows`]) cut into what they are added to; with
    /// a control `ctl` (`[B, T, CONTROL]`, or one step's `[B, CONTROL]`),
    /// plus its share ([`Vrnn::frame_bias`]; an error for a model without
    /// the control).
    pub(super) fn split(&self, e: &Tensor, ctl: Option<&Tensor>) -> Result<Bias> {
        if let Some(k) = ctl {
            return self.frame_bias(e, k);
        }
        let c = &self.config;
        let (pre, prior) = (2 * c.latent + 4 * c.hidden, 2 * c.latent);
        Ok(Bias {
            pre: e.narrow(1, 0, pre)?,
            prior: e.narrow(1, pre, prior)?,
            decoder: e.narrow(1, pre + prior, c.decoder[0])?,
            parts: None,
            all: None,
        })
    }

    /// The same model with every weight detached from the graph: what runs
    /// through it keeps no graph and no buffers for a backward pass (the
    /// feed rounds, whose output no gradient flows through, and every
    /// [`Generator`]).
    pub(super) fn detached(&self) -> Vrnn {
        let lin = |l: &Lin| Lin {
            w: l.w.detach(),
            b: l.b.detach(),
        };
        Vrnn {
            config: self.config.clone(),
            phi_x: self.phi_x.each_ref().map(lin),
            prior: self.prior.each_ref().map(lin),
            encoder: self.encoder.each_ref().map(lin),
            decoder: self.decoder.each_ref().map(lin),
            w_ih: self.w_ih.detach(),
            w_hh: self.w_hh.detach(),
            b_ih: self.b_ih.detach(),
            b_hh: self.b_hh.detach(),
            cond: self.cond.as_ref().map(Tensor::detach),
            control: self.control.as_ref().map(Tensor::detach),
        }
    }

    pub(super) fn dims(&self) -> ScanDims {
        ScanDims {
            hidden: self.config.hidden,
            latent: self.config.latent,
        }
    }

    pub(super) fn features(&self, x: &Tensor) -> Result<Tensor> {
        let a = self.phi_x[0].forward(x, Act::Relu)?;
        self.phi_x[1].forward(&a, Act::Relu)
    }

    /// The recurrence over whole sequences with noise `eps: [B, T, Z]`,
    /// from the features `feat = features(x)` of `x: [B, T, input]`; the LSTM
    /// reads `fed` instead of `x` where given (scheduled sampling), the
    /// posterior always reads `x`.
    pub(super) fn scan(
        &self,
        feat: &Tensor,
        fed: Option<&Tensor>,
        eps: &Tensor,
        bias: Option<&Bias>,
    ) -> Result<Scan> {
        let c = &self.config;
        let (e2, h, z) = (c.extractor[1], c.hidden, c.latent);
        // What does not depend on the recurrence, for all rows at once: the
        // x'' halves of the posterior and of the LSTM input product.
        let enc = stacked(&self.encoder[0], &self.encoder[1])?;
        let (enc_x, gates_x) = (
            Lin {
                w: enc.w.narrow(1, 0, e2)?,
                b: enc.b.clone(),
            },
            Lin {
                w: self.w_ih.narrow(1, 0, e2)?,
                b: (&self.b_ih + &self.b_hh)?,
            },
        );
        let pre = match fed {
            None => vec![Lin {
                w: Tensor::cat(&[&enc_x.w, &gates_x.w], 0)?,
                b: Tensor::cat(&[&enc_x.b, &gates_x.b], 0)?,
            }
            .forward(feat, Act::None)?],
            Some(f) => vec![
                enc_x.forward(feat, Act::None)?,
                gates_x.forward(&self.features(f)?, Act::None)?,
            ],
        };
        let w = Tensor::cat(
            &[
                enc.w.narrow(1, e2, h)?.flatten_all()?,
                self.w_ih.narrow(1, e2, z)?.flatten_all()?,
                self.w_hh.flatten_all()?,
            ],
            0,
        )?;
        // Rows per frame (the control) join the products; rows per
        // sequence are the recurrence's to add.
        let (pre, rows) = match bias.filter(|b| b.per_frame()) {
            Some(b) => match (pre.as_slice(), &b.parts) {
                ([one], _) => (vec![(one + &b.pre)?], None),
                ([e, g], Some([be, bg])) => (vec![(e + be)?, (g + bg)?], None),
                _ => candle_core::bail!("scan: rows per frame without their parts"),
            },
            None => (pre, bias.map(|b| &b.pre)),
        };
        let pre: Vec<&Tensor> = pre.iter().collect();
        let s = latent_lstm(&pre, rows, eps, &w, self.dims())?;
        Ok(Scan {
            h: s.narrow(D::Minus1, 0, h)?,
            q: s.narrow(D::Minus1, h, 2 * z)?,
            z: s.narrow(D::Minus1, h + 2 * z, z)?,
        })
    }

    /// The decoder's layers over rows `[…, Z]` and `[…, H]` (before the
    /// output filter and the skeleton).
    pub(super) fn decode_raw(&self, z: &Tensor, h: &Tensor, bias: Option<&Bias>) -> Result<Tensor> {
        let u = Tensor::cat(&[z, h], D::Minus1)?;
        let a = match bias {
            Some(b) => add_rows(
                &self.decoder[0].forward(&u, Act::None)?,
                &b.decoder,
                Act::Relu,
            )?,
            None => self.decoder[0].forward(&u, Act::Relu)?,
        };
        let b = self.decoder[1].forward(&a, Act::Relu)?;
        self.decoder[2].forward(&b, Act::None)
    }

    /// Decoder output (filtered) → features: through the skeleton when it
    /// is on, with bone lengths `lengths: […, 18]`.
    pub(super) fn finish(&self, o: &Tensor, lengths: Option<&Tensor>) -> Result<Tensor> {
        let o = o.narrow(D::Minus1, 0, self.config.input)?;
        match (&self.config.body, lengths) {
            (Some(body), Some(l)) if self.config.parts.skeleton => self.place(&o, body, l),
            _ => Ok(o),
        }
    }

    /// The contact logits of decoder outputs (foot-lock part).
    pub(super) fn contact_logits(&self, o: &Tensor) -> Result<Option<Tensor>> {
        match contacts(&self.config) {
            0 => Ok(None),
            n => o.narrow(D::Minus1, self.config.input, n).map(Some),
        }
    }

    /// Foot-locked root velocity over sequences: frames 1.. of `x_hat`
    /// (normalised `[B, T, input]`) get the velocity that keeps the feet of
    /// frame `t − 1` in place, weighted by the contact probabilities
    /// (`logits: [B, T, 2]`).
    pub(super) fn lock_sequence(&self, x_hat: &Tensor, logits: &Tensor) -> Result<Tensor> {
        match &self.config.body {
            Some(body) => feet::foot_lock(x_hat, logits, &body.stats()),
            None => Ok(x_hat.clone()),
        }
    }

    /// The whole decoder over sequences `[B, T, ·]`: latent filter, layers,
    /// output filter, skeleton, foot lock. Returns the features and, with the
    /// foot lock, the contact logits.
    pub(super) fn decode(
        &self,
        z: &Tensor,
        h: &Tensor,
        lengths: Option<&Tensor>,
        bias: Option<&Bias>,
    ) -> Result<(Tensor, Option<Tensor>)> {
        let o = self.decode_raw(&self.filtered(z)?, h, bias)?;
        let rho = self.config.parts.output_filter;
        let o = if rho > 0.0 {
            filter::smooth(&o, rho)?
        } else {
            o
        };
        let x_hat = self.finish(&o, lengths)?;
        match self.contact_logits(&o)? {
            Some(l) => Ok((self.lock_sequence(&x_hat, &l)?, Some(l))),
            None => Ok((x_hat, None)),
        }
    }

    /// Skeleton part: decoder outputs (the 58 normalised features, as in
    /// the paper) → each decoded bone (joint minus parent) rescaled to its
    /// length by forward kinematics → the 58 normalised features
    /// ([`blocks::skeleton::place`]).
    pub(super) fn place(&self, o: &Tensor, body: &Body, lengths: &Tensor) -> Result<Tensor> {
        place(o, lengths, &body.mean, &body.std)
    }

    /// The decoder's latent: `z` through the causal filter when it is on.
    pub(super) fn filtered(&self, z: &Tensor) -> Result<Tensor> {
        let rho = self.config.parts.latent_filter;
        if rho > 0.0 {
            filter::smooth(z, rho)
        } else {
            Ok(z.clone())
        }
    }

    /// Generate in runs of at most `frames` new frames ([`Parts::restart`];
    /// None or 0: one run).
    pub fn set_restart(&mut self, frames: Option<usize>) {
        self.config.parts.restart = frames.filter(|&f| f > 0);
    }

    /// Sample at temperature `t` ([`Parts::temperature`]; None: 1) instead
    /// of the one the model was trained with.
    pub fn set_temperature(&mut self, t: Option<f64>) -> Result<()> {
        positive("temperature", t)?;
        self.config.parts.temperature = t;
        Ok(())
    }

    /// Generate with the foot lock's contact logits times `k`
    /// ([`Parts::contact_sharpness`]; None: 1) instead of the model's own.
    pub fn set_contact_sharpness(&mut self, k: Option<f64>) -> Result<()> {
        positive("contact sharpness", k)?;
        self.config.parts.contact_sharpness = k;
        Ok(())
    }

    /// Each window's bone lengths (mean over its frames) for every row:
    /// `[B, T, 18]`, or `None` without the skeleton part.
    pub(super) fn window_bones(&self, x: &Tensor) -> Result<Option<Tensor>> {
        let Some(body) = self
            .config
            .body
            .as_ref()
            .filter(|_| self.config.parts.skeleton)
        else {
            return Ok(None);
        };
        let (b, t, f) = x.dims3()?;
        let v = x.flatten_all()?.to_vec1::<f32>()?;
        let mut out = vec![0.0f32; b * t * BONES];
        let raw = |row: &[f32], k: usize| row[k] * body.std[k] + body.mean[k];
        let mut joints = [0.0f32; 3 * BONES];
        for (w, window) in v.chunks_exact(t * f).enumerate() {
            let mut mean = [0.0f64; BONES];
            for row in window.chunks_exact(f) {
                for (k, j) in joints.iter_mut().enumerate() {
                    *j = raw(row, 1 + k);
                }
                let lengths = row_bone_lengths(raw(row, 0), &joints);
                for (m, l) in mean.iter_mut().zip(&lengths) {
                    *m += *l as f64;
                }
            }
            for o in out[w * t * BONES..(w + 1) * t * BONES].chunks_exact_mut(BONES) {
                for (o, m) in o.iter_mut().zip(&mean) {
                    *o = (m / t as f64) as f32;
                }
            }
        }
        Tensor::from_vec(out, (b, t, BONES), x.device()).map(Some)
    }
}

/// An error unless the optional setting `what` is positive and finite.
pub(super) fn positive(what: &str, v: Option<f64>) -> Result<()> {
    match v {
        Some(w) if !(w.is_finite() && w > 0.0) => {
            candle_core::bail!("{what} must be positive, got {w}")
        }
        _ => Ok(()),
    }
}

/// A draw from a Gaussian head's `[μ | logit σ]` (last dimension `2Z`)
/// with noise `e`.
pub(super) fn draw(p: &Tensor, e: &Tensor, latent: usize) -> Result<Tensor> {
    let mu = p.narrow(D::Minus1, 0, latent)?;
    let sigma =
        candle_nn::ops::sigmoid(&p.narrow(D::Minus1, latent, latent)?)?.clamp(SIGMA_MIN, 1.0)?;
    mu + (sigma * e)?
}
