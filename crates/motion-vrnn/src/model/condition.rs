//! The condition a model reads: category weights per sequence, and the
//! pace ([`Parts::pace`]) as their last columns.

use super::*;

/// The normalised features of the root's motion ([`Parts::root_weight`]):
/// `vel_x`, `vel_z`, `ang_vel_y`, the last three.
pub const ROOT_FEATURES: std::ops::Range<usize> = VEL_X..ANG_VEL_Y + 1;

/// The frames a window's pace is read from: its first, the context a
/// generated motion continues (`generate::CONTEXT` is this).
pub const PACE_FRAMES: usize = 16;

/// Frames per run of a long motion: one window's length. A long motion is
/// made in runs, each a fresh recurrence after the last
/// [`PACE_FRAMES`] frames of the run before, its pace read from them (the
/// sampler, steering, live play).
pub const PACE_EVERY: usize = 128;

/// A control row asking the root for less speed than this (m/s), a stand,
/// leaves the pace as it is ([`Config::control_pace`]): asked a pace of
/// standing, the default walked on after a stop more often.
pub const CONTROL_PACE_MIN_M_S: f64 = 0.1;

/// The guidance scale generation asks a category at unless told otherwise
/// (`--guidance`, [`Config::condition`]). Training, its
/// validation loss and the judge read categories at 1.
pub const GUIDANCE: f64 = 1.4;

/// The normalised features whose means make the pace ([`Parts::pace`]):
/// `root_y`, `vel_x`, `vel_z`, `ang_vel_y`.
pub const PACE_FEATURES: [usize; 4] = [ROOT_Y, VEL_X, VEL_Z, ANG_VEL_Y];

/// Category weights `cond: [B, categories + 1]` with the pace `[B,
/// PACE_FEATURES]` as their last columns, weighed like the category (`1 −`
/// the weight of row 0): [`Config::paced`], [`Config::asking_pace`].
pub(super) fn with_pace(cond: &Tensor, pace: &Tensor) -> Result<Tensor> {
    let asked = cond.narrow(1, 0, 1)?.affine(-1.0, 1.0)?;
    Tensor::cat(&[cond, &pace.broadcast_mul(&asked)?], 1)
}

/// The pace of sequences `x: [B, T, ≥ 58]` (normalised features): the mean
/// over the frames of each of [`PACE_FEATURES`], `[B, 4]`.
pub fn pace(x: &Tensor) -> Result<Tensor> {
    let columns = PACE_FEATURES
        .iter()
        .map(|&f| x.narrow(2, f, 1))
        .collect::<Result<Vec<_>>>()?;
    Tensor::cat(&columns, 2)?.mean(1)
}

/// The root's horizontal speed `√(vx² + vz² + offset)` in each frame of
/// `x: [B, T, ≥ 58]` (normalised features, `body`'s statistics), CMU units
/// a frame: `[B, T, 1]`. The positive `offset` keeps the gradient finite
/// at a standstill.
pub(super) fn frame_speed(x: &Tensor, body: &feet::Stats, offset: f64) -> Result<Tensor> {
    let squared = |f: usize| feet::raw_col(x, f, body)?.sqr();
    ((squared(VEL_X)? + squared(VEL_Z)?)? + offset)?.sqrt()
}

impl Config {
    /// Columns of the condition weights after the categories': the pace's
    /// ([`Parts::pace`]), or none.
    pub fn pace_columns(&self) -> usize {
        if self.parts.pace {
            PACE_FEATURES.len()
        } else {
            0
        }
    }

    /// The pace of sequences `x: [B, T, ≥ 58]` as this model reads it
    /// ([`pace`]), `[B, pace_columns]`.
    pub fn pace_of(&self, x: &Tensor) -> Result<Tensor> {
        pace(x)
    }

    /// `cond` with the pace of `x: [B, T, input]` ([`Parts::pace`]) as its
    /// last columns, weighed like the category (`1 −` the weight of row 0:
    /// zero where no category is asked, `guidance` where one is); `cond`
    /// as it is without the pace part or where it has its pace already
    /// (generation asks for a window's own, [`crate::generate`]). Without
    /// frames (`x` None or empty) the pace is 0, the training set's mean.
    pub fn paced(&self, cond: Option<&Tensor>, x: Option<&Tensor>) -> Result<Option<Tensor>> {
        let n = self.categories.len() + 1;
        let Some(cond) = cond.filter(|c| self.parts.pace && c.dim(1).is_ok_and(|w| w == n)) else {
            return Ok(cond.cloned());
        };
        let pace = match x {
            Some(x) if x.dim(1)? > 0 => self.pace_of(x)?,
            _ => Tensor::zeros(
                (cond.dim(0)?, self.pace_columns()),
                DType::F32,
                cond.device(),
            )?,
        };
        with_pace(cond, &pace).map(Some)
    }

    /// `cond` (paced, [`Config::paced`]) asking for the pace `want`
    /// (`[B, PACE_FEATURES]`) instead of its own, weighed as
    /// [`Config::paced`] weighs it (by the weight of the category asked):
    /// how a motion is held to its pace ([`crate::generate::PACE_GAIN`]).
    pub fn asking_pace(&self, cond: &Tensor, want: &Tensor) -> Result<Tensor> {
        let w = self.categories.len() + 1;
        if !self.parts.pace || cond.dim(1)? != w + self.pace_columns() {
            candle_core::bail!(
                "asking_pace: a paced condition of {} columns, got {:?}",
                w + self.pace_columns(),
                cond.shape()
            );
        }
        with_pace(&cond.narrow(1, 0, w)?, want)
    }

