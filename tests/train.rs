//! End to end: a dataset from a few real CMU files, a few training steps, a
//! checkpoint that reloads to the same loss; the NaN guard.

use motion_vrnn::data::load;
use motion_vrnn::generate::{sample_windows, Judge, Rollout};
use motion_vrnn::train::{
    layout, load_model, noise, read_meta, train, Conditioning, Quiet, Select, TrainConfig,
    TrainError,
};
use motion_vrnn::MotionModel;
use std::path::Path;

/// Motions of `frames` frames continuing `context` frames, seed 3.
fn roll(frames: usize, context: usize) -> Rollout {
    Rollout {
        frames,
        context,
        seed: 3,
        ask: None,
        pace_gain: 0.0,
        draws: 1,
    }
}

fn small_dataset(dir: &Path) -> std::path::PathBuf {
    integration_tests::small_dataset(dir, [0.5, 0.5, 0.0])
}

fn tiny_config() -> TrainConfig {
    TrainConfig {
        batch: 8,
        epochs: 2,
        ..TrainConfig::quick()
    }
}

#[test]
fn train_checkpoint_reload_gives_the_same_loss() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let ds = small_dataset(tmp.path());
    let data = load(&ds, &["train", "val"]).unwrap();
    let tr = &data.splits["train"];
    assert!(tr.n >= 8, "{} train windows", tr.n);
    let run = tmp.path().join("run");
    let dev = candle_core::Device::Cpu;
    let out = train(&data, &tiny_config(), &run, false, &dev, &Quiet).unwrap();
    assert_eq!(out.history.len(), 2);
    assert!(out
        .history
        .iter()
        .all(|m| m.train_recon.is_finite() && m.val_kl.is_finite()));
    for f in [layout::MODEL, layout::OPTIMIZER, layout::META] {
        assert!(run.join(layout::LAST).join(f).is_file(), "{f}");
    }
    assert!(run.join(layout::BEST).join(layout::MODEL).is_file());
    assert_eq!(
        std::fs::read_to_string(run.join(layout::METRICS))
            .unwrap()
            .lines()
            .count(),
        2
    );

    let (reloaded, meta) = load_model(&run.join(layout::LAST), &dev).unwrap();
    assert_eq!(meta.epoch, 2);
    assert_eq!(meta.dataset_manifest_sha256, data.manifest_sha256);
    let idx: Vec<usize> = (0..8).collect();
    let x = tr.batch(&idx, &dev).unwrap();
    let eps = noise(42, 0, tr.length, 8, 8, &dev).unwrap();
    let a = out.model.model.losses(&x, &eps, None, None).unwrap();
    let b = reloaded.model.losses(&x, &eps, None, None).unwrap();
    let s = |t: &candle_core::Tensor| t.to_scalar::<f32>().unwrap();
    assert_eq!(s(&a.recon), s(&b.recon));
    assert_eq!(s(&a.kl), s(&b.kl));

    // A second run into the same directory must ask for --resume.
    let err = train(&data, &tiny_config(), &run, false, &dev, &Quiet)
        .err()
        .unwrap();
    assert!(err.to_string().contains("--resume"), "{err}");
    // Resuming with other options names them.
    let mut other = tiny_config();
    other.condition = Some(Conditioning { dropout: 0.1 });
    other.batch = 4;
    let err = train(&data, &other, &run, true, &dev, &Quiet)
        .err()
        .unwrap();
    let e = err.to_string();
    assert!(
        e.contains("batch: 8 → 4") && e.contains("condition: null →"),
        "{e}"
    );

    // A checkpoint with settings this version does not have (an older
    // version's options) loads, ignoring them, and is not resumed.
    let meta_path = run.join(layout::LAST).join(layout::META);
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&meta_path).unwrap()).unwrap();
    v["config"]["mirror"] = true.into();
    v["config"]["model"]["parts"]["swing"] = 1.0.into();
    std::fs::write(&meta_path, v.to_string()).unwrap();
    let (old, _) = load_model(&run.join(layout::LAST), &dev).unwrap();
    let c = old.model.losses(&x, &eps, None, None).unwrap();
    assert_eq!(s(&a.recon), s(&c.recon));
    let err = train(&data, &tiny_config(), &run, true, &dev, &Quiet)
        .err()
        .unwrap();
    let e = err.to_string();
    assert!(
        e.contains("mirror") && e.contains("model.parts.swing") && e.contains("not resumed"),
        "{e}"
    );
}

