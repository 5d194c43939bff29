//! Each fused block against candle's autograd of its reference (values and
//! gradients) and against central finite differences of the fused forward.

use candle_core::{Device, Tensor, Var};
use motion_vrnn::blocks::scan::ScanDims;
use motion_vrnn::blocks::{self, filter, skeleton, Act};
use motion_vrnn::rng::Rng;

fn randn(seed: u64, shape: &[usize], scale: f64) -> Var {
    let n = shape.iter().product();
    let v: Vec<f32> = Rng::new(seed, 3)
        .normals(n)
        .iter()
        .map(|x| (*x as f64 * scale) as f32)
        .collect();
    Var::from_tensor(&Tensor::from_vec(v, shape, &Device::Cpu).unwrap()).unwrap()
}

fn values(t: &Tensor) -> Vec<f32> {
    t.flatten_all().unwrap().to_vec1::<f32>().unwrap()
}

fn rel(a: &[f32], b: &[f32]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
    let den: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum();
    (num / den.max(1e-30)).sqrt()
}

/// A scalar of a block's output: `Σ out ⊙ w` with fixed random `w`, so every
/// output element's gradient is exercised.
fn project(out: &Tensor) -> Tensor {
    let w = randn(99, out.dims(), 1.0);
    (out * w.as_tensor()).unwrap().sum_all().unwrap()
}

/// Fused vs reference: the scalar and the gradient of every input in
/// `check` agree to `tol` (relative); then central differences of the fused
/// scalar on `fd` coordinates of each checked input agree with the fused
/// gradient to 2 % (or 1e-3 absolute).
fn check(
    name: &str,
    inputs: &[Var],
    check: &[usize],
    tol: f64,
    fd: usize,
    f: impl Fn(&[Tensor]) -> Tensor,
) {
    let ts: Vec<Tensor> = inputs.iter().map(|v| v.as_tensor().clone()).collect();
    let fused = project(&f(&ts));
    let reference = blocks::reference(|| project(&f(&ts)));
    let (a, r) = (
        fused.to_scalar::<f32>().unwrap(),
        reference.to_scalar::<f32>().unwrap(),
    );
    assert!(
        ((a - r) as f64).abs() <= tol * (r.abs() as f64).max(1.0),
        "{name}: value {a} vs {r}"
    );
    let gf = fused.backward().unwrap();
    let gr = reference.backward().unwrap();
    for &i in check {
        let (x, y) = (
            values(gf.get(&inputs[i]).expect("fused gradient")),
            values(gr.get(&inputs[i]).expect("reference gradient")),
        );
        let e = rel(&x, &y);
        assert!(
            e < tol,
            "{name}: input {i} gradient off by {e:e} (relative)"
        );
        // Finite differences on a few coordinates.
        let base = values(inputs[i].as_tensor());
        let mut rng = Rng::new(7 + i as u64, 5);
        for _ in 0..fd {
            let k = (rng.uniform() * base.len() as f64) as usize % base.len();
            let h = 1e-2f32 * base[k].abs().max(1.0);
            let at = |d: f32| {
                let mut v = base.clone();
                v[k] += d;
                let mut ts = ts.clone();
                ts[i] = Tensor::from_vec(v, inputs[i].shape(), &Device::Cpu).unwrap();
                project(&f(&ts)).to_scalar::<f32>().unwrap() as f64
            };
            let num = (at(h) - at(-h)) / (2.0 * h as f64);
            let g = x[k] as f64;
            assert!(
                (num - g).abs() <= 0.02 * g.abs().max(num.abs()) + 1e-3,
                "{name}: input {i}[{k}]: finite difference {num} vs gradient {g}"
            );
        }
    }
}

#[test]
fn linear_block() {
    let (x, w, b) = (
        randn(1, &[3, 5, 7], 1.0),
        randn(2, &[4, 7], 0.5),
        randn(3, &[4], 0.5),
    );
    check(
        "linear",
        &[x.clone(), w.clone(), b.clone()],
        &[0, 1, 2],
        1e-5,
        6,
        |t| blocks::linear(&t[0], &t[1], &t[2], Act::None).unwrap(),
    );
    // ReLU: against autograd only (its kinks defeat finite differences).
    check("linear relu", &[x, w, b], &[0, 1, 2], 1e-5, 0, |t| {
        blocks::linear(&t[0], &t[1], &t[2], Act::Relu).unwrap()
    });
}

