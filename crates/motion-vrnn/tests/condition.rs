//! Conditioning on a category (`train --condition category`): a conditioned
//! model starts as the unconditioned one, "no category" is row 0 of the
//! condition table, asking for a category changes the motion, guidance
//! weighs the rows as documented, the fused path matches autograd, and the
//! errors name what can be asked.

use candle_core::{Device, Tensor, Var};
use motion_vrnn::blocks;
use motion_vrnn::model::COND_WEIGHT;
use motion_vrnn::rng::Rng;
use motion_vrnn::train::{init_model, named_vars, noise, sharded, Trained};
use motion_vrnn::{Config, MotionModel};

const CATEGORIES: [&str; 3] = ["walk", "run", "dance"];

fn batch(b: usize, t: usize, seed: u64) -> (Tensor, Tensor) {
    let x = Rng::new(seed, 1).normals(b * t * 58);
    let x = Tensor::from_vec(x, (b, t, 58), &Device::Cpu).unwrap();
    (x, noise(seed, 7, t, b, 8, &Device::Cpu).unwrap())
}

/// The named model fitted to synthetic statistics, conditioned on
/// [`CATEGORIES`] or not.
fn model(name: &str, conditioned: bool) -> Trained {
    let mut c = Config::named(name).unwrap();
    let (mut mean, std) = (vec![0.0; 58], vec![2.0; 58]);
    mean[0] = 15.0;
    let (x, _) = batch(4, 8, 100);
    let flat = x.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    c.fit_to(&mean, &std, &flat);
    if conditioned {
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
        let (plain, cond) = (model(name, false), model(name, true));
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
    let m = model("motion", true);
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
    let m = model("paper", true);
    // Row 0 gets 1 − g, the category's row g: g = 2.5 → −1.5 and 2.5.
    let w = flat(&ask(&m, &[Some(3), None], 2.5));
    assert_eq!(w, vec![-1.5, 0.0, 0.0, 2.5, 1.0, 0.0, 0.0, 0.0]);
    // An unconditioned model gives no weights; a row out of range is an error.
    let plain = model("paper", false);
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
        let m = model(name, true);
        randomise(&m);
        let (x, eps) = batch(5, 9, 12);
        let c = ask(&m, &[Some(1), Some(2), None, Some(3), Some(1)], 1.0);
        let loss = |m: &dyn MotionModel| {
            let l = m.losses(&x, &eps, None, Some(&c)).unwrap();
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
        for (n, v) in named_vars(&m.varmap) {
            let (f, r) = (flat(gf.get(&v).unwrap()), flat(gr.get(&v).unwrap()));
            let num: f64 = f
                .iter()
                .zip(&r)
                .map(|(a, b)| ((a - b) as f64).powi(2))
                .sum();
            let den: f64 = r.iter().map(|b| (*b as f64).powi(2)).sum();
            assert!((num / den.max(1e-30)).sqrt() < 1e-4, "{name}: {n}");
        }
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
        let vars: Vec<Var> = named_vars(&m.varmap).into_iter().map(|v| v.1).collect();
        let (x, eps) = batch(70, 4, 3);
        let rows: Vec<Option<usize>> = (0..70).map(|i| (i % 4 > 0).then_some(i % 4)).collect();
        let c = ask(&m, &rows, 1.0);
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let (l, g) =
                    sharded(&m.model, &x, &eps, None, Some(&c), Some((1.0, &vars))).unwrap();
                let g = g.unwrap();
                (
                    l,
                    vars.iter()
                        .map(|v| flat(g.get(v).unwrap()))
                        .collect::<Vec<_>>(),
                )
            })
        };
        assert_eq!(run(1), run(3), "{name}");
    }
}

#[test]
fn asking_names_what_can_be_asked() {
    let (plain, cond) = (model("paper", false), model("paper", true));
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
