//! The DDPG update of Popov et al. (2017): critic regression on `y = r + gamma Q'(s', mu'(s'))`, the
//! deterministic policy gradient through the critic, and target networks.
//!
//! This module computes gradients on a worker's local copy of the parameters; applying them (Adam,
//! target updates, sharing between ADPG-R workers) is the trainer's job. All buffers live in
//! [`UpdateBuffers`], built once per worker.

use super::LearnError;
use super::kernel::Engine;
use super::nets::{Activation, Mlp, MlpScratch, MlpSpec};
use super::replay::Batch;
use serde::{Deserialize, Serialize};

/// How target networks follow the online networks.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TargetUpdate {
    /// Copy the online parameters every `every` updates (the paper's scheme).
    Copy {
        /// Period in (global) updates; 0 is treated as 1.
        every: u64,
    },
    /// After every update, `target = tau * online + (1 - tau) * target`.
    Polyak {
        /// Mixing rate in `(0, 1]`.
        tau: f32,
    },
}

impl Default for TargetUpdate {
    fn default() -> Self {
        TargetUpdate::Copy { every: 100 }
    }
}

impl TargetUpdate {
    /// Moves `target` toward `online` if this update (`updates`, counted from 1) is due. Returns whether
    /// the target changed.
    pub fn apply(&self, updates: u64, online: &[f32], target: &mut [f32]) -> bool {
        match *self {
            TargetUpdate::Copy { every } => {
                if updates.is_multiple_of(every.max(1)) {
                    target.copy_from_slice(online);
                    true
                } else {
                    false
                }
            }
            TargetUpdate::Polyak { tau } => {
                target
                    .iter_mut()
                    .zip(online)
                    .for_each(|(t, &o)| *t += tau * (o - *t));
                true
            }
        }
    }
}

/// Shapes of the two networks and the update's hyper-parameters (learning rates are in the trainer's
/// Adam configs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DdpgConfig {
    /// Hidden widths of the actor (`obs -> hidden... -> act`, ReLU, tanh output).
    pub actor_hidden: Vec<usize>,
    /// Hidden widths of the critic (`obs ++ act -> hidden... -> 1`, ReLU, linear output).
    pub critic_hidden: Vec<usize>,
    /// Layer norm on the critic's hidden layers.
    pub critic_layer_norm: bool,
    /// Discount factor.
    pub gamma: f32,
    /// Mini-batch size N.
    pub batch_size: usize,
    /// Initial weights of both output layers are uniform in `+-final_init`.
    pub final_init: f32,
    /// Target network scheme.
    pub target: TargetUpdate,
    /// GEMM engine.
    pub engine: Engine,
}

impl Default for DdpgConfig {
    fn default() -> Self {
        DdpgConfig {
            actor_hidden: vec![256, 256],
            critic_hidden: vec![256, 256],
            critic_layer_norm: false,
            gamma: 0.99,
            batch_size: 64,
            final_init: 3e-3,
            target: TargetUpdate::default(),
            engine: Engine::default(),
        }
    }
}

/// The actor and critic shapes for an environment's dimensions.
#[derive(Debug, Clone)]
pub struct Networks {
    /// Policy `mu(s)`, outputs in `[-1, 1]`.
    pub actor: Mlp,
    /// Action value `Q(s, a)`, input is the observation followed by the action.
    pub critic: Mlp,
    /// Observation length.
    pub obs_dim: usize,
    /// Action length.
    pub act_dim: usize,
}

impl Networks {
    /// Builds both networks. Fails on zero dimensions.
    pub fn new(cfg: &DdpgConfig, obs_dim: usize, act_dim: usize) -> Result<Self, LearnError> {
        if obs_dim == 0 || act_dim == 0 {
            return Err(LearnError::BadNetwork(
                "observation and action sizes must be positive",
            ));
        }
        let actor = Mlp::new(
            MlpSpec::stack(
                obs_dim,
                &cfg.actor_hidden,
                Activation::Relu,
                false,
                act_dim,
                Activation::Tanh,
            ),
            cfg.engine,
        )?;
        let critic = Mlp::new(
            MlpSpec::stack(
                obs_dim + act_dim,
                &cfg.critic_hidden,
                Activation::Relu,
                cfg.critic_layer_norm,
                1,
                Activation::Linear,
            ),
            cfg.engine,
        )?;
        Ok(Networks {
            actor,
            critic,
            obs_dim,
            act_dim,
        })
    }
}

