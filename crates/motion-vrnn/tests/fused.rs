//! The fused kernel against candle's autograd on the same weights and batch.

use candle_core::{Device, Tensor, Var};
use motion_vrnn::rng::Rng;
use motion_vrnn::train::{init_model, named_vars, noise, Trained};
use motion_vrnn::Config;

const T: usize = 24;

fn batch(b: usize, seed: u64) -> (Tensor, Tensor) {
    batch_t(b, T, seed)
}

fn batch_t(b: usize, t: usize, seed: u64) -> (Tensor, Tensor) {
    let c = Config::default();
    let x = Rng::new(seed, 1).normals(b * t * c.input);
    let x = Tensor::from_vec(x, (b, t, c.input), &Device::Cpu).unwrap();
    let eps = noise(seed, 7, t, b, c.latent, &Device::Cpu).unwrap();
    (x, eps)
}

fn model(seed: u64) -> Trained {
    init_model(&Config::default(), seed, &Device::Cpu).unwrap()
}

fn grads(vars: &[(String, Var)], loss: &Tensor) -> Vec<(String, Vec<f32>)> {
    let g = loss.backward().unwrap();
    vars.iter()
        .map(|(n, v)| {
            let t = g.get(v).unwrap_or_else(|| panic!("no gradient for {n}"));
            (
                n.clone(),
                t.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
            )
        })
        .collect()
}

fn rel(a: &[f32], b: &[f32]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
    let den: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum();
    (num / den.max(1e-30)).sqrt()
}

/// Loss and every parameter's gradient agree with autograd to 1e-4
/// (relative), for a batch with a partial last shard.
fn compare(b: usize, kl_w: f64, precompute: bool) {
    let m = model(3);
    let vars = named_vars(&m.varmap);
    let (x, eps) = batch(b, 11);
    let reference = m.model.forward(&x, &eps).unwrap();
    let fused = m
        .model
        .losses(&x, &eps, precompute.then_some(kl_w))
        .unwrap();
    for (name, a, r) in [
        ("recon", &fused.recon, &reference.recon),
        ("kl", &fused.kl, &reference.kl),
    ] {
        let (a, r) = (a.to_scalar::<f32>().unwrap(), r.to_scalar::<f32>().unwrap());
        assert!(
            ((a - r) / r).abs() < 1e-5,
            "{name}: fused {a}, autograd {r}"
        );
    }
    let loss = |l: &motion_vrnn::model::Losses| (&l.recon + (&l.kl * kl_w).unwrap()).unwrap();
    let gr = grads(&vars, &loss(&reference));
    let gf = grads(&vars, &loss(&fused));
    assert_eq!(gr.len(), 22);
    for ((name, r), (_, f)) in gr.iter().zip(&gf) {
        let e = rel(f, r);
        assert!(e < 1e-4, "{name}: relative gradient error {e:e}");
    }
}

#[test]
fn fused_matches_autograd_with_precomputed_gradient() {
    compare(40, 0.3, true);
}

#[test]
fn fused_matches_autograd_when_the_losses_are_combined_otherwise() {
    // The precomputed gradient is for recon + 0.7·kl; the loss uses 0.3.
    let m = model(5);
    let vars = named_vars(&m.varmap);
    let (x, eps) = batch(9, 2);
    let r = m.model.forward(&x, &eps).unwrap();
    let f = m.model.losses(&x, &eps, Some(0.7)).unwrap();
    let loss = |l: &motion_vrnn::model::Losses| {
        ((&l.recon * 2.0).unwrap() + (&l.kl * 0.3).unwrap()).unwrap()
    };
    for ((name, a), (_, b)) in grads(&vars, &loss(&r)).iter().zip(&grads(&vars, &loss(&f))) {
        assert!(rel(b, a) < 1e-4, "{name}");
    }
    compare(5, 1.0, false);
}

#[test]
fn fused_gradient_matches_finite_differences() {
    // Central differences of the fused loss itself on three coordinates of
    // every parameter. The loss is f32, so the batch is small (one window of
    // 4 frames) and the step 1e-2. A step can cross a ReLU kink (the
    // one-sided differences then disagree), so a few coordinates may miss;
    // the exact comparison is the autograd one above.
    let m = model(9);
    let vars = named_vars(&m.varmap);
    let (x, eps) = batch_t(1, 4, 4);
    let value = || {
        let l = m.model.losses(&x, &eps, None).unwrap();
        (l.recon.to_scalar::<f32>().unwrap() + l.kl.to_scalar::<f32>().unwrap()) as f64
    };
    let l = m.model.losses(&x, &eps, Some(1.0)).unwrap();
    let g = grads(&vars, &(&l.recon + &l.kl).unwrap());
    let base = value();
    let (mut agree, mut off) = (0, Vec::new());
    for ((name, var), (_, grad)) in vars.iter().zip(&g) {
        let orig = var.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let set = |v: Vec<f32>| {
            var.set(&Tensor::from_vec(v, var.shape(), &Device::Cpu).unwrap())
                .unwrap()
        };
        for k in [0, orig.len() / 2, orig.len() - 1] {
            let h = 1e-2f32;
            let mut v = orig.clone();
            v[k] = orig[k] + h;
            set(v.clone());
            let up = value();
            v[k] = orig[k] - h;
            set(v);
            let down = value();
            set(orig.clone());
            let fd = (up - down) / (2.0 * h as f64);
            let an = grad[k] as f64;
            if (fd - an).abs() <= 2e-2 * an.abs().max(1.0) {
                agree += 1;
            } else {
                eprintln!(
                    "{name}[{k}]: finite difference {fd} (one-sided {} and {}), kernel {an}",
                    (up - base) / h as f64,
                    (base - down) / h as f64
                );
                off.push(name.clone());
            }
        }
    }
    assert_eq!(agree + off.len(), 66);
    assert!(
        agree >= 62,
        "{} of 66 coordinates disagree: {off:?}",
        off.len()
    );
}

#[test]
fn fused_results_do_not_depend_on_the_thread_count() {
    let m = model(1);
    let vars = named_vars(&m.varmap);
    let (x, eps) = batch(100, 8);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let l = m.model.losses(&x, &eps, Some(1.0)).unwrap();
            let v = (
                l.recon.to_scalar::<f32>().unwrap(),
                l.kl.to_scalar::<f32>().unwrap(),
            );
            (v, grads(&vars, &(&l.recon + &l.kl).unwrap()))
        })
    };
    let (a, ga) = run(1);
    let (b, gb) = run(4);
    assert_eq!(a.0.to_bits(), b.0.to_bits());
    assert_eq!(a.1.to_bits(), b.1.to_bits());
    for ((n, x), (_, y)) in ga.iter().zip(&gb) {
        assert!(
            x.iter().zip(y).all(|(p, q)| p.to_bits() == q.to_bits()),
            "{n}"
        );
    }
}

#[test]
fn fused_sampler_matches_candle_ops() {
    let m = model(4);
    let eps = noise(3, 0, 32, 6, Config::default().latent, &Device::Cpu).unwrap();
    let a = m.model.sample(&eps).unwrap();
    let r = m.model.sample_autograd(&eps).unwrap();
    assert_eq!(a.dims(), &[6, 32, 58]);
    let (a, r) = (
        a.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
        r.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
    );
    let e = rel(&a, &r);
    assert!(e < 1e-4, "relative error {e:e}");
}