#[test]
fn linear_without_an_input_gradient() {
    // A plain input (data) gets no gradient; the weights' are the same.
    let (x, w, b) = (
        randn(1, &[3, 5, 7], 1.0),
        randn(2, &[4, 7], 0.5),
        randn(3, &[4], 0.5),
    );
    let grads = |x: &Tensor| {
        let g = project(&blocks::linear(x, &w, &b, Act::Relu).unwrap())
            .backward()
            .unwrap();
        (values(g.get(&w).unwrap()), values(g.get(&b).unwrap()))
    };
    let data = x.as_tensor().detach();
    assert!(!data.track_op());
    assert_eq!(grads(&data), grads(x.as_tensor()));
}

#[test]
fn add_rows_block() {
    let y = randn(11, &[3, 5, 6], 1.0);
    for (name, r) in [
        ("per sequence", randn(12, &[3, 1, 6], 0.5)),
        ("shared", randn(13, &[1, 1, 6], 0.5)),
        ("per frame", randn(16, &[3, 5, 6], 0.5)),
    ] {
        check(name, &[y.clone(), r.clone()], &[0, 1], 1e-6, 6, |t| {
            blocks::add_rows(&t[0], &t[1], Act::None).unwrap()
        });
        check(name, &[y.clone(), r.clone()], &[0, 1], 1e-6, 0, |t| {
            blocks::add_rows(&t[0], &t[1], Act::Relu).unwrap()
        });
        // To the bit: the model's numbers do not change with the block.
        for act in [Act::None, Act::Relu] {
            let ts = [y.as_tensor().clone(), r.as_tensor().clone()];
            let run = || project(&blocks::add_rows(&ts[0], &ts[1], act).unwrap());
            let (gf, gr) = (
                run().backward().unwrap(),
                blocks::reference(run).backward().unwrap(),
            );
            for v in [&y, &r] {
                assert_eq!(values(gf.get(v).unwrap()), values(gr.get(v).unwrap()));
            }
            let fwd = || blocks::add_rows(&ts[0], &ts[1], act).unwrap();
            assert_eq!(values(&fwd()), values(&blocks::reference(fwd)));
        }
    }
    // One step (`[B, n]`, as sampling runs): the same as the sequence form.
    let (y2, r2) = (randn(14, &[3, 6], 1.0), randn(15, &[1, 6], 0.5));
    for act in [Act::None, Act::Relu] {
        let one = || blocks::add_rows(y2.as_tensor(), r2.as_tensor(), act).unwrap();
        assert_eq!(one().dims(), [3, 6]);
        assert_eq!(values(&one()), values(&blocks::reference(one)));
    }
    for bad in [(2, 1, 6), (3, 4, 6), (3, 5, 5)] {
        let r = Tensor::zeros(bad, candle_core::DType::F32, &Device::Cpu).unwrap();
        assert!(blocks::add_rows(y.as_tensor(), &r, Act::None).is_err());
    }
}