#[test]
fn a_learning_rate_that_cannot_train_is_refused() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let data = load(&small_dataset(tmp.path()), &["train", "val"]).unwrap();
    let dev = candle_core::Device::Cpu;
    let refused = |cfg: TrainConfig, what: &str| {
        let run = tmp.path().join(what);
        let err = train(&data, &cfg, &run, false, &dev, &Quiet).err().unwrap();
        assert!(err.to_string().contains(what), "{err}");
        // Refused before anything is written.
        assert!(!run.join(layout::LAST).exists());
    };
    let mut cfg = tiny_config();
    cfg.adam.lr = -1e-3;
    refused(cfg, "learning rate must be positive");
    let mut cfg = tiny_config();
    cfg.model.latent = 0;
    refused(cfg, "latent size must be at least 1");
    let mut cfg = tiny_config();
    cfg.model.hidden = 0;
    refused(cfg, "hidden size must be at least 1");
    let mut cfg = tiny_config();
    cfg.model.extractor[1] = 0;
    refused(
        cfg,
        "extractor's layer sizes (--extractor) must be at least 1",
    );
    let mut cfg = tiny_config();
    cfg.model.decoder[0] = 0;
    refused(cfg, "decoder's layer sizes (--decoder) must be at least 1");
    for f in [0.0, -0.5, 1.5, f64::NAN] {
        let cfg = TrainConfig {
            lr_final: Some(f),
            ..tiny_config()
        };
        refused(cfg, "--lr-final");
    }
}

#[test]
fn a_non_finite_loss_stops_with_the_step_and_keeps_the_checkpoint() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let ds = small_dataset(tmp.path());
    let mut data = load(&ds, &["train", "val"]).unwrap();
    let run = tmp.path().join("run");
    let dev = candle_core::Device::Cpu;
    let cfg = TrainConfig {
        epochs: 1,
        ..tiny_config()
    };
    train(&data, &cfg, &run, false, &dev, &Quiet).unwrap();
    let before = std::fs::read(run.join(layout::LAST).join(layout::MODEL)).unwrap();
    let steps = motion_vrnn::train::read_meta(&run.join(layout::LAST))
        .unwrap()
        .step;
    // Poison the data, then resume for one more epoch: its first step stops.
    let w = data.splits.get_mut("train").unwrap();
    w.data.iter_mut().for_each(|v| *v = f32::NAN);
    let cfg2 = TrainConfig {
        epochs: 2,
        ..tiny_config()
    };
    let err = train(&data, &cfg2, &run, true, &dev, &Quiet).err().unwrap();
    match &err {
        TrainError::NonFinite { step, epoch, .. } => assert_eq!((*step, *epoch), (steps + 1, 2)),
        other => panic!("{other}"),
    }
    assert!(
        err.to_string().contains(&format!("step {}", steps + 1)),
        "{err}"
    );
    // The last good checkpoint is untouched.
    assert_eq!(
        std::fs::read(run.join(layout::LAST).join(layout::MODEL)).unwrap(),
        before
    );
    assert_eq!(
        motion_vrnn::train::read_meta(&run.join(layout::LAST))
            .unwrap()
            .epoch,
        1
    );
}

#[test]
fn best_is_the_epoch_whose_generated_motion_scores_best() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let ds = small_dataset(tmp.path());
    let data = load(&ds, &["train", "val"]).unwrap();
    let run = tmp.path().join("run");
    let dev = candle_core::Device::Cpu;
    let cfg = TrainConfig {
        epochs: 4,
        kl_warmup_epochs: 2,
        select: Select::Generation { every: 2 },
        ..tiny_config()
    };
    assert_eq!(cfg.schedule_end(), 2);
    let out = train(&data, &cfg, &run, false, &dev, &Quiet).unwrap();
    // Judged at epochs 2 and 4 only.
    let judged: Vec<(usize, f64)> = out
        .history
        .iter()
        .filter_map(|m| m.generated.as_ref().map(|v| (m.epoch, v.score)))
        .collect();
    assert_eq!(judged.iter().map(|j| j.0).collect::<Vec<_>>(), [2, 4]);
    assert!(judged.iter().all(|j| j.1.is_finite() && j.1 >= 0.0));
    let want = *judged.iter().min_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
    let best = read_meta(&run.join(layout::BEST)).unwrap();
    assert_eq!(best.epoch, want.0);
    assert_eq!(best.best_generated, Some((want.1, want.0)));
    assert_eq!(
        read_meta(&run.join(layout::LAST)).unwrap().best_generated,
        Some((want.1, want.0))
    );
    // The judge is deterministic: the last model judged again gives the
    // verdict of epoch 4.
    let judge = Judge::new(&data).unwrap();
    let again = judge.judge(&out.model.model, &dev).unwrap();
    assert_eq!(Some(&again), out.history[3].generated.as_ref());
    assert!(judge.real().contact_share > 0.0 && judge.frechet_ref() > 0.0);
    // Rolled out for 3 windows, the first stretch is the one-window
    // verdict's (same noise, same context) and the last one adds its score.
    let long = Judge::new(&data).unwrap().stretches(3);
    let v = long.judge(&out.model.model, &dev).unwrap();
    assert_eq!(v.generated, again.generated);
    assert_eq!(v.frechet, again.frechet);
    let (last, last_frechet) = v.last.clone().expect("the last stretch is measured");
    assert_ne!(last, again.generated);
    let last_score =
        motion_metrics::goal_distance(judge.real(), &last, last_frechet, judge.frechet_ref());
    assert!((v.score - (again.score + last_score)).abs() < 1e-9 * v.score.max(1.0));
}

