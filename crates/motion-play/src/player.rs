//! [`Player`]: the model steered by the keys held, one frame per call.

use crate::bundle::{Bundle, Header};
use crate::PlayError;
use candle_core::{DType, Device, Tensor};
use candle_nn::VarBuilder;
use mocap_ingest::features::{Placer, ANG_VEL_Y, VEL_X, VEL_Z};
use mocap_ingest::skeleton::NUM_JOINTS;
use mocap_ingest::FeatureVec;
use motion_steer::{Frame2, Keys, Stick};
use motion_vrnn::model::{Generator, GUIDANCE, PACE_EVERY, PACE_FRAMES};
use motion_vrnn::rng::noise;
use motion_vrnn::Vrnn;
use std::collections::VecDeque;

/// The seed's stream of a run's noise: the one `motion_vrnn::steer` draws
/// from, so a run is made with the noise a steered motion's run gets.
const NOISE_STREAM: u64 = 0x57EE_2000;

/// One frame made.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// Global joint positions (dataset units, y up, the floor at 0; the
    /// motion starts at the origin facing +z).
    pub pose: [[f64; 3]; NUM_JOINTS],
    /// The root on the floor (metres, the start frame).
    pub root: Frame2,
    /// The asked heading (unit vector, start frame) and speed (m/s); the
    /// root's own while the start frames play.
    pub heading: [f64; 2],
    /// The asked speed, metres per second.
    pub speed: f64,
}

/// The model made to walk where the keys say, frame by frame: the start
/// context, then generated frames, each asked for by the [`Stick`]'s
/// control row from where the root is. As the sampler does, the motion is
/// made in runs of [`PACE_EVERY`] frames, each run a fresh recurrence after
/// the last [`PACE_FRAMES`] frames made.
pub struct Player {
    model: Vrnn,
    header: Header,
    seed: u64,
    category: usize,
    cond: Option<Tensor>,
    gen: Generator,
    run: u64,
    eps: Tensor,
    /// The last [`PACE_FRAMES`] frames made, normalised.
    recent: VecDeque<Vec<f32>>,
    root: Frame2,
    placer: Placer,
    stick: Option<Stick>,
    made: usize,
}

impl Player {
    /// A player of the bundle's model, starting from its first context; the
    /// same bundle, seed and keys make the same frames.
    pub fn new(bytes: &[u8], seed: u64) -> Result<Player, PlayError> {
        let Bundle { header, weights } = Bundle::from_bytes(bytes)?;
        let dev = Device::Cpu;
        let vb = VarBuilder::from_buffered_safetensors(weights, DType::F32, &dev)?;
        let model = Vrnn::new(&header.config, vb)?;
        if !header.config.parts.control {
            return Err(PlayError::Invalid(
                "this model was trained without the control, so it cannot be steered; train the default model (`cargo xtask train`)".into(),
            ));
        }
        let start = Tensor::from_vec(
            header.starts[0].frames.clone(),
            (1, PACE_FRAMES, header.config.input),
            &dev,
        )?;
        let gen = model.generator(Some(&start), None, 1)?;
        let mut p = Player {
            model,
            eps: Tensor::zeros(1, DType::F32, &dev)?,
            header,
            seed,
            category: 0,
            cond: None,
            gen,
            run: 0,
            recent: VecDeque::with_capacity(PACE_FRAMES),
            root: Frame2::START,
            placer: Placer::default(),
            stick: None,
            made: 0,
        };
        p.restart(0)?;
        Ok(p)
    }

    /// The categories the digit keys pick, in order.
    pub fn categories(&self) -> Vec<&str> {
        self.header
            .starts
            .iter()
            .map(|s| s.category.as_str())
            .collect()
    }

    /// The category asked now (an index of [`Player::categories`]).
    pub fn category(&self) -> usize {
        self.category
    }

    /// Asks category `i` from the next frame on, the motion going on.
    pub fn pick(&mut self, i: usize) -> Result<(), PlayError> {
        self.cond = self.condition(i)?;
        self.category = i;
        self.gen.set_condition(self.cond.as_ref())?;
        Ok(())
    }

