//! Adam (Kingma & Ba) with its state exposed, so checkpoints can hold it and a
//! resumed run continues exactly.

use candle_core::{Result, Tensor, Var};
use std::collections::HashMap;

/// Adam hyper-parameters.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AdamConfig {
    /// Learning rate.
    pub lr: f64,
    /// First-moment decay.
    pub beta1: f64,
    /// Second-moment decay.
    pub beta2: f64,
    /// Denominator guard.
    pub eps: f64,
}

impl Default for AdamConfig {
    fn default() -> Self {
        AdamConfig {
            lr: 1e-3,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
        }
    }
}

/// Adam over named variables.
pub struct Adam {
    config: AdamConfig,
    vars: Vec<(String, Var)>,
    m: Vec<Tensor>,
    v: Vec<Tensor>,
    /// Updates done so far.
    pub step: u64,
    /// The moving average of the weights ([`Adam::with_average`]), if kept.
    average: Option<Average>,
}

/// An exponential moving average of the weights: after each update
/// `a ← β·a + (1 − β)·w`, starting from the weights it was made with.
struct Average {
    beta: f64,
    weights: Vec<Tensor>,
}

impl Adam {
    /// An optimiser for `vars` (sorted by name for a stable order).
    pub fn new(mut vars: Vec<(String, Var)>, config: AdamConfig) -> Result<Adam> {
        vars.sort_by(|a, b| a.0.cmp(&b.0));
        let m = vars
            .iter()
            .map(|(_, v)| v.as_tensor().zeros_like())
            .collect::<Result<Vec<_>>>()?;
        let v = m.clone();
        Ok(Adam {
            config,
            vars,
            m,
            v,
            step: 0,
            average: None,
        })
    }

    /// Also keep an exponential moving average of the weights with decay
    /// `beta` (`0 < beta < 1`), from their values now.
    pub fn with_average(mut self, beta: f64) -> Result<Adam> {
        if !(beta > 0.0 && beta < 1.0) {
            candle_core::bail!("the weights' average needs a decay between 0 and 1, got {beta}");
        }
        let weights = self
            .vars
            .iter()
            .map(|(_, v)| v.as_tensor().copy())
            .collect::<Result<Vec<_>>>()?;
        self.average = Some(Average { beta, weights });
        Ok(self)
    }

    /// Exchange the variables' values with the average's (a no-op without
    /// one): call it again to get the trained weights back.
    pub fn swap_average(&mut self) -> Result<()> {
        if let Some(a) = &mut self.average {
            for (w, (_, var)) in a.weights.iter_mut().zip(&self.vars) {
                let now = var.as_tensor().copy()?;
                var.set(w)?;
                *w = now;
            }
        }
        Ok(())
    }

    /// Set the learning rate of the next updates (a schedule's).
    pub fn set_lr(&mut self, lr: f64) {
        self.config.lr = lr;
    }

    /// The variables, sorted by name.
    pub fn vars(&self) -> &[(String, Var)] {
        &self.vars
    }

    /// Apply one update from the gradients (variables without a gradient are
    /// left alone).
    pub fn step(&mut self, grads: &candle_core::backprop::GradStore) -> Result<()> {
        self.step += 1;
        let c = self.config;
        let t = self.step as i32;
        let bc1 = 1.0 - c.beta1.powi(t);
        let bc2 = 1.0 - c.beta2.powi(t);
        for (i, (_, var)) in self.vars.iter().enumerate() {
            let Some(g) = grads.get(var.as_tensor()) else {
                continue;
            };
            let m = ((&self.m[i] * c.beta1)? + (g * (1.0 - c.beta1))?)?;
            let v = ((&self.v[i] * c.beta2)? + (g.sqr()? * (1.0 - c.beta2))?)?;
            let update = ((&m / bc1)? / ((&v / bc2)?.sqrt()? + c.eps)?)?;
            var.set(&(var.as_tensor() - (update * c.lr)?)?)?;
            self.m[i] = m;
            self.v[i] = v;
        }
        if let Some(a) = &mut self.average {
            for (w, (_, var)) in a.weights.iter_mut().zip(&self.vars) {
                *w = ((&*w * a.beta)? + (var.as_tensor() * (1.0 - a.beta))?)?;
            }
        }
        Ok(())
    }

    /// The moments as named tensors (`NAME.adam_m`, `NAME.adam_v`), and
    /// the weights' average where one is kept (`NAME.average`).
    pub fn state(&self) -> HashMap<String, Tensor> {
        let mut out = HashMap::new();
        for (i, (name, _)) in self.vars.iter().enumerate() {
            out.insert(format!("{name}.adam_m"), self.m[i].clone());
            out.insert(format!("{name}.adam_v"), self.v[i].clone());
            if let Some(a) = &self.average {
                out.insert(format!("{name}.average"), a.weights[i].clone());
            }
        }
        out
    }

