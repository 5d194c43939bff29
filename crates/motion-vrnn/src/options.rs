//! Presets and overrides of a [`TrainConfig`]: a preset is the starting
//! point, and every `cargo xtask train` option given replaces its value.

use crate::train::{Select, TrainConfig};

/// The starting point of a training configuration.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Preset {
    /// [`TrainConfig::standard`]: the four-second model.
    Standard,
    /// [`TrainConfig::quick`], a quick look.
    Quick,
    /// [`TrainConfig::paper`], exactly the paper.
    Paper,
    /// The default of `cargo xtask train`: `standard` for a minute of
    /// motion ([`Preset::overrides`]): fed back to every depth in one pass,
    /// drawn at the sampling temperature, conditioned on the category and
    /// the pace, the judge over 14 stretches every 10 epochs, from the best
    /// of 3 initialisations after 20 epochs, with a wider extractor and
    /// decoder ([`MINUTE_EXTRACTOR`], [`MINUTE_DECODER`]),
    /// [`MINUTE_EPOCHS`] epochs, every one trained (no early stopping), the
    /// last [`MINUTE_LATE`] through the rollout with the root's motion
    /// weighed [`MINUTE_LATE_ROOT_WEIGHT`]; all of it a budget of the
    /// windows those epochs see on [`SAMPLES_TRAIN_WINDOWS`]
    /// ([`TrainConfig::budget`]), so on another dataset every count of
    /// epochs is scaled to it.
    Minute,
}

/// The `minute` preset's feature-extractor sizes: the paper's 48, 32 widened
/// to 64, 32.
pub const MINUTE_EXTRACTOR: [usize; 2] = [64, 32];

/// The `minute` preset's decoder sizes: the paper's 32, 48 doubled.
pub const MINUTE_DECODER: [usize; 2] = [64, 96];

/// The `minute` preset's epochs (`--epochs`; `standard`'s 400 for a model
/// without the late epochs).
pub const MINUTE_EPOCHS: usize = 600;

/// The `minute` preset's last epochs through the rollout
/// (`--rollout-last`; [`TrainConfig::rollout_last`]): the second half of
/// its [`MINUTE_EPOCHS`], where the learning rate anneals.
pub const MINUTE_LATE: usize = 300;

/// The training windows of the shared CMU samples' dataset (`cargo xtask
/// dataset --source` the BVH and the ASF/AMC sample): the size the
/// `minute` preset's epochs are counted at; its budget is its epochs times
/// these ([`Preset::for_model`]).
pub const SAMPLES_TRAIN_WINDOWS: u64 = 776;

/// The root's weight in the `minute` preset's late epochs
/// (`--late-root-weight`; [`TrainConfig::late_root_weight`]).
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
                condition: Some(ConditionOn::CategoryPaceControl),
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
    /// keeps `standard`'s. `minute` sets its epochs as a budget: the
    /// windows they see on [`SAMPLES_TRAIN_WINDOWS`].
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
        if self == Preset::Minute {
            cfg.budget = Some(cfg.epochs as u64 * SAMPLES_TRAIN_WINDOWS);
        }
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
    /// The category, the pace and, at every frame, where the root goes
    /// over the next second ([`crate::model::Parts::control`]): a model
    /// that can be steered.
    CategoryPaceControl,
}

