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

/// Replay settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReplayConfig {
    /// Total capacity in transitions; with per-worker buffers each holds `capacity / workers`.
    pub capacity: usize,
    /// One buffer shared by all workers (true) or one per worker (false).
    pub shared: bool,
}

impl Default for ReplayConfig {
    fn default() -> Self {
        ReplayConfig {
            capacity: 1_000_000,
            shared: true,
        }
    }
}

/// The evaluation protocol.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EvalConfig {
    /// Evaluate after every this many training episodes (all workers together); 0 disables evaluation.
    pub every_episodes: u64,
    /// Noise-free episodes per evaluation.
    pub episodes: usize,
    /// Safety cap on an evaluation episode's length, for environments that never end one.
    pub max_steps: usize,
    /// Every evaluation uses the same `episodes` starts (so a curve shows learning, not which
    /// starts were drawn); false draws fresh starts per evaluation (the paper's protocol).
    pub fixed_starts: bool,
}

impl Default for EvalConfig {
    fn default() -> Self {
        EvalConfig {
            every_episodes: 30,
            episodes: 10,
            max_steps: 10_000,
            fixed_starts: true,
        }
    }
}

/// Everything a run needs besides the environment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RunConfig {
    /// Networks and the DDPG update.
    pub ddpg: DdpgConfig,
    /// Adam for the actor (the paper tunes only learning rates).
    pub actor_adam: AdamConfig,
    /// Adam for the critic.
    pub critic_adam: AdamConfig,
    /// Worker threads W (1 = DPG-R).
    pub workers: usize,
    /// Mini-batch updates per environment step R (per worker).
    pub updates_per_step: usize,
    /// Replay buffer(s).
    pub replay: ReplayConfig,
    /// Exploration noise.
    pub noise: NoiseConfig,
    /// Transitions in the sampled buffer before updates start.
    pub learning_starts: usize,
    /// Evaluation protocol.
    pub eval: EvalConfig,
    /// Cut training episodes after this many steps (the environment's own limit applies too).
    pub train_episode_steps: Option<usize>,
    /// Observation normalisation (off by default; see [`Trainer::policy_params`] for export).
    pub obs_norm: ObsNormConfig,
    /// Quantisation-aware training of the actor (off by default; see [`super::quantise`]).
    pub quantise: QuantiseConfig,
    /// TD3's stabilisers (all off by default; see [`super::td3`]).
    pub td3: Td3Config,
    /// n-step returns (1: the paper's one-step targets; see [`super::n_step`]).
    pub n_step: usize,
    /// Demonstrations in the batches and the cloning term (off by default; see
    /// [`super::demo_data`]); the buffer itself is given with [`Trainer::set_demonstrations`].
    pub demos: DemoDataConfig,
    /// Seed of everything random in the run.
    pub seed: u64,
}

impl Default for RunConfig {
    fn default() -> Self {
        RunConfig {
            ddpg: DdpgConfig::default(),
            actor_adam: AdamConfig {
                lr: 1e-4,
                ..AdamConfig::default()
            },
            critic_adam: AdamConfig {
                lr: 1e-3,
                ..AdamConfig::default()
            },
            workers: 1,
            updates_per_step: 1,
            replay: ReplayConfig::default(),
            noise: NoiseConfig::default(),
            learning_starts: 1_000,
            eval: EvalConfig::default(),
            train_episode_steps: None,
            obs_norm: ObsNormConfig::default(),
            quantise: QuantiseConfig::default(),
            td3: Td3Config::default(),
            n_step: 1,
            demos: DemoDataConfig::default(),
            seed: 0,
        }
    }
}

