//! DPG-R and ADPG-R: W worker threads (W = 1 is DPG-R), each with its own environment and generator,
//! sharing the actor, the critic, their targets and Adam's second moment.
//!
//! # Sharing design
//! Each network's shared half (parameters, target, Adam second moment, version counters) sits in its own
//! mutex, one for the actor and one for the critic; the update count is an atomic. A worker keeps a local
//! copy of every network and, per update:
//! 1. samples a mini-batch (from its own replay, or from the shared one under its own lock);
//! 2. under each network's lock, refreshes whichever local copies are stale (version counters avoid
//!    needless copies; with one worker nothing is copied here);
//! 3. computes the critic gradient without a lock;
//! 4. under the critic's lock, applies Adam (its own first moment, the shared second moment) to the
//!    shared critic and copies the result back;
//! 5. computes the actor gradient through the updated critic without a lock;
//! 6. under the actor's lock, applies Adam to the shared actor, counts the update, moves the actor's
//!    target when due and copies the actor back; then under the critic's lock moves the critic's target.
//!
//! The expensive part (the gradients) runs in parallel; the locked parts are an Adam step and memcpy
//! (about a tenth of an update at batch 64 for 256-wide networks), and one worker's actor step can
//! overlap another's critic step. Gradients are therefore computed on
//! parameters at most a few updates old, which is the asynchrony of the paper. With W = 1 the
//! sequence is exactly sequential DDPG and a fixed seed gives bit-identical results.
//!
//! Evaluation follows the paper: after every `eval.every_episodes` training episodes (counted over all
//! workers), the worker that finished that episode runs `eval.episodes` noise-free episodes with its
//! current copy of the actor on its own environment, with a generator derived from the seed and the
//! evaluation index. A [`Trainer::run`] call stops at the first episode end after the transition budget
//! is reached, so running in chunks (with checkpoints in between) continues exactly like one long run.

use super::LearnError;
use super::adam::{AdamConfig, AdamLocal, AdamShared, adam_step};
use super::ddpg::{
    ActorLoss, CriticSlot, DdpgConfig, Networks, TargetSmoothing, UpdateBuffers, actor_gradient,
    critic_regression, critic_targets,
};
use super::demo_data::{DemoBuffer, DemoDataConfig};
use super::env::Env;
use super::n_step::NStepQueue;
use super::nets::{Mlp, MlpScratch};
use super::noise::ExplorationNoise;
pub use super::noise::NoiseConfig;
use super::norm::{Normalizer, ObsNormConfig, ObsStats};
use super::quantise::{QuantiseConfig, QuantisedCopy, fake_quantise};
use super::replay::Replay;
use super::rng::Rng;
use super::td3::Td3Config;
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard, mpsc};
use std::time::{Duration, Instant};

mod config;
mod evaluation;
mod events;
mod shared;
mod state;
mod update;
mod worker;

pub use config::{EvalConfig, ReplayConfig, RunConfig};
use evaluation::evaluate;
pub use evaluation::evaluate_actor;
pub use events::{EvalRecord, Event, Progress, RunSummary};
use shared::{Ctx, lock, poisoned};
pub(crate) use shared::{NetShared, RankSync, SharedNets};
pub(crate) use state::{Counters, SharedState, WorkerState};
use update::update;
use worker::{Local, Phase, pretrain, worker_loop};

/// Stream of [`Rng::derive`] for initial parameters.
const STREAM_INIT: u64 = 0;
/// Streams of worker generators start here.
const STREAM_WORKER: u64 = 1 << 20;
/// Streams of evaluation generators start here.
const STREAM_EVAL: u64 = 1 << 40;

/// A DPG-R / ADPG-R training run: configuration, networks, shared and per-worker state.
#[derive(Debug, Clone)]
pub struct Trainer {
    pub(crate) cfg: RunConfig,
    pub(crate) nets: Networks,
    pub(crate) shared: SharedState,
    pub(crate) shared_replay: Option<Replay>,
    pub(crate) workers: Vec<WorkerState>,
    pub(crate) counters: Counters,
    /// Demonstration transitions (not in checkpoints: given again on resume).
    pub(crate) demos: Option<DemoBuffer>,
    /// The frozen proposal actor of [`RunConfig::ibrl`] (not in checkpoints: given again on
    /// resume).
    pub(crate) proposal: Option<Vec<f32>>,
}

