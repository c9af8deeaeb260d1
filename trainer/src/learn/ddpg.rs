//! The DDPG update of Popov et al. (2017): critic regression on `y = r + gamma Q'(s', mu'(s'))`, the
//! deterministic policy gradient through the critic, and target networks.
//!
//! This module computes gradients on a worker's local copy of the parameters; applying them (Adam,
//! target updates, sharing between ADPG-R workers) is the trainer's job. All buffers live in
//! [`UpdateBuffers`], built once per worker.
//!
//! Beyond the paper, each switchable and off by default: the TD3 targets ([`super::td3`]: minimum of
//! twin target critics, smoothed target actions), and the actor loss's extra terms
//! ([`ActorLoss`]: a Q-filtered cloning term on demonstration rows, [`super::demo_data`]; an L2
//! penalty on the actions, against the bang-bang saturation of a pure `-Q` loss).

use super::LearnError;
use super::kernel::Engine;
use super::nets::{Activation, Mlp, MlpScratch, MlpSpec};
use super::replay::Batch;
use super::rng::Rng;
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
    /// Weight of the action penalty `action_l2 / N sum |mu(s)|^2` in the actor's loss (0: none).
    pub action_l2: f32,
    /// A residual actor on the frozen starting policy ([`crate::learn::residual`]): this many
    /// residual units beside the base's in every hidden layer (the actor's hidden widths are
    /// `actor_hidden[i] + residual`; `actor_hidden` stays the base's). `None`: the actor is one
    /// network that trains whole (the paper's).
    pub residual: Option<usize>,
}

/// The largest residual width (the evaluator's layers are at most 1024 wide).
pub const MAX_RESIDUAL: usize = 768;

impl DdpgConfig {
    /// The actor's hidden widths: `actor_hidden`, widened by the residual units when on.
    pub fn actor_widths(&self) -> Vec<usize> {
        match self.residual {
            Some(r) => crate::learn::residual::widened(&self.actor_hidden, r),
            None => self.actor_hidden.clone(),
        }
    }

    /// These settings without the residual: the base network a starting policy must match.
    pub fn base(&self) -> DdpgConfig {
        DdpgConfig {
            residual: None,
            ..self.clone()
        }
    }
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
            action_l2: 0.0,
            residual: None,
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
    /// The actor's parameters that never train: a residual actor's base
    /// ([`crate::learn::residual::frozen_ranges`]); empty without a residual.
    pub actor_frozen: Vec<std::ops::Range<usize>>,
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
                &cfg.actor_widths(),
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
        let actor_frozen = match cfg.residual {
            Some(_) => crate::learn::residual::frozen_ranges(&actor, &cfg.actor_hidden)?,
            None => Vec::new(),
        };
        Ok(Networks {
            actor,
            critic,
            obs_dim,
            act_dim,
            actor_frozen,
        })
    }
}

/// Preallocated buffers for one worker's updates.
#[derive(Debug, Clone)]
pub struct UpdateBuffers {
    /// The sampled mini-batch.
    pub batch: Batch,
    pub(crate) actor_s: MlpScratch,
    pub(crate) critic_s: MlpScratch,
    pub(crate) target_actor_s: MlpScratch,
    pub(crate) critic_in: Vec<f32>,
    pub(crate) next_act: Vec<f32>,
    pub(crate) y: Vec<f32>,
    pub(crate) dq: Vec<f32>,
    /// A second row of ratings (IBRL's proposal at the next states).
    pub(crate) q_alt: Vec<f32>,
    q_demo: Vec<f32>,
    dcritic_in: Vec<f32>,
    dact: Vec<f32>,
    /// Critic gradient of the last [`critic_gradient`] / [`critic_regression`] call.
    pub critic_grads: Vec<f32>,
    /// The second (twin) critic's gradient of the last [`critic_regression`] call on it.
    pub critic2_grads: Vec<f32>,
    /// Demonstration rows the cloning term was applied to in the last [`actor_gradient`] call
    /// (after the Q-filter).
    pub bc_rows_used: usize,
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
            next_act: vec![0.0; n * nets.act_dim],
            y: vec![0.0; n],
            dq: vec![0.0; n],
            q_alt: vec![0.0; n],
            q_demo: vec![0.0; n],
            dcritic_in: vec![0.0; n * ci],
            dact: vec![0.0; n * nets.act_dim],
            critic_grads: vec![0.0; nets.critic.num_params()],
            critic2_grads: vec![0.0; nets.critic.num_params()],
            bc_rows_used: 0,
            actor_grads: vec![0.0; nets.actor.num_params()],
        }
    }
}

