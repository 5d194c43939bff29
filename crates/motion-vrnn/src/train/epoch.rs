//! The epochs of a run: Adam steps over shuffled windows, validation,
//! judging, checkpoints; and the probe of several initialisations.

use super::*;

/// What every epoch of a run reads.
pub(super) struct Epochs<'a> {
    pub(super) data: &'a Dataset,
    pub(super) train: &'a Windows,
    pub(super) val: Option<&'a Windows>,
    pub(super) config: &'a TrainConfig,
    pub(super) run: &'a Path,
    pub(super) device: &'a Device,
}

impl Epochs<'_> {
    /// The epochs from `s.start_epoch` to the last (or early stopping) of
    /// `t`, each judged where `judge` says, its metrics appended and its
    /// checkpoints saved: every epoch's metrics, resumed ones included.
    pub(super) fn all(
        &self,
        t: &Trained,
        adam: &mut Adam,
        judge: Option<&(Judge, usize)>,
        s: RunState,
        progress: &dyn TrainProgress,
    ) -> Result<Vec<EpochMetrics>, TrainError> {
        let (config, data, run, device) = (self.config, self.data, self.run, self.device);
        let metrics_path = run.join(layout::METRICS);
        let RunState {
            mut history,
            start_epoch,
            mut best,
            mut best_generated,
            init,
        } = s;
        let mut stale = history.len().saturating_sub(best.1);
        for epoch in start_epoch..config.epochs {
            if config.early_stopping.is_some_and(|p| stale >= p) {
                break;
            }
            let started = std::time::Instant::now();
            let mut m = self.run(t, adam, epoch, progress)?;
            let improved = m.val_loss() < best.0;
            if improved {
                best = (m.val_loss(), m.epoch);
                stale = 0;
            } else {
                stale += 1;
            }
            // Judge every `every` epochs, at the last epoch, and before early
            // stopping ends the run.
            let last =
                m.epoch == config.epochs || config.early_stopping.is_some_and(|p| stale >= p);
            let chosen = match judge {
                None => improved,
                Some((j, every))
                    if (m.epoch % every == 0 && m.epoch >= config.schedule_end()) || last =>
                {
                    let v = j.judge(&t.model, device)?;
                    let better = best_generated.is_none_or(|(s, _)| v.score < s);
                    if better {
                        best_generated = Some((v.score, m.epoch));
                    }
                    m.generated = Some(v);
                    better
                }
                Some(_) => false,
            };
            m.seconds = started.elapsed().as_secs_f64();
            let meta = CheckpointMeta {
                config: config.clone(),
                dataset_manifest_sha256: data.manifest_sha256.clone(),
                dataset: data.dir.display().to_string(),
                epoch: m.epoch,
                step: adam.step,
                best_val_loss: best.0,
                best_epoch: best.1,
                best_generated,
                init: init.clone(),
                metrics: Some(m.clone()),
            };
            // Metrics first, then the checkpoint: a resume trims metrics to the
            // checkpoint's epoch, so a kill in between loses nothing.
            append_metrics(&metrics_path, &m)?;
            if chosen {
                save_checkpoint(run, layout::BEST, &t.varmap, None, &meta)?;
            }
            save_checkpoint(run, layout::LAST, &t.varmap, Some(&*adam), &meta)?;
            progress.epoch(&m);
            history.push(m);
        }
        Ok(history)
    }

    /// Epoch `epoch` (0-based) of `t`: Adam steps over the shuffled training
    /// windows, then the validation loss; the metrics, not yet judged.
    pub(super) fn run(
        &self,
        t: &Trained,
        adam: &mut Adam,
        epoch: usize,
        progress: &dyn TrainProgress,
    ) -> Result<EpochMetrics, TrainError> {
        let (config, train, device) = (self.config, self.train, self.device);
        let vars = adam.vars().to_vec();
        let var_list: Vec<Var> = vars.iter().map(|(_, v)| v.clone()).collect();
        let started = std::time::Instant::now();
        let kl_w = config.kl_weight(epoch);
        let lr = config.lr(epoch);
        adam.set_lr(lr);
        let perm = Rng::new(config.seed, 1000 + epoch as u64).permutation(train.n);
        // The late epochs' model shares `t`'s variables.
        let late = match config.late_model(epoch) {
            Some(c) => Some(Vrnn::new(
                &c,
                VarBuilder::from_varmap(&t.varmap, DType::F32, device),
            )?),
            None => None,
        };
        let step_model = late.as_ref().unwrap_or(&t.model);
        let (mut sum_r, mut sum_k, mut seen) = (0.0f64, 0.0f64, 0usize);
        for chunk in perm.chunks(config.batch) {
            let step = adam.step + 1;
            let x = self.batch_control(&train.batch(chunk, device)?, step)?;
            let eps = noise(
                config.seed,
                step,
                train.length,
                chunk.len(),
                config.model.latent,
                device,
            )?;
            let feed = feed_mask(
                config.seed,
                step,
                chunk.len(),
                train.length,
                config.feed_share(epoch),
                device,
            )?;
            let cond = self.batch_condition(chunk, step)?;
            let ((r, k), grads) = sharded(
                step_model,
                &x,
                &eps,
                feed.as_ref(),
                cond.as_ref(),
                Some((kl_w, &var_list)),
            )?;
            if !(r.is_finite() && k.is_finite()) {
                return Err(TrainError::NonFinite {
                    step,
                    epoch: epoch + 1,
                    recon: r,
                    kl: k,
                    dir: self.run.to_path_buf(),
                });
            }
            let mut grads = grads.ok_or_else(|| TrainError::Invalid("no gradients".into()))?;
            if let Some(max) = config.clip_grad_norm {
                clip_grad_norm(&vars, &mut grads, max)?;
            }
            adam.step(&grads)?;
            sum_r += r as f64 * chunk.len() as f64;
            sum_k += k as f64 * chunk.len() as f64;
            seen += chunk.len();
            let wps = seen as f64 / started.elapsed().as_secs_f64().max(1e-9);
            progress.step(epoch + 1, adam.step, r, k, wps);
        }
        let train_secs = started.elapsed().as_secs_f64();
        self.metrics(t, adam, epoch, (kl_w, lr), (sum_r, sum_k, seen), train_secs)
    }

    /// The windows `x` with their control ([`Config::with_control`]), left
    /// free in the share [`CONTROL_DROPOUT`] drawn from the seed and step
    /// (`x` as it is without the control).
    pub(super) fn batch_control(&self, x: &Tensor, step: u64) -> Result<Tensor, TrainError> {
        let model = &self.config.model;
        if !model.parts.control {
            return Ok(x.clone());
        }
        let mut rng = Rng::new(self.config.seed ^ 0xC047_0000_0000, step);
        let keep: Vec<bool> = (0..x.dim(0)?)
            .map(|_| rng.uniform() >= CONTROL_DROPOUT)
            .collect();
        Ok(model.with_control(x, &keep)?)
    }

    /// The condition weights of the training windows `chunk` at step
    /// `step`: each window's category, or none for the share
    /// [`Conditioning::dropout`] drawn from the seed and step (None when
    /// unconditioned).
    pub(super) fn batch_condition(
        &self,
        chunk: &[usize],
        step: u64,
    ) -> Result<Option<Tensor>, TrainError> {
        let config = self.config;
        Ok(match config.condition {
            Some(c) => {
                let mut rng = Rng::new(config.seed ^ 0xC0DE_0000_0000, step);
                let drop: Vec<bool> = chunk.iter().map(|_| rng.uniform() < c.dropout).collect();
                let model = &config.model;
                model.window_condition(
                    self.data.categories_of("train"),
                    chunk,
                    1.0,
                    |k| drop[k],
                    self.device,
                )?
            }
            None => None,
        })
    }

    /// Epoch `epoch`'s metrics after its steps: the KL weight and learning
    /// rate it trained at, its summed training losses over `seen` windows
    /// in `train_secs` seconds, and the validation loss (the training
    /// losses without a validation split); an error if that is not finite.
    pub(super) fn metrics(
        &self,
        t: &Trained,
        adam: &Adam,
        epoch: usize,
        (kl_w, lr): (f64, f64),
        (sum_r, sum_k, seen): (f64, f64, usize),
        train_secs: f64,
    ) -> Result<EpochMetrics, TrainError> {
        let (config, device) = (self.config, self.device);
        let (val_recon, val_kl) = match self.val {
            Some(v) => evaluate(
                &t.model,
                v,
                self.data.categories_of("val"),
                config.batch,
                config.seed,
                device,
            )?,
            None => (sum_r / seen as f64, sum_k / seen as f64),
        };
        let m = EpochMetrics {
            epoch: epoch + 1,
            step: adam.step,
            train_recon: sum_r / seen as f64,
            train_kl: sum_k / seen as f64,
            val_recon,
            val_kl,
            kl_weight: kl_w,
            lr: Some(lr),
            windows_per_s: seen as f64 / train_secs.max(1e-9),
            seconds: 0.0,
            generated: None,
        };
        if !m.val_loss().is_finite() {
            return Err(TrainError::NonFinite {
                step: adam.step,
                epoch: epoch + 1,
                recon: val_recon as f32,
                kl: val_kl as f32,
                dir: self.run.to_path_buf(),
            });
        }
        Ok(m)
    }

    /// [`TrainConfig::inits`]: each candidate trained for `inits.epochs`
    /// epochs, the one with the lowest validation loss kept (the first of
    /// equals; a candidate whose loss leaves the finite numbers loses).
    pub(super) fn probe(
        &self,
        inits: Inits,
        progress: &dyn TrainProgress,
    ) -> Result<InitChoice, TrainError> {
        // A run shorter than the probe is probed over its whole length.
        let epochs = inits.epochs.min(self.config.epochs);
        let mut val_losses = Vec::with_capacity(inits.candidates);
        for k in 0..inits.candidates {
            let seed = inits.seed(self.config.seed, k);
            progress.note(&format!(
                "initialisation {} of {} (weights from seed {seed}): {epochs} epochs",
                k + 1,
                inits.candidates,
            ));
            let t = init_model(&self.config.model, seed, self.device)?;
            let mut adam = Adam::new(named_vars(&t.varmap), self.config.adam)?;
            let mut loss = f64::INFINITY;
            for epoch in 0..epochs {
                match self.run(&t, &mut adam, epoch, progress) {
                    Ok(m) => loss = m.val_loss(),
                    Err(TrainError::NonFinite { .. }) => {
                        loss = f64::INFINITY;
                        break;
                    }
                    Err(e) => return Err(e),
                }
            }
            val_losses.push(loss);
        }
        let kept =
            (0..val_losses.len()).fold(0, |b, k| if val_losses[k] < val_losses[b] { k } else { b });
        let shown: Vec<String> = val_losses.iter().map(|l| format!("{l:.1}")).collect();
        progress.note(&format!(
            "kept initialisation {} of {} (validation loss after {epochs} epochs: {})",
            kept + 1,
            inits.candidates,
            shown.join(", ")
        ));
        Ok(InitChoice {
            seed: inits.seed(self.config.seed, kept),
            val_losses,
        })
    }
}
