//! One DDPG update on the shared parameters (steps 1-6 of the module docs of [`super`]).

use super::*;

/// One DDPG update on shared parameters (steps 1-6 of the module docs), with the TD3 pieces and
/// the demonstration rows where configured.
pub(super) fn update(
    ctx: &Ctx<'_>,
    ws: &mut WorkerState,
    local: &mut Local,
    phase: Phase,
) -> Result<(), LearnError> {
    let cfg = ctx.cfg;
    let nets = ctx.nets;
    let n = cfg.ddpg.batch_size;
    let pretraining = phase == Phase::Pretrain;
    let k = match ctx.demos {
        Some(d) if pretraining => {
            d.sample_into(&mut ws.rng, n, &mut local.bufs.batch);
            local.bufs.batch.len = n;
            n
        }
        Some(d) if cfg.demos.uses_demos() => {
            let k = cfg.demos.rows(n);
            d.sample_into(&mut ws.rng, k, &mut local.bufs.batch);
            k
        }
        None if pretraining => {
            return Err(LearnError::Worker("pre-training without demonstrations"));
        }
        _ => {
            local.bufs.batch.demo_rows = 0;
            0
        }
    };
    if !pretraining {
        match (&ctx.replay, &ws.replay) {
            (Some(m), _) => lock(m)?.sample_after(&mut ws.rng, k, n - k, &mut local.bufs.batch),
            (None, Some(r)) => r.sample_after(&mut ws.rng, k, n - k, &mut local.bufs.batch),
            (None, None) => return Err(LearnError::Worker("no replay buffer")),
        }
    }
    if cfg.obs_norm.enabled {
        let rows = local.bufs.batch.len * nets.obs_dim;
        local.norm.apply_rows(&mut local.bufs.batch.obs[..rows]);
        local
            .norm
            .apply_rows(&mut local.bufs.batch.next_obs[..rows]);
    }
    let [
        seen_actor,
        seen_critic,
        seen_target_actor,
        seen_target_critic,
    ] = &mut local.versions;
    lock(&ctx.actor)?.refresh_into(
        (&mut local.actor, seen_actor),
        (&mut local.target_actor, seen_target_actor),
    );
    lock(&ctx.critic)?.refresh_into(
        (&mut local.critic, seen_critic),
        (&mut local.target_critic, seen_target_critic),
    );
    if let Some(m) = &ctx.critic2 {
        let [seen, seen_target] = &mut local.versions2;
        lock(m)?.refresh_into(
            (&mut local.critic2, seen),
            (&mut local.target_critic2, seen_target),
        );
    }
    // Quantisation-aware: the target actor and the actor are used with int8-grid weights; the
    // actor's gradient (taken at the quantised weights) updates the f32 weights (straight-through).
    let aware = ctx.quantisation_aware();
    let target_actor =
        local
            .target_actor_q
            .select(aware, &nets.actor, &local.target_actor, local.versions[2])?;
    let td3 = cfg.td3;
    let twin = ctx.critic2.is_some();
    let smoothing = (td3.target_noise > 0.0).then_some(TargetSmoothing {
        rng: &mut ws.rng,
        std: td3.target_noise,
        clip: td3.target_noise_clip,
    });
    let second_target: &[f32] = if twin {
        &local.target_critic2
    } else {
        &local.target_critic
    };
    critic_targets(
        nets,
        cfg.ddpg.gamma,
        target_actor,
        [&local.target_critic, second_target],
        smoothing,
        &mut local.bufs,
    )?;
    if let Some(proposal) = ctx.proposal {
        crate::learn::ibrl::bootstrap_with_proposal(
            nets,
            cfg.ddpg.gamma,
            proposal,
            [&local.target_critic, second_target],
            &mut local.bufs,
        )?;
    }
    critic_regression(nets, &local.critic, CriticSlot::First, &mut local.bufs)?;
    if twin {
        critic_regression(nets, &local.critic2, CriticSlot::Second, &mut local.bufs)?;
    }
    {
        let mut guard = lock(&ctx.critic)?;
        let c = &mut *guard;
        adam_step(
            &cfg.critic_adam,
            &mut c.params,
            &local.bufs.critic_grads,
            &mut ws.critic_m,
            &mut c.adam,
        );
        c.version += 1;
        local.critic.copy_from_slice(&c.params);
        local.versions[1] = c.version;
    }
    if let Some(m) = &ctx.critic2 {
        let mut guard = lock(m)?;
        let c = &mut *guard;
        adam_step(
            &cfg.critic_adam,
            &mut c.params,
            &local.bufs.critic2_grads,
            &mut ws.critic2_m,
            &mut c.adam,
        );
        c.version += 1;
        local.critic2.copy_from_slice(&c.params);
        local.versions2[0] = c.version;
    }
    let u = ctx.updates.fetch_add(1, Ordering::Relaxed) + 1;
    let t = cfg.ddpg.target;
    if !pretraining && u <= cfg.demos.pretrain_updates + cfg.critic_warmup_updates {
        // Critic warm-up: the actor stays as it started; the critic's target follows the critic.
        return move_critic_targets(ctx, t, u);
    }
    if !pretraining && !td3.actor_due(u) {
        return Ok(());
    }
    let actor = local
        .actor_q
        .select(aware, &nets.actor, &local.actor, local.versions[0])?;
    let loss = if pretraining {
        ActorLoss {
            action_l2: cfg.ddpg.action_l2,
            bc_weight: 1.0,
            q_filter: false,
            clone_only: true,
            q_normalisation: 0.0,
        }
    } else {
        ActorLoss {
            action_l2: cfg.ddpg.action_l2,
            bc_weight: cfg.demos.bc_weight,
            q_filter: cfg.demos.q_filter,
            clone_only: false,
            q_normalisation: cfg.demos.q_normalisation,
        }
    };
    actor_gradient(nets, actor, &local.critic, &loss, &mut local.bufs)?;
    // A residual actor's base and zero blocks stay as they are; only the residual trains.
    crate::learn::residual::zero_frozen(&nets.actor_frozen, &mut local.bufs.actor_grads)?;
    // Pre-training is cloning: it may take its own learning rate (the fine-tuning's is lower).
    let pretrain_adam;
    let actor_adam = match cfg.demos.pretrain_actor_lr {
        Some(lr) if pretraining => {
            pretrain_adam = AdamConfig {
                lr,
                ..cfg.actor_adam
            };
            &pretrain_adam
        }
        _ => &cfg.actor_adam,
    };
    {
        let mut guard = lock(&ctx.actor)?;
        let a = &mut *guard;
        adam_step(
            actor_adam,
            &mut a.params,
            &local.bufs.actor_grads,
            &mut ws.actor_m,
            &mut a.adam,
        );
        a.version += 1;
        if t.apply(u, &a.params, &mut a.target) {
            a.target_version += 1;
        }
        local.actor.copy_from_slice(&a.params);
        local.versions[0] = a.version;
    }
    move_critic_targets(ctx, t, u)
}

/// Moves the critics' targets (both, with TD3's twin) when `t` says so after update `u`.
fn move_critic_targets(
    ctx: &Ctx<'_>,
    t: crate::learn::ddpg::TargetUpdate,
    u: u64,
) -> Result<(), LearnError> {
    for m in std::iter::once(&ctx.critic).chain(ctx.critic2.as_ref()) {
        let mut guard = lock(m)?;
        let c = &mut *guard;
        if t.apply(u, &c.params, &mut c.target) {
            c.target_version += 1;
        }
    }
    Ok(())
}