impl Trainer {
    /// A fresh run for an environment with the given dimensions.
    pub fn new(cfg: RunConfig, obs_dim: usize, act_dim: usize) -> Result<Self, LearnError> {
        cfg.validate()?;
        cfg.noise.validate(Some(act_dim))?;
        let nets = Networks::new(&cfg.ddpg, obs_dim, act_dim)?;
        let mut rng = Rng::derive(cfg.seed, STREAM_INIT);
        let actor = nets.actor.init_params(&mut rng, cfg.ddpg.final_init);
        let critic = nets.critic.init_params(&mut rng, cfg.ddpg.final_init);
        // Drawn after the first two so a run without the twin starts exactly as before.
        let critic2 = if cfg.td3.twin_critics {
            nets.critic.init_params(&mut rng, cfg.ddpg.final_init)
        } else {
            Vec::new()
        };
        let shared = SharedState {
            target_actor: actor.clone(),
            target_critic: critic.clone(),
            actor_adam: AdamShared::new(actor.len()),
            critic_adam: AdamShared::new(critic.len()),
            target_critic2: critic2.clone(),
            critic2_adam: AdamShared::new(critic2.len()),
            critic2,
            actor,
            critic,
            obs_stats: ObsStats::new(obs_dim),
            ..SharedState::default()
        };
        let w = cfg.workers;
        let labelled = |r: Replay| {
            if cfg.teacher_labels {
                r.with_labels()
            } else {
                r
            }
        };
        let shared_replay = cfg
            .replay
            .shared
            .then(|| labelled(Replay::new(cfg.replay.capacity, obs_dim, act_dim)));
        let workers = (0..w)
            .map(|i| WorkerState {
                rng: Rng::derive(cfg.seed, STREAM_WORKER + i as u64),
                actor_m: AdamLocal::new(nets.actor.num_params()),
                critic_m: AdamLocal::new(nets.critic.num_params()),
                critic2_m: AdamLocal::new(if cfg.td3.twin_critics {
                    nets.critic.num_params()
                } else {
                    0
                }),
                replay: (!cfg.replay.shared)
                    .then(|| labelled(Replay::new(cfg.replay.capacity / w, obs_dim, act_dim))),
                transitions: 0,
            })
            .collect();
        Ok(Trainer {
            cfg,
            nets,
            shared,
            shared_replay,
            workers,
            counters: Counters::default(),
            demos: None,
            proposal: None,
        })
    }

    /// Gives the run its demonstration transitions (needed when `demos.fraction > 0`; again after
    /// loading a checkpoint, which does not hold them). Fails when the sizes differ.
    pub fn set_demonstrations(&mut self, demos: DemoBuffer) -> Result<(), LearnError> {
        let want = (self.nets.obs_dim, self.nets.act_dim);
        if demos.dims() != want {
            return Err(LearnError::EnvMismatch {
                expected: want,
                got: demos.dims(),
            });
        }
        // Frozen statistics are measured once, on a fresh run (a checkpoint keeps them).
        if self.cfg.obs_norm.frozen_from_demos && self.shared.obs_stats.count == 0 {
            let od = self.nets.obs_dim;
            for row in demos.observations().chunks_exact(od) {
                self.shared.obs_stats.push(row);
            }
        }
        self.demos = Some(demos);
        Ok(())
    }

    /// Starts a fresh run's actor and its target from `params` (e.g. an exported clone read by
    /// `crate::files::policy_import`); the critic keeps its fresh initialisation. Fails once the run has
    /// stepped or updated, and when `params` does not fit the actor. With a residual
    /// (`ddpg.residual`), `params` is the base (`ddpg.actor_hidden`'s shape) and the actor
    /// becomes it plus the residual's units, whose head starts at zero
    /// ([`crate::learn::residual::compose`]).
    pub fn set_initial_actor(&mut self, params: Vec<f32>) -> Result<(), LearnError> {
        let p = self.progress();
        if p.transitions > 0 || p.updates > 0 {
            return Err(LearnError::Config {
                field: "init_policy",
                why: "an initial actor is given to a fresh run only",
            });
        }
        let params = match self.cfg.ddpg.residual {
            // The policy given is the base: the residual's units and head join it.
            Some(_) => crate::learn::residual::compose(
                &self.nets.actor,
                &self.cfg.ddpg.actor_hidden,
                &params,
                &self.shared.actor,
            )?,
            None => params,
        };
        self.nets.actor.layers(&params)?;
        self.shared.target_actor.clone_from(&params);
        self.shared.actor = params;
        Ok(())
    }

