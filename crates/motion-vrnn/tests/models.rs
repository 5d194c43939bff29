//! Every model: the fused path against autograd of the same definition, the
//! paper model against the kernel it replaced, thread-count independence,
//! and what the skeleton part promises.

use candle_core::{Device, Tensor, Var};
use motion_vrnn::blocks;
use motion_vrnn::model::MODELS;
use motion_vrnn::rng::Rng;
use motion_vrnn::train::{feed_mask, init_model, named_vars, noise, sharded, Trained};
use motion_vrnn::{Config, MotionModel};

fn rel(a: &[f32], b: &[f32]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
    let den: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum();
    (num / den.max(1e-30)).sqrt()
}

fn batch(b: usize, t: usize, seed: u64) -> (Tensor, Tensor) {
    let x = Rng::new(seed, 1).normals(b * t * 58);
    let x = Tensor::from_vec(x, (b, t, 58), &Device::Cpu).unwrap();
    (x, noise(seed, 7, t, b, 8, &Device::Cpu).unwrap())
}

/// The named model with a body fitted to synthetic statistics: feature
/// means 0 except the root height (15) and std 2, so joints sit where the
/// random normalised data puts them.
fn model(name: &str, seed: u64) -> Trained {
    let mut c = Config::named(name).unwrap();
    let mut mean = vec![0.0; 58];
    mean[0] = 15.0;
    let std = vec![2.0; 58];
    let (x, _) = batch(4, 8, 100);
    c.fit_to(
        &mean,
        &std,
        &x.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
    );
    init_model(&c, seed, &Device::Cpu).unwrap()
}

fn sorted_vars(t: &Trained) -> Vec<(String, Var)> {
    let mut v = named_vars(&t.varmap);
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}

/// The scheduled-sampling mask a model is trained with at its full share
/// (None for models that do not feed back).
fn feed(m: &Trained, x: &Tensor) -> Option<Tensor> {
    let (b, t, _) = x.dims3().unwrap();
    let share = m.model.config().parts.self_feed;
    feed_mask(9, 1, b, t, share, &Device::Cpu).unwrap()
}

fn grads(t: &Trained, x: &Tensor, eps: &Tensor, w: f64) -> ((f32, f32), Vec<Vec<f32>>) {
    let vars: Vec<Var> = sorted_vars(t).into_iter().map(|v| v.1).collect();
    let (l, g) = sharded(
        &t.model,
        x,
        eps,
        feed(t, x).as_ref(),
        None,
        Some((w, &vars)),
    )
    .unwrap();
    let g = g.unwrap();
    let v = vars
        .iter()
        .map(|v| {
            g.get(v)
                .unwrap()
                .flatten_all()
                .unwrap()
                .to_vec1::<f32>()
                .unwrap()
        })
        .collect();
    (l, v)
}

/// The paper model gives the losses and gradients of the hand-written
/// kernel it replaced (frozen in `fixtures/`: 40 windows of 24 frames,
/// weights of seed 3, loss `recon + 0.7·kl`) to 1e-6 relative.
#[test]
fn paper_model_equals_the_former_kernel() {
    let names = include_str!("fixtures/paper_kernel_b40_t24.txt");
    let bytes = include_bytes!("fixtures/paper_kernel_b40_t24.bin");
    let want: Vec<f32> = bytes
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let m = init_model(&Config::default(), 3, &Device::Cpu).unwrap();
    let x = Tensor::from_vec(
        Rng::new(11, 1).normals(40 * 24 * 58),
        (40, 24, 58),
        &Device::Cpu,
    )
    .unwrap();
    let eps = noise(11, 7, 24, 40, 8, &Device::Cpu).unwrap();
    let ((recon, kl), g) = grads(&m, &x, &eps, 0.7);
    assert!(
        ((recon - want[0]) / want[0]).abs() < 1e-6,
        "recon {recon} vs {}",
        want[0]
    );
    assert!(
        ((kl - want[1]) / want[1]).abs() < 1e-6,
        "kl {kl} vs {}",
        want[1]
    );
    let mut at = 2;
    let vars = sorted_vars(&m);
    for (line, (name, gv)) in names.lines().zip(vars.iter().map(|v| &v.0).zip(&g)) {
        let (n, len) = line.split_once(' ').unwrap();
        assert_eq!(n, name);
        let len: usize = len.parse().unwrap();
        let e = rel(gv, &want[at..at + len]);
        assert!(e < 1e-6, "{name}: gradient off by {e:e} (relative)");
        at += len;
    }
    assert_eq!(at, want.len());
}

