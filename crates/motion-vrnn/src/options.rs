//! Overrides of a [`TrainConfig`], one per `cargo xtask train` option: a
//! preset is the starting point, and every option given replaces its value.

use crate::train::{Select, TrainConfig};

/// The starting point of a training configuration.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Preset {
    /// [`TrainConfig::standard`]: the four-second model (the default
    /// until the minute preset replaced it).
    Standard,
    /// [`TrainConfig::quick`], a quick look.
    Quick,
    /// [`TrainConfig::paper`], exactly the paper.
    Paper,
    /// The default of `cargo xtask train`: `standard` for a minute of
    /// motion ([`Preset::overrides`]): fed back to every depth in one pass,
    /// drawn at the sampling temperature, conditioned on the category and the pace, the judge over
    /// 14 stretches every 10 epochs (`docs/training.md`, "The judge and the
    /// minute"), from the best of 3 initialisations after 20 epochs, with
    /// a wider extractor and decoder ([`MINUTE_EXTRACTOR`],
    /// [`MINUTE_DECODER`]), [`MINUTE_EPOCHS`] epochs, every one trained (no
    /// early stopping), the last [`MINUTE_LATE`] through the rollout with
    /// the root's motion weighed [`MINUTE_LATE_ROOT_WEIGHT`]
    /// (`docs/training.md`, "The root weighed in the late epochs only",
    /// "Longer: 600 epochs").
    Minute,
}

/// The `minute` preset's feature-extractor sizes: the paper's 48, 32 widened
/// to 64, 32 (docs/training.md, "A wider extractor and decoder: the
/// default since 2026-11-28").
pub const MINUTE_EXTRACTOR: [usize; 2] = [64, 32];

/// The `minute` preset's decoder sizes: the paper's 32, 48 doubled.
pub const MINUTE_DECODER: [usize; 2] = [64, 96];

/// The `minute` preset's epochs (`--epochs`; `standard`'s 400 for a model
/// without the late epochs): chosen on `val` over 400, with which the
/// judge kept epochs 350–390 and motions asked for `other` were recognised
/// 82 % (`docs/training.md`, "Longer: 600 epochs").
pub const MINUTE_EPOCHS: usize = 600;

/// The `minute` preset's last epochs through the rollout
/// (`--rollout-last`; [`TrainConfig::rollout_last`]): the second half of
/// its [`MINUTE_EPOCHS`], where the learning rate anneals.
pub const MINUTE_LATE: usize = 300;

/// The root's weight in the `minute` preset's late epochs
/// (`--late-root-weight`; [`TrainConfig::late_root_weight`]): chosen on
/// `val` over 4, 8 and 12 (`docs/training.md`, "The root weighed in the
/// late epochs only").
pub const MINUTE_LATE_ROOT_WEIGHT: f64 = 8.0;

impl Preset {
    /// The preset's configuration (its model: the default model), before
    /// [`Preset::overrides`].
    pub fn config(self) -> TrainConfig {
        match self {
            Preset::Standard | Preset::Minute => TrainConfig::standard(),
            Preset::Quick => TrainConfig::quick(),
            Preset::Paper => TrainConfig::paper(),
        }
    }

    /// What the preset changes on top of [`Preset::config`] once the model
    /// is chosen (nothing but for `minute`).
    pub fn overrides(self) -> Overrides {
        match self {
            Preset::Minute => Overrides {
                feed_rounds: Some(0),
                rollouts_at_temperature: true,
                condition: Some(ConditionOn::CategoryPace),
                judge_stretches: Some(14),
                judge_every: Some(10),
                inits: Some(3),
                extractor: Some(MINUTE_EXTRACTOR),
                decoder: Some(MINUTE_DECODER),
                epochs: Some(MINUTE_EPOCHS),
                early_stopping: Some(0),
                rollout_last: Some(MINUTE_LATE),
                late_root_weight: Some(MINUTE_LATE_ROOT_WEIGHT),
                ..Overrides::default()
            },
            _ => Overrides::default(),
        }
    }