/// Writes rows `[obs | act]` into `out`.
pub(crate) fn concat(obs: &[f32], act: &[f32], n: usize, od: usize, ad: usize, out: &mut [f32]) {
    for r in 0..n {
        let row = &mut out[r * (od + ad)..(r + 1) * (od + ad)];
        row[..od].copy_from_slice(&obs[r * od..(r + 1) * od]);
        row[od..].copy_from_slice(&act[r * ad..(r + 1) * ad]);
    }
}

/// Critic gradient on `bufs.batch` into `bufs.critic_grads`, for the loss
/// `1/(2N) sum (Q(s,a) - y)^2` with `y = r + gamma (1 - terminal) Q'(s', mu'(s'))`. Returns the loss.
/// (The paper's target: [`critic_targets`] then [`critic_regression`].)
#[allow(clippy::too_many_arguments)]
pub fn critic_gradient(
    nets: &Networks,
    gamma: f32,
    critic: &[f32],
    target_actor: &[f32],
    target_critic: &[f32],
    bufs: &mut UpdateBuffers,
) -> Result<f32, LearnError> {
    critic_targets(
        nets,
        gamma,
        target_actor,
        [target_critic, target_critic],
        None,
        bufs,
    )?;
    critic_regression(nets, critic, CriticSlot::First, bufs)
}

/// Clipped Gaussian noise on the target action (TD3's target policy smoothing).
#[derive(Debug)]
pub struct TargetSmoothing<'a> {
    /// The worker's generator.
    pub rng: &'a mut Rng,
    /// Noise standard deviation.
    pub std: f32,
    /// Clip of the noise.
    pub clip: f32,
}

/// Which critic's gradient buffer a regression fills.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CriticSlot {
    /// `bufs.critic_grads`.
    First,
    /// `bufs.critic2_grads` (the twin).
    Second,
}

/// The regression targets `y = r + gamma * not_done * min_i Q'_i(s', a')` into the buffers, with
/// `a' = mu'(s')`, plus clipped noise and clipped to `[-1, 1]` when smoothing. Pass the same
/// target critic twice for a single critic (the minimum of a value with itself is the value).
pub fn critic_targets(
    nets: &Networks,
    gamma: f32,
    target_actor: &[f32],
    target_critics: [&[f32]; 2],
    smoothing: Option<TargetSmoothing<'_>>,
    bufs: &mut UpdateBuffers,
) -> Result<(), LearnError> {
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
    bufs.next_act[..n * ad].copy_from_slice(&next_act[..n * ad]);
    if let Some(sm) = smoothing {
        for a in &mut bufs.next_act[..n * ad] {
            let e = sm.rng.normal(0.0, sm.std).clamp(-sm.clip, sm.clip);
            *a = (*a + e).clamp(-1.0, 1.0);
        }
    }
    concat(
        &bufs.batch.next_obs,
        &bufs.next_act,
        n,
        od,
        ad,
        &mut bufs.critic_in,
    );
    rate_min(
        nets,
        target_critics,
        &bufs.critic_in[..n * ci],
        &mut bufs.critic_s,
        &mut bufs.dq[..n],
    )?;
    for (((y, &r), &nd), &q) in bufs.y[..n]
        .iter_mut()
        .zip(&bufs.batch.reward)
        .zip(&bufs.batch.not_done)
        .zip(&bufs.dq[..n])
    {
        *y = r + gamma * nd * q;
    }
    Ok(())
}

/// The critics' rating of the rows `[obs | act]` of `input` (one per value of `out`) into `out`:
/// the first critic's, or the smaller of the two when `critics` holds two different parameter
/// sets (pass the same one twice for a single critic).
pub(crate) fn rate_min(
    nets: &Networks,
    critics: [&[f32]; 2],
    input: &[f32],
    scratch: &mut MlpScratch,
    out: &mut [f32],
) -> Result<(), LearnError> {
    let n = out.len();
    out.copy_from_slice(&nets.critic.forward(critics[0], input, n, scratch)?[..n]);
    if !std::ptr::eq(critics[0], critics[1]) {
        let q2 = nets.critic.forward(critics[1], input, n, scratch)?;
        for (q, &q2) in out.iter_mut().zip(q2) {
            *q = q.min(q2);
        }
    }
    Ok(())
}