/// Each model's fused losses and gradients equal candle's autograd of the
/// same definition run through the blocks' references.
#[test]
fn every_model_matches_autograd() {
    for (name, _) in MODELS {
        let m = model(name, 4);
        let vars = sorted_vars(&m);
        let (x, eps) = batch(5, 9, 12);
        let fed = feed(&m, &x);
        let loss = |m: &dyn MotionModel| {
            let l = m.losses(&x, &eps, fed.as_ref(), None).unwrap();
            ((&l.recon + (&l.kl * 0.5).unwrap()).unwrap() + &l.extra).unwrap()
        };
        let fused = loss(&m.model);
        let reference = blocks::reference(|| loss(&m.model));
        let (a, r) = (
            fused.to_scalar::<f32>().unwrap(),
            reference.to_scalar::<f32>().unwrap(),
        );
        assert!(((a - r) / r).abs() < 1e-5, "{name}: loss {a} vs {r}");
        let (gf, gr) = (fused.backward().unwrap(), reference.backward().unwrap());
        let of = |g: &candle_core::backprop::GradStore, v: &Var| -> Vec<f32> {
            let t = g.get(v).unwrap().flatten_all().unwrap();
            t.to_vec1::<f32>().unwrap()
        };
        for (n, v) in &vars {
            let e = rel(&of(&gf, v), &of(&gr, v));
            assert!(e < 1e-4, "{name}: {n} gradient off by {e:e}");
        }
        // Reconstruction and sampling: the fused path equals the reference.
        let (rf, rr) = (
            m.model.reconstruct(&x, None).unwrap(),
            blocks::reference(|| m.model.reconstruct(&x, None).unwrap()),
        );
        let flat = |t: &Tensor| t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        assert!(rel(&flat(&rf), &flat(&rr)) < 1e-5, "{name}: reconstruct");
        let e = noise(1, 2, 9, 3, 8, &Device::Cpu).unwrap();
        let (sf, sr) = (
            m.model.sample(&e, None, None).unwrap(),
            blocks::reference(|| m.model.sample(&e, None, None).unwrap()),
        );
        assert_eq!(sf.dims(), &[3, 9, 58]);
        assert!(rel(&flat(&sf), &flat(&sr)) < 1e-4, "{name}: sample");
        // Started from 2 real frames: those come out unchanged, the rest
        // differs from the unstarted sample.
        let start = x.narrow(0, 0, 3).unwrap().narrow(1, 0, 2).unwrap();
        let s2 = m.model.sample(&e, Some(&start), None).unwrap();
        assert_eq!(flat(&s2.narrow(1, 0, 2).unwrap()), flat(&start));
        assert_ne!(
            flat(&s2.narrow(1, 2, 7).unwrap()),
            flat(&sf.narrow(1, 2, 7).unwrap())
        );
    }
}

/// Scheduled sampling: a mask of zeros gives the teacher-forced losses;
/// feeding back every frame changes them (the recurrence reads the model's
/// own frames) but not the first step's KL, whose state is still the
/// initial one.
#[test]
fn fed_back_frames_reach_the_recurrence_only() {
    for name in ["fed", "motion"] {
        let m = model(name, 5);
        let (x, eps) = batch(3, 7, 14);
        let losses = |mask: Option<f32>| {
            let f = mask.map(|v| Tensor::full(v, (3, 7), &Device::Cpu).unwrap());
            let l = m.model.losses(&x, &eps, f.as_ref(), None).unwrap();
            (
                l.recon.to_scalar::<f32>().unwrap(),
                l.kl.to_scalar::<f32>().unwrap(),
            )
        };
        let (none, zeros, ones) = (losses(None), losses(Some(0.0)), losses(Some(1.0)));
        assert!(
            ((none.0 - zeros.0) / none.0).abs() < 1e-6,
            "{name}: {none:?} vs {zeros:?}"
        );
        assert!(
            ((none.1 - zeros.1) / none.1).abs() < 1e-6,
            "{name}: {none:?} vs {zeros:?}"
        );
        assert!(
            (none.1 - ones.1).abs() > 1e-3 * none.1,
            "{name}: {none:?} vs {ones:?}"
        );
        assert_ne!(none.0, ones.0, "{name}");
        // One frame: nothing is fed back before the only step.
        let (x1, e1) = (x.narrow(1, 0, 1).unwrap(), eps.narrow(0, 0, 1).unwrap());
        let one = Tensor::ones((3, 1), candle_core::DType::F32, &Device::Cpu).unwrap();
        let (a, b) = (
            m.model.losses(&x1, &e1, None, None).unwrap(),
            m.model.losses(&x1, &e1, Some(&one), None).unwrap(),
        );
        assert_eq!(
            a.kl.to_scalar::<f32>().unwrap(),
            b.kl.to_scalar::<f32>().unwrap(),
            "{name}"
        );
    }
}