    /// The preset for `model`: [`Preset::config`] with `model` in place of
    /// its own, then [`Preset::overrides`]. The late epochs through the
    /// rollout (and with them the longer run and the end of early
    /// stopping) only for a model that feeds its frames back to a skeleton,
    /// the one kind they can train ([`TrainConfig::late_model`]); any other
    /// keeps `standard`'s.
    pub fn for_model(self, model: crate::model::Config) -> TrainConfig {
        let mut cfg = self.config();
        cfg.model = model;
        let mut o = self.overrides();
        let parts = &cfg.model.parts;
        if !(parts.skeleton && parts.self_feed > 0.0) {
            (
                o.epochs,
                o.early_stopping,
                o.rollout_last,
                o.late_root_weight,
            ) = (None, None, None, None);
        }
        o.apply(&mut cfg);
        cfg
    }
}

impl std::str::FromStr for Preset {
    type Err = String;
    fn from_str(s: &str) -> Result<Preset, String> {
        match s {
            "standard" => Ok(Preset::Standard),
            "quick" => Ok(Preset::Quick),
            "paper" => Ok(Preset::Paper),
            "minute" => Ok(Preset::Minute),
            _ => Err(format!(
                "unknown preset {s:?}: `standard`, `quick`, `paper` or `minute`"
            )),
        }
    }
}

/// What a model is conditioned on (`--condition`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ConditionOn {
    /// Nothing (the unconditioned model).
    None,
    /// Each window's category ([`crate::train::Conditioning`]).
    Category,
    /// The category and the pace of each window
    /// ([`crate::model::Parts::pace`]).
    CategoryPace,
    /// The category and the pace with the root's speed
    /// ([`crate::model::Parts::pace_speed`]).
    CategoryPaceSpeed,
}

impl std::str::FromStr for ConditionOn {
    type Err = String;
    fn from_str(s: &str) -> Result<ConditionOn, String> {
        match s {
            "none" => Ok(ConditionOn::None),
            "category" => Ok(ConditionOn::Category),
            "category+pace" => Ok(ConditionOn::CategoryPace),
            "category+pace+speed" => Ok(ConditionOn::CategoryPaceSpeed),
            _ => Err(format!(
                "unknown condition {s:?}; choose `category`, `category+pace`, `category+pace+speed` or `none`"
            )),
        }
    }
}

/// How the `best` checkpoint is chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SelectBy {
    /// The epoch whose generated motion is closest to the training windows
    /// ([`crate::generate::Judge`]).
    Generation,
    /// The epoch with the lowest validation loss.
    Loss,
}

impl std::str::FromStr for SelectBy {
    type Err = String;
    fn from_str(s: &str) -> Result<SelectBy, String> {
        match s {
            "generation" => Ok(SelectBy::Generation),
            "loss" => Ok(SelectBy::Loss),
            _ => Err(format!("unknown choice {s:?}: `generation` or `loss`")),
        }
    }
}