#[test]
fn control_rows_block() {
    // `base + ctl · w` per frame; the control is data (no gradient).
    let (ctl, w) = (randn(16, &[3, 5, 4], 1.0), randn(17, &[4, 6], 0.5));
    for (name, base) in [
        ("per sequence", randn(18, &[3, 6], 0.5)),
        ("shared", randn(19, &[1, 6], 0.5)),
    ] {
        let inputs = [ctl.clone(), w.clone(), base.clone()];
        check(name, &inputs, &[1, 2], 1e-5, 6, |t| {
            blocks::control_rows(&t[0], &t[1], &t[2]).unwrap()
        });
        // To the bit, the composition it replaced: a product with `wᵀ` and
        // a zero bias, then `base` broadcast over the frames.
        let before = || {
            let none = Tensor::zeros(6, candle_core::DType::F32, &Device::Cpu).unwrap();
            let wt = w.as_tensor().t().unwrap().contiguous().unwrap();
            let r = blocks::linear(&ctl.as_tensor().detach(), &wt, &none, Act::None).unwrap();
            r.broadcast_add(&base.as_tensor().unsqueeze(1).unwrap())
                .unwrap()
        };
        let now =
            || blocks::control_rows(ctl.as_tensor(), w.as_tensor(), base.as_tensor()).unwrap();
        assert_eq!(values(&now()), values(&before()));
        let (gn, gb) = (
            project(&now()).backward().unwrap(),
            project(&before()).backward().unwrap(),
        );
        for v in [&w, &base] {
            assert_eq!(values(gn.get(v).unwrap()), values(gb.get(v).unwrap()));
        }
        assert!(gn.get(&ctl).is_none());
    }
    // One step (`[B, C]`, as generation runs): `[B, n]`, the same rows.
    let one = blocks::control_rows(
        &ctl.as_tensor().narrow(1, 2, 1).unwrap().squeeze(1).unwrap(),
        w.as_tensor(),
        &randn(18, &[3, 6], 0.5).as_tensor().clone(),
    )
    .unwrap();
    let all = blocks::control_rows(
        ctl.as_tensor(),
        w.as_tensor(),
        randn(18, &[3, 6], 0.5).as_tensor(),
    )
    .unwrap();
    assert_eq!(one.dims(), [3, 6]);
    assert!(rel(&values(&one), &values(&all.narrow(1, 2, 1).unwrap())) < 1e-6);
    assert!(blocks::control_rows(
        ctl.as_tensor(),
        w.as_tensor(),
        randn(20, &[2, 6], 0.5).as_tensor()
    )
    .is_err());
}

#[test]
fn squared_error_block() {
    let (a, b) = (randn(4, &[2, 3, 5], 1.0), randn(5, &[2, 3, 5], 1.0));
    check("squared error", &[a, b], &[0, 1], 1e-5, 6, |t| {
        blocks::squared_error(&t[0], &t[1]).unwrap()
    });
}

#[test]
fn gaussian_kl_block() {
    let (b, t, z) = (3, 6, 4);
    // q = [μ | σ] with σ in (0.2, 1).
    let mu = randn(6, &[b, t, z], 1.0);
    let s: Vec<f32> = Rng::new(7, 1)
        .normals(b * t * z)
        .iter()
        .map(|v| 0.6 + 0.3 * v.tanh())
        .collect();
    let q = Tensor::cat(
        &[
            mu.as_tensor(),
            &Tensor::from_vec(s, (b, t, z), &Device::Cpu).unwrap(),
        ],
        2,
    )
    .unwrap();
    let q = Var::from_tensor(&q).unwrap();
    let p = randn(8, &[b, t, 2 * z], 1.0);
    check("gaussian kl", &[q, p], &[0, 1], 1e-5, 8, |t| {
        blocks::gaussian_kl(&t[0], &t[1]).unwrap()
    });
}

#[test]
fn latent_lstm_block() {
    let dims = ScanDims {
        hidden: 5,
        latent: 3,
    };
    let (b, t) = (4, 7);
    let pre = randn(9, &[b, t, dims.pre()], 1.0);
    let eps = randn(10, &[b, t, dims.latent], 1.0);
    let w = randn(11, &[dims.weights()], 0.4);
    check(
        "latent lstm",
        &[pre, eps.clone(), w.clone()],
        &[0, 2],
        1e-5,
        10,
        |x| blocks::latent_lstm(&[&x[0]], None, &x[1], &x[2], dims).unwrap(),
    );
    // `pre` in two blocks, with rows added to every step.
    let enc = randn(20, &[b, t, 2 * dims.latent], 1.0);
    let gates = randn(21, &[b, t, 4 * dims.hidden], 1.0);
    for (name, rb) in [("rows per sequence", b), ("one row for all", 1)] {
        let rows = randn(24, &[rb, 1, dims.pre()], 0.5);
        let inputs = [enc.clone(), gates.clone(), rows, eps.clone(), w.clone()];
        check(name, &inputs, &[0, 1, 2, 4], 1e-5, 6, |x| {
            blocks::latent_lstm(&[&x[0], &x[1]], Some(&x[2]), &x[3], &x[4], dims).unwrap()
        });
    }
}