/// Preallocated buffers for one worker's updates.
#[derive(Debug, Clone)]
pub struct UpdateBuffers {
    /// The sampled mini-batch.
    pub batch: Batch,
    actor_s: MlpScratch,
    critic_s: MlpScratch,
    target_actor_s: MlpScratch,
    critic_in: Vec<f32>,
    y: Vec<f32>,
    dq: Vec<f32>,
    dcritic_in: Vec<f32>,
    dact: Vec<f32>,
    /// Critic gradient of the last [`critic_gradient`] call.
    pub critic_grads: Vec<f32>,
    /// Actor gradient of the last [`actor_gradient`] call.
    pub actor_grads: Vec<f32>,
}

impl UpdateBuffers {
    /// Buffers for mini-batches of `batch_size`.
    pub fn new(nets: &Networks, batch_size: usize) -> Self {
        let n = batch_size.max(1);
        let ci = nets.obs_dim + nets.act_dim;
        UpdateBuffers {
            batch: Batch::new(n, nets.obs_dim, nets.act_dim),
            actor_s: nets.actor.scratch(n),
            critic_s: nets.critic.scratch(n),
            target_actor_s: nets.actor.scratch(n),
            critic_in: vec![0.0; n * ci],
            y: vec![0.0; n],
            dq: vec![0.0; n],
            dcritic_in: vec![0.0; n * ci],
            dact: vec![0.0; n * nets.act_dim],
            critic_grads: vec![0.0; nets.critic.num_params()],
            actor_grads: vec![0.0; nets.actor.num_params()],
        }
    }
}

/// Writes rows `[obs | act]` into `out`.
fn concat(obs: &[f32], act: &[f32], n: usize, od: usize, ad: usize, out: &mut [f32]) {
    for r in 0..n {
        let row = &mut out[r * (od + ad)..(r + 1) * (od + ad)];
        row[..od].copy_from_slice(&obs[r * od..(r + 1) * od]);
        row[od..].copy_from_slice(&act[r * ad..(r + 1) * ad]);
    }
}

/// Critic gradient on `bufs.batch` into `bufs.critic_grads`, for the loss
/// `1/(2N) sum (Q(s,a) - y)^2` with `y = r + gamma (1 - terminal) Q'(s', mu'(s'))`. Returns the loss.
#[allow(clippy::too_many_arguments)]
pub fn critic_gradient(
    nets: &Networks,
    gamma: f32,
    critic: &[f32],
    target_actor: &[f32],
    target_critic: &[f32],
    bufs: &mut UpdateBuffers,
) -> Result<f32, LearnError> {
    let n = bufs.batch.len;
    if n == 0 {
        return Err(LearnError::EmptyReplay);
    }
    let (od, ad) = (nets.obs_dim, nets.act_dim);
    let ci = od + ad;
    let next_act = nets.actor.forward(
        target_actor,
        &bufs.batch.next_obs,
        n,
        &mut bufs.target_actor_s,
    )?;
    concat(
        &bufs.batch.next_obs,
        next_act,
        n,
        od,
        ad,
        &mut bufs.critic_in,
    );
    let q_next = nets.critic.forward(
        target_critic,
        &bufs.critic_in[..n * ci],
        n,
        &mut bufs.critic_s,
    )?;
    for (((y, &r), &nd), &q) in bufs.y[..n]
        .iter_mut()
        .zip(&bufs.batch.reward)
        .zip(&bufs.batch.not_done)
        .zip(q_next)
    {
        *y = r + gamma * nd * q;
    }
    concat(
        &bufs.batch.obs,
        &bufs.batch.act,
        n,
        od,
        ad,
        &mut bufs.critic_in,
    );
    let q = nets
        .critic
        .forward(critic, &bufs.critic_in[..n * ci], n, &mut bufs.critic_s)?;
    let mut loss = 0.0f32;
    let inv_n = 1.0 / n as f32;
    for ((dq, &q), &y) in bufs.dq[..n].iter_mut().zip(q).zip(&bufs.y) {
        let e = q - y;
        loss += 0.5 * e * e * inv_n;
        *dq = e * inv_n;
    }
    nets.critic.backward(
        critic,
        &bufs.critic_in[..n * ci],
        &mut bufs.critic_s,
        &bufs.dq[..n],
        Some(&mut bufs.critic_grads),
        None,
    )?;
    Ok(loss)
}