impl RunConfig {
    /// Checks ranges that would make a run meaningless.
    pub fn validate(&self) -> Result<(), LearnError> {
        let bad = |field, why| Err(LearnError::Config { field, why });
        if self.workers == 0 {
            return bad("workers", "must be at least 1");
        }
        if self.ddpg.batch_size == 0 {
            return bad("ddpg.batch_size", "must be at least 1");
        }
        if self.replay.capacity < self.workers {
            return bad(
                "replay.capacity",
                "must hold at least one transition per worker",
            );
        }
        if !(self.ddpg.gamma >= 0.0 && self.ddpg.gamma <= 1.0) {
            return bad("ddpg.gamma", "must be in [0, 1]");
        }
        self.noise.validate(None)?;
        self.td3.validate()?;
        self.demos.validate()?;
        if self.n_step == 0 || self.n_step > 100 {
            return bad("n_step", "must be in 1..=100");
        }
        if self.obs_norm.frozen_from_demos && !(self.obs_norm.enabled && self.demos.uses_demos()) {
            return bad(
                "obs_norm.frozen_from_demos",
                "needs obs_norm.enabled and demonstrations in the batches (demos.fraction > 0)",
            );
        }
        if self.demos.uses_demos() && self.quantise.aware_from.is_some() {
            return bad(
                "demos.fraction",
                "demonstrations with quantisation-aware training are not supported",
            );
        }
        for (field, a) in [
            ("actor_adam", &self.actor_adam),
            ("critic_adam", &self.critic_adam),
        ] {
            let ok = a.lr > 0.0
                && a.lr.is_finite()
                && (0.0..1.0).contains(&a.beta1)
                && (0.0..1.0).contains(&a.beta2)
                && a.eps > 0.0;
            if !ok {
                return bad(field, "lr > 0, betas in [0, 1), eps > 0");
            }
        }
        if self.quantise.aware_from.is_some() && self.obs_norm.enabled {
            return bad(
                "quantise.aware_from",
                "needs obs_norm off: folding the normaliser into the first layer would move its \
                 weights off the int8 grid",
            );
        }
        if let super::ddpg::TargetUpdate::Polyak { tau } = self.ddpg.target
            && !(tau > 0.0 && tau <= 1.0)
        {
            return bad("ddpg.target.tau", "must be in (0, 1]");
        }
        Ok(())
    }
}

/// One evaluation, as written to the JSON-lines log.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalRecord {
    /// Evaluation number (1, 2, ...).
    pub eval_index: u64,
    /// Training episodes finished (all workers).
    pub episodes: u64,
    /// Environment transitions (all workers).
    pub transitions: u64,
    /// Environment transitions of each worker.
    pub transitions_per_worker: Vec<u64>,
    /// Mini-batch updates applied (all workers).
    pub updates: u64,
    /// Training wall-clock time in seconds (summed over resumed runs).
    pub wall_s: f64,
    /// Mean undiscounted return of the evaluation episodes.
    pub mean_return: f64,
    /// Fraction of evaluation episodes ending in success.
    pub success_rate: f64,
    /// Mean return of the training episodes since the previous evaluation (with noise).
    pub train_return: f64,
    /// The worker that ran the evaluation.
    pub worker: usize,
}

impl EvalRecord {
    /// One JSON line (no trailing newline).
    pub fn to_json_line(&self) -> String {
        // Serialising plain numbers and vectors cannot fail.
        serde_json::to_string(self).unwrap_or_default()
    }
}

/// Live counters, reported about twice a second during [`Trainer::run`].
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct Progress {
    /// Environment transitions (all workers).
    pub transitions: u64,
    /// Environment transitions of each worker.
    pub transitions_per_worker: Vec<u64>,
    /// Updates applied.
    pub updates: u64,
    /// Training episodes finished.
    pub episodes: u64,
    /// Training wall-clock seconds (summed over resumed runs).
    pub wall_s: f64,
}

/// What [`Trainer::run`] streams to its caller (on the calling thread).
#[derive(Debug, Clone, Copy)]
pub enum Event<'a> {
    /// An evaluation finished.
    Eval(&'a EvalRecord),
    /// Periodic counters.
    Progress(&'a Progress),
}

/// What one [`Trainer::run`] call did.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RunSummary {
    /// Evaluations of this call, in order.
    pub records: Vec<EvalRecord>,
    /// Counters at the end of the call (cumulative over the whole training).
    pub progress: Progress,
    /// True if the stop flag ended the call before the budget.
    pub stopped: bool,
}

#[derive(Debug, Clone, PartialEq, Default)]
pub(crate) struct SharedState {
    pub(crate) actor: Vec<f32>,
    pub(crate) critic: Vec<f32>,
    pub(crate) target_actor: Vec<f32>,
    pub(crate) target_critic: Vec<f32>,
    pub(crate) actor_adam: AdamShared,
    pub(crate) critic_adam: AdamShared,
    /// The twin critic (empty without `td3.twin_critics`).
    pub(crate) critic2: Vec<f32>,
    pub(crate) target_critic2: Vec<f32>,
    pub(crate) critic2_adam: AdamShared,
    pub(crate) updates: u64,
    pub(crate) train_return_sum: f64,
    pub(crate) train_return_n: u64,
    pub(crate) obs_stats: ObsStats,
}

impl Default for AdamShared {
    fn default() -> Self {
        AdamShared::new(0)
    }
}