    /// [`Trainer::set_initial_actor`] for an actor that takes normalised observations
    /// `(x - mean) * inv_std` (a policy file's own normalisation, not folded): the run's frozen
    /// normaliser becomes that one. Needs `obs_norm.frozen_from_init`; every `inv_std` must be
    /// positive and at most `1 / obs_norm.min_std` (the normaliser's floor would change it).
    pub fn set_initial_actor_normalised(
        &mut self,
        params: Vec<f32>,
        mean: &[f32],
        inv_std: &[f32],
    ) -> Result<(), LearnError> {
        let bad = |why| {
            Err(LearnError::Config {
                field: "obs_norm.frozen_from_init",
                why,
            })
        };
        if !self.cfg.obs_norm.frozen_from_init {
            return bad("a normalised initial actor needs obs_norm.frozen_from_init");
        }
        let od = self.nets.obs_dim;
        if mean.len() != od || inv_std.len() != od {
            return Err(LearnError::Shape {
                what: "initial normalisation",
                expected: od,
                got: mean.len().min(inv_std.len()),
            });
        }
        let floor = self.cfg.obs_norm.min_std;
        if inv_std
            .iter()
            .any(|&k| !(k > 0.0 && k.is_finite() && 1.0 / k >= floor))
        {
            return bad(
                "an inv_std of the initial policy is not positive or is above 1 / obs_norm.min_std",
            );
        }
        self.set_initial_actor(params)?;
        // One pseudo-observation whose statistics give exactly this mean and standard deviation.
        let stats = &mut self.shared.obs_stats;
        stats.count = 1;
        for (i, (&m, &k)) in mean.iter().zip(inv_std).enumerate() {
            stats.mean[i] = f64::from(m);
            let std = 1.0 / f64::from(k);
            stats.m2[i] = std * std;
        }
        Ok(())
    }

    /// Gives an [`RunConfig::ibrl`] run its frozen proposal: the starting policy's parameters
    /// in the actor's shape and input (the run's `init_policy`, as [`Trainer::set_initial_actor`]
    /// or [`Trainer::set_initial_actor_normalised`] took it). Needed again after loading a
    /// checkpoint, which does not hold it. Fails without `ibrl` or when the shape differs.
    pub fn set_proposal(&mut self, params: Vec<f32>) -> Result<(), LearnError> {
        if !self.cfg.ibrl {
            return Err(LearnError::Config {
                field: "ibrl",
                why: "a proposal is given to a run with ibrl = true only",
            });
        }
        self.nets.actor.layers(&params)?;
        self.proposal = Some(params);
        Ok(())
    }

    /// The demonstration transitions given to the run, if any.
    pub fn demonstrations(&self) -> Option<&DemoBuffer> {
        self.demos.as_ref()
    }

    /// The run's configuration.
    pub fn config(&self) -> &RunConfig {
        &self.cfg
    }

    /// The network shapes.
    pub fn networks(&self) -> &Networks {
        &self.nets
    }

    /// The actor network and its current parameters (see [`Mlp::layers`] for per-layer views).
    pub fn actor(&self) -> (&Mlp, &[f32]) {
        (&self.nets.actor, &self.shared.actor)
    }

    /// The critic network and its current parameters.
    pub fn critic(&self) -> (&Mlp, &[f32]) {
        (&self.nets.critic, &self.shared.critic)
    }

    /// The twin critic's current parameters, with `td3.twin_critics`.
    pub fn twin_critic(&self) -> Option<&[f32]> {
        self.cfg
            .td3
            .twin_critics
            .then_some(&self.shared.critic2[..])
    }