/// Values that replace a preset's; `None` keeps it. Where an option's
/// "off" value is given (e.g. a KL weight of 1, a clip of 0) the
/// configuration stores "none", as the presets do.
#[derive(Clone, Debug, Default)]
pub struct Overrides {
    /// The model's latent filter pole (0: off).
    pub latent_filter: Option<f64>,
    /// The model's output filter pole (0: off).
    pub output_filter: Option<f64>,
    /// Weight of the foot-slide penalty (0: off).
    pub feet_weight: Option<f64>,
    /// KL weight after warm-up (1: the ELBO).
    pub kl_weight: Option<f64>,
    /// Largest share of frames fed back in training (0: off).
    pub self_feed: Option<f64>,
    /// Rounds of feeding back (1: one step deep; 0: every depth).
    pub feed_rounds: Option<usize>,
    /// Sampling temperature (1: the prior as trained).
    pub temperature: Option<f64>,
    /// Latent size (the paper's 8).
    pub latent: Option<usize>,
    /// LSTM hidden size (the paper's 32).
    pub hidden: Option<usize>,
    /// Feature-extractor layer sizes (the paper's 48, 32).
    pub extractor: Option<[usize; 2]>,
    /// Decoder layer sizes (the paper's 32, 48).
    pub decoder: Option<[usize; 2]>,
    /// Epochs.
    pub epochs: Option<usize>,
    /// Windows per step.
    pub batch: Option<usize>,
    /// Adam learning rate.
    pub lr: Option<f64>,
    /// Learning rate of the last epoch as a share of `lr` (1: constant).
    pub lr_final: Option<f64>,
    /// Seed of initialisation, shuffling and noise.
    pub seed: Option<u64>,
    /// KL warm-up epochs (0: off).
    pub kl_warmup: Option<usize>,
    /// Gradient-norm clip (0: off).
    pub clip: Option<f64>,
    /// Early-stopping patience (0: off).
    pub early_stopping: Option<usize>,
    /// How `best` is chosen.
    pub select: Option<SelectBy>,
    /// Epochs between two judgements of generated motion.
    pub judge_every: Option<usize>,
    /// Window-long stretches the judge rolls its motions out for.
    pub judge_stretches: Option<usize>,
    /// What the model is conditioned on.
    pub condition: Option<ConditionOn>,
    /// Share of windows trained without their category (with
    /// `condition: Category`; default [`crate::train::CONDITION_DROPOUT`]).
    pub condition_dropout: Option<f64>,
    /// Feed rounds drawn at the sampling temperature (`true`: on).
    pub rollouts_at_temperature: bool,
    /// Generation keeps the lowest joint at most this high (CMU units;
    /// [`crate::model::Parts::float_limit`]; 0: no limit; a negative one is
    /// refused when the model is built).
    pub float_limit: Option<f64>,
    /// Planted toes in the contact loss must also move slower than this
    /// (m/s; [`crate::model::Parts::contact_speed`]; 0: height alone).
    pub contact_speed: Option<f64>,
    /// Weight of the swing loss ([`crate::model::Parts::swing`]; 0: off).
    pub swing_weight: Option<f64>,
    /// Weight of the fed jerk loss ([`crate::model::Parts::fed_jerk`]; 0: off).
    pub fed_jerk_weight: Option<f64>,
    /// Weight of the fed speed loss ([`crate::model::Parts::fed_speed`]; 0: off).
    pub fed_speed_weight: Option<f64>,
    /// Weight of the root's motion in the squared error
    /// ([`crate::model::Parts::root_weight`]; 1: the ELBO's).
    pub root_weight: Option<f64>,
    /// The gradient through the fed-back frames
    /// ([`crate::model::Parts::rollout_gradient`]; `true`: on).
    pub rollout_gradient: bool,
    /// The gradient through the last round of feeding back
    /// ([`crate::model::Parts::last_round_gradient`]; `true`: on).
    pub last_round_gradient: bool,
    /// Initialisations tried, each for [`crate::train::INIT_EPOCHS`]
    /// epochs, the best on validation kept ([`crate::train::Inits`]; 1: the
    /// seed's alone).
    pub inits: Option<usize>,
    /// Fed-back frames in runs of this many (1: each on its own).
    pub feed_run: Option<usize>,
    /// Decay of the weights' moving average the judge keeps
    /// ([`TrainConfig::average`]; 0: off).
    pub average: Option<f64>,
    /// Train on the windows' mirror images too ([`TrainConfig::mirror`]).
    pub mirror: bool,
    /// The last epochs through the rollout ([`TrainConfig::rollout_last`]; 0: none).
    pub rollout_last: Option<usize>,
    /// The root's weight in those epochs ([`TrainConfig::late_root_weight`];
    /// 1: the ELBO's).
    pub late_root_weight: Option<f64>,
}

