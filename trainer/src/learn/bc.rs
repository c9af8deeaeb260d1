//! Behaviour cloning: fit the actor to demonstration actions by mean squared error.
//!
//! It is both the diagnostic the learner needs (can this observation and this network represent the
//! demonstrator at all?) and the starting point of the reinforcement learner's fine-tuning. Inputs are
//! scaled by a fixed [`ObsScaling`] measured on the demonstration data and clipped, the same map the
//! exported policy file applies (mean, scale and `obs_clip` in its header), so the runtime sees exactly
//! what the network was trained on.

use serde::{Deserialize, Serialize};

use super::LearnError;
use super::adam::{AdamConfig, AdamLocal, AdamShared, adam_step};
use super::kernel::Engine;
use super::nets::{Activation, Mlp, MlpSpec};
use super::norm::Normalizer;
use super::rng::Rng;

/// Fixed observation scaling: the learner's [`Normalizer`] measured once on the demonstration data,
/// then clipped: `clip((x - mean) * inv_std, -clip, clip)`.
#[derive(Debug, Clone, PartialEq)]
pub struct ObsScaling {
    /// Mean and inverse standard deviation.
    pub norm: Normalizer,
    /// Bound of the scaled values.
    pub clip: f32,
}

impl ObsScaling {
    /// Mean and standard deviation of `rows` (row-major, `dim` wide); a component's standard deviation
    /// is at least `min_std` (inputs that barely vary in the data are not blown up).
    pub fn from_rows(rows: &[f32], dim: usize, min_std: f32, clip: f32) -> Self {
        let n = (rows.len() / dim.max(1)).max(1) as f64;
        let mut mean = vec![0.0f64; dim];
        let mut sq = vec![0.0f64; dim];
        for row in rows.chunks_exact(dim) {
            for (i, &v) in row.iter().enumerate() {
                mean[i] += f64::from(v);
            }
        }
        mean.iter_mut().for_each(|m| *m /= n);
        for row in rows.chunks_exact(dim) {
            for (i, &v) in row.iter().enumerate() {
                sq[i] += (f64::from(v) - mean[i]).powi(2);
            }
        }
        let inv_std = sq
            .iter()
            .map(|s| (1.0 / (s / n).sqrt().max(f64::from(min_std))) as f32)
            .collect();
        Self {
            norm: Normalizer {
                mean: mean.iter().map(|&m| m as f32).collect(),
                inv_std,
            },
            clip,
        }
    }

    /// Scales rows in place.
    pub fn apply_rows(&self, data: &mut [f32]) {
        self.norm.apply_rows(data);
        data.iter_mut()
            .for_each(|v| *v = v.clamp(-self.clip, self.clip));
    }
}

/// Settings of behaviour cloning.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BcConfig {
    /// Hidden layer widths of the actor (ReLU; tanh output).
    pub hidden: Vec<usize>,
    /// Gradient steps.
    pub steps: u64,
    /// Rows per mini-batch.
    pub batch: usize,
    /// Adam settings.
    pub adam: AdamConfig,
    /// The learning rate follows a cosine from `adam.lr` down to `adam.lr * final_lr_fraction` at
    /// the last step (1: constant, the first releases' schedule).
    pub final_lr_fraction: f32,
    /// Floor of the scaling's standard deviation (observation units).
    pub min_std: f32,
    /// Bound of the scaled observations.
    pub obs_clip: f32,
    /// Labels are clipped to `[-label_clip, label_clip]` (a tanh output cannot reach +-1).
    pub label_clip: f32,
    /// Seed of initialisation and sampling.
    pub seed: u64,
    /// The actor also takes the controller's task features (`dex_runtime::features`: the pinch
    /// site's yaw, the bricks' yaws relative to it modulo the half turn, the pinch-to-brick
    /// vectors in the pinch frame) after the observation; its file lists them and the runtime
    /// computes them. Off in the first releases' recipe.
    pub features: bool,
}

impl Default for BcConfig {
    /// 256-256 actor, 20,000 steps of batch 256, Adam 1e-3, scaling floor 0.01 clipped at 5, labels
    /// at +-0.97. Chosen from the spike described in docs/experiments.md (BC section).
    fn default() -> Self {
        Self {
            hidden: vec![256, 256],
            steps: 20_000,
            batch: 256,
            adam: AdamConfig::default(),
            final_lr_fraction: 1.0,
            min_std: 0.01,
            obs_clip: 5.0,
            label_clip: 0.97,
            seed: 0,
            features: false,
        }
    }
}

