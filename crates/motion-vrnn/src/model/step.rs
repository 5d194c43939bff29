//! The recurrence one step at a time ([`Steps`]), for sampling and for
//! feeding back to every depth.

use super::*;

/// One step of the recurrence at a time, for the step loops (sampling,
/// feeding back to every depth): the weights as each step reads them,
/// made once per loop; each step is given the condition's rows (`[B or 1,
/// ·]`) it adds.
pub(super) struct Steps {
    prior: Lin,
    encoder: Lin,
    gates_in: Lin,
    w_hh: Tensor,
    no_bias: Tensor,
    latent: usize,
    hidden: usize,
}

impl Steps {
    pub(super) fn new(m: &Vrnn) -> Result<Steps> {
        Ok(Steps {
            prior: stacked(&m.prior[0], &m.prior[1])?,
            encoder: stacked(&m.encoder[0], &m.encoder[1])?,
            gates_in: Lin {
                w: m.w_ih.clone(),
                b: (&m.b_ih + &m.b_hh)?,
            },
            w_hh: m.w_hh.clone(),
            no_bias: m.b_hh.zeros_like()?,
            latent: m.config.latent,
            hidden: m.config.hidden,
        })
    }

    /// The condition's share of the posterior (`gates` false) or of the
    /// gates: the part it was made as, else a slice of `pre`.
    fn pre_part(&self, bias: Option<&Bias>, gates: bool) -> Result<Option<Tensor>> {
        let Some(b) = bias else { return Ok(None) };
        if let Some(parts) = &b.parts {
            return Ok(Some(parts[gates as usize].clone()));
        }
        let (z2, h4) = (2 * self.latent, 4 * self.hidden);
        match gates {
            false => b.pre.narrow(1, 0, z2).map(Some),
            true => b.pre.narrow(1, z2, h4).map(Some),
        }
    }

    /// The posterior's `[μ | logit σ]` from features `feat` and state `h`.
    pub(super) fn posterior(
        &self,
        feat: &Tensor,
        h: &Tensor,
        bias: Option<&Bias>,
    ) -> Result<Tensor> {
        let q = self
            .encoder
            .forward(&Tensor::cat(&[feat, h], 1)?, Act::None)?;
        plus(q, self.pre_part(bias, false)?.as_ref())
    }

    /// The prior's draw from state `h` with noise `e` (`e` itself at the
    /// first step: `N(0, I)`).
    pub(super) fn prior_draw(
        &self,
        h: &Tensor,
        e: Tensor,
        first: bool,
        bias: Option<&Bias>,
    ) -> Result<Tensor> {
        if first {
            return Ok(e);
        }
        let p = plus(self.prior.forward(h, Act::None)?, bias.map(|b| &b.prior))?;
        draw(&p, &e, self.latent)
    }

    /// The LSTM's state `(h, c)` after reading `[feat, z]` from `(h, cell)`.
    pub(super) fn advance(
        &self,
        (feat, z): (&Tensor, &Tensor),
        h: &Tensor,
        cell: &Tensor,
        bias: Option<&Bias>,
    ) -> Result<(Tensor, Tensor)> {
        let gates = (self
            .gates_in
            .forward(&Tensor::cat(&[feat, z], 1)?, Act::None)?
            + linear(h, &self.w_hh, &self.no_bias, Act::None)?)?;
        lstm_cell(&plus(gates, self.pre_part(bias, true)?.as_ref())?, cell)
    }
}

/// One step of a causal filter with pole `rho` (the first value as is).
pub(super) fn step_filter(prev: &Option<Tensor>, x: Tensor, rho: f64) -> Result<Tensor> {
    match prev {
        Some(p) if rho > 0.0 => filter::step(p, &x, rho),
        _ => Ok(x),
    }
}