/// Rounds of feeding back: the first fed frame of a window is predicted
/// from real frames in every round, so with one fed frame a second round
/// changes nothing; in a run of fed frames the later ones are predicted
/// from the first round's predictions, so the losses change.
#[test]
fn a_second_round_rolls_out_runs_of_fed_frames() {
    let one = model("fed", 5);
    let mut c = one.model.config().clone();
    assert_eq!(c.parts.rounds(), 1);
    c.parts.feed_rounds = Some(2);
    let two = init_model(&c, 5, &Device::Cpu).unwrap();
    // Weights three times their initial scale, so the recurrence carries
    // what it reads (at the initial scale it forgets within a step or two).
    for m in [&one, &two] {
        for (_, v) in named_vars(&m.varmap) {
            v.set(&(v.as_tensor() * 3.0).unwrap()).unwrap();
        }
    }
    let (x, eps) = batch(3, 8, 21);
    let losses = |m: &Trained, mask: &[f32]| {
        let f = Tensor::from_vec(mask.repeat(3), (3, 8), &Device::Cpu).unwrap();
        let l = m.model.losses(&x, &eps, Some(&f), None).unwrap();
        [&l.recon, &l.kl].map(|v| v.to_scalar::<f32>().unwrap())
    };
    let single = [0., 0., 0., 1., 0., 0., 0., 0.];
    let (a, b) = (losses(&one, &single), losses(&two, &single));
    for (a, b) in a.iter().zip(&b) {
        assert!(((a - b) / a).abs() < 1e-6, "{a} vs {b}");
    }
    // A run: the second round moves the losses by a fair share of what
    // feeding back moves them at all.
    let run = [0., 1., 1., 1., 1., 1., 1., 0.];
    let (real, a, b) = (
        losses(&one, &[0.; 8]),
        losses(&one, &run),
        losses(&two, &run),
    );
    for k in 0..2 {
        let (fed, second) = ((a[k] - real[k]).abs(), (b[k] - a[k]).abs());
        assert!(
            second > 0.1 * fed && fed > 1e-4 * real[k],
            "{real:?} {a:?} {b:?}"
        );
    }
    c.parts.feed_rounds = Some(0);
    assert!(init_model(&c, 5, &Device::Cpu).is_err());
}

/// The temperature scales the prior's noise after the real start frames and
/// nothing else: sampling at temperature 0.5 is sampling at 1 with those
/// steps' noise halved; it leaves the losses alone; it must be positive.
#[test]
fn the_temperature_scales_the_prior_noise_only() {
    for name in ["paper", "motion"] {
        let mut m = model(name, 6);
        let (x, _) = batch(3, 9, 17);
        let (start, k) = (x.narrow(1, 0, 3).unwrap(), 3);
        let e = noise(4, 0, 9, 3, 8, &Device::Cpu).unwrap();
        let halved = Tensor::cat(
            &[
                e.narrow(0, 0, k).unwrap(),
                (e.narrow(0, k, 9 - k).unwrap() * 0.5).unwrap(),
            ],
            0,
        )
        .unwrap();
        let flat = |t: Tensor| t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let (x8, eps) = batch(2, 6, 3);
        let loss = |m: &Trained| flat(m.model.losses(&x8, &eps, None, None).unwrap().recon);
        m.model.set_temperature(None).unwrap();
        let want = flat(m.model.sample(&halved, Some(&start), None).unwrap());
        let plain = flat(m.model.sample(&e, Some(&start), None).unwrap());
        let l1 = loss(&m);
        m.model.set_temperature(Some(0.5)).unwrap();
        let got = flat(m.model.sample(&e, Some(&start), None).unwrap());
        assert!(rel(&got, &want) < 1e-6, "{name}");
        assert!(rel(&got, &plain) > 1e-3, "{name}");
        assert_eq!(loss(&m), l1, "{name}");
        for bad in [0.0, -1.0, f64::NAN] {
            assert!(m.model.set_temperature(Some(bad)).is_err(), "{name} {bad}");
        }
    }
}