#[test]
fn judging_starts_once_the_schedule_is_in_full() {
    // The standard schedule: the default model feeds back its own frames,
    // rising to their full share over half of the 400 epochs.
    let standard = TrainConfig::standard();
    assert_eq!(standard.schedule_end(), 200);
    // Without scheduled sampling: the end of the KL warm-up.
    let paper = TrainConfig {
        model: motion_vrnn::model::Config::named("paper").unwrap(),
        ..TrainConfig::standard()
    };
    assert_eq!(paper.schedule_end(), 20);
    // Never past the last epoch.
    let short = TrainConfig {
        epochs: 10,
        ..paper
    };
    assert_eq!(short.schedule_end(), 10);
}

#[test]
fn learning_rate_anneals_over_the_second_half() {
    // 10 epochs at 1e-3, annealed to a tenth: constant for epochs 0–4, then
    // 1e-3 · (0.1 + 0.9 · (1 + cos πp) / 2) with p = (epoch + 1 − 5) / 5.
    let cfg = TrainConfig {
        epochs: 10,
        lr_final: Some(0.1),
        ..TrainConfig::paper()
    };
    let want = [
        (0, 1e-3),
        (4, 1e-3),
        (5, 1e-3 * (0.1 + 0.45 * (1.0 + 0.809_016_994_374_947_5))),
        (7, 1e-3 * (0.1 + 0.45 * (1.0 - 0.309_016_994_374_947_4))),
        (9, 1e-4),
    ];
    for (epoch, lr) in want {
        assert!(
            (cfg.lr(epoch) - lr).abs() < 1e-15,
            "epoch {epoch}: {} against {lr}",
            cfg.lr(epoch)
        );
    }
    // The paper's schedule keeps its constant rate; the standard one anneals.
    let paper = TrainConfig::paper();
    assert!((0..paper.epochs).all(|e| paper.lr(e) == 1e-3));
    let standard = TrainConfig::standard();
    assert_eq!(standard.lr(199), 1e-3);
    assert!((standard.lr(399) - 1e-4).abs() < 1e-15);
}

#[test]
fn generated_motions_continue_their_real_context() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let ds = small_dataset(tmp.path());
    let data = load(&ds, &["train", "val"]).unwrap();
    let dev = candle_core::Device::Cpu;
    let cfg = TrainConfig {
        epochs: 1,
        ..tiny_config()
    };
    let out = train(&data, &cfg, &tmp.path().join("run"), false, &dev, &Quiet).unwrap();
    let train_w = &data.splits["train"];
    let (f, k, frames) = (train_w.features, 5, 10);
    let gen = sample_windows(&out.model.model, train_w, 6, &roll(frames, k), &dev).unwrap();
    assert_eq!(gen.len(), 6);
    // Each motion starts at the last context frame of some training window
    // (bit for bit: a real frame is read, not decoded), then moves on.
    for m in &gen {
        assert_eq!(m.len(), frames * f);
        let first = &m[..f];
        let found = train_w
            .data
            .chunks(train_w.length * f)
            .any(|w| &w[(k - 1) * f..k * f] == first);
        assert!(found, "a motion does not start at a context frame");
        assert!(m[f..2 * f] != m[..f], "the second frame is generated");
    }
    // The same seed gives the same motions.
    let again = sample_windows(&out.model.model, train_w, 6, &roll(frames, k), &dev).unwrap();
    assert_eq!(gen, again);
    // Restarted every 4 frames, a motion of 13 frames is made in runs: the
    // first run is the unrestarted motion's start (the same noise), later
    // runs continue the frames made; the same seed gives the same motion.
    let mut restarted = out.model.model.clone();
    restarted.set_restart(Some(4));
    let long =
        |m: &motion_vrnn::model::Vrnn| sample_windows(m, train_w, 3, &roll(13, k), &dev).unwrap();
    let (once, runs) = (long(&out.model.model), long(&restarted));
    for (a, b) in once.iter().zip(&runs) {
        assert_eq!(b.len(), 13 * f);
        assert_eq!(&a[..5 * f], &b[..5 * f], "the first run");
        assert_ne!(&a[5 * f..], &b[5 * f..], "later runs restart");
    }
    assert_eq!(runs, long(&restarted));
    // A context longer than a window, or none, is refused.
    for bad in [0, train_w.length + 1] {
        let e = sample_windows(&out.model.model, train_w, 2, &roll(frames, bad), &dev).unwrap_err();
        assert!(e.to_string().contains("context"), "{e}");
    }
}