#[test]
fn latent_lstm_reads_blocks_and_rows_to_the_bit() {
    // The scan reading `pre` in two blocks and adding the rows itself gives
    // the bits of `cat`, then `add_rows`, then the scan: output and every
    // gradient (the default model's training depends on it). A zero may
    // differ in its sign: candle's gradient store (vendor/README.md) keeps a
    // first gradient's −0 where adding it into zeros made it +0, and no
    // update of Adam can tell them apart.
    let dims = ScanDims {
        hidden: 6,
        latent: 2,
    };
    let (b, t) = (3, 9);
    let (enc, gates) = (
        randn(30, &[b, t, 2 * dims.latent], 1.0),
        randn(31, &[b, t, 4 * dims.hidden], 1.0),
    );
    let (eps, w) = (
        randn(32, &[b, t, dims.latent], 1.0),
        randn(33, &[dims.weights()], 0.4),
    );
    for rb in [b, 1] {
        let rows = randn(34, &[rb, 1, dims.pre()], 0.5);
        let vars = [&enc, &gates, &rows, &w];
        let run = |fused_in: bool| {
            let (e, g, r) = (enc.as_tensor(), gates.as_tensor(), rows.as_tensor());
            let out = if fused_in {
                blocks::latent_lstm(&[e, g], Some(r), eps.as_tensor(), w.as_tensor(), dims)
            } else {
                let pre = Tensor::cat(&[e, g], 2).unwrap();
                let pre = blocks::add_rows(&pre, r, Act::None).unwrap();
                blocks::latent_lstm(&[&pre], None, eps.as_tensor(), w.as_tensor(), dims)
            }
            .unwrap();
            let grads = project(&out).backward().unwrap();
            let mut all = vec![values(&out)];
            all.extend(vars.iter().map(|v| values(grads.get(v).expect("gradient"))));
            all
        };
        let (inside, outside) = (run(true), run(false));
        for (k, (a, o)) in inside.iter().zip(&outside).enumerate() {
            let same = a.len() == o.len()
                && a.iter()
                    .zip(o)
                    .all(|(x, y)| x.to_bits() == y.to_bits() || (*x == 0.0 && *y == 0.0));
            assert!(same, "rows {rb}: part {k} differs");
        }
    }
    // Blocks or rows that do not fit are refused.
    let bad = randn(35, &[b, 1, dims.pre() + 1], 0.5);
    let (e, g) = (enc.as_tensor(), gates.as_tensor());
    assert!(blocks::latent_lstm(
        &[e, g],
        Some(bad.as_tensor()),
        eps.as_tensor(),
        w.as_tensor(),
        dims
    )
    .is_err());
    assert!(blocks::latent_lstm(&[g, e], None, eps.as_tensor(), w.as_tensor(), dims).is_err());
    assert!(blocks::latent_lstm(&[], None, eps.as_tensor(), w.as_tensor(), dims).is_err());
}

#[test]
fn lstm_cell_matches_the_reference() {
    let (g, c) = (randn(12, &[3, 20], 1.0), randn(13, &[3, 5], 1.0));
    let (h1, c1) = blocks::lstm_cell(g.as_tensor(), c.as_tensor()).unwrap();
    let (h2, c2) = blocks::reference(|| blocks::lstm_cell(g.as_tensor(), c.as_tensor()).unwrap());
    assert!(rel(&values(&h1), &values(&h2)) < 1e-6);
    assert!(rel(&values(&c1), &values(&c2)) < 1e-6);
}

#[test]
fn smooth_block() {
    let x = randn(14, &[2, 9, 3], 1.0);
    check("smooth", &[x], &[0], 1e-5, 6, |t| {
        filter::smooth(&t[0], 0.7).unwrap()
    });
    // By hand: ρ = 0.6, gain 0.8; x = (1, 0, 0) → (1, 0.6, 0.36).
    let x = Tensor::new(&[[[1f32], [0.0], [0.0]]], &Device::Cpu).unwrap();
    let y = values(&filter::smooth(&x, 0.6).unwrap());
    assert!(rel(&y, &[1.0, 0.6, 0.36]) < 1e-6, "{y:?}");
}