#[derive(Debug, Clone)]
pub(crate) struct WorkerState {
    pub(crate) rng: Rng,
    pub(crate) actor_m: AdamLocal,
    pub(crate) critic_m: AdamLocal,
    /// First moment of the twin critic (empty without it).
    pub(crate) critic2_m: AdamLocal,
    pub(crate) replay: Option<Replay>,
    pub(crate) transitions: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) struct Counters {
    pub(crate) episodes: u64,
    pub(crate) evals: u64,
    pub(crate) wall_s: f64,
}

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
        let shared_replay = cfg
            .replay
            .shared
            .then(|| Replay::new(cfg.replay.capacity, obs_dim, act_dim));
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
                    .then(|| Replay::new(cfg.replay.capacity / w, obs_dim, act_dim)),
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
        let Trainer {
            cfg,
            nets,
            shared,
            shared_replay,
            workers,
            counters,
            demos,
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

struct Ctx<'a> {
    cfg: &'a RunConfig,
    nets: &'a Networks,
    actor: Mutex<NetShared>,
    critic: Mutex<NetShared>,
    /// The twin critic, with `td3.twin_critics`.
    critic2: Option<Mutex<NetShared>>,
    demos: Option<&'a DemoBuffer>,
    returns: Mutex<(f64, u64)>,
    obs_stats: Mutex<ObsStats>,
    replay: Option<Mutex<Replay>>,
    transitions: AtomicU64,
    per_worker: Vec<AtomicU64>,
    updates: AtomicU64,
    episodes: AtomicU64,
    evals: AtomicU64,
    stop: &'a AtomicBool,
    failed: AtomicBool,
    /// Set by a [`RankSync`] that ends the run (the parameter server said stop).
    ended: AtomicBool,
    until: u64,
    start: Instant,
    base_wall: f64,
}

impl Ctx<'_> {
    fn wall_s(&self) -> f64 {
        self.base_wall + self.start.elapsed().as_secs_f64()
    }

    fn progress(&self) -> Progress {
        Progress {
            transitions: self.transitions.load(Ordering::Relaxed),
            transitions_per_worker: self
                .per_worker
                .iter()
                .map(|a| a.load(Ordering::Relaxed))
                .collect(),
            updates: self.updates.load(Ordering::Relaxed),
            episodes: self.episodes.load(Ordering::Relaxed),
            wall_s: self.wall_s(),
        }
    }

    /// Whether the actor is used quantisation-aware from now on.
    fn quantisation_aware(&self) -> bool {
        self.cfg
            .quantise
            .active(self.transitions.load(Ordering::Relaxed))
    }

    fn halted(&self) -> bool {
        self.stop.load(Ordering::Relaxed)
            || self.failed.load(Ordering::Relaxed)
            || self.ended.load(Ordering::Relaxed)
    }
}

/// The exchange of a distributed worker rank, polled on the run's calling thread (the only
/// thread of the rank that talks to other ranks).
pub(crate) trait RankSync {
    /// Moves parameters between this rank's shared state and the parameter server; `fresh` holds
    /// the evaluations finished since the last call (the sync takes what it forwards). Returns
    /// true when the run should end.
    fn poll(
        &mut self,
        shared: &SharedNets<'_, '_>,
        fresh: &mut Vec<EvalRecord>,
    ) -> Result<bool, LearnError>;
}

/// What a [`RankSync`] may touch of a running [`Trainer`]: the networks' shared halves (under
/// their locks) and the counters.
pub(crate) struct SharedNets<'c, 'a> {
    ctx: &'c Ctx<'a>,
}

impl SharedNets<'_, '_> {
    /// Runs `f` on network `i` (see [`SharedNets::net_count`]) under its lock; the workers copy
    /// the parameters and target again afterwards.
    pub(crate) fn with_net<R>(
        &self,
        i: usize,
        f: impl FnOnce(&mut NetShared) -> R,
    ) -> Result<R, LearnError> {
        let m = match i {
            0 => &self.ctx.actor,
            1 => &self.ctx.critic,
            _ => self
                .ctx
                .critic2
                .as_ref()
                .ok_or(LearnError::Worker("no such network"))?,
        };
        let mut g = lock(m)?;
        let r = f(&mut g);
        g.version += 1;
        g.target_version += 1;
        Ok(r)
    }

    /// The update counter (all of this rank's workers).
    pub(crate) fn updates(&self) -> &AtomicU64 {
        &self.ctx.updates
    }

    /// The rank's counters now.
    pub(crate) fn progress(&self) -> Progress {
        self.ctx.progress()
    }
}

fn poisoned<T>(_: std::sync::PoisonError<T>) -> LearnError {
    LearnError::Worker("shared state lock poisoned")
}

fn lock<T>(m: &Mutex<T>) -> Result<MutexGuard<'_, T>, LearnError> {
    m.lock()
        .map_err(|_| LearnError::Worker("a lock was poisoned by a panicking worker"))
}

/// One network's shared half during a run.
pub(crate) struct NetShared {
    pub(crate) params: Vec<f32>,
    pub(crate) target: Vec<f32>,
    pub(crate) adam: AdamShared,
    version: u64,
    target_version: u64,
}