/// Actor gradient on `bufs.batch.obs` into `bufs.actor_grads`, for the loss `-1/N sum Q(s, mu(s))`
/// (gradient flows through the critic's action input only). Returns the mean `Q(s, mu(s))`.
pub fn actor_gradient(
    nets: &Networks,
    actor: &[f32],
    critic: &[f32],
    bufs: &mut UpdateBuffers,
) -> Result<f32, LearnError> {
    let n = bufs.batch.len;
    if n == 0 {
        return Err(LearnError::EmptyReplay);
    }
    let (od, ad) = (nets.obs_dim, nets.act_dim);
    let ci = od + ad;
    let act = nets
        .actor
        .forward(actor, &bufs.batch.obs, n, &mut bufs.actor_s)?;
    concat(&bufs.batch.obs, act, n, od, ad, &mut bufs.critic_in);
    let q = nets
        .critic
        .forward(critic, &bufs.critic_in[..n * ci], n, &mut bufs.critic_s)?;
    let inv_n = 1.0 / n as f32;
    let mean_q = q.iter().sum::<f32>() * inv_n;
    bufs.dq[..n].fill(-inv_n);
    nets.critic.backward(
        critic,
        &bufs.critic_in[..n * ci],
        &mut bufs.critic_s,
        &bufs.dq[..n],
        None,
        Some(&mut bufs.dcritic_in),
    )?;
    for r in 0..n {
        bufs.dact[r * ad..(r + 1) * ad]
            .copy_from_slice(&bufs.dcritic_in[r * ci + od..(r + 1) * ci]);
    }
    nets.actor.backward(
        actor,
        &bufs.batch.obs,
        &mut bufs.actor_s,
        &bufs.dact[..n * ad],
        Some(&mut bufs.actor_grads),
        None,
    )?;
    Ok(mean_q)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::learn::rng::Rng;

    #[test]
    fn target_update_schemes() {
        let online = [1.0f32, 2.0];
        let mut t = [0.0f32, 0.0];
        assert!(!TargetUpdate::Copy { every: 3 }.apply(1, &online, &mut t));
        assert!(TargetUpdate::Copy { every: 3 }.apply(3, &online, &mut t));
        assert_eq!(t, online);
        let mut t = [0.0f32, 0.0];
        TargetUpdate::Polyak { tau: 0.5 }.apply(1, &online, &mut t);
        assert_eq!(t, [0.5, 1.0]);
    }

    #[test]
    fn actor_gradient_is_the_chain_rule_through_the_critic() {
        // d/dtheta -mean Q(s, mu_theta(s)) checked by a central difference on a few parameters.
        let cfg = DdpgConfig {
            actor_hidden: vec![5],
            critic_hidden: vec![6],
            final_init: 0.5,
            batch_size: 4,
            ..DdpgConfig::default()
        };
        let nets = Networks::new(&cfg, 3, 2).expect("nets");
        let mut rng = Rng::seed_from_u64(5);
        let actor = nets.actor.init_params(&mut rng, 0.5);
        let critic = nets.critic.init_params(&mut rng, 0.5);
        let mut bufs = UpdateBuffers::new(&nets, 4);
        bufs.batch.len = 4;
        for v in &mut bufs.batch.obs {
            *v = rng.uniform(-1.0, 1.0);
        }
        let q0 = actor_gradient(&nets, &actor, &critic, &mut bufs).expect("grad");
        assert!(q0.is_finite());
        let grads = bufs.actor_grads.clone();
        for &i in &[0usize, 7, 14, actor.len() - 1] {
            let h = 1e-2f32;
            let mut p = actor.clone();
            p[i] += h;
            let up = actor_gradient(&nets, &p, &critic, &mut bufs).expect("grad");
            p[i] -= 2.0 * h;
            let down = actor_gradient(&nets, &p, &critic, &mut bufs).expect("grad");
            let fd = -(up - down) / (2.0 * h);
            assert!(
                (fd - grads[i]).abs() < 2e-3 + 0.05 * fd.abs(),
                "param {i}: fd {fd} vs {}",
                grads[i]
            );
        }
    }
}
