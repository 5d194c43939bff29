//! The recurrence one step at a time ([`Steps`]), for sampling and for
//! feeding back to every depth.

use super::*;

/// One step of the recurrence at a time, for the step loops (sampling,
/// feeding back to every depth): the weights as each step reads them.
pub(super) struct Steps<'a> {
    /// The condition's rows (`[B or 1, ·]`).
    pub(super) bias: Option<&'a Bias>,
    /// The condition's share of the posterior and of the gates.
    pub(super) enc_bias: Option<Tensor>,
    pub(super) gates_bias: Option<Tensor>,
    pub(super) prior: Lin,
    pub(super) encoder: Lin,
    pub(super) gates_in: Lin,
    pub(super) w_hh: Tensor,
    pub(super) no_bias: Tensor,
    pub(super) latent: usize,
}

impl<'a> Steps<'a> {
    pub(super) fn new(m: &Vrnn, bias: Option<&'a Bias>) -> Result<Steps<'a>> {
        let (z, h) = (m.config.latent, m.config.hidden);
        let (enc_bias, gates_bias) = match bias {
            Some(b) => (
                Some(b.pre.narrow(1, 0, 2 * z)?),
                Some(b.pre.narrow(1, 2 * z, 4 * h)?),
            ),
            None => (None, None),
        };
        Ok(Steps {
            bias,
            enc_bias,
            gates_bias,
            prior: stacked(&m.prior[0], &m.prior[1])?,
            encoder: stacked(&m.encoder[0], &m.encoder[1])?,
            gates_in: Lin {
                w: m.w_ih.clone(),
                b: (&m.b_ih + &m.b_hh)?,
            },
            w_hh: m.w_hh.clone(),
            no_bias: m.b_hh.zeros_like()?,
            latent: z,
        })
    }

    /// The posterior's `[μ | logit σ]` from features `feat` and state `h`.
    pub(super) fn posterior(&self, feat: &Tensor, h: &Tensor) -> Result<Tensor> {
        let q = self
            .encoder
            .forward(&Tensor::cat(&[feat, h], 1)?, Act::None)?;
        plus(q, self.enc_bias.as_ref())
    }

    /// The prior's draw from state `h` with noise `e` (`e` itself at the
    /// first step: `N(0, I)`).
    pub(super) fn prior_draw(&self, h: &Tensor, e: Tensor, first: bool) -> Result<Tensor> {
        if first {
            return Ok(e);
        }
        let p = plus(
            self.prior.forward(h, Act::None)?,
            self.bias.map(|b| &b.prior),
        )?;
        draw(&p, &e, self.latent)
    }

    /// The LSTM's state `(h, c)` after reading `[feat, z]` from `(h, cell)`.
    pub(super) fn advance(
        &self,
        feat: &Tensor,
        z: &Tensor,
        h: &Tensor,
        cell: &Tensor,
    ) -> Result<(Tensor, Tensor)> {
        let gates = (self
            .gates_in
            .forward(&Tensor::cat(&[feat, z], 1)?, Act::None)?
            + linear(h, &self.w_hh, &self.no_bias, Act::None)?)?;
        lstm_cell(&plus(gates, self.gates_bias.as_ref())?, cell)
    }
}

/// One step of a causal filter with pole `rho` (the first value as is).
pub(super) fn step_filter(prev: &Option<Tensor>, x: Tensor, rho: f64) -> Result<Tensor> {
    match prev {
        Some(p) if rho > 0.0 => filter::step(p, &x, rho),
        _ => Ok(x),
    }
}