    /// The critic's target network parameters (what the TD targets are computed with).
    pub fn target_critic(&self) -> &[f32] {
        &self.shared.target_critic
    }

    /// The stored transitions: the shared replay buffer, or each worker's own (what a critic
    /// trained apart from the run, or a diagnosis, reads; in checkpoints since they resume runs).
    pub fn replays(&self) -> Vec<&Replay> {
        match &self.shared_replay {
            Some(r) => vec![r],
            None => self
                .workers
                .iter()
                .filter_map(|w| w.replay.as_ref())
                .collect(),
        }
    }

    /// Cumulative counters.
    pub fn progress(&self) -> Progress {
        let per: Vec<u64> = self.workers.iter().map(|w| w.transitions).collect();
        Progress {
            transitions: per.iter().sum(),
            transitions_per_worker: per,
            updates: self.shared.updates,
            episodes: self.counters.episodes,
            wall_s: self.counters.wall_s,
        }
    }

    /// The deterministic action of the current actor for one observation.
    pub fn act(&self, obs: &[f32], action: &mut [f32]) -> Result<(), LearnError> {
        let mut s = self.nets.actor.scratch(1);
        let mut x = obs.to_vec();
        if let Some(n) = self.obs_normalizer() {
            let d = self.nets.obs_dim.min(x.len());
            n.apply_rows(&mut x[..d]);
        }
        // Once quantisation-aware, the int8-grid actor (no normaliser then, see `validate`).
        let grid;
        let params = if self.quantisation_aware() {
            grid = self.policy_params()?;
            &grid[..]
        } else {
            &self.shared.actor[..]
        };
        let out = self.nets.actor.forward(params, &x, 1, &mut s)?;
        let n = action.len().min(out.len());
        action[..n].copy_from_slice(&out[..n]);
        Ok(())
    }

    /// The observation normaliser in use, if normalisation is on.
    pub fn obs_normalizer(&self) -> Option<Normalizer> {
        self.cfg
            .obs_norm
            .enabled
            .then(|| self.shared.obs_stats.normalizer(self.cfg.obs_norm.min_std))
    }

    /// Whether the actor is quantisation-aware now (see [`super::quantise`]): acting, evaluation and
    /// export use its int8-grid weights.
    pub fn quantisation_aware(&self) -> bool {
        self.cfg.quantise.active(self.progress().transitions)
    }

    /// The actor's parameters for export: the raw parameters; once quantisation-aware, the weights
    /// on the int8 grid (the policy the learner trains); or with normalisation on, the parameters
    /// with the normaliser folded into the first layer, so the policy takes raw observations
    /// (`Trainer::actor().0` describes all three). Normalisation and quantisation-aware training
    /// exclude each other ([`RunConfig::validate`]).
    pub fn policy_params(&self) -> Result<Vec<f32>, LearnError> {
        if self.quantisation_aware() {
            let mut q = vec![0.0; self.shared.actor.len()];
            fake_quantise(&self.nets.actor, &self.shared.actor, &mut q)?;
            return Ok(q);
        }
        match self.obs_normalizer() {
            Some(n) => n.fold_into_actor(&self.nets.actor, &self.shared.actor),
            None => Ok(self.shared.actor.clone()),
        }
    }