impl std::str::FromStr for ConditionOn {
    type Err = String;
    fn from_str(s: &str) -> Result<ConditionOn, String> {
        match s {
            "none" => Ok(ConditionOn::None),
            "category" => Ok(ConditionOn::Category),
            "category+pace" => Ok(ConditionOn::CategoryPace),
            "category+pace+control" => Ok(ConditionOn::CategoryPaceControl),
            _ => Err(format!(
                "unknown condition {s:?}; choose `category+pace+control`, `category+pace`, `category` or `none`"
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
/// "off" value is given (e.g. a clip of 0) the configuration stores
/// "none", as the presets do. Every field but the last two is a `cargo
/// xtask train` option; those two only a preset sets.
#[derive(Clone, Debug, Default)]
pub struct Overrides {
    /// Sampling temperature (1: the prior as trained).
    pub temperature: Option<f64>,
    /// Feature-extractor layer sizes (the paper's 48, 32).
    pub extractor: Option<[usize; 2]>,
    /// Decoder layer sizes (the paper's 32, 48).
    pub decoder: Option<[usize; 2]>,
    /// Epochs (in place of a budget).
    pub epochs: Option<usize>,
    /// Training windows seen ([`TrainConfig::budget`]; 0: none, the
    /// epochs as they are); `epochs` wins.
    pub budget: Option<u64>,
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
    /// Initialisations tried, each for [`crate::train::INIT_EPOCHS`]
    /// epochs, the best on validation kept ([`crate::train::Inits`]; 1: the
    /// seed's alone).
    pub inits: Option<usize>,
    /// The last epochs through the rollout ([`TrainConfig::rollout_last`]; 0: none).
    pub rollout_last: Option<usize>,
    /// The root's weight in those epochs ([`TrainConfig::late_root_weight`];
    /// 1: the ELBO's).
    pub late_root_weight: Option<f64>,
    /// Rounds of feeding back ([`crate::model::Parts::feed_rounds`]; 1: one
    /// step deep; 0: every depth).
    pub feed_rounds: Option<usize>,
    /// Feed rounds drawn at the sampling temperature
    /// ([`crate::model::Parts::rollouts_at_temperature`]; `true`: on).
    pub rollouts_at_temperature: bool,
}

impl Overrides {
    /// `cfg` with every given value in place of its own.
    pub fn apply(&self, cfg: &mut TrainConfig) {
        let parts = &mut cfg.model.parts;
        if let Some(v) = self.feed_rounds {
            parts.feed_rounds = (v != 1).then_some(v);
        }
        if let Some(v) = self.temperature {
            parts.temperature = (v != 1.0).then_some(v);
        }
        if self.rollouts_at_temperature {
            parts.rollouts_at_temperature = true;
        }
        if let Some(v) = self.extractor {
            cfg.model.extractor = v;
        }
        if let Some(v) = self.decoder {
            cfg.model.decoder = v;
        }
        self.apply_training(cfg);
        self.apply_choice(cfg);
    }

    /// The training schedule's values of `self` into `cfg` (budget, epochs,
    /// batch, learning rate, seed, warm-up, clipping, stopping, judge,
    /// inits, late epochs).
    fn apply_training(&self, cfg: &mut TrainConfig) {
        if let Some(v) = self.budget {
            cfg.budget = (v > 0).then_some(v);
        }
        if let Some(v) = self.epochs {
            cfg.epochs = v;
            cfg.budget = None;
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
    }

    /// The condition and the checkpoint choice of `self` into `cfg`.
    fn apply_choice(&self, cfg: &mut TrainConfig) {
        match self.condition {
            Some(ConditionOn::None) => {
                cfg.condition = None;
                cfg.model.parts.pace = false;
                cfg.model.parts.control = false;
            }
            Some(on) => {
                cfg.condition = Some(crate::train::Conditioning {
                    dropout: crate::train::CONDITION_DROPOUT,
                });
                cfg.model.parts.pace = on != ConditionOn::Category;
                cfg.model.parts.control = on == ConditionOn::CategoryPaceControl;
            }
            None => {}
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

/// A positive layer size.
fn parse_size(s: &str) -> Result<usize, String> {
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
            clip: Some(0.0),
            early_stopping: Some(0),
            lr_final: Some(1.0),
            judge_every: Some(7),
            judge_stretches: Some(1),
            seed: Some(3),
            extractor: Some([64, 48]),
            decoder: Some([40, 96]),
            inits: Some(1),
            rollout_last: Some(0),
            late_root_weight: Some(1.0),
            ..Default::default()
        }
        .apply(&mut cfg);
        assert_eq!(cfg.rollout_last, None);
        assert_eq!(cfg.late_root_weight, None);
        assert_eq!(cfg.inits, None);
        assert_eq!(
            (cfg.model.extractor, cfg.model.decoder),
            ([64, 48], [40, 96])
        );
        assert_eq!(cfg.judge_stretches, None);
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
        assert_eq!("loss".parse::<SelectBy>(), Ok(SelectBy::Loss));
        assert!("best".parse::<SelectBy>().is_err());
        assert_eq!(
            "paper".parse::<Preset>().map(Preset::config),
            Ok(TrainConfig::paper())
        );
        assert!("fast".parse::<Preset>().is_err());
    }

    #[test]
    fn the_minute_preset_is_named_as_its_model_for_every_model() {
        // Named as its model, for every model (the checkpoint's name);
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
            assert_eq!(cfg.budget, Some(cfg.epochs as u64 * 776), "{name}");
        }
    }

    #[test]
    fn the_minute_budget_scales_every_count_of_epochs_to_the_dataset() {
        let motion = crate::model::Config::named("motion").unwrap_or_default();
        let minute = Preset::Minute.for_model(motion);
        // On the samples' 776 windows, the schedule as it is: 600 epochs.
        assert_eq!(minute.for_windows(776), minute);
        // 465,600 / 777 = 599.2: 599 epochs.
        assert_eq!(minute.for_windows(777).epochs, 599);
        // On 13,625 windows (the samples ×17): 465,600 / 13,625 = 34.17,
        // 34 epochs; each count × 34/600, rounded, at least 1.
        let big = minute.for_windows(13_625);
        assert_eq!((big.epochs, big.budget), (34, Some(465_600)));
        assert_eq!(big.rollout_last, Some(17)); // 300 × 34/600 = 17
        assert_eq!(big.kl_warmup_epochs, 1); // 20 × 34/600 = 1.13
        assert_eq!(big.select, Select::Generation { every: 1 }); // 10 → 0.57
        assert_eq!(big.inits.map(|i| i.epochs), Some(1)); // 20 → 1.13
        assert_eq!(big.early_stopping, None);
        // The late epochs are the last 17 (epochs 18–34, 1-based), where
        // the learning rate anneals: 1e-3 through epoch 17, a half cosine
        // over the 17 after it, 1e-4 at the last; the feed ramp ends at 17,
        // and the judge starts there.
        assert_eq!(big.late_model(16), None);
        assert!(big.late_model(17).is_some_and(|c| c.parts.rollout_gradient));
        assert_eq!((big.lr(0), big.lr(16)), (1e-3, 1e-3));
        // Epoch 26 (1-based): 1e-3 × (0.1 + 0.9 × (1 + cos(π·9/17)) / 2).
        assert!(
            (big.lr(25) - 5.084_792_382e-4).abs() < 1e-12,
            "{}",
            big.lr(25)
        );
        assert!((big.lr(33) - 1e-4).abs() < 1e-15);
        assert_eq!(big.feed_share(0), big.model.parts.self_feed * (1.0 / 17.0));
        assert_eq!(big.feed_share(16), big.model.parts.self_feed);
        assert_eq!(big.schedule_end(), 17);
        // Scaled once for good; everything else as it was.
        assert_eq!(big.for_windows(13_625), big);
        let back = TrainConfig {
            epochs: 600,
            kl_warmup_epochs: 20,
            select: Select::Generation { every: 10 },
            inits: minute.inits,
            rollout_last: Some(300),
            ..big.clone()
        };
        assert_eq!(back, minute);
        // A dataset of 100 windows: 4,656 epochs, the late 2,328, the
        // warm-up 155 (20 × 7.76 = 155.2), the judge every 78 (77.6).
        let small = minute.for_windows(100);
        assert_eq!((small.epochs, small.rollout_last), (4656, Some(2328)));
        assert_eq!(small.kl_warmup_epochs, 155);
        assert_eq!(small.select, Select::Generation { every: 78 });
        // `standard`'s early stopping scales too; --epochs wins over a budget.
        let mut standard = TrainConfig::standard();
        Overrides {
            budget: Some(400 * 776),
            ..Default::default()
        }
        .apply(&mut standard);
        let half = standard.for_windows(1552);
        assert_eq!((half.epochs, half.early_stopping), (200, Some(30)));
        assert_eq!(half.kl_warmup_epochs, 10);
        let mut fixed = minute.clone();
        Overrides {
            budget: Some(1000),
            epochs: Some(40),
            ..Default::default()
        }
        .apply(&mut fixed);
        assert_eq!(fixed.budget, None);
        assert_eq!(fixed.for_windows(13_625).epochs, 40);
        assert_eq!(fixed.for_windows(13_625).rollout_last, Some(300));
    }

    #[test]
    fn the_minute_preset_is_the_standard_one_with_its_options_for_any_model() {
        let motion = || crate::model::Config::named("motion").unwrap_or_default();
        let minute = Preset::Minute.for_model(motion());
        // The same as `standard` fed back to every depth at the sampling
        // temperature, with `--condition category+pace+control --judge-stretches 14
        // --judge-every 10 --inits 3 --extractor 64,32 --decoder 64,96
        // --epochs 600 --early-stopping 0 --rollout-last 300
        // --late-root-weight 8`.
        let mut flags = TrainConfig::standard();
        flags.model = motion();
        Overrides {
            feed_rounds: Some(0),
            rollouts_at_temperature: true,
            condition: Some(ConditionOn::CategoryPaceControl),
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
        // The epochs as a budget: what 600 see on the samples' 776 windows.
        assert_eq!(minute.budget, Some(600 * 776));
        assert_eq!(
            minute,
            TrainConfig {
                budget: Some(465_600),
                ..flags
            }
        );
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
        assert!(minute.model.parts.rollouts_at_temperature && minute.model.parts.pace);
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
        assert!(none.condition.is_none() && !none.model.parts.pace && !none.model.parts.control);
        assert!("category+pace+speed".parse::<ConditionOn>().is_err());
        assert_eq!("minute".parse::<Preset>(), Ok(Preset::Minute));
        assert_eq!(
            minute.extras(),
            " conditioned on the category, its pace and a path to follow (--condition none: none of them), \
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