    /// `cond` (paced, [`Config::paced`]) asking, in each row whose control
    /// `ctl: [B, CONTROL]` asks the root to move (at
    /// [`CONTROL_PACE_MIN_M_S`] or more), for the root motion that control
    /// asks for (`motion_steer::asked_root_motion`) in place of the pace's
    /// `vel_x`, `vel_z` and `ang_vel_y`, weighed as the pace is; its
    /// `root_y`, rows left free and rows asking to stand, as they are.
    pub fn control_pace(&self, cond: &Tensor, ctl: &Tensor) -> Result<Tensor> {
        let w = self.categories.len() + 1;
        let body = match &self.body {
            Some(b) if self.parts.pace && cond.dim(1)? == w + self.pace_columns() => b,
            _ => return Ok(cond.clone()),
        };
        let (mut rows, ctl) = (cond.to_vec2::<f32>()?, ctl.to_vec2::<f32>()?);
        for (row, c) in rows.iter_mut().zip(&ctl) {
            let Ok(c) = <&[f32; motion_steer::CONTROL]>::try_from(c.as_slice()) else {
                candle_core::bail!(
                    "a control row has {} values, not {}",
                    c.len(),
                    motion_steer::CONTROL
                );
            };
            let Some(asked) = motion_steer::asked_root_motion(c) else {
                continue;
            };
            let speed =
                asked[0].hypot(asked[1]) * motion_steer::METRES_PER_UNIT * motion_steer::FPS;
            if speed < CONTROL_PACE_MIN_M_S {
                continue;
            }
            let weight = 1.0 - row[0];
            // PACE_FEATURES: root_y, then these three.
            for (i, (k, v)) in [VEL_X, VEL_Z, ANG_VEL_Y].into_iter().zip(asked).enumerate() {
                row[w + 1 + i] = weight * ((v as f32 - body.mean[k]) / body.std[k]);
            }
        }
        let b = rows.len();
        Tensor::from_vec(rows.concat(), (b, w + self.pace_columns()), cond.device())
    }

    /// Condition weights `[B, categories + 1]` for sequences asking for
    /// `asked` (rows of [`Config::categories`], counted from 1; None: no
    /// category) at guidance scale `guidance`: a sequence asking for row
    /// `k` weighs row `k` by `guidance` and row 0 by `1 − guidance`, so 1 is
    /// the plain conditional model, 0 the unconditional one, and above 1
    /// pushes away from the unconditional model (classifier-free guidance
    /// on the pre-activations the condition feeds). None for an
    /// unconditioned model.
    pub fn condition(
        &self,
        asked: &[Option<usize>],
        guidance: f64,
        device: &Device,
    ) -> Result<Option<Tensor>> {
        let n = self.categories.len() + 1;
        if n == 1 {
            return Ok(None);
        }
        let mut w = vec![0f32; asked.len() * n];
        for (row, a) in w.chunks_exact_mut(n).zip(asked) {
            match a {
                Some(k) if *k >= 1 && *k < n => {
                    row[0] = (1.0 - guidance) as f32;
                    row[*k] = guidance as f32;
                }
                Some(k) => candle_core::bail!("category row {k} is out of range (1..{n})"),
                None => row[0] = 1.0,
            }
        }
        Tensor::from_vec(w, (asked.len(), n), device).map(Some)
    }

    /// Condition weights for the windows `windows` of a split whose
    /// windows have the categories `categories` (`other` past its end, as
    /// for a dataset without categories), each asking for its own category
    /// at `guidance` ([`Config::condition`]), or for none where
    /// `dropped(k)` (`k`: the position in `windows`) or where the model has
    /// no row for it; None for an unconditioned model.
    pub fn window_condition(
        &self,
        categories: &[Category],
        windows: &[usize],
        guidance: f64,
        dropped: impl Fn(usize) -> bool,
        device: &Device,
    ) -> Result<Option<Tensor>> {
        if self.categories.is_empty() {
            return Ok(None);
        }
        let rows: Vec<Option<usize>> = windows
            .iter()
            .enumerate()
            .map(|(k, &i)| {
                let c = categories.get(i).copied().unwrap_or(Category::Other);
                self.row_of(c).filter(|_| !dropped(k))
            })
            .collect();
        self.condition(&rows, guidance, device)
    }

    /// The condition-table row of `category` (counted from 1), if the
    /// model has one.
    pub(super) fn row_of(&self, category: Category) -> Option<usize> {
        self.categories
            .iter()
            .position(|c| c == category.name())
            .map(|k| k + 1)
    }

    /// The row of the condition table asked for by the category `name`
    /// (counted from 1, [`Config::condition`]), or an error that says what
    /// can be asked: an unknown name lists the known ones, a known one the
    /// model was not trained with lists the model's.
    pub fn category_row(&self, name: &str) -> std::result::Result<usize, String> {
        let category: Category = name.parse()?;
        if self.categories.is_empty() {
            return Err(format!(
                "this model was trained without categories, so it cannot be asked for {category}; train one with `cargo xtask train --condition category`"
            ));
        }
        self.row_of(category).ok_or_else(|| {
                format!(
                    "the model was not trained with {category} (its training set had no {category} windows); it knows: {}",
                    self.categories.join(", ")
                )
            })
    }
}