    /// Restore what [`Adam::state`] saved (the average too, where this
    /// optimiser keeps one) and the step count.
    pub fn load_state(&mut self, tensors: &HashMap<String, Tensor>, step: u64) -> Result<()> {
        for (i, (name, var)) in self.vars.iter().enumerate() {
            let mut slots = vec![("adam_m", &mut self.m[i]), ("adam_v", &mut self.v[i])];
            if let Some(a) = &mut self.average {
                slots.push(("average", &mut a.weights[i]));
            }
            for (suffix, slot) in slots {
                let t = tensors.get(&format!("{name}.{suffix}")).ok_or_else(|| {
                    candle_core::Error::Msg(format!("optimiser state lacks {name}.{suffix}"))
                })?;
                *slot = t.to_device(var.device())?;
            }
        }
        self.step = step;
        Ok(())
    }
}

/// Scale gradients so their global L2 norm is at most `max_norm`; returns the
/// norm before clipping.
pub fn clip_grad_norm(
    vars: &[(String, Var)],
    grads: &mut candle_core::backprop::GradStore,
    max_norm: f64,
) -> Result<f64> {
    let mut total = 0.0f64;
    for (_, v) in vars {
        if let Some(g) = grads.get(v.as_tensor()) {
            total += g.sqr()?.sum_all()?.to_scalar::<f32>()? as f64;
        }
    }
    let norm = total.sqrt();
    if norm > max_norm && norm.is_finite() {
        let s = max_norm / norm;
        for (_, v) in vars {
            if let Some(g) = grads.remove(v.as_tensor()) {
                grads.insert(v.as_tensor(), (g * s)?);
            }
        }
    }
    Ok(norm)
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    /// One variable `w = [1, −2]` whose gradient is `w` itself.
    fn one_var() -> (Var, Adam) {
        let w = Var::from_vec(vec![1f32, -2.0], 2, &Device::Cpu).expect("var");
        let adam = Adam::new(vec![("w".into(), w.clone())], AdamConfig::default()).expect("adam");
        (w, adam)
    }

    fn step(w: &Var, adam: &mut Adam) {
        let grads = w.as_tensor().sqr().expect("sqr").sum_all().expect("sum");
        let grads = (grads * 0.5).expect("half").backward().expect("backward");
        adam.step(&grads).expect("step");
    }

    fn values(t: &Tensor) -> Vec<f32> {
        t.to_vec1().expect("values")
    }

    #[test]
    fn the_average_follows_each_update_and_swaps_back() {
        let (w, adam) = one_var();
        let mut adam = adam.with_average(0.9).expect("average");
        // Adam's first two updates move each weight by lr against its
        // gradient's sign: 1 → 0.999 → 0.998, −2 → −1.999 → −1.998.
        step(&w, &mut adam);
        step(&w, &mut adam);
        let trained = values(w.as_tensor());
        // a₀ = w₀; a₁ = 0.9 a₀ + 0.1 w₁; a₂ = 0.9 a₁ + 0.1 w₂.
        let expect = |w0: f32, w1: f32, w2: f32| 0.9 * (0.9 * w0 + 0.1 * w1) + 0.1 * w2;
        let want = [expect(1.0, 0.999, 0.998), expect(-2.0, -1.999, -1.998)];
        adam.swap_average().expect("swap");
        for (got, want) in values(w.as_tensor()).iter().zip(want) {
            assert!((got - want).abs() < 1e-6, "{got} against {want}");
        }
        adam.swap_average().expect("swap back");
        assert_eq!(values(w.as_tensor()), trained);
        // Saved and restored with the moments.
        let state = adam.state();
        assert_eq!(values(&state["w.average"]).len(), 2);
        let (w2, fresh) = one_var();
        let mut fresh = fresh.with_average(0.9).expect("average");
        fresh.load_state(&state, adam.step).expect("load");
        fresh.swap_average().expect("swap");
        assert_eq!(values(w2.as_tensor()), values(&state["w.average"]));
        // A state without the average does not restore an optimiser that
        // keeps one.
        let (_, plain) = one_var();
        let err = fresh
            .load_state(&plain.state(), 0)
            .expect_err("no average saved");
        assert!(err.to_string().contains("w.average"), "{err}");
    }

    #[test]
    fn an_average_needs_a_decay_between_0_and_1() {
        for beta in [0.0, 1.0, -0.5, f64::NAN] {
            let (_, adam) = one_var();
            assert!(adam.with_average(beta).is_err(), "{beta}");
        }
        let (w, mut adam) = one_var();
        step(&w, &mut adam);
        let before = values(w.as_tensor());
        adam.swap_average().expect("no average: nothing to swap");
        assert_eq!(values(w.as_tensor()), before);
        assert!(!adam.state().contains_key("w.average"));
    }
}