/// The mask has the share asked for, and is a pure function of seed and step.
#[test]
fn feed_masks_have_their_share() {
    let m = feed_mask(1, 2, 40, 128, 0.3, &Device::Cpu)
        .unwrap()
        .unwrap();
    let v = m.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    let share = v.iter().sum::<f32>() / v.len() as f32;
    assert!((share - 0.3).abs() < 0.02, "{share}");
    assert!(v.iter().all(|&x| x == 0.0 || x == 1.0));
    let again = feed_mask(1, 2, 40, 128, 0.3, &Device::Cpu)
        .unwrap()
        .unwrap();
    assert_eq!(v, again.flatten_all().unwrap().to_vec1::<f32>().unwrap());
    assert!(feed_mask(1, 2, 4, 4, 0.0, &Device::Cpu).unwrap().is_none());
}

/// The losses and gradients of a batch are bit for bit the same with 1 and
/// 3 threads (shards are summed in order).
#[test]
fn results_do_not_depend_on_the_thread_count() {
    for name in ["paper", "motion"] {
        let m = model(name, 6);
        let (x, eps) = batch(70, 10, 13);
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| grads(&m, &x, &eps, 1.0))
        };
        let (a, b) = (run(1), run(3));
        assert_eq!(a.0, b.0, "{name}: losses");
        assert_eq!(a.1, b.1, "{name}: gradients");
    }
}

/// With the skeleton part, every bone keeps its length: the window's own in
/// a reconstruction, the training set's mean skeleton in a sample.
#[test]
fn skeleton_models_keep_their_bones() {
    let m = model("motion", 8);
    let body = m.model.config().body.clone().unwrap();
    let raw = |t: &Tensor| -> Vec<f32> {
        t.flatten_all()
            .unwrap()
            .to_vec1::<f32>()
            .unwrap()
            .iter()
            .enumerate()
            .map(|(i, v)| v * body.std[i % 58] + body.mean[i % 58])
            .collect()
    };
    let lengths = |raw: &[f32]| {
        let y: Vec<f32> = raw.chunks_exact(58).map(|r| r[0]).collect();
        let j: Vec<f32> = raw
            .chunks_exact(58)
            .flat_map(|r| r[1..55].to_vec())
            .collect();
        blocks::skeleton::bone_lengths(&y, &j)
    };
    let s = m
        .model
        .sample(&noise(3, 3, 12, 2, 8, &Device::Cpu).unwrap(), None, None)
        .unwrap();
    for (i, l) in lengths(&raw(&s)).iter().enumerate() {
        let want = body.bones[i % 18];
        assert!(
            (l - want).abs() < 1e-3 * want.max(1.0),
            "sample bone {}: {l} vs {want}",
            i % 18
        );
    }
    let (x, _) = batch(2, 6, 21);
    let r = m.model.reconstruct(&x, None).unwrap();
    let (got, real) = (lengths(&raw(&r)), lengths(&raw(&x)));
    for w in 0..2 {
        for b in 0..18 {
            let mean: f32 = (0..6).map(|t| real[(w * 6 + t) * 18 + b]).sum::<f32>() / 6.0;
            for t in 0..6 {
                let l = got[(w * 6 + t) * 18 + b];
                assert!(
                    (l - mean).abs() < 1e-3 * mean.max(1.0),
                    "window {w} bone {b}: {l} vs {mean}"
                );
            }
        }
    }
}

/// The KL weight warms up linearly to the model's own weight (1 unless the
/// model says otherwise); the share fed back rises to the model's over the
/// first half of the epochs.
#[test]
fn schedules_follow_the_model() {
    let mut c = motion_vrnn::train::TrainConfig::standard();
    c.kl_warmup_epochs = 20;
    c.epochs = 400;
    assert_eq!(c.kl_weight(9), 0.5);
    assert_eq!(c.kl_weight(30), 1.0);
    c.model.parts.kl_weight = Some(0.4);
    assert!((c.kl_weight(9) - 0.2).abs() < 1e-12);
    assert!((c.kl_weight(300) - 0.4).abs() < 1e-12);
    c.model.parts.self_feed = 0.5;
    assert!((c.feed_share(99) - 0.25).abs() < 1e-12);
    assert_eq!(c.feed_share(199), 0.5);
    assert_eq!(c.feed_share(399), 0.5);
    c.model.parts.self_feed = 0.0;
    assert_eq!(c.feed_share(399), 0.0);
}