#[test]
fn forward_kinematics_block() {
    let n = 6;
    let y = randn(15, &[n, 1], 1.0);
    let d = randn(16, &[n, 3 * skeleton::BONES], 1.0);
    let l: Vec<f32> = (0..n * skeleton::BONES)
        .map(|i| 1.0 + (i % 7) as f32)
        .collect();
    let l = Var::from_tensor(&Tensor::from_vec(l, (n, skeleton::BONES), &Device::Cpu).unwrap())
        .unwrap();
    check("forward kinematics", &[y, d, l], &[0, 1], 1e-5, 10, |t| {
        skeleton::forward_kinematics(&t[0], &t[1], &t[2]).unwrap()
    });
}

#[test]
fn place_block() {
    // Decoded features → bones rescaled by forward kinematics, through
    // statistics that are not the identity.
    let (n, f) = (5, 58);
    let o = randn(17, &[n, f], 1.0);
    let l: Vec<f32> = (0..n * skeleton::BONES)
        .map(|i| 1.0 + (i % 5) as f32 * 0.5)
        .collect();
    let l = Var::from_tensor(&Tensor::from_vec(l, (n, skeleton::BONES), &Device::Cpu).unwrap())
        .unwrap();
    let mean: Vec<f32> = (0..f).map(|k| ((k * 7) % 5) as f32 - 2.0).collect();
    let std: Vec<f32> = (0..f).map(|k| 0.5 + ((k * 3) % 4) as f32 * 0.5).collect();
    check("place", &[o, l], &[0], 1e-5, 12, |t| {
        skeleton::place(&t[0], &t[1], &mean, &std).unwrap()
    });
}

#[test]
fn forward_kinematics_by_hand() {
    // Every bone along +x with length 2 except the left leg chain: joint j's
    // position is the sum of its chain. LeftUpLeg (1) from Hips at (0, 5, 0).
    let b = skeleton::BONES;
    let mut d = vec![0f32; 3 * b];
    for j in 0..b {
        d[3 * j] = 3.0; // any length: directions are normalised
    }
    let y = Tensor::new(&[[5f32]], &Device::Cpu).unwrap();
    let d = Tensor::from_vec(d, (1, 3 * b), &Device::Cpu).unwrap();
    let l = Tensor::from_vec(vec![2f32; b], (1, b), &Device::Cpu).unwrap();
    let p = values(&skeleton::forward_kinematics(&y, &d, &l).unwrap());
    // LeftToeBase (joint 4): 4 bones from the hips → x = 8.
    assert!((p[3 * 3] - 8.0).abs() < 1e-5 && (p[3 * 3 + 1] - 5.0).abs() < 1e-6);
    // Head (joint 12): Spine, Spine1, Neck1, Head → x = 8.
    assert!((p[3 * 11] - 8.0).abs() < 1e-5);
    // RightHand (joint 18): Spine, Spine1, RightArm, ForeArm, Hand → x = 10.
    assert!((p[3 * 17] - 10.0).abs() < 1e-5);
    // The lengths measured back.
    let yv = [5f32];
    let lengths = skeleton::bone_lengths(&yv, &p);
    assert!(
        lengths.iter().all(|v| (v - 2.0).abs() < 1e-5),
        "{lengths:?}"
    );
}

#[test]
fn foot_lock_block() {
    let (b, t, f) = (2, 6, 58);
    let x = randn(21, &[b, t, f], 1.0);
    let logits = randn(22, &[b, t, 2], 2.0);
    let mean: Vec<f32> = (0..f).map(|k| ((k * 7) % 5) as f32 - 2.0).collect();
    let std: Vec<f32> = (0..f).map(|k| 0.5 + ((k * 3) % 4) as f32 * 0.5).collect();
    let stats = blocks::feet::Stats {
        mean: &mean,
        std: &std,
        contact_height: 0.7,
    };
    check("foot lock", &[x, logits], &[0, 1], 1e-5, 12, |t| {
        blocks::feet::foot_lock(&t[0], &t[1], &stats).unwrap()
    });
}

