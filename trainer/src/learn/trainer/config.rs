//! The settings of a run: replay, evaluation protocol and everything [`RunConfig`] holds.

use super::*;

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
    /// Quantisation-aware training of the actor (off by default; see [`crate::learn::quantise`]).
    pub quantise: QuantiseConfig,
    /// TD3's stabilisers (all off by default; see [`crate::learn::td3`]).
    pub td3: Td3Config,
    /// n-step returns (1: the paper's one-step targets; see [`crate::learn::n_step`]).
    pub n_step: usize,
    /// Demonstrations in the batches and the cloning term (off by default; see
    /// [`crate::learn::demo_data`]); the buffer itself is given with [`Trainer::set_demonstrations`].
    pub demos: DemoDataConfig,
    /// Critic warm-up (Cal-QL / WSRL's remedy for a pre-trained actor "unlearning" under a
    /// fresh critic): after DDPGfD's pre-training, if any, the first this many updates train the
    /// critic (and move its target) but leave the actor as it started, so the critic has rated
    /// the starting policy's own transitions before it moves that policy. 0: off.
    pub critic_warmup_updates: u64,
    /// Teacher labels (beyond the paper; DAgger's relabelling inside the RL loop): every
    /// transition a worker collects is stored with the teacher's action at its observation
    /// ([`crate::learn::env::Env::expert_action`]: for the Jaco tasks the Markov demonstrator, a
    /// function of the state), and the cloning term (`demos.bc_weight`) applies to every row of
    /// every batch with that label as its target: the actor is held to the teacher on the states
    /// it visits itself, not only on the teacher's own, while the critic's gradient moves it
    /// where the return says the teacher is wrong. Needs `n_step = 1` and `demos.bc_weight > 0`.
    pub teacher_labels: bool,
    /// The starting policy as a frozen proposal (IBRL; [`crate::learn::ibrl`]): each step the
    /// worker executes whichever of the actor's noisy action and the starting policy's action
    /// the critic rates higher, and the critic's targets bootstrap from the better of the two.
    /// The starting policy is given with [`Trainer::set_proposal`] (the run's `init_policy`);
    /// the export is the actor alone. Not with a residual actor or quantisation-aware training.
    pub ibrl: bool,
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
            critic_warmup_updates: 0,
            teacher_labels: false,
            ibrl: false,
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
        if self.updates_per_step == 0 {
            return bad(
                "updates_per_step",
                "must be at least 1 (R = 0 would collect transitions and never learn)",
            );
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
        if let Some(r) = self.ddpg.residual {
            if r == 0 || r > crate::learn::ddpg::MAX_RESIDUAL {
                return bad(
                    "ddpg.residual",
                    "the residual's width must be in 1..=768 units per hidden layer",
                );
            }
            if self.ddpg.actor_hidden.is_empty() {
                return bad(
                    "ddpg.residual",
                    "a residual needs a base with hidden layers (ddpg.actor_hidden)",
                );
            }
        }
        self.noise.validate(None)?;
        self.td3.validate()?;
        self.demos.validate_with(self.teacher_labels)?;
        if self.n_step == 0 || self.n_step > 100 {
            return bad("n_step", "must be in 1..=100");
        }
        if self.teacher_labels && self.n_step != 1 {
            return bad(
                "teacher_labels",
                "needs n_step = 1 (a label is the teacher's action at the row's own observation)",
            );
        }
        if self.teacher_labels && self.demos.bc_weight <= 0.0 {
            return bad(
                "teacher_labels",
                "needs demos.bc_weight > 0 (the labels are the cloning term's targets)",
            );
        }
        if self.ibrl && self.ddpg.residual.is_some() {
            return bad(
                "ibrl",
                "the proposal is the starting policy beside the actor; a residual actor already \
                 holds it inside (choose one)",
            );
        }
        if self.ibrl && self.quantise.aware_from.is_some() {
            return bad(
                "ibrl",
                "not supported with quantisation-aware training (quantise.aware_from)",
            );
        }
        if self.obs_norm.frozen_from_demos && !(self.obs_norm.enabled && self.demos.uses_demos()) {
            return bad(
                "obs_norm.frozen_from_demos",
                "needs obs_norm.enabled and demonstrations in the batches (demos.fraction > 0)",
            );
        }
        if self.obs_norm.frozen_from_init
            && (!self.obs_norm.enabled || self.obs_norm.frozen_from_demos)
        {
            return bad(
                "obs_norm.frozen_from_init",
                "needs obs_norm.enabled and not obs_norm.frozen_from_demos",
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
        if let crate::learn::ddpg::TargetUpdate::Polyak { tau } = self.ddpg.target
            && !(tau > 0.0 && tau <= 1.0)
        {
            return bad("ddpg.target.tau", "must be in (0, 1]");
        }
        Ok(())
    }
}