impl Overrides {
    /// `cfg` with every given value in place of its own.
    pub fn apply(&self, cfg: &mut TrainConfig) {
        let parts = &mut cfg.model.parts;
        if let Some(v) = self.latent_filter {
            parts.latent_filter = v;
        }
        if let Some(v) = self.output_filter {
            parts.output_filter = v;
        }
        if let Some(v) = self.feet_weight {
            parts.feet = v;
        }
        if let Some(v) = self.self_feed {
            parts.self_feed = v;
        }
        if let Some(v) = self.kl_weight {
            parts.kl_weight = (v != 1.0).then_some(v);
        }
        if let Some(v) = self.feed_rounds {
            parts.feed_rounds = (v != 1).then_some(v);
        }
        if let Some(v) = self.temperature {
            parts.temperature = (v != 1.0).then_some(v);
        }
        if self.rollouts_at_temperature {
            parts.rollouts_at_temperature = true;
        }
        if let Some(v) = self.float_limit {
            parts.float_limit = (v != 0.0).then_some(v);
        }
        if let Some(v) = self.contact_speed {
            parts.contact_speed = (v != 0.0).then_some(v);
        }
        if let Some(v) = self.swing_weight {
            parts.swing = (v != 0.0).then_some(v);
        }
        if let Some(v) = self.fed_jerk_weight {
            parts.fed_jerk = (v != 0.0).then_some(v);
        }
        if let Some(v) = self.fed_speed_weight {
            parts.fed_speed = (v != 0.0).then_some(v);
        }
        if let Some(v) = self.root_weight {
            parts.root_weight = (v != 1.0).then_some(v);
        }
        if self.rollout_gradient {
            parts.rollout_gradient = true;
        }
        if self.last_round_gradient {
            parts.last_round_gradient = true;
        }
        if let Some(v) = self.latent {
            cfg.model.latent = v;
        }
        if let Some(v) = self.hidden {
            cfg.model.hidden = v;
        }
        if let Some(v) = self.extractor {
            cfg.model.extractor = v;
        }
        if let Some(v) = self.decoder {
            cfg.model.decoder = v;
        }
        if let Some(v) = self.epochs {
            cfg.epochs = v;
        }
        if let Some(v) = self.batch {
            cfg.batch = v;
        }
        if let Some(v) = self.lr {
            cfg.adam.lr = v;
        }
        if let Some(v) = self.lr_final {
            cfg.lr_final = (v != 1.0).then_some(v);
        }
        if let Some(v) = self.seed {
            cfg.seed = v;
        }
        if let Some(v) = self.kl_warmup {
            cfg.kl_warmup_epochs = v;
        }
        if let Some(v) = self.clip {
            cfg.clip_grad_norm = (v > 0.0).then_some(v);
        }
        if let Some(v) = self.early_stopping {
            cfg.early_stopping = (v > 0).then_some(v);
        }
        if let Some(v) = self.judge_stretches {
            cfg.judge_stretches = (v > 1).then_some(v);
        }
        if let Some(v) = self.inits {
            cfg.inits = (v > 1).then_some(crate::train::Inits {
                candidates: v,
                epochs: crate::train::INIT_EPOCHS,
            });
        }
        if let Some(v) = self.feed_run {
            cfg.feed_run = (v > 1).then_some(v);
        }
        if let Some(v) = self.average {
            cfg.average = (v != 0.0).then_some(v);
        }
        if self.mirror {
            cfg.mirror = true;
        }
        if let Some(v) = self.rollout_last {
            cfg.rollout_last = (v > 0).then_some(v);
            if v == 0 {
                // No late epochs: nothing to weigh the root in either
                // (unless asked for below, which training refuses).
                cfg.late_root_weight = None;
            }
        }
        if let Some(v) = self.late_root_weight {
            cfg.late_root_weight = (v != 1.0).then_some(v);
        }
        match self.condition {
            Some(ConditionOn::None) => {
                cfg.condition = None;
                cfg.model.parts.pace = false;
                cfg.model.parts.pace_speed = false;
            }
            Some(on) => {
                cfg.condition = Some(crate::train::Conditioning {
                    dropout: crate::train::CONDITION_DROPOUT,
                });
                cfg.model.parts.pace = on != ConditionOn::Category;
                cfg.model.parts.pace_speed = on == ConditionOn::CategoryPaceSpeed;
            }
            None => {}
        }
        if let (Some(c), Some(d)) = (&mut cfg.condition, self.condition_dropout) {
            c.dropout = d;
        }
        let every = match cfg.select {
            Select::Generation { every } => every,
            Select::Loss => 5,
        };
        cfg.select = match (self.select, self.judge_every) {
            (Some(SelectBy::Loss), _) => Select::Loss,
            (Some(SelectBy::Generation), n) => Select::Generation {
                every: n.unwrap_or(every),
            },
            (None, Some(n)) if !cfg.select.is_loss() => Select::Generation { every: n },
            (None, _) => cfg.select,
        };
    }
}

