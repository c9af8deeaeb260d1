//! The starting policy as a proposal (IBRL, Hu et al. 2023, "Imitation Bootstrapped
//! Reinforcement Learning"; beyond the paper, off by default: [`RunConfig::ibrl`]).
//!
//! A fine-tune that moves the clone it starts from can lose what the clone solved (docs/
//! experiments.md, sessions 14-20: the RL stage's outcome is a lottery over seeds). Here the clone
//! stays in the loop, frozen, beside the actor that trains:
//! - **acting**: the worker proposes the actor's action with its exploration noise and the
//!   clone's action without noise, and executes whichever the critic rates higher
//!   ([`choose`]; with twin critics, the smaller of the two ratings);
//! - **bootstrapping**: the regression target takes the better of the two proposals at the next
//!   state, `y = r + gamma * not_done * max(Q'(s', mu'(s')), Q'(s', mu_clone(s')))`
//!   ([`bootstrap_with_proposal`]), so the critic values a state by what the pair can do from it
//!   and never below what the clone does there.
//!
//! The actor's own update is unchanged (the critic's gradient plus the cloning term where
//! configured). What a run exports is the actor alone: a single MLP the runtime can run.
//!
//! [`RunConfig::ibrl`]: crate::learn::RunConfig::ibrl

use super::LearnError;
use super::ddpg::{Networks, UpdateBuffers, concat, rate_min};
use super::nets::MlpScratch;

/// The buffers [`choose`] needs for one observation: the proposal's forward pass and the critic's
/// two rows (the actor's action and the proposal's).
#[derive(Debug, Clone)]
pub struct ProposalScratch {
    actor: MlpScratch,
    critic: MlpScratch,
    critic_in: Vec<f32>,
}

impl ProposalScratch {
    /// Buffers for the networks' shapes.
    pub fn new(nets: &Networks) -> Self {
        ProposalScratch {
            actor: nets.actor.scratch(1),
            critic: nets.critic.scratch(2),
            critic_in: vec![0.0; 2 * (nets.obs_dim + nets.act_dim)],
        }
    }
}

/// Which action [`choose`] kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Chosen {
    /// The actor's (noisy) action.
    Actor,
    /// The frozen proposal's action, now in `action`.
    Proposal,
}

/// Rates `action` (the actor's, with its exploration noise) and the proposal's action at `obs`
/// (the observation as the actor takes it) by the critics (`critics[1]` may be `critics[0]`: a
/// single critic) and leaves the better one in `action`; ties keep the actor's.
pub fn choose(
    nets: &Networks,
    proposal: &[f32],
    critics: [&[f32]; 2],
    obs: &[f32],
    action: &mut [f32],
    scratch: &mut ProposalScratch,
) -> Result<Chosen, LearnError> {
    let (od, ad) = (nets.obs_dim, nets.act_dim);
    if obs.len() != od || action.len() != ad {
        return Err(LearnError::Shape {
            what: "proposal observation and action",
            expected: od + ad,
            got: obs.len() + action.len(),
        });
    }
    let proposed = nets.actor.forward(proposal, obs, 1, &mut scratch.actor)?;
    // Rows [obs | action] and [obs | proposed], written in place (this runs every step).
    let ci = od + ad;
    let rows = &mut scratch.critic_in;
    rows[..od].copy_from_slice(obs);
    rows[od..ci].copy_from_slice(action);
    rows[ci..ci + od].copy_from_slice(obs);
    rows[ci + od..2 * ci].copy_from_slice(&proposed[..ad]);
    let mut q = [0.0f32; 2];
    rate_min(
        nets,
        critics,
        &scratch.critic_in,
        &mut scratch.critic,
        &mut q,
    )?;
    if q[1] > q[0] {
        action.copy_from_slice(&scratch.critic_in[ci + od..2 * ci]);
        Ok(Chosen::Proposal)
    } else {
        Ok(Chosen::Actor)
    }
}

