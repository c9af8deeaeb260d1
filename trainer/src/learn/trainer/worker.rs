//! A worker thread: its local copies of the networks, DDPGfD's pre-training and the loop that
//! steps its environment and updates.

use super::*;

/// A worker's local copies of the networks and its buffers.
pub(super) struct Local {
    pub(super) actor: Vec<f32>,
    pub(super) critic: Vec<f32>,
    pub(super) target_actor: Vec<f32>,
    pub(super) target_critic: Vec<f32>,
    /// Versions of the local actor, critic, target actor, target critic.
    pub(super) versions: [u64; 4],
    /// The twin critic and its target (empty without it) and their versions.
    pub(super) critic2: Vec<f32>,
    pub(super) target_critic2: Vec<f32>,
    pub(super) versions2: [u64; 2],
    pub(super) bufs: UpdateBuffers,
    pub(super) act_scratch: MlpScratch,
    /// The worker's copy of the observation normaliser (refreshed every step when on).
    pub(super) norm: Normalizer,
    /// Int8-grid copies of the actor and target actor (quantisation-aware training).
    pub(super) actor_q: QuantisedCopy,
    pub(super) target_actor_q: QuantisedCopy,
}

impl Local {
    /// A worker's copies of the shared networks as they are now.
    pub(super) fn new(ctx: &Ctx<'_>) -> Result<Self, LearnError> {
        let (cfg, nets) = (ctx.cfg, ctx.nets);
        let a = lock(&ctx.actor)?;
        let c = lock(&ctx.critic)?;
        let (critic2, target_critic2, versions2) = match &ctx.critic2 {
            Some(m) => {
                let c2 = lock(m)?;
                (
                    c2.params.clone(),
                    c2.target.clone(),
                    [c2.version, c2.target_version],
                )
            }
            None => (Vec::new(), Vec::new(), [0, 0]),
        };
        Ok(Local {
            actor: a.params.clone(),
            critic: c.params.clone(),
            target_actor: a.target.clone(),
            target_critic: c.target.clone(),
            versions: [a.version, c.version, a.target_version, c.target_version],
            critic2,
            target_critic2,
            versions2,
            bufs: UpdateBuffers::new(nets, cfg.ddpg.batch_size),
            act_scratch: nets.actor.scratch(1),
            norm: lock(&ctx.obs_stats)?.normalizer(cfg.obs_norm.min_std),
            actor_q: QuantisedCopy::default(),
            target_actor_q: QuantisedCopy::default(),
        })
    }
}

/// DDPGfD's pre-training ([`DemoDataConfig::pretrain_updates`]): updates on demonstration rows
/// alone with worker 0's random stream, until the update counter reaches the setting.
pub(super) fn pretrain(
    ctx: &Ctx<'_>,
    ws: &mut WorkerState,
    on_event: &mut dyn FnMut(Event<'_>),
) -> Result<(), LearnError> {
    let want = ctx.cfg.demos.pretrain_updates;
    if want == 0 || ctx.updates.load(Ordering::Relaxed) >= want {
        return Ok(());
    }
    let mut local = Local::new(ctx)?;
    let mut shown = Instant::now();
    while ctx.updates.load(Ordering::Relaxed) < want {
        if ctx.halted() {
            return Ok(());
        }
        update(ctx, ws, &mut local, Phase::Pretrain)?;
        if shown.elapsed() >= Duration::from_millis(500) {
            on_event(Event::Progress(&ctx.progress()));
            shown = Instant::now();
        }
    }
    Ok(())
}

/// Which kind of update [`update`] does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Phase {
    /// Demonstration rows alone; the actor clones them (see [`DemoDataConfig::pretrain_updates`]).
    Pretrain,
    /// The run's update: replay rows (and demonstration rows where configured).
    Run,
}