/// A worker's local copies of the networks and its buffers.
struct Local {
    actor: Vec<f32>,
    critic: Vec<f32>,
    target_actor: Vec<f32>,
    target_critic: Vec<f32>,
    /// Versions of the local actor, critic, target actor, target critic.
    versions: [u64; 4],
    /// The twin critic and its target (empty without it) and their versions.
    critic2: Vec<f32>,
    target_critic2: Vec<f32>,
    versions2: [u64; 2],
    bufs: UpdateBuffers,
    act_scratch: MlpScratch,
    /// The worker's copy of the observation normaliser (refreshed every step when on).
    norm: Normalizer,
    /// Int8-grid copies of the actor and target actor (quantisation-aware training).
    actor_q: QuantisedCopy,
    target_actor_q: QuantisedCopy,
}

impl Local {
    /// A worker's copies of the shared networks as they are now.
    fn new(ctx: &Ctx<'_>) -> Result<Self, LearnError> {
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
fn pretrain(
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
enum Phase {
    /// Demonstration rows alone; the actor clones them (see [`DemoDataConfig::pretrain_updates`]).
    Pretrain,
    /// The run's update: replay rows (and demonstration rows where configured).
    Run,
}

fn worker_loop<E: Env>(
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
    let mut obs_n = vec![0.0f32; od];
    let mut eval_scratch = nets.actor.scratch(1);
    let norm_on = cfg.obs_norm.enabled;
    let norm_moves = norm_on && !cfg.obs_norm.frozen_from_demos;
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
        pending.push(&obs, &action, step.reward, step.terminal, done, |t| {
            replay.push_discounted(t.obs, t.act, t.reward, &next_obs, t.not_done);
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

impl NetShared {
    /// Copies the online and target parameters into a worker's copies (each with the version it
    /// last copied) where the shared version moved on since.
    fn refresh_into(&self, online: (&mut [f32], &mut u64), target: (&mut [f32], &mut u64)) {
        for ((local, seen), shared, version) in [
            (online, &self.params, self.version),
            (target, &self.target, self.target_version),
        ] {
            if *seen != version {
                local.copy_from_slice(shared);
                *seen = version;
            }
        }
    }
}

/// One DDPG update on shared parameters (steps 1-6 of the module docs), with the TD3 pieces and
/// the demonstration rows where configured.
fn update(
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
    let t = cfg.ddpg.target;
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
    for m in std::iter::once(&ctx.critic).chain(ctx.critic2.as_ref()) {
        let mut guard = lock(m)?;
        let c = &mut *guard;
        if t.apply(u, &c.params, &mut c.target) {
            c.target_version += 1;
        }
    }
    Ok(())
}

/// Runs `cfg.episodes` noise-free episodes; returns (mean return, success rate).
fn evaluate<E: Env>(
    actor: &Mlp,
    params: &[f32],
    env: &mut E,
    cfg: &EvalConfig,
    rng: &mut Rng,
    scratch: &mut MlpScratch,
    norm: Option<&Normalizer>,
) -> Result<(f64, f64), LearnError> {
    let (od, ad) = (env.obs_dim(), env.act_dim());
    let mut obs = vec![0.0f32; od];
    let mut obs_n = vec![0.0f32; od];
    let mut action = vec![0.0f32; ad];
    let mut total = 0.0f64;
    let mut successes = 0usize;
    for _ in 0..cfg.episodes {
        env.reset_eval(rng, &mut obs);
        let mut last_success = false;
        for _ in 0..cfg.max_steps.max(1) {
            obs_n.copy_from_slice(&obs);
            if let Some(n) = norm {
                n.apply_rows(&mut obs_n);
            }
            let out = actor.forward(params, &obs_n, 1, scratch)?;
            action.copy_from_slice(out);
            let step = env.step(&action, &mut obs);
            total += f64::from(step.reward);
            last_success = step.success;
            if step.done() {
                break;
            }
        }
        successes += usize::from(last_success);
    }
    let n = cfg.episodes.max(1) as f64;
    Ok((total / n, successes as f64 / n))
}

/// Evaluates an actor on `episodes` noise-free episodes with a generator seeded from `seed`; returns
/// (mean return, success rate). For final evaluations outside training.
pub fn evaluate_actor<E: Env>(
    actor: &Mlp,
    params: &[f32],
    env: &mut E,
    episodes: usize,
    max_steps: usize,
    seed: u64,
) -> Result<(f64, f64), LearnError> {
    let cfg = EvalConfig {
        every_episodes: 0,
        episodes,
        max_steps,
        fixed_starts: true,
    };
    let mut scratch = actor.scratch(1);
    evaluate(
        actor,
        params,
        env,
        &cfg,
        &mut Rng::seed_from_u64(seed),
        &mut scratch,
        None,
    )
}
