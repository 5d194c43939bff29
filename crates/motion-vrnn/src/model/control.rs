//! The control ([`Parts::control`]): where the root is asked to be over
//! the next second, per frame ([`motion_steer::CONTROL`] values), added to
//! the condition's rows through its own weights.

use super::*;
use motion_steer::{control_of_motion, CONTROL};

/// The name of the control's variable (`[CONTROL, 2Z + 4H + 2Z + d1]`); it
/// starts at zero, as the condition table does ([`COND_WEIGHT`]).
pub const CONTROL_WEIGHT: &str = "control.weight";

impl Config {
    /// Control columns a frame of this model's input has after its
    /// features: [`CONTROL`] with [`Parts::control`], else none.
    pub fn control_columns(&self) -> usize {
        if self.parts.control {
            CONTROL
        } else {
            0
        }
    }

    /// Normalised windows `x: [B, T, input]` with their control appended
    /// (`[B, T, input + CONTROL]`): row `t` asks for where the root of
    /// frame `t − 1` went over the next second, in that frame's own axes
    /// ([`control_of_motion`]), so a frame is made knowing only frames
    /// before it; rows with no second after them, the first row, and every
    /// row of a window with `keep[k]` false are left free (zeros). `x` as
    /// it is for a model without the control.
    pub fn with_control(&self, x: &Tensor, keep: &[bool]) -> Result<Tensor> {
        if !self.parts.control {
            return Ok(x.clone());
        }
        let Some(body) = &self.body else {
            candle_core::bail!("the control needs the training set's statistics (Config::fit_to)");
        };
        let (b, t, f) = x.dims3()?;
        let v = x.flatten_all()?.to_vec1::<f32>()?;
        let mut out = vec![0f32; b * t * CONTROL];
        for s in 0..b {
            if !keep.get(s).copied().unwrap_or(true) {
                continue;
            }
            let root: Vec<[f64; 3]> = (0..t)
                .map(|r| {
                    let row = &v[(s * t + r) * f..];
                    [VEL_X, VEL_Z, ANG_VEL_Y]
                        .map(|k| row[k] as f64 * body.std[k] as f64 + body.mean[k] as f64)
                })
                .collect();
            for (r, c) in control_of_motion(&root).iter().enumerate().take(t - 1) {
                let at = (s * t + r + 1) * CONTROL;
                out[at..at + CONTROL].copy_from_slice(c);
            }
        }
        let ctl = Tensor::from_vec(out, (b, t, CONTROL), x.device())?;
        Tensor::cat(&[x, &ctl], 2)
    }
}

impl Vrnn {
    /// `x: [B, T, input (+ CONTROL)]` cut into its features and its
    /// control (None where it has none).
    pub(super) fn split_control(&self, x: &Tensor) -> Result<(Tensor, Option<Tensor>)> {
        let f = self.config.input;
        match x.dim(D::Minus1)? {
            w if w == f => Ok((x.clone(), None)),
            w if w == f + self.config.control_columns() => Ok((
                x.narrow(D::Minus1, 0, f)?.contiguous()?,
                Some(x.narrow(D::Minus1, f, w - f)?.contiguous()?),
            )),
            w => candle_core::bail!(
                "frames of {w} values; this model reads {f}, or {} with its control",
                f + self.config.control_columns()
            ),
        }
    }

    /// The condition's rows `base` (`[B or 1, ·]`, one per sequence) plus
    /// the control's `ctl`: `[B, T, CONTROL]`, one row per frame, or one
    /// step's `[B, CONTROL]`. One [`control_rows`] makes every part; each
    /// part is a slice of it ([`Bias::all`], which the rollout reads whole).
    pub(super) fn frame_bias(&self, base: &Tensor, ctl: &Tensor) -> Result<Bias> {
        let (Some(w), c) = (&self.control, &self.config) else {
            candle_core::bail!(
                "this model was trained without the control; train one with the default model (`cargo xtask train`)"
            );
        };
        let all = control_rows(ctl, w, base)?;
        let (z2, h4, d1) = (2 * c.latent, 4 * c.hidden, c.decoder[0]);
        let part = |at: usize, n: usize| all.narrow(D::Minus1, at, n);
        Ok(Bias {
            pre: part(0, z2 + h4)?,
            prior: part(z2 + h4, z2)?,
            decoder: part(2 * z2 + h4, d1)?,
            parts: Some([part(0, z2)?, part(z2, h4)?]),
            all: Some(all),
        })
    }
}

impl Vrnn {
    /// One generation step's rows: the condition's `rows` ([`Vrnn::rows`])
    /// with the control `ctl: [B, CONTROL]` ([`Vrnn::split`]); an error for
    /// a model without the control.
    pub(super) fn step_bias(&self, rows: Option<&Tensor>, ctl: &Tensor) -> Result<Bias> {
        match rows {
            Some(e) => self.split(e, Some(ctl)),
            None => candle_core::bail!(
                "this model was trained without the control; train one with the default model (`cargo xtask train`)"
            ),
        }
    }
}

/// What generation asks of the control at each step ([`MotionModel::steer`]):
/// given the step and the frames made so far (`[B, input]` each, the start
/// frames first), the control `[B, CONTROL]` for the frame about to be made
/// (in the axes of the last frame made), or None to leave it free.
pub type Control<'a> = dyn FnMut(usize, &[Tensor]) -> Result<Option<Tensor>> + 'a;