impl BcConfig {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), LearnError> {
        let bad = |field, why| Err(LearnError::Config { field, why });
        if self.hidden.is_empty() || self.hidden.contains(&0) {
            return bad("bc.hidden", "needs at least one non-empty hidden layer");
        }
        if self.batch == 0 {
            return bad("bc.batch", "must be at least 1");
        }
        if !(self.adam.lr > 0.0 && self.adam.lr.is_finite()) {
            return bad("bc.adam.lr", "must be positive");
        }
        if !(self.min_std > 0.0 && self.min_std.is_finite()) {
            return bad("bc.min_std", "must be positive");
        }
        if !(self.obs_clip > 0.0 && self.obs_clip.is_finite()) {
            return bad("bc.obs_clip", "must be positive");
        }
        if !(self.label_clip > 0.0 && self.label_clip <= 1.0) {
            return bad("bc.label_clip", "must be in (0, 1]");
        }
        if !(self.final_lr_fraction > 0.0 && self.final_lr_fraction <= 1.0) {
            return bad("bc.final_lr_fraction", "must be in (0, 1]");
        }
        Ok(())
    }
}

/// A cloned actor with the scaling it expects.
#[derive(Debug, Clone)]
pub struct BcPolicy {
    /// The network's shape.
    pub actor: Mlp,
    /// Its parameters.
    pub params: Vec<f32>,
    /// The observation scaling it was trained with.
    pub scaling: ObsScaling,
    /// Mean squared error over the last 1% of steps.
    pub final_loss: f32,
}