pub(super) fn worker_loop<E: Env>(
    ctx: &Ctx<'_>,
    id: usize,
    ws: &mut WorkerState,
    make_env: &(impl Fn(usize) -> E + Sync),
    tx: &mpsc::Sender<EvalRecord>,
) -> Result<(), LearnError> {
    let cfg = ctx.cfg;
    let nets = ctx.nets;
    let mut env = make_env(id);
    let (od, ad) = (nets.obs_dim, nets.act_dim);
    if env.obs_dim() != od || env.act_dim() != ad {
        return Err(LearnError::EnvMismatch {
            expected: (od, ad),
            got: (env.obs_dim(), env.act_dim()),
        });
    }
    let mut local = Local::new(ctx)?;
    let mut obs = vec![0.0f32; od];
    let mut next_obs = vec![0.0f32; od];
    let mut action = vec![0.0f32; ad];
    let mut label = vec![0.0f32; ad];
    let mut obs_n = vec![0.0f32; od];
    let mut eval_scratch = nets.actor.scratch(1);
    let mut proposal_scratch = crate::learn::ibrl::ProposalScratch::new(nets);
    let norm_on = cfg.obs_norm.enabled;
    let norm_moves = norm_on && !cfg.obs_norm.frozen();
    let observe = |x: &[f32], norm: &mut Normalizer| -> Result<(), LearnError> {
        if norm_moves {
            let mut st = lock(&ctx.obs_stats)?;
            st.push(x);
            st.write_normalizer(cfg.obs_norm.min_std, norm);
        }
        Ok(())
    };
    let mut noise = ExplorationNoise::new(&cfg.noise, ad);
    let mut pending = NStepQueue::new(cfg.n_step, cfg.ddpg.gamma, od, ad);
    env.reset(&mut ws.rng, &mut obs);
    noise.reset(&mut ws.rng);
    observe(&obs, &mut local.norm)?;
    let mut ep_steps = 0usize;
    let mut ep_return = 0.0f64;
    loop {
        if ctx.halted() {
            return Ok(());
        }
        obs_n.copy_from_slice(&obs);
        if norm_on {
            local.norm.apply_rows(&mut obs_n);
        }
        // The actor as the worker uses it: its int8-grid version once quantisation-aware.
        let params = local.actor_q.select(
            ctx.quantisation_aware(),
            &nets.actor,
            &local.actor,
            local.versions[0],
        )?;
        let mean = nets
            .actor
            .forward(params, &obs_n, 1, &mut local.act_scratch)?;
        noise.perturb(&mut ws.rng, mean, &mut action);
        if let Some(proposal) = ctx.proposal {
            let second = if ctx.critic2.is_some() {
                &local.critic2
            } else {
                &local.critic
            };
            let chosen = crate::learn::ibrl::choose(
                nets,
                proposal,
                [&local.critic, second],
                &obs_n,
                &mut action,
                &mut proposal_scratch,
            )?;
            if chosen == crate::learn::ibrl::Chosen::Proposal {
                ctx.proposal_chosen.fetch_add(1, Ordering::Relaxed);
            }
            ctx.proposal_steps.fetch_add(1, Ordering::Relaxed);
        }
        if cfg.teacher_labels && !env.expert_action(&mut label) {
            return Err(LearnError::Worker(
                "teacher_labels: the environment has no teacher",
            ));
        }
        let step = env.step(&action, &mut next_obs);
        observe(&next_obs, &mut local.norm)?;
        ep_steps += 1;
        ep_return += f64::from(step.reward);
        let cut = cfg.train_episode_steps.is_some_and(|n| ep_steps >= n);
        let done = step.done() || cut;
        let mut guard = None;
        let replay = match (&ctx.replay, &mut ws.replay) {
            (Some(m), _) => &mut **guard.insert(lock(m)?),
            (None, Some(r)) => r,
            (None, None) => return Err(LearnError::Worker("no replay buffer")),
        };
        // With teacher labels n_step is 1, so the row pushed is this step's (`label` is its).
        pending.push(&obs, &action, step.reward, step.terminal, done, |t| {
            replay.push_labelled(t.obs, t.act, t.reward, &next_obs, t.not_done, &label);
        });
        let stored = replay.len();
        drop(guard);
        ws.transitions += 1;
        ctx.per_worker[id].store(ws.transitions, Ordering::Relaxed);
        ctx.transitions.fetch_add(1, Ordering::Relaxed);
        std::mem::swap(&mut obs, &mut next_obs);
        if stored >= cfg.learning_starts.max(1) {
            for _ in 0..cfg.updates_per_step {
                update(ctx, ws, &mut local, Phase::Run)?;
            }
        }
        if done {
            let n = ctx.episodes.fetch_add(1, Ordering::Relaxed) + 1;
            {
                let mut r = lock(&ctx.returns)?;
                r.0 += ep_return;
                r.1 += 1;
            }
            let every = cfg.eval.every_episodes;
            if every > 0 && n.is_multiple_of(every) {
                let index = n / every;
                let stream = if cfg.eval.fixed_starts { 0 } else { index };
                let mut rng = Rng::derive(cfg.seed, STREAM_EVAL + stream);
                let params = local.actor_q.select(
                    ctx.quantisation_aware(),
                    &nets.actor,
                    &local.actor,
                    local.versions[0],
                )?;
                let (mean_return, success_rate) = evaluate(
                    &nets.actor,
                    params,
                    &mut env,
                    &cfg.eval,
                    &mut rng,
                    &mut eval_scratch,
                    norm_on.then_some(&local.norm),
                )?;
                let train_return = {
                    let mut r = lock(&ctx.returns)?;
                    let m = r.0 / r.1.max(1) as f64;
                    *r = (0.0, 0);
                    m
                };
                let proposal_share = ctx.proposal.map(|_| {
                    let chosen = ctx.proposal_chosen.swap(0, Ordering::Relaxed);
                    let steps = ctx.proposal_steps.swap(0, Ordering::Relaxed);
                    chosen as f64 / steps.max(1) as f64
                });
                ctx.evals.fetch_max(index, Ordering::Relaxed);
                let p = ctx.progress();
                // The receiver only goes away when the run is over; nothing to do then.
                let _ = tx.send(EvalRecord {
                    eval_index: index,
                    episodes: n,
                    transitions: p.transitions,
                    transitions_per_worker: p.transitions_per_worker,
                    updates: p.updates,
                    wall_s: p.wall_s,
                    mean_return,
                    success_rate,
                    train_return,
                    worker: id,
                    proposal_share,
                });
            }
            if ctx.transitions.load(Ordering::Relaxed) >= ctx.until {
                return Ok(());
            }
            env.reset(&mut ws.rng, &mut obs);
            noise.reset(&mut ws.rng);
            observe(&obs, &mut local.norm)?;
            ep_steps = 0;
            ep_return = 0.0;
        }
    }
}