/// After [`super::ddpg::critic_targets`] (which left the actor's bootstrap values in the
/// buffers), raises each row's target to the proposal's where the target critics rate the
/// proposal's action at the next state higher: `y = r + gamma * not_done * max(q_actor,
/// q_proposal)`.
pub fn bootstrap_with_proposal(
    nets: &Networks,
    gamma: f32,
    proposal: &[f32],
    target_critics: [&[f32]; 2],
    bufs: &mut UpdateBuffers,
) -> Result<(), LearnError> {
    let n = bufs.batch.len;
    if n == 0 {
        return Err(LearnError::EmptyReplay);
    }
    let (od, ad) = (nets.obs_dim, nets.act_dim);
    let next = nets.actor.forward(
        proposal,
        &bufs.batch.next_obs[..n * od],
        n,
        &mut bufs.target_actor_s,
    )?;
    bufs.next_act[..n * ad].copy_from_slice(&next[..n * ad]);
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
        &bufs.critic_in[..n * (od + ad)],
        &mut bufs.critic_s,
        &mut bufs.q_alt[..n],
    )?;
    for i in 0..n {
        let best = bufs.dq[i].max(bufs.q_alt[i]);
        bufs.dq[i] = best;
        bufs.y[i] = bufs.batch.reward[i] + gamma * bufs.batch.not_done[i] * best;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::learn::ddpg::{DdpgConfig, critic_targets};
    use crate::learn::rng::Rng;

    fn nets() -> Networks {
        let cfg = DdpgConfig {
            actor_hidden: vec![8],
            critic_hidden: vec![8],
            critic_layer_norm: false,
            ..DdpgConfig::default()
        };
        Networks::new(&cfg, 3, 2).expect("networks")
    }

    /// A critic whose output is `w . a + 10` (the action part of its input through one unit that
    /// stays positive): its rating of two actions is known in advance.
    fn linear_critic(nets: &Networks, w: [f32; 2]) -> Vec<f32> {
        let mut p = vec![0.0f32; nets.critic.num_params()];
        let spans: Vec<_> = nets.critic.weight_spans().collect();
        let (first, fan_in, fan_out) = spans[0];
        // Inputs 3 and 4 are the action's; unit 0 of the hidden layer.
        p[first + 3 * fan_out] = w[0];
        p[first + 4 * fan_out] = w[1];
        p[first + fan_in * fan_out] = 10.0;
        let (last, _, _) = spans[spans.len() - 1];
        p[last] = 1.0;
        p
    }

    #[test]
    fn the_better_rated_action_is_executed() {
        let nets = nets();
        let mut rng = Rng::derive(3, 0);
        let proposal = nets.actor.init_params(&mut rng, 3e-3);
        let obs = [0.1, -0.2, 0.3];
        let mut s = ProposalScratch::new(&nets);
        let proposed = nets
            .actor
            .forward(&proposal, &obs, 1, &mut nets.actor.scratch(1))
            .expect("forward")
            .to_vec();
        // A critic that prefers large first components: an actor action of +1 wins.
        let critic = linear_critic(&nets, [1.0, 0.0]);
        let mut action = [1.0, 0.0];
        let c = choose(
            &nets,
            &proposal,
            [&critic, &critic],
            &obs,
            &mut action,
            &mut s,
        )
        .expect("choose");
        assert_eq!((c, action), (Chosen::Actor, [1.0, 0.0]));
        // The same action against a critic that prefers small first components: the proposal
        // (a small-initialised network's output, near 0) wins and replaces it.
        let critic = linear_critic(&nets, [-1.0, 0.0]);
        let c = choose(
            &nets,
            &proposal,
            [&critic, &critic],
            &obs,
            &mut action,
            &mut s,
        )
        .expect("choose");
        assert_eq!(c, Chosen::Proposal);
        assert_eq!(action.to_vec(), proposed);
        // Twin critics rate by the smaller: one that prefers +1 and one that prefers -1 rate the
        // actor's +1 at their minimum, below the proposal near 0.
        let (up, down) = (
            linear_critic(&nets, [1.0, 0.0]),
            linear_critic(&nets, [-1.0, 0.0]),
        );
        let mut action = [1.0, 0.0];
        let c = choose(&nets, &proposal, [&up, &down], &obs, &mut action, &mut s).expect("choose");
        assert_eq!(c, Chosen::Proposal);
    }

    #[test]
    fn the_target_takes_the_larger_bootstrap_and_never_lowers_it() {
        let nets = nets();
        let mut rng = Rng::derive(5, 0);
        let actor = nets.actor.init_params(&mut rng, 3e-3);
        let proposal = nets.actor.init_params(&mut rng, 3e-1);
        let critic = nets.critic.init_params(&mut rng, 3e-1);
        let n = 16;
        let mut bufs = UpdateBuffers::new(&nets, n);
        bufs.batch.len = n;
        for i in 0..n {
            for j in 0..3 {
                bufs.batch.next_obs[i * 3 + j] = rng.normal(0.0, 1.0);
            }
            bufs.batch.reward[i] = i as f32 * 0.1;
            bufs.batch.not_done[i] = if i % 4 == 0 { 0.0 } else { 1.0 };
        }
        critic_targets(&nets, 0.9, &actor, [&critic, &critic], None, &mut bufs).expect("targets");
        let plain = bufs.y[..n].to_vec();
        bootstrap_with_proposal(&nets, 0.9, &proposal, [&critic, &critic], &mut bufs)
            .expect("proposal");
        // By hand: the proposal's value at each next state.
        let next = nets
            .actor
            .forward(
                &proposal,
                &bufs.batch.next_obs[..n * 3],
                n,
                &mut nets.actor.scratch(n),
            )
            .expect("forward")
            .to_vec();
        let mut raised = 0;
        for i in 0..n {
            let mut row = bufs.batch.next_obs[i * 3..i * 3 + 3].to_vec();
            row.extend_from_slice(&next[i * 2..i * 2 + 2]);
            let qp = nets
                .critic
                .forward(&critic, &row, 1, &mut nets.critic.scratch(1))
                .expect("forward")[0];
            let nd = bufs.batch.not_done[i];
            let r = bufs.batch.reward[i];
            let q_actor = if nd > 0.0 {
                (plain[i] - r) / (0.9 * nd)
            } else {
                0.0
            };
            let want = r + 0.9 * nd * q_actor.max(qp);
            assert!((bufs.y[i] - want).abs() < 1e-4, "row {i}");
            assert!(bufs.y[i] >= plain[i] - 1e-6, "row {i} lowered");
            if bufs.y[i] > plain[i] + 1e-6 {
                raised += 1;
            }
        }
        // Terminal rows keep their reward; some others are raised by the proposal.
        assert!(raised > 0);
        for i in (0..n).step_by(4) {
            assert_eq!(bufs.y[i], bufs.batch.reward[i]);
        }
    }
}