#[test]
fn foot_slide_block() {
    let (b, t, f) = (2, 7, 58);
    let x_hat = randn(23, &[b, t, f], 1.0);
    let x = randn(24, &[b, t, f], 1.0);
    let mean: Vec<f32> = (0..f).map(|k| ((k * 5) % 3) as f32 - 1.0).collect();
    let std: Vec<f32> = (0..f).map(|k| 0.5 + ((k * 3) % 4) as f32 * 0.5).collect();
    let stats = blocks::feet::Stats {
        mean: &mean,
        std: &std,
        contact_height: 0.7,
    };
    // Some real toes on the floor, some not.
    let contact = values(&x)
        .chunks_exact(f)
        .filter(|r| r[11] * std[11] + mean[11] < blocks::feet::CONTACT_UNITS as f32)
        .count();
    assert!((1..b * t).contains(&contact), "{contact} contact rows");
    check("foot slide", &[x_hat, x], &[0], 1e-5, 12, |t| {
        blocks::feet::foot_slide(&t[0], &t[1], &stats).unwrap()
    });
}

#[test]
fn contact_loss_block() {
    let (b, t, f) = (3, 6, 58);
    let logits = randn(25, &[b, t, 2], 2.0);
    let x = randn(26, &[b, t, f], 1.0);
    let mean: Vec<f32> = (0..f).map(|k| ((k * 5) % 3) as f32 - 1.0).collect();
    let std: Vec<f32> = (0..f).map(|k| 0.5 + ((k * 3) % 4) as f32 * 0.5).collect();
    let stats = blocks::feet::Stats {
        mean: &mean,
        std: &std,
        contact_height: 0.7,
    };
    let inputs = [logits.clone(), x.clone()];
    check("contact loss", &inputs, &[0], 1e-5, 8, |t| {
        blocks::feet::contact_loss(&t[0], &t[1], &stats).unwrap()
    });
}

/// A scalar block's value, fused and through its reference.
fn both_paths(run: impl Fn() -> Tensor) -> [f32; 2] {
    [run(), blocks::reference(&run)].map(|t| t.to_scalar::<f32>().unwrap())
}

#[test]
fn contact_loss_by_hand() {
    let (mean, std) = (vec![0f32; 58], vec![1f32; 58]);
    let stats = blocks::feet::Stats {
        mean: &mean,
        std: &std,
        contact_height: 0.0,
    };
    let sp = |l: f32| (1.0 + l.exp()).ln();
    // One frame, identity statistics: left toe down (y = 0), right toe up
    // (y = 9). Logits 0 and 2: ln 2 for the left toe, softplus(2) for the right.
    let mut x = vec![0f32; 58];
    x[1 + 3 * 7 + 1] = 9.0;
    let x = Tensor::from_vec(x, (1, 1, 58), &Device::Cpu).unwrap();
    let logits = Tensor::new(&[[[0f32, 2.0]]], &Device::Cpu).unwrap();
    let got = both_paths(|| blocks::feet::contact_loss(&logits, &x, &stats).unwrap());
    for g in got {
        assert!((g - (2f32.ln() + sp(2.0))).abs() < 1e-5, "{got:?}");
    }
}

/// The gradient store of the vendored candle-core (`vendor/README.md`)
/// stores a node's first gradient as it is instead of adding it into zeros:
/// hand-computed sums over a leaf reached several ways (twice through one
/// `add`, through a broadcast and through a transpose), two leaves given the
/// same gradient tensor, and every stored gradient contiguous.
#[test]
fn a_patched_gradient_store_sums_the_same() {
    let dev = &Device::Cpu;
    let x = Var::from_vec(vec![1f32, 2., 3., 4., 5., 6.], (2, 3), dev).unwrap();
    let y = Var::from_vec(vec![0.5f32, -1., 2.], 3, dev).unwrap();
    let w = Tensor::from_vec(vec![1f32, -2., 3., 0.5, 0., -1.], (2, 3), dev).unwrap();
    let t = Tensor::from_vec(vec![10f32, 20., 30., 40., 50., 60.], (3, 2), dev).unwrap();
    let a = ((x.as_tensor() + x.as_tensor()).unwrap() * &w).unwrap();
    let b = x.as_tensor().broadcast_add(y.as_tensor()).unwrap();
    let c = (x.as_tensor().t().unwrap() * &t).unwrap();
    let loss = (a.sum_all().unwrap() + b.sum_all().unwrap() + c.sum_all().unwrap()).unwrap();
    let grads = loss.backward().unwrap();
    let gx = grads.get(x.as_tensor()).unwrap();
    let gy = grads.get(y.as_tensor()).unwrap();
    // d/dx = 2w + 1 + tᵀ; d/dy = the two rows' ones summed.
    let want_x = [13f32, 27., 57., 22., 41., 59.];
    assert_eq!(values(gx), want_x);
    assert_eq!(values(gy), [2f32, 2., 2.]);
    assert!(gx.is_contiguous() && gy.is_contiguous());

    let p = Var::from_vec(vec![1f32, 2.], 2, dev).unwrap();
    let q = Var::from_vec(vec![3f32, 4.], 2, dev).unwrap();
    let loss = ((p.as_tensor() + q.as_tensor()).unwrap() * 3.0)
        .unwrap()
        .sum_all()
        .unwrap();
    let grads = loss.backward().unwrap();
    assert_eq!(values(grads.get(p.as_tensor()).unwrap()), [3f32, 3.]);
    assert_eq!(values(grads.get(q.as_tensor()).unwrap()), [3f32, 3.]);
}

