//! Every model: the fused path against autograd of the same definition, the
//! paper model against the kernel it replaced, thread-count independence,
//! and what the skeleton part promises.

use candle_core::{Device, Tensor, Var};
use motion_vrnn::blocks;
use motion_vrnn::model::{COND_WEIGHT, MODELS};
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
    (l, vars.iter().map(|v| grad_of(&g, v)).collect())
}

/// The gradient of `v` in `g`, flat.
fn grad_of(g: &candle_core::backprop::GradStore, v: &Var) -> Vec<f32> {
    g.get(v)
        .unwrap()
        .flatten_all()
        .unwrap()
        .to_vec1::<f32>()
        .unwrap()
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

/// The fused losses `recon + 0.5·kl + extra` of `m` equal the reference's
/// (relative 1e-5) and so do all its gradients (1e-4); the fused
/// gradients.
fn fused_matches_reference(
    name: &str,
    m: &Trained,
    x: &Tensor,
    eps: &Tensor,
    fed: Option<&Tensor>,
    cond: Option<&Tensor>,
) -> candle_core::backprop::GradStore {
    let loss = |m: &dyn MotionModel| {
        let l = m.losses(x, eps, fed, cond).unwrap();
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
    for (n, v) in sorted_vars(m) {
        let e = rel(&grad_of(&gf, &v), &grad_of(&gr, &v));
        assert!(e < 1e-4, "{name}: {n} gradient off by {e:e}");
    }
    gf
}

/// Each model's fused losses and gradients equal candle's autograd of the
/// same definition run through the blocks' references.
#[test]
fn every_model_matches_autograd() {
    for (name, _) in MODELS {
        let m = model(name, 4);
        let (x, eps) = batch(5, 9, 12);
        let fed = feed(&m, &x);
        fused_matches_reference(name, &m, &x, &eps, fed.as_ref(), None);
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
}

/// Feeding back to every depth in one pass (`feed_rounds` 0) gives what
/// rounds give once there are as many rounds as fed frames, and differs
/// from two rounds; on the default's parts (filters, skeleton, feet, the
/// category and its pace, rollouts at the temperature).
#[test]
fn one_pass_in_time_order_is_every_round() {
    let mut c = model("motion", 5).model.config().clone();
    c.categories = CATEGORIES.map(String::from).to_vec();
    c.parts.pace = true;
    c.parts.rollouts_at_temperature = true;
    let with = |rounds: usize| {
        let mut c = c.clone();
        c.parts.feed_rounds = Some(rounds);
        let m = init_model(&c, 5, &Device::Cpu).unwrap();
        randomise(&m);
        for (_, v) in named_vars(&m.varmap) {
            v.set(&(v.as_tensor() * 3.0).unwrap()).unwrap();
        }
        m
    };
    let (x, eps) = batch(3, 8, 21);
    let mask: [f32; 8] = [0., 1., 1., 0., 1., 1., 1., 0.];
    let f = Tensor::from_vec(mask.repeat(3), (3, 8), &Device::Cpu).unwrap();
    let losses = |m: &Trained| {
        let cond = ask(m, &[Some(1), None, Some(3)], 1.0);
        let l = m.model.losses(&x, &eps, Some(&f), Some(&cond)).unwrap();
        [&l.recon, &l.kl, &l.extra].map(|v| v.to_scalar::<f32>().unwrap() as f64)
    };
    let (all, five, two) = (losses(&with(0)), losses(&with(5)), losses(&with(2)));
    // The fused pass against its reference, the model's step loop in
    // candle ops (as every block runs off the CPU).
    let slow = blocks::reference(|| losses(&with(0)));
    for k in 0..3 {
        let d = |a: f64, b: f64| ((a - b) / a).abs();
        assert!(d(all[k], five[k]) < 1e-5, "{all:?} vs {five:?}");
        assert!(d(all[k], slow[k]) < 1e-5, "{all:?} vs {slow:?}");
        assert!(d(all[k], two[k]) > 1e-4, "{all:?} vs {two:?}");
    }
}

/// The gradient through the rollout (`rollout_gradient`) leaves the losses
/// as they are (the same frames fed back) and changes the gradients, which
/// now also reach the weights through the fed frames. It needs feeding back
/// to every depth.
#[test]
fn the_gradient_through_the_rollout_changes_the_gradients_only() {
    let mut c = model("motion", 5).model.config().clone();
    c.parts.feed_rounds = Some(0);
    let with = |set: &dyn Fn(&mut Config)| {
        let mut c = c.clone();
        set(&mut c);
        let m = init_model(&c, 5, &Device::Cpu).unwrap();
        for (_, v) in named_vars(&m.varmap) {
            v.set(&(v.as_tensor() * 3.0).unwrap()).unwrap();
        }
        m
    };
    let (x, eps) = batch(3, 8, 21);
    let ((ra, ka), ga) = grads(&with(&|_| ()), &x, &eps, 1.0);
    let d = |a: f32, b: f32| ((a - b) / a).abs();
    let ((rb, kb), gb) = grads(&with(&|c| c.parts.rollout_gradient = true), &x, &eps, 1.0);
    assert!(d(ra, rb) < 1e-5 && d(ka, kb) < 1e-5, "{ra} {rb} {ka} {kb}");
    assert!(rel(&ga.concat(), &gb.concat()) > 1e-3);
    c.parts.rollout_gradient = true;
    c.parts.feed_rounds = None;
    assert!(init_model(&c, 5, &Device::Cpu).is_err());
}

/// The fed speed loss (`fed_speed`), with the gradient through the rollout,
/// leaves the reconstruction and KL as they are and changes the gradients
/// (it reaches the weights through the fed frames); it needs a positive
/// weight and the skeleton's statistics.
#[test]
fn the_fed_speed_loss_changes_the_gradients_only() {
    let mut c = model("motion", 5).model.config().clone();
    c.parts.feed_rounds = Some(0);
    c.parts.rollout_gradient = true;
    let (x, eps) = batch(3, 8, 21);
    let with = |c: &Config, w: Option<f64>| {
        let mut c = c.clone();
        c.parts.fed_speed = w;
        init_model(&c, 5, &Device::Cpu)
    };
    let (a, ga) = grads(&with(&c, None).unwrap(), &x, &eps, 1.0);
    let (b, gb) = grads(&with(&c, Some(1.0)).unwrap(), &x, &eps, 1.0);
    assert_eq!(a, b);
    assert!(rel(&ga.concat(), &gb.concat()) > 1e-4);
    let t = with(&c, Some(1.0)).unwrap();
    let l = t
        .model
        .losses(&x, &eps, feed(&t, &x).as_ref(), None)
        .unwrap();
    assert!(l.extra.to_scalar::<f32>().unwrap() > 0.0);
    assert!(with(&c, Some(0.0)).is_err() && with(&c, Some(-1.0)).is_err());
    c.body = None;
    assert!(with(&c, Some(1.0)).is_err());
}

/// The root's weight (`root_weight`) adds `(w − 1)` times the root
/// features' squared error to the extra losses and leaves the reported
/// reconstruction and KL alone: linear in `w − 1`, zero at 1, and the
/// gradients move.
#[test]
fn the_root_weight_changes_the_gradients_only() {
    let c = model("motion", 5).model.config().clone();
    let (x, eps) = batch(3, 8, 21);
    let with = |w: Option<f64>| {
        let mut c = c.clone();
        c.parts.root_weight = w;
        init_model(&c, 5, &Device::Cpu)
    };
    let extra = |w: Option<f64>| {
        let t = with(w).unwrap();
        let l = t
            .model
            .losses(&x, &eps, feed(&t, &x).as_ref(), None)
            .unwrap();
        l.extra.to_scalar::<f32>().unwrap() as f64
    };
    let (e1, e2, e4) = (extra(None), extra(Some(2.0)), extra(Some(4.0)));
    assert!(e2 > e1, "{e1} {e2}");
    assert!(
        ((e4 - e1) - 3.0 * (e2 - e1)).abs() < 1e-3 * (e4 - e1),
        "{e1} {e2} {e4}"
    );
    let (a, ga) = grads(&with(None).unwrap(), &x, &eps, 1.0);
    let (b, gb) = grads(&with(Some(4.0)).unwrap(), &x, &eps, 1.0);
    assert_eq!(a, b);
    assert!(rel(&ga.concat(), &gb.concat()) > 1e-4);
    assert!(with(Some(0.0)).is_err() && with(Some(-1.0)).is_err());
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

/// `rollouts_at_temperature`: the feed rounds draw the prior's latent at the
/// model's temperature, so the fed-back frames and the losses move; with
/// nothing fed back, or at temperature 1, the losses are the model's own,
/// to the bit; off, nothing changes (the default models' bits).
#[test]
fn rollouts_at_the_temperature_scale_the_fed_back_draws() {
    let base = model("motion", 7);
    let mut c = base.model.config().clone();
    assert!(c.parts.temperature.is_some_and(|t| t < 1.0));
    assert!(!c.parts.rollouts_at_temperature);
    c.parts.rollouts_at_temperature = true;
    let hot = init_model(&c, 7, &Device::Cpu).unwrap();
    let (x, eps) = batch(3, 8, 23);
    let mask = feed(&base, &x);
    assert!(mask.is_some());
    let losses = |m: &Trained, f: Option<&Tensor>| {
        let l = m.model.losses(&x, &eps, f, None).unwrap();
        [&l.recon, &l.kl, &l.extra].map(|v| v.to_scalar::<f32>().unwrap())
    };
    assert_ne!(losses(&hot, mask.as_ref()), losses(&base, mask.as_ref()));
    assert_eq!(losses(&hot, None), losses(&base, None));
    c.parts.temperature = None;
    let cold = init_model(&c, 7, &Device::Cpu).unwrap();
    let mut plain = c.clone();
    plain.parts.rollouts_at_temperature = false;
    let plain = init_model(&plain, 7, &Device::Cpu).unwrap();
    assert_eq!(losses(&cold, mask.as_ref()), losses(&plain, mask.as_ref()));
    // Absent from a checkpoint's JSON, it is off.
    let json = serde_json::to_string(base.model.config()).unwrap();
    assert!(!json.contains("rollouts_at_temperature"));
}

/// What the generation-only settings are probed with: 3 start frames of 3
/// motions, noise for 9 frames, and a batch whose losses must not change.
fn generation_probe() -> (Tensor, Tensor, Tensor, Tensor) {
    let (x, _) = batch(3, 9, 17);
    let start = x.narrow(1, 0, 3).unwrap();
    let e = noise(4, 0, 9, 3, 8, &Device::Cpu).unwrap();
    let (x8, eps) = batch(2, 6, 3);
    (start, e, x8, eps)
}

/// The foot lock's sharpness changes generated frames only, and only in a
/// model with the foot lock: 1 is the model as trained, bit for bit; 4
/// moves the generated root; the losses ignore it; it must be positive.
#[test]
fn contact_sharpness_changes_the_generated_foot_lock_only() {
    for (name, locks) in [("paper", false), ("motion", true)] {
        let mut m = model(name, 6);
        let (start, e, x8, eps) = generation_probe();
        let flat = |t: Tensor| t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let loss = |m: &Trained| flat(m.model.losses(&x8, &eps, None, None).unwrap().recon);
        let plain = flat(m.model.sample(&e, Some(&start), None).unwrap());
        let l1 = loss(&m);
        m.model.set_contact_sharpness(Some(1.0)).unwrap();
        assert_eq!(
            flat(m.model.sample(&e, Some(&start), None).unwrap()),
            plain,
            "{name}"
        );
        m.model.set_contact_sharpness(Some(4.0)).unwrap();
        let sharp = flat(m.model.sample(&e, Some(&start), None).unwrap());
        // The start frames (3 × 58 values per motion) stay as they are.
        let f = 58;
        for k in 0..3 {
            let row = k * 9 * f;
            assert_eq!(sharp[row..row + 3 * f], plain[row..row + 3 * f], "{name}");
        }
        assert_eq!(rel(&sharp, &plain) > 1e-4, locks, "{name}");
        assert_eq!(loss(&m), l1, "{name}");
        for bad in [0.0, -1.0, f64::NAN] {
            assert!(
                m.model.set_contact_sharpness(Some(bad)).is_err(),
                "{name} {bad}"
            );
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
    for name in ["paper", "motion", "every depth", "through the rollout"] {
        let m = match name {
            "every depth" | "through the rollout" => {
                let mut c = model("motion", 6).model.config().clone();
                c.parts.feed_rounds = Some(0);
                if name == "through the rollout" {
                    c.parts.rollout_gradient = true;
                    c.parts.fed_speed = Some(1.0);
                    c.parts.root_weight = Some(8.0);
                }
                init_model(&c, 6, &Device::Cpu).unwrap()
            }
            _ => model(name, 6),
        };
        let (x, eps) = batch(70, 16, 13);
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

// Conditioning on a category (`train --condition category`): a conditioned
// model starts as the unconditioned one, "no category" is row 0 of the
// condition table, asking for a category changes the motion, guidance
// weighs the rows as documented, the fused path matches autograd, and the
// errors name what can be asked.

const CATEGORIES: [&str; 3] = ["walk", "run", "dance"];

/// The named model of [`model`] (seed 4), conditioned on [`CATEGORIES`] or
/// not.
fn conditioned(name: &str, on: bool) -> Trained {
    let mut c = model(name, 4).model.config().clone();
    if on {
        c.categories = CATEGORIES.map(String::from).to_vec();
    }
    init_model(&c, 4, &Device::Cpu).unwrap()
}

fn table(m: &Trained) -> Var {
    named_vars(&m.varmap)
        .into_iter()
        .find(|v| v.0 == COND_WEIGHT)
        .unwrap()
        .1
}

/// A condition table of random rows (a trained one is not zero).
fn randomise(m: &Trained) {
    let t = table(m);
    let v: Vec<f32> = Rng::new(8, 8)
        .normals(t.elem_count())
        .iter()
        .map(|v| 0.5 * v)
        .collect();
    t.set(&Tensor::from_vec(v, t.shape(), &Device::Cpu).unwrap())
        .unwrap();
}

/// The losses and every variable's gradient of a batch ([`sharded`]) on
/// `threads` threads.
fn sharded_on(
    threads: usize,
    m: &Trained,
    x: &Tensor,
    eps: &Tensor,
    fed: Option<&Tensor>,
    cond: Option<&Tensor>,
) -> ((f32, f32), Vec<Vec<f32>>) {
    let vars: Vec<Var> = named_vars(&m.varmap).into_iter().map(|v| v.1).collect();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        let (l, g) = sharded(&m.model, x, eps, fed, cond, Some((1.0, &vars))).unwrap();
        let g = g.unwrap();
        (l, vars.iter().map(|v| flat(g.get(v).unwrap())).collect())
    })
}

fn flat(t: &Tensor) -> Vec<f32> {
    t.flatten_all().unwrap().to_vec1::<f32>().unwrap()
}

fn ask(m: &Trained, rows: &[Option<usize>], guidance: f64) -> Tensor {
    m.model
        .config()
        .condition(rows, guidance, &Device::Cpu)
        .unwrap()
        .unwrap()
}

#[test]
fn a_conditioned_model_starts_as_the_unconditioned_one() {
    for name in ["paper", "motion"] {
        let (plain, cond) = (conditioned(name, false), conditioned(name, true));
        // The same variables with the same values, and a zero table of
        // one row per category and one for "no category".
        let mut vars = named_vars(&cond.varmap);
        vars.sort_by(|a, b| a.0.cmp(&b.0));
        let t = table(&cond);
        assert_eq!(t.dims()[0], CATEGORIES.len() + 1);
        assert!(flat(t.as_tensor()).iter().all(|v| *v == 0.0));
        let mut others = named_vars(&plain.varmap);
        others.sort_by(|a, b| a.0.cmp(&b.0));
        let without: Vec<_> = vars.iter().filter(|v| v.0 != COND_WEIGHT).collect();
        assert_eq!(without.len(), others.len(), "{name}");
        for (a, b) in without.iter().zip(&others) {
            assert_eq!(a.0, b.0);
            assert_eq!(
                flat(a.1.as_tensor()),
                flat(b.1.as_tensor()),
                "{name}: {}",
                a.0
            );
        }
        let (x, eps) = batch(3, 6, 5);
        let walk = ask(&cond, &[Some(1); 3], 1.0);
        let (a, b) = (
            plain.model.losses(&x, &eps, None, None).unwrap(),
            cond.model.losses(&x, &eps, None, Some(&walk)).unwrap(),
        );
        assert_eq!(flat(&a.recon), flat(&b.recon), "{name}");
        assert_eq!(flat(&a.kl), flat(&b.kl), "{name}");
        let e = noise(1, 2, 9, 3, 8, &Device::Cpu).unwrap();
        assert_eq!(
            flat(&plain.model.sample(&e, None, None).unwrap()),
            flat(&cond.model.sample(&e, None, Some(&walk)).unwrap()),
            "{name}"
        );
    }
}

#[test]
fn no_category_is_row_zero_and_a_category_changes_the_motion() {
    let m = conditioned("motion", true);
    randomise(&m);
    let (x, eps) = batch(3, 6, 5);
    let start = x.narrow(1, 0, 2).unwrap();
    let e = noise(1, 2, 9, 3, 8, &Device::Cpu).unwrap();
    let sample = |c: Option<&Tensor>| flat(&m.model.sample(&e, Some(&start), c).unwrap());
    let none = sample(None);
    assert_eq!(none, sample(Some(&ask(&m, &[None; 3], 1.0))));
    // Guidance 0 is no category; a category at guidance 1 is another motion.
    assert_eq!(none, sample(Some(&ask(&m, &[Some(2); 3], 0.0))));
    let run = sample(Some(&ask(&m, &[Some(2); 3], 1.0)));
    assert_ne!(none, run);
    assert_ne!(run, sample(Some(&ask(&m, &[Some(3); 3], 1.0))));
    // Each sequence reads its own row: the first of a mixed batch is the
    // first of an all-`run` batch.
    let mixed = sample(Some(&ask(&m, &[Some(2), Some(3), None], 1.0)));
    let per = 9 * 58;
    assert_eq!(mixed[..per], run[..per]);
    assert_eq!(mixed[2 * per..], none[2 * per..]);
    // The losses and reconstructions read the condition too.
    let l = |c: Option<&Tensor>| flat(&m.model.losses(&x, &eps, None, c).unwrap().recon);
    assert_ne!(l(None), l(Some(&ask(&m, &[Some(1); 3], 1.0))));
    let r = |c: Option<&Tensor>| flat(&m.model.reconstruct(&x, c).unwrap());
    assert_ne!(r(None), r(Some(&ask(&m, &[Some(1); 3], 1.0))));
}

#[test]
fn guidance_weighs_the_category_against_no_category() {
    let m = conditioned("paper", true);
    // Row 0 gets 1 − g, the category's row g: g = 2.5 → −1.5 and 2.5.
    let w = flat(&ask(&m, &[Some(3), None], 2.5));
    assert_eq!(w, vec![-1.5, 0.0, 0.0, 2.5, 1.0, 0.0, 0.0, 0.0]);
    // An unconditioned model gives no weights; a row out of range is an error.
    let plain = conditioned("paper", false);
    let c = plain
        .model
        .config()
        .condition(&[Some(1)], 1.0, &Device::Cpu);
    assert!(c.unwrap().is_none());
    assert!(m
        .model
        .config()
        .condition(&[Some(4)], 1.0, &Device::Cpu)
        .is_err());
}

#[test]
fn the_conditioned_fused_path_matches_autograd() {
    for name in ["paper", "motion"] {
        let m = conditioned(name, true);
        randomise(&m);
        let (x, eps) = batch(5, 9, 12);
        let c = ask(&m, &[Some(1), Some(2), None, Some(3), Some(1)], 1.0);
        let gf = fused_matches_reference(name, &m, &x, &eps, None, Some(&c));
        // Every row asked for learns; the sharded sum over threads is the
        // same for any thread count.
        let g = flat(gf.get(&table(&m)).unwrap());
        let width = g.len() / 4;
        for row in g.chunks(width) {
            assert!(
                row.iter().any(|v| *v != 0.0),
                "{name}: a row without gradient"
            );
        }
        let (x, eps) = batch(70, 4, 3);
        let rows: Vec<Option<usize>> = (0..70).map(|i| (i % 4 > 0).then_some(i % 4)).collect();
        let c = ask(&m, &rows, 1.0);
        let run = |threads| sharded_on(threads, &m, &x, &eps, None, Some(&c));
        assert_eq!(run(1), run(3), "{name}");
    }
}

#[test]
fn asking_names_what_can_be_asked() {
    let (plain, cond) = (conditioned("paper", false), conditioned("paper", true));
    let c = cond.model.config();
    assert_eq!(c.category_row("walk"), Ok(1));
    assert_eq!(c.category_row("Dance"), Ok(3));
    let unknown = c.category_row("salsa").unwrap_err();
    assert!(
        unknown.contains("unknown category") && unknown.contains("gesture"),
        "{unknown}"
    );
    let absent = c.category_row("floor").unwrap_err();
    assert!(
        absent.contains("not trained with floor") && absent.contains("walk, run, dance"),
        "{absent}"
    );
    let none = plain.model.config().category_row("walk").unwrap_err();
    assert!(none.contains("--condition category"), "{none}");
    // Asking an unconditioned model through the trait is an error too.
    let e = noise(1, 2, 4, 1, 8, &Device::Cpu).unwrap();
    let w = Tensor::new(&[[0f32, 1.0]], &Device::Cpu).unwrap();
    assert!(plain.model.sample(&e, None, Some(&w)).is_err());
}

#[test]
fn the_pace_is_four_means_read_where_a_category_is_asked() {
    // `pace`: per sequence, the mean over its frames of root_y, vel_x,
    // vel_z and ang_vel_y (features 0, 55, 56, 57).
    let mut v = vec![0f32; 2 * 3 * 58];
    for (k, f) in [0, 55, 56, 57, 1, 54].into_iter().enumerate() {
        for t in 0..3 {
            v[t * 58 + f] = (k + 1) as f32 * t as f32; // 0, k+1, 2(k+1): mean k+1
            v[(3 + t) * 58 + f] = -2.0;
        }
    }
    let x = Tensor::from_vec(v, (2, 3, 58), &Device::Cpu).unwrap();
    let p = flat(&motion_vrnn::model::pace(&x).unwrap());
    assert_eq!(p, vec![1.0, 2.0, 3.0, 4.0, -2.0, -2.0, -2.0, -2.0]);

    // The table gains a row per pace feature, zero at the start.
    let mut c = conditioned("motion", true).model.config().clone();
    c.parts.pace = true;
    let m = init_model(&c, 4, &Device::Cpu).unwrap();
    assert_eq!(table(&m).dims()[0], CATEGORIES.len() + 1 + 4);
    randomise(&m);
    // The same model without the pace, its table the first rows of `m`'s.
    let plain = conditioned("motion", true);
    let rows = table(&m).as_tensor().narrow(0, 0, CATEGORIES.len() + 1);
    table(&plain).set(&rows.unwrap()).unwrap();

    let (x, eps) = batch(3, 6, 5);
    let start = x.narrow(1, 0, 2).unwrap();
    let e = noise(1, 2, 9, 3, 8, &Device::Cpu).unwrap();
    let sample =
        |t: &Trained, c: Option<&Tensor>| flat(&t.model.sample(&e, Some(&start), c).unwrap());
    let loss = |t: &Trained, c: Option<&Tensor>| {
        let l = t.model.losses(&x, &eps, None, c).unwrap();
        (flat(&l.recon), flat(&l.kl))
    };
    let (none, walk) = (ask(&m, &[None; 3], 1.0), ask(&m, &[Some(1); 3], 1.0));
    // No category asked: the pace is not read.
    assert_eq!(sample(&m, Some(&none)), sample(&plain, Some(&none)));
    assert_eq!(sample(&m, None), sample(&plain, None));
    assert_eq!(loss(&m, Some(&none)), loss(&plain, Some(&none)));
    // A category asked: it is, in training and in generation.
    assert_ne!(sample(&m, Some(&walk)), sample(&plain, Some(&walk)));
    assert_ne!(loss(&m, Some(&walk)), loss(&plain, Some(&walk)));
    // Generation without start frames asks for the mean pace (0).
    let f = |t: &Trained| flat(&t.model.sample(&e, None, Some(&walk)).unwrap());
    assert_eq!(f(&m), f(&plain));
    // Weights that carry their pace already are kept as they are (how
    // generation asks for a window's own pace).
    let asked = m
        .model
        .config()
        .paced(Some(&walk), Some(&x))
        .unwrap()
        .unwrap();
    assert_eq!(asked.dims(), [3, CATEGORIES.len() + 1 + 4]);
    let again = m.model.config().paced(Some(&asked), None).unwrap().unwrap();
    assert_eq!(flat(&again), flat(&asked));
    let whole = |c: &Tensor| flat(&m.model.sample(&e, Some(&start), Some(c)).unwrap());
    assert_ne!(whole(&asked), sample(&m, Some(&walk)));
    // With its pace rows at zero the model is the one without the pace.
    let t = table(&m);
    let kept = t.as_tensor().narrow(0, 0, CATEGORIES.len() + 1).unwrap();
    let zero = Tensor::zeros((4, t.dims()[1]), candle_core::DType::F32, &Device::Cpu).unwrap();
    t.set(&Tensor::cat(&[&kept, &zero], 0).unwrap()).unwrap();
    assert_eq!(sample(&m, Some(&walk)), sample(&plain, Some(&walk)));
    assert_eq!(loss(&m, Some(&walk)), loss(&plain, Some(&walk)));
}

#[test]
fn asking_pace_weighs_the_pace_as_paced_does() {
    let mut c = conditioned("motion", true).model.config().clone();
    c.parts.pace = true;
    let m = init_model(&c, 4, &Device::Cpu).unwrap();
    let c = m.model.config();
    // Row 1 at guidance 1.25: weights [−0.25, 1.25, 0, 0], the pace × 1.25.
    let mut v = vec![0f32; 2 * 58];
    for (&f, p) in motion_vrnn::model::PACE_FEATURES
        .iter()
        .zip([1f32, 2.0, 3.0, 4.0])
    {
        v[f] = p;
        v[58 + f] = p;
    }
    let x = Tensor::from_vec(v, (1, 2, 58), &Device::Cpu).unwrap();
    let cond = c
        .paced(Some(&ask(&m, &[Some(1)], 1.25)), Some(&x))
        .unwrap()
        .unwrap();
    assert_eq!(flat(&cond), [-0.25, 1.25, 0.0, 0.0, 1.25, 2.5, 3.75, 5.0]);
    let target = motion_vrnn::model::pace(&x).unwrap();
    // Asking for its own pace changes nothing.
    assert_eq!(flat(&c.asking_pace(&cond, &target).unwrap()), flat(&cond));
    // Another pace, weighed by 1.25.
    let want = Tensor::new(&[[1.5f32, 2.0, 2.0, 4.0]], &Device::Cpu).unwrap();
    assert_eq!(
        flat(&c.asking_pace(&cond, &want).unwrap()),
        [-0.25, 1.25, 0.0, 0.0, 1.875, 2.5, 2.5, 5.0]
    );
    // Weights without their pace are refused.
    let bare = ask(&m, &[Some(1)], 1.25);
    assert!(c.asking_pace(&bare, &target).is_err());
}

#[test]
fn a_given_control_asks_for_its_own_pace() {
    use mocap_ingest::features::{ANG_VEL_Y, VEL_X, VEL_Z};
    let mut c = conditioned("motion", true).model.config().clone();
    (c.parts.pace, c.parts.control) = (true, true);
    // Statistics: vel_z of mean 1 and std 2, the rest 0 and 1.
    let (mut mean, mut std) = (vec![0f32; 58], vec![1f32; 58]);
    (mean[VEL_Z], std[VEL_Z]) = (1.0, 2.0);
    c.body = Some(motion_vrnn::model::Body {
        mean,
        std,
        bones: vec![1.0; 18],
        contact_height: 0.0,
    });
    // Row 1 at guidance 1.25, paced [1, 2, 3, 4] (× 1.25).
    let cond = Tensor::new(
        &[[-0.25f32, 1.25, 0.0, 0.0, 1.25, 2.5, 3.75, 5.0]; 2],
        &Device::Cpu,
    )
    .unwrap();
    // A straight walk of 2 units a frame: vel_z (2 − 1) / 2 = 0.5, × 1.25;
    // vel_x and ang_vel_y 0; root_y kept. A free row keeps its pace, and so
    // does a row asking to stand (0.05 units a frame: 0.085 m/s).
    let walk = motion_steer::control_of_motion(&[[0.0, 2.0, 0.0]; 40])[0];
    let stand = motion_steer::control_of_motion(&[[0.0, 0.05, 0.0]; 40])[0];
    let free = [0.0; motion_steer::CONTROL];
    let cond = Tensor::cat(&[&cond, &cond.narrow(0, 0, 1).unwrap()], 0).unwrap();
    let ctl = Tensor::new(&[walk, free, stand], &Device::Cpu).unwrap();
    let got = flat(&c.control_pace(&cond, &ctl).unwrap());
    let want = [-0.25, 1.25, 0.0, 0.0, 1.25, 0.0, 0.625, 0.0];
    for (g, w) in got[..8].iter().zip(want) {
        assert!((g - w).abs() < 1e-5, "{got:?}");
    }
    assert_eq!(got[8..], flat(&cond)[8..]);
    assert_eq!([VEL_X, VEL_Z, ANG_VEL_Y], [55, 56, 57]);
    // Weights without their pace are left as they are.
    let bare = cond.narrow(1, 0, 4).unwrap();
    assert_eq!(flat(&c.control_pace(&bare, &ctl).unwrap()), flat(&bare));
}

#[test]
fn motions_are_held_to_their_pace_run_by_run() {
    use motion_vrnn::data::Windows;
    use motion_vrnn::generate::{
        continue_windows, Ask, Rollout, PACE_CORRECTIONS, PACE_EVERY, PACE_GAIN,
    };
    use motion_vrnn::model::pace;
    let with_pace = |pace: bool| {
        let mut c = conditioned("motion", true).model.config().clone();
        c.parts.pace = pace;
        let m = init_model(&c, 4, &Device::Cpu).unwrap();
        randomise(&m);
        m
    };
    let (paced, plain) = (with_pace(true), with_pace(false));
    let (len, f, k) = (16, 58, 4);
    let windows = Windows {
        data: Rng::new(5, 5)
            .normals(3 * len * f)
            .iter()
            .map(|v| 0.5 * v)
            .collect(),
        n: 3,
        length: len,
        features: f,
    };
    let walk = Some(Ask {
        row: 1,
        guidance: 1.25,
    });
    let run = |m: &motion_vrnn::model::Vrnn, frames, picks: &[usize], ask, pace_gain, draws| {
        let o = Rollout {
            frames,
            context: k,
            seed: 2,
            ask,
            pace_gain,
            draws,
        };
        continue_windows(m, &windows, picks, &o, &Device::Cpu).unwrap()
    };
    // One window, by hand: the weights asking for each context's pace, tried
    // on the draw's noise, each try's ask moved by gain × (target − made).
    let one = PACE_EVERY + 1;
    let c = paced.model.config();
    let by_hand = |picks: &[usize], d: u64, held: bool| {
        let whole = windows.batch(picks, &Device::Cpu).unwrap();
        let context = whole.narrow(1, 0, k).unwrap();
        let rows: Vec<_> = picks.iter().map(|_| Some(1)).collect();
        let asking = c
            .paced(Some(&ask(&paced, &rows, 1.25)), Some(&context))
            .unwrap()
            .unwrap();
        let target = pace(&context).unwrap();
        let seed = 2 ^ 0x5A3F1E ^ (d << 40);
        let eps =
            motion_vrnn::rng::noise(seed, 0, k + one - 1, picks.len(), c.latent, &Device::Cpu)
                .unwrap();
        let made = |cond: &Tensor| {
            let x = paced
                .model
                .sample(&eps, Some(&context), Some(cond))
                .unwrap();
            x.narrow(1, k - 1, one).unwrap()
        };
        let (mut want, mut cond) = (target.clone(), asking.clone());
        for _ in 0..PACE_CORRECTIONS * usize::from(held) {
            let off = (&target - pace(&made(&cond)).unwrap()).unwrap();
            want = (&want + (off * PACE_GAIN).unwrap()).unwrap();
            cond = c.asking_pace(&asking, &want).unwrap();
        }
        (made(&cond), context.mean(1).unwrap())
    };
    let held = run(&paced.model, one, &[1], walk, PACE_GAIN, 1);
    assert_eq!(held[0], flat(&by_hand(&[1], 0, true).0));
    let free = run(&paced.model, one, &[1], walk, 0.0, 1);
    assert_eq!(held[0][..f], free[0][..f], "the same start frame");
    assert_ne!(held[0][f..], free[0][f..], "asked for another pace");
    assert_eq!(
        free[0],
        flat(&by_hand(&[1], 0, false).0),
        "not held: as trained"
    );
    // Chosen among draws: each motion keeps the held draw whose mean pose is
    // closest to its context's.
    let picks = [0, 1, 2];
    let draws: Vec<_> = (0..3).map(|d| by_hand(&picks, d, true)).collect();
    let chosen = run(&paced.model, one, &picks, walk, PACE_GAIN, 3);
    let mut kept = Vec::new();
    for (i, motion) in chosen.iter().enumerate() {
        let off = |(x, pose): &(Tensor, Tensor)| {
            let x = x.get(i).unwrap();
            let d = (x.mean(0).unwrap() - pose.get(i).unwrap()).unwrap();
            d.sqr()
                .unwrap()
                .sum_all()
                .unwrap()
                .to_scalar::<f32>()
                .unwrap()
        };
        let offs: Vec<f32> = draws.iter().map(off).collect();
        let best = (0..3).fold(0, |b, d| if offs[d] < offs[b] { d } else { b });
        assert_eq!(*motion, flat(&draws[best].0.get(i).unwrap()), "motion {i}");
        kept.push(best);
    }
    assert_ne!(
        kept,
        [0, 0, 0],
        "some motion keeps another draw than the first"
    );
    // A long motion: runs of PACE_EVERY, each held, each restarting on the
    // last frames made.
    let frames = 2 * PACE_EVERY + 20;
    let held = run(&paced.model, frames, &[0, 2], walk, PACE_GAIN, 2);
    let mut restarted = paced.model.clone();
    restarted.set_restart(Some(PACE_EVERY));
    let runs = run(&restarted, frames, &[0, 2], walk, 0.0, 2);
    let first = (PACE_EVERY + 1) * f;
    for (h, r) in held.iter().zip(&runs) {
        assert_eq!(h.len(), frames * f);
        assert_ne!(h[..first], r[..first]);
        assert_ne!(h[first..], r[first..]);
    }
    assert_eq!(
        held,
        run(&paced.model, frames, &[0, 2], walk, PACE_GAIN, 2),
        "the same seed, the same motion"
    );
    // Nothing to hold without a pace asked: no category, or no pace part.
    for (m, a) in [(&paced.model, None), (&plain.model, walk)] {
        assert_eq!(
            run(m, frames, &[0, 2], a, PACE_GAIN, 2),
            run(m, frames, &[0, 2], a, 0.0, 1)
        );
    }
}

/// A generated motion reads its context and nothing after it: changing
/// every frame of the windows after the context leaves the motions (and so
/// the pace asked and held, and the draw kept) unchanged, with the default
/// sampler, one free draw, and the judge's window condition; changing one
/// context frame changes them.
#[test]
fn generated_motion_never_reads_past_its_context() {
    use motion_vrnn::data::Windows;
    use motion_vrnn::generate::{continue_windows, continue_windows_with, Ask, Rollout};
    let mut c = conditioned("motion", true).model.config().clone();
    c.parts.pace = true;
    let m = init_model(&c, 4, &Device::Cpu).unwrap();
    randomise(&m);
    let (n, len, f, k) = (3, 24, 58, 5);
    let data: Vec<f32> = Rng::new(9, 9)
        .normals(n * len * f)
        .iter()
        .map(|v| 0.5 * v)
        .collect();
    let windows = |data: Vec<f32>| Windows {
        data,
        n,
        length: len,
        features: f,
    };
    let (real, mut future, mut past) = (windows(data.clone()), data.clone(), data);
    // Every frame after the context: a figure racing off, turning, higher.
    for w in 0..n {
        for v in &mut future[(w * len + k) * f..(w + 1) * len * f] {
            *v = 3.0 - *v * 2.0;
        }
    }
    past[(2 * len + k - 1) * f + 3] += 1.0;
    let (future, past) = (windows(future), windows(past));
    let picks = [0, 1, 2];
    let ask = Some(Ask {
        row: 1,
        guidance: 1.4,
    });
    for (pace_gain, draws, frames) in [(0.5, 3, 40), (0.0, 1, 40), (0.5, 2, 300)] {
        let o = Rollout {
            frames,
            context: k,
            seed: 4,
            ask,
            pace_gain,
            draws,
        };
        let gen = |w: &Windows| continue_windows(&m.model, w, &picks, &o, &Device::Cpu).unwrap();
        let base = gen(&real);
        let same = base == gen(&future);
        assert!(same, "gain {pace_gain}, {draws} draws: the future was read");
        assert!(base[2] != gen(&past)[2], "a context frame must matter");
        // The judge's way: each window asking for its own category.
        let labels = [motion_vrnn::data::Category::Walk; 3];
        let judged = |w: &Windows| {
            let cond = m
                .model
                .config()
                .window_condition(&labels, &picks, 1.0, |_| false, &Device::Cpu)
                .unwrap();
            continue_windows_with(&m.model, w, &picks, &o, cond, &Device::Cpu).unwrap()
        };
        assert!(
            judged(&real) == judged(&future),
            "the judge read the future"
        );
    }
}

/// Sampling from a model over training variables records no graph (a long
/// motion would otherwise hold every step's tensors) and makes the same
/// frames, bit for bit, as the same weights loaded as plain tensors.
#[test]
fn sampling_keeps_no_graph_and_makes_the_same_frames() {
    use candle_nn::VarBuilder;
    for (name, _) in MODELS {
        let m = model(name, 3);
        let (x, e) = batch(5, 6, 5);
        let tracked = m.model.losses(&x, &e, None, None).unwrap();
        assert!(tracked.recon.track_op(), "{name}: training records a graph");
        let eps = noise(1, 2, 12, 5, 8, &Device::Cpu).unwrap();
        let start = x.narrow(1, 0, 4).unwrap();
        let s = m.model.sample(&eps, Some(&start), None).unwrap();
        assert!(!s.track_op(), "{name}: sampling recorded a graph");
        let plain: std::collections::HashMap<String, Tensor> = sorted_vars(&m)
            .into_iter()
            .map(|(k, v)| (k, v.as_detached_tensor()))
            .collect();
        let vb = VarBuilder::from_tensors(plain, candle_core::DType::F32, &Device::Cpu);
        let frozen = motion_vrnn::Vrnn::new(m.model.config(), vb).unwrap();
        let f = frozen.sample(&eps, Some(&start), None).unwrap();
        assert_eq!(flat(&s), flat(&f), "{name}: other frames");
    }
}

/// The gradient through the rollout runs as one fused block with its own
/// backward (`blocks::rollout::RolloutOp`): the losses and every gradient,
/// with and without the gradient through the fed frames, equal candle's
/// autograd through the step loop it replaces (`Vrnn::fed_in_sequence`)
/// and the scan over its frames, with and without a condition, the skeleton,
/// the filters and the foot lock on; so does the part of each gradient that
/// flows through the fed frames alone (the gradient less the one without
/// them), which is small beside the rest: within 1e-3, since the block also
/// gives the loss its recurrence, so the two totals it is the difference
/// of are summed in different orders (a missing term is off by ~1).
#[test]
fn the_fused_gradient_through_the_rollout_matches_autograd() {
    for on in [false, true] {
        let build = |through: bool| {
            let mut c = conditioned("motion", on).model.config().clone();
            c.parts.feed_rounds = Some(0);
            c.parts.rollout_gradient = through;
            let m = init_model(&c, 4, &Device::Cpu).unwrap();
            if on {
                randomise(&m);
            }
            m
        };
        let (with, without) = (build(true), build(false));
        let (x, eps) = batch(5, 9, 12);
        let fed = feed_mask(9, 1, 5, 9, 0.5, &Device::Cpu).unwrap();
        let cond = on.then(|| ask(&with, &[Some(1), Some(2), None, Some(3), Some(1)], 1.0));
        fused_matches_reference("rollout", &with, &x, &eps, fed.as_ref(), cond.as_ref());
        fused_matches_reference(
            "every depth",
            &without,
            &x,
            &eps,
            fed.as_ref(),
            cond.as_ref(),
        );
        let grads = |m: &Trained, reference: bool| -> Vec<Vec<f32>> {
            let run = || {
                let l = m
                    .model
                    .losses(&x, &eps, fed.as_ref(), cond.as_ref())
                    .unwrap();
                let total = ((&l.recon + (&l.kl * 0.5).unwrap()).unwrap() + &l.extra).unwrap();
                total.backward().unwrap()
            };
            let g = if reference {
                blocks::reference(run)
            } else {
                run()
            };
            sorted_vars(m).iter().map(|(_, v)| grad_of(&g, v)).collect()
        };
        let part = |reference: bool| -> Vec<Vec<f32>> {
            let (a, b) = (grads(&with, reference), grads(&without, reference));
            a.iter()
                .zip(&b)
                .map(|(a, b)| a.iter().zip(b).map(|(x, y)| x - y).collect())
                .collect()
        };
        let (pf, pr) = (part(false), part(true));
        for ((n, _), (f, r)) in sorted_vars(&with).iter().zip(pf.iter().zip(&pr)) {
            let e = rel(f, r);
            assert!(
                e < 1e-3,
                "condition {on}: {n}: the rollout's part off by {e:e}"
            );
        }
        assert!(pr.iter().any(|r| r.iter().any(|v| v.abs() > 1e-3)));
    }
}

/// A model with the control ([`motion_vrnn::model::Parts::control`]):
/// the fused rollout, with and without its gradient, matches autograd
/// through the references with one condition row per frame; the control's
/// weights learn; the results do not depend on the thread count; and
/// steering with the control left free is sampling.
#[test]
fn the_controlled_model_matches_autograd_and_steers_freely_as_it_samples() {
    for through in [false, true] {
        let mut c = conditioned("motion", true).model.config().clone();
        c.parts.pace = true;
        c.parts.control = true;
        c.parts.feed_rounds = Some(0);
        c.parts.rollout_gradient = through;
        let m = init_model(&c, 4, &Device::Cpu).unwrap();
        randomise(&m);
        let control = named_vars(&m.varmap)
            .into_iter()
            .find(|v| v.0 == motion_vrnn::model::CONTROL_WEIGHT)
            .unwrap()
            .1;
        let v: Vec<f32> = Rng::new(9, 9)
            .normals(control.elem_count())
            .iter()
            .map(|v| 0.2 * v)
            .collect();
        control
            .set(&Tensor::from_vec(v, control.shape(), &Device::Cpu).unwrap())
            .unwrap();
        let (x, eps) = batch(3, 36, 12);
        let wide = c.with_control(&x, &[true, false, true]).unwrap();
        assert_eq!(wide.dims(), &[3, 36, 58 + motion_steer::CONTROL]);
        // Rows 1 to 6 of a kept window are given (flag 1: a second follows
        // the frame before them), the rest free.
        let flags = flat(&wide.narrow(2, 58 + motion_steer::CONTROL - 1, 1).unwrap());
        let given: Vec<usize> = (0..36).filter(|&t| flags[t] == 1.0).collect();
        assert_eq!(given, (1..7).collect::<Vec<_>>());
        assert!(flags[36..72].iter().all(|&f| f == 0.0));
        let fed = feed_mask(9, 1, 3, 36, 0.5, &Device::Cpu).unwrap();
        let cond = ask(&m, &[Some(1), Some(2), None], 1.0);
        let g = fused_matches_reference("control", &m, &wide, &eps, fed.as_ref(), Some(&cond));
        assert!(flat(g.get(&control).unwrap()).iter().any(|v| *v != 0.0));
        // The same losses and gradients with 1 and 3 threads.
        let (xb, eb) = batch(40, 36, 3);
        let wb = c.with_control(&xb, &[]).unwrap();
        let cb = ask(&m, &vec![Some(1); 40], 1.0);
        let fb = feed_mask(9, 1, 40, 36, 0.5, &Device::Cpu).unwrap();
        let run = |threads| sharded_on(threads, &m, &wb, &eb, fb.as_ref(), Some(&cb));
        assert_eq!(run(1), run(3), "control: thread count");
        // A free control is no control: the same losses as without it.
        let l = |x: &Tensor| {
            let l = m.model.losses(x, &eps, None, Some(&cond)).unwrap();
            l.recon.to_scalar::<f32>().unwrap()
        };
        let free = c.with_control(&x, &[false; 3]).unwrap();
        assert_eq!(l(&free), l(&x));
        assert_ne!(l(&wide), l(&x));
        // Steering that asks nothing is sampling, bit for bit; asking
        // something changes the frames after the start.
        let e = noise(1, 2, 12, 3, 8, &Device::Cpu).unwrap();
        let start = x.narrow(1, 0, 4).unwrap();
        let sampled = m.model.sample(&e, Some(&start), Some(&cond)).unwrap();
        let mut none = |_: usize, _: &[Tensor]| Ok(None);
        let steered = m
            .model
            .steer(&e, Some(&start), Some(&cond), &mut none)
            .unwrap();
        assert_eq!(flat(&sampled), flat(&steered));
        let row = wide.narrow(1, 3, 1).unwrap().squeeze(1).unwrap();
        let row = row.narrow(1, 58, motion_steer::CONTROL).unwrap();
        let mut asked = |t: usize, _: &[Tensor]| Ok((t >= 4).then(|| row.clone()));
        let steered = m
            .model
            .steer(&e, Some(&start), Some(&cond), &mut asked)
            .unwrap();
        let cut = |t: &Tensor| flat(&t.narrow(1, 5, 7).unwrap());
        assert_ne!(cut(&sampled), cut(&steered));
    }
}