/// Gradient of `1/(2N) sum (Q(s,a) - y)^2` for one critic, on the targets of the last
/// [`critic_targets`] call, into the slot's gradient buffer. Returns the loss.
pub fn critic_regression(
    nets: &Networks,
    critic: &[f32],
    slot: CriticSlot,
    bufs: &mut UpdateBuffers,
) -> Result<f32, LearnError> {
    let n = bufs.batch.len;
    if n == 0 {
        return Err(LearnError::EmptyReplay);
    }
    let (od, ad) = (nets.obs_dim, nets.act_dim);
    let ci = od + ad;
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
    let grads = match slot {
        CriticSlot::First => &mut bufs.critic_grads,
        CriticSlot::Second => &mut bufs.critic2_grads,
    };
    nets.critic.backward(
        critic,
        &bufs.critic_in[..n * ci],
        &mut bufs.critic_s,
        &bufs.dq[..n],
        Some(grads),
        None,
    )?;
    Ok(loss)
}

/// The actor loss's terms beyond `-Q` (all zero: the paper's loss).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ActorLoss {
    /// Weight of `1/N sum |mu(s)|^2`.
    pub action_l2: f32,
    /// Weight of the cloning term `1/k sum_k |mu(s) - a_demo|^2` on the batch's demonstration rows.
    pub bc_weight: f32,
    /// Only rows where `Q(s, a_demo) > Q(s, mu(s))` count in the cloning term.
    pub q_filter: bool,
    /// The cloning term (and `action_l2`) alone, without `-Q` and without the filter: the
    /// pre-training on demonstrations, while the critic does not yet know anything.
    pub clone_only: bool,
    /// TD3+BC's scale (Fujimoto and Gu 2021): the `-Q` term is multiplied by
    /// `q_normalisation / mean|Q|` of the batch (held constant in the gradient), so the cloning
    /// term keeps its weight whatever the scale of the returns. 0: off (the term as it is).
    pub q_normalisation: f32,
}