/// A positive layer size (a command-line parser).
pub fn parse_size(s: &str) -> Result<usize, String> {
    s.trim()
        .parse::<usize>()
        .ok()
        .filter(|&n| n > 0)
        .ok_or_else(|| format!("`{s}`: a positive size"))
}

/// Two positive layer sizes, `A,B` (a command-line parser).
pub fn parse_two_sizes(s: &str) -> Result<[usize; 2], String> {
    let sizes: Option<Vec<usize>> = s.split(',').map(|x| parse_size(x).ok()).collect();
    sizes
        .and_then(|v| v.try_into().ok())
        .ok_or_else(|| format!("`{s}`: two positive sizes, A,B"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layer_sizes_are_positive_and_come_in_pairs() {
        assert_eq!(parse_two_sizes("64,48"), Ok([64, 48]));
        assert_eq!(parse_two_sizes(" 64, 96 "), Ok([64, 96]));
        for bad in ["64", "64,48,32", "0,48", "a,b", "", "64,"] {
            let e = parse_two_sizes(bad).unwrap_err();
            assert!(e.contains("two positive sizes"), "{bad}: {e}");
        }
        assert_eq!(parse_size("64"), Ok(64));
        assert!(parse_size("0").is_err());
        assert!(parse_size("-1").is_err());
    }

    #[test]
    fn the_last_epochs_go_through_the_rollout() {
        let mut cfg = TrainConfig::standard();
        Overrides {
            epochs: Some(10),
            rollout_last: Some(3),
            ..Default::default()
        }
        .apply(&mut cfg);
        assert_eq!(cfg.late_model(6), None);
        for e in 7..10 {
            let c = cfg.late_model(e).unwrap();
            assert!(c.parts.rollout_gradient);
            assert_eq!(c.parts.fed_speed, Some(crate::train::LATE_SPEED_WEIGHT));
            let mut back = c.clone();
            back.parts.rollout_gradient = false;
            back.parts.fed_speed = None;
            assert_eq!(back, cfg.model, "nothing else changes");
        }
        cfg.model.parts.fed_speed = Some(0.5);
        assert_eq!(cfg.late_model(9).unwrap().parts.fed_speed, Some(0.5));
        // The root weighed more in the late epochs only.
        Overrides {
            late_root_weight: Some(4.0),
            ..Default::default()
        }
        .apply(&mut cfg);
        assert_eq!(cfg.late_model(9).unwrap().parts.root_weight, Some(4.0));
        assert_eq!(cfg.model.parts.root_weight, None);
        assert_eq!(cfg.late_model(6), None);
        cfg.rollout_last = None;
        assert_eq!(cfg.late_model(9), None);
    }

    #[test]
    fn off_values_become_none_and_the_judge_keeps_its_period() {
        let mut cfg = TrainConfig::standard();
        Overrides {
            kl_weight: Some(1.0),
            clip: Some(0.0),
            early_stopping: Some(0),
            lr_final: Some(1.0),
            judge_every: Some(7),
            judge_stretches: Some(1),
            seed: Some(3),
            latent: Some(16),
            hidden: Some(64),
            extractor: Some([64, 48]),
            decoder: Some([40, 96]),
            inits: Some(1),
            feed_run: Some(1),
            average: Some(0.0),
            rollout_last: Some(0),
            late_root_weight: Some(1.0),
            ..Default::default()
        }
        .apply(&mut cfg);
        assert_eq!(cfg.rollout_last, None);
        assert_eq!(cfg.late_root_weight, None);
        assert_eq!(cfg.average, None);
        assert_eq!(cfg.inits, None);
        assert_eq!(cfg.feed_run, None);
        assert_eq!(cfg.model.latent, 16);
        assert_eq!(
            (cfg.model.hidden, cfg.model.extractor, cfg.model.decoder),
            (64, [64, 48], [40, 96])
        );
        assert_eq!(cfg.judge_stretches, None);
        assert_eq!(cfg.model.parts.kl_weight, None);
        assert_eq!(cfg.clip_grad_norm, None);
        assert_eq!(cfg.early_stopping, None);
        assert_eq!(cfg.lr_final, None);
        assert_eq!(cfg.select, Select::Generation { every: 7 });
        assert_eq!(cfg.seed, 3);
        // The paper preset chooses by loss; --judge-every alone keeps that.
        let mut paper = TrainConfig::paper();
        Overrides {
            judge_every: Some(7),
            ..Default::default()
        }
        .apply(&mut paper);
        assert_eq!(paper.select, Select::Loss);
        Overrides {
            select: Some(SelectBy::Generation),
            ..Default::default()
        }
        .apply(&mut paper);
        assert_eq!(paper.select, Select::Generation { every: 5 });
        Overrides {
            judge_stretches: Some(4),
            ..Default::default()
        }
        .apply(&mut paper);
        assert_eq!(paper.judge_stretches, Some(4));
        Overrides {
            inits: Some(3),
            ..Default::default()
        }
        .apply(&mut paper);
        let inits = crate::train::Inits {
            candidates: 3,
            epochs: crate::train::INIT_EPOCHS,
        };
        assert_eq!(paper.inits, Some(inits));
        assert_eq!(inits.seed(5, 2), 5 + (2 << 32));
        Overrides {
            feed_run: Some(8),
            ..Default::default()
        }
        .apply(&mut paper);
        assert_eq!(paper.feed_run, Some(8));
        Overrides {
            average: Some(0.95),
            ..Default::default()
        }
        .apply(&mut paper);
        assert_eq!(paper.average, Some(0.95));
        assert_eq!("loss".parse::<SelectBy>(), Ok(SelectBy::Loss));
        assert!("best".parse::<SelectBy>().is_err());
        assert_eq!(
            "paper".parse::<Preset>().map(Preset::config),
            Ok(TrainConfig::paper())
        );
        assert!("fast".parse::<Preset>().is_err());
    }

    #[test]
    fn the_minute_preset_is_the_standard_one_with_its_options_for_any_model() {
        let motion = || crate::model::Config::named("motion").unwrap_or_default();
        let minute = Preset::Minute.for_model(motion());
        // The same as `--feed-rounds 0 --rollouts-at-temperature --condition
        // category+pace --judge-stretches 14 --judge-every 10 --inits 3
        // --extractor 64,32 --decoder 64,96 --epochs 600 --early-stopping 0
        // --rollout-last 300 --late-root-weight 8` on `standard`.
        let mut flags = TrainConfig::standard();
        flags.model = motion();
        Overrides {
            feed_rounds: Some(0),
            rollouts_at_temperature: true,
            condition: Some(ConditionOn::CategoryPace),
            judge_stretches: Some(14),
            judge_every: Some(10),
            inits: Some(3),
            extractor: Some([64, 32]),
            decoder: Some([64, 96]),
            epochs: Some(600),
            early_stopping: Some(0),
            rollout_last: Some(300),
            late_root_weight: Some(8.0),
            ..Default::default()
        }
        .apply(&mut flags);
        assert_eq!(minute, flags);
        // Every epoch trained, the second half through the rollout with the
        // root weighed 8; the epochs before and the run's model as they were.
        assert_eq!((minute.epochs, minute.early_stopping), (600, None));
        assert_eq!(minute.late_model(299), None);
        let late = minute.late_model(300).unwrap_or_default();
        assert_eq!(late.parts.root_weight, Some(8.0));
        assert!(late.parts.rollout_gradient);
        assert_eq!(minute.model.parts.root_weight, None);
        // `--rollout-last 0` turns the late epochs off, their weight with them.
        let mut off = minute.clone();
        Overrides {
            rollout_last: Some(0),
            ..Default::default()
        }
        .apply(&mut off);
        assert_eq!((off.rollout_last, off.late_root_weight), (None, None));
        assert_eq!(
            (
                minute.model.extractor,
                minute.model.hidden,
                minute.model.latent
            ),
            ([64, 32], 32, 8)
        );
        // `--float-limit L` sets the ceiling, 0 turns it off again; the
        // model keeps its name.
        let mut held = minute.clone();
        let limit = |l: f64, c: &mut TrainConfig| {
            Overrides {
                float_limit: Some(l),
                ..Default::default()
            }
            .apply(c)
        };
        limit(3.0, &mut held);
        assert_eq!(held.model.parts.float_limit, Some(3.0));
        assert_eq!(held.model.name(), Some("motion"));
        assert!(held.extras().ends_with(
            ", generated figures at most 3 units off the floor, judged over 14 stretches, \
             from the best of 3 initialisations after 20 epochs"
        ));
        limit(0.0, &mut held);
        assert_eq!(held, minute);
        // A negative one is kept, for the model to refuse (not read as none).
        limit(-1.0, &mut held);
        assert_eq!(held.model.parts.float_limit, Some(-1.0));
        assert!(minute.model.parts.rollouts_at_temperature && minute.model.parts.pace);
        // `--contact-speed V` asks planted toes to be still; 0 turns it off.
        let mut still = minute.clone();
        let speed = |v: f64, c: &mut TrainConfig| {
            Overrides {
                contact_speed: Some(v),
                ..Default::default()
            }
            .apply(c)
        };
        speed(0.3, &mut still);
        assert_eq!(still.model.parts.contact_speed, Some(0.3));
        assert_eq!(still.model.name(), Some("motion"));
        assert!(still.extras().contains(", toes planted only below 0.3 m/s"));
        let units = still.model.parts.still_units().unwrap_or_default();
        assert!((units - 0.3 / 30.0 / 0.0564).abs() < 1e-6, "{units}");
        speed(0.0, &mut still);
        assert_eq!(
            still.model.parts.contact_speed,
            minute.model.parts.contact_speed
        );
        // Still named as its model, for every model (the checkpoint's name);
        // the late epochs only where the frames are fed back to a skeleton
        // (`motion`), the others stopping early as `standard` does.
        for (name, _) in crate::model::MODELS {
            let c = crate::model::Config::named(name).unwrap_or_default();
            let cfg = Preset::Minute.for_model(c);
            assert_eq!(cfg.model.name(), Some(name));
            let late = (name == "motion").then_some(300);
            assert_eq!(cfg.rollout_last, late, "{name}");
            let standard = TrainConfig::standard();
            let stops = standard.early_stopping;
            assert_eq!(cfg.early_stopping, late.map_or(stops, |_| None), "{name}");
            assert_eq!(cfg.epochs, late.map_or(standard.epochs, |_| 600), "{name}");
        }
        assert_eq!(minute.judge_stretches, Some(14));
        assert_eq!(minute.select, Select::Generation { every: 10 });
        assert_ne!(minute, Preset::Standard.for_model(motion()));
        assert_eq!(
            Preset::Standard.for_model(motion()),
            TrainConfig::standard()
        );
        // A user's option still wins: no condition, so no pace.
        let mut none = minute.clone();
        Overrides {
            condition: Some(ConditionOn::None),
            ..Default::default()
        }
        .apply(&mut none);
        assert!(none.condition.is_none() && !none.model.parts.pace);
        // The pace with the speed: both parts on; the plain pace, only one.
        let mut speed = minute.clone();
        Overrides {
            condition: "category+pace+speed".parse().ok(),
            ..Default::default()
        }
        .apply(&mut speed);
        assert!(speed.model.parts.pace && speed.model.parts.pace_speed);
        assert!(!minute.model.parts.pace_speed);
        assert!("pace+speed".parse::<ConditionOn>().is_err());
        assert_eq!("minute".parse::<Preset>(), Ok(Preset::Minute));
        assert_eq!(
            minute.extras(),
            " conditioned on the category and its pace (--condition none: neither), \
             fed back to every depth at the sampling temperature, the last 300 epochs \
             through the rollout with the fed speed loss and the root's motion weighed 8, \
             judged over 14 stretches, from the best of 3 initialisations after 20 epochs"
        );
        assert_eq!(
            none.extras(),
            ", fed back to every depth at the sampling temperature, the last 300 epochs \
             through the rollout with the fed speed loss and the root's motion weighed 8, \
             judged over 14 stretches, from the best of 3 initialisations after 20 epochs"
        );
        assert_eq!(
            TrainConfig::standard().extras(),
            " conditioned on the category (--condition none: without)"
        );
    }
}