    /// Trains until at least `until_transitions` transitions (all workers, cumulative) have been
    /// collected and each worker has finished its episode (returns at once if the count is already
    /// reached), or until `stop` is set (checked every step; a worker's unfinished episode is then
    /// dropped). `make_env(worker)` builds each worker's environment on its own thread. Events arrive
    /// on the calling thread.
    pub fn run<E, F>(
        &mut self,
        make_env: F,
        until_transitions: u64,
        stop: &AtomicBool,
        on_event: &mut dyn FnMut(Event<'_>),
    ) -> Result<RunSummary, LearnError>
    where
        E: Env,
        F: Fn(usize) -> E + Sync,
    {
        self.run_synced(make_env, until_transitions, stop, on_event, None)
    }

    /// Pre-trains on the demonstrations where configured
    /// ([`DemoDataConfig::pretrain_updates`]) and collects nothing: a distributed run's server does
    /// this once before its worker ranks start.
    pub(crate) fn pretrain_only(
        &mut self,
        stop: &AtomicBool,
        on_event: &mut dyn FnMut(Event<'_>),
    ) -> Result<(), LearnError> {
        if self.cfg.demos.pretrain_updates == 0 || self.progress().transitions > 0 {
            return Ok(());
        }
        let make_env = |_| super::env::PointMass::new(super::env::PointMassConfig::default());
        self.run_inner(make_env, 0, stop, on_event, None, true)
            .map(|_| ())
    }

    /// [`Trainer::run`] with a [`RankSync`] polled on the calling thread about every millisecond
    /// (a distributed worker rank's exchange with the parameter server; see
    /// [`super::distributed`]). The run also ends when the sync asks for it.
    pub(crate) fn run_synced<E, F>(
        &mut self,
        make_env: F,
        until_transitions: u64,
        stop: &AtomicBool,
        on_event: &mut dyn FnMut(Event<'_>),
        sync: Option<&mut dyn RankSync>,
    ) -> Result<RunSummary, LearnError>
    where
        E: Env,
        F: Fn(usize) -> E + Sync,
    {
        self.run_inner(make_env, until_transitions, stop, on_event, sync, false)
    }

    fn run_inner<E, F>(
        &mut self,
        make_env: F,
        until_transitions: u64,
        stop: &AtomicBool,
        on_event: &mut dyn FnMut(Event<'_>),
        mut sync: Option<&mut dyn RankSync>,
        pretrain_only: bool,
    ) -> Result<RunSummary, LearnError>
    where
        E: Env,
        F: Fn(usize) -> E + Sync,
    {
        if self.cfg.demos.uses_demos() && self.demos.is_none() {
            return Err(LearnError::Config {
                field: "demos.fraction",
                why: "the run draws demonstration rows but no demonstrations were given",
            });
        }
        if self.cfg.ibrl && self.proposal.is_none() {
            return Err(LearnError::Config {
                field: "ibrl",
                why: "the run proposes the starting policy's actions but none was given \
                      (Trainer::set_proposal)",
            });
        }
        let Trainer {
            cfg,
            nets,
            shared,
            shared_replay,
            workers,
            counters,
            demos,
            proposal,
        } = self;
        let per: Vec<u64> = workers.iter().map(|w| w.transitions).collect();
        if per.iter().sum::<u64>() >= until_transitions && !pretrain_only {
            // Already done (e.g. resuming a finished run): collect nothing.
            return Ok(RunSummary {
                records: Vec::new(),
                progress: self.progress(),
                stopped: false,
            });
        }
        let s = std::mem::take(shared);
        let ctx = Ctx {
            cfg,
            nets,
            actor: Mutex::new(NetShared {
                params: s.actor,
                target: s.target_actor,
                adam: s.actor_adam,
                version: 0,
                target_version: 0,
            }),
            critic: Mutex::new(NetShared {
                params: s.critic,
                target: s.target_critic,
                adam: s.critic_adam,
                version: 0,
                target_version: 0,
            }),
            critic2: cfg.td3.twin_critics.then(|| {
                Mutex::new(NetShared {
                    params: s.critic2,
                    target: s.target_critic2,
                    adam: s.critic2_adam,
                    version: 0,
                    target_version: 0,
                })
            }),
            demos: demos.as_ref(),
            proposal: proposal.as_deref(),
            proposal_chosen: AtomicU64::new(0),
            proposal_steps: AtomicU64::new(0),
            returns: Mutex::new((s.train_return_sum, s.train_return_n)),
            obs_stats: Mutex::new(s.obs_stats),
            replay: shared_replay.take().map(Mutex::new),
            transitions: AtomicU64::new(per.iter().sum()),
            per_worker: per.iter().map(|&t| AtomicU64::new(t)).collect(),
            updates: AtomicU64::new(s.updates),
            episodes: AtomicU64::new(counters.episodes),
            evals: AtomicU64::new(counters.evals),
            stop,
            failed: AtomicBool::new(false),
            ended: AtomicBool::new(false),
            until: until_transitions,
            start: Instant::now(),
            base_wall: counters.wall_s,
        };
        let mut records = Vec::new();
        let mut sync_err = None;
        // Pre-training on the demonstrations, on the calling thread before any worker starts
        // (continued where a stop left it: no transition collected yet).
        let pre = match workers.first_mut() {
            Some(ws) if ctx.transitions.load(Ordering::Relaxed) == 0 => {
                pretrain(&ctx, ws, on_event)
            }
            _ => Ok(()),
        };
        let (tx, rx) = mpsc::channel::<EvalRecord>();
        let results: Vec<Result<(), LearnError>> = if pre.is_err() || pretrain_only {
            vec![pre]
        } else {
            std::thread::scope(|s| {
                let handles: Vec<_> = workers
                    .iter_mut()
                    .enumerate()
                    .map(|(id, ws)| {
                        let tx = tx.clone();
                        let ctx = &ctx;
                        let make_env = &make_env;
                        s.spawn(move || {
                            let r = worker_loop(ctx, id, ws, make_env, &tx);
                            if r.is_err() {
                                ctx.failed.store(true, Ordering::Relaxed);
                            }
                            r
                        })
                    })
                    .collect();
                drop(tx);
                let tick = if sync.is_some() {
                    Duration::from_millis(1)
                } else {
                    Duration::from_millis(500)
                };
                let mut shown = Instant::now();
                let mut fresh = Vec::new();
                loop {
                    match rx.recv_timeout(tick) {
                        Ok(rec) => {
                            on_event(Event::Eval(&rec));
                            fresh.push(rec.clone());
                            records.push(rec);
                        }
                        Err(mpsc::RecvTimeoutError::Timeout) => {}
                        Err(mpsc::RecvTimeoutError::Disconnected) => break,
                    }
                    if shown.elapsed() >= Duration::from_millis(500) {
                        on_event(Event::Progress(&ctx.progress()));
                        shown = Instant::now();
                    }
                    if let Some(sy) = sync.as_deref_mut() {
                        match sy.poll(&SharedNets { ctx: &ctx }, &mut fresh) {
                            Ok(false) => {}
                            Ok(true) => ctx.ended.store(true, Ordering::Relaxed),
                            Err(e) => {
                                sync_err.get_or_insert(e);
                                ctx.failed.store(true, Ordering::Relaxed);
                            }
                        }
                    }
                }
                handles
                    .into_iter()
                    .map(|h| {
                        h.join()
                            .unwrap_or(Err(LearnError::Worker("worker thread panicked")))
                    })
                    .collect()
            })
        };
        let progress = ctx.progress();
        let stopped = stop.load(Ordering::Relaxed);
        counters.episodes = ctx.episodes.load(Ordering::Relaxed);
        counters.evals = ctx.evals.load(Ordering::Relaxed);
        counters.wall_s = progress.wall_s;
        let a = ctx.actor.into_inner().map_err(poisoned)?;
        let c = ctx.critic.into_inner().map_err(poisoned)?;
        let c2 = match ctx.critic2 {
            Some(m) => m.into_inner().map_err(poisoned)?,
            None => NetShared {
                params: Vec::new(),
                target: Vec::new(),
                adam: AdamShared::new(0),
                version: 0,
                target_version: 0,
            },
        };
        let (train_return_sum, train_return_n) = ctx.returns.into_inner().map_err(poisoned)?;
        let obs_stats = ctx.obs_stats.into_inner().map_err(poisoned)?;
        *shared = SharedState {
            actor: a.params,
            critic: c.params,
            target_actor: a.target,
            target_critic: c.target,
            actor_adam: a.adam,
            critic_adam: c.adam,
            critic2: c2.params,
            target_critic2: c2.target,
            critic2_adam: c2.adam,
            updates: ctx.updates.load(Ordering::Relaxed),
            train_return_sum,
            train_return_n,
            obs_stats,
        };
        *shared_replay = match ctx.replay {
            Some(m) => Some(
                m.into_inner()
                    .map_err(|_| LearnError::Worker("replay lock poisoned"))?,
            ),
            None => None,
        };
        if let Some(e) = sync_err {
            return Err(e);
        }
        for r in results {
            r?;
        }
        Ok(RunSummary {
            records,
            progress,
            stopped,
        })
    }
}