    /// Starts again from category `i`'s context, at the origin.
    pub fn restart(&mut self, i: usize) -> Result<(), PlayError> {
        self.cond = self.condition(i)?;
        self.category = i;
        let frames = self.header.starts[i].frames.clone();
        self.recent.clear();
        self.root = Frame2::START;
        self.placer = Placer::default();
        self.stick = None;
        self.made = 0;
        self.run = 0;
        self.begin_run(frames, false)
    }

    /// The condition of category `i` at the default guidance.
    fn condition(&self, i: usize) -> Result<Option<Tensor>, PlayError> {
        let c = &self.header.config;
        let name = &self
            .header
            .starts
            .get(i)
            .ok_or_else(|| {
                PlayError::Invalid(format!(
                    "no category {i}: the page has {}",
                    self.header.starts.len()
                ))
            })?
            .category;
        let row = c.category_row(name).map_err(PlayError::Invalid)?;
        Ok(c.condition(&[Some(row)], GUIDANCE, &Device::Cpu)?)
    }

    /// A fresh recurrence after `context` (normalised, [`PACE_FRAMES`]
    /// frames), with the run's noise; its context frames are read through
    /// the posterior now when `silent` (they were shown already).
    fn begin_run(&mut self, context: Vec<f32>, silent: bool) -> Result<(), PlayError> {
        let c = &self.header.config;
        let dev = Device::Cpu;
        let start = Tensor::from_vec(context, (1, PACE_FRAMES, c.input), &dev)?;
        self.gen = self.model.generator(Some(&start), self.cond.as_ref(), 1)?;
        self.eps = noise(
            self.seed ^ NOISE_STREAM,
            self.run,
            PACE_FRAMES + PACE_EVERY,
            1,
            c.latent,
            &dev,
        )?;
        if silent {
            for step in 0..PACE_FRAMES {
                self.gen.next(&self.eps.get(step)?, None)?;
            }
        }
        Ok(())
    }

    /// The next frame, with `keys` held.
    pub fn step(&mut self, keys: Keys) -> Result<Frame, PlayError> {
        if self.gen.step() == PACE_FRAMES + PACE_EVERY {
            self.run += 1;
            let context: Vec<f32> = self.recent.iter().flatten().copied().collect();
            self.begin_run(context, true)?;
        }
        let step = self.gen.step();
        let speeds = self.header.speeds;
        let ctl = match step >= PACE_FRAMES {
            true => {
                let root = self.root;
                let stick = self
                    .stick
                    .get_or_insert_with(|| Stick::new(&root, speeds[0], speeds[1]));
                Some(Tensor::from_slice(
                    &stick.control(&root, keys),
                    (1, motion_steer::CONTROL),
                    &Device::Cpu,
                )?)
            }
            false => None,
        };
        let x = self
            .gen
            .next(&self.eps.get(step)?, ctl.as_ref())?
            .flatten_all()?
            .to_vec1::<f32>()?;
        let body = self.header.config.body.as_ref().ok_or_else(|| {
            PlayError::Invalid("the model has no statistics to undo the normalisation with".into())
        })?;
        let mut f: FeatureVec = [0.0; mocap_ingest::NUM_FEATURES];
        for (k, v) in f.iter_mut().enumerate() {
            *v = x[k] as f64 * body.std[k] as f64 + body.mean[k] as f64;
        }
        if self.made > 0 {
            self.root = self.root.advanced([f[VEL_X], f[VEL_Z], f[ANG_VEL_Y]]);
        }
        self.made += 1;
        if self.recent.len() == PACE_FRAMES {
            self.recent.pop_front();
        }
        self.recent.push_back(x);
        let (heading, speed) = match &self.stick {
            Some(s) => (s.heading(), s.speed()),
            None => (self.root.forward, 0.0),
        };
        Ok(Frame {
            pose: self.placer.place(&f),
            root: self.root,
            heading,
            speed,
        })
    }
}