/// Actor gradient on `bufs.batch.obs` into `bufs.actor_grads`, for the loss `-1/N sum Q(s, mu(s))`
/// (gradient flows through the critic's action input only) plus the [`ActorLoss`] terms. Returns
/// the mean `Q(s, mu(s))` (0 with `clone_only`).
pub fn actor_gradient(
    nets: &Networks,
    actor: &[f32],
    critic: &[f32],
    loss: &ActorLoss,
    bufs: &mut UpdateBuffers,
) -> Result<f32, LearnError> {
    let n = bufs.batch.len;
    if n == 0 {
        return Err(LearnError::EmptyReplay);
    }
    let (od, ad) = (nets.obs_dim, nets.act_dim);
    let ci = od + ad;
    let k = bufs.batch.demo_rows.min(n);
    let cloning = loss.bc_weight > 0.0 && k > 0;
    let q_filter = loss.q_filter && !loss.clone_only;
    if cloning && q_filter {
        // Q(s, a_demo) on the demonstration rows, for the filter.
        concat(
            &bufs.batch.obs,
            &bufs.batch.bc_target,
            k,
            od,
            ad,
            &mut bufs.critic_in,
        );
        let qd = nets
            .critic
            .forward(critic, &bufs.critic_in[..k * ci], k, &mut bufs.critic_s)?;
        bufs.q_demo[..k].copy_from_slice(&qd[..k]);
    }
    let act = nets
        .actor
        .forward(actor, &bufs.batch.obs, n, &mut bufs.actor_s)?;
    let inv_n = 1.0 / n as f32;
    let mut mean_q = 0.0;
    bufs.bc_rows_used = 0;
    if loss.clone_only {
        bufs.dact[..n * ad].fill(0.0);
        if cloning {
            bufs.y[..k].fill(1.0);
            bufs.bc_rows_used = k;
        }
    } else {
        concat(&bufs.batch.obs, act, n, od, ad, &mut bufs.critic_in);
        let q = nets
            .critic
            .forward(critic, &bufs.critic_in[..n * ci], n, &mut bufs.critic_s)?;
        mean_q = q.iter().sum::<f32>() * inv_n;
        // Which demonstration rows the cloning term applies to (the filter compares with
        // Q(s, mu(s))).
        if cloning {
            for ((flag, &qd), &qp) in bufs.y[..k].iter_mut().zip(&bufs.q_demo[..k]).zip(q) {
                let keep = !q_filter || qd > qp;
                *flag = if keep { 1.0 } else { 0.0 };
                bufs.bc_rows_used += usize::from(keep);
            }
        }
        let lambda = if loss.q_normalisation > 0.0 {
            let mean_abs = q.iter().map(|v| v.abs()).sum::<f32>() * inv_n;
            loss.q_normalisation / mean_abs.max(1e-6)
        } else {
            1.0
        };
        bufs.dq[..n].fill(-inv_n * lambda);
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
    }
    // The actor's outputs are still in its scratch (the critic has its own).
    let mu = nets.actor.output(&bufs.actor_s, n);
    if loss.action_l2 > 0.0 {
        let c = 2.0 * loss.action_l2 * inv_n;
        for (d, &m) in bufs.dact[..n * ad].iter_mut().zip(mu) {
            *d += c * m;
        }
    }
    if cloning {
        let c = 2.0 * loss.bc_weight / k as f32;
        for r in (0..k).filter(|&r| bufs.y[r] > 0.0) {
            let row = r * ad..(r + 1) * ad;
            for ((d, &m), &t) in bufs.dact[row.clone()]
                .iter_mut()
                .zip(&mu[row.clone()])
                .zip(&bufs.batch.bc_target[row])
            {
                *d += c * (m - t);
            }
        }
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
        let q0 =
            actor_gradient(&nets, &actor, &critic, &ActorLoss::default(), &mut bufs).expect("grad");
        assert!(q0.is_finite());
        let grads = bufs.actor_grads.clone();
        for &i in &[0usize, 7, 14, actor.len() - 1] {
            let h = 1e-2f32;
            let mut p = actor.clone();
            p[i] += h;
            let up =
                actor_gradient(&nets, &p, &critic, &ActorLoss::default(), &mut bufs).expect("grad");
            p[i] -= 2.0 * h;
            let down =
                actor_gradient(&nets, &p, &critic, &ActorLoss::default(), &mut bufs).expect("grad");
            let fd = -(up - down) / (2.0 * h);
            assert!(
                (fd - grads[i]).abs() < 2e-3 + 0.05 * fd.abs(),
                "param {i}: fd {fd} vs {}",
                grads[i]
            );
        }
    }

    fn small(batch: usize) -> (Networks, Vec<f32>, Vec<f32>, Vec<f32>, UpdateBuffers, Rng) {
        let cfg = DdpgConfig {
            actor_hidden: vec![5],
            critic_hidden: vec![6],
            final_init: 0.5,
            batch_size: batch,
            ..DdpgConfig::default()
        };
        let nets = Networks::new(&cfg, 3, 2).expect("nets");
        let mut rng = Rng::seed_from_u64(11);
        let actor = nets.actor.init_params(&mut rng, 0.5);
        let critic = nets.critic.init_params(&mut rng, 0.5);
        let critic2 = nets.critic.init_params(&mut rng, 0.5);
        let mut bufs = UpdateBuffers::new(&nets, batch);
        bufs.batch.len = batch;
        for v in bufs
            .batch
            .obs
            .iter_mut()
            .chain(&mut bufs.batch.next_obs)
            .chain(&mut bufs.batch.act)
            .chain(&mut bufs.batch.bc_target)
        {
            *v = rng.uniform(-1.0, 1.0);
        }
        for r in 0..batch {
            bufs.batch.reward[r] = rng.uniform(0.0, 1.0);
            bufs.batch.not_done[r] = if r == 0 { 0.0 } else { 0.9 };
        }
        (nets, actor, critic, critic2, bufs, rng)
    }

    #[test]
    fn twin_targets_take_the_minimum_of_the_two_target_critics() {
        let (nets, actor, c1, c2, mut bufs, _) = small(4);
        let q = |c: &[f32], bufs: &mut UpdateBuffers| {
            critic_targets(&nets, 0.5, &actor, [c, c], None, bufs).expect("targets");
            bufs.y[..4].to_vec()
        };
        let (y1, y2) = (q(&c1, &mut bufs), q(&c2, &mut bufs));
        critic_targets(&nets, 0.5, &actor, [&c1, &c2], None, &mut bufs).expect("targets");
        for r in 0..4 {
            assert_eq!(bufs.y[r], y1[r].min(y2[r]), "row {r}");
        }
        assert!(y1.iter().zip(&y2).any(|(a, b)| a != b), "critics differ");
        // Row 0 is terminal: its target is the reward alone, whatever the critics say.
        assert_eq!(bufs.y[0], bufs.batch.reward[0]);
        // Smoothing moves the targets (the noise reaches the target action) and keeps them finite.
        let mut rng = Rng::seed_from_u64(1);
        let sm = TargetSmoothing {
            rng: &mut rng,
            std: 0.2,
            clip: 0.5,
        };
        critic_targets(&nets, 0.5, &actor, [&c1, &c1], Some(sm), &mut bufs).expect("targets");
        assert!(bufs.y[1..4].iter().zip(&y1[1..]).any(|(a, b)| a != b));
        assert!(bufs.y.iter().all(|v| v.is_finite()));
    }

    #[test]
    fn actor_loss_terms_have_their_gradients() {
        // Loss = -mean Q + action_l2 mean |mu|^2 + bc_weight / k sum_k |mu - a_d|^2 (no filter).
        let (nets, actor, critic, _, mut bufs, _) = small(4);
        bufs.batch.demo_rows = 2;
        let loss = ActorLoss {
            action_l2: 0.3,
            bc_weight: 0.7,
            q_filter: false,
            clone_only: false,
            q_normalisation: 0.0,
        };
        let total = |p: &[f32], bufs: &mut UpdateBuffers| {
            let mean_q = actor_gradient(&nets, p, &critic, &loss, bufs).expect("grad");
            let mut s = nets.actor.scratch(4);
            let mu = nets
                .actor
                .forward(p, &bufs.batch.obs, 4, &mut s)
                .expect("fwd");
            let l2 = mu.iter().map(|m| m * m).sum::<f32>() / 4.0;
            let bc = (0..4)
                .map(|j| (mu[j] - bufs.batch.bc_target[j]).powi(2))
                .sum::<f32>()
                / 2.0;
            -mean_q + loss.action_l2 * l2 + loss.bc_weight * bc
        };
        total(&actor, &mut bufs);
        let grads = bufs.actor_grads.clone();
        assert_eq!(bufs.bc_rows_used, 2);
        for &i in &[0usize, 4, 11, actor.len() - 3, actor.len() - 1] {
            let h = 1e-2f32;
            let mut p = actor.clone();
            p[i] += h;
            let up = total(&p, &mut bufs);
            p[i] -= 2.0 * h;
            let down = total(&p, &mut bufs);
            let fd = (up - down) / (2.0 * h);
            assert!(
                (fd - grads[i]).abs() < 3e-3 + 0.05 * fd.abs(),
                "param {i}: fd {fd} vs {}",
                grads[i]
            );
        }
    }

    #[test]
    fn the_q_filter_keeps_only_rows_where_the_demonstration_is_rated_higher() {
        let (nets, actor, critic, _, mut bufs, _) = small(8);
        bufs.batch.demo_rows = 8;
        let filtered = ActorLoss {
            action_l2: 0.0,
            bc_weight: 1.0,
            q_filter: true,
            clone_only: false,
            q_normalisation: 0.0,
        };
        actor_gradient(&nets, &actor, &critic, &filtered, &mut bufs).expect("grad");
        let kept = bufs.bc_rows_used;
        // Count by hand: Q(s, a_d) > Q(s, mu(s)).
        let mut s = nets.actor.scratch(8);
        let mu = nets
            .actor
            .forward(&actor, &bufs.batch.obs, 8, &mut s)
            .expect("fwd")
            .to_vec();
        let q_of = |acts: &[f32]| {
            let mut input = vec![0.0; 8 * 5];
            concat(&bufs.batch.obs, acts, 8, 3, 2, &mut input);
            let mut cs = nets.critic.scratch(8);
            nets.critic
                .forward(&critic, &input, 8, &mut cs)
                .expect("fwd")
                .to_vec()
        };
        let (qd, qp) = (q_of(&bufs.batch.bc_target), q_of(&mu));
        let want = qd.iter().zip(&qp).filter(|(d, p)| d > p).count();
        assert_eq!(kept, want);
        assert!(
            want > 0 && want < 8,
            "the random critic splits the rows: {want}"
        );
        let unfiltered = ActorLoss {
            q_filter: false,
            ..filtered
        };
        actor_gradient(&nets, &actor, &critic, &unfiltered, &mut bufs).expect("grad");
        assert_eq!(bufs.bc_rows_used, 8);
    }
}