/// Fits an actor to (`obs`, `labels`) rows (`obs_dim` and `act_dim` wide); `progress(step, loss)` is
/// called every 100 steps.
pub fn train_bc(
    obs: &[f32],
    labels: &[f32],
    obs_dim: usize,
    act_dim: usize,
    cfg: &BcConfig,
    progress: &mut dyn FnMut(u64, f32),
) -> Result<BcPolicy, LearnError> {
    cfg.validate()?;
    let n = obs.len() / obs_dim.max(1);
    if n == 0 || obs.len() != n * obs_dim {
        return Err(LearnError::Shape {
            what: "BC observations",
            expected: n.max(1) * obs_dim,
            got: obs.len(),
        });
    }
    if labels.len() != n * act_dim {
        return Err(LearnError::Shape {
            what: "BC labels",
            expected: n * act_dim,
            got: labels.len(),
        });
    }
    let scaling = ObsScaling::from_rows(obs, obs_dim, cfg.min_std, cfg.obs_clip);
    let mut x = obs.to_vec();
    scaling.apply_rows(&mut x);
    let y: Vec<f32> = labels
        .iter()
        .map(|v| v.clamp(-cfg.label_clip, cfg.label_clip))
        .collect();
    let spec = MlpSpec::stack(
        obs_dim,
        &cfg.hidden,
        Activation::Relu,
        false,
        act_dim,
        Activation::Tanh,
    );
    let actor = Mlp::new(spec, Engine::default())?;
    let mut rng = Rng::derive(cfg.seed, 0xBC);
    let mut params = actor.init_params(&mut rng, 3e-3);
    let mut grads = vec![0.0f32; params.len()];
    let mut local = AdamLocal::new(params.len());
    let mut shared = AdamShared::new(params.len());
    let batch = cfg.batch.min(n);
    let mut scratch = actor.scratch(batch);
    let mut bx = vec![0.0f32; batch * obs_dim];
    let mut by = vec![0.0f32; batch * act_dim];
    let mut dout = vec![0.0f32; batch * act_dim];
    let tail = (cfg.steps / 100).max(1);
    let (mut tail_sum, mut tail_n) = (0.0f64, 0u64);
    let mut window = 0.0f64;
    for step in 1..=cfg.steps {
        for b in 0..batch {
            let i = rng.below(n);
            bx[b * obs_dim..(b + 1) * obs_dim].copy_from_slice(&x[i * obs_dim..(i + 1) * obs_dim]);
            by[b * act_dim..(b + 1) * act_dim].copy_from_slice(&y[i * act_dim..(i + 1) * act_dim]);
        }
        let out = actor.forward(&params, &bx, batch, &mut scratch)?;
        let mut loss = 0.0f64;
        let k = 2.0 / (batch * act_dim) as f32;
        for ((d, &o), &t) in dout.iter_mut().zip(out).zip(&by) {
            let e = o - t;
            loss += f64::from(e * e);
            *d = k * e;
        }
        loss /= (batch * act_dim) as f64;
        actor.backward(&params, &bx, &mut scratch, &dout, Some(&mut grads), None)?;
        let adam = if cfg.final_lr_fraction == 1.0 {
            cfg.adam
        } else {
            let progress = (step - 1) as f32 / (cfg.steps.max(2) - 1) as f32;
            let cosine = 0.5 * (1.0 + (std::f32::consts::PI * progress).cos());
            let f = cfg.final_lr_fraction + (1.0 - cfg.final_lr_fraction) * cosine;
            AdamConfig {
                lr: cfg.adam.lr * f,
                ..cfg.adam
            }
        };
        adam_step(&adam, &mut params, &grads, &mut local, &mut shared);
        window += loss;
        if step > cfg.steps - tail {
            tail_sum += loss;
            tail_n += 1;
        }
        if step % 100 == 0 {
            progress(step, (window / 100.0) as f32);
            window = 0.0;
        }
    }
    Ok(BcPolicy {
        actor,
        params,
        scaling,
        final_loss: (tail_sum / tail_n.max(1) as f64) as f32,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scaling_centres_scales_and_clips() {
        let rows = [0.0f32, 5.0, 2.0, 5.0, 4.0, 5.0];
        let s = ObsScaling::from_rows(&rows, 2, 0.01, 3.0);
        assert!((s.norm.mean[0] - 2.0).abs() < 1e-6 && (s.norm.mean[1] - 5.0).abs() < 1e-6);
        assert!(
            (s.norm.inv_std[1] - 100.0).abs() < 1e-3,
            "floor 0.01 on a constant input"
        );
        let mut v = [4.0f32, 6.0];
        s.apply_rows(&mut v);
        assert!((v[0] - 2.0 / (8.0f32 / 3.0).sqrt()).abs() < 1e-5);
        assert_eq!(v[1], 3.0, "clipped");
    }

    #[test]
    fn clones_a_smooth_function() {
        // y = tanh-able function of x; BC must fit it well below the label variance.
        let mut rng = Rng::seed_from_u64(3);
        let n = 2000;
        let obs: Vec<f32> = (0..n * 3).map(|_| rng.uniform(-1.0, 1.0)).collect();
        let labels: Vec<f32> = obs
            .chunks_exact(3)
            .flat_map(|x| [0.8 * (x[0] - x[1]).clamp(-1.0, 1.0), 0.5 * x[2] * x[0]])
            .collect();
        let cfg = BcConfig {
            hidden: vec![32, 32],
            steps: 1500,
            batch: 64,
            ..BcConfig::default()
        };
        let p = train_bc(&obs, &labels, 3, 2, &cfg, &mut |_, _| {}).unwrap();
        assert!(p.final_loss < 0.01, "loss {}", p.final_loss);
        // Same seed, same result.
        let q = train_bc(&obs, &labels, 3, 2, &cfg, &mut |_, _| {}).unwrap();
        assert_eq!(p.params, q.params);
        // A learning rate annealed to 5% fits too, along another path.
        let annealed = BcConfig {
            final_lr_fraction: 0.05,
            ..cfg
        };
        let a = train_bc(&obs, &labels, 3, 2, &annealed, &mut |_, _| {}).unwrap();
        assert!(a.final_loss < 0.01, "annealed loss {}", a.final_loss);
        assert_ne!(a.params, p.params);
    }

    #[test]
    fn refuses_bad_settings_and_shapes() {
        let bad = BcConfig {
            label_clip: 1.5,
            ..BcConfig::default()
        };
        assert!(bad.validate().is_err());
        for f in [0.0, 1.5, f32::NAN] {
            let bad = BcConfig {
                final_lr_fraction: f,
                ..BcConfig::default()
            };
            assert!(bad.validate().is_err(), "final_lr_fraction {f}");
        }
        assert!(
            train_bc(
                &[0.0; 5],
                &[0.0; 2],
                3,
                2,
                &BcConfig::default(),
                &mut |_, _| {}
            )
            .is_err()
        );
    }
}