/// The vendored gradient store also keeps the gradients of `narrow`'s
/// slices until their node is reached (`vendor/README.md`): slices that
/// cover a tensor, slices with a gap, slices that overlap, and slices mixed
/// with uses of the whole tensor, each summed as by hand.
#[test]
fn a_patched_gradient_store_joins_slices() {
    let dev = &Device::Cpu;
    let x = Var::from_vec((1..=10).map(|v| v as f32).collect(), (2, 5), dev).unwrap();
    let xt = x.as_tensor();
    let grad = |loss: Tensor| values(loss.backward().unwrap().get(xt).unwrap());
    let part = |at: usize, n: usize, k: f64| {
        (xt.narrow(1, at, n).unwrap() * k)
            .unwrap()
            .sum_all()
            .unwrap()
    };
    let sum = |ts: &[Tensor]| {
        ts.iter()
            .skip(1)
            .fold(ts[0].clone(), |a, t| (a + t).unwrap())
    };
    // Three slices covering the columns: 2·x[:, 0..2] + 3·x[:, 2..3] + 5·x[:, 3..5].
    let got = grad(sum(&[part(3, 2, 5.0), part(0, 2, 2.0), part(2, 1, 3.0)]));
    assert_eq!(got, [2f32, 2., 3., 5., 5., 2., 2., 3., 5., 5.]);
    // A gap: columns 1 and 4 get nothing.
    let got = grad(sum(&[part(0, 1, 2.0), part(2, 2, 3.0)]));
    assert_eq!(got, [2f32, 0., 3., 3., 0., 2., 0., 3., 3., 0.]);
    // Overlapping slices add up.
    let got = grad(sum(&[part(0, 3, 2.0), part(2, 3, 3.0)]));
    assert_eq!(got, [2f32, 2., 5., 3., 3., 2., 2., 5., 3., 3.]);
    // The whole tensor and a slice: x·x summed gives 2x, plus 7 on column 1.
    let whole = xt.sqr().unwrap().sum_all().unwrap();
    let got = grad(sum(&[whole, part(1, 1, 7.0)]));
    let want: Vec<f32> = (1..=10)
        .map(|v| 2.0 * v as f32 + if v % 5 == 2 { 7.0 } else { 0.0 })
        .collect();
    assert_eq!(got, want);
    // Slices along the rows.
    let rows = sum(&[
        (xt.narrow(0, 1, 1).unwrap() * 4.0)
            .unwrap()
            .sum_all()
            .unwrap(),
        (xt.narrow(0, 0, 1).unwrap() * 6.0)
            .unwrap()
            .sum_all()
            .unwrap(),
    ]);
    assert_eq!(grad(rows), [6f32, 6., 6., 6., 6., 4., 4., 4., 4., 4.]);
    // One slice with zeros either side, stored contiguous.
    let loss = (xt.narrow(1, 1, 2).unwrap() * 2.0)
        .unwrap()
        .sum_all()
        .unwrap();
    let grads = loss.backward().unwrap();
    let g = grads.get(xt).unwrap();
    assert!(g.is_contiguous());
    assert_eq!(values(g), [0f32, 2., 2., 0., 0., 0., 2., 2., 0., 0.]);
}
